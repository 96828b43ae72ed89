"""The README's main command (``jgi run configs/quickstart.toml``, which ``./dev quickstart``
calls) runs end to end and writes its outputs."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

from jgi.core.imageio import read_exr
from jgi.experiment import run

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "quickstart.toml"


def test_quickstart_runs_and_writes_results(tmp_path):
    # the bundled config as it is (64^2, four repetitions of 1..16 spp: about 30 s)
    out = run(CONFIG, out_root=tmp_path, progress=False)
    for f in ("metrics.csv", "metrics.json", "slopes.json", "mse_vs_spp.png", "mse_vs_time.png",
              "error_maps.png", "reference.exr", "provenance.json"):
        assert (out / f).exists(), f
    prov = json.loads((out / "provenance.json").read_text())
    res = tomllib.loads(CONFIG.read_text())["experiment"]["resolution"]
    assert prov["jax_version"] and read_exr(out / "reference.exr").shape[:2] == (res, res)
    slopes = {s["label"]: s for s in json.loads((out / "slopes.json").read_text())
              if s["key"] == "spp"}
    assert set(slopes) == {"bsdf", "light", "mis"}
    for s in slopes.values():  # unbiased Monte Carlo: MSE ~ spp^-1, inside each stated interval
        assert s["lo"] <= -1.0 <= s["hi"] and s["hi"] - s["lo"] < 0.6, s
