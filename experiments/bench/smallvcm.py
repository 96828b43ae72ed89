"""SmallVCM, the peer of the bidirectional and photon benchmarks, built and run in the same run.

SmallVCM's source (Davidovic, Georgiev et al.; MIT) is not part of jgi: the steering side keeps
an unchanged copy in ``../shared/peers/smallvcm`` next to the repository (or give its folder as
``JGI_SMALLVCM_SRC``). :func:`build` copies it into a temporary folder and compiles that copy
with ``g++ -O3 -fopenmp`` (about 3 s), after two edits to the copy only: one more scene
configuration, ``kLightCeiling | kBothSmallSpheres`` (its default box: the light box under the
ceiling, a mirror and a glass ball; ``jgi.load_scene("smallvcm_box")`` is the same scene), and
the base seed read from ``SMALLVCM_SEED`` (fixed at 1234 in its source), so that independent
runs give the seed-to-seed spread the image comparison needs. SmallVCM renders 512^2 only.

A rate is taken from wall clock, as jgi's: SmallVCM's own "done in" figure is ``clock()``,
the process's CPU time over all threads, so :func:`rate` runs it twice (``n`` and ``2 n``
iterations) and divides the extra ``n`` iterations by the extra wall time, which leaves out
its start, scene build and file writing.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

RESOLUTION = 512
SCENE_ID = 4                      # the configuration build() appends to g_SceneConfigs
CONFIG = "Scene::kLightCeiling | Scene::kBothSmallSpheres"
ALGORITHMS = ("pt", "lt", "ppm", "bpm", "bpt", "vcm")


class PeerUnavailable(RuntimeError):
    """SmallVCM cannot be built here; the message says why (printed as the benchmark's skip)."""


def source_folder() -> Path:
    env = os.environ.get("JGI_SMALLVCM_SRC")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2].parent / "shared" / "peers" / "smallvcm"


@dataclass(frozen=True)
class SmallVCM:
    executable: Path

    def run(self, algorithm: str, iterations: int, seed: int, image: Path | None = None,
            threads: int | None = None) -> tuple[float, float]:
        """One run; returns (wall seconds of the whole process, SmallVCM's CPU seconds)."""
        if algorithm not in ALGORITHMS:
            raise ValueError(f"SmallVCM algorithm {algorithm!r}; allowed: {ALGORITHMS}")
        cmd = [str(self.executable), "-s", str(SCENE_ID), "-a", algorithm, "-i", str(iterations)]
        if image is not None:
            cmd += ["-o", str(image)]
        env = dict(os.environ, SMALLVCM_SEED=str(seed))
        if threads is not None:
            env["OMP_NUM_THREADS"] = str(threads)
        t0 = time.perf_counter()
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True,
                             cwd=self.executable.parent)
        wall = time.perf_counter() - t0
        m = re.search(r"done in ([0-9.]+) s", out.stdout)
        if m is None:
            raise RuntimeError(f"SmallVCM printed no time:\n{out.stdout}\n{out.stderr}")
        return wall, float(m.group(1))

    def rate(self, algorithm: str, iterations: int) -> dict:
        """Samples (one light and one camera subpath per pixel, SmallVCM's "paths") per second
        of wall clock over ``iterations`` iterations, start-up left out (see the module)."""
        short, cpu_short = self.run(algorithm, iterations, seed=1)
        long, cpu_long = self.run(algorithm, 2 * iterations, seed=1)
        samples = RESOLUTION * RESOLUTION * iterations
        return dict(samples_per_s=samples / max(long - short, 1e-9),
                    samples_per_cpu_s=samples / max(cpu_long - cpu_short, 1e-9),
                    seconds=long - short)

    def images(self, algorithm: str, iterations: int, seeds) -> np.ndarray:
        """[seeds, H, W, 3] linear radiance, row 0 at the top, one image per seed."""
        from jgi.core.imageio import read_hdr

        out = []
        with tempfile.TemporaryDirectory() as tmp:
            for seed in seeds:
                path = Path(tmp) / f"{algorithm}_{seed}.hdr"
                self.run(algorithm, iterations, seed=seed, image=path)
                out.append(read_hdr(path, centred=True))   # it truncates
        return np.stack(out)


def _patch(src: Path) -> None:
    config = src / "config.hxx"
    text = config.read_text()
    table = re.search(r"uint g_SceneConfigs\[\] = \{(.*?)\};", text, re.S)
    seed = "oConfig.mBaseSeed      = 1234;"
    if table is None or seed not in text or table.group(1).count("Scene::kLight") != SCENE_ID:
        raise PeerUnavailable(f"{config}: not the SmallVCM source this benchmark knows (its "
                              "scene table or base seed moved)")
    rows = table.group(1).rstrip() + f",\n    {CONFIG}\n"
    text = text[:table.start(1)] + rows + text[table.end(1):]
    text = text.replace(seed, 'oConfig.mBaseSeed = std::getenv("SMALLVCM_SEED") ? '
                              'std::atoi(std::getenv("SMALLVCM_SEED")) : 1234;')
    config.write_text("#include <cstdlib>\n" + text)


def build(folder: Path) -> SmallVCM:
    """Copy SmallVCM's source into ``folder``, patch the copy (see the module) and compile it.
    Raises :class:`PeerUnavailable` naming what is missing (the source, a compiler)."""
    origin = source_folder()
    if not (origin / "src" / "smallvcm.cxx").is_file():
        raise PeerUnavailable(f"no SmallVCM source at {origin} (set JGI_SMALLVCM_SRC to its "
                              "folder)")
    compiler = shutil.which(os.environ.get("CXX", "g++"))
    if compiler is None:
        raise PeerUnavailable("no C++ compiler (g++, or CXX) to build SmallVCM")
    src = Path(folder) / "src"
    shutil.copytree(origin / "src", src)
    _patch(src)
    exe = Path(folder) / "smallvcm"
    done = subprocess.run([compiler, "-O3", "-std=c++11", "-fopenmp", str(src / "smallvcm.cxx"),
                           "-o", str(exe)], capture_output=True, text=True)
    if done.returncode != 0:
        raise PeerUnavailable(f"building SmallVCM failed:\n{done.stderr[-2000:]}")
    return SmallVCM(exe)
