"""Work split over several devices gives the same results as one device, bit for bit.

Runs in a subprocess because the CPU device count must be fixed before JAX starts."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent("""
    import sys
    import jax, numpy as np, jgi
    from jgi.drivers import chunked as R
    from jgi.drivers.chunked import render_paths_sharded
    from jgi.transport.photons import trace_photons
    from jgi.core.configured import Configured
    from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels
    assert len(jax.devices()) == 2, jax.devices()
    sc = jgi.scenes.cornell_box_caustics(resolution=16)
    fn = Configured(trace_pixels, PathTracerConfig())
    for spp in (1, 7):
        one = R.render_paths(sc, fn, spp=spp, seed=4, chunk=256)
        two = render_paths_sharded(sc, fn, spp=spp, seed=4, chunk=256,
                                   chunks_per_call=R.CHUNKS_PER_CALL)
        assert np.array_equal(one, two), np.abs(one - two).max()
    a = trace_photons(sc, 5000, seed=2, chunk=1024, devices=jax.devices()[:1])
    b = trace_photons(sc, 5000, seed=2, chunk=1024)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        assert np.array_equal(x, y)
    print("SHARDING-OK")
""")


def test_two_cpu_devices_match_one_device():
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               PYTHONPATH=str(ROOT))
    r = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True,
                       timeout=600, cwd=ROOT)
    assert r.returncode == 0 and "SHARDING-OK" in r.stdout, r.stdout + r.stderr
