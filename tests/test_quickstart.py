"""The README's main command (``jgi run configs/quickstart.toml``, which ``./dev quickstart``
calls) runs end to end at a reduced size and writes its outputs."""

from __future__ import annotations

import json
from pathlib import Path

from jgi.experiment import run

CONFIG = Path(__file__).resolve().parents[1] / "configs" / "quickstart.toml"


def test_quickstart_runs_and_writes_results(tmp_path):
    # the bundled config at 16^2 with two repetitions; every spp of its sweep is kept, so the
    # convergence slopes are fitted over 1..16 spp as in the full run
    text = CONFIG.read_text()
    assert "resolution = 32\n" in text and "repetitions = 3\n" in text
    config = tmp_path / "quickstart.toml"
    config.write_text(text.replace("resolution = 32\n", "resolution = 16\n")
                      .replace("repetitions = 3\n", "repetitions = 2\n"))
    out = run(config, out_root=tmp_path / "runs", progress=False)
    for f in ("metrics.csv", "metrics.json", "slopes.json", "mse_vs_spp.png", "mse_vs_time.png",
              "error_maps.png", "reference.exr", "provenance.json"):
        assert (out / f).exists(), f
    prov = json.loads((out / "provenance.json").read_text())
    assert prov["jax_version"]
    assert json.loads((out / "config_as_run.json").read_text())["experiment"]["resolution"] == 16
    slopes = {s["label"]: s for s in json.loads((out / "slopes.json").read_text())
              if s["key"] == "spp"}
    assert set(slopes) == {"bsdf", "light", "mis"}
    for s in slopes.values():  # Monte Carlo: MSE falls with spp
        assert s["slope"] < -0.5
