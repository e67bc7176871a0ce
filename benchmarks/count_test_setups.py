"""How much the suite's tests could share: a pytest plugin that records each test's set-up,
and a report over what it recorded.

For every test the plugin writes one line (JSON) with its wall time (set-up, call and
tear-down) and, in order, its ``ts.init`` calls, its scene builds (preset, parameters, seed)
and its steppers (integrator, step). The report counts the distinct scenes, the scenes that
more than one test builds, and the tests whose whole set-up repeats another test's: the time
of all but the first test of each such group bounds what sharing identical set-ups could save
(docs/first-contact.md, "How much the tests could share, counted").

    rm -rf /tmp/setups && mkdir /tmp/setups
    TS_SETUP_LOG=/tmp/setups PYTHONPATH=benchmarks .venv/bin/python -m pytest -q -n 2 \\
        -p no:cacheprovider -p count_test_setups
    .venv/bin/python benchmarks/count_test_setups.py /tmp/setups
"""
import collections
import glob
import json
import os
import sys
import time

import pytest

_events: list = []
_started = [0.0]


def _record_setups() -> None:
    """Wrap the package's entry points so that each call is recorded for the running test."""
    import taichi_sim as ts
    import taichi_sim.runtime as runtime
    import taichi_sim.scene as scene
    import taichi_sim.scene.presets as presets
    import taichi_sim.stepper as stepper

    build_scene, init, stepper_init = presets.build_scene, runtime.init, stepper.Stepper.__init__

    def recorded_build(name, params=None, *, seed=0):
        _events.append(["build", name, json.dumps(params, sort_keys=True, default=repr), seed])
        return build_scene(name, params, seed=seed)

    def recorded_init(*args, **kwargs):
        _events.append(["init", repr(args), json.dumps(kwargs, sort_keys=True, default=repr)])
        return init(*args, **kwargs)

    def recorded_stepper(self, scene_, integrator, dt, **kwargs):
        stepper_init(self, scene_, integrator, dt, **kwargs)
        _events.append(["stepper", type(self.integrator).__name__, repr(dt)])

    for module in (ts, scene, presets):
        module.build_scene = recorded_build
    ts.init = runtime.init = recorded_init
    stepper.Stepper.__init__ = recorded_stepper


# -- the pytest plugin (``-p count_test_setups`` with benchmarks/ on PYTHONPATH) ---------------

def pytest_configure(config):
    if not os.environ.get("TS_SETUP_LOG"):
        raise RuntimeError("count_test_setups: set TS_SETUP_LOG to the folder for the records")
    _record_setups()


@pytest.hookimpl(tryfirst=True)  # before the fixtures' set-up, which calls ts.init
def pytest_runtest_setup(item):
    _events.clear()
    _started[0] = time.perf_counter()


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_teardown(item):
    yield  # after the tear-down: the test's whole time, fixtures included
    path = os.path.join(os.environ["TS_SETUP_LOG"], f"{os.getpid()}.jsonl")
    with open(path, "a") as f:
        f.write(json.dumps({"test": item.nodeid, "seconds": time.perf_counter() - _started[0],
                            "events": list(_events)}) + "\n")


# -- the report -----------------------------------------------------------------------------------

def report(folder: str) -> str:
    rows = []
    for path in glob.glob(os.path.join(folder, "*.jsonl")):
        with open(path) as f:
            rows.extend(json.loads(line) for line in f)
    if not rows:
        raise SystemExit(f"count_test_setups: no records in {folder}")
    total = sum(r["seconds"] for r in rows)
    same_setup = collections.defaultdict(list)
    for r in rows:
        if r["events"]:
            same_setup[json.dumps(r["events"])].append(r)
    groups = [g for g in same_setup.values() if len(g) > 1]
    beyond_first = sum(sum(r["seconds"] for r in g) - min(r["seconds"] for r in g) for g in groups)
    builders = collections.defaultdict(set)
    for r in rows:
        precision = None
        for event in r["events"]:
            if event[0] == "init":
                precision = event[2]
            elif event[0] == "build":
                builders[(precision, *event[1:])].add(r["test"])
    shared = {k: v for k, v in builders.items() if len(v) > 1}
    lines = [f"{len(rows)} tests, {total:.0f} s in all (set-up, call and tear-down)",
             f"distinct scenes built (precision, preset, parameters, seed): {len(builders)}",
             f"built by more than one test: {len(shared)} scenes, "
             f"{len(set().union(*shared.values())) if shared else 0} tests",
             f"tests whose whole set-up repeats another's: {sum(len(g) for g in groups)} in {len(groups)} groups; "
             f"all but the first of each group: {beyond_first:.0f} s ({beyond_first / total:.0%})",
             "", "the most shared scenes (tests: preset, parameters):"]
    for key, tests in sorted(shared.items(), key=lambda kv: -len(kv[1]))[:10]:
        lines.append(f"  {len(tests)}: {key[1]} {key[2]}")
    return "\n".join(lines)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: count_test_setups.py FOLDER (the TS_SETUP_LOG of a suite run)")
    print(report(sys.argv[1]))
