"""Scene loading: built-in names and TOML files (format documented in docs/scene-format.md)."""

from __future__ import annotations

from pathlib import Path

from . import scenes
from .scene import Scene, SceneError


def load_scene(source: str | Path, **kwargs) -> Scene:
    src = str(source)
    if src in scenes.BUILTINS:
        return scenes.get(src, **kwargs)
    raise SceneError(f"{src}: not a built-in scene ({', '.join(scenes.BUILTINS)}) and not a scene file")
