from __future__ import annotations

import taichi as ti

from .. import runtime
from .base import ForceTerm


@ti.data_oriented
class Drag(ForceTerm):
    """Viscous drag -k_drag * v_i (k_drag in N s/m, a 0-D field so it can change at run time)."""

    name = "drag"

    def __init__(self, k_drag: float):
        self.k = ti.field(runtime.real(), shape=())
        self.set(k_drag)

    def set(self, k_drag: float) -> None:
        self.k[None] = float(k_drag)

    def get(self) -> float:
        return float(self.k[None])

    @ti.func
    def force(self, i, y, mass_i):
        return -self.k[None] * y.v[i]
