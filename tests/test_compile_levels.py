"""The suite compiles its kernels "quick" (Taichi's opt_level 0, tests/conftest.py), users'
runs "optimised": the two must give the same answers, or the suite tests code users do not run.

Each case runs a scene at both levels in one process and compares the end states. LLVM is handed
different IR at the two levels, so the last bits may differ (docs/lab/suite-time.md), and a
contact decision taken on a rounding difference can part two runs: the cases are chosen to
exercise each family of kernels (explicit stages, an adaptive pair, Newton with CG, the
position-level solves, vbd's contact in its solve, the self-contact stage after the step), and
short enough to stay on one branch.

Also: Taichi keeps one type per local name, and a ``_`` bound to a scalar, then a vector, then a
scalar in one kernel (the implicit methods' Newton start) compiled at the default level but
aborted the process in LLVM at level 0."""
import os
import subprocess
import sys

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim import runtime
from taichi_sim.errors import ConfigError

CASES = {
    # name: (preset, parameters, integrator, dt, steps)
    "explicit stages": ("cloth", {"nx": 6, "ny": 6}, "rk4", 1e-3, 40),
    "adaptive pair": ("cloth", {"nx": 6, "ny": 6}, "rkf45", 1e-3, 20),
    "newton and cg": ("cloth", {"nx": 6, "ny": 6}, "implicit_euler", 1 / 60, 10),
    "xpbd": ("cloth", {"nx": 6, "ny": 6}, "xpbd", 1 / 60, 10),
    "projective dynamics": ("cloth", {"nx": 6, "ny": 6}, "projective_dynamics", 1 / 60, 10),
    "vbd with contact": ("cloth-fold", {"nx": 8, "ny": 8}, "vbd", 1 / 60, 30),
    "self-contact stage": ("cloth-fold", {"nx": 8, "ny": 8}, "symplectic_euler", 2e-3, 150),
}


def end_state(compile_mode: str, preset: str, params: dict, integrator: str, dt: float, steps: int):
    ts.init(precision="f64", compile_mode=compile_mode)
    scene = ts.build_scene(preset, params)
    result = ts.run(scene, integrator, dt=dt, steps=steps, progress=False)
    assert result.status.value == "ok", result.message
    x, v = scene.state.to_numpy()
    return np.asarray(x, float), np.asarray(v, float)


@pytest.mark.parametrize("case", list(CASES))
def test_quick_and_optimised_kernels_give_the_same_run(case):
    preset, params, integrator, dt, steps = CASES[case]
    x1, v1 = end_state("optimised", preset, params, integrator, dt, steps)
    x0, v0 = end_state("quick", preset, params, integrator, dt, steps)
    moved = np.abs(x1 - end_state_start(preset, params)).max()
    assert moved > 1e-3  # the run did something to compare
    np.testing.assert_allclose(x0, x1, rtol=0, atol=1e-9 * max(1.0, moved))
    np.testing.assert_allclose(v0, v1, rtol=0, atol=1e-7 * max(1.0, np.abs(v1).max()))


def end_state_start(preset: str, params: dict) -> np.ndarray:
    return np.asarray(ts.build_scene(preset, params).x0, float)


def test_the_mode_comes_from_the_call_or_the_environment(monkeypatch):
    monkeypatch.setenv(runtime.COMPILE_MODE_VARIABLE, "quick")
    ts.init(precision="f32")
    assert runtime._current["compile_mode"] == "quick"
    import taichi as ti
    assert ti.lang.impl.current_cfg().opt_level == 0
    ts.init(precision="f32", compile_mode="optimised")
    assert ti.lang.impl.current_cfg().opt_level == 1
    with pytest.raises(ConfigError, match="compile_mode"):
        ts.init(compile_mode="fast")
    monkeypatch.setenv(runtime.COMPILE_MODE_VARIABLE, "O0")
    with pytest.raises(ConfigError, match=runtime.COMPILE_MODE_VARIABLE):
        ts.init()


def test_the_implicit_newton_step_compiles_at_opt_level_0(tmp_path):
    code = ("import taichi_sim as ts\n"
            "ts.init(precision='f64', offline_cache=False, compile_mode='quick')\n"
            "print(ts.run(ts.build_scene('spring', {}), 'implicit_euler', dt=1e-2, steps=3).status.value)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                          env=os.environ, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[-1] == "ok"
