"""One long render as seeded chunks, each a file: ``jgi render ... --chunk-spp N --checkpoint DIR``.

A render of ``spp`` samples runs as chunks of about ``chunk_spp`` samples, chunk c seeded
:func:`jgi.experiment.plan.chunk_seed` (seed, c), each one task (:mod:`jgi.experiment.tasks`)
writing ``DIR/<key>.npz`` atomically. An interrupted render resumes from the chunks on disk, a
Dask cluster spreads the chunks over its workers, and the result does not depend on which ran
where or when. The chunks are combined exactly (:func:`jgi.analysis.stats.combine_chunks`: the
mean weighted by samples, which is the image of all ``spp`` samples, and its per-pixel variance
from the chunks' spread). ``DIR/render.json`` records what is being rendered, so resuming with
other settings is refused instead of mixing two renders.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .. import __version__
from ..analysis.stats import combine_chunks
from ..core.errors import CheckpointError
from .executors import run_tasks
from .plan import chunk_tasks, content_hash
from .tasks import StudyJob


def render_checkpointed(scene_src: str, estimator: str, *, spp: int, seed: int, folder,
                        chunk_spp: int, params: dict | None = None,
                        resolution: int | None = None, workers: int | None = None,
                        scheduler: str | None = None, render=None,
                        progress: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Render ``spp`` samples of ``scene_src`` (a built-in name or a scene file) in chunks kept
    in ``folder``; returns (image, per-pixel variance of the image). Chunks already in
    ``folder`` are not rendered again. ``render``: as in :func:`jgi.experiment.run`."""
    params = dict(params or {})
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    scene_id = (scene_src if not Path(scene_src).is_file()
                else content_hash(Path(scene_src).read_bytes().hex()))
    what = dict(scene=str(scene_src), scene_id=scene_id, resolution=resolution,
                estimator=estimator, spp=spp, seed=seed, params=params, chunk_spp=chunk_spp,
                jgi_version=__version__)
    manifest = folder / "render.json"
    if manifest.exists():
        before, now = json.loads(manifest.read_text()), json.loads(json.dumps(what))
        changed = sorted(k for k in now if before.get(k) != now[k])
        if changed:
            raise CheckpointError(f"{manifest}: this folder holds another render ("
                                  f"{', '.join(changed)} differ); use a new folder or delete it")
    else:
        manifest.write_text(json.dumps(what, indent=2))
    todo = chunk_tasks(dict(scene=scene_id, res=resolution), estimator, spp, seed, params,
                       chunk_spp, estimator)
    job = StudyJob(str(scene_src), resolution, {"chunk": str(folder)}, render)
    run_tasks(job, todo, f"{estimator} {spp} spp in {len(todo)} chunks", workers=workers,
              scheduler=scheduler, progress=progress)
    return combine(job, todo)


def combine(job: StudyJob, chunks: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """The chunks' files combined: (image, per-pixel variance of the image)."""
    images, samples = [], []
    for c in chunks:
        with np.load(job.path(c)) as z:
            images.append(z["image"])
            samples.append(int(z["spp"]))
    return combine_chunks(np.stack(images), samples)
