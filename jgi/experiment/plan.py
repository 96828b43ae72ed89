"""What a study renders, as independent tasks: every (estimator, sweep point, repetition) and
every chunk of every reference, each with its own seed and a content key naming its result file.

A task is a plain dict (it travels to Dask workers as it is): ``kind`` ("run" or "chunk"),
``estimator``, ``spp``, ``params``, ``seed`` and ``key``. Its image depends on nothing else (the
scene comes from the config), so it is the same bit for bit wherever and whenever it runs, and a
study that finds a task's file already written does not run it again.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from .. import __version__
from ..scene.files import load_scene
from .config import sweep_points

# Default size of a reference chunk: a long reference becomes many tasks (resumable, spread
# over workers); two chunks at least, as their spread gives the reference's variance.
REFERENCE_CHUNK_SPP = 256
_CHUNK_STREAM = 2**31 - 1     # spawn key of chunks: apart from every (estimator, point, rep)
# A study's reference chunks are seeded from this, not from the study's seed: studies of one
# scene with different seeds share their references (jgi.experiment.study keeps them in
# <out>/.cache/references).
REFERENCE_SEED = 900_001


def content_hash(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run_seed(base: int, estimator: int, point: int, rep: int, nested: bool = False) -> int:
    """The seed of one render: independent streams for every (estimator, sweep point,
    repetition), drawn from ``base`` by numpy's SeedSequence (so no two renders of a study
    share samples and the errors of its sweep points are independent, as the slope fits
    assume); ``nested``: the points of an estimator share a repetition's seed."""
    key = (estimator, rep) if nested else (estimator, point, rep)
    return int(np.random.SeedSequence(base, spawn_key=key).generate_state(1)[0] >> 1)


def chunk_seed(seed: int, chunk: int) -> int:
    """The seed of chunk ``chunk`` of a render seeded ``seed`` (independent chunks)."""
    return int(np.random.SeedSequence(seed, spawn_key=(_CHUNK_STREAM, chunk))
               .generate_state(1)[0] >> 1)


def chunk_sizes(spp: int, chunk_spp: int) -> list[int]:
    """``spp`` split into ceil(spp / chunk_spp) chunks as equal as possible (at least two)."""
    n = max(2, -(-spp // chunk_spp))
    return [spp // n + (1 if i < spp % n else 0) for i in range(n)]


def chunk_tasks(ident: dict, estimator: str, spp: int, seed: int, params: dict, chunk_spp: int,
                label: str) -> list[dict]:
    """The tasks of one render of ``spp`` samples as seeded chunks (:func:`chunk_sizes`, chunk c
    seeded :func:`chunk_seed` (seed, c)); ``ident`` names the scene (and film size) in the
    keys."""
    sizes = chunk_sizes(spp, chunk_spp)
    base = content_hash(dict(ident, est=estimator, spp=spp, seed=seed, params=params,
                             chunks=sizes, v=__version__))
    return [dict(kind="chunk", estimator=estimator, spp=n, params=params,
                 seed=chunk_seed(seed, c), label=f"{label} chunk {c + 1}/{len(sizes)}",
                 key=f"{base}-{c:04d}") for c, n in enumerate(sizes)]


def plan(doc: dict) -> list[dict]:
    """The sweep's renders: one dict per (estimator, sweep point, repetition), in config order."""
    exp = doc["experiment"]
    reps = exp.get("repetitions", 4)
    nested = exp.get("nested_seeds", False)
    runs = []
    for i, e in enumerate(doc["estimator"]):
        for j, point in enumerate(sweep_points(e)):
            for r in range(reps):
                runs.append(dict(index=i, name=e["name"], label=e.get("label", e["name"]),
                                 point=point, rep=r,
                                 seed=run_seed(exp.get("seed", 0), i, j, r, nested)))
    return runs


def scene_source(doc: dict, config_path) -> tuple[str, str]:
    """(what load_scene takes, an id of its content): a built-in name, or the scene file's path
    (relative to the config) with a hash of its bytes."""
    src = doc["experiment"]["scene"]
    if not src.endswith((".toml", ".xml", ".pbrt")):
        return src, src
    p = (Path(config_path).parent / src).resolve()
    return str(p), hashlib.sha256(p.read_bytes()).hexdigest()


def study_scene(doc: dict, config_path):
    """The study's scene at its resolution, and the id of its content."""
    src, scene_id = scene_source(doc, config_path)
    return load_scene_at(src, doc["experiment"].get("resolution")), scene_id


def load_scene_at(src: str, resolution):
    """The scene ``src`` with its film resized: ``resolution`` None (as in the file), an int
    (square) or (width, height)."""
    scene = load_scene(src)
    if resolution is not None:
        w, h = (resolution, resolution) if isinstance(resolution, int) else resolution
        scene = scene.with_resolution(int(w), int(h))
    return scene


def reference_params(doc: dict, point: dict) -> tuple[dict, dict]:
    """(the matched swept values, the reference's parameters) for a sweep point."""
    cfg = doc["experiment"]["reference"]
    matched = {k: point[k] for k in cfg.get("match", [])}
    return matched, {**cfg.get("params", {}), **matched}


def tasks(doc: dict, runs: list[dict], scene_id: str) -> tuple[list[dict], dict]:
    """Every task of the study, references' chunks first (a long render should not wait for the
    sweep), then the sweep's renders; and for each matched reference value its chunk tasks.
    Each run dict gains the ``key`` of its result file."""
    exp = doc["experiment"]
    res = exp.get("resolution")
    out, references = [], {}
    cfg = exp["reference"]
    for r in runs:
        matched, params = reference_params(doc, r["point"])
        rkey = json.dumps(matched, sort_keys=True)
        if "closed_form" in cfg or rkey in references:
            continue
        chunks = chunk_tasks(dict(scene=scene_id, res=res), cfg["estimator"], cfg["spp"],
                             REFERENCE_SEED, params, cfg.get("chunk_spp", REFERENCE_CHUNK_SPP),
                             "reference")
        references[rkey] = dict(matched=matched, chunks=chunks)
        out += chunks
    for r in runs:
        params = {k: v for k, v in r["point"].items() if k != "spp"}
        r["key"] = content_hash(dict(scene=scene_id, res=res, est=r["name"], point=r["point"],
                                     seed=r["seed"], v=__version__))
        out.append(dict(kind="run", estimator=r["name"], spp=r["point"]["spp"], params=params,
                        seed=r["seed"], label=f"{r['label']} {r['point']} rep {r['rep']}",
                        key=r["key"]))
    return out, references
