"""Time the test suite as CI runs it, and record the figure the README quotes.

Clones the repository's HEAD into a temporary folder and runs ``CI=true bash .ci/run`` there
(the set-up makes its own ``.venv``; the suite's kernel cache, ``~/.cache/taichi_sim/test-kernels``,
is the machine's, or an empty one with ``--empty-cache``). pytest's own time for the tests
(its last line, ``N passed in S s``) becomes docs/figures/suite_time.json (or
suite_time_empty_cache.json) and the test count suite_tests.json; a failing suite records
nothing and exits with its status.

    .venv/bin/python benchmarks/time_suite.py                 # about 10 minutes on 2 cores
    .venv/bin/python benchmarks/time_suite.py --empty-cache
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import figures  # noqa: E402  (benchmarks/ is not a package)

ROOT = Path(__file__).resolve().parent.parent
SUMMARY = re.compile(r"\b(\d+) passed\b.* in ([\d.]+)s\b")


def minutes(seconds: float) -> str:
    whole = round(seconds)
    return f"{whole // 60} min {whole % 60} s"


def parse_summary(output: str) -> tuple[int, float]:
    """(tests passed, seconds) from pytest's last summary line in ``output``; ValueError when
    there is none or it counts a failure or an error."""
    lines = [line for line in output.splitlines() if SUMMARY.search(line)]
    if not lines:
        raise ValueError("no pytest summary ('N passed in S s') in the output")
    if re.search(r"\b\d+ (failed|errors?)\b", lines[-1]):
        raise ValueError(f"the suite did not pass: {lines[-1].strip()}")
    passed, seconds = SUMMARY.search(lines[-1]).groups()
    return int(passed), float(seconds)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Time .ci/run in a fresh clone and record the figure.")
    parser.add_argument("--empty-cache", action="store_true", help="run with an empty kernel cache")
    parser.add_argument("--log", type=Path, help="keep the suite's output in this file")
    args = parser.parse_args(argv)
    load = figures.load_average()
    env = dict(os.environ, CI="true")
    with tempfile.TemporaryDirectory() as tmp:
        clone = Path(tmp) / "clone"
        subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
        if args.empty_cache:
            env["TI_OFFLINE_CACHE_FILE_PATH"] = str(Path(tmp) / "kernels")
        print(f"running bash .ci/run in {clone} ...", flush=True)
        done = subprocess.run(["bash", ".ci/run"], cwd=clone, env=env, stdin=subprocess.DEVNULL,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    if args.log:
        args.log.write_text(done.stdout)
    print(done.stdout[-2000:])
    if done.returncode != 0:
        print(f"time_suite: the suite failed (exit {done.returncode}); nothing recorded", file=sys.stderr)
        return done.returncode
    passed, seconds = parse_summary(done.stdout)
    cache = "empty" if args.empty_cache else "warm"
    command = "python benchmarks/time_suite.py" + (" --empty-cache" if args.empty_cache else "")
    name = "suite_time_empty_cache" if args.empty_cache else "suite_time"
    figures.record(name, minutes(seconds), seconds, "s", command=command, load=load, headline=True,
                   what=f"`bash .ci/run` in a fresh clone: the suite's {passed} tests, kernel cache {cache} (target 8 min)")
    figures.record("suite_tests", str(passed), passed, "tests", command=command, load=load,
                   what="the tests the suite ran")
    print(f"{passed} passed in {minutes(seconds)} (cache {cache}); python benchmarks/figures.py render puts it "
          f"into the pages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
