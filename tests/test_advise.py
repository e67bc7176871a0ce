"""``advise --target-error``: candidates ranked by measured wall time (not f-evaluations), the
pilots that cannot win left out, the cost said first, and no error promised where contact makes
the answer not settle as the step shrinks."""
import math

import pytest

from taichi_sim.bench import advise_target
from taichi_sim.bench.advise_target import Pilot, _Search
from taichi_sim.cli import main


class Method:
    """A stand-in for a run: error K h^p at t_end, and a fixed wall time per step (s)."""

    def __init__(self, name, order, evals, h_max, constant, per_step):
        self.row = {"integrator": name, "order": order, "evals": evals, "h_max": h_max, "max_by": "stability",
                    "pilots": [], "status": "waiting", "bound": math.ceil(1.0 / h_max) * (evals or 1) * 1e-6}
        self.constant, self.per_step = constant, per_step


def search(methods, *, budget=30.0):
    """_Search over ``methods`` with stub runs; returns it and the names bound, in order."""
    by_name = {m.row["integrator"]: m for m in methods}
    bound, give_ups = [], []

    def bind(name):
        bound.append(name)
        return by_name[name]

    def judge(method, h, order, *, give_up=math.inf):
        give_ups.append(give_up)
        pilot = Pilot(x=True, per_step=method.per_step)
        pilot.error = method.constant * h ** method.row["order"]
        return pilot

    rows = [m.row for m in methods]
    run = _Search(None, rows, judge, bind, 1e-3, 1.0, budget, False)
    return run, rows, bound, give_ups


def test_ranked_by_wall_time_not_by_f_evaluations(monkeypatch):
    """rk4 needs 4x the f-evaluations of symplectic Euler per step and fewer steps; here its
    steps are so slow (per_step) that it takes longer for the target: the measured time ranks
    symplectic Euler first although rk4 needs fewer f-evaluations in all."""
    monkeypatch.setattr(advise_target, "probe_step", lambda scene, method, h: method.per_step)
    rk4 = Method("rk4", 4, 4, 2e-3, constant=1e7, per_step=20e-3)
    symplectic = Method("symplectic_euler", 1, 1, 1e-3, constant=10.0, per_step=1e-5)
    run, rows, _, _ = search([rk4, symplectic])
    run.run()
    rows.sort(key=advise_target._rank)
    assert [r["status"] for r in rows] == ["ok", "ok"]
    first, second = rows
    assert first["integrator"] == "symplectic_euler" and second["integrator"] == "rk4"
    f_evals = {r["integrator"]: r["steps"] * r["evals"] for r in rows}
    assert f_evals["rk4"] < f_evals["symplectic_euler"]  # the f-evaluation count would rank rk4 first
    for r in rows:  # the run time is the measured time per step times the steps
        assert r["wall_s"] == pytest.approx(r["steps"] * by_per_step(r, rk4, symplectic))
        assert r["error"] <= 1e-3 and r["measured"]


def by_per_step(row, *methods):
    return next(m.per_step for m in methods if m.row["integrator"] == row["integrator"])


def test_a_candidate_that_cannot_beat_a_shown_run_is_not_piloted(monkeypatch):
    """Once a run is shown to meet the target in T s, a fixed-work method whose run at its
    largest step takes at least T s is skipped unbound (no kernels compiled), and an iterative
    method's pilot gives up after T s."""
    monkeypatch.setattr(advise_target, "probe_step", lambda scene, method, h: method.per_step)
    fast = Method("rk4", 4, 4, 1e-3, constant=1.0, per_step=1e-4)  # meets it at h_max: 0.1 s
    slow = Method("euler", 1, 1, 1e-6, constant=1.0, per_step=1e-4)
    slow.row["bound"] = 5.0  # a million steps of f at 5 us
    iterative = Method("vbd", 1, None, 0.05, constant=1.0, per_step=1e-2)
    run, rows, bound, give_ups = search([fast, slow, iterative])
    run.run()
    assert bound[0] == "rk4" and "euler" not in bound
    assert slow.row["status"] == "skipped" and "slower than" in slow.row["note"]
    assert give_ups[-1] == pytest.approx(fast.row["wall_s"])  # vbd's run gives up when slower
    assert fast.row["status"] == "ok" and fast.row["wall_s"] == pytest.approx(1000 * 1e-4)


def test_the_pilots_stay_within_the_budget(monkeypatch):
    """A pilot may not run past the budget left, and none starts once it is spent."""
    monkeypatch.setattr(advise_target, "probe_step", lambda scene, method, h: method.per_step)
    methods = [Method(f"m{k}", 1, None, 0.05, constant=100.0, per_step=1.0) for k in range(3)]
    run, rows, bound, give_ups = search(methods, budget=5.0)
    run.spent = 5.0  # as if the first pilots took it all
    run.run()
    assert bound == [] and all(r["status"] == "not piloted" and "--budget" in r["note"] for r in rows)
    run, rows, bound, give_ups = search([Method("m", 1, None, 0.05, constant=100.0, per_step=1.0)], budget=5.0)
    run.run()
    assert give_ups and max(give_ups) <= 5.0


