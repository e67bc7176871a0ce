"""Geometry checks on positions alone (numpy, exact predicates): independent of the solvers."""
from .intersections import IntersectionReport, self_intersections

__all__ = ["IntersectionReport", "self_intersections"]
