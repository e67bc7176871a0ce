"""The sweep engine under the benches (taichi_sim/bench/sweep): the table does not depend on
--jobs or on running through a Dask cluster, a stopped study resumes without re-running its
finished cases, a hung case is recorded as a timeout, and bad input exits 2 touching nothing.
Each case is a process that starts Taichi (~2-5 s here), so the studies are two or three
cases of ten steps."""
import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from taichi_sim.bench.extremes import STUDY_VERSION as EXTREMES_VERSION
from taichi_sim.bench.precision import compare
from taichi_sim.bench.sweep.table import MACHINE_COLUMNS
from taichi_sim.cli import main

ROOT = Path(__file__).resolve().parents[1]
# Two cases (one per integrator), two runs each: one bounded, one past symplectic Euler's limit.
STUDY = ["bench", "extremes", "--quick", "--scenes", "spring", "--stiffnesses", "1e4",
         "--step-sizes", "1e-3,1/20", "--integrators", "symplectic_euler,implicit_euler", "--quiet"]
TIMES = set(MACHINE_COLUMNS) | {"seconds"}  # wall times and overlap: the machine's, not the study's


def table(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in TIMES} for row in csv.DictReader(f)]


def cases_of(path: Path) -> dict[str, str]:
    """case key -> its wall time as written (a case run again gets a new one)."""
    with open(path, newline="") as f:
        return {row["case"]: row["case_wall_s"] for row in csv.DictReader(f)}


@pytest.fixture(scope="module")
def one_at_a_time(tmp_path_factory):
    out = tmp_path_factory.mktemp("jobs1")
    assert main(STUDY + ["--out", str(out), "--jobs", "1"]) == 0
    return table(out / "extremes.csv")


@pytest.mark.long
def test_two_jobs_give_the_same_table_as_one(one_at_a_time, tmp_path):
    assert main(STUDY + ["--out", str(tmp_path), "--jobs", "2"]) == 0
    rows = table(tmp_path / "extremes.csv")
    assert rows == one_at_a_time
    assert [r["outcome"] for r in rows] == ["ok", "reported", "ok", "ok"]
    with open(tmp_path / "extremes.csv", newline="") as f:
        assert {r["concurrency"] for r in csv.DictReader(f)} <= {"1", "2"}


