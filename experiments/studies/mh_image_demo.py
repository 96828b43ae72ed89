"""The lecture's "Metropolis-Hastings: sampling an image": random-walk steps with occasional
uniform jumps, short and long walks against the image.

    python -m experiments.studies.mh_image_demo [--out runs/mh_image_demo] [--image file.exr]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from jgi.transport import mcmc


def procedural_image(n=128):
    y, x = np.mgrid[0:n, 0:n] / n
    img = 0.05 + np.exp(-((x - 0.3) ** 2 + (y - 0.35) ** 2) / 0.005)
    img += 0.6 * ((np.abs(x - 0.7) < 0.12) & (np.abs(y - 0.65) < 0.2))
    img += 0.3 * (np.sin(12 * x) ** 2) * (y > 0.85)
    return img.astype(np.float32)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs/mh_image_demo")
    ap.add_argument("--image", default=None, help="EXR to sample (luminance); default procedural")
    ap.add_argument("--chains", type=int, default=256)
    a = ap.parse_args(argv)
    if a.image:
        from jgi.core.imageio import read_exr
        rgb = read_exr(a.image)
        img = 0.2126 * rgb[..., 0] + 0.7152 * rgb[..., 1] + 0.0722 * rgb[..., 2]
    else:
        img = procedural_image()
    H, W = img.shape
    table = jnp.asarray(img)
    target = lambda x: table[jnp.clip((x[1] * H).astype(jnp.int32), 0, H - 1),
                             jnp.clip((x[0] * W).astype(jnp.int32), 0, W - 1)]
    prop = mcmc.mixture(0.05, mcmc.torus_random_walk(0.002, 0.05), mcmc.independent_uniform())

    def record(acc, x, wx, y, wy):  # expected-value histogram of the walk
        ix = lambda z: (jnp.clip((z[1] * H).astype(jnp.int32), 0, H - 1) * W +
                        jnp.clip((z[0] * W).astype(jnp.int32), 0, W - 1))
        return acc.at[ix(x)].add(wx).at[ix(y)].add(wy)

    x0 = jnp.asarray(np.random.default_rng(0).random((2, a.chains)), jnp.float32)
    target_p = img.ravel() / img.sum()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(10, 3.4))
    axes[0].imshow(img, cmap="gray")
    axes[0].set_title("target f")
    for ax, steps in zip(axes[1:], (20, 2000)):
        s, hist = jax.jit(lambda x: mcmc.run_chains(target, prop, x, steps, seed=1, burn_in=0,
                                                    record=record,
                                                    record_init=jnp.zeros(H * W)))(x0)
        h = np.asarray(hist)
        p = h / h.sum()
        tv = 0.5 * np.abs(p - target_p).sum()
        rate = float(s.accepted.mean()) / steps
        ax.imshow(p.reshape(H, W), cmap="gray")
        ax.set_title(f"{'short' if steps < 100 else 'long'} walk: {steps} steps x {a.chains}\n"
                     f"TV distance {tv:.3f}, acceptance {rate:.2f}")
        print(f"{steps:5d} steps: total-variation distance to f {tv:.4f}, "
              f"acceptance rate {rate:.3f}")
    for ax in axes:
        ax.axis("off")
    fig.tight_layout()
    fig.savefig(out / "mh_image_demo.png", dpi=120)
    print(f"wrote {out / 'mh_image_demo.png'}")


if __name__ == "__main__":
    main()
