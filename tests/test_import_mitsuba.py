"""Mitsuba 3 XML import: same scene data as jgi's own description, same image as Mitsuba."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

import jgi
from jgi.scene import SceneError
from jgi.scene.importers import _common, load_mitsuba_xml, mitsuba
from jgi.scene.tables import (
    BECKMANN,
    GGX,
    MIRROR,
    NAMED_METALS,
    ROUGH_CONDUCTOR,
    ROUGH_DIELECTRIC,
    ROUGH_PLASTIC,
)
from tests.support.mitsuba import load_mitsuba
from tests.support.scenes import leaves_equal, ply_quad
from tests.support.stats import assert_agree, critical_t

DATA = Path(__file__).parent / "data"
CORNELL_XML = DATA / "cornell_box_mitsuba.xml"


def test_cornell_box_xml_loads_to_the_builtin_scene():
    a = load_mitsuba_xml(CORNELL_XML)
    b = jgi.scenes.cornell_box(resolution=256)
    # Mitsuba's diffuse is one-sided (jgi's built-in box is two-sided: seen from inside alike)
    assert np.all(np.asarray(a.materials.one_sided))
    leaves_equal(dataclasses.replace(a, materials=dataclasses.replace(a.materials,
                                                                     one_sided=None)), b)
    assert a.rects.axis_counts == b.rects.axis_counts and a.boxes.count == 2


def write(tmp_path, body, name="scene.xml"):
    p = tmp_path / name
    p.write_text(f'<scene version="3.0.0">\n{body}\n</scene>\n')
    return p


SENSOR = ('<sensor type="perspective"><float name="fov" value="45"/><transform name="to_world">'
          '<lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform><film type="hdrfilm">'
          '<integer name="width" value="8"/><integer name="height" value="6"/></film></sensor>')


def test_lights_materials_and_transforms(tmp_path):
    body = SENSOR + """
    <bsdf type="twosided" id="m"><bsdf type="diffuse">
      <rgb name="reflectance" value="0.2,0.4,0.6"/></bsdf></bsdf>
    <bsdf type="dielectric" id="g"><string name="int_ior" value="water"/>
      <float name="ext_ior" value="1.0"/></bsdf>
    <bsdf type="conductor" id="mirror"/>
    <shape type="sphere"><point name="center" value="1,2,3"/><float name="radius" value="0.5"/>
      <transform name="to_world"><scale value="2"/><translate x="1"/></transform>
      <ref id="g"/></shape>
    <shape type="rectangle"><ref id="mirror"/></shape>
    <shape type="rectangle"><transform name="to_world"><rotate x="1" y="1" angle="30"/></transform>
      <ref id="m"/></shape>
    <emitter type="point"><point name="position" value="0,3,0"/>
      <rgb name="intensity" value="5"/></emitter>
    <emitter type="spot"><rgb name="intensity" value="2"/><float name="cutoff_angle" value="25"/>
      <float name="beam_width" value="25"/>
      <transform name="to_world"><lookat origin="0,4,0" target="0,0,0" up="0,0,1"/>
      </transform></emitter>
    <emitter type="directional"><vector name="direction" value="0,-1,0"/>
      <rgb name="irradiance" value="3"/></emitter>
    <emitter type="constant"><rgb name="radiance" value="0.25"/></emitter>
    """
    s = load_mitsuba_xml(write(tmp_path, body))
    np.testing.assert_allclose([s.spheres.center.x[0], s.spheres.center.y[0],
                                s.spheres.center.z[0]], [3, 4, 6])
    np.testing.assert_allclose(s.spheres.radius, [1.0])
    # diffuse rows keep the default
    np.testing.assert_allclose(s.materials.ior, [1.5, 1.3330, 1.5], rtol=1e-6)
    assert s.rects.count == 1 and s.quads.count == 1   # the rotated rectangle is a general quad
    assert sorted(s.lights.kinds) == [3, 4, 5, 6]
    assert s.camera.width == 8 and s.camera.height == 6
    np.testing.assert_allclose(float(s.lights.cos_total[1]), np.cos(np.radians(25)), rtol=1e-6)


@pytest.mark.parametrize("body, message", [
    ('<shape type="sdfgrid"/>',
     "shape plugin 'sdfgrid' is not supported.*rectangle, cube, sphere, disk, cylinder, obj, ply"),
    ('<bsdf type="thindielectric" id="x"/>',
     "bsdf plugin 'thindielectric' is not supported by jgi.*supported bsdf plugins: diffuse, "
     "conductor, roughconductor, dielectric, roughdielectric, roughplastic, plastic, twosided"),
    ('<bsdf type="plastic" id="x"><float name="alpha" value="0.1"/></bsdf>',
     "plastic.*alpha"),
    ('<bsdf type="principled" id="x"/>', "bsdf plugin 'principled'.*diffuse, conductor"),
    ('<bsdf type="conductor" id="x"><string name="material" value="Unobtainium"/></bsdf>',
     "conductor: material 'Unobtainium' is not in jgi's table of metals; supported: none, a-C"),
    ('<bsdf type="roughconductor" id="x"><string name="material" value="Au"/>'
     '<rgb name="k" value="2"/></bsdf>', "give either material='Au' or eta/k, not both"),
    ('<bsdf type="roughconductor" id="x"><string name="distribution" value="phong"/></bsdf>',
     "roughconductor: unknown distribution 'phong'; supported: beckmann, ggx"),
    ('<bsdf type="roughdielectric" id="x"><float name="alpha" value="0.1"/>'
     '<float name="alpha_u" value="0.2"/><float name="alpha_v" value="0.2"/></bsdf>',
     "give either alpha or alpha_u / alpha_v, not both"),
    ('<bsdf type="roughconductor" id="x"><float name="alpha_u" value="0.2"/></bsdf>',
     "alpha_u and alpha_v must be given together"),
    ('<bsdf type="roughplastic" id="x"><float name="alpha_u" value="0.2"/>'
     '<float name="alpha_v" value="0.3"/></bsdf>', "roughplastic: alpha_u / alpha_v are not "
     "supported"),
    ('<bsdf type="roughconductor" id="x"><float name="alpha" value="-0.1"/></bsdf>',
     "alpha must be >= 0"),
    ('<bsdf type="roughplastic" id="x"><float name="int_ior" value="1.2"/>'
     '<float name="ext_ior" value="1.2"/></bsdf>', "int_ior and ext_ior must differ"),
    ('<bsdf type="roughdielectric" id="x"><string name="int_ior" value="glass"/></bsdf>',
     "roughdielectric: int_ior 'glass' is unknown; names: vacuum"),
    ('<bsdf type="roughplastic" id="x"><float name="roughness" value="0.1"/></bsdf>',
     "bsdf 'roughplastic': unknown parameter 'roughness'; roughplastic takes: "
     "diffuse_reflectance"),
    ('<bsdf type="roughdielectric" id="x"><texture type="checkerboard" '
     'name="specular_transmittance"/></bsdf>', "must be one texture for both"),
    ('<emitter type="spot"><float name="cutoff_angle" value="30"/>'
     '<float name="beam_width" value="40"/></emitter>', "beam_width"),
    ('<shape type="rectangle"><ref id="nope"/></shape>', "unknown bsdf 'nope'"),
    ('<shape type="obj"><string name="filename" value="missing.obj"/></shape>', "does not exist"),
    ('<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap" name="reflectance">'
     '<string name="filename" value="wood.png"/></texture></bsdf></shape>',
     "bitmap\\): cannot read '.*wood.png'"),
    ('<bsdf type="roughplastic" id="x"><texture type="checkerboard" name="alpha"/></bsdf>',
     "roughplastic: 'alpha' cannot be a texture \\(Mitsuba's roughplastic takes a <float> alpha"),
    ('<texture type="checkerboard"/>', "a top-level <texture> needs an id"),
    ('<texture type="mesh_attribute" id="t"/>', "texture plugin 'mesh_attribute' is not "
     "supported by jgi; supported texture plugins: bitmap, checkerboard"),
    ('<bsdf type="roughplastic" id="x"><ref name="diffuse_reflectance" id="checks"/></bsdf>',
     "parameter 'diffuse_reflectance' refers to 'checks', which is not a texture defined"),
    ('<shape type="rectangle"><emitter type="area"><texture type="checkerboard" '
     'name="radiance"/></emitter></shape>', "emitter 'area': a textured radiance is not "
     "supported"),
    ('<emitter type="point"><texture type="checkerboard" name="intensity"/></emitter>',
     "emitter 'point': a textured intensity is not supported"),
    ('<volume/>', "<volume> is not supported"),
    ('<shape type="rectangle"', "XML syntax error"),
])
def test_unsupported_input_names_file_line_and_plugin(tmp_path, body, message):
    path = write(tmp_path, SENSOR + "\n" + body)
    with pytest.raises(SceneError, match=message) as e:
        load_mitsuba_xml(path)
    assert str(path) in str(e.value) and ":" in str(e.value).split(str(path))[1][:3]


def rows(scene, names, b):
    """Material rows of ``scene`` as dicts, by builder name."""
    m = scene.materials
    out = {}
    for name in names:
        i = b[name]
        out[name] = dict(
            kind=int(m.kind[i]), alpha=(float(m.alpha_u[i]), float(m.alpha_v[i])),
            distribution=int(m.distribution[i]), ior=float(m.ior[i]),
            eta=[float(c[i]) for c in (m.eta.x, m.eta.y, m.eta.z)],
            k=[float(c[i]) for c in (m.k.x, m.k.y, m.k.z)],
            diffuse=[float(c[i]) for c in (m.diffuse.x, m.diffuse.y, m.diffuse.z)],
            specular=[float(c[i]) for c in (m.specular.x, m.specular.y, m.specular.z)],
            nonlinear=bool(m.nonlinear[i]))
    return out


MICROFACET_BSDFS = {   # id -> <bsdf> element, each new plugin with defaults and with parameters
    "rc_default": '<bsdf type="roughconductor" id="rc_default"/>',
    "rc_gold": '<bsdf type="roughconductor" id="rc_gold"><string name="material" value="Au"/>'
               '<string name="distribution" value="GGX"/><float name="alpha" value="0.3"/>'
               '<boolean name="sample_visible" value="false"/></bsdf>',
    "rc_aniso": '<bsdf type="roughconductor" id="rc_aniso"><rgb name="eta" value="0.2 0.9 1.1"/>'
                '<spectrum name="k" value="2.5"/><float name="alpha_u" value="0.05"/>'
                '<float name="alpha_v" value="0.3"/>'
                '<rgb name="specular_reflectance" value="0.9"/></bsdf>',
    "rc_eta_only": '<bsdf type="roughconductor" id="rc_eta_only"><float name="eta" value="1.2"/>'
                   '<float name="alpha" value="0"/></bsdf>',
    "c_default": '<bsdf type="conductor" id="c_default"/>',
    "c_cr": '<bsdf type="conductor" id="c_cr"><string name="material" value="Cr"/></bsdf>',
    "c_k_only": '<bsdf type="conductor" id="c_k_only"><rgb name="k" value="3 2 1"/></bsdf>',
    "rd_default": '<bsdf type="roughdielectric" id="rd_default"/>',
    "rd_water": '<bsdf type="roughdielectric" id="rd_water"><string name="int_ior" '
                'value="Water"/><float name="ext_ior" value="1.1"/><string name="distribution" '
                'value="ggx"/><float name="alpha_u" value="0.1"/><float name="alpha_v" '
                'value="0.2"/></bsdf>',
    "rp_default": '<bsdf type="roughplastic" id="rp_default"/>',
    "rp_blue": '<bsdf type="roughplastic" id="rp_blue"><rgb name="diffuse_reflectance" '
               'value="0.1 0.2 0.7"/><rgb name="specular_reflectance" value="0.8"/>'
               '<float name="int_ior" value="1.6"/><string name="ext_ior" value="vacuum"/>'
               '<float name="alpha" value="0.25"/><string name="distribution" value="ggx"/>'
               '<boolean name="nonlinear" value="true"/></bsdf>',
}


def test_microfacet_bsdfs_give_the_builder_rows(tmp_path):
    body = SENSOR + "".join(MICROFACET_BSDFS.values())
    imp = mitsuba._Importer(write(tmp_path, body))
    s = imp.run()
    r = rows(s, MICROFACET_BSDFS, imp.b.material_names)
    au, cr, none = NAMED_METALS["Au"], NAMED_METALS["Cr"], NAMED_METALS["none"]
    air, bk7, pp = 1.000277, 1.5046, 1.49
    expect = {   # Mitsuba's defaults: beckmann, alpha 0.1, material "none" (eta 0, k 1)
        "rc_default": dict(kind=ROUGH_CONDUCTOR, alpha=(0.1, 0.1), distribution=BECKMANN,
                           eta=none[0], k=none[1], specular=[1] * 3),
        "rc_gold": dict(kind=ROUGH_CONDUCTOR, alpha=(0.3, 0.3), distribution=GGX, eta=au[0],
                        k=au[1]),
        "rc_aniso": dict(kind=ROUGH_CONDUCTOR, alpha=(0.05, 0.3), distribution=BECKMANN,
                         eta=[0.2, 0.9, 1.1], k=[2.5] * 3, specular=[0.9] * 3),
        "rc_eta_only": dict(kind=ROUGH_CONDUCTOR, alpha=(1e-4, 1e-4), eta=[1.2] * 3,
                            k=[1] * 3),   # Mitsuba's k default with eta; alpha 0 -> 1e-4
        "c_default": dict(kind=MIRROR, eta=none[0], k=none[1], specular=[1] * 3),
        "c_cr": dict(kind=MIRROR, eta=cr[0], k=cr[1], specular=[1] * 3),
        "c_k_only": dict(kind=MIRROR, eta=[0] * 3, k=[3, 2, 1]),
        "rd_default": dict(kind=ROUGH_DIELECTRIC, alpha=(0.1, 0.1), distribution=BECKMANN,
                           ior=bk7 / air, specular=[1] * 3),
        "rd_water": dict(kind=ROUGH_DIELECTRIC, alpha=(0.1, 0.2), distribution=GGX,
                         ior=1.333 / 1.1),
        "rp_default": dict(kind=ROUGH_PLASTIC, alpha=(0.1, 0.1), distribution=BECKMANN,
                           ior=pp / air, diffuse=[0.5] * 3, specular=[1] * 3, nonlinear=False),
        "rp_blue": dict(kind=ROUGH_PLASTIC, alpha=(0.25, 0.25), distribution=GGX, ior=1.6,
                        diffuse=[0.1, 0.2, 0.7], specular=[0.8] * 3, nonlinear=True),
    }
    for name, want in expect.items():
        for key, value in want.items():
            np.testing.assert_allclose(r[name][key], value, rtol=1e-6, atol=1e-7,
                                       err_msg=f"{name}.{key}")


def test_microfacet_parameters_as_mitsuba_reads_them(tmp_path):
    """Each <bsdf> above, loaded by Mitsuba 3 itself: the same alpha, distribution, eta, k, ior,
    reflectances and nonlinear flag as jgi's rows (Mitsuba's defaults are what it applies)."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    imp = mitsuba._Importer(write(tmp_path, SENSOR + "".join(MICROFACET_BSDFS.values())))
    r = rows(imp.run(), MICROFACET_BSDFS, imp.b.material_names)

    def value(params, key):
        return np.ravel(np.asarray(params[key], float)) if key in params else None

    for name, xml in MICROFACET_BSDFS.items():
        bsdf = mi.load_string(xml.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
        text, params = str(bsdf), mi.traverse(bsdf)
        mine = r[name]
        dist = re.search(r"distribution = (\w+)", text)
        if dist:
            assert (dist.group(1) == "beckmann") == (mine["distribution"] == BECKMANN), name
        for key, ours in (("alpha", mine["alpha"][0]), ("alpha.value", mine["alpha"][0]),
                          ("alpha_u.value", mine["alpha"][0]),
                          ("alpha_v.value", mine["alpha"][1]),
                          ("eta.value", mine["eta"]), ("k.value", mine["k"]),
                          ("diffuse_reflectance.value", mine["diffuse"]),
                          ("specular_reflectance.value", mine["specular"])):
            theirs = value(params, key)
            if theirs is not None:   # Mitsuba clamps alpha to 1e-4 where it uses it
                theirs = np.maximum(theirs, 1e-4) if key.startswith("alpha") else theirs
                ours = np.atleast_1d(ours)
                np.testing.assert_allclose(np.broadcast_to(theirs, ours.shape), ours, rtol=1e-5,
                                           err_msg=f"{name}: {key}")
        if "eta" in params:   # dielectrics: the relative index
            np.testing.assert_allclose(value(params, "eta"), mine["ior"], rtol=1e-6,
                                       err_msg=name)
        nl = re.search(r"nonlinear = (\d)", text)
        if nl:
            assert bool(int(nl.group(1))) == mine["nonlinear"], name


ANISO = ('<bsdf type="roughconductor" id="brushed"><float name="alpha_u" value="0.05"/>'
         '<float name="alpha_v" value="0.3"/></bsdf>')


@pytest.mark.parametrize("shape, ok", [
    ('<shape type="rectangle"><ref id="brushed"/></shape>', True),   # dp/du = x = jgi's s
    ('<shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-90"/>'
     '</transform><ref id="brushed"/></shape>', True),                # Cornell's right wall
    ('<shape type="rectangle"><transform name="to_world"><rotate z="1" angle="90"/>'
     '</transform><ref id="brushed"/></shape>', False),               # dp/du = y, jgi's s = x
    ('<shape type="obj"><string name="filename" value="tri.obj"/><ref id="brushed"/>'
     '<boolean name="face_normals" value="true"/></shape>', True),   # p1 - p0 = x = jgi's s
    ('<shape type="obj"><string name="filename" value="tri2.obj"/><ref id="brushed"/>'
     '<boolean name="face_normals" value="true"/></shape>', False),  # p1 - p0 = y
    ('<shape type="obj"><string name="filename" value="uv.obj"/><ref id="brushed"/>'
     '<boolean name="face_normals" value="true"/></shape>', False),
    ('<shape type="sphere"><ref id="brushed"/></shape>', False),
    # (twosided nests only BSDFs without transmission, in Mitsuba and here)
    ('<shape type="cube"><bsdf type="twosided"><bsdf type="roughconductor">'
     '<float name="alpha_u" value="0.05"/><float name="alpha_v" value="0.3"/></bsdf></bsdf>'
     '</shape>', False),
])
def test_anisotropy_only_where_the_frames_agree(tmp_path, shape, ok):
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "tri2.obj").write_text("v 0 0 0\nv 0 1 0\nv -1 0 0\nf 1 2 3\n")
    (tmp_path / "uv.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                                     "f 1/1 2/2 3/3\n")
    path = write(tmp_path, SENSOR + ANISO + shape)
    if ok:
        assert load_mitsuba_xml(path).materials.alpha_v.max() == pytest.approx(0.3)
    else:
        with pytest.raises(SceneError, match=r"is anisotropic \(alpha_u != alpha_v\), and") as e:
            load_mitsuba_xml(path)
        assert f"{path}:2:" in str(e.value)


@pytest.mark.parametrize("shape, origin", [
    ({"type": "rectangle"}, [0.2, 0.3, 5]),
    ({"type": "rectangle", "to_world": "rotate_y"}, [5, 0.3, 0.2]),
    ({"type": "obj", "filename": "tri.obj", "face_normals": True}, [0.2, 0.2, 5]),
    ({"type": "obj", "filename": "tri2.obj", "face_normals": True}, [-0.2, 0.2, 5]),
])
def test_mitsubas_tangent_is_the_one_the_importer_assumes(tmp_path, shape, origin):
    """Mitsuba 3's own shading tangent (si.sh_frame.s at a ray hit) against the importer's
    rule: jgi's tangent on the accepted shapes, something else on the refused tri2.obj."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    (tmp_path / "tri2.obj").write_text("v 0 0 0\nv 0 1 0\nv -1 0 0\nf 1 2 3\n")
    shape = dict(shape)
    if "filename" in shape:
        shape["filename"] = str(tmp_path / shape["filename"])
    if shape.get("to_world") == "rotate_y":   # the Cornell box's left wall: normal +x
        shape["to_world"] = mi.ScalarTransform4f().rotate([0, 1, 0], 90)
    scene = mi.load_dict({"type": "scene", "shape": shape})
    target = np.zeros(3) if shape["type"] == "rectangle" else np.array([origin[0], origin[1], 0])
    d = target - np.array(origin, float)
    d /= np.linalg.norm(d)
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*[float(x) for x in origin]),
                                      mi.Vector3f(*[float(x) for x in d])))
    n = np.ravel(np.asarray(si.n))
    theirs = np.ravel(np.asarray(si.sh_frame.s))
    ours, _ = _common.tangent_frame(n)
    same = abs(float(np.dot(theirs, ours))) > 1 - 1e-5
    assert same == ("tri2" not in shape.get("filename", "")), (theirs, ours)


def test_material_preview_scene_loads_in_jgi_and_mitsuba():
    """scenes/material_preview.xml (docs/scene-format.md): rough gold, rough plastic, rough
    aluminium on a rough-plastic floor. Rendered against Mitsuba 3 at 32 x 32, 32 x 64 spp,
    it agreed within |t| = 0.85 over the whole image and 2.98 over 4 x 4 regions."""
    path = Path(__file__).resolve().parents[1] / "scenes" / "material_preview.xml"
    s = jgi.load_scene(path, resolution=8)
    assert s.materials.kinds == (0, ROUGH_CONDUCTOR, ROUGH_PLASTIC)
    assert s.spheres.count == 2 and s.triangles.count == 2304 and s.lights.environment >= 0
    mi = load_mitsuba()
    if mi is not None:
        assert len(mi.load_file(str(path)).shapes()) == 5


def test_missing_sensor(tmp_path):
    with pytest.raises(SceneError, match="no <sensor>"):
        load_mitsuba_xml(write(tmp_path, '<shape type="rectangle"/>'))


def test_meshes_shade_smooth_unless_face_normals(tmp_path):
    """Mitsuba shades OBJ/PLY meshes with vertex normals (the file's, or computed ones when it
    has none) unless face_normals is true: so does jgi (tests/test_shading_normals.py compares
    the normals with Mitsuba's)."""
    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0.2 1\n"
                                      "f 1//1 2//1 3//1\n")
    body = SENSOR + '<shape type="obj"><string name="filename" value="tri.obj"/></shape>'
    s = load_mitsuba_xml(write(tmp_path, body))
    assert s.has_shading_normals
    np.testing.assert_allclose(np.asarray(s.triangles.normals).reshape(3, 3),
                               np.tile([0, 0.2, 1] / np.sqrt(1.04), (3, 1)), atol=1e-6)
    (tmp_path / "bare.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    body = SENSOR + '<shape type="obj"><string name="filename" value="bare.obj"/></shape>'
    s = load_mitsuba_xml(write(tmp_path, body, "bare.xml"))
    assert s.has_shading_normals   # computed: a single triangle's are its face normal
    np.testing.assert_allclose(np.asarray(s.triangles.normals).reshape(3, 3),
                               np.tile([0, 0, 1.0], (3, 1)), atol=1e-6)
    body = SENSOR + ('<shape type="obj"><string name="filename" value="tri.obj"/>'
                     '<boolean name="face_normals" value="true"/></shape>')
    s = load_mitsuba_xml(write(tmp_path, body, "flat.xml"))
    assert s.triangles.count == 1 and not s.has_shading_normals
    # an emitter shades flat: accepted where its vertex normals are its face normals
    body = SENSOR + ('<shape type="obj"><string name="filename" value="bare.obj"/>'
                     '<emitter type="area"/></shape>')
    assert not load_mitsuba_xml(write(tmp_path, body, "em.xml")).has_shading_normals
    body = SENSOR + ('<shape type="obj"><string name="filename" value="tri.obj"/>'
                     '<emitter type="area"/></shape>')
    with pytest.raises(SceneError, match="area emitter shaded with vertex normals"):
        load_mitsuba_xml(write(tmp_path, body, "em2.xml"))


def test_cornell_box_renders_like_mitsuba(tmp_path):
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    xml = tmp_path / "cb.xml"
    xml.write_text(CORNELL_XML.read_text().replace('value="256"', 'value="16"'))
    scene_mi = mi.load_file(str(xml))
    ours = load_mitsuba_xml(xml)
    seeds = range(16)
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=32, seed=s))[..., :3] for s in seeds])
    mine = np.stack([jgi.render(ours, "pt", spp=32, seed=s, max_depth=8, rr_depth=5)
                     for s in seeds])
    assert_agree(mine, theirs, regions=4, label="jgi vs Mitsuba 3")


