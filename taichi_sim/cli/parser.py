"""The ``taichi-sim`` command line's parser: every command, its options and their checks (the
integrators' own options come from their declarations: :mod:`.integrator_flags`)."""
from __future__ import annotations

import argparse
import math

from ..errors import ConfigError
from .integrator_flags import add_integrator_flags, integrator_classes, tolerance_help

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors are one line (plus exit code 2), and an option must be spelled
    out: with prefix matching ``--step 5`` would silently mean ``--steps 5``."""

    def __init__(self, *args, **kwargs):
        kwargs["allow_abbrev"] = False
        super().__init__(*args, **kwargs)

    def error(self, message: str):
        raise ConfigError(message)

    def parse_known_args(self, args=None, namespace=None):
        # argparse checks the required arguments before it looks at unknown options, so
        # `advise --frobnicate` said "required: scene". A command's own parser (one without
        # subcommands, handed just its arguments) names an unknown option first.
        if args is not None and self._subparsers is None:
            unknown = self._unknown_options(args)
            if unknown:
                self.error(f"unrecognized arguments: {' '.join(unknown)}{self._suggestion(unknown)}")
        return super().parse_known_args(args, namespace)

    def _unknown_options(self, args) -> list[str]:
        """The tokens of ``args`` that look like options this parser does not have (a number is
        a value, ``--`` ends the options)."""
        unknown = []
        for token in args:
            if token == "--":
                break
            if len(token) < 2 or token[0] not in self.prefix_chars:
                continue
            if _is_number(token):  # a value ("-1", "-1e-3"): argparse says what it makes of it
                continue
            name = token.split("=", 1)[0] if token.startswith("--") else token[:2]
            if name not in self._option_string_actions:
                unknown.append(token)
        return unknown

    def _suggestion(self, unknown: list[str]) -> str:
        """"; did you mean --X?" for a single unknown option close to one of this parser's."""
        from ..errors import close_names

        if len(unknown) != 1 or not unknown[0].startswith("--"):
            return ""
        close = close_names(unknown[0].split("=", 1)[0], [o for o in self._option_string_actions if o.startswith("--")])
        return f"; did you mean {close[0]}?" if len(close) == 1 else ""


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class _VersionAction(argparse.Action):
    """``--version``: print the version, looked up only when asked for (reading the package's
    metadata took 0.1 s of every command's start), and exit."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS,
                 help="show program's version number and exit"):
        super().__init__(option_strings=option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {_version()}")
        parser.exit()


def _version() -> str:
    """The installed package's version (from its metadata), or the source tree's when the
    package is run from a checkout that was never installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("taichi_sim")
    except PackageNotFoundError:
        import tomllib
        from pathlib import Path

        pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
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


def _add_option(p: argparse.ArgumentParser, note: str) -> None:
    p.add_argument("--option", dest="integrator_options", action="append", type=_assignment, default=[],
                   metavar="NAME=VALUE",
                   help="a keyword option of the integrator's constructor, e.g. a plug-in's own; repeat "
                        f"for several (`taichi-sim list` shows each method's options){note}")


