"""What the media tests share: single scattering from a point light in an infinite homogeneous
medium, by quadrature; the gradient check of a homogeneous medium's parameters."""

from __future__ import annotations

import numpy as np

from jgi.scene.builder import SceneBuilder


def point_light_scene(g: float):
    """A camera and a point light in an infinite homogeneous medium (RGB extinction and
    albedo, HG g), no surfaces: every path scatters in the medium."""
    b = SceneBuilder("single_scattering")
    b.camera((0.0, 0.0, 0.0), (0.0, 0.0, 1.0), fov=30, width=8, height=8)
    b.point_light((0.8, 0.3, 1.5), (2.0, 2.0, 2.0))
    b.medium(sigma_t=(0.5, 0.9, 0.2), albedo=(0.8, 0.6, 0.9), g=g)
    return b.build()


def single_scattering_mean(scene, n=48, t_max=80.0, nt=8001):
    """The film-averaged radiance of one scattering event, by quadrature: directions of the film
    (sx, sy) in [-1, 1]^2 (midpoints), int_0^inf sigma_s T(t) p(mu) I T(r) / r^2 dt each (the
    trapezoid rule on nt points: 8,001 and 40,001 agree to 2e-6 relative; one row of the film
    at a time)."""
    cam = scene.camera
    f, r, u = (np.array([float(c) for c in v]) for v in (cam.forward, cam.right, cam.up))
    o = np.array([float(c) for c in cam.position])
    m = scene.medium
    st = np.array([float(c) for c in m.sigma_t])
    ss = st * np.array([float(c) for c in m.albedo])
    g = float(m.g)
    light, intensity = np.array([0.8, 0.3, 1.5]), 2.0
    s = (np.arange(n) + 0.5) / n * 2 - 1
    t = np.linspace(0, t_max, nt)
    total = np.zeros(3)
    for sx in s:
        d = f + sx * r + s[:, None] * u                          # (n, 3): one film row
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        x = o + t[None, :, None] * d[:, None, :]                 # (n, nt, 3)
        to = light - x
        dist = np.linalg.norm(to, axis=2)
        mu = np.einsum("ntk,nk->nt", to, d) / dist
        p = (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * mu) ** 1.5)
        radial = p * intensity / dist**2                          # (n, nt)
        for c in range(3):
            integrand = ss[c] * np.exp(-(t + dist) * st[c]) * radial
            total[c] += np.trapezoid(integrand, t, axis=1).sum()
    return total / (n * n)


# The room of the Mitsuba volpath comparisons (a grey floor, back wall and sphere, a small area
# light; the sensor in medium ``medium``), after the scene's <integrator> and <medium>:
# ``MITSUBA_FOG_ROOM.format(res=..., medium=...)``.
MITSUBA_FOG_ROOM = """  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 0.2, 3.2" target="0, -0.2, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
      <rfilter type="box"/></film>
    <ref name="medium" id="{medium}"/>
  </sensor>
  <bsdf type="diffuse" id="grey"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale value="2"/><rotate x="1" angle="-90"/>
    <translate y="-1"/></transform><ref id="grey"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="2"/><translate z="-1"/>
    </transform><ref id="grey"/></shape>
  <shape type="sphere"><point name="center" value="0.3, -0.6, 0.1"/><float name="radius"
    value="0.4"/><ref id="grey"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.4"/><rotate x="1" angle="90"/>
    <translate y="1"/></transform>
    <emitter type="area"><rgb name="radiance" value="12, 12, 12"/></emitter></shape>
</scene>
"""


def assert_medium_gradients(scene, medium_of, spp: int = 64, max_depth: int = 4):
    """jax.grad of the path tracer's image (its film mean, all channels) with respect to a
    homogeneous medium's sigma_t (a scale), albedo (a scale) and g (an offset), the medium
    being ``medium_of(scene)`` (a pytree node of the scene: ``Scene.medium``, or the table
    ``Scene.bounded_media``), through detached medium sampling: an unbiased estimate of the
    derivative of the expected image, so over 16 seeds its mean agrees with central
    differences of the estimate (same streams) within 5 standard errors of the paired
    difference, plus the quotient's h^2 error (bounded by a second step size); each parameter
    changes the image (|mean| > 5 standard errors)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from jgi.core.vec import V3
    from jgi.estimators.path_tracer import PathTracerConfig, trace_pixels

    n = scene.camera.width * scene.camera.height
    pixel = jnp.tile(jnp.arange(n, dtype=jnp.int32), spp)
    sample = jnp.repeat(jnp.arange(spp, dtype=jnp.int32), n)
    cfg = PathTracerConfig(strategy="mis", max_depth=max_depth, rr_depth=-1)
    m = medium_of(scene)

    def estimate(theta, seed):
        medium = type(m)(V3(*(c * theta[0] for c in m.sigma_t)),
                         V3(*(c * theta[1] for c in m.albedo)), m.g + theta[2])
        sc = eqx.tree_at(medium_of, scene, medium)
        L = trace_pixels(sc, cfg, seed, pixel, sample)
        return L.x.mean() + L.y.mean() + L.z.mean()

    value_and_grad = jax.jit(jax.value_and_grad(estimate))
    base = np.array([1.0, 1.0, 0.0], np.float32)
    f = lambda x, s: float(value_and_grad(jnp.asarray(x, jnp.float32), jnp.uint32(s))[0])  # noqa: E731
    steps = np.array([0.05, 0.05, 0.05])
    g, fd, fd2 = [], [], []
    for s in range(16):
        g.append(np.asarray(value_and_grad(jnp.asarray(base), jnp.uint32(s))[1]))
        e = np.eye(3)
        fd.append([(f(base + h * e[i], s) - f(base - h * e[i], s)) / (2 * h)
                   for i, h in enumerate(steps)])
        fd2.append([(f(base + 2 * h * e[i], s) - f(base - 2 * h * e[i], s)) / (4 * h)
                    for i, h in enumerate(steps)])
    g, fd, fd2 = np.array(g), np.array(fd), np.array(fd2)
    se = lambda x: x.std(0, ddof=1) / np.sqrt(len(x))  # noqa: E731
    curvature = np.abs(fd2.mean(0) - fd.mean(0))
    print("grad", g.mean(0), "+-", se(g), "fd", fd.mean(0), "paired se", se(g - fd))
    np.testing.assert_array_less(np.abs(g.mean(0) - fd.mean(0)), 5 * se(g - fd) + curvature)
    np.testing.assert_array_less(5 * se(g), np.abs(g.mean(0)))