def _compare_with_mitsuba(tmp_path, xml_path, label):
    """32 independent 256-spp renders (16 x 16 pixels) by jgi's path tracer and by Mitsuba's
    path integrator (max_depth 8, Russian roulette from depth 5 in both), compared per 4 x 4
    pixel region and over the whole image (Welch's t per channel, Bonferroni-corrected).

    Measured (Mitsuba 3.9.1 llvm_ad_rgb, jgi CPU): at this sample count the regions detect a
    relative difference of about 5 % (median over regions; more in the darkest), the whole
    image about 2.5 %; with 32 x 512 spp the whole-image means agreed within 0.22 % (rough
    plastic / conductors, |t| <= 0.63) and 0.13 % (rough glass, |t| <= 0.41)."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    xml = tmp_path / xml_path.name
    xml.write_text(xml_path.read_text())
    scene_mi = mi.load_file(str(xml))
    ours = load_mitsuba_xml(xml)
    seeds, spp = range(32), 256
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=spp, seed=s))[..., :3]
                       for s in seeds])
    mine = np.stack([jgi.render(ours, "pt", spp=spp, seed=s, max_depth=8, rr_depth=5)
                     for s in seeds])
    t4 = assert_agree(mine, theirs, regions=4, label=f"{label} (4 x 4 regions)")
    t1 = assert_agree(mine, theirs, regions=1, label=f"{label} (whole image)")
    print(f"{label}: max |t| = {t4.max():.2f} over 48 region-channels, "
          f"{t1.max():.2f} over the 3 image channels")


def test_rough_plastic_and_conductors_renders_like_mitsuba(tmp_path):
    _compare_with_mitsuba(tmp_path, DATA / "cornell_box_rough_mitsuba.xml",
                          "roughplastic / roughconductor / conductor vs Mitsuba 3")


def test_rough_dielectric_renders_like_mitsuba(tmp_path):
    _compare_with_mitsuba(tmp_path, DATA / "cornell_box_rough_glass_mitsuba.xml",
                          "roughdielectric vs Mitsuba 3")


def test_textured_ply_and_cube_load(tmp_path):
    """A textured PLY mesh takes its file's uv (Mitsuba's names, v as written), a textured
    cube becomes Mitsuba's cube mesh (uv per face), an untextured cube stays a box."""

    ply_quad(tmp_path / "q.ply", ("texture_u", "texture_v"))
    body = SENSOR + """
    <texture type="checkerboard" id="c"/>
    <bsdf type="diffuse" id="t"><ref name="reflectance" id="c"/></bsdf>
    <shape type="ply"><string name="filename" value="q.ply"/><ref id="t"/></shape>
    <shape type="cube"><ref id="t"/></shape>
    <shape type="cube"><transform name="to_world"><translate x="3"/></transform></shape>
    <emitter type="point"><point name="position" x="0" y="3" z="3"/></emitter>"""
    scene = load_mitsuba_xml(write(tmp_path, body))
    assert (scene.triangles.count, scene.boxes.count) == (2 + 12, 1)
    uv = np.asarray(scene.triangles.uv)
    np.testing.assert_allclose(uv[0], [0.1, 0.2, 0.8, -0.1, 0.7, 0.5], atol=1e-6)
    np.testing.assert_allclose(uv[2:, :2].reshape(6, 2, 2)[:, 0], [[0, 1]] * 6)


