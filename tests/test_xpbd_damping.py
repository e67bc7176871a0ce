"""XPBD's spring dashpots against an independent reference of the same damped model."""
import numpy as np

import taichi_sim as ts
from taichi_sim.integrators import create_integrator
from taichi_sim.reference import solve_reference

T_END = 1.0  # s

# A 5-particle chain falling from horizontal on soft springs (k = 50 N/m, 0.1 kg particles), so
# that it stretches and swings, with dashpots of c = 2 N s/m along each spring (damping ratio
# c / (2 sqrt(k m)) ~ 0.45) and no drag: the dashpots are the only physical damping.
CHAIN = {"particle_count": 5, "stiffness": 50.0, "damping": 2.0, "drag": 0.0}


def xpbd_error(substeps: int, reference: np.ndarray) -> float:
    """Largest position error (m) of XPBD at ``substeps`` per 1/60 s step against ``reference``."""
    scene = ts.build_scene("pendulum", CHAIN)
    result = ts.run(scene, create_integrator("xpbd", scene.system, substeps=substeps), dt=1 / 60,
                    t_end=T_END, energy_every=0, progress=False)
    assert result.status is ts.Status.OK, result.message
    return float(np.abs(scene.state.to_numpy()[0] - reference).max())


def test_xpbd_with_dashpots_converges_to_the_damped_reference(f64):
    """scipy's DOP853 on the exported force model (spring_damping along each spring) gives the
    damped motion at 1 s; XPBD's error shrinks like its first order (2.8 mm at 100 substeps,
    5.6 mm at 50) while the undamped motion is 75 mm away: XPBD without its damping of C-dot
    (gamma = 0 in the spring projection) misses by 78 mm and fails."""
    scene = ts.build_scene("pendulum", CHAIN)
    data = scene.arrays
    data["x0"], data["v0"] = scene.state.to_numpy()
    damped, _ = solve_reference(data, T_END, rtol=1e-10, atol=1e-10)
    undamped, _ = solve_reference({**data, "spring_damping": 0.0 * data["spring_damping"]}, T_END,
                                  rtol=1e-10, atol=1e-10)
    separation = np.abs(damped - undamped).max()
    assert separation > 0.05  # the dashpots matter here: 75 mm

    fine, coarse = xpbd_error(100, damped), xpbd_error(50, damped)
    assert fine < 0.1 * separation, (fine, separation)
    assert fine < 0.6 * coarse, (fine, coarse)  # first order: halving dt halves the error
