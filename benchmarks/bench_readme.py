"""Time what a newcomer runs first, as the README shows it, and record the figures it quotes.

* The README's garment recipe (its block marked ``<!-- command: run -->``: make the skirt,
  simulate it with an export, check it), run line by line as written in a temporary folder:
  the wall time of the whole recipe and of its ``simulate`` line, medians of ``--repeats`` runs
  after one warm-up run (which fills Taichi's kernel cache).
* The time to the first step, ``taichi-sim simulate cloth-fold --steps 1`` with its kernels
  cached: the median of ``--repeats`` runs after a warm-up.

Writes docs/figures/readme_garment_recipe.json, readme_garment_simulate.json and
first_step_cloth_fold.json (``benchmarks/figures.py``); then
``python benchmarks/figures.py render`` puts them into the pages.

    .venv/bin/python benchmarks/bench_readme.py            # about a minute on 2 cores
"""
from __future__ import annotations

import argparse
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import figures  # noqa: E402  (benchmarks/ is not a package)

ROOT = Path(__file__).resolve().parent.parent
RUN_BLOCK = re.compile(r"<!--\s*command:\s*run\s*-->\s*\n```\w*\n(.*?)^```", re.S | re.M)
CLI = [sys.executable, "-m", "taichi_sim"]
# the checkout's package, also where the interpreter's environment holds another copy
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))


def recipe_lines(readme: Path) -> list[str]:
    """The commands of the README's first block marked ``<!-- command: run -->`` (continuations
    joined, comments dropped)."""
    match = RUN_BLOCK.search(readme.read_text())
    if match is None:
        raise SystemExit(f"{readme}: no block marked <!-- command: run -->")
    lines, pending = [], ""
    for raw in match.group(1).splitlines():
        line = pending + raw.strip()
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        pending = ""
        line = re.sub(r"\s+#.*$", "", line).strip()
        if line and not line.startswith("#"):
            lines.append(line)
    return lines


def argv_of(line: str) -> list[str]:
    """A README line as the arguments to run: ``taichi-sim`` and ``.venv/bin/python`` become this
    interpreter, paths into the repository stay valid from a temporary folder."""
    words = shlex.split(line)
    if words[0] == "taichi-sim":
        return CLI + words[1:]
    if words[0].endswith("python"):
        return [sys.executable] + [str(ROOT / w) if (ROOT / w).is_file() else w for w in words[1:]]
    raise SystemExit(f"bench_readme: cannot run {line!r} (neither taichi-sim nor python)")


def timed(argv: list[str], cwd: Path) -> float:
    """Wall seconds of one command; a failing command stops the bench with its output."""
    start = time.perf_counter()
    done = subprocess.run(argv, cwd=cwd, env=ENV, capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"bench_readme: {shlex.join(argv)} exited {done.returncode}:\n{done.stdout}{done.stderr}")
    return elapsed


def run_recipe(lines: list[str]) -> dict[str, float]:
    """Wall seconds of each line of the recipe, run in order in a new temporary folder."""
    with tempfile.TemporaryDirectory() as tmp:
        return {line: timed(argv_of(line), Path(tmp)) for line in lines}


def seconds(value: float) -> str:
    return f"{value:.1f} s"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Time the README's first commands and record the figures.")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs after the warm-up (default 3)")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be >= 1")
    load = figures.load_average()
    lines = recipe_lines(ROOT / "README.md")
    simulate = next(line for line in lines if " simulate " in f" {line} ")
    run_recipe(lines)  # warm-up: compiles what the cache lacks
    runs = [run_recipe(lines) for _ in range(args.repeats)]
    whole = statistics.median(sum(r.values()) for r in runs)
    step = statistics.median(r[simulate] for r in runs)
    command = f"python benchmarks/bench_readme.py --repeats {args.repeats}"
    figures.record("readme_garment_recipe", seconds(whole), whole, "s", command=command, load=load, headline=True,
                   what="the README's garment recipe (make the skirt, simulate 1 s with a USD export, check), kernels cached")
    figures.record("readme_garment_simulate", seconds(step), step, "s", command=command, load=load,
                   what="its simulate line: 60 xpbd steps of the 5 000-vertex skirt, with the export")
    first = argv_of("taichi-sim simulate cloth-fold --steps 1 --out fold.npz")
    with tempfile.TemporaryDirectory() as tmp:
        timed(first, Path(tmp))
        times = [timed(first, Path(tmp)) for _ in range(args.repeats)]
    first_step = statistics.median(times)
    figures.record("first_step_cloth_fold", seconds(first_step), first_step, "s", command=command, load=load, headline=True,
                   what="`taichi-sim simulate cloth-fold --steps 1` from the shell prompt to the prompt, kernels cached")
    print(f"recipe {whole:.2f} s (simulate {step:.2f} s), first step of cloth-fold {first_step:.2f} s "
          f"(medians of {args.repeats}); python benchmarks/figures.py render puts them into the pages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
