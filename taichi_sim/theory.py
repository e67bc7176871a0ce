"""Stability theory of the integrators on a spring network (docs/integrators.md, Stability on an
oscillator).

Every method here is stable on an undamped linear oscillator of angular frequency omega while
theta = h omega stays below a constant C of the method; a spring network linearised about a
configuration is a set of such oscillators, and the fastest one, omega_max, sets the limit
h_max = C / omega_max.

omega_max^2 is the largest eigenvalue of M^-1 K, where K (3n x 3n) is the Hessian of the spring
energy with the pinned particles' rows and columns removed: spring s = (i, j) with stiffness k,
rest length r and d = x_i - x_j contributes the 3x3 block

    B_s = k (u u^T + tau (I - u u^T)),   u = d / |d|,   tau = max(0, 1 - r / |d|)

(+B_s on the (i, i) and (j, j) blocks, -B_s on (i, j) and (j, i)); at rest length tau = 0. The
transverse factor is clamped at 0 exactly as the implicit integrators clamp it, so this is the
stiffness those integrators see. M^-1 K has the eigenvalues of the symmetric S = W K W with
W = M^-1/2 (zero on pinned particles), so:

* :func:`omega_max_bound`: block Gershgorin on S, a cheap upper bound,
  omega_max^2 <= max over free i of ( sum_s k_s / m_i + sum_{s, j free} k_s / sqrt(m_i m_j) ),
  because ||B_s|| = k_s (tau <= 1). With equal masses and no pinned neighbour this is
  2 (sum of attached k) / m, the bound in docs/integrators.md; a pinned neighbour counts once, so
  the single spring of the ``spring`` scene gives exactly sqrt(k / m).
* :func:`omega_max_power`: power iteration on S; its Rayleigh quotient rises to the sharp value
  from below.

Gravity and drag add no stiffness. Dashpots and drag damp: on x'' = -omega^2 x - gamma x' an
explicit method's stable region is bounded along the negative real axis too, so strong damping
(a fine grid's light particles under the same dashpots) shortens the limit. Where an integrator
states its limit on the damped oscillator (``damped_limit``: symplectic Euler in closed form, the
explicit Runge-Kutta methods from their stability polynomial) the prediction takes gamma_max,
the largest eigenvalue of M^-1 D for the dashpots' and drag's damping matrix D, with omega_max
(:func:`damped_step_limit`): by power iteration in ``advise`` and the messages
(:func:`scene_damping_rate`); a cloth preset's default step takes the Gershgorin bounds and,
where they call it too long, power iteration (:func:`explicit_default_step`). Wind is left out.
The circle ODE (``simple``) has omega = 1.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from .forces.springs.spectrum import (  # noqa: F401 (theory's API)
    StiffnessOperator,
    damping_rate_bound,
    damping_rate_power,
    explicit_default_step,
    omega_max_bound,
    omega_max_power,
    spring_network,
)
from .memory import POWER_PARTICLES


def method_class(method):
    """The integrator class of ``method``: a class, an instance, or a name (a built-in's, an
    installed or already loaded plug-in's, or a ``module:Class`` spec)."""
    if isinstance(method, str):
        from .integrators import integrator_class  # the facts live on the classes

        return integrator_class(method)
    return method if isinstance(method, type) else type(method)


def stability_constant(method) -> float | None:
    """C of an integrator (h_max = C / omega_max; its class's ``stability_constant``): 0 when
    it grows at every step on the imaginary axis (|R(i theta)| > 1 for every theta > 0; only
    damping or a finite horizon gives a limit), inf when no step blows it up, None for an
    adaptive method."""
    return method_class(method).stability_constant


def predicted_limit(name, omega_max: float | None, gamma_max: float = 0.0) -> float | None:
    """The largest stable step (s) of integrator ``name`` (a name or class) for a system whose fastest mode is ``omega_max``
    (rad/s), damped at rates up to ``gamma_max`` (1/s): C / omega_max undamped
    (:func:`damped_step_limit` with damping); inf when unconditional or when nothing
    oscillates or damps; 0 when the method is never stable on the imaginary axis; None when not
    applicable (adaptive, unknown omega)."""
    c = stability_constant(name)
    if c is None or omega_max is None or not math.isfinite(omega_max):
        return None
    if math.isinf(c):
        return math.inf
    if c == 0.0:
        return 0.0 if omega_max > 0 else math.inf
    return damped_step_limit(name, omega_max, gamma_max)


def step_limited(name) -> bool:
    """Whether integrator ``name`` has a finite, positive stable step (0 < C < inf): the
    explicit methods a scene's default step is made for (not the implicit, positional or
    adaptive ones, nor those that grow at every step)."""
    c = stability_constant(name)
    return c is not None and 0.0 < c < math.inf


def damped_step_limit(name, omega: float, gamma: float) -> float:
    """The largest stable step (s) of a method with 0 < C < inf for modes up to ``omega``
    (rad/s) damped at rates up to ``gamma`` (1/s): the least of its ``damped_limit`` over a
    5 x 5 grid of (omega', gamma') in [0, omega] x [0, gamma], or C / omega when it states none.
    A mode may have any stiffness and damping up to the bounds, and a Runge-Kutta method's limit
    does not shrink with both: damping widens it near the imaginary axis, and a slow, strongly
    damped mode (drag damps every mode alike) is limited near 2.785 / gamma for RK4, below what
    the fastest mode with that damping allows. Symplectic Euler's shrinks with both, so for it
    the grid's least is the corner (omega, gamma)."""
    cls = method_class(name)
    undamped = cls.stability_constant / omega if omega > 0 else math.inf
    if gamma <= 0:
        return undamped
    shares = (0.0, 0.25, 0.5, 0.75, 1.0)
    limits = [cls.damped_limit(a * omega, b * gamma) for a in shares for b in shares if a or b]
    if any(limit is None for limit in limits):
        return undamped
    return min(undamped, *limits)


def horizon_limit(name, omega: float, t_end: float, growth: float = 2.0) -> float | None:
    """For a method that grows on the imaginary axis (C = 0), the largest step (s) whose energy
    growth |R(i h omega)|^(2 t_end / h) over ``t_end`` s stays within ``growth``; None for the
    others."""
    cls = method_class(name)
    if cls.stability_constant != 0.0 or omega <= 0:
        return None
    rate = cls.amplification_squared

    def grows(h):
        return (t_end / h) * math.log(rate(h * omega)) > math.log(growth)

    lo, hi = 1e-12 / omega, 10.0 / omega
    if not grows(hi):
        return hi
    for _ in range(200):
        mid = math.sqrt(lo * hi)
        lo, hi = (lo, mid) if grows(mid) else (mid, hi)
        if hi / lo < 1 + 1e-10:
            break
    return lo


def omega_max_eigsh(arrays: Mapping[str, np.ndarray], x: np.ndarray) -> float | None:
    """omega_max by scipy's Lanczos (``eigsh``) on the same operator: an independent check of
    :func:`omega_max_power`; None without scipy."""
    try:
        from scipy.sparse.linalg import LinearOperator, eigsh
    except ImportError:
        return None
    op = StiffnessOperator(arrays, x)
    if len(op.i) == 0 or not op.free.any():
        return 0.0
    size = 3 * op.n
    if size <= 60:  # small: the dense matrix, column by column
        dense = np.stack([op(e.reshape(op.n, 3)).ravel() for e in np.eye(size)], axis=1)
        return math.sqrt(max(float(np.linalg.eigvalsh(0.5 * (dense + dense.T)).max()), 0.0))
    linear = LinearOperator((size, size), matvec=lambda v: op(v.reshape(op.n, 3)).ravel(), dtype=float)
    value = eigsh(linear, k=1, which="LA", return_eigenvectors=False, tol=1e-12,
                  v0=np.ones(size) * np.repeat(op.free, 3))[0]
    return math.sqrt(max(float(value), 0.0))


def is_circle(scene) -> bool:
    return not scene.system.second_order and type(scene.system).__name__ == "CircleSystem"


def scene_omega_max(scene, method: str = "bound", **options) -> float | None:
    """omega_max (rad/s) of a built scene: 1 for the circle ODE; for a particle scene the
    Gershgorin ``"bound"`` or the ``"power"`` iteration at the scene's initial positions; None
    for a first-order system it does not know."""
    if is_circle(scene):
        return 1.0
    if not scene.system.second_order:
        return None
    arrays = scene.arrays
    if method == "bound":
        return omega_max_bound(arrays)
    if method == "power":
        return omega_max_power(arrays, scene.x0, **options)[0]
    raise ValueError(f"unknown omega_max method {method!r}")


def stability_warning(scene, integrator_name, dt: float | None, *, power_iterations: int = 200) -> str | None:
    """One line for ``simulate`` when ``dt`` exceeds the predicted stability limit of
    ``integrator_name`` (a name or class) on ``scene``, else None: C / omega_max with omega_max
    by power iteration, the figure that :func:`stable_step_advice` and ``taichi-sim advise``
    print, so a run that warns and then fails names one limit. The cheap Gershgorin bound (never
    below omega_max) skips the iteration when ``dt`` is within even its smaller limit. Methods
    with no finite positive limit (adaptive, implicit, or never stable on the imaginary axis) get
    no warning."""
    c = stability_constant(integrator_name)
    if dt is None or c is None or c == 0.0 or math.isinf(c):
        return None
    bound = scene_omega_max(scene, "bound")
    if not bound or dt <= damped_step_limit(integrator_name, bound, scene_damping_rate(scene)):
        return None
    omega = _omega_power(scene, power_iterations)
    if not omega:
        return None
    gamma = _gamma(scene, power_iterations)
    limit = damped_step_limit(integrator_name, omega, gamma)
    if dt <= limit:
        return None
    return (f"dt = {dt:g} s exceeds the predicted stable step {limit:.3g} s of "
            f"{method_class(integrator_name).name} here ({_limit_terms(scene, c, omega, gamma, limit)}; "
            "see taichi-sim advise); expect divergence")


def scene_damping_rate(scene, method: str = "bound", power_iterations: int = 200) -> float:
    """gamma_max (1/s) of a built particle scene's dashpots and drag (0 for others): the
    Gershgorin ``"bound"``, or by ``"power"`` iteration (:func:`damping_rate_power`) at the
    initial positions. The bound sums the |c_s| of springs pointing every way, about twice the
    sharp value on a grid cloth."""
    if is_circle(scene) or not scene.system.second_order:
        return 0.0
    arrays = scene.arrays
    try:
        if method == "bound":
            return damping_rate_bound(arrays)
        return damping_rate_power(arrays, scene.x0, power_iterations)
    except (KeyError, ValueError):
        return 0.0


def _limit_terms(scene, c: float, omega: float, gamma: float, limit: float) -> str:
    """How a predicted limit came about, for a message."""
    undamped = c / omega
    terms = f"C / omega_max = {c:.3g} / {omega:.4g} rad/s"
    if limit < undamped * (1 - 1e-9):
        terms += (f" = {undamped:.3g} s undamped, shortened by dashpots and drag damping at up to "
                  f"{gamma:.4g} /s")
    return terms if _iterated(scene) else terms + ", Gershgorin bounds"


def _iterated(scene) -> bool:
    """Whether a message's prediction may take power iteration: at most POWER_PARTICLES
    particles. Above, it takes minutes (a 1024 x 1024 cloth's failure message waited over two),
    and a message must not hold up the run or the failure it explains: the Gershgorin bounds."""
    return scene.system.particle_count <= POWER_PARTICLES


def _gamma(scene, power_iterations: int) -> float:
    """gamma_max (1/s) for a message: power iteration, or the bound above POWER_PARTICLES."""
    return scene_damping_rate(scene, "power" if _iterated(scene) else "bound", power_iterations)


def _omega_power(scene, power_iterations: int) -> float | None:
    """omega_max (rad/s) by power iteration at the initial positions (the Gershgorin bound above
    POWER_PARTICLES), or None when there is none (a prediction must never hide the run or the
    failure it explains)."""
    if not _iterated(scene):
        return scene_omega_max(scene, "bound") or None
    try:
        omega = scene_omega_max(scene, "power", max_iterations=power_iterations, tol=1e-8)
    except Exception:
        return None
    return omega if omega and math.isfinite(omega) else None


def stable_step_advice(scene, name, *, power_iterations: int = 200) -> str:
    """A clause for a failure message: the predicted largest stable step of integrator ``name``
    on ``scene`` (C / omega_max, with omega_max by power iteration at the initial positions, as
    ``taichi-sim advise`` computes it); "" for implicit and adaptive methods, or when there is
    no prediction."""
    try:
        c = stability_constant(name)
    except Exception:  # a prediction must never hide the failure it explains
        return ""
    if c is None or math.isinf(c):
        return ""
    omega = _omega_power(scene, power_iterations)
    if omega is None:
        return ""
    if c == 0.0:
        others = [m for m in ("symplectic_euler", "rk4") if scene.system.second_order or m == "rk4"]
        gamma = _gamma(scene, power_iterations)
        steps = ", ".join(f"{m} {damped_step_limit(m, omega, gamma):.3g} s" for m in others)
        name = method_class(name).name
        return (f"{name} grows at every step on undamped oscillations (no stable step); predicted "
                f"stable steps here (omega_max = {omega:.4g} rad/s): {steps}")
    gamma = _gamma(scene, power_iterations)
    limit = damped_step_limit(name, omega, gamma)
    name = method_class(name).name
    return (f"predicted stable step of {name} here: {limit:.3g} s "
            f"({_limit_terms(scene, c, omega, gamma, limit)}; see taichi-sim advise)")
