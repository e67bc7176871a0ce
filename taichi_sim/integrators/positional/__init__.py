"""Position-level solvers for stiff springs at large steps: XPBD (compliant constraints,
Gauss-Seidel on a colouring) and projective dynamics (local/global, one prefactorised matrix)."""
from .projective import ProjectiveDynamics
from .xpbd import XPBD

__all__ = ["ProjectiveDynamics", "XPBD"]
