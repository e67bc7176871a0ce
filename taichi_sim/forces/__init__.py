"""Force terms a particle system composes: gravity, drag, springs with dashpots, wind, grab."""
from .base import ForceTerm
from .drag import Drag
from .grab import GrabSpring
from .gravity import Gravity
from .springs import SPRING_KINDS, Springs, incidence, incidence_of
from .wind import Wind

__all__ = ["ForceTerm", "Gravity", "Drag", "Springs", "Wind", "GrabSpring", "SPRING_KINDS", "incidence",
           "incidence_of"]