def _add_view_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``demo`` and ``record``: what to run and how."""
    which = p.add_mutually_exclusive_group()
    which.add_argument("--integrator", default=None,
                       help="integrator name (default: the scene's), or package.module:Class or "
                            "path/to/file.py:Class (see docs/plugins.md)")
    which.add_argument("--side-by-side", dest="side_by_side", type=_name_list, metavar="A,B[,C]",
                       help="run the scene with 2 or 3 integrators at once, drawn next to each other")
    _add_option(p, "; not with --side-by-side")
    p.add_argument("--dt", type=_positive_float, default=None, help="step size in s (default: the scene's)")
    p.add_argument("--set", dest="assignments", action="append", type=_assignment, default=[],
                   metavar="NAME=VALUE", help=_SET_HELP)
    p.add_argument("--seed", type=int, default=None, help="random seed for scenes with randomness (default 0)")
    p.add_argument("--curves", metavar="FILE", default=None,
                   help="JSON file of parameter curves over time (see docs/constraints-and-curves.md)")
    p.add_argument("--precision", choices=("f32", "f64"), default=None, help=_PRECISION_HELP)
    p.add_argument("--arch", choices=("cpu", "gpu"), default=None,
                   help=_ARCH_HELP + "; rendering always uses Vulkan")


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The command line's parser. ``simulate`` takes a flag for each integrator option declared
    with one (:mod:`.integrator_flags`), which imports the integrators: given the ``argv`` about
    to be parsed, they are imported only for a ``simulate`` command, and a plug-in it names with
    ``--integrator`` adds its own flags; without ``argv``, the built-ins' flags are there."""
    parser = _Parser(prog="taichi-sim", description="Particle and mass-spring simulation on Taichi.",
                     epilog="Without a command: the interactive launcher where a display exists, else a "
                            "short showcase recorded into ./out/showcase/.")
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)

    lst = sub.add_parser("list", help="list scenes (with parameters) and integrators (with order)")
    lst.add_argument("--scene-file", metavar="SCENE",
                     help="print SCENE as a scene file (TOML) with every parameter at its default, to edit "
                          "and run with `simulate FILE.toml` (see docs/scene-files.md)")

    sim = sub.add_parser("simulate", help="run a scene headless and write an .npz")
    sim.add_argument("scene", help="scene name (see `taichi-sim list`), or a scene file FILE.toml "
                                   "(options given here override the file's values)")
    sim.add_argument("--integrator", default=None,
                     help="integrator name (default: the scene's), or your own class as package.module:Class "
                          "or path/to/file.py:Class (see docs/plugins.md)")
    sim.add_argument("--dt", type=_positive_float, default=None,
                     help="step size in s (default: the scene's; adaptive methods: the first step, "
                          "chosen automatically)")
    length = sim.add_mutually_exclusive_group()  # required, unless a scene file gives it
    length.add_argument("--steps", type=_positive_int, metavar="N", help="number of steps to take")
    length.add_argument("--t-end", type=_positive_float, metavar="T",
                        help="end time in s (the last step is shortened to land on it)")
    sim.add_argument("--precision", choices=("f32", "f64"), default=None, help=_PRECISION_HELP)
    sim.add_argument("--arch", choices=("cpu", "gpu"), default=None, help=_ARCH_HELP)
    sim.add_argument("--set", dest="assignments", action="append", type=_assignment, default=[],
                     metavar="NAME=VALUE", help=_SET_HELP)
    classes = integrator_classes(argv)
    if classes is not None:
        add_integrator_flags(sim, classes)
    _add_option(sim, "")
    sim.add_argument("--tolerance", type=_positive_float, metavar="METRES",
                     help="how far a step's positions may be from the solution of the equation its method "
                          "solves (default 0.001 m; estimated at sampled steps)"
                          + (f": {tolerance_help(classes)}" if classes is not None else ""))
    sim.add_argument("--max-residual", type=_positive_float, metavar="R",
                     help="bound on the relative residual recorded beside the error estimate (default 1e-2)")
    sim.add_argument("--max-energy-growth", type=_positive_float, metavar="F",
                     help="the blow-up guard's energy bound: the run is diverged when its energy "
                          "rises more than F energy scales above the start (default 10)")
    sim.add_argument("--seed", type=int, default=None,
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
    sim.add_argument("--out", help="output .npz path (required unless a scene file names one)")
    sim.add_argument("--export", metavar="PATH",
                     help="also write the frames kept by --save-every for other tools: a folder of OBJ or "
                          "PLY files, or one USD file (see docs/export.md)")
    sim.add_argument("--export-format", metavar="obj|ply|usd", help="format of --export")
    sim.add_argument("--curves", metavar="FILE", default=None,
                     help="JSON file of parameter curves over time (see docs/constraints-and-curves.md)")
    sim.add_argument("--quiet", action="store_true", help="no summary line or progress bar")

    demo = sub.add_parser("demo", help="the interactive launcher (needs a display and Vulkan)")
    demo.add_argument("scene", nargs="?", default="cloth",
                      help="scene (or scene file FILE.toml) to start with (default cloth)")
    _add_view_options(demo)
    demo.add_argument("--substeps", type=_positive_int, default=None,
                      help="a fixed number of steps per drawn frame (default: as many as keep "
                           "simulated time with the clock)")
    demo.add_argument("--size", default="1280x800", metavar="WxH", help="window size in pixels")

    rec = sub.add_parser("record", help="render a scene offscreen into .mp4, .gif or a folder of PNGs")
    rec.add_argument("scene", nargs="?", help="scene (or scene file FILE.toml) to record (not with --showcase)")
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
    rec.add_argument("--contacts", action="store_true",
                     help="draw the contacts the integrator holds in its solve (as the launcher's x key "
                          "does)")
    dest = rec.add_mutually_exclusive_group(required=True)
    dest.add_argument("--out", help="FILE.mp4, FILE.gif, or DIR/ for PNG frames")
    dest.add_argument("--showcase", metavar="DIR", nargs="?", const="media",
                      help="record the full showcase, the README's gallery (a GIF and a PNG per "
                           "entry, 5 to 15 minutes), into DIR (default media/)")
    rec.add_argument("--only", metavar="NAME[,NAME...]",
                     help="with --showcase: re-record only these entries (e.g. cloth-fold), updating "
                          "their items in DIR/gallery.json")
    rec.add_argument("--fit", action="store_true",
                     help="frame what the run draws: the camera fixed on the box its points fill over the "
                          "clip, not on the scene's start (simulates the clip once more; one integrator)")
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
                    help="of spring,pendulum,cloth,membrane-stvk,membrane-neohookean,membrane-shells, and clothN for an N x N "
                    "cloth (default: all but clothN)")
    ex.add_argument("--stiffnesses", metavar="K,K,...", help="spring stiffness, or a membrane's E t, in N/m (default 1,1e4,1e8)")
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
    adv.add_argument("--budget", type=_positive_float, metavar="S", default=20.0,
                     help="at most S seconds of pilot runs, compiling included (default 20)")
    adv.add_argument("--precision", choices=("f32", "f64"), default="f64", help=_PRECISION_HELP)
    adv.add_argument("--arch", choices=("cpu", "gpu"), default="cpu", help=_ARCH_HELP)
    adv.add_argument("--seed", type=int, default=0, help="random seed for scenes with randomness (default 0)")

    exp = sub.add_parser("export", help="write a saved run's frames as OBJ or PLY files, or one USD file")
    exp.add_argument("npz", help="a run written by `simulate --save-every K`")
    exp.add_argument("--format", required=True, metavar="obj|ply|usd",
                     help="obj or ply: a folder of frame_NNNN files; usd: one .usda, .usdc or .usd file")
    exp.add_argument("--out", required=True, metavar="PATH", help="the folder (obj, ply) or file (usd) to write")
    exp.add_argument("--quiet", action="store_true", help="no summary line or progress bar")

    chk = sub.add_parser("check", help="look for a cloth passing through itself, or into an object, in a saved "
                                       "run's frames")
    chk.add_argument("npz", help="a run written by `simulate` (with --save-every for every frame)")
    return parser
