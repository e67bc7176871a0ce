"""How much memory a scene will need, estimated from its parameters before anything is allocated,
so that an impossible size is refused with one line instead of a MemoryError deep in numpy or
Taichi.

The estimate counts bytes per particle, per spring and per triangle, plus each integrator's
scratch as its class states it (``Integrator.scratch_bytes``). The per-item constants are rounded up from measurements of peak resident memory (the
growth of ``resource.getrusage(...).ru_maxrss`` across ``build_scene`` and across
``create_integrator`` plus two steps, numpy's peak by ``tracemalloc``; 2026-11-23, Taichi 1.7.4
on x64, f64, 2 vCPUs of an AMD EPYC): building a 512 x 512 cloth (262 144 particles,
1 567 746 springs, 522 242 triangles) took 449 MB, of which 341 MB was numpy's peak while
building the topology (about 217 bytes per spring); the first steps of implicit_euler with CG
added 204 MB on top, rk4 and symplectic Euler a few MB (their scratch states fit in memory the
build had already freed). The estimate for that cloth is 631 MB (plus 222 MB for implicit_euler; it was 543 MB before
the force buffer of 6 reals per spring, about 75 MB here at f64, was added):
it errs on the side of refusing a little early.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from .errors import ConfigError

# Taichi indexes fields with 32-bit integers; the spring gather holds 2 entries per spring.
MAX_INDEX = 2**31 - 1

# Bytes per item at a real of r bytes (4 for f32, 8 for f64): fixed bytes + reals * r.
# A particle: numpy x0, v0, positions and their build copies; the state, the guard's snapshot,
# mass and flags. A spring: numpy ends, kinds, rest lengths and their temporaries; Taichi's
# ends, gather lists, rest length, stiffness, damping, tearing, and the force buffer of a
# whole-system evaluation (3 reals; the grid stencil's slots hold 3 parameters and 3 force
# components instead). A triangle: numpy and Taichi vertex ids and the per-particle
# incidence lists.
_PARTICLE_FIXED, _PARTICLE_REALS = 200, 14
_SPRING_FIXED, _SPRING_REALS = 230, 10
# The power iteration that sharpens a scene's default step or a message's prediction runs on
# scenes of at most POWER_PARTICLES particles (above, minutes: the Gershgorin bounds instead);
# on top of the build's numpy peak it adds about 130 bytes a spring (its own peak is about
# 210: spectrum.explicit_default_step at 64 x 64 and 128 x 128, 2026-11-27).
POWER_PARTICLES = 100_000
_POWER_SPRING = 130
_TRIANGLE_FIXED, _TRIANGLE_REALS = 80, 2


@dataclass(frozen=True)
class Size:
    """What a scene will allocate: particle, spring and triangle counts."""

    particles: int
    springs: int
    triangles: int = 0


def estimate_bytes(size: Size, *, precision: str = "f64", integrators: tuple = (),
                   linear_solver: str = "cg", copies: int = 1) -> int:
    """Estimated peak memory (bytes) of building ``copies`` scenes of ``size`` and stepping them
    with each of ``integrators`` (integrator classes: each states its own scratch,
    ``Integrator.scratch_bytes``; side-by-side runs each own a scene and an integrator). The
    callers name them: this module sits below the integrators."""
    r = 4 if precision == "f32" else 8
    n, s, t = size.particles, size.springs, size.triangles
    spring = _SPRING_FIXED + _SPRING_REALS * r + (_POWER_SPRING if n <= POWER_PARTICLES else 0)
    total = copies * (n * (_PARTICLE_FIXED + _PARTICLE_REALS * r) + s * spring
                      + t * (_TRIANGLE_FIXED + _TRIANGLE_REALS * r))
    for method in integrators:
        total += method.scratch_bytes(n, s, r, linear_solver)
    return int(total)


def available_bytes() -> int | None:
    """Memory the system can give this process without swapping (bytes): MemAvailable from
    /proc/meminfo, else free physical pages; None where neither can be read."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def format_bytes(count: float) -> str:
    """``1.5e9`` -> ``"1.5 GB"`` (decimal units)."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if count >= scale:
            return f"{count / scale:.3g} {unit}"
    return f"{int(count)} B"


def check_size(size: Size, culprits: str, *, precision: str = "f64", integrators: tuple = (),
               linear_solver: str = "cg", copies: int = 1, available: int | None = None) -> int:
    """Raise ConfigError naming ``culprits`` (e.g. ``"nx = 100000, ny = 100000"``) when a scene of
    ``size`` cannot be indexed by Taichi or would need more memory than is available (bytes;
    default: :func:`available_bytes`). Returns the estimate (bytes)."""
    what = f"{size.particles:,} particles, {size.springs:,} springs"
    need = estimate_bytes(size, precision=precision, integrators=integrators, linear_solver=linear_solver,
                          copies=copies)
    if available is None:
        available = available_bytes()
    if available is not None and need > available:
        raise ConfigError(f"parameters {culprits}: the scene needs about {format_bytes(need)} ({what}) "
                          f"but only {format_bytes(available)} of memory is available; choose a smaller scene")
    if max(size.particles, 2 * size.springs, 3 * size.triangles) > MAX_INDEX:
        raise ConfigError(f"parameters {culprits}: {what} (about {format_bytes(need)}) are more than "
                          f"Taichi's 32-bit field indices can address ({MAX_INDEX:,}); choose a smaller scene")
    return need
