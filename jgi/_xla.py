"""CPU-backend performance devices, kept in this one module so estimators stay readable.

1. ``XLA_FLAGS`` set before JAX starts its backend (importing jgi first is enough; flags already
   present in the environment are kept, and ``JGI_NO_XLA_FLAGS=1`` disables them): let LLVM
   unroll and vectorise the large fused bounce kernels (``JGI_UNROLL_THRESHOLD`` trades that
   speed for compile time, see ``UNROLL_THRESHOLD``).
2. :func:`materialize`: XLA's fusion pass duplicates a producer into every consumer fusion, so
   an intersection or a sample used by a dozen consumers is recomputed a dozen times (measured:
   about 25,000 instead of 3,000 operations per bounce). Routing the values through one
   multi-output ``lax.reduce`` over a size-2 axis makes XLA compute them once and store them;
   ``lax.optimization_barrier`` does not do this on the CPU backend. The reduce adds zero (or
   ORs False), so the values are unchanged, though the new fusions round differently (see
   below). Limits found in XLA's fusion pass (jax 0.10):
   a value that reaches more than 15 of the outputs is still split off into a kernel of its
   own ("code duplication too high": each output's reshape counts as one more emission), so a
   flag that selects every leaf of a wide state (such as a path restart) is computed
   separately; and the outputs of the reduce cannot be written in place into while-loop
   buffers, which costs one copy per loop-carried leaf unless the loop body runs two steps
   (jgi.drivers.wavefront.WAVEFRONT_UNROLL).

3. :func:`take`: rows of small tables (materials, a handful of primitives) read with a chain of
   selects rather than a gather, which XLA's CPU backend emits as a separate, unfused loop.

4. :func:`sincos`: XLA's CPU backend calls the C library's ``sincosf`` once per *element* (a
   scalar call that also splits the vectorised kernel); a polynomial is a dozen vector ops.

5. :func:`recip` (and :func:`recip_normal`), :func:`div`, :func:`rsqrt`, :func:`sqrt`: float
   division, square root and reciprocal square root are "expensive" to XLA's fusion pass: one
   whose value is used in more than one place, or whose operand is also used directly (v / |v|),
   is never duplicated and usually never fused either, so each splits the bounce into separate
   kernels that store and reload their inputs (the light-sampling code alone was 10 kernels).
   Written as a bit-trick seed and Newton steps (multiplies and adds, which XLA fuses and
   duplicates freely) they stay inside one kernel. Accuracy: max relative error 1.2e-7 (recip)
   and 1.3e-7 (rsqrt) over the whole normal float32 range, with mean error below 3e-9 (no bias:
   the Newton steps converge to the rounding level, unlike a one- or two-step reciprocal, which
   measurably darkens images); inf, 0, NaN and negative arguments behave like the exact
   operations, denormal arguments and results are flushed to zero (like the CPU backend's
   fast-math mode).
   ``JGI_NO_FAST_DIVISION=1`` turns them back into the plain operations.

6. :func:`pow_positive`: ``x ** y`` with a traced exponent lowers to the C library's ``powf``,
   called once per element, like ``sincosf`` (a scalar call inside the vectorised loop);
   ``exp(y log x)`` uses XLA's own vectorised exp and log.

A fault of XLA's under these flags: with ``--xla_cpu_prefer_vector_width=512`` the vectorised
single-argument ``jnp.arctan`` is wrong on arrays of 1024 elements or more (arctan(-6.28) came
out +1.404; jax 0.10.2); every other elementary function jgi uses was within 6e-7, and arctan2
with a traced second argument is right. jgi calls no ``jnp.arctan`` (tests/test_xla.py).

What is guaranteed (measured with tests/test_cpu.py, which runs its cases under each setting
below in a subprocess; ``--xla_cpu_max_isa`` makes XLA generate code for a lesser CPU, so any
machine can check the others):

* The same machine, seed and parameters give the same image, bit for bit (the drivers add their
  parts in a fixed order, whatever the timing of threads; tests/test_wavefront.py,
  test_photons.py).
* x86-64 CPUs with FMA (every CPU with AVX2: Intel since Haswell, AMD since Zen), with or
  without AVX-512: the same image bit for bit. The vector width changes no result, since every
  operation is element-wise IEEE and no reduction order depends on it (measured: AVX-512 against
  ``--xla_cpu_max_isa=AVX2`` on PT, light tracing, BDPT, photon mapping and SPPM, 32^2 at 16 spp:
  equal).
* CPUs without FMA (older, and some low-end parts): XLA contracts a * b + c into a fused
  multiply-add wherever the CPU has one (it offers no switch for it), so results differ by float
  rounding: each path's value to a few roundings per operation, amplified where the integrand is
  steep (Phong's cos^n: up to 7e-5 relative per pixel on Veach's plates). A path that passes
  within a rounding of a decision boundary (a ray at a primitive's silhouette, a photon at the
  gather radius) can go the other way: 0-5 pixels of 1024 changed by more than 1e-3 per render
  at 32^2 and 16 spp, 46 for the photon map's density estimate. Images agree in distribution.
* Edge cases are decided alike on every CPU: a surface seen edge-on scatters nothing and has
  pdf 0, a ray in a primitive's plane misses it (jgi.core.vec.EDGE_ON_COS: a band wider than the
  rounding of a dot product, which with and without FMA differ in sign for exactly perpendicular
  vectors), a ray through an edge shared by two triangles hits one of them (the barycentric test
  is widened by bvh.BARY_EPS), the cosine-hemisphere warp's rim has cos = 0 exactly.

What each device here changes (the same renders, each device off in turn):

* The flags (unroll threshold, vector width): nothing, bit for bit.
* :func:`materialize`: rounding only. The reduce adds zero, but the fusions it creates contract
  different products into FMAs (measured: up to 6e-5 relative on Veach's plates, no decision).
* :func:`recip`, :func:`div`, :func:`rsqrt`, :func:`sqrt`: within an ulp or two of the IEEE
  operations, so rounding, and like a CPU without FMA, a rare boundary decision.
* :func:`sincos`: within 1e-7 absolute of the C library. :func:`pow_positive`: see there.
* :func:`take`: nothing (a select chain reads the same values as a gather).
"""

