"""Option parsing the bench commands share: name lists, number lists, the run's metadata."""
from __future__ import annotations

import math

from ..errors import ConfigError
from . import common


def _names(text: str | None, allowed, what: str) -> list[str] | None:
    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ConfigError(f"--{what} needs at least one name")
    unknown = [n for n in names if n not in allowed]
    if unknown:
        raise ConfigError(f"unknown {what[:-1] if what.endswith('s') else what} {unknown[0]!r} "
                          f"(choose from {', '.join(allowed)})")
    return names


def _integrator_names(text: str | None) -> list[str]:
    """The integrators of ``--integrators`` (default: every built-in): registry names, installed
    plug-ins or ``module:Class`` specs, each resolved now so that a bad one is a ConfigError
    before any work."""
    from ..integrators import INTEGRATORS, integrator_class

    if text is None:
        return list(INTEGRATORS)
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise ConfigError("--integrators needs at least one name")
    for name in names:
        integrator_class(name)
    return names


def _meta(name: str, args, config: dict) -> dict:
    return {"benchmark": name, "command": common.command_line(), "quick": bool(args.quick),
            "machine": common.machine_info(), "config": config,
            "note": "timings come from a machine that may be shared with other work: compare them "
                    "within one run, not across runs"}


def _float_list(text: str | None, what: str, default) -> list[float]:
    if text is None:
        return list(default)
    try:
        values = [_fraction(v) for v in text.split(",") if v.strip()]
    except (ValueError, ZeroDivisionError):
        raise ConfigError(f"--{what} expects comma-separated numbers, got {text!r}") from None
    if not values or not all(math.isfinite(v) and v > 0 for v in values):
        raise ConfigError(f"--{what} expects finite numbers > 0, got {text!r}")
    return values


def _fraction(text: str) -> float:
    """``"1/60"`` or ``"0.5"`` as a float (ValueError otherwise)."""
    top, sep, bottom = text.strip().partition("/")
    return float(top) / float(bottom) if sep else float(top)


def _fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        if math.isinf(value):
            return "unbounded"
        return f"{value:.6g}"
    return str(value)
