"""How far a step's result is from the equations its method claims to solve.

A method that solves a system per step (Newton, local/global or Gauss-Seidel iterations)
declares the equation it solves (:class:`Equation`, the integrator's ``equation`` attribute);
explicit methods solve none and are not measured. The measure is the residual of that
equation at the step's result, computed here in float64 with numpy from the states before and
after the step, independently of the solver's own kernels and of the run's precision:

    backward Euler:   r = M (x1 - x0 - h v0) / h^2 - F(x1, v1)   (the gradient of the
                      incremental potential; x1 = x0 + h v1 makes it M (v1 - v0) / h - F)
    implicit midpoint: the same on the midpoint stage, tau = h / 2, at X = (x0 + x1) / 2,
                      V = (v0 + v1) / 2

over the free particles, with F the scene's force model (gravity, drag, springs with their
dashpots, the grab; ``reference.py`` states the same model). Methods that take the forces
other than the springs and the grab at the step's start (projective dynamics, XPBD) declare
``explicit_external``; projective dynamics' dashpots damp the whole relative velocity of a
spring's ends (``isotropic_dashpots``).

The residual is relative: |r| / (|M (x1 - x0 - h v0) / h^2| + |F_internal| + |F_external|),
2-norms over all free particles, i.e. the share of the forces at play that the result leaves
unbalanced. It means the same at every stiffness, step, size and precision: a cloth frozen in
mid-air by single-precision rounding (its springs' forces round to more than gravity) has
about 1, a step solved to a Newton tolerance of 1e-6 about 1e-6 or less.
"""
from __future__ import annotations

import math

import numpy as np

from ..errors import ConfigError
from ..integrators.equation import Equation

#: Default bound on the relative residual (``--max-residual``): see :func:`check_max_residual`.
DEFAULT_MAX_RESIDUAL = 1e-2

#: Above this share of the weight that rounding alone leaves unbalanced, a method that promises
#: the exact step refuses the precision (a frozen cloth leaves about 1 unbalanced).
MAX_FLOOR = 0.1
#: The bound is at least this many times the rounding floor: a step resolved down to rounding
#: leaves about the floor (16^2 cloth, k = 1e4 N/m, f32: floor 0.013, samples 0.002-0.031).
FLOOR_MARGIN = 3.0

#: Share of a run's time the samples may take, by the cost model of :mod:`.monitor`.
BUDGET = 0.05

#: Scene features whose forces this module does not model: a scene with one is not measured.
UNMODELLED_FEATURES = ("wind", "turbulence", "constraints", "emitter")


def check_max_residual(value) -> float:
    """A bound on the relative residual in (0, 1]: ConfigError naming ``max_residual`` else.

    The default, 1e-2, is the share of the forces a step may leave unbalanced: a backward
    Euler step solved to the Newton driver's default tolerance stays below it on every scene of
    ``docs`` (typically 1e-4 to 1e-3), while a stiff cloth left unsolved (too few projective
    dynamics iterations, or frozen by single-precision rounding) is at 0.1 to 1."""
    if value is None:
        return DEFAULT_MAX_RESIDUAL
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (0 < value <= 1):
        raise ConfigError(f"max_residual must be a number in (0, 1], got {value!r}")
    return float(value)


def unmodelled(scene) -> str | None:
    """The first feature of ``scene`` whose forces the residual does not model, or None."""
    for name in UNMODELLED_FEATURES:
        if scene.features.get(name):
            return name
    return None


