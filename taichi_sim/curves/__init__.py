"""Curves: scene parameters over time (a monotone cubic spline per parameter), their JSON
files, and the driver that applies them to a running scene."""
from .drive import CurveDriver
from .files import (
                    FORMAT,
                    MAX_POINTS,
                    VERSION,
                    Curves,
                    check_curves,
                    curves_json,
                    load_curves,
                    parse_curves,
                    save_curves,
)
from .spline import Spline

__all__ = ["CurveDriver", "Curves", "FORMAT", "MAX_POINTS", "Spline", "VERSION", "check_curves",
           "curves_json", "load_curves", "parse_curves", "save_curves"]