from __future__ import annotations

import os

import jax
import jax.numpy as jnp

# LLVM's unroll threshold, high enough for the bounce kernels to vectorise, at a cost in compile
# time (perf: docs/performance.md#unroll-threshold). JGI_UNROLL_THRESHOLD sets it; the test
# suite, which is compile-bound, uses 1000 (tests/conftest.py). Unrolling changes no result
# (test_xla checks a render bit for bit).
DEFAULT_UNROLL_THRESHOLD = 4000
UNROLL_THRESHOLD = int(os.environ.get("JGI_UNROLL_THRESHOLD", DEFAULT_UNROLL_THRESHOLD))

_FLAGS: list[str] = [
    f"--xla_backend_extra_options=-unroll-threshold={UNROLL_THRESHOLD},"
    "-runtime-memory-check-threshold=10000,-vectorize-memory-check-threshold=10000",
    "--xla_cpu_prefer_vector_width=512",
]

if not os.environ.get("JGI_NO_XLA_FLAGS"):
    _current = os.environ.get("XLA_FLAGS", "")
    _extra = [f for f in _FLAGS if f.split("=")[0] not in _current]
    if _extra:
        os.environ["XLA_FLAGS"] = (_current + " " + " ".join(_extra)).strip()

ENABLED = not os.environ.get("JGI_NO_MATERIALIZE")
FAST_DIVISION = not os.environ.get("JGI_NO_FAST_DIVISION")