def test_textured_roughness_and_dielectric_tint(tmp_path):
    """Textured alpha_u / alpha_v (each alone, or both) and a dielectric whose reflectance and
    transmittance are one texture: the builder's texture columns; an isotropic textured alpha
    keeps alpha_v following alpha_u (no alpha_v column); a texture on one tint alone is refused. A
    checkerboard roughness is Mitsuba 3.9.1's eval_1 of it, which exchanges color0 and color1
    (mitsuba.load_dict of a checkerboard: eval_1 gives color1 where eval gives color0)."""
    from jgi.scene.tables import TEX_ALPHA, TEX_ALPHA_V, TEX_SPECULAR

    def load(bsdfs):
        shapes = "".join(f'<shape type="rectangle"><ref id="{i}"/></shape>'
                         for i in re.findall(r'id="(b\d)"', bsdfs))
        return load_mitsuba_xml(write(tmp_path, SENSOR + '<texture type="checkerboard" id="c"/>'
                                      '<texture type="checkerboard" id="d"/>' + bsdfs + shapes))

    iso = load('<bsdf type="roughconductor" id="b0"><ref name="alpha" id="c"/></bsdf>')
    assert iso.materials.textured == (TEX_ALPHA,)
    aniso = load('<bsdf type="roughconductor" id="b0"><ref name="alpha_u" id="c"/>'
                 '<float name="alpha_v" value="0.3"/></bsdf>'
                 '<bsdf type="roughdielectric" id="b1"><float name="alpha_u" value="0.2"/>'
                 '<ref name="alpha_v" id="d"/></bsdf>'
                 '<bsdf type="roughconductor" id="b2"><ref name="alpha" id="d"/></bsdf>'
                 '<bsdf type="dielectric" id="b3"><ref name="specular_reflectance" id="c"/>'
                 '<ref name="specular_transmittance" id="c"/></bsdf>')
    m = aniso.materials
    assert m.textured == (TEX_SPECULAR, TEX_ALPHA, TEX_ALPHA_V)
    np.testing.assert_array_equal(np.asarray(m.texture)[:, [TEX_SPECULAR, TEX_ALPHA,
                                                            TEX_ALPHA_V]],
                                  [[-1, 2, -1], [-1, -1, 3], [-1, 3, 3], [0, -1, -1]])
    # roughness reads Mitsuba's checkerboard eval_1: a twin with the colours exchanged
    tex = m.textures
    np.testing.assert_allclose([float(tex.color0.x[2]), float(tex.color1.x[2])], [0.2, 0.4])
    np.testing.assert_allclose(np.asarray(m.alpha_v)[:2], [0.3, 0.1])
    np.testing.assert_allclose(np.asarray(m.alpha_u)[:2], [0.1, 0.2])
    with pytest.raises(SceneError, match="dielectric: a textured specular_reflectance or "
                                         "specular_transmittance must be one texture for both"):
        load('<bsdf type="dielectric" id="b0"><ref name="specular_reflectance" id="c"/></bsdf>')


