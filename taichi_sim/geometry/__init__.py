"""Geometry checks on positions alone (numpy, exact predicates): independent of the solvers."""
from .inside import inside_objects
from .intersections import IntersectionReport, self_intersections

__all__ = ["IntersectionReport", "inside_objects", "self_intersections"]
