"""Helpers the tests share, imported as a package (``from tests.support.stats import
assert_agree``): statistics, directions, Mitsuba, and scenes with known answers. Test modules
import these, never each other; ``tests/conftest.py`` holds only pytest's settings and
fixtures. The samplers of warps, BSDFs, lights and cameras (``*_samplers``) are shared with the
paper's chi-square table (paper/chi2_table.py), which imports them from here too."""