def test_smooth_plastic_renders_like_mitsuba(tmp_path):
    """Mitsuba's smooth ``plastic`` (defaults; nonlinear with a tinted coating and int_ior 1.7;
    a checkerboard base with a named int_ior; int_ior 2.2): its Dirac coating reflection shows
    the lamp in the floor and the walls in the box and ball."""
    _compare_with_mitsuba(tmp_path, DATA / "cornell_box_plastic_mitsuba.xml",
                          "plastic vs Mitsuba 3")


# --- <path>, twosided, integrator wrappers, spot falloff, to_uv (issue 31) ---------------------

def _triangle_obj(path, z):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(f"v 0 0 {z}\nv 1 0 {z}\nv 0 1 {z}\nf 1 2 3\n")


@pytest.mark.parametrize("body, expected_z", [
    ('<path value="a"/><path value="b"/>' + '<shape type="obj">'
     '<string name="filename" value="m.obj"/></shape>', [2.0]),          # the latest <path> wins
    ('<path value="b"/><path value="a"/><shape type="obj">'
     '<string name="filename" value="m.obj"/></shape>', [1.0]),
    ('<path value="a"/><path value="x"/><shape type="obj">'             # x is found in a
     '<string name="filename" value="m.obj"/></shape>', [5.0]),
    ('<path value="c"/><shape type="obj"><string name="filename" value="only.obj"/></shape>'
     '<include filename="inc.xml"/>', [7.0, 9.0]),                       # inc.xml found in c
    ('<include filename="d/inc.xml"/>', [0.0]),      # not in d/: the included file's folder
])
def test_path_elements_resolve_files_as_mitsuba(tmp_path, body, expected_z):
    """Relative file names are looked up in the <path> folders, the latest first, then in the
    scene file's folder, for <include>d files too (whose own folder is not searched): the same
    triangle as Mitsuba 3.9.1 loads in each case."""
    for sub, z in (("", 0), ("a", 1), ("b", 2), ("a/x", 5), ("c", 9), ("d", 11)):
        _triangle_obj(tmp_path / sub / "m.obj", z)
    _triangle_obj(tmp_path / "c" / "only.obj", 7)
    for sub in ("c", "d"):
        (tmp_path / sub / "inc.xml").write_text(
            '<scene version="3.0.0"><shape type="obj"><string name="filename" value="m.obj"/>'
            '</shape></scene>')
    path = write(tmp_path, SENSOR + body)
    ours = load_mitsuba_xml(path)
    assert sorted(np.unique(np.asarray(ours.triangles.v0.z)).tolist()) == expected_z
    mi = load_mitsuba()
    if mi is not None:
        theirs = sorted(float(s.bbox().min.z) for s in mi.load_file(str(path)).shapes())
        assert theirs == expected_z


