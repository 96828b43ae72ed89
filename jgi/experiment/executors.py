"""Where a study's tasks run (:func:`run_tasks`, the one loop of ``jgi run`` and of a
checkpointed ``jgi render``): in this process, one after another (the default), or on a Dask
cluster (``jgi run CONFIG --workers N`` or ``--scheduler ADDRESS``).

Either way the study's process only plans and aggregates: a task is
:func:`jgi.experiment.tasks.execute`, which writes its own result file atomically, so results
are the same bit for bit wherever a task ran, a task whose worker died is simply run again by
Dask (its file was never half-written), and a study interrupted anywhere resumes from the files.

On a :class:`~dask.distributed.LocalCluster` each worker is a process running one task at a time
with its own JAX, pinned to its own share of the cores (``os.sched_setaffinity`` before JAX
starts its thread pools), so N workers do not oversubscribe the machine. On a cluster started
elsewhere (``dask-jobqueue`` for Slurm or PBS, ``dask scheduler`` / ``dask worker`` by hand),
give each worker one thread (``--nthreads 1``) and as many cores as it should use. Each worker
reads and writes JAX's persistent compilation cache (``jgi.compile_cache``): on a shared file
system a structure compiles once for the whole cluster.

Progress: a worker sends each render's ticks to the client as Dask events (topic
``jgi-progress``), so the study's display shows compiling and rendering per task and the
study's ETA, wherever the tasks run.
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path
from typing import Callable, Iterable

from ..core.progress import Tick
from .display import StudyDisplay
from .tasks import StudyJob, execute, remove_temporaries

PROGRESS_TOPIC = "jgi-progress"
TICK_INTERVAL = 0.5       # seconds between a worker's progress events for one task

OnTick = Callable[[str, Tick], None]
OnDone = Callable[[dict, dict], None]


class InProcess:
    """Run the tasks here, in order (the embedded default)."""

    workers = 1

    def run(self, job: StudyJob, tasks: Iterable[dict], on_tick: OnTick, on_done: OnDone):
        for task in tasks:
            result = execute(job, task, sink=lambda tick, k=task["key"]: on_tick(k, tick))
            on_done(task, result)

    def close(self):
        pass


# Run in every LocalCluster worker before its first task: pin the process to its share of the
# cores. Dask passes a preload containing spaces to the worker as the text of a script.
_PIN_WORKER = """
import os

def dask_setup(worker):
    cores = sorted(os.sched_getaffinity(0))
    n, k = int(os.environ["JGI_WORKERS"]), int(worker.name)
    share = cores[k * len(cores) // n: (k + 1) * len(cores) // n] or [cores[k % len(cores)]]
    os.sched_setaffinity(0, share)
"""


def _forward_ticks(key: str):
    """A sink for a worker: each tick of task ``key`` as a Dask event (at most one every
    ``TICK_INTERVAL`` s, but the first and the last always)."""
    from distributed import get_worker

    worker, last = get_worker(), [0.0]

    def send(tick: Tick):
        now = time.monotonic()
        if tick.finished or tick.done == 0 or now - last[0] >= TICK_INTERVAL:
            last[0] = now
            worker.log_event(PROGRESS_TOPIC, [key, asdict(tick)])
    return send


def execute_on_worker(job: StudyJob, task: dict) -> dict:
    """:func:`jgi.experiment.tasks.execute` on a Dask worker, its ticks sent to the client."""
    return execute(job, task, sink=_forward_ticks(task["key"]))


class DaskCluster:
    """Run the tasks on Dask: a new LocalCluster of ``workers`` processes, or the cluster whose
    scheduler is at ``scheduler``."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 retries: int = 3):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise SystemExit("jgi: --workers and --scheduler need Dask: pip install "
                             "'dask[distributed]' (or jgi's [cluster] extra)") from None
        self.cluster = None
        self.retries = retries
        if scheduler:
            self.client = Client(scheduler)
        else:
            workers = workers or 2
            self.cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True,
                dashboard_address=None, preload=[_PIN_WORKER],
                env={"JGI_WORKERS": str(workers)})
            self.client = Client(self.cluster)
        self.workers = max(1, len(self.client.scheduler_info(n_workers=-1)["workers"]))

    def run(self, job: StudyJob, tasks: Iterable[dict], on_tick: OnTick, on_done: OnDone):
        from distributed import as_completed

        tasks = list(tasks)
        by_key = {f"jgi-{t['key']}": t for t in tasks}
        self.client.subscribe_topic(
            PROGRESS_TOPIC, lambda event: on_tick(event[1][0], Tick(**event[1][1])))
        try:
            futures = [self.client.submit(execute_on_worker, job, t, key=k, pure=False,
                                          retries=self.retries) for k, t in by_key.items()]
            for fut in as_completed(futures):
                on_done(by_key[fut.key], fut.result())
        finally:
            self.client.unsubscribe_topic(PROGRESS_TOPIC)

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def executor(workers: int | None = None, scheduler: str | None = None):
    """The executor for ``jgi run``'s options: in-process without either."""
    if workers is None and scheduler is None:
        return InProcess()
    if workers is not None and workers < 1:
        raise SystemExit(f"jgi: --workers must be at least 1, got {workers}")
    return DaskCluster(workers=workers, scheduler=scheduler)


def run_tasks(job: StudyJob, tasks: list[dict], name: str, *, workers: int | None = None,
              scheduler: str | None = None, progress: bool = True) -> None:
    """Run every task of ``tasks`` whose file is missing, in this process or on Dask
    (:func:`jgi.experiment.executors.executor`), showing their progress; then remove what
    killed writers left behind."""
    done = [t for t in tasks if job.path(t).exists()]
    ex = executor(workers, scheduler)
    display = StudyDisplay(name, tasks, ex.workers, enabled=progress)
    try:
        for t in done:
            display.skip(t)
        ex.run(job, [t for t in tasks if t not in done], display.tick, display.done)
    finally:
        display.close()
        ex.close()
    for folder in set(job.folders.values()):
        remove_temporaries(Path(folder))
