"""Closed forms for participating media shared by the media tests: single scattering from a
point light in an infinite homogeneous medium, by quadrature."""

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
