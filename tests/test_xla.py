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
# compares the caustic box and light tracing across processors)
CASES = [("veach_plates", dict(strategy="mis"))]
PRODUCTION_THRESHOLD = _xla.DEFAULT_UNROLL_THRESHOLD


def _render(name, params):
    return jgi.render(jgi.load_scene(name, resolution=8), "pt", spp=4, seed=3, **params)


def test_unroll_threshold_changes_no_result(tmp_path):
    """The suite compiles with a lower LLVM unroll threshold than jgi ships (tests/conftest.py);
    a render under the shipped threshold, in a process of its own (LLVM options are fixed when
    JAX starts), must be the same bits."""
    assert _xla.UNROLL_THRESHOLD != PRODUCTION_THRESHOLD, "the suite runs jgi's own threshold"
    assert f"-unroll-threshold={_xla.UNROLL_THRESHOLD}," in os.environ["XLA_FLAGS"]
    out = tmp_path / "images.npz"
    script = textwrap.dedent(f"""
        import os, numpy as np, jgi
        from jgi import _xla
        assert _xla.UNROLL_THRESHOLD == {PRODUCTION_THRESHOLD}
        assert "-unroll-threshold={PRODUCTION_THRESHOLD}," in os.environ["XLA_FLAGS"]
        from tests.test_xla import CASES, _render
        np.savez({str(out)!r}, *[_render(n, p) for n, p in CASES])
    """)
    # this process's XLA_FLAGS carry its own threshold, and jgi keeps flags it finds set: drop
    # them so the child sets its own (the persistent compile cache keys on XLA_FLAGS too)
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split()
             if not f.startswith("--xla_backend_extra_options=")]
    env = dict(os.environ, JGI_UNROLL_THRESHOLD=str(PRODUCTION_THRESHOLD), PYTHONPATH=str(ROOT),
               XLA_FLAGS=" ".join(flags))
    r = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True,
                       timeout=600, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    shipped = np.load(out)
    for i, (name, params) in enumerate(CASES):
        here = _render(name, params)
        assert np.array_equal(here, shipped[f"arr_{i}"]), name
