"""Progress of a render, with compilation apart from rendering.

A render's first call of each kernel compiles it (seconds to a minute on the CPU), then the
kernels run. A bar that divides the work done by the wall time counts compilation as rendering:
it starts with an ETA many times the real one. Here compilation is measured, not guessed: JAX
reports the duration of each tracing, lowering and XLA compile (``jax.monitoring`` events, also
when the program is read from the persistent cache), and a render's *render time* is its wall
time minus the compile time spent during it. Rates and ETAs use render time only.

* :func:`tracking` wraps one render (``jgi.render(..., progress=True)`` does): it sends a
  :class:`Tick` when the render starts, whenever a driver calls :func:`advance`, and when it ends.
* Ticks go to a *sink*, a callable taking a :class:`Tick`: by default a ``rich`` bar on stderr
  (:class:`TerminalBar`); a study sets its own with :func:`sending_to` (its display, or on a Dask
  worker a forwarder to the client: ``jgi.experiment.display``).

Nothing here changes a result: ticks only report.
"""

from __future__ import annotations

import contextvars
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Iterator

from jax import monitoring
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn

_COMPILE_EVENTS = frozenset({
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    "/jax/core/compile/backend_compile_duration",
})
_compile_lock = threading.Lock()
_compile_total = [0.0]


def _on_duration(event: str, duration: float, **_) -> None:
    if event in _COMPILE_EVENTS:
        with _compile_lock:
            _compile_total[0] += duration


monitoring.register_event_duration_secs_listener(_on_duration)


def compile_seconds() -> float:
    """Seconds this process has spent tracing, lowering and compiling JAX programs so far."""
    with _compile_lock:
        return _compile_total[0]


@dataclass(frozen=True)
class Tick:
    """Where one render stands: ``done`` of ``total`` work units (``unit``: paths, iterations;
    total 0 while unknown), seconds spent compiling and rendering so far, whether it ended."""

    label: str
    done: int
    total: int
    unit: str
    compile_s: float
    render_s: float
    finished: bool = False

    @property
    def phase(self) -> str:
        if self.finished:
            return "done"
        return "rendering" if self.done > 0 else "compiling"

    @property
    def rate(self) -> float:
        """Work units per second of render time (0 before the first unit)."""
        return self.done / self.render_s if self.done > 0 and self.render_s > 0 else 0.0

    @property
    def eta(self) -> float | None:
        """Seconds of rendering left at the current rate, None while unknown."""
        if not self.total or self.rate <= 0:
            return None
        return max(self.total - self.done, 0) / self.rate

    def describe(self) -> str:
        if self.finished:
            return f"rendered in {self.render_s:.1f} s, compiled in {self.compile_s:.1f} s"
        if self.phase == "compiling":
            return f"compiling ... {self.compile_s + self.render_s:.0f} s"
        scale, prefix = (1e6, "M") if self.rate >= 1e5 else (1.0, "")
        eta = "" if self.eta is None else f"  ETA {self.eta:.0f} s"
        return (f"{self.rate / scale:.2f} {prefix}{self.unit}/s{eta}  "
                f"(compiled in {self.compile_s:.1f} s)")


Sink = Callable[[Tick], None]
_sink: contextvars.ContextVar[Sink | None] = contextvars.ContextVar("jgi_progress_sink",
                                                                    default=None)
_current: contextvars.ContextVar[_Render | None] = contextvars.ContextVar("jgi_progress_render",
                                                                          default=None)


class _Render:
    def __init__(self, label: str, sink: Sink):
        self.label, self.sink = label, sink
        self.t0, self.c0 = time.perf_counter(), compile_seconds()
        self.done, self.total, self.unit = 0, 0, "paths"

    def tick(self, finished: bool = False) -> Tick:
        wall = time.perf_counter() - self.t0
        compiled = min(compile_seconds() - self.c0, wall)
        t = Tick(self.label, self.done, self.total, self.unit, compiled, wall - compiled,
                 finished)
        self.sink(t)
        return t


@contextmanager
def sending_to(sink: Sink) -> Iterator[None]:
    """Renders tracked inside this block send their ticks to ``sink``."""
    token = _sink.set(sink)
    try:
        yield
    finally:
        _sink.reset(token)


@contextmanager
def tracking(label: str) -> Iterator[list]:
    """Track one render: ticks go to the current sink (default: a :class:`TerminalBar`). The
    list yielded receives the final :class:`Tick` when the block ends."""
    sink = _sink.get() or TerminalBar()
    render = _Render(label, sink)
    token = _current.set(render)
    last: list[Tick] = []
    render.tick()
    try:
        yield last
    finally:
        _current.reset(token)
        last.append(render.tick(finished=True))


def advance(done: int, total: int, unit: str = "paths") -> None:
    """A driver's report: ``done`` of ``total`` units of the tracked render are finished (no
    effect outside :func:`tracking`)."""
    render = _current.get()
    if render is not None:
        render.done, render.total, render.unit = int(done), int(total), unit
        render.tick()


class TerminalBar:
    """One render's bar on stderr (``rich``): compiling, then rate and ETA from render time."""

    def __init__(self):
        self.bar = Progress(TextColumn("{task.description}"), BarColumn(),
                            TextColumn("{task.percentage:>5.1f}%  {task.fields[info]}"),
                            console=Console(file=sys.stderr), transient=False)
        self.task = None

    def __call__(self, tick: Tick) -> None:
        if self.task is None:
            self.bar.start()
            self.task = self.bar.add_task(tick.label or "render", total=None, info="")
        total = tick.total or None
        done = tick.total if tick.finished and tick.total else tick.done
        self.bar.update(self.task, completed=done, total=total, info=tick.describe())
        if tick.finished:
            self.bar.stop()
