"""The ``taichi-sim`` command line."""
from __future__ import annotations

import argparse
import math
import sys

from .errors import ConfigError
from .scene.params import scene_assignments

EXIT_USAGE = 2
# The most steps one `simulate` takes. The cheapest scene (the circle ODE, RK4) runs at about a
# thousand steps a second on a loaded 2-core machine, a few thousand on an idle one: 10^8 steps
# are already a day or more, so a larger count (--steps 100000000000000, or --t-end 1e6 --dt
# 1e-6) is a typo, not a plan. A long run wants a larger --dt or an adaptive integrator.
MAX_STEPS = 10**8


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors are one line (plus exit code 2), and an option must be spelled
    out: with prefix matching ``--step 5`` would silently mean ``--steps 5``."""

    def __init__(self, *args, **kwargs):
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        raise ConfigError(message)


def _version() -> str:
    """The installed package's version (from its metadata), or the source tree's when the
    package is run from a checkout that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("taichi_sim")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path

        pyproject = Path(__file__).resolve().parent.parent / "pyproject.toml"
        return tomllib.loads(pyproject.read_text())["project"]["version"]


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def _assignment(text: str) -> tuple[str, str]:
    name, sep, value = text.partition("=")
    if not sep or not name:
        raise argparse.ArgumentTypeError(f"expects NAME=VALUE, got {text!r}")
    return name.strip(), value.strip()


def _name_list(text: str) -> list[str]:
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not 2 <= len(names) <= 3:
        raise argparse.ArgumentTypeError(f"expects 2 or 3 comma-separated integrator names, got {text!r}")
    return names


_SET_HELP = "scene parameter; repeat for several, each at most once (see `taichi-sim list`)"
_PRECISION_HELP = "floating-point precision of every state and parameter field (default f64)"
_ARCH_HELP = ("where the simulation runs: cpu (default) or gpu (CUDA, Vulkan or Metal, whichever "
              "Taichi finds; the choice is printed)")


