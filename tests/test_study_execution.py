"""Where a study's tasks run (jgi.experiment.executors, tasks, checkpoint): on a Dask
LocalCluster whose worker dies mid-study, the results are those of the serial run bit for bit,
with no file lost or half-written; an interrupted chunked render resumes to the same image; the
chunks' combination is the image of all samples with an unbiased variance; and progress shows
compiling apart from rendering."""

from __future__ import annotations

import json
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jgi.analysis.stats import combine_chunks
from jgi.core import progress
from jgi.core.errors import CheckpointError
from jgi.experiment import executors as executors_module
from jgi.experiment import run
from jgi.experiment.checkpoint import render_checkpointed
from jgi.experiment.display import StudyDisplay
from jgi.experiment.tasks import TMP_SUFFIX
from tests.support.renders import CountingRender, KillingRender, worker_pid_killed

STUDY = """
[experiment]
name = "cluster-test"
scene = "cornell_box"
resolution = 8
repetitions = 3
reference = { estimator = "pt", spp = 8, chunk_spp = 2 }

[[estimator]]
name = "pt"
sweep = { spp = [1, 2], strategy = ["bsdf", "mis"] }
"""


def _images(folder):
    out = {}
    for p in sorted(folder.glob("*.npz")):
        with np.load(p) as z:
            out[p.name] = z["image"].copy()
    return out


def test_study_on_a_local_cluster_with_a_dying_worker_equals_the_serial_run(tmp_path,
                                                                            monkeypatch):
    config = tmp_path / "study.toml"
    config.write_text(STUDY)
    serial = run(config, out_root=tmp_path / "serial", progress=False)
    # the worker running the render seeded like the 7th run (mid-study) kills itself once
    from jgi.experiment import load_config, plan
    victim = plan(load_config(config))[6]["seed"]
    marker = tmp_path / "killed"
    ticks = []

    class Recording(StudyDisplay):
        def tick(self, key, tick):
            ticks.append((key, tick))
            super().tick(key, tick)

    monkeypatch.setattr(executors_module, "StudyDisplay", Recording)
    clustered = run(config, out_root=tmp_path / "cluster", workers=2, progress=False,
                    render=KillingRender(victim, str(marker)))
    assert worker_pid_killed(marker) is not None          # a worker did die mid-task
    for sub in ("results", "../.cache/references"):
        a, b = _images(serial / sub), _images(clustered / sub)
        assert a.keys() == b.keys() and len(a) > 0, sub    # no file lost
        for name in a:                                     # every file whole and identical
            assert np.array_equal(a[name], b[name]), name
        assert not list((clustered / sub).glob(f"*{TMP_SUFFIX}"))
    rows = [json.loads((o / "metrics.json").read_text()) for o in (serial, clustered)]
    assert [r["mse"] for r in rows[0]] == [r["mse"] for r in rows[1]]
    # the workers' progress reached the study's display, the drivers' counts with it: every
    # finished render reports all its paths done (the last tick may trail the last result)
    finished = {k: t for k, t in ticks if t.finished}
    assert len(finished) >= 12 + 4 - 1
    assert all(t.total > 0 and t.done == t.total for t in finished.values())


def test_interrupted_chunked_render_resumes_to_the_same_image(tmp_path):
    kw = dict(spp=12, seed=5, chunk_spp=3, resolution=8, progress=False)
    whole, whole_var = render_checkpointed("cornell_box", "pt", folder=tmp_path / "a", **kw)
    first = CountingRender(fail_after=2)
    with pytest.raises(KeyboardInterrupt):
        render_checkpointed("cornell_box", "pt", folder=tmp_path / "b", render=first, **kw)
    assert len(list((tmp_path / "b").glob("*.npz"))) == 2
    second = CountingRender()
    image, var = render_checkpointed("cornell_box", "pt", folder=tmp_path / "b", render=second,
                                     **kw)
    assert second.calls == 4 - 2
    assert np.array_equal(image, whole) and np.array_equal(var, whole_var)
    with pytest.raises(CheckpointError, match="spp"):
        render_checkpointed("cornell_box", "pt", folder=tmp_path / "b",
                            **{**kw, "spp": 24})


