"""The estimator registry: every estimator, its parameters and their defaults, in one table.

An estimator registers a :class:`Estimator` whose ``run(scene, spp=, seed=, **params)`` returns a
float32 linear-radiance image of shape (H, W, 3) as a numpy array. ``jgi.render`` and the CLI
validate parameters against the declared :class:`Param` list, so a typo is an error naming the
parameter and the allowed ones, never a silently ignored keyword.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from ..core.errors import ParameterError


@dataclass(frozen=True)
class Param:
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


@dataclass(frozen=True)
class Estimator:
    name: str
    summary: str
    run: Callable[..., Any]
    params: tuple[Param, ...] = field(default_factory=tuple)

    def resolve(self, given: dict) -> dict:
        """Defaults overlaid with ``given``, each value checked; unknown keys are refused."""
        known = {p.name: p for p in self.params}
        unknown = sorted(set(given) - set(known))
        if unknown:
            raise ParameterError(
                f"estimator '{self.name}' has no parameter {', '.join(map(repr, unknown))}; "
                f"allowed: {', '.join(sorted(known)) or '(none)'}"
            )
        out = {p.name: p.default for p in self.params}
        for k, v in given.items():
            out[k] = known[k].check(self.name, v)
        return out

    def describe(self) -> str:
        lines = [f"{self.name}: {self.summary}"]
        for p in self.params:
            extra = f" one of {list(p.choices)}" if p.choices else ""
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
