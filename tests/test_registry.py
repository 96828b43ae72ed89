"""The estimator registry: each estimator's parameters are declared once, as fields of its Config
dataclass, and derived from it; former names are refused naming the new one (jgi.render, TOML
experiment configs, the CLI); estimators return Render(image, stats); random-stream salts live
in one table."""

from __future__ import annotations

import ast
import dataclasses
import inspect
import typing
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import jgi
from jgi import cli
from jgi.core import rng
from jgi.estimators import irradiance_cache, mlt, mmlt, photon_mapping, pssmlt, registry
from jgi.estimators.registry import Estimator, Param, Render, param, params_of
from jgi.experiment import ConfigError, run
from jgi.transport import mcmc, photons, subpath

PACKAGE = Path(jgi.__file__).parent
RENAMED = [  # estimator, former name, current name
    ("pt", "beta", "power"),
    ("bdpt", "beta", "power"),
    ("mmlt", "beta", "power"),
    ("pm", "alpha", "gauss_alpha"),
    ("pm", "beta", "gauss_beta"),
    ("ppm", "alpha", "radius_alpha"),
    ("sppm", "alpha", "radius_alpha"),
]


# --- one schema per estimator ---------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(jgi.REGISTRY))
def test_every_config_field_declared_with_param_is_a_parameter(name):
    est = jgi.REGISTRY[name]
    hints = typing.get_type_hints(est.config)
    declared = [f for f in dataclasses.fields(est.config) if registry._METADATA_KEY in f.metadata]
    assert declared, f"{name}: its Config declares no parameter"
    assert [p.name for p in est.params] == [f.name for f in declared]
    for f, p in zip(declared, est.params):
        spec = f.metadata[registry._METADATA_KEY]
        assert p.default == f.default and type(p.default) is type(f.default), (name, f.name)
        assert (p.doc, p.choices, p.minimum, p.maximum) == tuple(spec), (name, f.name)
        assert p.type is hints[f.name], (name, f.name)
        assert p.doc and p.check(name, p.default) == p.default
    # the defaults are the Config's defaults; no input gives the default Config
    assert est.resolve({}) == est.config()
    assert est.resolve({p.name: p.default for p in est.params}) == est.config()


@pytest.mark.parametrize("name", sorted(jgi.REGISTRY))
def test_nothing_is_declared_twice(name):
    """The run function takes the Config, not the parameters again as keywords."""
    est = jgi.REGISTRY[name]
    sig = inspect.signature(est.run)
    assert list(sig.parameters)[:2] == ["scene", "cfg"]
    assert set(sig.parameters) == {"scene", "cfg", "spp", "seed", "progress"}, (name, sig)


def test_no_parameter_list_is_written_by_hand():
    """Outside the registry no estimator module constructs a Param: all are derived."""
    for path in sorted((PACKAGE / "estimators").glob("*.py")):
        if path.name == "registry.py":
            continue
        calls = [n for n in ast.walk(ast.parse(path.read_text()))
                 if isinstance(n, ast.Call)
                 and getattr(n.func, "id", getattr(n.func, "attr", "")) == "Param"]
        assert not calls, f"{path.name}: Param(...) written by hand"


def test_resolve_returns_the_config_with_checked_values():
    cfg = jgi.REGISTRY["pt"].resolve(dict(heuristic="power", power=3, max_depth=4.0))
    assert cfg == jgi.estimators.path_tracer.PathTracerConfig(heuristic="power", power=3.0,
                                                              max_depth=4)
    assert type(cfg.power) is float and type(cfg.max_depth) is int
    # a setting the registry does not offer stays a field only Python callers set
    assert "s1" not in {p.name for p in jgi.REGISTRY["pssmlt"].params}
    assert pssmlt.PSSMLTConfig().s1 == 1 / 1024


def test_a_config_declares_parameters_with_param():
    @dataclass(frozen=True)
    class Toy:
        n: int = param(3, "a count", minimum=1, maximum=9)
        mode: str = param("a", "a mode", choices=("a", "b"))
        on: bool = param(True, "a switch")
        hidden: float = 0.5

    assert params_of(Toy) == (Param("n", 3, "a count", int, None, 1, 9),
                              Param("mode", "a", "a mode", str, ("a", "b")),
                              Param("on", True, "a switch", bool))
    est = Estimator("toy", "a toy", lambda scene, cfg, *, spp, seed, progress=False: None, Toy,
                    renamed={"count": "n"})
    assert est.resolve(dict(n=5)) == Toy(n=5)
    with pytest.raises(jgi.ParameterError,
                       match=r"estimator 'toy', parameter 'n': 10 is above the maximum 9"):
        est.resolve(dict(n=10))
    with pytest.raises(jgi.ParameterError,
                       match=r"estimator 'toy': parameter 'count' was renamed 'n'"):
        est.resolve(dict(count=5))
    with pytest.raises(jgi.ParameterError,
                       match=r"estimator 'toy' has no parameter 'hidden'; allowed: mode, n, on"):
        est.resolve(dict(hidden=1.0))
    assert "n = 3 in [1, 9]" in est.describe() and "one of ['a', 'b']" in est.describe()


