"""Exact solutions and small utilities shared by the tests."""
import math

import numpy as np

import taichi_sim as ts


def spring_exact(scene, t):
    """Exact (y, v_y) of the bob of the `spring` scene (a 1-D harmonic oscillator, no drag)."""
    p = scene.params
    k, m, g = p["stiffness"], p["particle_mass"], p["gravity"]
    omega = math.sqrt(k / m)
    sag = m * g / k
    amplitude = p["stretch"] - sag
    y = -(p["rest_length"] + sag) - amplitude * math.cos(omega * t)
    v = amplitude * omega * math.sin(omega * t)
    return y, v, omega


def fitted_order(hs, errors):
    """Least-squares slope of log(error) against log(h)."""
    return float(np.polyfit(np.log(hs), np.log(errors), 1)[0])


def run_fixed(scene, name, dt, t_end, **options):
    integrator = ts.create_integrator(name, scene.system, **options)
    scene.reset()
    return ts.run(scene, integrator, dt=dt, t_end=t_end, energy_every=0)