def materialize(tree, group: int | None = None):
    """Return ``tree`` unchanged in value, but computed once and stored (see module docstring).

    ``group``: store the leaves ``group`` at a time, each group its own kernel. One kernel
    computing a hundred outputs is too large for LLVM to vectorise its loop over lanes (BDPT's
    MIS weights and contributions ran as scalar code, about 1 ns an operation per lane)."""
    if group is not None:
        leaves, treedef = jax.tree_util.tree_flatten(tree)
        stored = [x for k in range(0, len(leaves), group)
                  for x in materialize(tuple(leaves[k:k + group]))]
        return jax.tree_util.tree_unflatten(treedef, stored)
    if not ENABLED:
        return tree
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    if not leaves:
        return tree
    leaves = [jnp.asarray(x) for x in leaves]
    shapes = {x.shape for x in leaves}
    if len(shapes) != 1 or leaves[0].ndim == 0:
        return tree
    return jax.tree_util.tree_unflatten(treedef, list(_stored(*leaves)))


@jax.custom_jvp
def _stored(*leaves):
    ops = [jnp.stack([x, jnp.zeros_like(x)]) for x in leaves]
    inits = [jnp.zeros((), x.dtype) for x in leaves]
    kinds = [x.dtype == jnp.bool_ for x in leaves]

    def combine(a, b):
        return tuple((ai | bi) if k else (ai + bi) for ai, bi, k in zip(a, b, kinds))

    return tuple(jax.lax.reduce(ops, inits, combine, (0,)))


@_stored.defjvp
def _stored_jvp(primals, tangents):
    # The value is the identity, so is its derivative. JAX has no derivative rule for a reduce
    # with a custom combiner; the tangents need no materialising trick.
    return _stored(*primals), tuple(tangents)


SMALL_TABLE = 8  # tables up to this many rows are read with selects


def take(table, idx):
    """``table[idx]`` for a 1-D table and an index array of valid rows (0 <= idx < len)."""
    n = table.shape[0]
    if n == 1:
        return jnp.broadcast_to(table[0], jnp.shape(idx))
    if n > SMALL_TABLE:
        return table[idx]
    out = jnp.broadcast_to(table[n - 1], jnp.shape(idx))
    for i in range(n - 2, -1, -1):
        out = jnp.where(idx == i, table[i], out)
    return out


# Cody-Waite split of pi/2 (Cephes' DP1..DP3 for pi/4, doubled): q * _PIO2_1 is exact for |q| < 2^11
_PIO2_1, _PIO2_2, _PIO2_3 = 1.5703125, 4.837512969970703125e-4, 7.54978995489188216e-8


def sincos(x):
    """(sin x, cos x) in float32 for |x| <= 4096 (the warps use [-pi, 2 pi]): reduce by the
    nearest multiple q of pi/2 (three-part Cody-Waite), evaluate Cephes' single-precision
    minimax polynomials on [-pi/4, pi/4], then rotate by the quadrant q mod 4. Max abs error
    about 1e-7 on [-4096, 4096] (checked against float64)."""
    x = jnp.asarray(x, jnp.float32)
    q = jnp.round(x * jnp.float32(2.0 / 3.141592653589793))
    r = ((x - q * _PIO2_1) - q * _PIO2_2) - q * _PIO2_3
    sin_r, cos_r = sincos_quarter(r)
    k = q.astype(jnp.int32)
    swap = (k & 1) == 1
    s = jnp.where(swap, cos_r, sin_r)
    c = jnp.where(swap, sin_r, cos_r)
    s = jnp.where((k & 2) == 2, -s, s)
    c = jnp.where(((k + 1) & 2) == 2, -c, c)
    return s, c


def sincos_quarter(r):
    """(sin r, cos r) for |r| <= pi/4, no range reduction: :func:`sincos`'s polynomials alone
    (for callers whose angle is already in range, such as the concentric disc map)."""
    r = jnp.asarray(r, jnp.float32)
    z = r * r
    sin_r = r + r * z * (-1.6666654611e-1 + z * (8.3321608736e-3 + z * -1.9515295891e-4))
    cos_r = 1.0 - 0.5 * z + z * z * (4.166664568298827e-2 + z * (-1.388731625493765e-3
                                                                   + z * 2.443315711809948e-5))
    return sin_r, cos_r


