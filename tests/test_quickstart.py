"""The README's main command runs end to end (at a reduced size) and writes its outputs."""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_quickstart_runs_and_writes_results(tmp_path):
    sys.path.insert(0, str(ROOT / "experiments"))
    import quickstart

    summary = quickstart.main(["--out", str(tmp_path), "--res", "16", "--reps", "2"])
    for f in ("metrics.csv", "metrics.json", "convergence.png", "images.png", "reference.exr",
              "provenance.json"):
        assert (tmp_path / f).exists(), f
    prov = json.loads((tmp_path / "provenance.json").read_text())
    assert prov["jax_version"] and prov["resolution"] == 16
    assert set(summary) == {"bsdf", "light", "mis"}
    for s in summary.values():  # Monte Carlo: MSE falls with spp
        assert s["slope"] < -0.5
