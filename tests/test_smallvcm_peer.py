"""The SmallVCM peer of the bidirectional benchmark: its scene in jgi and the patched build copy."""

from __future__ import annotations

import numpy as np
import pytest

import jgi
from experiments.bench import smallvcm


def test_smallvcm_box_is_smallvcms_scene():
    """The light box's emitting face points down with SmallVCM's radiance and area, and the
    balls stand on its floor where its LoadCornellBox puts them."""
    from jgi.scene.builtin import SMALLVCM_BOX

    scene = jgi.load_scene("smallvcm_box", resolution=8)
    lights = scene.lights
    assert scene.camera.width == 8 and lights.count == 2              # two emitting triangles
    np.testing.assert_allclose(np.stack(lights.emission, -1), 25.03329895614464, rtol=1e-6)
    np.testing.assert_allclose(np.stack(lights.normal, -1), [[0, 0, -1]] * 2, atol=1e-6)
    np.testing.assert_allclose(np.asarray(lights.area).sum(), 0.25, rtol=1e-6)
    floor = SMALLVCM_BOX[:, 2].min()
    bottoms = np.asarray(scene.spheres.center.z) - np.asarray(scene.spheres.radius)
    np.testing.assert_allclose(bottoms, floor, atol=1e-5)


def test_the_build_copy_adds_the_scene_and_a_seed(tmp_path):
    """The benchmark edits a copy of SmallVCM's config (the peer's folder stays unchanged):
    one more scene configuration and the base seed from SMALLVCM_SEED."""
    origin = smallvcm.source_folder() / "src"
    if not (origin / "config.hxx").is_file():
        pytest.skip(f"no SmallVCM source at {origin}")
    before = (origin / "config.hxx").read_text()
    (tmp_path / "config.hxx").write_text(before)
    smallvcm._patch(tmp_path)
    text = (tmp_path / "config.hxx").read_text()
    table = text[text.index("g_SceneConfigs[]"):]
    table = table[:table.index("};")]
    assert table.count("Scene::kLight") == smallvcm.SCENE_ID + 1
    assert table.rstrip().endswith(smallvcm.CONFIG)
    assert 'getenv("SMALLVCM_SEED")' in text
    assert (origin / "config.hxx").read_text() == before
