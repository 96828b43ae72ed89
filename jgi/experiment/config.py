"""Experiment config files: validation before any work (an error names the file and the key
path), sweep points, and the reduced smoke version of a study."""

from __future__ import annotations

import copy
import itertools
import tomllib
from pathlib import Path

from ..analysis import closed_form
from ..core.errors import ParameterError
from ..estimators.registry import get

EXPERIMENT_KEYS = {"name", "scene", "resolution", "repetitions", "seed", "reference",
                   "nested_seeds"}
ESTIMATOR_KEYS = {"name", "label", "spp", "params", "sweep"}


class ConfigError(ValueError):
    """A bad experiment config: the message names the file and the key path."""


def _fail(path, key, msg):
    raise ConfigError(f"{path}: {key}: {msg}")


def load_config(path) -> dict:
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text())
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e}") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: TOML syntax error: {e}") from None
    unknown = sorted(set(doc) - {"experiment", "estimator"})
    if unknown:
        _fail(path, unknown[0], "unknown table; allowed: experiment, estimator")
    exp = doc.get("experiment")
    if not isinstance(exp, dict):
        _fail(path, "experiment", "missing [experiment] table")
    bad = sorted(set(exp) - EXPERIMENT_KEYS)
    if bad:
        _fail(path, f"experiment.{bad[0]}",
              f"unknown key; allowed: {', '.join(sorted(EXPERIMENT_KEYS))}")
    for key in ("name", "scene"):
        if not isinstance(exp.get(key), str) or not exp.get(key):
            _fail(path, f"experiment.{key}", "required, a non-empty string")
    for key, lo in (("repetitions", 2), ("seed", 0), ("resolution", 1)):
        if key in exp and (isinstance(exp[key], bool) or not isinstance(exp[key], int)
                           or exp[key] < lo):
            _fail(path, f"experiment.{key}", f"must be an integer >= {lo}, got {exp[key]!r}")
    if not isinstance(exp.get("nested_seeds", False), bool):
        _fail(path, "experiment.nested_seeds", f"must be true or false, got "
                                               f"{exp['nested_seeds']!r}")
    ref = exp.get("reference")
    if not isinstance(ref, dict) or not ({"estimator", "spp"} <= set(ref) or "closed_form" in ref):
        _fail(path, "experiment.reference",
              "required: { estimator, spp, params } or { closed_form }")
    if "closed_form" in ref:
        cf = ref["closed_form"]
        if isinstance(cf, str):
            if cf not in closed_form.IMAGES:
                _fail(path, "experiment.reference.closed_form",
                      f"unknown closed form {cf!r}; allowed: {', '.join(closed_form.IMAGES)} "
                      "(or a number, or [r, g, b])")
            if cf != exp.get("scene"):
                _fail(path, "experiment.reference.closed_form",
                      f"the closed form {cf!r} is the image of the built-in scene {cf!r}, not "
                      f"of {exp.get('scene')!r}")
        if set(ref) != {"closed_form"} or not isinstance(cf, (int, float, list, str)):
            _fail(path, "experiment.reference.closed_form",
                  "a number, [r, g, b] or a built-in scene's name, alone")
    else:
        bad = sorted(set(ref) - {"estimator", "spp", "params", "match", "chunk_spp"})
        if bad:
            _fail(path, f"experiment.reference.{bad[0]}",
                  "unknown key; allowed: estimator, spp, params, match, chunk_spp")
        spp = ref["spp"]
        if isinstance(spp, bool) or not isinstance(spp, int) or spp < 2:
            _fail(path, "experiment.reference.spp", f"must be an integer >= 2 (the reference is "
                                                    f"rendered in chunks), got {spp!r}")
        chunk = ref.get("chunk_spp", 1)
        if isinstance(chunk, bool) or not isinstance(chunk, int) or not 1 <= chunk <= spp // 2:
            _fail(path, "experiment.reference.chunk_spp",
                  f"must be an integer from 1 to spp / 2 = {spp // 2} (at least two chunks, "
                  f"whose spread gives the reference's variance), got {chunk!r}")
        match = ref.get("match", [])
        if not isinstance(match, list) or not all(isinstance(k, str) for k in match):
            _fail(path, "experiment.reference.match", "a list of swept parameter names")
        _check_estimator(path, "experiment.reference", ref["estimator"], ref.get("params", {}))
    ests = doc.get("estimator")
    if not isinstance(ests, list) or not ests:
        _fail(path, "estimator", "at least one [[estimator]] table is required")
    for i, e in enumerate(ests):
        key = f"estimator[{i}]"
        bad = sorted(set(e) - ESTIMATOR_KEYS)
        if bad:
            _fail(path, f"{key}.{bad[0]}",
                  f"unknown key; allowed: {', '.join(sorted(ESTIMATOR_KEYS))}")
        if "name" not in e:
            _fail(path, f"{key}.name", "required")
        sweep = e.get("sweep", {})
        if not isinstance(sweep, dict):
            _fail(path, f"{key}.sweep", "a table of lists")
        for k, v in sweep.items():
            if not isinstance(v, list) or not v:
                _fail(path, f"{key}.sweep.{k}", "must be a non-empty list")
        if "spp" not in e and "spp" not in sweep:
            _fail(path, f"{key}.spp", "required (or sweep.spp)")
        for point in sweep_points(e):
            params = {k: v for k, v in point.items() if k != "spp"}
            _check_estimator(path, key, e["name"], params)
            if "match" in ref:
                missing = [k for k in ref["match"] if k not in point]
                if missing:
                    _fail(path, "experiment.reference.match",
                          f"{missing[0]!r} is not a parameter of {key}")
                _check_estimator(path, "experiment.reference.match", ref["estimator"],
                                 {**ref.get("params", {}), **{k: point[k] for k in ref["match"]}})
            spp = point["spp"]
            if isinstance(spp, bool) or not isinstance(spp, int) or spp < 1:
                _fail(path, f"{key}.spp", f"must be a positive integer, got {spp!r}")
    return doc


