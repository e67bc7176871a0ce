"""Turbulence: a seeded, smooth, divergence-free random acceleration field."""
import math

import numpy as np
import taichi as ti

from .. import runtime
from .base import ForceTerm, ZeroJacobian

#: Travelling waves summed into the field: enough that it looks random, few enough to be cheap.
TURBULENCE_MODES = 6


def turbulence_modes(seed: int, scale: float, frequency: float, modes: int = TURBULENCE_MODES) -> dict:
    """The waves of a turbulence field drawn from ``seed``: wave vectors ``k`` (modes, 3) rad/m
    with |k| = 2 pi / ``scale`` times a factor in [0.7, 1.4], unit ``direction`` (modes, 3) each
    perpendicular to its k (so every wave, and the sum, is divergence-free: it stirs the
    particles without bunching them), angular frequencies ``omega`` (modes,) rad/s around
    2 pi ``frequency``, and phases ``phase`` (modes,) rad."""
    rng = np.random.default_rng([int(seed), 0x7075])  # a stream of its own, apart from the emitter's
    axis = rng.normal(size=(modes, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    k = axis * (2 * math.pi / scale) * rng.uniform(0.7, 1.4, (modes, 1))
    other = rng.normal(size=(modes, 3))
    direction = np.cross(axis, other)
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    omega = 2 * math.pi * frequency * rng.uniform(0.5, 1.5, modes)
    phase = rng.uniform(0.0, 2 * math.pi, modes)
    return {"k": k, "direction": direction, "omega": omega, "phase": phase}


@ti.data_oriented
class Turbulence(ZeroJacobian, ForceTerm):
    """Force m_i a(x_i, t), with ``a`` a sum of M travelling sine waves (:func:`turbulence_modes`)::

        a(x, t) = amplitude / M * sum_j d_j sin(k_j . x - omega_j t + phi_j)

    smooth in x and t (so it belongs inside f and keeps every integrator's order), deterministic
    for a seed, bounded by ``amplitude`` (m/s^2) everywhere. The numpy reference
    (:func:`taichi_sim.reference.particle_rhs`) evaluates the same sum from :meth:`arrays`.
    ``amplitude`` is a 0-D field (changeable while running without recompiling).

    Args:
        amplitude: the bound on |a| (m/s^2); scale: wavelength of the eddies (m);
        frequency: how often the pattern changes (Hz); seed: draws the waves.
    """

    name = "turbulence"
    reads_other_particles = False
    variational = False  # time-dependent and not a gradient: no potential
    source = True

    def __init__(self, *, amplitude: float, scale: float, frequency: float, seed: int):
        real, npr = runtime.real(), runtime.np_real()
        self.modes = turbulence_modes(seed, scale, frequency)
        M = len(self.modes["omega"])
        self.count = M
        self.amplitude = ti.field(real, shape=())
        self.k = ti.Vector.field(3, real, shape=M)
        self.direction = ti.Vector.field(3, real, shape=M)
        self.omega = ti.field(real, shape=M)
        self.phase = ti.field(real, shape=M)
        for name in ("k", "direction", "omega", "phase"):
            getattr(self, name).from_numpy(self.modes[name].astype(npr))
        self.set(amplitude)

    def set(self, amplitude: float) -> None:
        self.amplitude[None] = float(amplitude)

    def get(self) -> float:
        return float(self.amplitude[None])

    def arrays(self) -> dict:
        """What the numpy reference needs to rebuild the field (stored with a run)."""
        return {"turbulence_amplitude": np.float64(self.get()), "turbulence_k": self.modes["k"],
                "turbulence_direction": self.modes["direction"], "turbulence_omega": self.modes["omega"],
                "turbulence_phase": self.modes["phase"]}

    @ti.func
    def force(self, i, y, mass_i, t):
        a = ti.Vector.zero(y.x.dtype, 3)
        for j in ti.static(range(self.count)):
            a += ti.sin(self.k[j].dot(y.x[i]) - self.omega[j] * t + self.phase[j]) * self.direction[j]
        return mass_i * (self.amplitude[None] / self.count) * a
