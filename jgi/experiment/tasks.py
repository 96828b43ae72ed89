"""Running one task of a study (:mod:`jgi.experiment.plan`), in this process or on a Dask worker.

The task's scene is loaded once per process; the render's progress ticks go to the sink the
executor gives; the result (image, render seconds, compile seconds, samples) is written to
``<folder>/<key>.npz`` through a uniquely named temporary file and an atomic rename, so a file
that exists is whole, a task killed mid-write leaves only a temporary file (removed by the
study when it ends), and a rerun of a task that already has its file does nothing.
"""

from __future__ import annotations

import functools
import os
import time
import uuid
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from ..api import render as render_image
from ..core.progress import Sink, Tick, sending_to
from .plan import load_scene_at

TMP_SUFFIX = ".tmp.npz"


@dataclass(frozen=True)
class StudyJob:
    """What every task of one study shares: the scene, the result folders by task kind, and the
    render function (``jgi.render`` unless a test wraps it; it takes ``progress=``)."""

    scene_src: str
    resolution: int | tuple | None
    folders: dict
    render: Callable | None = None

    def path(self, task: dict) -> Path:
        return Path(self.folders[task["kind"]]) / f"{task['key']}.npz"


def atomic_save(path: Path, **arrays) -> None:
    """Write ``arrays`` to ``path`` whole or not at all (unique temporary name, then rename)."""
    tmp = path.with_name(f"{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}{TMP_SUFFIX}")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)


@functools.lru_cache(maxsize=4)
def _scene(src: str, resolution):
    return load_scene_at(src, resolution)


def execute(job: StudyJob, task: dict, sink: Sink | None = None) -> dict:
    """Run ``task`` unless its file exists; returns {key, ran, render_s, compile_s}."""
    path = job.path(task)
    if path.exists():
        return dict(key=task["key"], ran=False)
    scene = _scene(job.scene_src, job.resolution)
    render = job.render or render_image
    ticks: list[Tick] = []

    def keep(tick: Tick) -> None:
        ticks.append(tick)
        if sink is not None:
            sink(tick)

    t0 = time.perf_counter()
    with sending_to(keep):
        image = render(scene, task["estimator"], spp=task["spp"], seed=task["seed"],
                       progress=True, **task["params"])
    wall = time.perf_counter() - t0
    final = ticks[-1] if ticks and ticks[-1].finished else None
    render_s = final.render_s if final else wall
    compile_s = final.compile_s if final else 0.0
    atomic_save(path, image=np.asarray(image, np.float32), seconds=np.float64(render_s),
                compile_seconds=np.float64(compile_s), spp=np.int64(task["spp"]))
    return dict(key=task["key"], ran=True, render_s=render_s, compile_s=compile_s)


def remove_temporaries(folder: Path) -> int:
    """Delete what killed writers left in ``folder`` (call when no task is running)."""
    stale = list(Path(folder).glob(f"*{TMP_SUFFIX}"))
    for p in stale:
        p.unlink(missing_ok=True)
    return len(stale)