def _add_view_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``demo`` and ``record``: what to run and how."""
    which = p.add_mutually_exclusive_group()
    which.add_argument("--integrator", default=None,
                       help="integrator name (default: the scene's), or package.module:Class or "
                            "path/to/file.py:Class (see docs/plugins.md)")
    which.add_argument("--side-by-side", dest="side_by_side", type=_name_list, metavar="A,B[,C]",
                       help="run the scene with 2 or 3 integrators at once, drawn next to each other")
    p.add_argument("--dt", type=_positive_float, default=None, help="step size in s (default: the scene's)")
    p.add_argument("--set", dest="assignments", action="append", type=_assignment, default=[],
                   metavar="NAME=VALUE", help=_SET_HELP)
    p.add_argument("--seed", type=int, default=0, help="random seed for scenes with randomness (default 0)")
    p.add_argument("--curves", metavar="FILE", default=None,
                   help="JSON file of parameter curves over time (see docs/constraints-and-curves.md)")
    p.add_argument("--precision", choices=("f32", "f64"), default="f64", help=_PRECISION_HELP)
    p.add_argument("--arch", choices=("cpu", "gpu"), default="cpu",
                   help=_ARCH_HELP + "; rendering always uses Vulkan")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="taichi-sim", description="Particle and mass-spring simulation on Taichi.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)

    sub.add_parser("list", help="list scenes (with parameters) and integrators (with order)")

    sim = sub.add_parser("simulate", help="run a scene headless and write an .npz")
    sim.add_argument("scene", help="scene name (see `taichi-sim list`)")
    sim.add_argument("--integrator", default=None,
                     help="integrator name (default: the scene's), or your own class as package.module:Class "
                          "or path/to/file.py:Class (see docs/plugins.md)")
    sim.add_argument("--dt", type=_positive_float, default=None,
                     help="step size in s (default: the scene's; adaptive methods: the first step, "
                          "chosen automatically)")
    length = sim.add_mutually_exclusive_group(required=True)
    length.add_argument("--steps", type=_positive_int, metavar="N", help="number of steps to take")
    length.add_argument("--t-end", type=_positive_float, metavar="T",
                        help="end time in s (the last step is shortened to land on it)")
    sim.add_argument("--precision", choices=("f32", "f64"), default="f64", help=_PRECISION_HELP)
    sim.add_argument("--arch", choices=("cpu", "gpu"), default="cpu", help=_ARCH_HELP)
    sim.add_argument("--set", dest="assignments", action="append", type=_assignment, default=[],
                     metavar="NAME=VALUE", help=_SET_HELP)
    sim.add_argument("--rtol", type=_positive_float, help="relative tolerance (adaptive methods)")
    sim.add_argument("--atol", type=_positive_float, help="absolute tolerance (adaptive methods)")
    sim.add_argument("--linear-solver", choices=("cg", "direct"),
                     help="linear solver of the implicit methods (default cg)")
    sim.add_argument("--max-step", type=_positive_float,
                     help="largest step of an adaptive method in s (default: unbounded, or 10x the "
                          "scene's default dt when the scene has collisions, tearing or emission)")
    sim.add_argument("--cg-tolerance", type=_positive_float,
                     help="relative residual at which CG stops (implicit methods; default 1e-3 for "
                          "implicit_euler_linearised, adaptive (forcing terms) for implicit_euler on "
                          "particles, else 1e-8 in f64 / 1e-5 in f32)")
    sim.add_argument("--newton-iterations", type=_positive_int,
                     help="most Newton iterations per implicit step, before the step is split "
                          "(default 50)")
    sim.add_argument("--newton-tolerance", type=_positive_float,
                     help="relative nonlinear residual at which Newton stops, in (0, 1) (default 1e-3 "
                          "for implicit_euler on particles, else 1e-6 in f64 / 1e-5 in f32)")
    sim.add_argument("--substeps", type=_positive_int,
                     help="substeps per step of xpbd (default 20)")
    sim.add_argument("--iterations", type=_positive_int,
                     help="Gauss-Seidel sweeps per substep of xpbd (default 1), or local/global "
                          "iterations per step of projective_dynamics (default 10)")
    sim.add_argument("--pd-tolerance", dest="tolerance", type=_positive_float,
                     help="projective_dynamics stops iterating once an iteration moves no particle "
                          "by more than this fraction of the step's largest displacement, in (0, 1)")
    sim.add_argument("--chebyshev-rho", type=float,
                     help="projective_dynamics' Chebyshev acceleration: the spectral radius "
                          "estimate in [0, 1) (default 0: off)")
    sim.add_argument("--option", dest="integrator_options", action="append", type=_assignment, default=[],
                     metavar="NAME=VALUE",
                     help="a keyword option of the integrator's constructor, e.g. a plug-in's own; repeat "
                          "for several (`taichi-sim list` shows each method's options)")
    sim.add_argument("--max-residual", type=_positive_float, metavar="R",
                     help="bound on the relative residual of a method that solves a system per step "
                          "(default 1e-2): above it implicit_euler and implicit_midpoint end not_converged "
                          "(exit 1), projective_dynamics, xpbd and the linearised step warn")
    sim.add_argument("--max-energy-growth", type=_positive_float, metavar="F",
                     help="the blow-up guard's energy bound: the run is diverged when its energy "
                          "rises more than F energy scales above the start (default 10)")
    sim.add_argument("--seed", type=int, default=0,
                     help="random seed for scenes with randomness (jitter, wind gusts, tearing noise, "
                          "the sprinkler; default 0)")
    sim.add_argument("--save-every", type=int, default=None, metavar="K",
                     help="keep the positions every K steps, at the start and at the end, in the npz "
                          "(x_history, t_history; default: only the final state)")
    sim.add_argument("--energy-every", type=int, default=None, metavar="K",
                     help="sample energy (and check for a blow-up) every K steps (0: never; default: "
                          "at the blow-up guard's checks, 1, 2, 4, ..., 64 and then "
                          "every 100 force evaluations, at most about 2000 samples). A sample costs "
                          "about two force evaluations")
    sim.add_argument("--out", required=True, help="output .npz path")
    sim.add_argument("--curves", metavar="FILE", default=None,
                     help="JSON file of parameter curves over time (see docs/constraints-and-curves.md)")
    sim.add_argument("--quiet", action="store_true", help="no summary line or progress bar")

    demo = sub.add_parser("demo", help="the interactive launcher (needs a display and Vulkan)")
    demo.add_argument("scene", nargs="?", default="cloth", help="scene to start with (default cloth)")
    _add_view_options(demo)
    demo.add_argument("--substeps", type=_positive_int, default=None,
                      help="a fixed number of steps per drawn frame (default: as many as keep "
                           "simulated time with the clock)")
    demo.add_argument("--size", default="1280x800", metavar="WxH", help="window size in pixels")

    rec = sub.add_parser("record", help="render a scene offscreen into .mp4, .gif or a folder of PNGs")
    rec.add_argument("scene", nargs="?", help="scene to record (not with --showcase)")
    _add_view_options(rec)
    rec.add_argument("--seconds", type=_positive_float, help="video length in s (default 5)")
    rec.add_argument("--fps", type=_positive_float, help="video frames per second (default 30)")
    rec.add_argument("--size", metavar="WxH", help="video size in pixels (default 1280x720)")
    rec.add_argument("--speed", type=_positive_float,
                     help="simulated seconds per video second (default 1)")
    rec.add_argument("--energy", action=argparse.BooleanOptionalAction, default=None,
                     help="plot each run's kinetic, gravitational, spring and total energy under its "
                          "panel (default: on with --side-by-side)")
    rec.add_argument("--strain", action="store_true",
                     help="colour the cloth by spring strain, with a colour bar")
    dest = rec.add_mutually_exclusive_group(required=True)
    dest.add_argument("--out", help="FILE.mp4, FILE.gif, or DIR/ for PNG frames")
    dest.add_argument("--showcase", metavar="DIR", nargs="?", const="media",
                      help="record the full showcase, the README's gallery (a GIF and a PNG per "
                           "entry, 5 to 15 minutes), into DIR (default media/)")
    rec.add_argument("--quiet", action="store_true", help="no summary line or progress bar")

    bench = sub.add_parser("bench", help="measure accuracy, stability and speed (CSV, JSON and PNG into --out)")
    bench_sub = bench.add_subparsers(
        dest="bench_command", parser_class=_Parser, required=True,
        metavar="{work-precision,stability,throughput,extremes,stiff-cloth,precision,all}")
    descriptions = {
        "work-precision": "error against cost for every integrator on each scene, and the observed orders",
        "stability": "largest stable step of every integrator, bisected, against C/omega_max",
        "throughput": "particle-steps/s by grid, precision and feature; against the Taichi and warp peers",
        "extremes": "every integrator at extreme stiffness and step: bounded, reported, or a silent "
                    "blow-up (exit 1)",
        "stiff-cloth": "the large-step methods on a stiff cloth: error against wall time against a fine "
                       "symplectic Euler reference, and their artificial damping",
        "precision": "every method on a stiff and a soft cloth in f32 and f64: how far f32 ends from f64, the "
                     "statuses and solver residuals (an f32 run that disagrees and says ok is a finding)",
        "all": "work-precision, stability and throughput, one after the other, with their default "
               "options (extremes is not included: run `bench extremes`); each writes its NAME.csv, "
               "NAME.json and NAME.png into --out",
    }
    bench_parsers = {name: bench_sub.add_parser(name, help=text, description=text)
                     for name, text in descriptions.items()}
    for name, p in bench_parsers.items():
        written = ("work-precision, stability and throughput .csv, .json and .png" if name == "all"
                   else f"{name}.csv, .json and .png")
        p.add_argument("--out", required=True, metavar="DIR", help=f"folder for {written}")
        p.add_argument("--quick", action="store_true", help="tiny sizes and few repeats (smoke test)")
        p.add_argument("--quiet", action="store_true", help="no tables or progress bar")
        if name != "all":
            p.add_argument("--integrators", metavar="A,B,...", help="integrators to measure (default: all)")
    wp = bench_parsers["work-precision"]
    wp.add_argument("--scenes", metavar="A,B,...", help="of simple,spring,pendulum,cloth (default: all)")
    wp.add_argument("--repeats", type=_positive_int, help="timed runs per point (default 5; --quick 1)")
    wp.add_argument("--budget", type=_positive_float, metavar="S",
                    help="seconds per (scene, integrator) before finer steps are skipped (default 120)")
    st = bench_parsers["stability"]
    st.add_argument("--systems", metavar="A,B,...", help="of oscillator,chain,cloth (default: all)")
    st.add_argument("--periods", type=_positive_float, help="periods of the fastest mode per trial (default 1000)")
    st.add_argument("--rel-tol", type=_positive_float, help="relative width of the final bracket (default 1e-3)")
    st.add_argument("--max-steps", type=_positive_int, help="most steps of one trial (default 20000)")
    ex = bench_parsers["extremes"]
    ex.add_argument("--scenes", metavar="A,B,...",
                    help="of spring,pendulum,cloth, and clothN for an N x N cloth (default: the first three)")
    ex.add_argument("--stiffnesses", metavar="K,K,...", help="spring stiffness in N/m (default 1,1e4,1e8)")
    ex.add_argument("--step-sizes", metavar="H,H,...", help="steps in s, fractions allowed (default 1e-6,1/60,1)")
    ex.add_argument("--steps", type=_positive_int, help="steps per run (default 30; --quick 10)")
    sc = bench_parsers["stiff-cloth"]
    sc.add_argument("--size", type=_positive_int, help="cloth side (default 64; --quick 8)")
    sc.add_argument("--stiffnesses", metavar="K,K,...", help="structural stiffness in N/m (default 1e2,1e4,1e8)")
    sc.add_argument("--step-sizes", metavar="H,H,...", help="steps in s, fractions allowed (default 1/60,1/120,1/240,1/480)")
    sc.add_argument("--t-end", type=_positive_float, help="simulated time in s (default 0.5)")
    sc.add_argument("--budget", type=_positive_float, metavar="S",
                    help="seconds of one run above which finer steps of that method are skipped (default 60)")
    pr = bench_parsers["precision"]
    pr.add_argument("--scenes", metavar="A,B,...", help="of stiff,soft (default: both)")
    pr.add_argument("--t-end", type=_positive_float, help="simulated time in s (default 0.25; --quick 0.02)")
    for name in ("extremes", "stiff-cloth", "precision", "stability", "work-precision", "all"):  # docs/sweeps.md
        p = bench_parsers[name]
        p.add_argument("--jobs", type=_positive_int, metavar="N",
                       help="cases at once on this machine, each in its own process (default: the cores)")
        p.add_argument("--scheduler", metavar="ADDRESS",
                       help="run the cases on the Dask cluster at ADDRESS (tcp://host:8786) instead")
        p.add_argument("--case-timeout", type=_positive_float, metavar="S", default=1800.0,
                       help="stop a case after S s and record `timeout` (default 1800)")
        p.add_argument("--fresh", action="store_true",
                       help="replace the table in --out (default: keep its finished cases and run the rest)")
    tp = bench_parsers["throughput"]
    tp.add_argument("--sizes", metavar="N,N,...", help="grid sides (default 32,64,128,256,512; --quick 8,16)")
    tp.add_argument("--precisions", metavar="f32,f64", help="default both (--quick f32)")
    tp.add_argument("--dt", type=_positive_float, help="step in s (default 1e-4)")
    tp.add_argument("--repeats", type=_positive_int, help="timed batches (default 7; --quick 5)")
    tp.add_argument("--batch-seconds", type=_positive_float, help="length of a timed batch (default 0.25 s)")
    tp.add_argument("--features-size", type=_positive_int, help="grid side of the features comparison")
    tp.add_argument("--no-features", action="store_true", help="skip the features comparison")
    tp.add_argument("--no-peers", action="store_true", help="skip the Taichi and warp peers")

    adv = sub.add_parser("advise", help="predicted stability limits and the cheapest integrator for a target error")
    adv.add_argument("scene", help="scene name (see `taichi-sim list`)")
    adv.add_argument("--set", dest="assignments", action="append", type=_assignment, default=[],
                     metavar="NAME=VALUE", help=_SET_HELP)
    adv.add_argument("--target-error", type=_positive_float, metavar="E",
                     help="largest position error (m) wanted at --t-end: recommend an integrator and step")
    adv.add_argument("--t-end", type=_positive_float, default=1.0, help="simulated time in s (default 1)")
    adv.add_argument("--integrators", metavar="A,B,...", help="candidates for the recommendation (default: all)")
    adv.add_argument("--precision", choices=("f32", "f64"), default="f64", help=_PRECISION_HELP)
    adv.add_argument("--arch", choices=("cpu", "gpu"), default="cpu", help=_ARCH_HELP)
    adv.add_argument("--seed", type=int, default=0, help="random seed for scenes with randomness (default 0)")

    chk = sub.add_parser("check", help="look for a cloth passing through itself in a saved run's frames")
    chk.add_argument("npz", help="a run written by `simulate` (with --save-every for every frame)")
    return parser


def cmd_check(args) -> int:
    """Self-intersections in every frame of a saved run (x_history, or the final x): exit 0 when
    none, 1 when some frame has any."""
    import os
    import zipfile

    import numpy as np

    from .geometry import self_intersections

    # np.load reads any file but a zip or .npy as a pickle, and refuses it talking of pickles
    if os.path.isfile(args.npz) and not zipfile.is_zipfile(args.npz):
        raise ConfigError(f"{args.npz} is not a run's npz (not a zip archive): give a file "
                          "written by `taichi-sim simulate --out RUN.npz`")
    try:
        with np.load(args.npz) as data:
            arrays = {k: data[k] for k in ("triangles", "x", "x_history", "t_history", "t", "scene")
                      if k in data.files}
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read {args.npz} as a run's npz: {exc}") from None
    if "triangles" not in arrays or "x" not in arrays:
        raise ConfigError(f"{args.npz} has no cloth surface (no `triangles`): only cloth scenes can be checked")
    frames = arrays.get("x_history", arrays["x"][None])
    times = arrays.get("t_history", np.atleast_1d(arrays.get("t", np.nan)))
    counts, flat = [], 0
    for x in _frame_bar(frames):
        try:
            report = self_intersections(x, arrays["triangles"])
        except ValueError as exc:
            raise ConfigError(f"{args.npz}: {exc}") from None
        counts.append(report.count)
        flat = max(flat, len(report.degenerate))
    counts = np.asarray(counts)
    name = str(arrays.get("scene", "run"))
    # zero-area triangles have no inside to pass through: left out, and said so
    unchecked = f" ({flat} zero-area triangle(s) in some frame, not checked)" if flat else ""
    if not counts.any():
        print(f"{name}: {len(counts)} frame(s), no triangles intersect{unchecked}")
        return 0
    worst = int(counts.argmax())
    print(f"{name}: {int((counts > 0).sum())} of {len(counts)} frame(s) have intersecting triangles; "
          f"first at t = {times[int(np.argmax(counts > 0))]:.6g} s, most ({counts[worst]} pairs) at "
          f"t = {times[worst]:.6g} s{unchecked}")
    return 1


def _frame_bar(frames):
    from tqdm import tqdm

    return tqdm(frames, unit="frame", leave=False, disable=None, mininterval=0.5)


def cmd_list(args) -> int:
    from .integrators import ENTRY_POINT_GROUP, INTEGRATORS, installed_plugins, integrator_class
    from .scene import SCENES

    print("Scenes (set parameters with --set NAME=VALUE):")
    for preset in SCENES.values():
        print(f"\n  {preset.name}: {preset.description}")
        print(f"    default integrator {preset.default_integrator}, default dt {preset.default_dt:g} s")
        for p in preset.params:
            default = str(p.default).lower() if isinstance(p.default, bool) else p.default
            unit = f" {p.unit}" if p.unit else ""
            print(f"    {p.name:<20} {str(default) + unit:<14} {p.meaning}")
    print("\nIntegrators (options: --option NAME=VALUE, or the flags of `simulate`):")
    for cls in INTEGRATORS.values():
        _print_integrator(cls.name, cls)
    plugins = installed_plugins()
    print(f"\nPlug-ins installed (entry-point group {ENTRY_POINT_GROUP}; or give --integrator "
          f"package.module:Class, see docs/plugins.md):" + ("" if plugins else " none"))
    for name in plugins:
        try:
            _print_integrator(name, integrator_class(name))
        except ConfigError as exc:
            print(f"  {name:<18} not usable: {exc}")
    return 0


def _print_integrator(name: str, cls) -> None:
    print(f"  {name:<18} order {cls.order}  {cls.description}")
    if cls.options():
        shown = ", ".join(f"{k}={'(automatic)' if v is None else v}" for k, v in cls.options().items())
        print(f"  {'':<18} options: {shown}")


def cmd_simulate(args) -> int:
    from . import io, runtime
    from .convergence import check_max_residual
    from .guard import GuardLimits
    from .integrators import check_options, create_integrator, integrator_class, parse_options
    from .run import check_run_args, planned_steps, run
    from .scene import build_scene, scene_preset
    from .scene.params import resolve
    from .scene.presets import check_scene_memory
    from .theory import stability_warning

    preset = scene_preset(args.scene)
    integrator_name = args.integrator or preset.default_integrator
    options = {name: getattr(args, name)
               for name in ("rtol", "atol", "linear_solver", "newton_iterations", "newton_tolerance",
                            "max_step", "cg_tolerance", "substeps", "iterations", "tolerance",
                            "chebyshev_rho")
               if getattr(args, name) is not None}
    for name, value in parse_options(integrator_name, scene_assignments(args.integrator_options, "--option")).items():
        if name in options:
            raise ConfigError(f"--option {name} repeats a value given by its own flag; give it once")
        options[name] = value
    adaptive = check_options(integrator_name, options).adaptive
    dt = args.dt if args.dt is not None or adaptive else preset.default_dt
    check_run_args(dt, args.steps, args.t_end, adaptive=adaptive)
    _check_step_count(args.steps, dt, args.t_end, planned_steps)
    if args.energy_every is not None and args.energy_every < 0:
        raise ConfigError(f"--energy-every must be >= 0, got {args.energy_every}")
    if args.save_every is not None and args.save_every < 1:
        raise ConfigError(f"--save-every must be >= 1, got {args.save_every}")
    check_max_residual(args.max_residual)
    params = scene_assignments(args.assignments)
    limits = GuardLimits() if args.max_energy_growth is None else GuardLimits(energy_growth=args.max_energy_growth)
    io.check_output_path(args.out)
    check_scene_memory(preset, resolve(preset.params, preset.name, params), precision=args.precision,
                       integrators=(integrator_class(integrator_name),),
                       linear_solver=options.get("linear_solver") or "cg")
    curves = _load_curves(args, preset)
    if args.save_every:
        _check_history_memory(preset, resolve(preset.params, preset.name, params), args.save_every,
                              args.steps if args.steps is not None else
                              (planned_steps(dt, args.t_end) if dt is not None else None))

    runtime.init(arch=args.arch, precision=args.precision)
    scene = build_scene(args.scene, params, seed=args.seed)
    if adaptive and scene.post_step and "max_step" not in options:
        options["max_step"] = 10 * preset.default_dt  # events act only between steps
    integrator = create_integrator(integrator_name, scene.system, **options)
    warning = stability_warning(scene, integrator_name, None if adaptive else dt)
    if warning:  # warn, never refuse
        print(f"taichi-sim: warning: {warning}", file=sys.stderr)
    result = run(scene, integrator, dt=dt, steps=args.steps, t_end=args.t_end,
                 energy_every=args.energy_every, progress=None if not args.quiet else False, guard=limits,
                 curves=curves, save_every=args.save_every, max_residual=args.max_residual)
    arrays = io.run_arrays(scene, result, integrator=integrator, dt=dt)
    if curves:
        import numpy as np

        from .curves import curves_json

        arrays["curves"] = np.asarray(curves_json(curves, scene.name))  # the curves it ran with
    path = io.save_npz(args.out, arrays)
    if result.message:
        print(f"taichi-sim: {result.message}", file=sys.stderr)
    for warning in result.warnings:
        print(f"taichi-sim: warning: {warning}", file=sys.stderr)
    for event in scene.post_step:
        if getattr(event, "warning", None) and event.warning():
            print(f"taichi-sim: warning: {event.warning()}", file=sys.stderr)
    if not args.quiet:
        rejected = f" ({result.rejected_steps} rejected)" if result.rejected_steps else ""
        print(f"{scene.name}: {result.steps} steps{rejected} of {integrator_name} to t = {result.t:.6g} s, "
              f"{result.f_evals} f-evals, {result.wall_time:.3f} s on {runtime.backend()}, "
              f"status {result.status.value} -> {path}")
        if len(result.solver_residual):
            worst = result.worst_residual
            verdict = "converged" if worst <= result.max_residual else "NOT converged"
            print(f"{scene.name}: solver residual at most {worst:.3g} (t = {_residual_time(result):.6g} s) over "
                  f"{len(result.solver_residual)} sampled steps, bound {result.max_residual:.3g}: {verdict}")
        elif result.residual_note and integrator.equation is not None:
            print(f"{scene.name}: solver residual not measured: {result.residual_note}")
        for event in scene.post_step:
            if hasattr(event, "summary"):
                print(f"{scene.name}: {event.summary()}")
        if result.constraint_violation is not None and len(result.constraint_violation):
            print(f"{scene.name}: largest |C| over the constraints {float(result.constraint_violation.max()):.3g} m "
                  f"over the run, {result.constraint_violation[-1]:.3g} m at the end")
    return 0 if result.status.value == "ok" else 1


def _check_step_count(steps: int | None, dt: float | None, t_end: float | None, planned_steps) -> None:
    """Refuse more than MAX_STEPS steps, given as --steps or as --t-end / --dt (an adaptive
    run's count is unknown beforehand: not checked)."""
    if steps is not None and steps > MAX_STEPS:
        raise ConfigError(f"--steps {steps:,} is over the limit of {MAX_STEPS:,} steps (a day or more of "
                          "computing on the cheapest scene); take fewer, larger steps")
    if steps is None and dt is not None and planned_steps(dt, t_end) > MAX_STEPS:
        raise ConfigError(f"--t-end {t_end:g} s at --dt {dt:g} s is {planned_steps(dt, t_end):,} steps, over the "
                          f"limit of {MAX_STEPS:,} (a day or more of computing on the cheapest scene); "
                          "raise --dt, shorten --t-end or pick an adaptive integrator")


def _residual_time(result) -> float:
    import numpy as np

    values = np.nan_to_num(result.solver_residual, nan=-1.0)
    return float(result.residual_t[int(np.argmax(values))])


def _check_history_memory(preset, values, save_every: int, steps: int | None) -> None:
    """Refuse --save-every when the frames it keeps would not fit in memory (an adaptive run's
    step count is unknown beforehand: not checked)."""
    from .memory import available_bytes, format_bytes

    if steps is None:
        return
    frames = steps // save_every + 2
    need = 2 * frames * preset.size(values).particles * 3 * 8  # kept, then stacked for the npz
    available = available_bytes()
    if available is not None and need > available:
        raise ConfigError(f"--save-every {save_every}: {frames:,} frames need about {format_bytes(need)} but "
                          f"only {format_bytes(available)} of memory is available; save less often")


def cmd_bench(args) -> int:
    from .bench.commands import bench_main

    return bench_main(args)


def cmd_advise(args) -> int:
    from .bench.commands import advise_main

    return advise_main(args)


def _load_curves(args, preset) -> dict | None:
    """The curves of ``--curves FILE``, checked against the scene's parameters (ConfigError
    naming the file otherwise), or None."""
    if getattr(args, "curves", None) is None:
        return None
    from .curves import load_curves

    return load_curves(args.curves, preset)


def _session_args(args) -> dict:
    """Scene, integrators, parameters and step of ``demo`` / ``record``, checked before any
    Taichi work (ConfigError names the culprit)."""
    from .integrators import integrator_class
    from .scene import scene_preset
    from .scene.params import resolve
    from .scene.presets import check_scene_memory

    preset = scene_preset(args.scene)
    integrators = args.side_by_side or [args.integrator or preset.default_integrator]
    for name in integrators:
        integrator_class(name)
    params = scene_assignments(args.assignments)
    check_scene_memory(preset, resolve(preset.params, preset.name, params), precision=args.precision,
                       integrators=tuple(integrator_class(name) for name in integrators), copies=len(integrators))
    return {"scene": preset.name, "integrators": tuple(integrators), "params": params, "dt": args.dt,
            "curves": _load_curves(args, preset) or {}}


def cmd_demo(args) -> int:
    from . import runtime
    from .app.launcher import Launcher
    from .app.session import Session
    from .render import RenderUnavailable, has_display, parse_size

    size = parse_size(args.size)
    spec = _session_args(args)
    try:
        if not has_display():
            raise RenderUnavailable("an on-screen window needs a display (DISPLAY or WAYLAND_DISPLAY "
                                    "is not set); record a video instead with `taichi-sim record`")
        runtime.init(arch=args.arch, precision=args.precision)
        session = Session(spec["scene"], spec["integrators"], params=spec["params"], dt=spec["dt"],
                          substeps=args.substeps or 10, seed=args.seed, interactive=True)
        if args.substeps is not None:
            session.set_real_time(False)
        if spec["curves"]:
            session.set_curves(spec["curves"])
        Launcher(session, size, curves_path=args.curves).run()
    except RenderUnavailable as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return 0


def cmd_record(args) -> int:
    from . import runtime
    from .app.record import Clip, check_clip, record
    from .app.showcase import record_showcase
    from .render import RenderUnavailable, parse_size
    from .render.video import check_output

    if args.showcase is not None:
        extra = [flag for flag, given in (("SCENE", args.scene), ("--integrator", args.integrator),
                                          ("--side-by-side", args.side_by_side), ("--dt", args.dt),
                                          ("--set", args.assignments), ("--seconds", args.seconds),
                                          ("--fps", args.fps), ("--size", args.size),
                                          ("--speed", args.speed), ("--curves", args.curves),
                                          ("--energy", args.energy is not None),
                                          ("--strain", args.strain)) if given]
        if extra:
            raise ConfigError(f"--showcase records its own scenes and settings; drop {', '.join(extra)}")
        try:
            runtime.init(arch=args.arch, precision=args.precision)
            record_showcase(args.showcase, progress=None if not args.quiet else False,
                            on_clip=None if args.quiet else _print_clip)
        except RenderUnavailable as exc:
            print(f"taichi-sim: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
        return 0
    if args.scene is None:
        raise ConfigError("record needs a SCENE (or --showcase DIR)")
    spec = _session_args(args)
    clip = Clip(scene=spec["scene"], integrators=spec["integrators"], params=spec["params"],
                dt=spec["dt"], seconds=args.seconds or 5.0, fps=args.fps or 30.0,
                size=parse_size(args.size or "1280x720"), speed=args.speed or 1.0, seed=args.seed,
                curves=spec["curves"], strain=args.strain,
                energy=bool(args.side_by_side) if args.energy is None else args.energy)
    check_clip(clip)
    check_output(args.out, clip.size, clip.fps)
    try:
        runtime.init(arch=args.arch, precision=args.precision)
        result = record(clip, args.out, progress=None if not args.quiet else False)
    except RenderUnavailable as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    for line in result.failures:
        print(f"taichi-sim: {line}", file=sys.stderr)
    if not args.quiet:
        stopped = " (stopped early: every run failed)" if result.stopped else ""
        print(f"{result.path}: {result.frames} frames of {clip.size[0]}x{clip.size[1]} at "
              f"{clip.fps:g} fps ({result.frames / clip.fps:g} s of video){stopped}, {result.wall:.1f} s")
    return 1 if result.stopped else 0


def _print_clip(k: int, count: int, entry, recording) -> None:
    """One line per recorded clip, as it is done (flushed: also when stdout is a file or a pipe)."""
    print(f"  [{k}/{count}] {recording.path}  {recording.still}  ({recording.frames} frames, "
          f"{recording.wall:.1f} s): {entry.title}", flush=True)


QUICK_SHOWCASE_DIR = "out/showcase"  # untracked (git-ignored); media/ is the README's gallery


def cmd_default() -> int:
    """No arguments: the launcher where a display exists, else a short showcase recorded into
    out/showcase/ (the full one, into media/, is ``record --showcase``)."""
    from pathlib import Path

    from . import runtime
    from .app.display import display_problem
    from .app.launcher import Launcher
    from .app.session import Session
    from .app.showcase import QUICK_SHOWCASE, record_showcase
    from .render import RenderUnavailable

    try:
        runtime.init(arch="cpu", precision="f64")
        problem = display_problem()
        if problem is None:
            Launcher(Session("cloth", ["symplectic_euler"], interactive=True)).run()
            return 0
        print(f"taichi-sim: {problem}: recording a short showcase into {QUICK_SHOWCASE_DIR}/ instead",
              file=sys.stderr)
        print(f"Recording {len(QUICK_SHOWCASE)} short clips into {QUICK_SHOWCASE_DIR}/ (open the GIFs in "
              "a browser; the full gallery: taichi-sim record --showcase):", flush=True)
        try:
            Path(QUICK_SHOWCASE_DIR).parent.mkdir(exist_ok=True)
        except OSError as exc:
            raise ConfigError(f"cannot create {QUICK_SHOWCASE_DIR}/: {exc.strerror or exc}") from None
        record_showcase(QUICK_SHOWCASE_DIR, entries=QUICK_SHOWCASE, on_clip=_print_clip)
    except RenderUnavailable as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    return 0


EXIT_CLOSED_PIPE = 128 + 13  # what a shell reports for a program ended by SIGPIPE


def _stdout_closed() -> bool:
    """Whether stdout is a pipe whose reader has gone (``| head`` has read its lines)."""
    import select

    try:
        poll = select.poll()
        poll.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poll.poll(0))
    except (AttributeError, OSError, ValueError):  # not a file (captured), or already closed
        return False


def _closed_pipe() -> int:
    """End quietly after the reader of stdout went away: what is still buffered goes to
    /dev/null (else Python's final flush reports the broken pipe), and the exit status is a
    closed pipe's."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (AttributeError, OSError, ValueError):
        pass
    return EXIT_CLOSED_PIPE


def main(argv: list[str] | None = None) -> int:
    """Run one command; its exit status (0 done, 1 the run or check failed, 2 bad input, 130
    interrupted, 141 stdout closed by its reader)."""
    try:
        code = _main(argv)
        sys.stdout.flush()  # a closed pipe shows here, not in Python's flush at exit
        return code
    except SystemExit:  # --help and --version print, then exit
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            if _stdout_closed():
                raise SystemExit(_closed_pipe()) from None
            raise
        raise
    except BrokenPipeError:
        if not _stdout_closed():  # another pipe (ffmpeg's, say) broke: a real error
            raise
        return _closed_pipe()


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            return cmd_default()
        return {"list": cmd_list, "simulate": cmd_simulate, "demo": cmd_demo,
                "record": cmd_record, "bench": cmd_bench, "advise": cmd_advise,
                "check": cmd_check}[args.command](args)
    except ConfigError as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("taichi-sim: interrupted", file=sys.stderr)
        return 130
