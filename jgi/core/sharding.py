"""Splitting estimator work over every visible device with ``jax.sharding``.

The renderers process paths (or photons) in *calls* of a fixed number of chunks; call c covers
path ids [c * per_call, (c + 1) * per_call) and every path draws its random numbers from
(seed, pixel, sample), so calls are independent. With D devices, ``shard_map`` over a 1-D
device mesh runs calls c, ..., c + D - 1 at once, one per device, and returns their partial
images, which the host adds **in call order**: the result is bit-for-bit the single-device
image for the same seed, whatever D is.

Several CPU "devices" on one machine: ``XLA_FLAGS=--xla_force_host_platform_device_count=N``
(set before JAX starts). Several hosts: call ``jax.distributed.initialize()`` on every host
before rendering; ``jax.devices()`` then lists all hosts' devices and the same mesh spans them
(each host must run the same program; only process 0 needs to write the image).
"""

from __future__ import annotations

from functools import partial
from typing import Callable, Sequence

import jax
import numpy as np
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P


def device_mesh(devices: Sequence | None = None) -> Mesh:
    devices = list(devices if devices is not None else jax.devices())
    return Mesh(np.array(devices), ("d",))


def _per_device(call, scene, seed, sample0, pixel0, count):
    out = call(scene, seed, sample0[0], pixel0[0], count[0])
    return jax.tree_util.tree_map(lambda x: x[None], out)


@partial(jax.jit, static_argnames=("call", "mesh"))
def sharded_calls(scene, seed, sample0, pixel0, count, *, call: Callable, mesh: Mesh):
    """``call(scene, seed, sample0, pixel0, count) -> pytree`` run once per device of ``mesh``
    on that device's entries of the [D] arrays (sample0, pixel0, count), the outputs stacked
    along a new leading device axis. ``call`` is a static argument: it must be hashable and
    equal by value (jgi.core.configured), so that JAX's compile cache keys on it."""
    return jax.shard_map(partial(_per_device, call), mesh=mesh,
                         in_specs=(P(), P(), P("d"), P("d"), P("d")),
                         out_specs=P("d"), check_vma=False)(scene, seed, sample0, pixel0, count)
