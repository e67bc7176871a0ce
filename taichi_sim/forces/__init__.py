"""Force terms a particle system composes: gravity, drag, springs with dashpots, wind, grab,
turbulence."""
from .base import ForceTerm
from .drag import Drag
from .grab import GrabSpring
from .gravity import Gravity
from .springs import SPRING_KINDS, Springs, incidence, incidence_of
from .turbulence import Turbulence
from .wind import Wind

__all__ = ["ForceTerm", "Gravity", "Drag", "Springs", "Wind", "Turbulence", "GrabSpring", "SPRING_KINDS", "incidence",
           "incidence_of"]
