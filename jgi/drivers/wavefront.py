"""The wavefront driver: estimators written as a per-segment step, with path regeneration.

``render_wavefront`` is the driver for estimators written as a per-segment *step* (the path
tracer): a fixed set of lanes advances one path segment per iteration, and a lane whose path has
ended starts the next path of its work slot at once (path regeneration, Novak et al. 2010);
lanes that finish their slot take the next one from a queue shared by all lanes, so no lane
idles while the longest paths of a batch finish. Which lane traces a path depends on timing
within the loop, but each path's random numbers come from (seed, pixel, sample), so the image
is still a function of the seed alone.

``start_fn`` and ``step_fn`` are static arguments of the jitted :func:`wavefront_call`: JAX's
compile cache keys on them, so they must be hashable and equal by value (module-level
functions, or :class:`jgi.core.configured.Configured` for a step with its settings).
"""

from __future__ import annotations

import warnings
from functools import partial
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .._xla import materialize
from ..core import calls
from ..core.errors import ParameterError
from ..core.progress import advance
from ..core.vec import V3
from ..scene.tables import Scene

# two loops of 2^12 lanes in flight beat one of 2^14 (perf: docs/performance.md#wavefront-lanes)
WAVEFRONT_LANES = 1 << 12   # lanes per loop
WAVEFRONT_SAMPLES = 16      # samples per work slot (one pixel's paths traced by one lane in a row)
WAVEFRONT_CALL_SLOTS = 64   # work slots per lane and call (on average): bounds a call's length
# 2+ slots per lane: concurrent loops (perf: docs/performance.md#wavefront-stream-slots)
WAVEFRONT_STREAM_SLOTS = 1  # least work slots per lane for a call of its own
# 2 segments save state copies, cost compile time (perf: docs/performance.md#wavefront-unroll)
WAVEFRONT_UNROLL = 2        # segments per inner-loop iteration, for images of at least
WAVEFRONT_UNROLL_PIXELS = 1 << 14


class _Lanes(NamedTuple):
    state: object        # the estimator's per-lane path state (a pytree of [lanes] arrays)
    slot: jax.Array      # the lane's work slot, counted from the call's first; n_call: none
    sample: jax.Array    # which of the slot's samples the path in flight is
    alive: jax.Array     # the lane has a path in flight (or one to start)
    fresh: jax.Array     # the path is to start at the next segment: ``state`` is stale
    acc: V3              # radiance summed over the slot's finished paths
    bad: jax.Array       # finished paths with a non-finite value (dropped)


def _slot_work(slot_id, P, spp, per_slot):
    """(pixel, first sample, sample count) of global work slot ``slot_id``: slots enumerate
    pixels fastest, then blocks of ``per_slot`` samples."""
    pixel = slot_id % P
    block = slot_id // P
    first = block * per_slot
    return pixel, first, jnp.clip(spp - first, 0, per_slot)


