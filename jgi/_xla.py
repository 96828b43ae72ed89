"""XLA settings that make jgi's kernels fast on the CPU backend, kept in this one module.

Applied by setting ``XLA_FLAGS`` before JAX starts its backend (importing jgi first is enough);
flags already present in the environment are left alone, and ``JGI_NO_XLA_FLAGS=1`` disables
this module. None of these change results beyond float rounding.
"""

import os

_FLAGS: list[str] = []

if not os.environ.get("JGI_NO_XLA_FLAGS"):
    current = os.environ.get("XLA_FLAGS", "")
    extra = [f for f in _FLAGS if f.split("=")[0] not in current]
    if extra:
        os.environ["XLA_FLAGS"] = (current + " " + " ".join(extra)).strip()
