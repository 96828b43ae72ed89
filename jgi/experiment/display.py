"""A study's progress on the terminal (``rich``): one row for the study, one per running task.

Each task's row shows compiling apart from rendering (ticks from :mod:`jgi.core.progress`, sent
from Dask workers as events when the study runs on a cluster). The study's row counts finished
tasks, and its ETA uses render time only: the render seconds per sample measured so far for
each estimator, times the samples left, divided by the number of workers (before an
estimator's first task ends, the mean over all finished tasks stands in).
"""

from __future__ import annotations

import sys
import threading

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn

from ..core.progress import Tick


class StudyDisplay:
    def __init__(self, name: str, tasks: list[dict], workers: int, enabled: bool = True):
        self.tasks = {t["key"]: t for t in tasks}
        self.workers = max(1, workers)
        self.enabled = enabled
        self.lock = threading.Lock()
        self.rows: dict[str, int] = {}
        self.seconds: dict[str, float] = {}     # estimator -> render seconds of finished tasks
        self.samples: dict[str, int] = {}       # estimator -> samples of finished tasks
        self.left = {k: t["spp"] for k, t in self.tasks.items()}
        self.bar = Progress(TextColumn("{task.description}"), BarColumn(),
                            MofNCompleteColumn(), TextColumn("{task.fields[info]}"),
                            console=Console(file=sys.stderr), transient=False)
        self.study = self.bar.add_task(name, total=len(tasks), info="")
        if enabled:
            self.bar.start()

    def skip(self, task: dict) -> None:
        """A task whose file was already there (a resumed study)."""
        with self.lock:
            self.left.pop(task["key"], None)
            self.bar.advance(self.study)

    def tick(self, key: str, tick: Tick) -> None:
        with self.lock:
            if key not in self.tasks or key not in self.left:
                return
            if key not in self.rows and not tick.finished:
                self.rows[key] = self.bar.add_task(f"  {self.tasks[key]['label']}", total=None,
                                                   info="")
            if key in self.rows:
                self.bar.update(self.rows[key], completed=tick.done, total=tick.total or None,
                                info=tick.describe())

    def done(self, task: dict, result: dict) -> None:
        with self.lock:
            key = task["key"]
            if key in self.rows:
                self.bar.remove_task(self.rows.pop(key))
            if self.left.pop(key, None) is None:
                return
            if result.get("ran"):
                est = task["estimator"]
                self.seconds[est] = self.seconds.get(est, 0.0) + result["render_s"]
                self.samples[est] = self.samples.get(est, 0) + task["spp"]
            self.bar.update(self.study, advance=1, info=self._eta())

    def _eta(self) -> str:
        if not self.samples:
            return ""
        mean = sum(self.seconds.values()) / max(sum(self.samples.values()), 1)
        left = sum(n * self.seconds.get(self.tasks[k]["estimator"], 0.0)
                   / self.samples.get(self.tasks[k]["estimator"], 1)
                   if self.tasks[k]["estimator"] in self.samples else n * mean
                   for k, n in self.left.items())
        return f"ETA {left / self.workers:.0f} s of rendering (compile excluded)"

    def close(self) -> None:
        if self.enabled:
            self.bar.stop()

