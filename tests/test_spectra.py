"""Spectra to RGB (jgi.scene.spectra): Planck's law and CIE illuminant A in closed form, flat
spectra, Mitsuba 3's own conversions (its spectrum_list_to_srgb, its XML loader, its spectral
variant's film for blackbodies) and pbrt-v4's normalisations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from jgi.scene import spectra
from jgi.scene.importers import load_mitsuba_xml
from tests.support.mitsuba import load_mitsuba

# Mitsuba integrates in float32 (1000 terms): measured max |difference| 1.1e-6 on values of
# order 1 over the spectra below; 4e-6 is ~60 float32 ulps at 1
MITSUBA_FLOAT32_ATOL = 4e-6
SPECTRA = [
    ([400, 500, 600, 700], [0.1, 0.5, 0.8, 0.3]),
    ([300, 900], [0.5, 0.5]),
    ([380, 450, 520, 610, 705, 790], [0.2, 0.9, 0.1, 0.6, 0.4, 0.05]),
    ([550, 560], [1.0, 1.0]),             # out of gamut: clamped
    ([400, 700], [2.0, 2.0]),             # above 1: clamped as a reflectance
]


def test_planck_closed_forms():
    """Wien's displacement law (the peak at b / T) and the Stefan-Boltzmann law
    (pi * integral of B = sigma T^4)."""
    for T in (1000.0, 3000.0, 6500.0):
        lam = np.linspace(100, 10000, 400001)
        B = spectra.planck(lam, T)
        assert abs(lam[np.argmax(B)] - 2.897771955e6 / T) < 0.03
        lam = np.geomspace(10, 1e7, 400001)
        power = math.pi * np.trapezoid(spectra.planck(lam, T), lam * 1e-9)
        np.testing.assert_allclose(power, 5.670374419e-8 * T ** 4, rtol=1e-4)
        # pbrt-v4's BlackbodySpectrum: Planck's law normalised to 1 at the peak
        np.testing.assert_allclose(spectra.pbrt_blackbody(T),
                                   spectra.planck(spectra.CIE_NM, T) / B.max(), rtol=2e-5)
    with pytest.raises(spectra.SpectrumError, match="temperature must be > 0"):
        spectra.pbrt_blackbody(0.0)


def test_flat_spectra_equal_their_constant():
    # pbrt: a reflectance under D65 maps D65's white to RGB (1, 1, 1) exactly
    flat = ([spectra.CIE_MIN, spectra.CIE_MAX], [0.37, 0.37])
    np.testing.assert_allclose(spectra.pbrt_rgb(flat, illuminant=False), 0.37, rtol=1e-12)
    np.testing.assert_allclose(spectra.pbrt_rgb(0.37, illuminant=False), 0.37, rtol=1e-12)
    # pbrt light spectra have luminance 1 whatever their magnitude
    y = spectra.PBRT_XYZ_FROM_SRGB[1]
    for s in (5.0, flat, spectra.pbrt_blackbody(2700.0)):
        np.testing.assert_allclose(y @ spectra.pbrt_rgb(s, illuminant=True), 1.0, rtol=1e-12)
    # Mitsuba: a constant is that constant; a flat list is within its tables' rounding
    # (Mitsuba gives 0.998985 for 1 over 300..900 nm)
    np.testing.assert_array_equal(spectra.mitsuba_rgb(0.37), np.full(3, 0.37))
    np.testing.assert_allclose(spectra.mitsuba_rgb(([300.0, 900.0], [0.37, 0.37])), 0.37,
                               rtol=1.2e-3)


def test_named_illuminants_are_the_cie_tables():
    """stdillum-D65 at a few wavelengths against CIE's table (100 at 560 nm); stdillum-A
    against its defining closed form (Planck at 2848 K with c2 = 1.435e-2 m K); both
    normalised as pbrt-v4 does, to a photometric integral of CIE_Y_integral."""
    nm = spectra.CIE_NM
    d65 = spectra.pbrt_named("stdillum-D65")
    at = {w: d65[int(w - spectra.CIE_MIN)] for w in (400, 500, 560, 600, 700)}
    cie = {400: 82.7549, 500: 109.354, 560: 100.0, 600: 90.0062, 700: 71.6091}
    for w in cie:
        np.testing.assert_allclose(at[w] / at[560], cie[w] / 100.0, rtol=1e-6)
    # stdillum-A: CIE's tabulated values (5 nm; pbrt's table) from the closed form
    a = spectra.pbrt_named("stdillum-A")
    table = {360: 6.14462, 400: 14.708, 500: 59.8611, 560: 100.0, 700: 198.261,
             780: 241.675, 830: 261.602}
    for w, v in table.items():
        np.testing.assert_allclose(a[w - spectra.CIE_MIN] / a[560 - spectra.CIE_MIN], v / 100,
                                   rtol=1e-5)
    assert nm[0] == 360 and nm[-1] == 830
    for name in spectra.pbrt_named_illuminants():
        s = spectra.pbrt_named(name)
        np.testing.assert_allclose((s * spectra.CIE_XYZ[:, 1]).sum(),
                                   spectra.PBRT_CIE_Y_INTEGRAL, rtol=1e-12)
    assert spectra.pbrt_named("glass-BK7") is None


@pytest.fixture(scope="module")
def mi():
    m = load_mitsuba()
    if m is None:
        pytest.skip("Mitsuba 3 is not installed")
    return m


@pytest.mark.parametrize("emitter, unbounded", [(False, False), (True, False), (False, True)])
def test_lists_match_mitsubas_conversion(mi, emitter, unbounded):
    for wl, v in SPECTRA:
        ours = spectra.mitsuba_rgb((np.array(wl, float), np.array(v, float)), emitter, unbounded)
        ref = np.array(mi.spectrum_list_to_srgb(wl, v, bounded=not (emitter or unbounded),
                                                d65=not emitter)).ravel()
        np.testing.assert_allclose(ours, ref, atol=MITSUBA_FLOAT32_ATOL, err_msg=f"{wl} {v}")


def test_mitsuba_files_give_mitsubas_values(mi, tmp_path):
    """The importer's RGB for <spectrum> values equals what Mitsuba's XML loader makes of the
    same file (read back with mi.traverse): reflectances, emitter radiance (constant and
    list: Mitsuba's equal-energy 'purple'), .spd files, conductor eta / k."""
    (tmp_path / "s.spd").write_text("# a comment\n410 0.15\n500 0.55\n600 0.8\n690 0.2\n")
    value = "400:0.1, 500:0.5, 600:0.8, 700:0.3"
    scene = f"""<scene version="3.0.0">
      <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="4"/>
        <integer name="height" value="4"/></film></sensor>
      <bsdf type="diffuse" id="a"><spectrum name="reflectance" value="{value}"/></bsdf>
      <bsdf type="diffuse" id="b"><spectrum name="reflectance" filename="s.spd"/></bsdf>
      <bsdf type="conductor" id="c"><spectrum name="eta" value="400:0.2, 700:1.9"/>
        <spectrum name="k" value="400:3.1, 550:2.5, 700:4.2"/></bsdf>
      <shape type="sphere"><ref id="a"/></shape>
      <shape type="sphere"><point name="center" x="3" y="0" z="0"/><ref id="b"/></shape>
      <shape type="sphere"><point name="center" x="6" y="0" z="0"/><ref id="c"/></shape>
      <shape type="sphere"><point name="center" x="9" y="0" z="0"/>
        <emitter type="area"><spectrum name="radiance" value="{value}"/></emitter></shape>
      <emitter type="constant"><spectrum name="radiance" value="0.25"/></emitter>
    </scene>"""
    path = tmp_path / "spectra.xml"
    path.write_text(scene)
    ours = load_mitsuba_xml(path)
    params = mi.traverse(mi.load_file(str(path)))

    def ref(key):
        return np.array(params[key]).ravel()

    diffuse = np.stack([np.asarray(ours.materials.diffuse.x), np.asarray(ours.materials.diffuse.y),
                        np.asarray(ours.materials.diffuse.z)], 1)
    for key in ("a.reflectance.value", "b.reflectance.value"):
        assert np.any(np.all(np.abs(diffuse - ref(key)) < MITSUBA_FLOAT32_ATOL, axis=1)), key
    eta = np.stack([np.asarray(ours.materials.eta.x), np.asarray(ours.materials.eta.y),
                    np.asarray(ours.materials.eta.z)], 1)
    k = np.stack([np.asarray(ours.materials.k.x), np.asarray(ours.materials.k.y),
                  np.asarray(ours.materials.k.z)], 1)
    assert np.any(np.all(np.abs(eta - ref("c.eta.value")) < MITSUBA_FLOAT32_ATOL, axis=1))
    assert np.any(np.all(np.abs(k - ref("c.k.value")) < MITSUBA_FLOAT32_ATOL, axis=1))
    emitted = np.stack([np.asarray(ours.lights.emission.x), np.asarray(ours.lights.emission.y),
                        np.asarray(ours.lights.emission.z)], 1)
    area = [key for key in params.keys() if key.endswith("emitter.radiance.value")]
    const = [key for key in params.keys() if key.endswith("radiance.value") and key not in area]
    for key in area + const:
        assert np.any(np.all(np.abs(emitted - ref(key)) < MITSUBA_FLOAT32_ATOL, axis=1)), key


def test_blackbody_as_mitsubas_spectral_film_sees_it(mi):
    """Mitsuba's RGB variants cannot render a blackbody; its spectral variant writes this RGB
    to its film: a constant blackbody environment seen by 64 pixels x 256 spectral samples,
    jgi's value within 3.5 standard errors of the pixel mean per channel (Mitsuba's side
    noisy, jgi's exact)."""
    previous = mi.variant()
    try:
        mi.set_variant(previous.replace("rgb", "spectral"))
        for T in (2700.0, 6500.0):
            scene = mi.load_string(f"""<scene version="3.0.0"><integrator type="path"/>
              <sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/>
              <integer name="height" value="8"/><rfilter type="box"/></film>
              <sampler type="independent"><integer name="sample_count" value="256"/></sampler>
              </sensor><emitter type="constant"><spectrum name="radiance" type="blackbody">
              <float name="temperature" value="{T}"/></spectrum></emitter></scene>""")
            img = np.array(mi.render(scene, seed=3), float).reshape(-1, 3)
            mean, se = img.mean(0), img.std(0, ddof=1) / math.sqrt(len(img))
            t = (spectra.mitsuba_blackbody_rgb(T) - mean) / se
            assert np.all(np.abs(t) < 3.5), (T, t)
    finally:
        mi.set_variant(previous)


def test_malformed_spectra_are_refused(tmp_path):
    with pytest.raises(spectra.SpectrumError, match="wavelengths must increase"):
        spectra.parse_mitsuba_value("500:1, 400:2")
    with pytest.raises(spectra.SpectrumError, match="not a wavelength:value pair"):
        spectra.parse_mitsuba_value("400:1, 500")
    (tmp_path / "bad.spd").write_text("400 1\n500 x\n")
    with pytest.raises(spectra.SpectrumError, match="'x' is not a number"):
        spectra.read_spd(tmp_path / "bad.spd")


@pytest.mark.parametrize("body, message", [
    ('<bsdf type="diffuse"><spectrum name="reflectance" type="blackbody">'
     '<float name="temperature" value="3000"/></spectrum></bsdf>',
     "a blackbody is supported as an emitter's radiance / intensity / irradiance only"),
    ('<bsdf type="diffuse"><spectrum name="reflectance" type="irregular">'
     '<string name="wavelengths" value="400, 700"/><string name="values" value="0.1, 0.2"/>'
     '</spectrum></bsdf>', "type 'irregular' is not supported"),
    ('<bsdf type="diffuse"><spectrum name="reflectance" value="400:0.1, 300:0.2"/></bsdf>',
     "spectrum 'reflectance': .*wavelengths must increase"),
    ('<bsdf type="diffuse"><spectrum name="reflectance" filename="none.spd"/></bsdf>',
     "spectrum file 'none.spd' does not exist"),
    ('<emitter type="constant"><spectrum name="radiance" type="blackbody">'
     '<float name="temp" value="3000"/></spectrum></emitter>',
     "blackbody: needs <float name=\"temperature\">"),
])
def test_mitsuba_spectrum_refusals_name_file_and_line(tmp_path, body, message):
    from jgi.scene import SceneError
    path = tmp_path / "bad.xml"
    path.write_text(f'<scene version="3.0.0">\n{body}\n</scene>\n')
    with pytest.raises(SceneError, match=message) as e:
        load_mitsuba_xml(path)
    assert f"{path}:2:" in str(e.value)
