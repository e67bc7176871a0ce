"""Systems: ODEs that compute the derivative of any state they are given."""
from .base import System
from .circle import CircleSystem
from .particles import ParticleSystem

__all__ = ["System", "CircleSystem", "ParticleSystem"]