def test_combined_chunks_are_the_mean_of_all_samples_with_an_unbiased_variance():
    rng = np.random.default_rng(3)
    sigma, sizes, trials = 2.0, [5, 5, 6], 20_000
    samples = rng.normal(1.0, sigma, (trials, sum(sizes)))
    edges = np.cumsum([0] + sizes)
    chunks = np.stack([samples[:, a:b].mean(1) for a, b in zip(edges[:-1], edges[1:])])
    mean, var = combine_chunks(chunks, sizes)       # trials play the role of pixels
    np.testing.assert_allclose(mean, samples.mean(1), rtol=1e-5)
    true_var = sigma**2 / sum(sizes)
    # var is unbiased for true_var: its mean over the trials within 4 standard errors
    se = var.std() / np.sqrt(trials)
    assert abs(var.mean() - true_var) < 4 * se, (var.mean(), true_var, se)
    with pytest.raises(ValueError, match="two chunks"):
        combine_chunks(chunks[:1], sizes[:1])


def test_progress_counts_compiling_apart_from_rendering():
    ticks = []

    @jax.jit
    def work(x):      # a program no other test compiles
        return jnp.cumsum(jnp.sin(x) * 1.2345) + x.size

    with progress.sending_to(ticks.append), progress.tracking("probe"):
        progress.advance(0, 2)
        t0 = time.perf_counter()
        work(jnp.ones(777)).block_until_ready()     # compiles: nearly all of this call
        first_call = time.perf_counter() - t0
        progress.advance(1, 2)
        for _ in range(3):
            work(jnp.ones(777)).block_until_ready()
        progress.advance(2, 2)
    first, final = ticks[0], ticks[-1]
    assert first.phase == "compiling" and final.finished and final.phase == "done"
    # the compile was seen (most of the first call), and is not counted as rendering
    assert 0.5 * first_call < final.compile_s <= first_call + final.render_s
    assert final.render_s < (final.compile_s + final.render_s) - 0.5 * first_call
    assert ticks[-2].rate > 0 and ticks[-2].eta == 0


def test_checkpointed_render_from_the_command_line(tmp_path):
    from jgi.cli import main
    from jgi.core.imageio import read_exr

    args = ["render", "cornell_box", "-e", "pt", "--spp", "4", "--width", "8", "--height", "8",
            "--checkpoint", str(tmp_path / "ck"), "--chunk-spp", "2", "--quiet",
            "--out", str(tmp_path / "img.exr")]
    assert main(args) == 0
    image, var = render_checkpointed("cornell_box", "pt", spp=4, seed=0, chunk_spp=2,
                                     resolution=(8, 8), folder=tmp_path / "ck", progress=False)
    assert np.array_equal(read_exr(tmp_path / "img.exr"), image)
    assert np.array_equal(read_exr(tmp_path / "img_variance.exr"), var) and var.max() > 0
    for bad, says in ((["--spp", "8"], "render.json"), (["--chunk-spp", "3"], "chunk-spp"),
                      (["--checkpoint"], "go together")):
        argv = list(args)
        if bad == ["--checkpoint"]:
            i = argv.index("--checkpoint")
            del argv[i: i + 2]
        else:
            argv[argv.index(bad[0]) + 1] = bad[1]
        with pytest.raises(SystemExit, match=says):
            main(argv)


def test_render_command_starts_without_the_study_modules():
    """`jgi render` imports neither the studies (Dask, plots, scipy.stats) nor colour-science
    or trimesh: a cached program then starts rendering in a few seconds."""
    import subprocess
    import sys

    code = ("import sys, jgi.cli; print(sorted(m for m in ('jgi.experiment', 'distributed', "
            "'colour', 'trimesh', 'scipy.stats') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.strip()
    assert out == "[]", out
