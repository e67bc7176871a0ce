"""The cloth's continuum terms (the membrane and its bending, :mod:`taichi_sim.forces.membrane`)
as forces of the equation a step solves: the numpy force model of :mod:`.residual` holds
springs, so these come from the terms themselves at the state measured, as a
:class:`~taichi_sim.integrators.equation.SolveForces` (forces, and the PSD-projected stiffness
the implicit methods solve with: the membrane's per-triangle blocks, the bending's constant
stencil blocks D w_a w_b I, or the hinge models' Gauss-Newton blocks per element)."""

import numpy as np
import scipy.sparse as sp
import taichi as ti

from ..integrators.equation import SolveForces, element_stiffness

MODELLED_TERMS = ("membrane", "bending")


@ti.kernel
def _forces(term: ti.template(), y: ti.template(), mass: ti.template(), t: float, out: ti.types.ndarray()):
    for i in range(out.shape[0]):
        f = term.force(i, y, mass[i], t)
        for a in ti.static(range(3)):
            out[i, a] = f[a]


@ti.kernel
def _membrane_blocks(term: ti.template(), y: ti.template(), a: float, b: float):
    term.precompute_jacobian(y, a, b)


def continuum_terms(system) -> list:
    """The system's terms this module measures (membrane, bending), in its order."""
    return [term for term in getattr(system, "terms", ()) if term.name in MODELLED_TERMS]


def term_forces(system, terms, y, tau: float, t: float) -> SolveForces:
    """The terms' forces (N) at state ``y`` (positions and velocities of the stage measured) and
    their stiffness -(df/dx + df/dv / tau) (N/m), for a stage of ``tau`` s ending at ``t`` s."""
    n = system.particle_count
    force = np.zeros((n, 3))
    stiffness = sp.csr_matrix((3 * n, 3 * n))
    for term in terms:
        f = np.zeros((n, 3), np.float64)
        _forces(term, y, system.mass, t, f)
        force += f
        if term.name == "membrane":
            _membrane_blocks(term, y, 1.0 / tau, 1.0)
            blocks = -term.triangle_block.to_numpy().astype(np.float64)  # (T, 3, 3, 3, 3)
            corners = term.triangles_np
        elif getattr(term, "precomputes_jacobian", False):  # hinge bending: (E, W, W, 3, 3)
            _membrane_blocks(term, y, 1.0 / tau, 1.0)
            blocks = -term.element_block.to_numpy().astype(np.float64)
            corners = term.vertices_np
        else:
            w = term.weights_np.astype(np.float64)
            blocks = (term.stiffness_value * w[:, :, None, None, None] * w[:, None, :, None, None]
                      * np.eye(3)[None, None, None])
            corners = term.vertices_np
        stiffness = stiffness + element_stiffness(corners, blocks, n)
    return SolveForces(force, stiffness)


def combined(a, b):
    """The sum of two sets of forces (either may be None)."""
    if a is None or b is None:
        return a if b is None else b
    return SolveForces(a.force + b.force, a.stiffness + b.stiffness)
