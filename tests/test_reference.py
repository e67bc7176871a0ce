"""A run checked from its npz alone against scipy's DOP853 (an independent reference)."""
import numpy as np
import pytest

from taichi_sim.cli import main
from taichi_sim.reference import particle_energy, solve_reference


@pytest.mark.parametrize("integrator, dt, tolerance", [
    # RK4's global error ~ C h^4: halving h must shrink it ~16x, so both bounds are checked.
    ("rk4", 2e-3, 4e-7), ("rk4", 1e-3, 4e-7 / 12),
])
def test_pendulum_chain_matches_dop853_from_the_npz(tmp_path, integrator, dt, tolerance):
    path = tmp_path / "p.npz"
    assert main(["simulate", "pendulum", "--integrator", integrator, "--dt", str(dt), "--t-end", "1.0",
                 "--set", "particle_count=5", "--set", "damping=0.3", "--set", "drag=0.05",
                 "--out", str(path), "--quiet"]) == 0
    data = dict(np.load(path))
    x_ref, v_ref = solve_reference(data, float(data["t"]), rtol=1e-12, atol=1e-12)
    err = np.abs(data["x"] - x_ref).max()
    assert err < tolerance
    assert np.abs(data["v"] - v_ref).max() < 100 * tolerance
    # the npz's energy trace is the exported model's energy
    assert data["energy"][-1] == pytest.approx(particle_energy(data, data["x"], data["v"]), rel=1e-12)
