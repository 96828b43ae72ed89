"""The config runner (jgi.experiment): validation before any work, dry runs, resumption after an
interruption, outputs, and every bundled config end to end at a reduced size."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import jgi
from jgi.experiment import ConfigError, load_config, plan, run, smoke
from tests.support.renders import CountingRender

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted((ROOT / "configs").glob("*.toml"))

FURNACE = """
[experiment]
name = "furnace-test"
scene = "furnace"
resolution = 4
repetitions = 3
reference = { closed_form = 1.9921875 }

[[estimator]]
name = "pt"
params = { rr_depth = -1 }
sweep = { spp = [1, 4], strategy = ["bsdf", "light"] }
"""


def write(tmp_path, text, name="exp.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


BAD = [
    ("[experiment]\nname='x'\n", "experiment.scene"),
    (FURNACE.replace('name = "pt"', 'name = "nope"'), "estimator[0]"),
    (FURNACE.replace("rr_depth = -1", "rr_dpth = -1"), "rr_dpth"),
    (FURNACE.replace("repetitions = 3", "repetitions = 1"), "experiment.repetitions"),
    (FURNACE.replace('strategy = ["bsdf", "light"]', 'strategy = ["bsdf", "sideways"]'),
     "sideways"),
    (FURNACE.replace("spp = [1, 4]", "spp = [1, -4]"), "estimator[0].spp"),
    (FURNACE.replace("spp = [1, 4]", "spp = []"), "estimator[0].sweep.spp"),
    (FURNACE.replace("reference = { closed_form = 1.9921875 }", "reference = { spp = 4 }"),
     "experiment.reference"),
    (FURNACE.replace("resolution = 4", "resolution = 4\nfoo = 1"), "experiment.foo"),
    (FURNACE.replace("resolution = 4", "resolution = 4\nnested_seeds = 1"),
     "experiment.nested_seeds"),
    (FURNACE + "\n[extra]\n", "extra"),
    (FURNACE.replace("[[estimator]]", "[[estimator]]\nlable = 'x'"), "estimator[0].lable"),
    ("[experiment\n", "TOML syntax error"),
]


@pytest.mark.parametrize("text, key", BAD)
def test_bad_configs_are_refused_before_any_rendering(tmp_path, text, key):
    path = write(tmp_path, text)
    render = CountingRender()
    with pytest.raises(ConfigError) as err:
        run(path, out_root=tmp_path / "runs", render=render, progress=False)
    message = str(err.value)
    assert str(path) in message and key in message, message
    assert render.calls == 0
    assert not (tmp_path / "runs").exists()


def test_missing_config_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="missing.toml"):
        load_config(tmp_path / "missing.toml")


def test_dry_run_prints_the_plan_and_renders_nothing(tmp_path, capsys):
    path = write(tmp_path, FURNACE)
    render = CountingRender()
    run(path, out_root=tmp_path / "runs", dry_run=True, render=render)
    out = capsys.readouterr().out
    assert "12 renders" in out  # 2 spp x 2 strategies x 3 repetitions
    assert render.calls == 0 and not (tmp_path / "runs").exists()


def test_plan_is_the_cartesian_product_with_distinct_seeds(tmp_path):
    doc = load_config(write(tmp_path, FURNACE))
    runs = plan(doc)
    assert len(runs) == 12
    points = {json.dumps(r["point"], sort_keys=True) for r in runs}
    assert len(points) == 4
    for p in points:  # repetitions of one point use different seeds
        seeds = [r["seed"] for r in runs if json.dumps(r["point"], sort_keys=True) == p]
        assert len(set(seeds)) == 3
    # every (estimator, sweep point, repetition) has its own seed: no render shares samples
    assert len({r["seed"] for r in runs}) == 12
    # nested on request: an estimator's sweep points share a repetition's seed
    doc["experiment"]["nested_seeds"] = True
    nested = plan(doc)
    by_rep = {}
    for r in nested:
        by_rep.setdefault((r["index"], r["rep"]), set()).add(r["seed"])
    assert all(len(s) == 1 for s in by_rep.values()) and len(by_rep) == 3


def test_interrupted_run_resumes_without_recomputing(tmp_path):
    path = write(tmp_path, FURNACE)
    out_root = tmp_path / "runs"
    first = CountingRender(fail_after=5)
    with pytest.raises(KeyboardInterrupt):
        run(path, out_root=out_root, render=first, progress=False)
    results = out_root / "furnace-test" / "results"
    assert len(list(results.glob("*.npz"))) == 5
    assert not list(results.glob("*.tmp*"))  # atomic writes leave no partial files
    second = CountingRender()
    out = run(path, out_root=out_root, render=second, progress=False)
    assert second.calls == 12 - 5
    third = CountingRender()
    run(path, out_root=out_root, render=third, progress=False)
    assert third.calls == 0
    # Results are those of an uninterrupted run: the bsdf-sampled furnace has zero variance, and
    # the light-sampled one is unbiased (|bias| below 5 standard errors of the mean).
    rows = json.loads((out / "metrics.json").read_text())
    assert len(rows) == 4
    for r in rows:
        mean = jgi.core.imageio.read_exr(out / r["image"])
        if r["strategy"] == "bsdf":
            np.testing.assert_allclose(mean, 1.9921875, rtol=1e-5)
            assert r["variance"] < 1e-10
        else:
            se = np.sqrt(r["variance"] / 3 / mean.size)
            assert abs(mean.mean() - 1.9921875) < 5 * se, (mean.mean(), se)
            assert r["variance"] > 0


def test_outputs_and_provenance(tmp_path):
    path = write(tmp_path, FURNACE)
    out = run(path, out_root=tmp_path / "runs", progress=False)
    for f in ("config.toml", "config_as_run.json", "metrics.csv", "metrics.json", "slopes.json",
              "provenance.json", "mse_vs_spp.png", "mse_vs_time.png", "error_maps.png"):
        assert (out / f).exists(), f
    with open(out / "metrics.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 and ({"mse", "bias2", "variance", "rel_mse", "seconds", "spp",
                                "mse_se", "mse_lo", "mse_hi", "variance_lo", "bias2_hi"}
                               <= set(rows[0]))
    prov = json.loads((out / "provenance.json").read_text())
    assert (prov["jax_version"] and prov["jgi_version"] == jgi.__version__
            and len(prov["seeds"]) == 12)    # 4 points x 3 repetitions, each its own seed
    slopes = json.loads((out / "slopes.json").read_text())
    # Only the light-sampled curve has nonzero MSE; with two spp values its slope is a secant.
    assert [s["fixed"] for s in slopes] == [{"strategy": "light"}]


def test_reference_render_is_cached_by_content(tmp_path):
    text = FURNACE.replace("reference = { closed_form = 1.9921875 }",
                           'reference = { estimator = "pt", spp = 8, params = { rr_depth = -1 } }')
    text = text.replace('strategy = ["bsdf", "light"]', 'strategy = ["light"]')
    path = write(tmp_path, text)
    first = CountingRender()
    run(path, out_root=tmp_path / "runs", render=first, progress=False)
    assert first.calls == 2 + 6  # two reference halves, then 2 spp x 3 repetitions
    (tmp_path / "runs" / "furnace-test" / "results").rename(tmp_path / "old")
    second = CountingRender()
    run(path, out_root=tmp_path / "runs", render=second, progress=False)
    assert second.calls == 6  # the reference came from the cache


def test_smoke_keeps_structure_and_caps_sizes(tmp_path):
    doc = smoke(load_config(ROOT / "configs" / "photon_count_vs_k.toml"))
    exp = doc["experiment"]
    assert exp["resolution"] <= 8 and exp["repetitions"] == 2 and exp["name"].endswith("-smoke")
    for e in doc["estimator"]:
        for v in e["sweep"].get("photons", []):
            assert v <= 20_000


# Every bundled config is validated as shipped (estimator names and parameters, the scene, the
# plan); these run end to end at the smoke size too, together covering every kind of reference
# (closed-form number and scene, rendered, matched per sweep value), sweeps over spp, photons
# and strategies, and the estimator families (PT, BDPT, PSSMLT, photon mapping, VCM). The others
# differ from them in scene and estimator parameters only, which the validation covers; a run
# costs mostly compilation (about 15-30 s each on the 2-core CI machine). The quickstart runs
# at its full size in tests/test_quickstart.py.
END_TO_END = ("furnace", "path_lengths", "photon_count_vs_k", "pt_vs_mlt", "vcm_sds_convergence")


@pytest.mark.parametrize("config", CONFIGS, ids=[c.stem for c in CONFIGS])
def test_bundled_config_is_valid_and_plans(config):
    from jgi.experiment import study_scene

    doc = load_config(config)  # the full-size config is valid as shipped
    scene, _ = study_scene(smoke(doc), config)
    assert scene.camera.width <= 8 and plan(smoke(doc))


def test_end_to_end_configs_exist():
    assert set(END_TO_END) <= {c.stem for c in CONFIGS}


@pytest.mark.parametrize("config", [c for c in CONFIGS if c.stem in END_TO_END],
                         ids=[c.stem for c in CONFIGS if c.stem in END_TO_END])
def test_bundled_config_runs_end_to_end_reduced(tmp_path, config):
    doc = load_config(config)
    out = run(config, out_root=tmp_path, reduced=True, progress=False)
    rows = json.loads((out / "metrics.json").read_text())
    n_points = len({(r["index"], json.dumps(r["point"], sort_keys=True)) for r in plan(smoke(doc))})
    assert len(rows) == n_points
    for r in rows:
        assert np.isfinite([r["mse"], r["variance"], r["seconds"]]).all(), r
        assert np.isfinite(jgi.core.imageio.read_exr(out / r["image"])).all()