_F32_MIN_NORMAL = 1.1754944e-38   # 2^-126
_F32_RECIP_MAX = 8.507059e37      # 2^126: above it the reciprocal is denormal (flushed to 0)


def _bits(x):
    return jax.lax.bitcast_convert_type(x, jnp.int32)


def _float(i):
    return jax.lax.bitcast_convert_type(i, jnp.float32)


def recip(x):
    """1 / x in float32 (see the module docstring, item 5)."""
    x = jnp.asarray(x, jnp.float32)
    if not FAST_DIVISION:
        return 1.0 / x
    a = jnp.abs(x)
    y = _float(jnp.int32(0x7EF311C3) - _bits(a))  # within 12.5% of 1/a
    for _ in range(3):                             # error e -> e^2: 0.125 -> 2e-4 -> rounding
        y = y * (2.0 - a * y)
    y = jnp.where(a < _F32_MIN_NORMAL, jnp.float32(jnp.inf), y)
    y = jnp.where(a > _F32_RECIP_MAX, 0.0, y)      # also a = inf
    return jnp.where(jnp.signbit(x), -y, y)


def recip_normal(x):
    """1 / x for finite x with 2^-126 <= |x| <= 2^126 (normal x with a normal reciprocal; callers
    guarantee the range, which lets this skip :func:`recip`'s special cases: about half the
    operations). The seed takes x's sign, so the Newton steps run on x itself. Same accuracy as
    :func:`recip` within that range."""
    x = jnp.asarray(x, jnp.float32)
    if not FAST_DIVISION:
        return 1.0 / x
    b = _bits(x)
    magnitude = b & jnp.int32(0x7FFFFFFF)
    y = _float((jnp.int32(0x7EF311C3) - magnitude) | (b ^ magnitude))
    for _ in range(3):
        y = y * (2.0 - x * y)
    return y


def div(a, b):
    """a / b in float32 (see the module docstring, item 5)."""
    if not FAST_DIVISION:
        return jnp.asarray(a, jnp.float32) / jnp.asarray(b, jnp.float32)
    return a * recip(b)


def rsqrt(x):
    """1 / sqrt(x) in float32 (see the module docstring, item 5)."""
    x = jnp.asarray(x, jnp.float32)
    if not FAST_DIVISION:
        return jax.lax.rsqrt(x)
    y = _float(jnp.int32(0x5F375A86) - (_bits(x) >> 1))  # within 3.5% for normal x > 0
    for _ in range(3):                  # error e -> 1.5 e^2: 3.5e-2 -> 1.8e-3 -> 5e-6 -> rounding
        y = y * (1.5 - (0.5 * (x * y)) * y)  # (x y) first: 0.5 x is denormal (flushed) near 2^-126
    y = jnp.where(x < _F32_MIN_NORMAL, jnp.float32(jnp.inf), y)
    y = jnp.where(x == jnp.inf, 0.0, y)
    return jnp.where(x < 0, jnp.float32(jnp.nan), y)


def sqrt(x):
    """sqrt(x) in float32 (see the module docstring, item 5)."""
    x = jnp.asarray(x, jnp.float32)
    if not FAST_DIVISION:
        return jnp.sqrt(x)
    r = x * rsqrt(x)
    r = jnp.where(x < _F32_MIN_NORMAL, 0.0, r)
    r = jnp.where(x == jnp.inf, x, r)
    return jnp.where(x < 0, jnp.float32(jnp.nan), r)


def pow_positive(x, y):
    """x ** y for x > 0 (callers mask other x), as exp(y log x) (see the module docstring,
    item 6). The relative error is about |y log x| float32 roundings (log's error amplified by
    y): 20 * 2^-23 = 2.4e-6 plus exp's own wherever the result exceeds e^-20 (measured 2.7e-6
    for exponents up to 10^4; powf: 6e-8). ``JGI_NO_FAST_DIVISION=1`` restores ``x ** y``."""
    if not FAST_DIVISION:
        return jnp.asarray(x, jnp.float32) ** y
    return jnp.exp(y * jnp.log(x))
