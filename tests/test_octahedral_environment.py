"""pbrt-v4's image infinite light: an equal-area octahedral environment map (Clarberg's
concentric octahedral square, nearest-texel radiance, sampling by a piecewise-constant
distribution over the square). The square <-> sphere maps against each other and their
Jacobian, the radiance against an independent float64 implementation of pbrt-v4's lookup, the
samplers against their pdf (chi-square), the constant map, estimators agreeing on a scene lit
by such a map, and the pbrt-v4 importer (filename, scale, illuminance, errors)."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jgi
from jgi.analysis.chi2 import SphereDomain, assert_chi2
from jgi.core import warps
from jgi.core.imageio import write_exr
from jgi.core.vec import V3
from jgi.physics import lights as LT
from jgi.scene import SceneBuilder, SceneError
from jgi.scene.importers import load_pbrt
from tests.support.environment import (
    radiance_and_pdf,
    rotation,
    sphere_midpoints,
    unit_directions,
)
from tests.support.light_samplers import build, pdf_li, sample_emission, sample_li
from tests.support.stats import assert_agree

X = np.array([0.1, -0.2, 0.3])


def octa_sky(N=16):
    """An N x N octahedral map: brighter towards +z (the inner diamond), a darker quadrant
    and one bright texel (a sun) in the upper hemisphere."""
    g = (np.arange(N) + 0.5) / N
    S, T = np.meshgrid(g, g, indexing="xy")
    z = warps.equal_area_square_to_sphere(S, T, xp=np).z
    img = (0.1 + np.array([0.6, 0.8, 1.2]) * (0.5 * (1 + z))[..., None])
    img[: N // 2, : N // 2] *= 0.4
    img[N // 2 - 3, N // 2 + 2] = (80.0, 60.0, 40.0)
    return img


def octa_lights(img=None, scale=1.5, to_world=None):
    img = octa_sky() if img is None else img
    return build(lambda b: b.environment_map(img, scale=scale, to_world=to_world,
                                             mapping="octahedral"))


# --- an independent float64 reading of pbrt-v4's lookup ------------------------------------

def pbrt_square_point(w):
    """pbrt-v4's EqualAreaSphereToSquare in float64, from its polar form: radius
    sqrt(1 - |z|), the azimuth's fraction of the quadrant, the lower hemisphere mirrored into
    the corners."""
    x, y, z = np.abs(w[:, 0]), np.abs(w[:, 1]), np.abs(w[:, 2])
    r = np.sqrt(np.maximum(1.0 - z, 0.0))
    frac = np.arctan2(y, x) / (np.pi / 2)          # 0 on the x axis, 1 on the y axis
    v = frac * r
    u = r - v
    lower = w[:, 2] < 0
    u, v = np.where(lower, 1 - v, u), np.where(lower, 1 - u, v)
    u, v = np.copysign(u, w[:, 0]), np.copysign(v, w[:, 1])
    return 0.5 * (u + 1), 0.5 * (v + 1)


def pbrt_lookup(img, scale, to_world, d):
    """ImageInfiniteLight::Le: the light-frame direction, its square point, the nearest texel
    (pixel (floor(s N), floor(t N)), row t), remapped as WrapMode::OctahedralSphere."""
    N = img.shape[0]
    w = d @ to_world[:3, :3]                       # world -> light (rows: d^T R = (R^T d)^T)
    s, t = pbrt_square_point(w)
    px, py = np.floor(s * N).astype(int), np.floor(t * N).astype(int)
    over_x = px >= N
    px, py = np.where(over_x, 2 * N - 1 - px, px), np.where(over_x, N - 1 - py, py)
    under_y, over_y = py < 0, py >= N
    px = np.where(under_y | over_y, N - 1 - px, px)
    py = np.where(under_y, -py, np.where(over_y, 2 * N - 1 - py, py))
    return scale * img[py, px], s * N, t * N


def test_square_and_sphere_maps_are_inverse_and_equal_area():
    """Both directions of the map agree to float32 rounding (4000 points: more than a
    vector kernel's worth), land on the unit sphere, and the square -> sphere Jacobian
    |d_s w x d_t w| is 4 pi away from the creases (the axes and the diamond's edges)."""
    rng = np.random.default_rng(0)
    st = rng.random((4000, 2)).astype(np.float32)
    w = jax.jit(warps.equal_area_square_to_sphere)(st[:, 0], st[:, 1])
    W = np.stack([np.asarray(w.x), np.asarray(w.y), np.asarray(w.z)], 1).astype(np.float64)
    assert np.abs(np.linalg.norm(W, axis=1) - 1).max() < 1e-6
    s, t = jax.jit(warps.equal_area_sphere_to_square)(w)
    np.testing.assert_allclose(np.asarray(s), st[:, 0], atol=1e-6)
    np.testing.assert_allclose(np.asarray(t), st[:, 1], atol=1e-6)
    d = unit_directions(4000, 1)
    s, t = jax.jit(warps.equal_area_sphere_to_square)(V3(*jnp.float32(d.T)))
    back = warps.equal_area_square_to_sphere(np.asarray(s, np.float64),
                                             np.asarray(t, np.float64), xp=np)
    np.testing.assert_allclose(np.stack([back.x, back.y, back.z], 1), d, atol=2e-6)
    # float64 numpy: exact inverses; float32 jax against it
    s64, t64 = warps.equal_area_sphere_to_square(V3(*d.T), xp=np)
    np.testing.assert_allclose(np.asarray(s), s64, atol=1e-6)
    ps, pt = pbrt_square_point(d)
    np.testing.assert_allclose(s64, ps, atol=1e-12)
    np.testing.assert_allclose(t64, pt, atol=1e-12)

    def point(p):
        v = warps.equal_area_square_to_sphere(p[0], p[1])
        return jnp.stack([v.x, v.y, v.z])

    u, v = 2 * st[:, 0] - 1, 2 * st[:, 1] - 1
    smooth = (np.abs(u) > 1e-2) & (np.abs(v) > 1e-2) & (np.abs(np.abs(u) + np.abs(v) - 1) > 1e-2)
    J = np.asarray(jax.jit(jax.vmap(jax.jacfwd(point)))(jnp.asarray(st[smooth])), np.float64)
    area = np.linalg.norm(np.cross(J[:, :, 0], J[:, :, 1]), axis=1)
    np.testing.assert_allclose(area, 4 * np.pi, rtol=2e-4)


def test_radiance_is_pbrts_nearest_texel_lookup():
    """Random directions under a rotated light frame, with scale: pbrt's texel (directions
    within 1e-4 texel of a texel edge, where float32 may round to the neighbour, are left out:
    under 1 % of them). The six axes of an unrotated map lie on texel edges and on the fold
    (s or t = 1), where pbrt's octahedral wrap picks the texel: the same texels."""
    img = np.random.default_rng(3).random((12, 12, 3)) + 0.05
    m = rotation(35.0, -25.0)
    d = unit_directions(5000, 7)
    theirs, sN, tN = pbrt_lookup(img, 1.5, m, d)
    near_edge = np.minimum(np.abs(sN - np.round(sN)), np.abs(tN - np.round(tN))) < 1e-4
    assert near_edge.sum() < 0.01 * len(d)
    mine, _ = radiance_and_pdf(octa_lights(img, 1.5, m), d)
    np.testing.assert_allclose(mine[~near_edge], theirs[~near_edge], rtol=1e-6)
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    theirs, _, _ = pbrt_lookup(img, 1.0, np.eye(4), axes)
    mine, _ = radiance_and_pdf(octa_lights(img, 1.0), axes)
    np.testing.assert_allclose(mine, theirs, rtol=1e-6)


def test_sampler_chi2_against_its_pdf():
    lights = octa_lights(to_world=rotation())
    s = sample_li(lights, X, seed=21)
    assert s["valid"].all() and np.all(np.isinf(s["dist"]))
    L, p = radiance_and_pdf(lights, s["wi"])
    np.testing.assert_allclose(s["pdf"], p, rtol=1e-6)      # the sample's pdf is pdf_li's
    np.testing.assert_allclose(s["Li"], L, rtol=1e-6)
    r = assert_chi2(s["wi"], lambda w: radiance_and_pdf(lights, w)[1],
                    SphereDomain(n_a=32, n_phi=32), "octahedral map", total=1.0, nodes=48)
    print(f"octahedral sample_li chi2 p = {r.p_value:.3f}")
    assert abs(r.pdf_integral - 1.0) < 2e-3, r.pdf_integral


def test_pdf_integrates_to_one_and_is_proportional_to_the_texels():
    """Midpoint rule over a fine (theta, phi) grid: 1. Per texel, pdf = mean(rgb) / (mean
    over texels) / (4 pi): pbrt's distribution (channel mean, equal solid angles)."""
    img = octa_sky()
    lights = octa_lights(img, to_world=rotation())
    d, dw = sphere_midpoints(800)
    L, p = radiance_and_pdf(lights, d)
    integral = (p * dw).sum()
    assert abs(integral - 1.0) < 2e-3, integral
    expected = img.mean(2) / img.mean() / (4 * np.pi)
    _, sN, tN = pbrt_lookup(img, 1.0, rotation(), d)
    texel = expected[np.minimum(tN.astype(int), 15), np.minimum(sN.astype(int), 15)]
    inner = np.minimum(np.abs(sN - np.round(sN)), np.abs(tN - np.round(tN))) > 1e-4
    np.testing.assert_allclose(p[inner], texel[inner], rtol=1e-5)
    k = lights.environment
    q = np.asarray(pdf_li(lights, np.int32(k), np.float32(X), np.float32(X + d[:1000]),
                          np.float32(-d[:1000])))
    np.testing.assert_allclose(q, p[:1000], rtol=1e-6)


def test_emission_directions_and_power():
    lights = octa_lights(to_world=rotation())
    R = float(lights.bound_radius)
    e = sample_emission(lights, seed=15)
    w = -e["d"]                                      # towards the environment
    L, p = radiance_and_pdf(lights, w)
    np.testing.assert_allclose(e["pdf_dir"], p, rtol=1e-6)
    r = assert_chi2(w, lambda v: radiance_and_pdf(lights, v)[1], SphereDomain(n_a=32, n_phi=32),
                    "octahedral map emission", total=1.0, nodes=48)
    print(f"octahedral emission chi2 p = {r.p_value:.3f}")
    # power pi R^2 \int L dw = pi R^2 (4 pi / N^2) sum of texels, times the scale
    power = np.pi * R * R * 4 * np.pi * 1.5 * octa_sky().mean((0, 1))
    m = e["weight"].mean(0)
    se = e["weight"].std(0) / np.sqrt(len(e["weight"]))
    assert np.all(np.abs(m - power) < 5 * se + 1e-4 * power), (m, power, se)


def test_constant_map_is_the_constant_environment():
    L = np.array([0.8, 1.0, 1.3])
    const = build(lambda b: b.environment_light(L))
    flat = octa_lights(np.ones((8, 8, 3)) * L, scale=1.0, to_world=rotation())
    d = unit_directions(2000, 2)
    Lc, pc = radiance_and_pdf(const, d)
    Lm, pm = radiance_and_pdf(flat, d)
    np.testing.assert_allclose(Lm, Lc, rtol=1e-6)
    np.testing.assert_allclose(pm, pc, rtol=1e-5)      # uniform: 1 / (4 pi)
    np.testing.assert_allclose(np.asarray(flat.pmf), np.asarray(const.pmf), rtol=1e-5)


def test_non_square_maps_and_unknown_mappings_are_refused():
    with pytest.raises(SceneError, match="must be square.*16 x 8"):
        octa_lights(np.ones((8, 16, 3)))
    with pytest.raises(SceneError, match="unknown mapping 'cube'; allowed: latlong, octahedral"):
        build(lambda b: b.environment_map(np.ones((8, 8, 3)), mapping="cube"))


def octa_scene(size=12):
    """A red ball on a floor seen from above, lit by the octahedral sky turned z-up -> y-up
    (pbrt's usual Rotate -90 1 0 0)."""
    m = np.eye(4)
    m[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]   # light +z -> world +y
    b = SceneBuilder("octa_lit")
    b.material("white", "diffuse", diffuse=0.7)
    b.material("red", "diffuse", diffuse=(0.7, 0.2, 0.2))
    b.sphere((0.0, 0.0, 0.0), 0.8, "red")
    b.quad((-3.0, -0.8, 3.0), (6.0, 0.0, 0.0), (0.0, 0.0, -6.0), "white")
    b.environment_map(octa_sky(), scale=1.0, to_world=m, mapping="octahedral")
    b.camera(position=(0, 3, 1.5), look_at=(0, -0.8, 0), fov=40, width=size, height=size)
    return b.build()


@pytest.mark.slow
def test_estimators_agree_on_an_octahedral_map():
    """PT (MIS with the map's sampling) against BDPT and light tracing (the frame is all
    floor and ball, which light tracing sees)."""
    scene = octa_scene()
    seeds = range(6)
    pt = np.stack([jgi.render(scene, "pt", spp=48, seed=s, max_depth=3) for s in seeds])
    bd = np.stack([jgi.render(scene, "bdpt", spp=24, seed=200 + s, max_depth=3)
                   for s in seeds])
    lt = np.stack([jgi.render(scene, "lt", spp=48, seed=50 + s, max_depth=3) for s in seeds])
    t1 = assert_agree(pt, bd, regions=3, label="pt vs bdpt")
    t2 = assert_agree(pt, lt, regions=3, label="pt vs lt")
    print(f"max |t|: pt-bdpt {t1.max():.2f}, pt-lt {t2.max():.2f}")


# --- pbrt-v4 files --------------------------------------------------------------------------

HEADER = """LookAt 0 0 5  0 0 0  0 1 0
Camera "perspective" "float fov" [ 40 ]
Film "rgb" "integer xresolution" [ 8 ] "integer yresolution" [ 8 ] "string filename" "x.exr"
WorldBegin
Material "diffuse"
Shape "sphere" "float radius" 1
"""


def load(tmp_path, light, name="scene.pbrt"):
    (tmp_path / name).write_text(HEADER + light + "\n")
    return load_pbrt(tmp_path / name)


def test_pbrt_infinite_light_with_a_map(tmp_path):
    """"filename" (an EXR next to the scene), "scale" and the CTM (world-from-light) as the
    builder's octahedral map; the radiance is pbrt's lookup."""
    img = octa_sky()
    write_exr(tmp_path / "sky.exr", img)
    scene = load(tmp_path, 'AttributeBegin\nRotate -90 1 0 0\nRotate 30 0 0 1\n'
                           'LightSource "infinite" "string filename" "sky.exr" "float scale" 2\n'
                           'AttributeEnd')
    from jgi.core import transform as xf
    m = xf.rotate((1, 0, 0), -90) @ xf.rotate((0, 0, 1), 30)
    d = unit_directions(3000, 9)
    mine, _ = radiance_and_pdf(scene.lights, d)
    theirs, sN, tN = pbrt_lookup(img.astype(np.float32).astype(np.float64), 2.0, m, d)
    near_edge = np.minimum(np.abs(sN - np.round(sN)), np.abs(tN - np.round(tN))) < 1e-4
    np.testing.assert_allclose(mine[~near_edge], theirs[~near_edge], rtol=1e-6)
    assert scene.lights.envmap.octahedral


def test_pbrt_illuminance_scales_as_pbrt_does(tmp_path):
    """"illuminance" E: a constant "L" gets luminance E / pi (illuminance E on a patch facing
    +z); a map is scaled by E over pbrt-v4's sum (texel centres above the xy plane, luminance
    x cos, times 2 pi / N^2: half a texel's solid angle), so it renders with illuminance 2 E, as
    in pbrt (measured here by a fine midpoint rule over the upper hemisphere); "scale"
    multiplies in after."""
    N, E = 8, 5.0
    write_exr(tmp_path / "flat.exr", np.full((N, N, 3), 3.0))
    scene = load(tmp_path, 'LightSource "infinite" "string filename" "flat.exr" '
                           '"float scale" 4 "float illuminance" 5')
    g = (np.arange(N) + 0.5) / N
    S, T = np.meshgrid(g, g, indexing="xy")
    u, v = 2 * S - 1, 2 * T - 1                      # pbrt's EqualAreaSquareToSphere: z only
    z = np.sign(1 - np.abs(u) - np.abs(v)) * (1 - (1 - np.abs(np.abs(u) + np.abs(v) - 1)) ** 2)
    pbrt_sum = np.sum(np.where(z > 0, 3.0 * z, 0.0)) * 2 * np.pi / N**2
    L, _ = radiance_and_pdf(scene.lights, unit_directions(200, 3))
    np.testing.assert_allclose(L, 4 * 3.0 * E / pbrt_sum, rtol=1e-5)
    scene = load(tmp_path, 'LightSource "infinite" "rgb L" [0.2 0.4 0.8] "float illuminance" 5')
    L, _ = radiance_and_pdf(scene.lights, unit_directions(200, 3))
    lum = 0.2126 * L[0, 0] + 0.7152 * L[0, 1] + 0.0722 * L[0, 2]
    assert abs(lum - E / np.pi) < 1e-5 * E and np.allclose(L[0] / L[0, 0], [1, 2, 4])
    # a map with structure renders with about 2 E (pbrt's factor; its centre rule on 16^2
    # texels adds a few per cent)
    write_exr(tmp_path / "sky.exr", octa_sky())
    scene = load(tmp_path, 'LightSource "infinite" "string filename" "sky.exr" '
                           '"float illuminance" 5')
    d, dw = sphere_midpoints(600, hemisphere=True)
    L, _ = radiance_and_pdf(scene.lights, d)
    lum = L @ np.array([0.2126, 0.7152, 0.0722])
    got = (lum * d[:, 2] * dw).sum()
    assert abs(got - 2 * E) < 0.1 * E, got


@pytest.mark.parametrize("light, message", [
    ('LightSource "infinite" "string filename" "wide.exr"',
     r"'.*wide.exr' is 16 x 8 texels; allowed: a square equal-area octahedral map"),
    ('LightSource "infinite" "string filename" "black.exr" "float illuminance" 2',
     "is black over its upper hemisphere"),
    ('LightSource "infinite" "string filename" "flat.exr" "point3 portal" '
     '[0 0 0 1 0 0 1 1 0 0 1 0]', '"portal" is not supported'),
])
def test_pbrt_bad_infinite_lights_are_refused(tmp_path, light, message):
    write_exr(tmp_path / "wide.exr", np.ones((8, 16, 3)))
    write_exr(tmp_path / "black.exr", np.zeros((8, 8, 3)))
    write_exr(tmp_path / "flat.exr", np.ones((8, 8, 3)))
    with pytest.raises(SceneError, match=message) as e:
        load(tmp_path, light)
    line = HEADER.count("\n") + 1
    assert f"scene.pbrt:{line}:" in str(e.value)


def test_black_map_samples_without_nan():
    """A black map: uniform sampling tables (density 1 / (4 pi)), zero radiance, no NaN or
    Inf from the sampler, the density or the emission."""
    lights = octa_lights(np.zeros((4, 4, 3)))
    s = sample_li(lights, X, seed=3, n=4096)
    e = sample_emission(lights, seed=4, n=4096)
    L, p = radiance_and_pdf(lights, s["wi"])
    assert np.all(np.isinf(s.pop("dist")))     # environment samples are at infinity
    for v in (*s.values(), *e.values(), L, p):
        assert np.all(np.isfinite(np.asarray(v, np.float64)))
    np.testing.assert_allclose(p, 1 / (4 * np.pi), rtol=1e-6)
    assert np.all(L == 0) and np.all(s["Li"] == 0) and np.all(e["weight"] == 0)
    assert math.isfinite(float(lights.pmf[0]))


def test_toml_octahedral_map(tmp_path):
    """TOML: ``mapping = "octahedral"`` on an image environment; other values and a mapping
    on a constant environment are refused by key."""
    write_exr(tmp_path / "sky.exr", octa_sky())
    head = ('[camera]\nposition = [0, 0, 4]\nlook_at = [0, 0, 0]\nwidth = 8\nheight = 8\n'
            '[[material]]\nname = "m"\ntype = "diffuse"\ndiffuse = 0.5\n'
            '[[shape]]\ntype = "sphere"\ncenter = [0, 0, 0]\nradius = 1\nmaterial = "m"\n')
    env = '[[light]]\ntype = "environment"\nimage = "sky.exr"\nmapping = "octahedral"\n'
    (tmp_path / "env.toml").write_text(head + env)
    scene = jgi.load_scene(tmp_path / "env.toml")
    d = unit_directions(500, 4)
    np.testing.assert_allclose(radiance_and_pdf(scene.lights, d)[0],
                               radiance_and_pdf(octa_lights(scale=1.0), d)[0], rtol=1e-6)
    for bad, match in [(env.replace("octahedral", "cube"),
                        r"light\[0\]\.mapping.*'cube'; allowed: latlong, octahedral"),
                       ('[[light]]\ntype = "environment"\nradiance = 1\nmapping = "octahedral"\n',
                        "mapping.*'image' environment only")]:
        (tmp_path / "bad.toml").write_text(head + bad)
        with pytest.raises(SceneError, match=match):
            jgi.load_scene(tmp_path / "bad.toml")


def test_radiance_gradient_reaches_the_looked_up_texels():
    """d/d texels of the summed radiance over some directions: scale times the number of
    directions reading each texel (the nearest lookup is linear in its texel; the sampling
    tables stay constants)."""
    img = octa_sky(8)
    lights = octa_lights(img, scale=1.5)
    d = unit_directions(3000, 5)
    _, sN, tN = pbrt_lookup(img, 1.0, np.eye(4), d)
    inner = np.minimum(np.abs(sN - np.round(sN)), np.abs(tN - np.round(tN))) > 1e-4
    d = d[inner]
    v = V3(*jnp.float32(d.T))

    def total(texels):
        lt = eqx.tree_at(lambda q: q.envmap.texels, lights, texels)
        return LT.environment_radiance(lt, v).x.sum()

    g = np.asarray(jax.jit(jax.grad(total))(lights.envmap.texels))
    counts = np.zeros((8, 8))
    np.add.at(counts, (tN[inner].astype(int), sN[inner].astype(int)), 1.0)
    np.testing.assert_allclose(g[..., 0], 1.5 * counts, rtol=1e-6)
    assert np.all(g[..., 1:] == 0)