def test_path_refusals_name_the_file_and_line(tmp_path):
    path = write(tmp_path, SENSOR + '\n<path value="nowhere"/>')
    with pytest.raises(SceneError, match=rf"{re.escape(str(path))}:3: <path> folder 'nowhere' "
                                         "does not exist"):
        load_mitsuba_xml(path)
    path = write(tmp_path, SENSOR + '\n<include filename="missing.xml"/>')
    with pytest.raises(SceneError, match=r":3: included file 'missing.xml' does not exist"):
        load_mitsuba_xml(path)


TWOSIDED = SENSOR + """
<bsdf type="roughplastic" id="p"><rgb name="diffuse_reflectance" value="0.2,0.4,0.6"/></bsdf>
<bsdf type="diffuse" id="q"/>
"""


@pytest.mark.parametrize("inner, message", [
    ('<ref id="p"/>', None),
    ('<ref id="p"/><ref id="p"/>', None),                       # the same BSDF on both sides
    ('<bsdf type="roughconductor"/>', None),
    ('<bsdf type="twosided"><bsdf type="plastic"/></bsdf>', None),
    ('<ref id="p"/><ref id="q"/>', "two different BSDFs"),
    ('<bsdf type="dielectric"/>', "Mitsuba nests only materials without transmission"),
    ('<ref id="p"/><ref id="p"/><ref id="p"/>', "one or two nested BSDFs"),
    ('<ref id="nope"/>', "unknown bsdf 'nope'"),
])
def test_twosided_around_any_opaque_bsdf(tmp_path, inner, message):
    """twosided is Mitsuba's: one BSDF (nested or a <ref>) on both sides (a two-sided jgi
    material; unwrapped, Mitsuba's reflective BSDFs are one-sided); two different ones
    (front, back), transmissive ones (Mitsuba refuses them too) and more than two are
    refused."""
    path = write(tmp_path, TWOSIDED + f'<shape type="rectangle"><bsdf type="twosided">{inner}'
                                      '</bsdf></shape>')
    if message is None:
        s = load_mitsuba_xml(path)
        assert s.rects.count == 1
        mi = load_mitsuba()
        if mi is not None:
            mi.load_file(str(path))   # Mitsuba accepts it too
    else:
        with pytest.raises(SceneError, match=rf"{re.escape(str(path))}:\d+: .*{message}"):
            load_mitsuba_xml(path)


