"""The CPU-backend devices of jgi._xla change speed, never results."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

import jgi
from jgi import _xla

ROOT = Path(__file__).resolve().parents[1]
# Veach's plates: Phong's exp(n log cos), the most rounding-sensitive kernel (tests/test_cpu.py
# compares it, and the BSDFs', lights' and intersections' decisions, across processors)
CASES = [("veach_plates", dict(strategy="mis"))]
PRODUCTION_THRESHOLD = _xla.DEFAULT_UNROLL_THRESHOLD


def _render(name, params):
    return jgi.render(jgi.load_scene(name, resolution=8), "pt", spp=4, seed=3, **params)


def _render_in_process(threshold: int, out: Path) -> np.ndarray:
    """CASES rendered in a fresh process with LLVM unroll threshold ``threshold`` (LLVM options
    are fixed when JAX starts) and no persistent compile cache: each side compiles its own
    programs (the suite's side rendered in a pytest worker crashed in JAX's loading of a cached
    executable where that worker had loaded Mitsuba's LLVM: tests/support/mitsuba.py)."""
    script = textwrap.dedent(f"""
        import os, numpy as np, jgi
        from jgi import _xla
        assert _xla.UNROLL_THRESHOLD == {threshold}
        assert "-unroll-threshold={threshold}," in os.environ["XLA_FLAGS"]
        from tests.test_xla import CASES, _render
        np.savez({str(out)!r}, *[_render(n, p) for n, p in CASES])
    """)
    # this process's XLA_FLAGS carry its own threshold, and jgi keeps flags it finds set: drop
    # them so the child sets its own
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split()
             if not f.startswith("--xla_backend_extra_options=")]
    env = dict(os.environ, JGI_UNROLL_THRESHOLD=str(threshold), PYTHONPATH=str(ROOT),
               XLA_FLAGS=" ".join(flags), JGI_CACHE_DIR="off")
    env.pop("JAX_COMPILATION_CACHE_DIR", None)     # the suite's cache (tests/conftest.py)
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                       timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    images = np.load(out)
    return [images[f"arr_{i}"] for i in range(len(CASES))]


def test_unroll_threshold_changes_no_result(tmp_path):
    """The suite compiles with a lower LLVM unroll threshold than jgi ships (tests/conftest.py);
    renders under the suite's threshold and under the shipped one, each in a process of its
    own, must be the same bits."""
    assert _xla.UNROLL_THRESHOLD != PRODUCTION_THRESHOLD, "the suite runs jgi's own threshold"
    assert f"-unroll-threshold={_xla.UNROLL_THRESHOLD}," in os.environ["XLA_FLAGS"]
    suite = _render_in_process(_xla.UNROLL_THRESHOLD, tmp_path / "suite.npz")
    shipped = _render_in_process(PRODUCTION_THRESHOLD, tmp_path / "shipped.npz")
    for (name, _), a, b in zip(CASES, suite, shipped):
        assert np.array_equal(a, b), name


def test_no_jax_arctan_where_the_vector_width_flag_breaks_it():
    """Under jgi's --xla_cpu_prefer_vector_width=512, XLA's vectorised single-argument arctan
    (also arctan2(y, 1), which XLA rewrites to it) is wrong on arrays of 1024 elements or
    more: arctan(-6.28) came out +1.404 (jax 0.10.2, found by the octahedral map work). Every
    other elementary function jgi uses is within 6e-7 there (measured), and arctan2 with a
    traced second argument is right. So jgi calls no jnp.arctan; this test keeps it so and
    records the fault while XLA has it."""
    import jax
    import jax.numpy as jnp

    calls = [f"{p.relative_to(ROOT)}:{i + 1}" for p in sorted((ROOT / "jgi").rglob("*.py"))
             for i, line in enumerate(p.read_text().splitlines())
             if "jnp.arctan(" in line.split("#")[0]]
    assert not calls, calls
    x = np.linspace(-8.0, 8.0, 4096, dtype=np.float32)
    y = np.linspace(-3.0, 3.0, 4096, dtype=np.float32)
    got = np.asarray(jax.jit(jnp.arctan2)(x, y))
    np.testing.assert_allclose(got, np.arctan2(x, y), atol=1e-6)
