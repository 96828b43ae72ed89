"""The persistent compilation cache: a second process reads the first one's programs."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np

PROBE = """
import json, sys
import jax.monitoring
events = {"hits": 0, "writes": 0}
def count(name, **kwargs):
    if name == "/jax/compilation_cache/cache_hits":
        events["hits"] += 1
    elif name == "/jax/compilation_cache/cache_misses":   # recorded when an entry is written
        events["writes"] += 1
jax.monitoring.register_event_listener(count)
import jgi
folder = jgi.compile_cache.folder()
image = jgi.render(jgi.load_scene("cornell_box", resolution=8), "pt", spp=2, seed=1, max_depth=3)
print(json.dumps(dict(events, folder=None if folder is None else str(folder),
                      image=image.tolist())))
"""


def _process(env_cache: str | None) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("JAX_COMPILATION_CACHE_DIR", "JGI_CACHE_DIR")}
    if env_cache is not None:
        env["JGI_CACHE_DIR"] = env_cache
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_second_process_compiles_nothing_and_renders_the_same(tmp_path):
    folder = tmp_path / "xla"
    first = _process(str(folder))
    assert first["folder"] == str(folder) and first["writes"] > 0 and first["hits"] == 0
    assert any(folder.iterdir())
    second = _process(str(folder))             # every program written is read back, none added
    assert second["writes"] == 0 and second["hits"] >= first["writes"]
    np.testing.assert_array_equal(np.array(first["image"]), np.array(second["image"]))
    off = _process("off")
    assert off["folder"] is None and off["hits"] == off["writes"] == 0
    np.testing.assert_array_equal(np.array(off["image"]), np.array(first["image"]))