def test_twosided_ref_is_the_referenced_material(tmp_path):
    s = load_mitsuba_xml(write(tmp_path, TWOSIDED + '<bsdf type="twosided" id="t"><ref id="p"/>'
                                                    '</bsdf><shape type="rectangle"><ref id="t"/>'
                                                    '</shape>'))
    assert int(s.materials.kind[int(s.rects.material[0])]) == ROUGH_PLASTIC


@pytest.mark.parametrize("integrator, expected", [
    ('', mitsuba.IntegratorSettings("path")),
    ('<integrator type="path"><integer name="max_depth" value="8"/></integrator>',
     mitsuba.IntegratorSettings("path", 8)),
    ('<default name="d" value="6"/><integrator type="moment"><integrator type="aov">'
     '<string name="aovs" value="dd:depth"/><integrator type="volpath">'
     '<integer name="max_depth" value="$d"/><integer name="rr_depth" value="3"/>'
     '<boolean name="hide_emitters" value="true"/></integrator></integrator></integrator>',
     mitsuba.IntegratorSettings("volpath", 6, 3, True, ("moment", "aov"))),
    ('<integrator type="aov"><string name="aovs" value="nn:sh_normal"/></integrator>',
     mitsuba.IntegratorSettings(None, wrappers=("aov",))),
])
def test_integrator_settings_read_through_moment_and_aov(tmp_path, integrator, expected):
    """The moment and aov wrappers are read through to the nested integrator's max_depth,
    rr_depth and hide_emitters (Mitsuba's defaults where absent); the scene loads as before."""
    path = write(tmp_path, integrator + SENSOR)
    assert mitsuba.read_mitsuba_integrator(path) == expected
    assert load_mitsuba_xml(path).camera.width == 8


def test_integrator_wrapper_with_two_integrators_is_refused(tmp_path):
    path = write(tmp_path, SENSOR + '\n<integrator type="moment"><integrator type="path"/>'
                                    '<integrator type="direct"/></integrator>')
    with pytest.raises(SceneError, match=r":3: integrator 'moment': jgi reads through exactly "
                                         "one nested <integrator>, got 2"):
        mitsuba.read_mitsuba_integrator(path)


SPOT_XML = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="60"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent"/>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
            <rfilter type="box"/></film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="3"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf>
    </shape>
    <emitter type="spot">
        <rgb name="intensity" value="5, 4, 3"/>
        <float name="cutoff_angle" value="40"/>
        BEAM
        <transform name="to_world"><lookat origin="0.3, 0.2, 1.2" target="0.6, -0.1, 0"
            up="0, 1, 0"/></transform>
    </emitter>
