"""pytest's settings and fixtures for the suite (the helpers tests share are in tests/support/)."""

from __future__ import annotations

import os
from pathlib import Path

# One persistent XLA compilation cache for the whole run, shared by the pytest-xdist workers
# (perf: docs/performance.md#test-suite-settings). Set before any test module imports JAX;
# results do not depend on it.
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR",
                      str(Path(__file__).resolve().parents[1] / ".cache" / "jax-tests"))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
# The suite is compile-bound: LLVM's unroll threshold 1000 instead of jgi's 4000 (see jgi._xla)
# compiles faster (perf: docs/performance.md#test-suite-settings). It changes no result:
# tests/test_xla.py renders with both and compares bit for bit.
os.environ.setdefault("JGI_UNROLL_THRESHOLD", "1000")
# Grid trackings in one loop, not also in smaller batches of the live lanes (jgi.physics.
# grid_media.TIERED_FROM): each batch size is another copy of the loop to compile (about 4 s a
# render). It changes no result: test_grid_media runs the smaller batches and compares bit for
# bit.
os.environ.setdefault("JGI_TIERED_FROM", str(1 << 30))
# Two pytest-xdist workers share the two cores: each XLA client's Eigen pool of one thread a core
# only oversubscribes them (perf: docs/performance.md#test-suite-settings). No result depends on
# it (tests/test_xla.py, test_wavefront.py: images bit for bit across thread counts and calls).
if "--xla_cpu_multi_thread_eigen" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "")
                               + " --xla_cpu_multi_thread_eigen=false").strip()

import numpy as np  # noqa: E402
import pytest  # noqa: E402


def _memory_maps() -> int:
    try:
        with open("/proc/self/maps") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def _max_map_count() -> int:
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 65530


MAP_LIMIT = _max_map_count() // 2


@pytest.fixture(autouse=True)
def _bounded_memory_maps():
    """Each compiled XLA:CPU program keeps its code in memory maps of its own (measured: about
    950 for a VCM render's programs, 400 for BDPT's), and a pytest worker compiles hundreds,
    so late in a full run a worker neared the kernel's vm.max_map_count (65530), where LLVM's
    mmap fails and the worker crashed: segfaults inside compiling, loading a cached executable
    and running one, in six full runs, always past 85% of the run, never in a test alone
    (measured: both workers passed 32,700 maps by 83% of a full run).
    After a test that leaves the worker over half the limit, jax.clear_caches() releases the
    programs (later tests compile theirs again)."""
    yield
    if _memory_maps() > MAP_LIMIT:
        import gc

        import jax

        jax.clear_caches()
        gc.collect()


@pytest.fixture
def rng_np():
    """A fresh generator per test: each test's data is fixed whatever ran before it (a
    session-wide generator handed each test the draws the previous tests left, so the data
    depended on test order and on how pytest-xdist shared the tests out)."""
    return np.random.default_rng(12345)
