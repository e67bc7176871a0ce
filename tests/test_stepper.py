"""The stepping core: the order of a step, landing on an end time, failures and the re-check
after a failed step, observers, and dt's validation."""
import dataclasses
import math

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.app.runner import Runner
from taichi_sim.stepper import Stepper, check_dt


class Faulty:
    """A real integrator whose call number ``fail_at`` fails with ``status`` (not accepted),
    optionally leaving NaN in the state (a method that broke the state before it gave up)."""

    adaptive = implicit = False

    def __init__(self, inner, fail_at, status=ts.Status.NOT_CONVERGED, poison=False):
        self.inner, self.fail_at, self.status, self.poison = inner, fail_at, status, poison
        self.name = inner.name
        self.calls = self.resets = 0

    def reset(self):
        self.resets += 1
        self.inner.reset()

    def step(self, state, t, h):
        self.calls += 1
        report = self.inner.step(state, t, h)
        if self.calls < self.fail_at:
            return report
        if self.poison:
            x = state.x.to_numpy()
            x[0] = np.nan
            state.x.from_numpy(x)
        return dataclasses.replace(report, accepted=False, status=self.status, message="no convergence")


def test_a_failed_step_that_broke_the_state_ends_diverged_on_the_last_good_state(f64):
    # the step fails with not_converged after 9 good steps: the state it left is checked
    # (the guard last checked after 7 units of work), found non-finite, and put back
    scene = ts.build_scene("pendulum")
    faulty = Faulty(ts.create_integrator("symplectic_euler", scene.system), fail_at=10, poison=True)
    stepper = Stepper(scene, faulty, 1e-3)
    while stepper.failure is None:
        stepper.step()
    failure = stepper.failure
    assert failure.status is ts.Status.DIVERGED and "non-finite" in failure.detail
    assert (failure.step, failure.t) == (10, pytest.approx(9e-3))
    assert (stepper.steps, stepper.t) == (failure.good_step, failure.good_t) == (7, pytest.approx(7e-3))
    assert np.isfinite(scene.state.to_numpy()[0]).all()
    assert failure.message.startswith("diverged at step 10 (t = 0.009 s) with symplectic_euler, h = 0.001 s")
    assert "the state returned is that of step 7" in failure.message


def test_a_failed_step_that_left_a_sound_state_keeps_its_status(f64):
    scene = ts.build_scene("pendulum")
    faulty = Faulty(ts.create_integrator("symplectic_euler", scene.system), fail_at=10)
    stepper = Stepper(scene, faulty, 1e-3)
    while stepper.failure is None:
        stepper.step()
    failure = stepper.failure
    assert failure.status is ts.Status.NOT_CONVERGED and failure.detail == "no convergence"
    assert failure.good_step is None and stepper.steps == 9  # the state is that of step 9, checked
    assert stepper.guard.good_step == 9
    assert "the state returned" not in failure.message


def test_the_launcher_re_checks_after_a_failed_step_as_run_does(f64):
    runner = Runner(ts.build_scene("pendulum"), "symplectic_euler", 1e-3)
    runner.stepper.set_integrator(Faulty(runner.integrator, fail_at=10, poison=True))
    runner.advance(0.05)
    assert runner.status is ts.Status.DIVERGED and "non-finite" in runner.failure
    assert np.isfinite(runner.scene.state.to_numpy()[0]).all()
    scene = ts.build_scene("pendulum")
    result = ts.run(scene, Faulty(ts.create_integrator("symplectic_euler", scene.system), 10, poison=True),
                    dt=1e-3, steps=50)
    assert result.status is ts.Status.DIVERGED and result.message == runner.message


