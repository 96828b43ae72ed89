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

import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def rng_np():
    """A fresh generator per test: each test's data is fixed whatever ran before it (a
    session-wide generator handed each test the draws the previous tests left, so the data
    depended on test order and on how pytest-xdist shared the tests out)."""
    return np.random.default_rng(12345)
