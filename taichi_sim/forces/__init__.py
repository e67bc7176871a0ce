"""Force terms a particle system composes: gravity, viscous drag, springs with dashpots."""
from .base import ForceTerm
from .drag import Drag
from .gravity import Gravity
from .springs import SPRING_KINDS, Springs, incidence

__all__ = ["ForceTerm", "Gravity", "Drag", "Springs", "SPRING_KINDS", "incidence"]