@pytest.mark.long
def test_a_local_dask_cluster_gives_the_same_table(one_at_a_time, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        assert main(STUDY + ["--out", str(tmp_path), "--scheduler", cluster.scheduler_address]) == 0
    assert table(tmp_path / "extremes.csv") == one_at_a_time


@pytest.mark.long
def test_a_study_stopped_with_ctrl_c_resumes_without_rerunning_finished_cases(tmp_path):
    study = [a if a != "symplectic_euler,implicit_euler" else "symplectic_euler,implicit_euler,rk4"
             for a in STUDY] + ["--out", str(tmp_path), "--jobs", "1"]
    command = [sys.executable, "-m", "taichi_sim", *study]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    # A suite started in the background of a script inherits SIGINT ignored (POSIX), and so
    # would the study: give it Ctrl-C's default so that it reacts as it does at a terminal.
    proc = subprocess.Popen(command, env=env, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    path = tmp_path / "extremes.csv"
    deadline = time.monotonic() + 120
    while not (path.exists() and cases_of(path)) and time.monotonic() < deadline:
        time.sleep(0.1)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    before = cases_of(path)
    assert 1 <= len(before) < 3, err
    assert "the same command finishes the others" in err
    done = subprocess.run(command, env=env, stderr=subprocess.PIPE, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    after = cases_of(path)
    assert len(after) == 3
    assert {key: after[key] for key in before} == before  # the finished cases did not run again


def test_a_case_past_its_timeout_is_recorded_and_the_study_goes_on(tmp_path, capsys):
    # No case starts Taichi in 0.2 s: both are stopped, both rows say so, the bench fails.
    assert main(STUDY + ["--out", str(tmp_path), "--jobs", "2", "--case-timeout", "0.2"]) == 1
    with open(tmp_path / "extremes.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["integrator"], r["outcome"]) for r in rows] == [("symplectic_euler", "timeout"),
                                                               ("implicit_euler", "timeout")]
    assert all("0.2 s timeout" in r["reason"] for r in rows)
    assert "timed out" in capsys.readouterr().err


def _bad(argv, capsys) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    return err[0]


def test_bad_input_exits_2_and_overwrites_nothing(tmp_path, capsys):
    out = ["--out", str(tmp_path)]
    assert "--jobs" in _bad(STUDY + out + ["--jobs", "0"], capsys)
    assert "cannot reach a Dask scheduler" in _bad(STUDY + out + ["--scheduler", "tcp://127.0.0.1:9"], capsys)
    assert "give one of them" in _bad(STUDY + out + ["--scheduler", "tcp://127.0.0.1:9", "--jobs", "2"], capsys)
    assert not list(tmp_path.iterdir())
    header = "study,study_version,case,scene,integrator,status\n"
    for name, text, said in [
        ("extremes.csv", "integrator,outcome\nrk4,ok\n", "not written by the sweep engine"),
        ("extremes.csv", header + "extremes,99,spring-rk4-0,spring,rk4,ok\n", "version 99"),
        ("extremes.csv", header + f"extremes,{EXTREMES_VERSION},spring-rk4-0,spring,rk4,ok\n", "does not plan"),
        ("precision.csv", header + "extremes,1,spring-rk4-0,spring,rk4,ok\n", "'extremes' table"),
    ]:
        (tmp_path / name).write_text(text)
        argv = STUDY if name == "extremes.csv" else ["bench", "precision", "--quick", "--quiet"]
        assert said in _bad(argv + out, capsys)
        assert (tmp_path / name).read_text() == text
        assert sorted(p.name for p in tmp_path.iterdir()) == [name]
        (tmp_path / name).unlink()


def test_the_precision_comparison_flags_an_ok_f32_run_that_disagrees():
    x64 = np.zeros((4, 3))
    x64[:, 0] = [0.0, 1.0, 2.0, 3.0]  # a 3 m cloth
    ok = {"status": "ok"}
    close = compare(ok, ok, x64, x64 + [0.0, 1e-4, 0.0])
    assert close["f32_vs_f64_m"] == pytest.approx(1e-4) and close["f32_vs_f64_rel"] == pytest.approx(1e-4 / 3)
    assert "finding" not in close
    far = compare(ok, ok, x64, x64 + [0.0, 0.01, 0.0])
    assert far["finding"].startswith("f32 ends 0.01 m")
    assert "finding" not in compare(ok, {"status": "diverged"}, x64, x64 + 0.01)  # it said so
    assert "f32_vs_f64_m" not in compare(ok, {"status": "refused"}, x64, None)


@pytest.mark.long
def test_bench_precision_writes_both_runs_of_each_case(tmp_path):
    assert main(["bench", "precision", "--scenes", "soft", "--integrators", "symplectic_euler,implicit_euler",
                 "--t-end", "0.01", "--jobs", "2", "--quiet", "--out", str(tmp_path)]) == 0
    with open(tmp_path / "precision.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["integrator"], r["precision"], r["status"]) for r in rows] == [
        ("symplectic_euler", "f64", "ok"), ("symplectic_euler", "f32", "ok"),
        ("implicit_euler", "f64", "ok"), ("implicit_euler", "f32", "ok")]
    f32 = [r for r in rows if r["precision"] == "f32"]
    assert all(0 < float(r["f32_vs_f64_rel"]) < 1e-4 for r in f32)  # rounding, not a finding
    assert rows[0]["worst_residual"] == "" and float(rows[2]["worst_residual"]) > 0  # explicit: none
    assert (tmp_path / "precision.png").stat().st_size > 0


def _echo_cases(sleeps):
    from taichi_sim.bench.sweep import Case

    return [Case("tests.sweep_cases:sleep_then_echo", {"value": i, "seconds": s}, {"n": i})
            for i, s in enumerate(sleeps)]


def _last_first_cases(folder, count):
    """``count`` cases that, run all at once, end last-first, a second apart: each starts its
    wait for the end once the next one has (a chain of marks), not after a guessed sleep."""
    from taichi_sim.bench.sweep import Case

    marks = [str(folder / f"ended-{i}") for i in range(count)] + [""]
    return [Case("tests.sweep_cases:echo_after",
                 {"value": i, "wait_for": marks[i + 1], "mark": marks[i], "gap": 1.0}, {"n": i})
            for i in range(count)]


def test_the_table_is_in_plan_order_whatever_order_cases_end_in(tmp_path):
    from taichi_sim.bench.sweep import Study, Sweep

    (tmp_path / "marks").mkdir()
    cases = _last_first_cases(tmp_path / "marks", 3)  # with three at once they end last-first
    sweep = Sweep(Study("echo", 1), cases, tmp_path, jobs=3, quiet=True)
    rows = sweep.run(cases, "echo")
    assert sweep.ran == [cases[2].key, cases[1].key, cases[0].key]
    assert [r["value"] for r in rows] == [0, 1, 2] and [r["square"] for r in rows] == [0, 1, 4]
    assert table(tmp_path / "echo.csv") == [{k: str(v) for k, v in r.items() if k not in TIMES} for r in rows]
    assert max(r["concurrency"] for r in rows) == 3
    again = Sweep(Study("echo", 1), cases + _echo_cases([0, 0, 0, 0])[3:], tmp_path, jobs=2, quiet=True)
    assert again.run(cases + _echo_cases([0, 0, 0, 0])[3:], "echo")[:3] == rows  # read back as written
    assert len(again.ran) == 1  # only the new case ran


def test_sigterm_stops_the_running_cases_and_keeps_the_finished_ones(tmp_path):
    # The cases run in sessions of their own, so the driver must stop them: a case left
    # sleeping would keep the driver waiting (its thread joins the child) for 60 s.
    script = ("import sys\nfrom taichi_sim.bench.sweep import Case, Study, Sweep\n"
              "cases = [Case('tests.sweep_cases:sleep_then_echo', {'value': i, 'seconds': s}, {'n': i})\n"
              "         for i, s in enumerate([0.0, 60.0])]\n"
              "Sweep(Study('echo', 1), cases, sys.argv[1], jobs=2, quiet=True).run(cases, 'echo')\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen([sys.executable, "-c", script, str(tmp_path)], env=env, stderr=subprocess.PIPE, text=True)
    path = tmp_path / "echo.csv"
    deadline = time.monotonic() + 60
    while not path.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    stopped = time.monotonic()
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=50)
    assert time.monotonic() - stopped < 20, err
    assert proc.returncode != 0 and "the same command finishes the others" in err
    assert len(cases_of(path)) == 1  # the finished case, kept


def test_a_case_whose_saved_arrays_are_missing_runs_again(tmp_path):
    # A later stage reads a reference case's arrays: its row alone does not make it done.
    from taichi_sim.bench.sweep import Case, Study, Sweep

    cases = [Case("tests.sweep_cases:echo_with_arrays", {"value": i}, {"n": i}) for i in range(2)]
    first = Sweep(Study("refs", 1), cases, tmp_path, jobs=2, quiet=True)
    first.run(cases, "refs", needs_arrays=True)
    saved = sorted((tmp_path / "refs-arrays").iterdir())
    assert len(saved) == 2
    saved[1].unlink()
    again = Sweep(Study("refs", 1), cases, tmp_path, jobs=1, quiet=True)
    assert not again.finished(cases[1], needs_arrays=True) and again.finished(cases[1])
    again.run(cases, "refs", needs_arrays=True)
    assert again.ran == [cases[1].key] and saved[1].exists()
    assert again.arrays(cases[1])["values"].tolist() == [1.0, 1.0, 1.0]


@pytest.mark.long
def test_a_resumed_work_precision_study_computes_a_missing_truth_again(tmp_path):
    study = ["bench", "work-precision", "--quick", "--scenes", "simple", "--integrators", "euler", "--quiet",
             "--out", str(tmp_path)]
    assert main(study) == 0
    before = cases_of(tmp_path / "work-precision.csv")
    (truth,) = (tmp_path / "work-precision-arrays").iterdir()
    truth.unlink()
    assert main(study) == 0  # not a crash reading the missing arrays, nor runs skipped for want of a truth
    after = cases_of(tmp_path / "work-precision.csv")
    assert truth.exists()
    assert {k: v for k, v in after.items() if k.startswith("run-")} == \
        {k: v for k, v in before.items() if k.startswith("run-")}  # the runs did not run again
    assert [after[k] != before[k] for k in before if k.startswith("truth-")] == [True]  # the truth did
