"""Render functions for study tests that must reach Dask workers (importable, picklable):
wrappers of jgi.render that count, interrupt, or kill the process running them."""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from pathlib import Path

import jgi


class CountingRender:
    """jgi.render that counts its calls and can simulate an interruption after n of them."""

    def __init__(self, fail_after: int | None = None):
        self.calls = 0
        self.fail_after = fail_after

    def __call__(self, *args, **kwargs):
        if self.fail_after is not None and self.calls >= self.fail_after:
            raise KeyboardInterrupt("simulated interruption")
        self.calls += 1
        return jgi.render(*args, **kwargs)


@dataclass(frozen=True)
class KillingRender:
    """jgi.render, except that the first call with seed ``seed`` (in any process: ``marker``
    records it) kills its own process with SIGKILL halfway, after rendering and before returning:
    a worker dying mid-task, once."""

    seed: int
    marker: str

    def __call__(self, scene, estimator, *, spp, seed, **kwargs):
        image = jgi.render(scene, estimator, spp=spp, seed=seed, **kwargs)
        if seed == self.seed:
            try:
                fd = os.open(self.marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                return image
            os.write(fd, str(os.getpid()).encode())
            os.close(fd)
            os.kill(os.getpid(), signal.SIGKILL)
        return image


def worker_pid_killed(marker) -> int | None:
    p = Path(marker)
    return int(p.read_text()) if p.exists() else None
