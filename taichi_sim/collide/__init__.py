"""Collision stages that act between steps (after any integrator)."""
from .self_contact import SelfCollision

__all__ = ["SelfCollision"]