</scene>
"""
SPOT_POS, SPOT_TARGET = np.array([0.3, 0.2, 1.2]), np.array([0.6, -0.1, 0.0])
RHO, INTENSITY = np.array([0.6, 0.5, 0.4]), np.array([5.0, 4.0, 3.0])


def mitsuba_spot_falloff(cos_theta, cutoff_deg, beam_deg):
    """Mitsuba 3's spot.cpp falloff_curve, in float64: 1 inside beam_width, then linear in the
    angle down to 0 at cutoff_angle."""
    c, b = np.radians(cutoff_deg), np.radians(beam_deg)
    theta = np.arccos(np.clip(cos_theta, -1, 1))
    ramp = np.where(cos_theta >= np.cos(b), 1.0, (c - theta) / max(c - b, 1e-300))
    return np.where(cos_theta > np.cos(c), ramp, 0.0)


def _spot_scene(tmp_path, beam):
    xml = tmp_path / "spot.xml"
    xml.write_text(SPOT_XML.replace("BEAM", "" if beam is None else
                                    f'<float name="beam_width" value="{beam}"/>'))
    return xml


def _spot_plane_radiance(points, cutoff, beam):
    """Radiance leaving the diffuse plane z = 0 towards any direction at ``points`` [N, 3]:
    rho / pi * I * falloff * cos / d^2 (direct light only: a plane cannot see itself)."""
    to_light = SPOT_POS - points
    d2 = np.sum(to_light**2, 1)
    d = np.sqrt(d2)
    axis = (SPOT_TARGET - SPOT_POS) / np.linalg.norm(SPOT_TARGET - SPOT_POS)
    fall = mitsuba_spot_falloff(-(to_light / d[:, None]) @ axis, cutoff, beam)
    cos_plane = to_light[:, 2] / d
    return RHO / np.pi * INTENSITY * (fall * cos_plane / d2)[:, None]


@pytest.mark.parametrize("beam", [None, 10.0, 0.0])
def test_spot_falloff_is_mitsubas(tmp_path, beam):
    """A Mitsuba spot light (beam_width absent: Mitsuba's 3/4 of cutoff_angle; 10 degrees; 0)
    gives jgi's light sampler I * falloff / d^2 with Mitsuba's falloff, linear in the angle
    between beam_width and cutoff_angle: equal to the closed form and to Mitsuba's own
    sample_direction at points across the whole ramp."""
    from tests.support.light_samplers import sample_li_from_uniforms, uniforms
    xml = _spot_scene(tmp_path, beam)
    lights = load_mitsuba_xml(xml).lights
    assert bool(lights.spot_linear[0])
    axis = (SPOT_TARGET - SPOT_POS) / np.linalg.norm(SPOT_TARGET - SPOT_POS)
    s, t = _common.tangent_frame(axis)
    angles = np.radians(np.linspace(0.0, 45.0, 91))
    dist = 1.3
    xs = SPOT_POS + dist * (np.cos(angles)[:, None] * axis + np.sin(angles)[:, None]
                            * (0.6 * s + 0.8 * t))
    out = {k: np.asarray(v) for k, v in sample_li_from_uniforms(
        lights, np.float32(xs), uniforms(3, 3, len(xs))).items()}
    fall = mitsuba_spot_falloff(np.cos(angles), 40.0, 30.0 if beam is None else beam)
    assert np.sum((fall > 0) & (fall < 1)) >= 10   # the ramp is sampled
    np.testing.assert_allclose(out["Li"], INTENSITY * fall[:, None] / dist**2, rtol=2e-5,
                               atol=1e-5)
    mi = load_mitsuba(vectorized=True)
    if mi is not None:
        emitter = mi.load_file(str(xml)).emitters()[0]
        it = mi.Interaction3f()
        it.p = mi.Point3f(*(xs.T.astype(np.float32)))
        _, spec = emitter.sample_direction(it, mi.Point2f(0.5, 0.5))
        theirs = np.stack([np.asarray(spec[c]) for c in range(3)], 1)
        np.testing.assert_allclose(out["Li"], theirs, rtol=2e-4, atol=1e-5)


def test_spot_emission_power_closed_form(tmp_path):
    """Light paths leave the Mitsuba spot with weights whose mean is its power,
    2 pi I (1 + (sin beam - sin cutoff) / (cutoff - beam)) for the falloff linear in the angle
    (the closed form of 2 pi int falloff(theta) sin(theta) d theta)."""
    from tests.support.light_samplers import sample_emission
    lights = load_mitsuba_xml(_spot_scene(tmp_path, 10.0)).lights
    e = sample_emission(lights, seed=21)
    c, b = np.radians(40.0), np.radians(10.0)
    power = 2 * np.pi * INTENSITY * (1 + (np.sin(b) - np.sin(c)) / (c - b))
    m, se = e["weight"].mean(0), e["weight"].std(0) / np.sqrt(len(e["weight"]))
    t = np.abs(m - power) / se
    assert np.all(t < critical_t(len(e["weight"]) - 1, 3)), (m, power, t)


def _spot_closed_form_image(cam, cutoff, beam, n=64):
    """The pixel averages of the closed-form radiance (n x n midpoints per pixel): the camera
    looks straight down at z = 0 from height 3, so a film point (sx, sy) sees the plane at
    position + 3 (forward + sx right + sy up)."""
    W, H = cam.width, cam.height
    pos = np.array([float(c) for c in cam.position])
    right = np.array([float(c) for c in cam.right])
    up = np.array([float(c) for c in cam.up])
    forward = np.array([float(c) for c in cam.forward])
    g = (np.arange(n) + 0.5) / n
    img = np.zeros((H, W, 3))
    for py in range(H):
        sy = 1.0 - 2.0 * (py + g) / H
        for px in range(W):
            sx = 2.0 * (px + g) / W - 1.0
            SX, SY = np.meshgrid(sx, sy)
            pts = pos + 3.0 * (forward + SX.reshape(-1, 1) * right + SY.reshape(-1, 1) * up)
            img[py, px] = _spot_plane_radiance(pts, cutoff, beam).mean(0)
    return img


@pytest.mark.parametrize("estimator", ["pt", "lt"])
def test_spot_plane_renders_the_closed_form(tmp_path, estimator):
    """A diffuse plane under a Mitsuba spot (default beam_width, its ramp crossing the image):
    jgi's path and light tracers' pixel means agree with the closed form
    rho / pi * I * falloff * cos / d^2 averaged over each pixel, per 4 x 4 region (Welch's t
    with the renders' standard error from 16 seeds)."""
    xml = _spot_scene(tmp_path, None)
    ours = load_mitsuba_xml(xml)
    assert float(ours.camera.forward.z) == pytest.approx(-1.0)
    ref = _spot_closed_form_image(ours.camera, 40.0, 30.0)
    mine = np.stack([jgi.render(ours, estimator, spp=16, seed=s, max_depth=3)
                     for s in range(16)])
    t = assert_agree(mine, np.stack([ref, ref]), regions=4,
                     label=f"{estimator} vs closed form (spot)")
    print(f"spot plane, {estimator} vs closed form: max |t| = {t.max():.2f}; image mean "
          f"{mine.mean():.5f} vs {ref.mean():.5f}")


def test_spot_renders_like_mitsuba(tmp_path):
    """The same spot-lit plane rendered by Mitsuba 3 and by jgi's path tracer: per 4 x 4 region
    (Welch's t, both sides' standard errors from 16 seeds)."""
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    xml = _spot_scene(tmp_path, None)
    scene_mi = mi.load_file(str(xml))
    theirs = np.stack([np.asarray(mi.render(scene_mi, spp=16, seed=s))[..., :3]
                       for s in range(16)])
    mine = np.stack([jgi.render(load_mitsuba_xml(xml), "pt", spp=16, seed=s, max_depth=3)
                     for s in range(16)])
    t = assert_agree(mine, theirs, regions=4, label="spot: jgi vs Mitsuba 3")
    print(f"spot plane vs Mitsuba: max |t| = {t.max():.2f}; means {mine.mean():.5f} vs "
          f"{theirs.mean():.5f}")


@pytest.mark.parametrize("to_uv", [
    '<rotate z="1" angle="30"/><translate x="0.25" y="0.1"/><scale x="3" y="2"/>',
    '<matrix value="2 0.5 0 0.3  0.1 3 0 -0.2  0 0 1 0  0 0 0 1"/>',
    '<matrix value="2 0.5 0.25  0.1 3 0.7  0.2 0.3 1.5"/>',   # 3 x 3: its third column dropped
])
def test_texture_to_uv_maps_as_mitsubas(tmp_path, to_uv):
    """A checkerboard's to_uv (composed operations, a 4 x 4 and a 3 x 3 matrix) maps texture
    coordinates as Mitsuba's: jgi's texture equals Mitsuba's eval at 4096 random (u, v), but
    for points within 1e-4 of a checker edge (float rounding decides there)."""
    from jgi.physics import textures
    path = write(tmp_path, SENSOR + f"""
    <shape type="rectangle"><bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
        <rgb name="color0" value="0.9, 0.6, 0.1"/><rgb name="color1" value="0.1, 0.5, 0.2"/>
        <transform name="to_uv">{to_uv}</transform></texture></bsdf></shape>""")
    ours = load_mitsuba_xml(path)
    rng = np.random.default_rng(7)
    u, v = rng.uniform(-1, 2, 4096), rng.uniform(-1, 2, 4096)
    tex, row = ours.materials.textures, np.zeros(u.shape, np.int32)
    mine = np.asarray(textures.evaluate(tex, row, (np.float32(u), np.float32(v))).stack())
    mu, mv = textures.map_uv(tex, row, u, v)
    frac = np.stack([np.asarray(mu) % 0.5, np.asarray(mv) % 0.5])
    clear = np.all(np.minimum(frac, 0.5 - frac) > 1e-4, axis=0)
    assert clear.mean() > 0.99
    mi = load_mitsuba(vectorized=True)
    if mi is None:
        pytest.skip("mitsuba is not installed")
    bsdf = mi.load_file(str(path)).shapes()[0].bsdf()
    si = mi.SurfaceInteraction3f()
    si.uv = mi.Point2f(np.float32(u), np.float32(v))
    theirs = np.stack([np.asarray(c) for c in bsdf.eval_diffuse_reflectance(si)], 1)
    np.testing.assert_allclose(mine[clear], theirs[clear], rtol=1e-6)


def _serialized_mesh(v, f, normals=None, uv=None, colors=None, face_normals=False,
                     double=False, version=4, name="mesh"):
    """One mesh in Mitsuba's documented serialized layout (little endian: uint16 0x041C,
    uint16 version, then zlib: uint32 flags, [v4: name], uint64 counts, arrays, uint32 faces)."""
    import struct
    import zlib
    flags = ((0x1 if normals is not None else 0) | (0x2 if uv is not None else 0)
             | (0x8 if colors is not None else 0) | (0x10 if face_normals else 0)
             | (0x2000 if double else 0x1000))
    body = struct.pack("<I", flags) + (name.encode() + b"\0" if version == 4 else b"")
    body += struct.pack("<QQ", len(v), len(f))
    for a in (v, normals, uv, colors):
        if a is not None:
            body += np.asarray(a, "<f8" if double else "<f4").tobytes()
    body += np.asarray(f, "<u4").tobytes()
    return struct.pack("<HH", 0x041C, version) + zlib.compress(body)


def _serialized_file(meshes, version=4):
    """Meshes concatenated, then their offsets and count (the end-of-file dictionary)."""
    import struct
    out, offsets = b"", []
    for m in meshes:
        offsets.append(len(out))
        out += m
    return out + np.asarray(offsets, "<u8" if version == 4 else "<u4").tobytes() + \
        struct.pack("<I", len(meshes))


def _icosphere():
    import trimesh
    s = trimesh.creation.icosphere(subdivisions=1)
    v = np.asarray(s.vertices, float)
    uv = np.stack([0.5 + np.arctan2(v[:, 1], v[:, 0]) / (2 * np.pi), 0.5 + 0.5 * v[:, 2]], 1)
    return v, np.asarray(s.faces), np.asarray(s.vertex_normals, float) * 1.7, uv


SERIALIZED_MESHES = [
    dict(),                                              # positions only: smooth normals
    dict(normals=True, uv=True, double=True),            # the file's normals, uv
    dict(normals=True, colors=True, face_normals=True),  # colours skipped; flag ignored
]


@pytest.mark.parametrize("version", [3, 4])
@pytest.mark.parametrize("index", range(len(SERIALIZED_MESHES)))
@pytest.mark.parametrize("face_normals", [False, True])
def test_serialized_meshes_read_as_mitsuba(tmp_path, version, index, face_normals):
    """A multi-mesh .serialized file (Mitsuba's documented format, versions 3 and 4, single and
    double precision, with and without normals, uv, colours): shape_index picks the mesh, and
    the triangles' corners, shading normals (Mitsuba's smooth ones where the file has none;
    none with face_normals) and uv after a non-uniform to_world are the vertex buffers Mitsuba
    3 loads from the same file (positions and normals to float32 rounding)."""
    v, f, n, uv = _icosphere()
    meshes = []
    for i, kw in enumerate(SERIALIZED_MESHES):
        meshes.append(_serialized_mesh(
            v + i, f, normals=n if kw.get("normals") else None,
            uv=uv if kw.get("uv") else None, colors=np.abs(v) if kw.get("colors") else None,
            face_normals=kw.get("face_normals", False), double=kw.get("double", False),
            version=version))
    (tmp_path / "m.serialized").write_bytes(_serialized_file(meshes, version))
    fn = '<boolean name="face_normals" value="true"/>' if face_normals else ""
    path = write(tmp_path, SENSOR + f"""
    <texture type="checkerboard" id="c"/>
    <shape type="serialized"><string name="filename" value="m.serialized"/>
        <integer name="shape_index" value="{index}"/>{fn}
        <transform name="to_world"><scale x="2" y="1" z="0.5"/><rotate x="0.6" y="0.8"
            angle="25"/><translate x="0.3"/></transform>
        <bsdf type="diffuse"><ref name="reflectance" id="c"/></bsdf></shape>""")
    ours = load_mitsuba_xml(path)
    t = ours.triangles
    corners = np.stack([t.v0.stack(), t.v0.stack() + t.edge1.stack(),
                        t.v0.stack() + t.edge2.stack()], 1)
    assert corners.shape == (len(f), 3, 3)
    mi = load_mitsuba()
    if mi is None:
        pytest.skip("mitsuba is not installed")
    shape = mi.load_file(str(path)).shapes()[0]
    params = mi.traverse(shape)
    faces = np.asarray(params["faces"]).reshape(-1, 3)
    pos = np.asarray(params["vertex_positions"]).reshape(-1, 3)
    np.testing.assert_allclose(corners, pos[faces], atol=2e-6)
    if face_normals:
        assert t.normals is None
    else:
        nrm = np.asarray(params["vertex_normals"]).reshape(-1, 3)[faces].reshape(-1, 9)
        np.testing.assert_allclose(np.asarray(t.normals), nrm, atol=2e-6)
    tuv = np.asarray(t.uv)
    mine_uv = np.stack([tuv[:, :2], tuv[:, :2] + tuv[:, 2:4], tuv[:, :2] + tuv[:, 4:6]], 1)
    if shape.has_vertex_texcoords():
        theirs_uv = np.asarray(params["vertex_texcoords"]).reshape(-1, 2)[faces]
    else:   # Mitsuba's (0,0), (1,0), (0,1) per triangle
        theirs_uv = np.broadcast_to([[0, 0], [1, 0], [0, 1]], mine_uv.shape)
    np.testing.assert_allclose(mine_uv, theirs_uv, atol=1e-6)


@pytest.mark.parametrize("data, index, message", [
    (b"\x1c\x05\x04\x00" + b"\0" * 8, 0, "not a serialized file"),
    (b"\x1c\x04\x05\x00" + b"\0" * 8, 0, "version 5 is not supported"),
    ("two", 2, r"shape_index 2 is out of range: the file holds 2 meshes \(0..1\)"),
    ("two", -1, "shape_index must be an integer >= 0"),
    ("cut", 0, "truncated or malformed|cannot decompress"),
])
def test_serialized_refusals(tmp_path, data, index, message):
    v, f, _, _ = _icosphere()
    one = _serialized_mesh(v, f)
    data = {"two": _serialized_file([one, one]), "cut": one[:60]}.get(data, data)
    (tmp_path / "m.serialized").write_bytes(data)
    path = write(tmp_path, SENSOR + f"""
    <shape type="serialized"><string name="filename" value="m.serialized"/>
        <integer name="shape_index" value="{index}"/></shape>""")
    with pytest.raises(SceneError, match=rf"{re.escape(str(path))}:\d+: .*({message})"):
        load_mitsuba_xml(path)


def test_rotation_about_a_non_unit_axis_is_mitsubas(tmp_path):
    """Mitsuba 3 rotates about the axis as given (c I + (1 - c) a a^T + s [a]x, not normalised:
    a non-unit axis scales and shears): the same vertices as Mitsuba's; a mesh whose file
    normals Mitsuba would move as if by a rotation is refused."""
    v, f, n, _ = _icosphere()
    (tmp_path / "m.serialized").write_bytes(_serialized_file([_serialized_mesh(v, f)]))
    (tmp_path / "n.serialized").write_bytes(_serialized_file([_serialized_mesh(v, f, n)]))
    shape = ('<shape type="serialized"><string name="filename" value="{}"/><transform '
             'name="to_world"><rotate x="1" y="1" angle="25"/><translate x="0.3"/></transform>'
             '</shape>')
    path = write(tmp_path, SENSOR + shape.format("m.serialized"))
    t = load_mitsuba_xml(path).triangles
    mi = load_mitsuba()
    if mi is not None:
        params = mi.traverse(mi.load_file(str(path)).shapes()[0])
        pos = np.asarray(params["vertex_positions"]).reshape(-1, 3)
        np.testing.assert_allclose(t.v0.stack(), pos[np.asarray(params["faces"])[::3]],
                                   atol=2e-6)
    with pytest.raises(SceneError, match=r":\d+: serialized mesh 'n.serialized': its to_world "
                                         "rotates about a non-unit axis"):
        load_mitsuba_xml(write(tmp_path, SENSOR + shape.format("n.serialized"), "n.xml"))


def test_area_emitter_by_reference(tmp_path):
    """A shape may <ref> a top-level area emitter with an id, defined before or after it (as in
    Mitsuba's documentation scenes): the scene is the one with the emitter nested."""
    emitter = '<emitter type="area" id="e"><rgb name="radiance" value="3,2,1"/></emitter>'
    shape = '<shape type="rectangle">{}</shape>'
    nested = load_mitsuba_xml(write(tmp_path, SENSOR + shape.format(emitter.replace(
        ' id="e"', "")), "a.xml"))
    for body in (shape.format('<ref id="e"/>') + emitter, emitter + shape.format('<ref id="e"/>')):
        leaves_equal(load_mitsuba_xml(write(tmp_path, SENSOR + body, "b.xml")), nested)
    with pytest.raises(SceneError, match=r":\d+: an area emitter must be nested in a shape, or "
                                         "have an id"):
        load_mitsuba_xml(write(tmp_path, SENSOR + emitter.replace(' id="e"', ""), "c.xml"))
