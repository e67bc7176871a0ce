"""The ``taichi-sim`` command line."""
from __future__ import annotations

import argparse
import math
import sys

from .errors import ConfigError

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse, but usage errors are one line (plus exit code 2)."""

    def error(self, message: str):
        raise ConfigError(message)


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


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="taichi-sim", description="Particle and mass-spring simulation on Taichi.")
    sub = parser.add_subparsers(dest="command", parser_class=_Parser)

    sub.add_parser("list", help="list scenes (with parameters) and integrators (with order)")

    sim = sub.add_parser("simulate", help="run a scene headless and write an .npz")
    sim.add_argument("scene")
    sim.add_argument("--integrator", default=None, help="integrator name (default: the scene's)")
    sim.add_argument("--dt", type=_positive_float, default=None, help="step size in s")
    length = sim.add_mutually_exclusive_group(required=True)
    length.add_argument("--steps", type=_positive_int)
    length.add_argument("--t-end", type=_positive_float, help="end time in s")
    sim.add_argument("--precision", choices=("f32", "f64"), default="f64")
    sim.add_argument("--arch", choices=("cpu", "gpu"), default="cpu")
    sim.add_argument("--set", dest="assignments", action="append", type=_assignment, default=[],
                     metavar="NAME=VALUE", help="scene parameter (repeatable); see `taichi-sim list`")
    sim.add_argument("--rtol", type=_positive_float, help="relative tolerance (adaptive methods)")
    sim.add_argument("--atol", type=_positive_float, help="absolute tolerance (adaptive methods)")
    sim.add_argument("--linear-solver", choices=("cg", "direct"),
                     help="linear solver of the implicit methods (default cg)")
    sim.add_argument("--newton-iterations", type=_positive_int,
                     help="Newton iterations per implicit step")
    sim.add_argument("--seed", type=int, default=0, help="random seed for scenes with randomness")
    sim.add_argument("--energy-every", type=int, default=None, metavar="K",
                     help="sample energy every K steps (0: never; default: every step up to 2000 "
                          "steps, else about 2000 samples)")
    sim.add_argument("--out", required=True, help="output .npz path")
    sim.add_argument("--quiet", action="store_true", help="no summary line or progress bar")
    return parser


def cmd_list(args) -> int:
    from .integrators import INTEGRATORS
    from .scene import SCENES

    print("Scenes (set parameters with --set NAME=VALUE):")
    for preset in SCENES.values():
        print(f"\n  {preset.name}: {preset.description}")
        print(f"    default integrator {preset.default_integrator}, default dt {preset.default_dt:g} s")
        for p in preset.params:
            default = str(p.default).lower() if isinstance(p.default, bool) else p.default
            unit = f" {p.unit}" if p.unit else ""
            print(f"    {p.name:<20} {str(default) + unit:<14} {p.meaning}")
    print("\nIntegrators:")
    for cls in INTEGRATORS.values():
        print(f"  {cls.name:<18} order {cls.order}  {cls.description}")
    return 0


def cmd_simulate(args) -> int:
    from . import io, runtime
    from .integrators import create_integrator, integrator_class
    from .run import check_run_args, run
    from .scene import build_scene, scene_preset

    preset = scene_preset(args.scene)
    integrator_name = args.integrator or preset.default_integrator
    integrator_cls = integrator_class(integrator_name)
    adaptive = integrator_cls.adaptive
    dt = args.dt if args.dt is not None or adaptive else preset.default_dt
    check_run_args(dt, args.steps, args.t_end, adaptive=adaptive)
    options = {name: getattr(args, name) for name in ("rtol", "atol", "linear_solver", "newton_iterations")
               if getattr(args, name) is not None}
    if args.energy_every is not None and args.energy_every < 0:
        raise ConfigError(f"--energy-every must be >= 0, got {args.energy_every}")
    params = dict(args.assignments)
    io.check_output_path(args.out)

    runtime.init(arch=args.arch, precision=args.precision)
    scene = build_scene(args.scene, params, seed=args.seed)
    integrator = create_integrator(integrator_name, scene.system, **options)
    result = run(scene, integrator, dt=dt, steps=args.steps, t_end=args.t_end,
                 energy_every=args.energy_every, progress=None if not args.quiet else False)
    path = io.save_npz(args.out, io.run_arrays(scene, result, integrator=integrator, dt=dt))
    if result.message:
        print(f"taichi-sim: {result.message}", file=sys.stderr)
    if not args.quiet:
        rejected = f" ({result.rejected_steps} rejected)" if result.rejected_steps else ""
        print(f"{scene.name}: {result.steps} steps{rejected} of {integrator_name} to t = {result.t:.6g} s, "
              f"{result.f_evals} f-evals, {result.wall_time:.3f} s on {runtime.backend()}, "
              f"status {result.status.value} -> {path}")
    return 0 if result.status.value == "ok" else 1


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:
            parser.print_help()
            return 0
        return {"list": cmd_list, "simulate": cmd_simulate}[args.command](args)
    except ConfigError as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("taichi-sim: interrupted", file=sys.stderr)
        return 130