@partial(jax.jit, static_argnames=("start_fn", "step_fn", "lanes", "unroll"))
def wavefront_call(scene: Scene, seed, slot0, n_call, spp, per_slot, n_inner, *, start_fn,
                   step_fn, lanes, unroll=1):
    """Trace every path of work slots slot0 .. slot0 + n_call - 1 and return the (P, 3) sum of
    their radiance, and how many paths were dropped as non-finite.

    ``start_fn(scene, seed, pixel, sample) -> state`` and ``step_fn(scene, state) -> (state,
    alive, L)`` define the estimator. Each lane traces the paths of one slot one after another
    (a finished path is replaced by the slot's next at once), then idles; every ``n_inner *
    unroll`` segments the idle lanes add their slot's sum to the image and take the next slots
    of the call in lane order (an exclusive prefix sum of the idle flags numbers them). Which
    lane traces a path depends on the others, but every path draws its random numbers from
    (seed, pixel, sample), so the image does not.

    Paths start lazily: a lane whose path ended is only flagged ``fresh``, and the next segment
    selects ``start_fn``'s state in those lanes as its input. The start is then computed inside
    the step's own kernels (the estimator stores, with its first results, what several of its
    kernels read), instead of in a kernel that rewrote every leaf of every lane's state after
    each segment for the quarter of the lanes whose path had ended
    (perf: docs/performance.md#lazy-path-starts)."""
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    lane = jnp.arange(lanes, dtype=jnp.int32)

    def work(slot):
        pixel, first, count = _slot_work(slot0 + slot, P, spp, per_slot)
        return pixel, first, jnp.where(slot < n_call, count, 0)

    zero = jnp.zeros((lanes,), jnp.int32)
    z = jnp.zeros((lanes,), jnp.float32)
    pixel0, first0, count0 = work(lane)
    init = _Lanes(start_fn(scene, seed, pixel0, first0), jnp.minimum(lane, n_call), zero,
                  count0 > 0, zero > 0, V3(z, z, z), zero)
    next0 = jnp.minimum(jnp.int32(lanes), n_call)

    def segment(c: _Lanes) -> _Lanes:
        pixel, first, count = work(c.slot)
        new = start_fn(scene, seed, pixel, first + c.sample)
        state = jax.tree_util.tree_map(lambda a, b: jnp.where(c.fresh, a, b), new, c.state)
        state, alive_path, L = step_fn(scene, state)
        finished = c.alive & ~alive_path
        finite = jnp.isfinite(L.x) & jnp.isfinite(L.y) & jnp.isfinite(L.z)
        bad = c.bad + (finished & ~finite).astype(jnp.int32)
        acc = V3(*(a + jnp.where(finished & finite, l, 0.0) for a, l in zip(c.acc, L)))
        sample = c.sample + finished.astype(jnp.int32)
        more = sample < count
        alive = jnp.where(finished, more, c.alive)
        # the lane's fate, computed once and stored in one small kernel; the state's leaves are
        # stored by the step itself
        sample, alive, fresh, acc, bad = materialize((sample, alive, finished & more, acc, bad))
        return _Lanes(state, c.slot, sample, alive, fresh, acc, bad)

    def refill(c: _Lanes, img, nxt):
        idle = ~c.alive
        done = idle & (c.slot < n_call)          # finished its slot: add the slot to the image
        img = img.at[jnp.where(done, work(c.slot)[0], P)].add(c.acc.stack(), mode="drop")
        i = idle.astype(jnp.int32)
        new = nxt + jnp.cumsum(i) - i
        gets = idle & (new < n_call)
        slot = jnp.where(idle, jnp.where(gets, new, n_call), c.slot)
        sample = jnp.where(idle, 0, c.sample)
        acc = V3(*(jnp.where(idle, 0.0, a) for a in c.acc))
        slot, sample, alive, fresh, acc = materialize(
            (slot, sample, jnp.where(idle, gets, c.alive), c.fresh | gets, acc))
        return (_Lanes(c.state, slot, sample, alive, fresh, acc, c.bad), img,
                jnp.minimum(nxt + jnp.sum(i), n_call))

    def inner(_, c):
        for _ in range(unroll):
            c = segment(c)
        return c

    def outer(carry):
        c, img, nxt = carry
        # a refill once per n_inner segments is cheap (perf: docs/performance.md#refill-interval)
        return refill(jax.lax.fori_loop(0, n_inner, inner, c), img, nxt)

    out, img, _ = jax.lax.while_loop(lambda c: jnp.any(c[0].alive) | (c[2] < n_call), outer,
                                     (init, jnp.zeros((P, 3), jnp.float32), next0))
    return img, jnp.sum(out.bad)


