"""Springs: the general spring-list term (``term``), its Jacobians for the implicit methods
(``jacobian``), the incidence it gathers over (``topology``) and the stencil fast path for
regular grids (``grid``)."""
from .term import SPRING_KINDS, Springs
from .topology import incidence, incidence_of

__all__ = ["SPRING_KINDS", "Springs", "incidence", "incidence_of"]