def test_bad_declarations_are_refused_at_registration():
    @dataclass(frozen=True)
    class OutOfRange:
        n: int = param(0, "a count", minimum=1)

    @dataclass(frozen=True)
    class NotAScalar:
        xs: tuple = param((1, 2), "values")

    run_ = lambda scene, cfg, *, spp, seed, progress=False: None  # noqa: E731
    with pytest.raises(jgi.ParameterError, match="below the minimum"):
        Estimator("x", "x", run_, OutOfRange)
    with pytest.raises(TypeError, match="bool, int, float or str"):
        Estimator("x", "x", run_, NotAScalar)

    @dataclass(frozen=True)
    class Fine:
        n: int = param(1, "a count")

    with pytest.raises(ValueError, match="former name to a current parameter"):
        Estimator("x", "x", run_, Fine, renamed={"m": "k"})
    with pytest.raises(ValueError, match="former name to a current parameter"):
        Estimator("x", "x", run_, Fine, renamed={"n": "n"})


def test_cross_field_checks_run_with_validation():
    """mlt's mixture must include large steps: refused by resolve, so experiment configs are
    refused before any rendering too."""
    with pytest.raises(jgi.ParameterError, match="p_large"):
        jgi.REGISTRY["mlt"].resolve(dict(p_large=0.0))
    with pytest.raises(jgi.ParameterError, match="must be positive"):
        jgi.REGISTRY["mlt"].resolve(dict(p_large=0.0, p_lens=0.0, p_caustic=0.0))


# --- former names ---------------------------------------------------------------------------------

@pytest.mark.parametrize("name, old, new", RENAMED)
def test_former_names_are_refused_naming_the_new_one(name, old, new):
    scene = jgi.scenes.furnace(resolution=4)
    message = f"estimator '{name}': parameter '{old}' was renamed '{new}'"
    with pytest.raises(jgi.ParameterError) as err:
        jgi.render(scene, name, spp=1, **{old: 2.0})
    assert str(err.value) == message
    assert dict(jgi.REGISTRY[name].renamed)[old] == new


def test_both_gaussian_names_are_reported_at_once():
    with pytest.raises(jgi.ParameterError) as err:
        jgi.render(jgi.scenes.furnace(resolution=4), "pm", alpha=1.0, beta=2.0)
    assert str(err.value) == ("estimator 'pm': parameter 'alpha' was renamed 'gauss_alpha'; "
                              "parameter 'beta' was renamed 'gauss_beta'")


def test_a_former_name_is_not_a_current_one_elsewhere():
    """'beta' is path throughput only: no estimator has a parameter of that name."""
    for est in jgi.REGISTRY.values():
        assert not {"beta", "alpha"} & {p.name for p in est.params}, est.name


CONFIG = """
[experiment]
name = "renamed"
scene = "furnace"
resolution = 4
repetitions = 2
reference = {{ closed_form = 1.0 }}

[[estimator]]
name = "{name}"
spp = 1
{where}
"""


@pytest.mark.parametrize("where, key", [
    ('params = {{ {old} = 2.0 }}', "estimator[0]"),
    ('sweep = {{ {old} = [1.0, 2.0] }}', "estimator[0]"),
])
@pytest.mark.parametrize("name, old, new",
                         [("pt", "beta", "power"), ("sppm", "alpha", "radius_alpha")])
def test_experiment_configs_name_the_new_key(tmp_path, name, old, new, where, key):
    path = tmp_path / "exp.toml"
    path.write_text(CONFIG.format(name=name, where=where.format(old=old)))
    calls = []
    with pytest.raises(ConfigError) as err:
        run(path, out_root=tmp_path / "runs", render=lambda *a, **k: calls.append(1),
            progress=False)
    message = str(err.value)
    assert str(path) in message and key in message, message
    assert f"estimator '{name}': parameter '{old}' was renamed '{new}'" in message
    assert not calls and not (tmp_path / "runs").exists()


def test_experiment_reference_params_name_the_new_key(tmp_path):
    path = tmp_path / "exp.toml"
    text = CONFIG.format(name="pt", where="").replace(
        "reference = { closed_form = 1.0 }",
        'reference = { estimator = "pt", spp = 4, params = { heuristic = "power", beta = 2.0 } }')
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"experiment\.reference: estimator 'pt': "
                                          r"parameter 'beta' was renamed 'power'"):
        run(path, out_root=tmp_path / "runs", progress=False)


