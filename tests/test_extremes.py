"""Stability at the extremes: every integrator x stiffness {1, 1e4, 1e8} N/m x step {1e-6, 1/60, 1} s
on a spring, a 10-particle pendulum, a 6 x 6 cloth and that cloth as a StVK and a Neo-Hookean
membrane (nu = 0.49; the stiffness is its E t); every run is bounded-and-ok, reported or (a method
that does not take a membrane) refused, never silent and never a crash. The same matrix with 30 steps per run, and any other, is
`taichi-sim bench extremes`."""
import json

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.bench import extremes
from taichi_sim.guard import GuardLimits
from taichi_sim.integrators import INTEGRATORS

STEPS = 10  # enough for every explicit blow-up in the matrix to pass the audit's bounds


@pytest.mark.long
@pytest.mark.parametrize("label", list(extremes.SCENES))
def test_no_run_at_the_extremes_is_silent(f64, label):
    rows = extremes.run_extremes({label: extremes.SCENES[label]}, list(INTEGRATORS),
                                 extremes.STIFFNESSES, extremes.STEP_SIZES, steps=STEPS)
    assert len(rows) == len(INTEGRATORS) * 9
    membrane = "material" in extremes.SCENES[label][1]
    refusing = {name for name, cls in INTEGRATORS.items() if not cls.takes_elastic_models} if membrane else set()
    wrong = [(r["integrator"], r["stiffness"], r["dt"], r["outcome"], r["reason"]) for r in rows
             if r["outcome"] not in ("ok", "reported") and not (r["outcome"] == "refused" and r["integrator"] in refusing)]
    assert not wrong
    assert {r["integrator"] for r in rows if r["outcome"] == "refused"} == refusing
    assert all("cannot step a cloth of material" in r["reason"] for r in rows if r["outcome"] == "refused")
    # The matrix does reach past what explicit methods can take, and every report says why.
    reported = [r for r in rows if r["outcome"] == "reported"]
    assert {r["integrator"] for r in reported} >= {"euler", "rk4", "symplectic_euler"}
    assert all(r["message"].startswith(f"{r['status']} at step {r['failed_step']} ") for r in reported)
    # An ok run took all its steps.
    assert all(r["steps"] == STEPS for r in rows if r["outcome"] == "ok")


def test_the_audit_catches_a_blow_up_the_guard_was_told_to_allow(f64):
    # With the guard's bounds opened wide, explicit Euler's growth (x (1 + h^2 w^2) per step)
    # goes unreported; the audit, which shares no code with the guard, must call it silent.
    wide = GuardLimits(energy_growth=1e300, reach=1e300, strain=1e300)
    rows = extremes.run_extremes({"spring": extremes.SCENES["spring"]}, ["euler"], [1e4], [1 / 60],
                                 steps=STEPS, guard=wide)
    assert [r["outcome"] for r in rows] == ["silent"]
    assert rows[0]["status"] == "ok" and "energy rose to" in rows[0]["reason"]


def test_the_audit_checks_each_bound_on_its_own(f64):
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    arrays = scene.arrays
    x0, v0 = (np.asarray(a, float) for a in scene.state.to_numpy())
    done = ts.run(scene, "symplectic_euler", dt=1e-3, steps=5, energy_every=0, progress=False)
    x, v = (np.asarray(a, float) for a in scene.state.to_numpy())
    assert extremes.audit(arrays, x0, v0, arrays, x, v, done) == ""
    free = ~arrays["pinned"]
    far = x.copy()
    far[:, 0] += 1e5  # sideways, the whole cloth: no spring or gravity energy changes
    assert "from the start" in extremes.audit(arrays, x0, v0, arrays, far, v, done)
    stretched = x.copy()
    stretched[np.flatnonzero(free)[0], 0] += 300.0
    limp = dict(arrays, stiffness=np.zeros_like(arrays["stiffness"]))  # strain alone, no energy
    assert "strain" in extremes.audit(arrays, x0, v0, limp, stretched, v, done)
    fast = v.copy()
    fast[free] += 1e4
    assert "energy rose" in extremes.audit(arrays, x0, v0, arrays, x, fast, done)
    nan = x.copy()
    nan[free] = np.nan
    assert extremes.audit(arrays, x0, v0, arrays, nan, v, done) == "non-finite state"
    judged = extremes.judge(ts.Status.DIVERGED, "", "", x, v)
    assert judged.outcome == "silent" and "without a message" in judged.reason


def test_bench_extremes_writes_its_table_and_fails_on_a_silent_run(tmp_path, capsys):
    from taichi_sim.cli import main

    out = tmp_path / "ext"
    code = main(["bench", "extremes", "--quick", "--out", str(out), "--integrators",
                 "symplectic_euler,implicit_euler", "--scenes", "spring", "--stiffnesses", "1e4",
                 "--step-sizes", "1e-3,1/20"])
    assert code == 0
    rows = json.loads((out / "extremes.json").read_text())["rows"]
    assert [(r["integrator"], r["outcome"]) for r in rows] == [
        ("symplectic_euler", "ok"), ("symplectic_euler", "reported"),
        ("implicit_euler", "ok"), ("implicit_euler", "ok")]
    assert (out / "extremes.csv").read_text().startswith("study,study_version,case,scene,integrator,stiffness,dt,")
    assert (out / "extremes.png").stat().st_size > 1000
    table = capsys.readouterr().out
    assert "silent" in table and "symplectic_euler" in table


def test_bench_extremes_takes_a_cloth_of_any_size(tmp_path):
    from taichi_sim.cli import main

    out = tmp_path / "ext"
    assert main(["bench", "extremes", "--quiet", "--out", str(out), "--scenes", "cloth3",
                 "--integrators", "symplectic_euler", "--stiffnesses", "1", "--step-sizes", "1e-3",
                 "--steps", "2"]) == 0
    data = json.loads((out / "extremes.json").read_text())
    assert data["config"]["scenes"] == {"cloth3": ["cloth", {"nx": 3, "ny": 3}]}
    assert [r["outcome"] for r in data["rows"]] == ["ok"]


@pytest.mark.parametrize("args, message", [
    (["--stiffnesses", "-1"], "--stiffnesses"),
    (["--step-sizes", "0"], "--step-sizes"),
    (["--step-sizes", "1/0"], "--step-sizes"),
    (["--scenes", "sprinkler"], "sprinkler"),
    (["--scenes", "cloth1"], "cloth1"),
    (["--steps", "0"], "--steps"),
])
def test_bench_extremes_refuses_bad_input_in_one_line(tmp_path, capsys, args, message):
    from taichi_sim.cli import main

    out = tmp_path / "ext"
    assert main(["bench", "extremes", "--quick", "--out", str(out)] + args) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()
