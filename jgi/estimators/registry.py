"""The estimator registry: every estimator, its parameters and their defaults, in one table.

An estimator's parameters are declared once, as fields of its configuration: a frozen dataclass
whose fields made with :func:`param` carry the default, a one-line doc, and the allowed range or
choices (the field's annotation, ``bool``, ``int``, ``float`` or ``str``, is the type)::

    @dataclass(frozen=True)
    class PathTracerConfig:
        heuristic: str = param("balance", "MIS heuristic", choices=("balance", "power"))
        power: float = param(2.0, "power-heuristic exponent", minimum=0.1, maximum=16)
        ...

Fields made without :func:`param` are settings a Python caller may change but the registry does
not offer. ``Estimator(name, summary, run, Config)`` derives its :class:`Param` list from the
class (:func:`params_of`), and :meth:`Estimator.resolve` turns user input into a ``Config``,
every value checked, so a typo is an error naming the estimator, the key and what is allowed,
never a silently ignored keyword; a key in ``renamed`` is an error naming its new name.

``run(scene, cfg, *, spp, seed, progress)`` returns a :class:`Render`: the float32 linear-radiance
image (H, W, 3) and a dict of the estimator's statistics (acceptance rates, photon counts, ...;
empty where it has none). ``jgi.render`` returns the image, ``jgi.render_result`` the Render.
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, NamedTuple

import numpy as np

from ..core.errors import ParameterError

_METADATA_KEY = "jgi.param"
_TYPES = (bool, int, float, str)


class Render(NamedTuple):
    """What every registered estimator returns."""

    image: np.ndarray   # (H, W, 3) float32 linear radiance
    stats: dict         # estimator statistics (see each estimator's ``render``); {} if none


class _Spec(NamedTuple):
    doc: str
    choices: tuple | None
    minimum: float | None
    maximum: float | None


def param(default: Any, doc: str, *, choices=None, minimum: float | None = None,
          maximum: float | None = None) -> Any:
    """A Config field that is an estimator parameter: ``name: type = param(default, doc, ...)``.

    ``minimum`` / ``maximum`` bound a number (inclusive), ``choices`` lists the allowed values."""
    spec = _Spec(doc, tuple(choices) if choices is not None else None, minimum, maximum)
    return field(default=default, metadata={_METADATA_KEY: spec})


@dataclass(frozen=True)
class Param:
    """One parameter of an estimator, as derived from its Config field (:func:`params_of`)."""

    name: str
    default: Any
    doc: str
    type: type = float
    choices: tuple | None = None
    minimum: float | None = None
    maximum: float | None = None

    def check(self, estimator: str, value: Any) -> Any:
        where = f"estimator '{estimator}', parameter '{self.name}'"
        if self.type is bool:
            if not isinstance(value, bool):
                raise ParameterError(f"{where}: expected true/false, got {value!r}")
            return value
        if self.type in (int, float):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ParameterError(f"{where}: expected a number, got {value!r}")
            if self.type is int and float(value) != int(value):
                raise ParameterError(f"{where}: expected an integer, got {value!r}")
            value = self.type(value)
            if self.minimum is not None and value < self.minimum:
                raise ParameterError(f"{where}: {value} is below the minimum {self.minimum}")
            if self.maximum is not None and value > self.maximum:
                raise ParameterError(f"{where}: {value} is above the maximum {self.maximum}")
        if self.choices is not None and value not in self.choices:
            raise ParameterError(f"{where}: {value!r} is not one of {list(self.choices)}")
        if self.type is str and not isinstance(value, str):
            raise ParameterError(f"{where}: expected a string, got {value!r}")
        return value


def params_of(config: type) -> tuple[Param, ...]:
    """The parameters a Config dataclass declares with :func:`param`, in field order."""
    if not (isinstance(config, type) and dataclasses.is_dataclass(config)):
        raise TypeError(f"{config!r} is not a dataclass")
    hints = typing.get_type_hints(config)
    out = []
    for f in dataclasses.fields(config):
        spec = f.metadata.get(_METADATA_KEY)
        if spec is None:
            continue
        kind = hints[f.name]
        if kind not in _TYPES:
            raise TypeError(f"{config.__name__}.{f.name}: a parameter is bool, int, float or str, "
                            f"not {kind!r}")
        out.append(Param(f.name, f.default, spec.doc, kind, spec.choices, spec.minimum,
                         spec.maximum))
    return tuple(out)


@dataclass(frozen=True)
class Estimator:
    """A registered estimator: ``run(scene, cfg, *, spp, seed, progress) -> Render`` with ``cfg``
    an instance of ``config``, whose :func:`param` fields are the parameters. ``renamed`` maps
    former parameter names to current ones; ``check(cfg)`` (optional) refuses combinations of
    values that each field's range cannot express, raising :class:`ParameterError`."""

    name: str
    summary: str
    run: Callable[..., Render]
    config: type
    renamed: Mapping[str, str] = field(default_factory=dict, hash=False)
    check: Callable[[Any], None] | None = field(default=None, compare=False)
    media: bool = False      # renders scenes filled by a homogeneous participating medium
    grid_media: bool = False  # and by a heterogeneous (grid) one
    params: tuple[Param, ...] = field(init=False)

    def __post_init__(self):
        params = params_of(self.config)
        object.__setattr__(self, "params", params)
        names = {p.name for p in params}
        for p in params:   # a default outside its own range is a declaration error
            p.check(self.name, p.default)
        for old, new in self.renamed.items():
            if old in names or new not in names:
                raise ValueError(f"estimator '{self.name}': renamed {old!r} -> {new!r} must map a "
                                 "former name to a current parameter")

    def refuse_media(self, scene) -> None:
        """A :class:`ParameterError` if the scene has a participating medium this estimator
        does not render (rather than an image that silently ignores the medium)."""
        if getattr(scene, "has_medium", False) and not self.media:
            able = ", ".join(e.name for e in REGISTRY.values() if e.media) or "none"
            raise ParameterError(
                f"estimator '{self.name}' does not render participating media (yet), and the "
                f"scene '{scene.name}' has one; estimators that do: {able}")
        if getattr(scene, "has_grid_medium", False) and not self.grid_media:
            able = ", ".join(e.name for e in REGISTRY.values() if e.grid_media) or "none"
            raise ParameterError(
                f"estimator '{self.name}' does not render heterogeneous (grid) media (yet), and "
                f"the scene '{scene.name}' is filled by one; estimators that do: {able}")

    def lookup(self, key: str) -> Param:
        """The parameter ``key``; a former name or an unknown key is a :class:`ParameterError`
        naming the new name, or the allowed ones."""
        for p in self.params:
            if p.name == key:
                return p
        self._refuse([key])
        raise AssertionError("unreachable")

    def _refuse(self, keys: list[str]) -> None:
        old = [k for k in keys if k in self.renamed]
        if old:
            raise ParameterError(f"estimator '{self.name}': " + "; ".join(
                f"parameter '{k}' was renamed '{self.renamed[k]}'" for k in old))
        if keys:
            raise ParameterError(
                f"estimator '{self.name}' has no parameter {', '.join(map(repr, keys))}; "
                f"allowed: {', '.join(sorted(p.name for p in self.params)) or '(none)'}"
            )

    def resolve(self, given: Mapping[str, Any]) -> Any:
        """The Config for ``given``: every value checked, the defaults elsewhere; former names
        and unknown keys are refused."""
        known = {p.name: p for p in self.params}
        self._refuse(sorted(set(given) - set(known)))
        cfg = self.config(**{k: known[k].check(self.name, v) for k, v in given.items()})
        if self.check is not None:
            self.check(cfg)
        return cfg

    def describe(self) -> str:
        lines = [f"{self.name}: {self.summary}"]
        for p in self.params:
            extra = f" one of {list(p.choices)}" if p.choices else ""
            if p.minimum is not None and p.maximum is not None:
                extra += f" in [{p.minimum:g}, {p.maximum:g}]"
            elif p.minimum is not None:
                extra += f" >= {p.minimum:g}"
            elif p.maximum is not None:
                extra += f" <= {p.maximum:g}"
            lines.append(f"    {p.name} = {p.default!r}{extra}  -- {p.doc}")
        return "\n".join(lines)


REGISTRY: dict[str, Estimator] = {}


def register(est: Estimator) -> Estimator:
    if est.name in REGISTRY:
        raise ValueError(f"estimator '{est.name}' is registered twice")
    REGISTRY[est.name] = est
    return est


def get(name: str) -> Estimator:
    try:
        return REGISTRY[name]
    except KeyError:
        raise ParameterError(
            f"unknown estimator '{name}'; registered: {', '.join(sorted(REGISTRY))}"
        ) from None