@pytest.mark.parametrize("args", [["-p", "beta=2"], ["--beta", "2"], ["--beta=2"]])
def test_cli_names_the_new_key(args, capsys):
    with pytest.raises(SystemExit) as err:
        cli.main(["render", "furnace", "-e", "pt", "--spp", "1", *args])
    assert str(err.value.code) == "jgi: estimator 'pt': parameter 'beta' was renamed 'power'"


def test_cli_unknown_key_lists_the_allowed_ones():
    with pytest.raises(SystemExit) as err:
        cli.main(["render", "furnace", "-e", "lt", "-p", "depth=2"])
    assert str(err.value.code) == "jgi: estimator 'lt' has no parameter 'depth'; allowed: max_depth"


def test_cli_renders_with_the_new_key(tmp_path, capsys):
    out = tmp_path / "img.exr"
    assert cli.main(["render", "furnace", "-e", "pt", "--spp", "1", "--width", "4", "--height", "4",
                     "--quiet", "-p", "heuristic=power", "-p", "power=3", "--out", str(out)]) == 0
    assert out.exists() and out.with_suffix(".png").exists()


# --- results --------------------------------------------------------------------------------------

def test_render_result_returns_image_and_stats():
    # tests/test_pssmlt.py's settings: its compiled kernels serve this test too
    scene = jgi.scenes.cornell_box(resolution=16)
    params = dict(chains=512, bootstrap_samples=8192, p_large=0.3)
    result = jgi.render_result(scene, "pssmlt", spp=2, seed=1, **params)
    assert isinstance(result, Render) and isinstance(result, tuple)
    image, stats = result
    assert image.dtype == np.float32 and image.shape == (16, 16, 3)
    assert set(stats) == {"b", "acceptance", "mutations"} and stats["mutations"] >= 2 * 16 * 16
    np.testing.assert_array_equal(image, jgi.render(scene, "pssmlt", spp=2, seed=1, **params))
    # the module's render is the registered one
    cfg = pssmlt.PSSMLTConfig(**params)
    np.testing.assert_array_equal(pssmlt.render(scene, cfg, spp=2, seed=1).image, image)
    # estimators without statistics return an empty dict
    assert jgi.render_result(scene, "pt", spp=1).stats == {}


def test_stats_of_photon_mapping_and_the_irradiance_cache():
    # photon counts and sizes of tests/test_photon_mapping.py: its compiled kernels serve here
    scene = jgi.scenes.cornell_box(resolution=16)
    pm = jgi.render_result(scene, "pm", spp=1, photons=10_000, radius=0.15).stats
    assert pm["stored"] > 0
    sppm = jgi.render_result(scene, "sppm", spp=1, passes=2, photons=10_000, radius=0.15,
                             radius_alpha=0.7).stats
    assert 0 < sppm["radius_final"] < 0.15
    scene = jgi.scenes.cornell_box(resolution=8)
    ic = jgi.render_result(scene, "irradiance_cache", spp=1, gather_m=2, gather_n=4, passes=1).stats
    assert ic["records"] > 0 and ic["gather_rays"] == (ic["records"] + ic["direct_points"]) * 8
    assert dataclasses.asdict(irradiance_cache.CacheStats(**ic)) == ic


# --- random-stream salts --------------------------------------------------------------------------

def test_salts_are_one_table_and_distinct_where_streams_meet():
    salts = rng.SALTS
    assert photons._SALT == salts["photons"] and mcmc._SALT == salts["mcmc"]
    assert photon_mapping._SALT == salts["final_gather"] and mlt._SALT == salts["mlt"]
    assert pssmlt._SALT == salts["pssmlt"] and mmlt._SALT == salts["mmlt"]
    assert irradiance_cache._SALT == salts["irradiance_gather"]
    assert subpath.LIGHT_SALT == salts["light_subpath"]
    # every salt an estimator derives with (offsets included), by stream
    used = {"photons": [salts["photons"]], "light_subpath": [salts["light_subpath"]],
            "final_gather": [salts["final_gather"]],
            "irradiance_gather": [salts["irradiance_gather"]],
            "mcmc": [salts["mcmc"]], "pssmlt": [salts["pssmlt"], salts["pssmlt"] + 1],
            "mmlt": [salts["mmlt"] + 1 + L for L in range(1, 17)],
            "mlt": [salts["mlt"], salts["mlt"] + 1],
            "ratio_tracking": [salts["ratio_tracking"] + j for j in range(64)],
            # volume v >= 1 of several, from a flight's or shadow ray's stream (as ratio tracking)
            "grid_volume": [salts["grid_volume"] + v for v in range(1, 64)]}
    assert set(used) == set(salts)
    owner = {}
    for stream, values in used.items():
        for v in values:
            owner.setdefault(v, set()).add(stream)
    shared = {v: s for v, s in owner.items() if len(s) > 1}
    # the one shared value: pm_jensen's final gather and mlt's bootstrap, which no estimate uses
    # together (see jgi.core.rng.SALTS)
    assert shared == {0x1B873593: {"final_gather", "mlt"}}, shared