def test_observers_see_each_step_in_the_house_order(f64):
    scene = ts.build_scene("pendulum")
    seen = []

    class Watch:
        def before_step(self, stepper, h):
            seen.append(("before", stepper.steps, h))

        def after_step(self, stepper, report):
            seen.append(("after", stepper.steps, stepper.checked))

        def after_check(self, stepper):
            seen.append(("check", stepper.steps))
            return "refused" if stepper.steps == 3 else None

    stepper = Stepper(scene, "symplectic_euler", 1e-3, observers=[Watch()])
    for _ in range(3):
        stepper.step()
    # checks after 1 and then 2 more units of work (the guard's 1, 2, 4, ... schedule)
    assert seen == [("before", 0, 1e-3), ("check", 1), ("after", 1, True),
                    ("before", 1, 1e-3), ("after", 2, False),
                    ("before", 2, 1e-3), ("check", 3)]
    assert stepper.status is ts.Status.DIVERGED and stepper.failure.detail == "refused"
    assert stepper.steps == 1  # back on the last state that passed


def test_advance_lands_on_the_end_or_takes_whole_steps(f64):
    scene = ts.build_scene("pendulum")
    stepper = Stepper(scene, "symplectic_euler", 0.003)
    stepper.advance_to(0.01, whole_steps=True)
    assert stepper.steps == 3 and stepper.t == pytest.approx(0.009, abs=1e-15)
    stepper.advance_to(0.01)
    assert stepper.steps == 4 and stepper.t == 0.01  # exactly: the last step was shortened
    stepper.step()
    assert stepper.t == pytest.approx(0.013, abs=1e-15)
    assert stepper.guard.work == 1 and stepper.failure is None


def test_the_one_loop_stops_where_told_and_its_observers_may_end_it(f64):
    scene = ts.build_scene("pendulum")
    stepper = Stepper(scene, "symplectic_euler", 0.003)
    seen, once = [], []

    class StopAtSeven:
        def after_step(self, stepper, report):
            seen.append(stepper.steps)
            if stepper.steps == 7:
                stepper.stop()

    class Once:  # watches one step, then leaves (as the run's warm clock does)
        def after_step(self, stepper, report):
            once.append(stepper.steps)
            stepper.remove_observer(self)

    stepper.add_observer(Once())
    stepper.add_observer(StopAtSeven())
    assert stepper.run_until(steps=50) == 7 and stepper.steps == 7
    assert seen == list(range(1, 8)) and once == [1]
    assert stepper.run_until(max_calls=4) == 4 and stepper.steps == 11  # a stop holds for one call only
    assert stepper.run_until(t_end=0.05, check_last=True) == 6
    assert stepper.t == 0.05 and stepper.checked  # landed exactly, the last step checked inside it


def test_a_curve_force_change_resets_the_integrator_and_rebases_the_guard(f64):
    from taichi_sim.curves import Spline

    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6, "wind": True})
    faulty = Faulty(ts.create_integrator("symplectic_euler", scene.system), fail_at=10**9)
    stepper = Stepper(scene, faulty, 2e-3, curves={"wind_speed": Spline([(0.0, 0.0), (0.01, 10.0)])})
    resets = faulty.resets
    for _ in range(3):
        stepper.step()
    # from the second step on the speed moved by more than 0.1 % of its range each step
    assert faulty.resets == resets + 2
    assert stepper.guard.reference_t == pytest.approx(4e-3)


@pytest.mark.parametrize("dt", [0.0, -1.0, math.nan, math.inf, True, "0.1", None])
def test_a_bad_dt_is_refused_naming_dt(dt):
    with pytest.raises(ts.ConfigError, match="dt"):
        check_dt(dt)
    assert check_dt(None, adaptive=True) is None


def test_switching_methods_back_and_forth_keeps_one_monitor_each(f64):
    """The launcher switches methods at will: each keeps its residual monitor (a State field
    per monitor; a new one per switch would grow the process and recompile), with its samples
    cleared, and the new method's samples are its own."""
    scene = ts.build_scene("cloth", {"nx": 6, "ny": 6})
    implicit = ts.create_integrator("implicit_euler", scene.system)
    xpbd = ts.create_integrator("xpbd", scene.system)
    stepper = Stepper(scene, implicit, 1e-2)
    first = stepper.monitor
    stepper.advance_to(0.05)
    assert first.values
    stepper.set_integrator(xpbd)
    assert stepper.monitor is not first
    stepper.set_integrator(implicit)
    assert stepper.monitor is first and not first.values
