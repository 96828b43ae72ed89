"""Scene importers for other renderers' formats (the subset jgi represents exactly)."""

from .mitsuba import load_mitsuba_xml  # noqa: F401
from .pbrt import load_pbrt  # noqa: F401
