"""How far a step's result is from the equations its method claims to solve: the residual
(:mod:`.residual`, the share of the forces left unbalanced), the distance in metres
(:mod:`.distance`) and the monitor that samples both during a run (:mod:`.monitor`)."""
from .distance import DistanceModel
from .monitor import DEFAULT_TOLERANCE, ConvergenceMonitor, check_tolerance, format_metres
from .residual import (
    BUDGET,
    DEFAULT_MAX_RESIDUAL,
    FLOOR_MARGIN,
    MAX_FLOOR,
    ForceModel,
    check_max_residual,
    relative_residual,
    rounding_floor,
    unmodelled,
)

__all__ = ["BUDGET", "DEFAULT_MAX_RESIDUAL", "DEFAULT_TOLERANCE", "FLOOR_MARGIN", "MAX_FLOOR",
           "ConvergenceMonitor", "DistanceModel", "ForceModel", "check_max_residual", "check_tolerance",
           "format_metres", "relative_residual", "rounding_floor", "unmodelled"]
