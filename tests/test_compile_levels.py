"""The kernels compile at Taichi's opt_level 0 too (a third of the compile time of the default;
docs/lab/suite-time.md): Taichi keeps one type per local name, and a ``_``
bound to a scalar, then a vector, then a scalar in one kernel (the implicit methods' Newton
start) compiled at the default level but aborted the process in LLVM at level 0."""
import os
import subprocess
import sys


def test_the_implicit_newton_step_compiles_at_opt_level_0(tmp_path):
    code = ("import taichi_sim as ts\n"
            "ts.init(precision='f64', offline_cache=False)\n"
            "print(ts.run(ts.build_scene('spring', {}), 'implicit_euler', dt=1e-2, steps=3).status.value)\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600,
                          env={**os.environ, "TI_OPT_LEVEL": "0"}, cwd=tmp_path)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split()[-1] == "ok"