def _check_estimator(path, key, name, params):
    try:
        get(name).resolve(params)
    except ParameterError as err:
        _fail(path, key, str(err))


def sweep_points(e: dict):
    """The parameter sets of an [[estimator]] table: its params and spp, with the cartesian
    product of its sweep lists."""
    base = dict(e.get("params", {}))
    if "spp" in e:
        base["spp"] = e["spp"]
    sweep = e.get("sweep", {})
    keys = sorted(sweep)
    for values in itertools.product(*(sweep[k] for k in keys)):
        yield {**base, **dict(zip(keys, values))}


SMOKE_RESOLUTION = 8
SMOKE_MAX = dict(spp=4, photons=20_000, caustic_photons=5_000, passes=2, chains=256,
                 bootstrap_samples=4096, final_gather=4, k=50, k_caustic=50, max_depth=3)


def smoke(doc: dict) -> dict:
    """The same study at a tiny size: resolution 8, two repetitions, at most two values per
    sweep key, and sample / photon counts capped by ``SMOKE_MAX`` (the structure, outputs and
    code paths are those of the full run)."""

    doc = copy.deepcopy(doc)
    exp = doc["experiment"]
    exp["resolution"] = min(exp.get("resolution", SMOKE_RESOLUTION), SMOKE_RESOLUTION)
    exp["repetitions"] = 2
    exp["name"] = exp["name"] + "-smoke"

    def cap(params):
        return {k: (min(v, SMOKE_MAX[k]) if k in SMOKE_MAX and isinstance(v, int)
                    and not isinstance(v, bool) else v)
                for k, v in params.items()}

    ref = exp["reference"]
    if "spp" in ref:
        ref["spp"] = min(ref["spp"], 16)
        ref["params"] = cap(ref.get("params", {}))
    for e in doc["estimator"]:
        if "spp" in e:
            e["spp"] = min(e["spp"], SMOKE_MAX["spp"])
        e["params"] = cap(e.get("params", {}))
        sweep = {}
        for k, v in e.get("sweep", {}).items():
            vals = [cap({k: x})[k] for x in v[:2]]
            sweep[k] = list(dict.fromkeys(vals))  # capping may merge values
        e["sweep"] = sweep
    return doc
