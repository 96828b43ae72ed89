"""A pytest plugin that records, per test, where its time went: JAX tracing, lowering, XLA's
backend compile (with the number of programs compiled and loaded from the persistent cache) and
the rest. For finding what makes the suite slow, not part of a normal run:

    JGI_COMPILE_PROFILE=runs/profile ./dev test -p tests.support.compile_profile

writes one JSON line per test to ``runs/profile/<worker>.jsonl``; summarise them with
``python -m tests.support.compile_profile runs/profile``.

JAX is imported only once the first test starts, after ``tests/conftest.py`` has set the
environment JAX reads at import."""

from __future__ import annotations

import json
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

import pytest

_EVENTS = {
    "/jax/core/compile/jaxpr_trace_duration": "trace_s",
    "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower_s",
    "/jax/core/compile/backend_compile_duration": "compile_s",
}
_COUNTS = {
    "/jax/compilation_cache/cache_hits": "cache_hits",
    "/jax/compilation_cache/cache_misses": "cache_misses",
}

_current: dict = defaultdict(float)
_listening = False


def _on_duration(event: str, duration: float, **_) -> None:
    name = _EVENTS.get(event)
    if name:
        _current[name] += duration
        if name == "compile_s":
            _current["programs"] += 1


def _on_event(event: str, **_) -> None:
    name = _COUNTS.get(event)
    if name:
        _current[name] += 1


def _listen() -> None:
    global _listening
    if not _listening:
        import jax.monitoring

        jax.monitoring.register_event_duration_secs_listener(_on_duration)
        jax.monitoring.register_event_listener(_on_event)
        _listening = True


def _out() -> Path | None:
    folder = os.environ.get("JGI_COMPILE_PROFILE")
    if not folder:
        return None
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    path = Path(folder) / f"{worker}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    _listen()
    _current.clear()
    start, cpu = time.perf_counter(), time.process_time()
    yield
    path = _out()
    if path is not None:
        row = {"test": item.nodeid, "wall_s": time.perf_counter() - start,
               "cpu_s": time.process_time() - cpu, **_current}
        with path.open("a") as f:
            f.write(json.dumps(row) + "\n")


def summarise(folder: Path, top: int = 60) -> None:
    rows = [json.loads(line) for p in sorted(folder.glob("*.jsonl")) for line in p.open()]
    total = lambda key: sum(r.get(key, 0.0) for r in rows)  # noqa: E731
    print(f"{len(rows)} tests, wall {total('wall_s'):.0f} worker-s, backend compile "
          f"{total('compile_s'):.0f} s ({total('programs'):.0f} programs), trace "
          f"{total('trace_s'):.0f} s, lower {total('lower_s'):.0f} s, cache hits "
          f"{total('cache_hits'):.0f}")
    by_module: dict = defaultdict(lambda: defaultdict(float))
    for r in rows:
        m = by_module[r["test"].split("::")[0]]
        for key in ("wall_s", "compile_s", "trace_s", "lower_s", "programs"):
            m[key] += r.get(key, 0.0)
        m["tests"] += 1
    print("\nby module: wall, compile, trace+lower, programs, tests")
    for name, m in sorted(by_module.items(), key=lambda kv: -kv[1]["wall_s"]):
        print(f"{m['wall_s']:7.0f} {m['compile_s']:7.0f} {m['trace_s'] + m['lower_s']:6.0f} "
              f"{m['programs']:5.0f} {m['tests']:4.0f}  {name}")
    print(f"\nslowest {top} tests: wall, compile, trace+lower, programs, cache hits")
    for r in sorted(rows, key=lambda r: -r["wall_s"])[:top]:
        print(f"{r['wall_s']:7.1f} {r.get('compile_s', 0):7.1f} "
              f"{r.get('trace_s', 0) + r.get('lower_s', 0):6.1f} {r.get('programs', 0):4.0f} "
              f"{r.get('cache_hits', 0):4.0f}  {r['test']}")


if __name__ == "__main__":
    summarise(Path(sys.argv[1]), *(int(a) for a in sys.argv[2:3]))
