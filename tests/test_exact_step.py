"""Exact backward Euler on stiff scenes: how a step split into pieces chooses the next step's
piece size, and the progress text a long step hands the run loop."""
import taichi_sim as ts
from taichi_sim.integrators import Status, create_integrator
from taichi_sim.integrators.implicit import newton

STIFF_CHAIN = {"particle_count": 10, "stiffness": 1e8, "damping": 0.0, "drag": 0.0}


def first_tries(integrator, scene, h: float, steps: int):
    """For each step: (pieces per step of its first try, tries made, tries that failed)."""
    tries = []
    attempt = integrator._attempt

    def logged(state, t, piece):
        report = attempt(state, t, piece)
        tries.append((round(h / piece), report.status is not Status.OK))
        return report

    integrator._attempt = logged
    out, t = [], 0.0
    for _ in range(steps):
        tries.clear()
        report = integrator.step(scene.state, t, h)
        assert report.status is Status.OK, report.message
        out.append((tries[0][0], len(tries), sum(failed for _, failed in tries)))
        t += h
    return out


def test_a_split_step_keeps_its_piece_size_for_coarsen_after_steps(f64):
    # A chain of k = 1e8 N/m released horizontally at h = 0.1 s: Newton cannot swing it down in
    # one step, so steps go in pieces; the piece size is tried coarser only after
    # ``coarsen_after`` steps that needed no finer pieces (each coarser try that fails costs
    # newton_iterations iterations).
    scene = ts.build_scene("pendulum", STIFF_CHAIN)
    integrator = create_integrator("implicit_euler", scene.system)
    wait = integrator.coarsen_after
    assert wait > 1
    steps = first_tries(integrator, scene, 0.1, 12)
    coarsened = 0
    for k in range(1, len(steps)):
        if steps[k][0] < steps[k - 1][0]:  # this step tried longer pieces than the last
            coarsened += 1
            calm = steps[k - wait:k]
            assert k >= wait and len({first for first, _, _ in calm}) == 1, steps
            assert all(failed == 0 and tries == first for first, tries, failed in calm), steps
    assert steps[0][2] > 0 and coarsened > 0, steps  # the run split and coarsened again


def test_a_long_step_reports_its_newton_progress(f64, monkeypatch):
    monkeypatch.setattr(newton, "PROGRESS_INTERVAL", 0.0)
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "stiffness": 1e8})
    integrator = create_integrator("implicit_euler", scene.system)
    texts = []
    integrator.progress = texts.append
    report = integrator.step(scene.state, 0.0, 1 / 60)
    assert report.status is Status.OK
    assert len(texts) == integrator.stats.newton_iterations > 1
    assert texts[-1].startswith(f"t=0 s Newton {len(texts)} ")
    assert f"{integrator.last_relative_residual:.1e}" in texts[-1]
    assert f"linear it {report.linear_iterations};" in texts[-1]


def test_the_command_line_bar_shows_newton_progress(f64, monkeypatch, capsys):
    monkeypatch.setattr(newton, "PROGRESS_INTERVAL", 0.0)
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "stiffness": 1e8})
    integrator = create_integrator("implicit_euler", scene.system)
    result = ts.run(scene, integrator, dt=1 / 60, steps=2, energy_every=0, progress=True)
    assert result.status is Status.OK
    assert "Newton" in capsys.readouterr().err
    integrator.progress = None
    ts.run(scene, integrator, dt=1 / 60, steps=2, energy_every=0, progress=False)
    assert integrator.progress is None and "Newton" not in capsys.readouterr().err