class ForceModel:
    """The scene's forces in float64 numpy (gravity, drag, springs, dashpots, the grab), read
    from the scene's fields at each evaluation (stiffness and grab change while a run goes)."""

    def __init__(self, scene):
        arrays = scene.static_arrays
        self.scene = scene
        self.mass = np.asarray(arrays["mass"], np.float64)
        self.free = ~np.asarray(arrays["pinned"], bool)
        self.gravity = np.asarray(arrays.get("gravity", np.zeros(3)), np.float64)
        self.drag = float(arrays.get("drag", 0.0))
        self.springs = scene.springs
        self.grab = scene.system.term("grab") if hasattr(scene.system, "term") else None

    def spring_arrays(self):
        if self.springs is None:
            return None
        data = self.springs.arrays()
        alive = data.get("alive")
        keep = slice(None) if alive is None else np.asarray(alive, bool)
        return (np.asarray(data["springs"], np.int64)[keep], data["rest_length"][keep],
                data["stiffness"][keep], data["spring_damping"][keep])

    def internal(self, x, v, x0, h, isotropic: bool, springs) -> np.ndarray:
        """Springs (with dashpots) and the grab at (x, v) (N, (n, 3))."""
        force = np.zeros_like(x)
        if springs is not None and len(springs[0]):
            ends, rest, k, c = springs
            a, b = ends[:, 0], ends[:, 1]
            d = x[a] - x[b]
            length = np.sqrt(np.einsum("ij,ij->i", d, d))
            u = d / np.where(length > 0, length, 1.0)[:, None]
            f = -(k * (length - rest))[:, None] * u * (length > 0)[:, None]
            if np.any(c):
                dv = v[a] - v[b]
                if isotropic:
                    f -= c[:, None] * dv
                else:
                    f -= (c * np.einsum("ij,ij->i", dv, u))[:, None] * u
            n = len(x)
            for axis in range(3):  # bincount: an order of magnitude faster than np.add.at
                force[:, axis] += (np.bincount(a, f[:, axis], minlength=n)
                                   - np.bincount(b, f[:, axis], minlength=n))
        if self.grab is not None:
            i = int(self.grab.particle[None])
            if i >= 0:
                target = np.asarray(self.grab.target[None].to_numpy(), np.float64)
                force[i] += (float(self.grab.stiffness[None]) * (target - x[i])
                             - float(self.grab.damping[None]) * v[i])
        return force

    def external(self, v) -> np.ndarray:
        """Gravity and drag at velocities v (N, (n, 3))."""
        return self.mass[:, None] * self.gravity - self.drag * v


def _norm(a: np.ndarray) -> float:
    """The 2-norm of all of ``a``'s entries (np.linalg.norm goes through BLAS, 100 times slower
    on (n, 3) arrays where OpenBLAS is pinned to a generic core type)."""
    return math.sqrt(float(np.einsum("ij,ij->", a, a)))


def rounding_floor(model: ForceModel, x, epsilon: float) -> float:
    """The relative residual that rounding alone leaves at positions x ((n, 3), m) when they
    are stored with machine epsilon ``epsilon``: a spring's length is a difference of
    coordinates rounded relative to |x|, so its force carries an error of about
    k max(|x_i|, |x_j|) epsilon / 2 (N), summed over a particle's springs as independent
    roundings, against the weight of the particles (what moves a resting cloth). NaN without
    gravity or springs (nothing to compare)."""
    springs = model.spring_arrays()
    weight = model.mass * np.linalg.norm(model.gravity)
    free = model.free
    if springs is None or not len(springs[0]) or not np.any(weight[free] > 0):
        return math.nan
    ends, _, k, _ = springs
    x = np.asarray(x, np.float64)
    reach = np.maximum(np.linalg.norm(x[ends[:, 0]], axis=1), np.linalg.norm(x[ends[:, 1]], axis=1))
    error2 = (0.5 * epsilon * k * reach) ** 2
    noise2 = (np.bincount(ends[:, 0], error2, minlength=len(x))
              + np.bincount(ends[:, 1], error2, minlength=len(x)))
    return float(math.sqrt(noise2[free].sum()) / np.linalg.norm(weight[free]))


def relative_residual(model: ForceModel, equation: Equation, x0, v0, x1, v1, h: float, extra=None) -> float:
    """|r| / scale of ``equation`` for the step of ``h`` s from (x0, v0) to (x1, v1) ((n, 3)
    arrays of any float type; computed in float64). NaN when nothing is free or h <= 0.
    ``extra``: the method's own forces at x1 (a backward Euler step's
    :class:`~taichi_sim.integrators.equation.SolveForces`), counted with the internal ones."""
    x0, v0, x1, v1 = (np.asarray(a, np.float64) for a in (x0, v0, x1, v1))
    if h <= 0 or not np.any(model.free):
        return math.nan
    # Every method holds a pinned particle still within a step (its derivative is zero), so its
    # dashpots see it at rest; a kinematic pin's script velocity is set after the step.
    pinned = ~model.free
    v0, v1 = v0.copy(), v1.copy()
    v0[pinned] = 0.0
    v1[pinned] = 0.0
    if equation.rule == "implicit_midpoint":
        tau = 0.5 * h
        x, v = 0.5 * (x0 + x1), 0.5 * (v0 + v1)
    else:
        tau = h
        x, v = x1, v1
    springs = model.spring_arrays()
    internal = model.internal(x, v, x0, tau, equation.isotropic_dashpots, springs)
    if extra is not None:
        internal = internal + extra.force
    external = model.external(v0 if equation.explicit_external else v)
    inertia = model.mass[:, None] * (x - x0 - tau * v0) / tau**2
    free = model.free
    residual = (inertia - internal - external)[free]
    scale = _norm(inertia[free]) + _norm(internal[free]) + _norm(external[free])
    if not np.all(np.isfinite(residual)):
        return math.inf
    if scale <= 0:
        return 0.0
    return float(_norm(residual) / scale)
