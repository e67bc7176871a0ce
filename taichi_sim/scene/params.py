"""Typed, validated scene parameters (what ``taichi-sim list`` prints and ``--set`` sets)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..errors import ConfigError, unknown_name


@dataclass(frozen=True)
class Param:
    """One scene parameter.

    Attributes:
        name: the ``--set`` name.
        default: default value (its Python type is the parameter's type: float, int, bool, str).
        unit: SI unit, or "" for dimensionless.
        meaning: one line for ``taichi-sim list``.
        minimum: smallest allowed value (numbers only).
        exclusive: whether ``minimum`` itself is excluded (e.g. mass > 0).
        choices: allowed values (strings only).
        allow_infinite: whether ``inf`` is a valid value (e.g. an unbreakable tearing threshold).
    """

    name: str
    default: Any
    unit: str
    meaning: str
    minimum: float | None = None
    exclusive: bool = False
    choices: tuple = ()
    allow_infinite: bool = False

    @property
    def kind(self) -> type:
        return type(self.default)

    def parse(self, text: str) -> Any:
        """Convert command-line text to a checked value."""
        kind = self.kind
        try:
            if kind is bool:
                lowered = text.strip().lower()
                if lowered not in ("1", "0", "true", "false", "on", "off", "yes", "no"):
                    raise ValueError
                value = lowered in ("1", "true", "on", "yes")
            elif kind is int:
                value = int(text)
            elif kind is float:
                value = float(text)
            else:
                value = text
        except ValueError:
            raise ConfigError(f"parameter {self.name}: {text!r} is not a valid {kind.__name__}") from None
        return self.check(value)

    def check(self, value: Any) -> Any:
        kind = self.kind
        if kind is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            value = float(value)
        elif kind is int and isinstance(value, float) and value.is_integer():
            value = int(value)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise ConfigError(f"parameter {self.name}: expected {kind.__name__}, got {value!r}")
        if kind is float and not math.isfinite(value) and not (self.allow_infinite and value == math.inf):
            raise ConfigError(f"parameter {self.name}: must be finite, got {value}")
        if self.minimum is not None and kind in (int, float):
            if value < self.minimum or (self.exclusive and value == self.minimum):
                relation = ">" if self.exclusive else ">="
                raise ConfigError(f"parameter {self.name}: must be {relation} {self.minimum:g}, got {value}")
        if self.choices and value not in self.choices:
            raise ConfigError(f"parameter {self.name}: must be one of {', '.join(self.choices)}, got {value!r}")
        return value


# Parameters a scene family replaced: old name -> (the new one, what changed), told to whoever
# still sets the old name on a scene that has the new one.
REPLACED = {
    "particle_mass": ("density", "the grid cloth's mass is per area now: density (kg/m^2, 10.24 gives 0.01 kg a "
                                 "particle at 32 x 32)"),
    "drag": ("area_drag", "the grid cloth's drag is per area now: area_drag (N s/m^3, 5.12 gives 0.005 N s/m a "
                          "particle at 32 x 32)"),
}


def resolve(params: tuple[Param, ...], scene: str, given: dict[str, Any]) -> dict[str, Any]:
    """Defaults overlaid with ``given`` (values checked); unknown names raise ConfigError."""
    by_name = {p.name: p for p in params}
    unknown = [k for k in given if k not in by_name]
    if unknown:
        name = unknown[0]
        if name in REPLACED and REPLACED[name][0] in by_name:
            raise ConfigError(f"scene {scene!r} has no parameter {name!r}: {REPLACED[name][1]}")
        raise ConfigError(unknown_name(f"scene {scene!r} has no parameter", name, by_name))
    values = {p.name: p.default for p in params}
    for name, value in given.items():
        values[name] = by_name[name].parse(value) if isinstance(value, str) and by_name[name].kind is not str \
            else by_name[name].check(value)
    return values


def scene_assignments(assignments: list[tuple[str, str]], flag: str = "--set") -> dict[str, str]:
    """``--set`` (or ``flag``) pairs as a dict; a parameter set twice is an error (which value
    was meant?)."""
    params: dict[str, str] = {}
    for name, value in assignments:
        if name in params:
            raise ConfigError(f"{flag} {name} given twice ({name}={params[name]} and {name}={value}); "
                              "give each parameter once")
        params[name] = value
    return params