def render_wavefront(scene: Scene, start_fn: Callable, step_fn: Callable, *, spp: int, seed: int,
                     progress: bool = False, lanes: int | None = None,
                     per_slot: int | None = None, devices=None,
                     unroll: int | None = None, streams: int | None = None) -> np.ndarray:
    """Average over ``spp`` samples per pixel of paths traced segment by segment.

    ``start_fn(scene, seed, pixel, sample) -> state`` starts the paths for (pixel, sample) index
    arrays; ``step_fn(scene, state) -> (state, alive, L)`` advances every lane by one segment and
    says which paths are still going; when a lane's ``alive`` turns False its ``L`` (a V3) is
    that path's final estimate. A new path's state reaches ``step_fn`` as ``start_fn``'s values
    selected in, not yet computed (see :func:`wavefront_call`), and the state ``step_fn``
    returns is carried as it is: the step stores (jgi._xla.materialize) whatever several of its
    kernels read. Work is split into slots of (pixel, up to ``per_slot`` samples,
    default ``WAVEFRONT_SAMPLES``) that lanes take from a queue as they finish (see
    :func:`wavefront_call`): lanes stay busy whatever the spread of path lengths over the
    image (perf: docs/performance.md#work-queue).
    Each inner-loop iteration advances every lane by ``unroll`` segments (default
    ``WAVEFRONT_UNROLL`` for images of at least ``WAVEFRONT_UNROLL_PIXELS``, else 1). Renders
    of at least ``WAVEFRONT_STREAM_SLOTS`` slots per lane are split into calls enough for
    ``streams`` (default ``jgi.core.calls.CALL_STREAMS``) loops per device to run at once, sharing
    one compiled function (:func:`jgi.core.calls.sum_calls`). None of these settings changes the
    image beyond float rounding of the sums, and none depends on the machine's core count.
    Non-finite path values are dropped with a warning, as in
    :func:`jgi.drivers.chunked.render_paths`."""
    W, H = scene.camera.width, scene.camera.height
    P = W * H
    lanes = lanes or min(WAVEFRONT_LANES, 1 << max(int(np.ceil(np.log2(P))), 8))
    devices = list(devices if devices is not None else jax.devices())
    D = len(devices)
    unroll = unroll or (WAVEFRONT_UNROLL if P >= WAVEFRONT_UNROLL_PIXELS else 1)
    per_slot = max(1, min(per_slot or WAVEFRONT_SAMPLES, spp))
    n_slots = P * -(-spp // per_slot)
    per_call = lanes * WAVEFRONT_CALL_SLOTS
    if n_slots + per_call * D >= 2**31:
        raise ParameterError(
            f"{P} pixels x {spp} spp is too many work slots for int32 indices; render several "
            f"seeds and average the images")
    # refill every ~8 segments, or sooner when slots are short (paths average ~4 segments)
    n_inner = max(1, min(8, 2 * per_slot) // unroll)
    # calls of at most per_call slots; a render of at least WAVEFRONT_STREAM_SLOTS slots per
    # lane and call is split into enough calls for ``streams`` loops per device to run at once
    streams = D * (streams or calls.CALL_STREAMS)
    n_calls = max(-(-n_slots // per_call),
                  min(streams, n_slots // (lanes * WAVEFRONT_STREAM_SLOTS)))
    bounds = [n_slots * i // n_calls for i in range(n_calls + 1)]
    args = (jnp.int32(spp), jnp.int32(per_slot), jnp.int32(n_inner))
    scenes = [jax.device_put(scene, d) for d in devices]   # call i runs on device i mod D

    def call(i):
        return wavefront_call(scenes[i % D], jnp.uint32(seed), jnp.int32(bounds[i]),
                              jnp.int32(bounds[i + 1] - bounds[i]), *args, start_fn=start_fn,
                              step_fn=step_fn, lanes=lanes, unroll=unroll)

    def report(i):
        if progress:
            advance(int(bounds[i + 1] / n_slots * P * spp), P * spp)

    img, bad = calls.sum_calls(call, n_calls, streams=streams, on_done=report)
    out = np.asarray(img, np.float32).reshape(H, W, 3) / np.float32(spp)
    bad = int(bad)
    if bad:
        warnings.warn(f"{bad} path samples were not finite and were dropped", RuntimeWarning)
    return out
