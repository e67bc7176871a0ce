"""Curves files: a small versioned JSON document of control points per scene parameter.

Schema (version 1)::

    {"format": "taichi-sim curves", "version": 1,
     "scene": "sprinkler",                       # optional: the scene the curves were made for
     "curves": {"rate": [[0.0, 100.0], [1.5, 900.0], [3.0, 0.0]],   # [t (s), value] pairs
                "spread": [[0.0, 5.0], [3.0, 30.0]]}}

Each curve is a :class:`~taichi_sim.curves.spline.Spline`: times finite, >= 0 and strictly
increasing; values finite and allowed by the parameter (its minimum); 1 to MAX_POINTS points.
The file is parsed with ``json`` only (never evaluated or unpickled); anything else raises
:class:`~taichi_sim.errors.ConfigError` naming the culprit.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any

from ..errors import ConfigError, unknown_name
from .spline import Spline

FORMAT = "taichi-sim curves"
VERSION = 1
MAX_POINTS = 64  # per curve: an editor's worth; more is a data file, not a curve
MAX_BYTES = 1 << 20  # a curves file larger than this is not one

Curves = dict[str, Spline]


def _reject_constant(text: str):
    raise ConfigError(f"{text} is not a number a curves file may hold")


def _no_duplicates(pairs: list[tuple[str, Any]]) -> dict:
    keys = [k for k, _ in pairs]
    dup = {k for k in keys if keys.count(k) > 1}
    if dup:
        raise ConfigError(f"key {sorted(dup)[0]!r} given twice")
    return dict(pairs)


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{what} must be a number, got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ConfigError(f"{what} must be finite, got {value}")
    return value


def check_points(name: str, points: Any) -> Spline:
    """A spline from ``points`` ([[t, value], ...]) or ConfigError naming curve ``name``."""
    if not isinstance(points, list) or not points:
        raise ConfigError(f"curve {name}: give a non-empty list of [t, value] points")
    if len(points) > MAX_POINTS:
        raise ConfigError(f"curve {name}: {len(points)} points, at most {MAX_POINTS}")
    pts = []
    for k, pair in enumerate(points):
        if not isinstance(pair, list) or len(pair) != 2:
            raise ConfigError(f"curve {name}: point {k} must be a [t, value] pair, got {pair!r}")
        t = _number(pair[0], f"curve {name}: point {k} time")
        v = _number(pair[1], f"curve {name}: point {k} value")
        if t < 0:
            raise ConfigError(f"curve {name}: point {k} time must be >= 0, got {t}")
        if pts and t <= pts[-1][0]:
            raise ConfigError(f"curve {name}: times must increase strictly (point {k}: {t} after {pts[-1][0]})")
        pts.append((t, v))
    return Spline(tuple(pts))


def check_curves(curves: Curves, preset) -> Curves:
    """Check curves against a scene preset: each names one of its numeric parameters that can
    change while it runs, and every control value is allowed for it (its minimum; the spline
    never leaves the range of its control values, so the whole curve is then allowed)."""
    from ..scene.live import LIVE_SETTERS

    params = {p.name: p for p in preset.params}
    for name, spline in curves.items():
        p = params.get(name)
        if p is None:
            raise ConfigError(f"curve {name}: " + unknown_name(f"scene {preset.name!r} has no parameter",
                                                               name, params))
        if p.kind not in (int, float) or name not in LIVE_SETTERS:
            live = ", ".join(n for n in LIVE_SETTERS if n in params and params[n].kind in (int, float))
            raise ConfigError(f"curve {name}: parameter {name!r} cannot change while {preset.name} runs "
                              f"(curves can drive: {live or 'none'})")
        for v in spline.values:
            try:
                p.check(float(v) if p.kind is float else round(v))
            except ConfigError as exc:
                raise ConfigError(f"curve {name}: {exc}") from None
    return curves


def curves_from_document(doc: Any, preset=None) -> Curves:
    """Curves from a parsed JSON document (checked against ``preset`` when given)."""
    if not isinstance(doc, dict):
        raise ConfigError("a curves file holds a JSON object")
    unknown = set(doc) - {"format", "version", "scene", "curves"}
    if unknown:
        raise ConfigError(f"unknown key {sorted(unknown)[0]!r} in a curves file")
    if doc.get("format") != FORMAT:
        raise ConfigError(f"not a curves file (\"format\" must be {FORMAT!r})")
    if doc.get("version") != VERSION:
        raise ConfigError(f"curves file version {doc.get('version')!r} is not supported (this reads {VERSION})")
    scene = doc.get("scene")
    if scene is not None and preset is not None and scene != preset.name:
        raise ConfigError(f"the curves were made for scene {scene!r}, not {preset.name!r}")
    raw = doc.get("curves")
    if not isinstance(raw, dict):
        raise ConfigError("\"curves\" must be an object of parameter name -> [[t, value], ...]")
    curves = {str(name): check_points(name, points) for name, points in raw.items()}
    return check_curves(curves, preset) if preset is not None else curves


def parse_curves(text: str, preset=None) -> Curves:
    """Curves from JSON text (see the module's schema)."""
    try:
        doc = json.loads(text, parse_constant=_reject_constant, object_pairs_hook=_no_duplicates)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"not JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except RecursionError:
        raise ConfigError("not a curves file (nested too deeply)") from None
    return curves_from_document(doc, preset)


def load_curves(path: str | os.PathLike, preset=None) -> Curves:
    """Read a curves file; ConfigError (naming the file) for anything wrong with it."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"--curves {path}: cannot read it ({exc.strerror})") from None
    try:
        if len(data) > MAX_BYTES:
            raise ConfigError(f"larger than {MAX_BYTES} bytes")
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise ConfigError("not UTF-8 text") from None
        return parse_curves(text, preset)
    except ConfigError as exc:
        raise ConfigError(f"--curves {path}: {exc}") from None


def curves_document(curves: Curves, scene: str | None = None) -> dict:
    """The JSON document of ``curves`` (the inverse of :func:`curves_from_document`)."""
    doc: dict[str, Any] = {"format": FORMAT, "version": VERSION}
    if scene is not None:
        doc["scene"] = scene
    doc["curves"] = {name: [[t, v] for t, v in spline.points] for name, spline in curves.items()}
    return doc


def curves_json(curves: Curves, scene: str | None = None) -> str:
    """The curves as one line of JSON (what the npz of a curve-driven run records)."""
    return json.dumps(curves_document(curves, scene), allow_nan=False)


def save_curves(path: str | os.PathLike, curves: Curves, scene: str | None = None) -> Path:
    """Write a curves file atomically (temporary file, then rename). Floats are written with
    ``repr`` precision, so loading gives back identical points."""
    from ..atomic import write_atomically

    text = json.dumps(curves_document(curves, scene), indent=1, allow_nan=False) + "\n"
    return write_atomically(Path(path), lambda f: f.write(text), binary=False)
