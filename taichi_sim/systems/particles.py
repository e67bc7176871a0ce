"""Particle systems: Newton's second law for particles under composable force terms."""

import numpy as np
import taichi as ti

from .. import runtime
from ..forces.base import ForceTerm
from ..state import State
from .base import System


@ti.data_oriented
class ParticleSystem(System):
    """dx/dt = v, dv/dt = F(x, v, t) / m, with F the sum of the force terms.

    Pinned particles have zero derivative (they neither move nor accelerate), whatever their
    forces.

    Args:
        mass: (n,) particle masses in kg, all > 0.
        pinned: (n,) bool.
        terms: force terms (see :class:`taichi_sim.forces.ForceTerm`); more may be added with
            :meth:`add_term` before the first evaluation (one kernel sums them, compiled then).
    """

    second_order = True

    def __init__(self, mass: np.ndarray, pinned: np.ndarray, terms: list[ForceTerm] = ()):
        mass = np.asarray(mass, dtype=float).reshape(-1)
        pinned = np.asarray(pinned, dtype=bool).reshape(-1)
        if len(mass) != len(pinned):
            raise ValueError("mass and pinned must have the same length")
        if not np.all(mass > 0):
            raise ValueError("mass must be > 0 for every particle")
        self.particle_count = n = len(mass)
        self.mass_np = mass
        self.pinned_np = pinned
        self.terms = list(terms)
        self.mass = ti.field(runtime.real(), shape=n)
        self.free = ti.field(ti.i32, shape=n)
        self.mass.from_numpy(mass.astype(runtime.np_real()))
        self.free.from_numpy((~pinned).astype(np.int32))

    def add_term(self, term: ForceTerm) -> None:
        """Add a force term; only before the first eval_f (its kernel is compiled then)."""
        self.terms.append(term)

    def term(self, name: str) -> ForceTerm | None:
        """The force term called ``name`` (``"gravity"``, ``"drag"``, ``"springs"``), if any."""
        return next((t for t in self.terms if t.name == name), None)

    def eval_f(self, y: State, t: float, out: State) -> None:
        self._eval_f(y, out)

    @ti.kernel
    def _eval_f(self, y: ti.template(), out: ti.template()):
        for i in y.x:
            if self.free[i]:
                m = self.mass[i]
                f = ti.Vector.zero(y.x.dtype, 3)
                for term in ti.static(self.terms):
                    f += term.force(i, y, m)
                out.x[i] = y.v[i]
                out.v[i] = f / m
            else:
                out.x[i] = ti.Vector.zero(y.x.dtype, 3)
                out.v[i] = ti.Vector.zero(y.x.dtype, 3)

    def forces(self, y: State, out: ti.Field) -> None:
        """Net force (N) on every particle at ``y`` into a (n,) vec3 field; zero when pinned."""
        self._forces(y, out)

    @ti.kernel
    def _forces(self, y: ti.template(), out: ti.template()):
        for i in y.x:
            f = ti.Vector.zero(y.x.dtype, 3)
            if self.free[i]:
                for term in ti.static(self.terms):
                    f += term.force(i, y, self.mass[i])
            out[i] = f

    def kinetic_energy(self, y: State) -> float:
        return float(self._kinetic(y))

    @ti.kernel
    def _kinetic(self, y: ti.template()) -> float:
        total = 0.0
        for i in y.v:
            total += 0.5 * self.mass[i] * y.v[i].norm_sqr()
        return total

    def energy(self, y: State) -> float:
        """Kinetic plus the potential energy of every conservative term (J)."""
        total = self.kinetic_energy(y)
        for term in self.terms:
            e = term.energy(y)
            if e is not None:
                total += e
        return total
