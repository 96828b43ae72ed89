"""Mitsuba 3 for the tests that compare against it: an optional dependency."""

from __future__ import annotations

import glob
import os


def load_mitsuba(vectorized: bool = False):
    """Mitsuba 3 with a variant set (``llvm_ad_rgb`` where it is safe, else ``scalar_rgb``), or
    None when it is not installed: the tests comparing against it skip then. ``vectorized``:
    the caller passes arrays of queries, which the scalar variant cannot take, so the test is
    skipped (naming the missing library) where only that variant is available."""
    try:
        if "DRJIT_LIBLLVM_PATH" not in os.environ:
            found = sorted(glob.glob("/usr/lib/*/libLLVM.so.19.1"))
            if found:
                os.environ["DRJIT_LIBLLVM_PATH"] = found[0]
        import mitsuba as mi
    except Exception:
        return None
    # llvm_ad_rgb aborts the process (uncatchable) with LLVM older than 19: use it only when
    # Debian's libllvm19 is there (./dev installs it), else the scalar variant.
    llvm = os.environ.get("DRJIT_LIBLLVM_PATH", "").endswith(".so.19.1")
    for variant in ("llvm_ad_rgb", "scalar_rgb") if llvm else ("scalar_rgb",):
        try:
            mi.set_variant(variant)
        except Exception:
            continue
        if vectorized and variant == "scalar_rgb":
            import pytest
            pytest.skip("needs Mitsuba's vectorised llvm_ad_rgb variant, which needs Debian's "
                        "libllvm19 (./dev test installs it)")
        return mi
    return None