def test_the_cost_is_said_before_the_advice(capsys):
    assert main(["advise", "spring", "--target-error", "1e-4", "--integrators", "rk4,symplectic_euler"]) == 0
    lines = capsys.readouterr().out.splitlines()
    cost = next(k for k, line in enumerate(lines) if line.startswith("advising: "))
    table = next(k for k, line in enumerate(lines) if line.startswith("For a position error"))
    assert cost < table and "reference run of rk4" in lines[cost] and "up to 2 candidates" in lines[cost]
    assert "roughly" in lines[cost] and "--budget" in lines[cost]
    assert any(line.startswith("advised in ") for line in lines[table:])


@pytest.mark.long
def test_contact_that_does_not_settle_gets_no_error_estimate(capsys):
    """The cloth falls onto the sphere and slides: RK4's answers at 2.6, 1.3 and 0.65 ms differ
    by 0.14 m and then 0.1 m, so no step can be promised 1 cm at t = 1 s; before this, advise
    recommended rk4 at 9.3 ms from a Richardson estimate."""
    code = main(["advise", "cloth-sphere", "--set", "nx=16", "--set", "ny=16", "--target-error", "1e-2",
                 "--t-end", "1"])
    captured = capsys.readouterr()
    assert code == 1 and "no fixed-step integrator could be recommended" in captured.err
    assert "the answer does not settle as the step shrinks" in captured.out
    assert "recommended:" not in captured.out


@pytest.mark.long
def test_contact_scene_before_contact_is_advised(capsys):
    """The same scene over its first 0.2 s, before the cloth reaches the sphere: the reference
    runs converge (order near 4) and a measured recommendation is made."""
    code = main(["advise", "cloth-sphere", "--set", "nx=8", "--set", "ny=8", "--target-error", "1e-2",
                 "--t-end", "0.2", "--integrators", "symplectic_euler,rk4,vbd"])
    out = capsys.readouterr().out
    assert code == 0 and "observed order" in out
    recommended = next(line for line in out.splitlines() if line.startswith("recommended:"))
    assert "shown by a pilot run at that step" in recommended


def test_a_scene_with_nothing_oscillating_still_gets_a_reference_run():
    """No springs (a sprinkler): RK4 has no step limit, which must not read as "no stable step";
    the reference starts at t_end / 20 and is refined from there."""
    assert advise_target.reference_steps([{"integrator": "rk4", "limit": math.inf}], 0.5) == 20
    assert advise_target.reference_steps([{"integrator": "rk4", "limit": 0.004}], 0.5) == 500
    assert advise_target.reference_steps([{"integrator": "rk4", "limit": None}], 0.5) is None


def test_step_times_leave_the_compiling_first_step_out(f64, monkeypatch):
    """A pilot's and a probe's time per step are those of warm kernels: a first step made to
    take 0.3 s (as compiling would) is not in them."""
    from helpers import slow_first_step

    import taichi_sim as ts

    scene = ts.build_scene("spring")
    integrator = ts.create_integrator("symplectic_euler", scene.system)
    calls = slow_first_step(monkeypatch, integrator)
    pilot = advise_target.run_to(scene, integrator, 0.01, 0.2)
    assert len(calls) == 20 and pilot.x is not None and pilot.per_step < 0.3 / 19 / 2
    calls.clear()
    assert advise_target.probe_step(scene, integrator, 0.01) < 0.3 / advise_target.PROBE_STEPS / 2
    assert len(calls) == 1 + advise_target.PROBE_STEPS


def test_without_a_reference_errors_are_richardson_estimates(f64, monkeypatch):
    """Where RK4 would need too many steps, each error comes from the run at h and h/2 (spring:
    an exact oscillator, so the estimate is good); on a scene with contact that is refused."""
    import taichi_sim as ts
    from taichi_sim.bench.advise import scene_omegas, stability_table

    monkeypatch.setattr(advise_target, "REFERENCE_MAX_STEPS", 1)
    scene = ts.build_scene("spring")
    table = stability_table(scene, scene_omegas(scene), 1.0)
    rows, line = advise_target.recommend(scene, table, 1e-4, 1.0, ["rk4"])
    assert "no reference run" in line and "Richardson estimates" in line
    assert rows[0]["status"] == "ok" and rows[0]["error"] <= 1e-4
    scene = ts.build_scene("cloth-sphere", {"nx": 4, "ny": 4})
    table = stability_table(scene, scene_omegas(scene), 0.1)
    rows, line = advise_target.recommend(scene, table, 1e-2, 0.1, ["symplectic_euler"])
    assert "not valid on a scene with contact" in line and rows[0]["status"] == "no estimate"
