"""The ``taichi-sim`` command line."""
from __future__ import annotations

import math
import sys
import warnings

from . import interrupt
from .cli_export import cmd_export, export_frames, export_request
from .cli_parser import EXIT_USAGE, build_parser
from .errors import ConfigError, InputNote, InputWarning

# The most steps one `simulate` takes. The cheapest scene (the circle ODE, RK4) runs at about a
# thousand steps a second on a loaded 2-core machine, a few thousand on an idle one: 10^8 steps
# are already a day or more, so a larger count (--steps 100000000000000, or --t-end 1e6 --dt
# 1e-6) is a typo, not a plan. A long run wants a larger --dt or an adaptive integrator.
MAX_STEPS = 10**8


def cmd_check(args) -> int:
    """Self-intersections, and vertices inside the scene's objects, in every frame of a saved
    run (x_history, or the final x): exit 0 when none, 1 when some frame has any."""
    from .frame_check import check_run, load_run

    lines, passed = check_run(load_run(args.npz), progress=_frame_bar)
    print("\n".join(lines))
    return 0 if passed else 1


def _frame_bar(frames):
    from tqdm import tqdm

    return tqdm(frames, unit="frame", leave=False, disable=None, mininterval=0.5)


def cmd_list(args) -> int:
    from .integrators import ENTRY_POINT_GROUP, INTEGRATORS, installed_plugins, integrator_class, method_label
    from .scene import SCENES, scene_preset

    if args.scene_file is not None:
        from .scene_file import scene_file_text

        print(scene_file_text(scene_preset(args.scene_file)), end="")
        return 0
    print("Scenes (set parameters with --set NAME=VALUE):")
    for preset in SCENES.values():
        print(f"\n  {preset.name}: {preset.description}")
        method = method_label(preset.default_integrator, preset.options_for(preset.default_integrator))
        print(f"    default integrator {method}, default dt {preset.default_dt:g} s")
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
    from .convergence import check_max_residual, check_tolerance, format_metres
    from .guard import GuardLimits
    from .integrators import check_options, create_integrator, integrator_class, method_label, parse_options
    from .run import check_run_args, planned_steps, run
    from .scene import build_scene, scene_preset
    from .scene.params import resolve, scene_assignments
    from .scene.presets import check_scene_memory
    from .theory import stability_warning, step_limited

    preset = scene_preset(args.scene)
    missing = [what for what, absent in (
        ("--steps N or --t-end T (or a scene file's [run] steps or duration)", args.steps is None and args.t_end is None),
        ("--out FILE.npz (or a scene file's [output] npz)", args.out is None)) if absent]
    if missing:  # both at once: one round of errors, not two
        raise ConfigError(f"simulate needs {' and '.join(missing)}")
    exporting = export_request(args)
    integrator_name = args.integrator or preset.default_integrator
    options = {name: getattr(args, name)
               for name in ("rtol", "atol", "linear_solver", "newton_iterations", "newton_tolerance",
                            "max_step", "cg_tolerance", "substeps", "iterations", "pd_tolerance",
                            "chebyshev_rho")
               if getattr(args, name) is not None}
    if "pd_tolerance" in options:
        options["tolerance"] = options.pop("pd_tolerance")
    for name, value in parse_options(integrator_name, scene_assignments(args.integrator_options, "--option")).items():
        if name in options:
            raise ConfigError(f"--option {name} repeats a value given by its own flag; give it once")
        options[name] = value
    given = frozenset(options)  # the caller's: --tolerance may raise the scene's, not these
    options = {**preset.options_for(integrator_name), **options}  # the scene's, unless told
    adaptive = check_options(integrator_name, options).adaptive
    dt = args.dt if args.dt is not None or adaptive else preset.default_dt
    check_run_args(dt, args.steps, args.t_end, adaptive=adaptive)
    if args.energy_every is not None and args.energy_every < 0:
        raise ConfigError(f"--energy-every must be >= 0, got {args.energy_every}")
    if args.save_every is not None and args.save_every < 1:
        raise ConfigError(f"--save-every must be >= 1, got {args.save_every}")
    check_max_residual(args.max_residual)
    check_tolerance(args.tolerance)
    params = scene_assignments(args.assignments)
    resolved = resolve(preset.params, preset.name, params)

    def check_planned(dt):
        """The step count and the saved frames' memory at step ``dt`` (s; None: adaptive)."""
        _check_step_count(args.steps, dt, args.t_end, planned_steps)
        if args.save_every:
            _check_history_memory(preset, resolved, args.save_every,
                                  args.steps if args.steps is not None else
                                  (planned_steps(dt, args.t_end) if dt is not None else None))

    check_planned(dt)
    limits = GuardLimits() if args.max_energy_growth is None else GuardLimits(energy_growth=args.max_energy_growth)
    io.check_output_path(args.out)
    check_scene_memory(preset, resolved, precision=args.precision, integrators=(integrator_class(integrator_name),),
                       linear_solver=options.get("linear_solver") or "cg")
    curves = _load_curves(args, preset)

    runtime.init(arch=args.arch, precision=args.precision)
    scene = build_scene(args.scene, params, seed=args.seed)
    start_warning = scene.start_warning()
    if start_warning:
        print(f"taichi-sim: warning: {start_warning}", file=sys.stderr)
    explicit_dt = scene.explicit_step
    if args.dt is None and not adaptive and step_limited(integrator_name) and explicit_dt < dt:
        # a fine cloth's particles are light: its explicit stable step is shorter than the preset's;
        # and the contact cloths' default (vbd) takes frame-sized steps
        print(f"taichi-sim: {integrator_name} takes this scene's step for explicit methods, {explicit_dt:g} s, "
              f"not the default {dt:g} s (at most 0.9 of symplectic Euler's stable step; give --dt to "
              f"choose)", file=sys.stderr)
        dt = explicit_dt
        check_planned(dt)
    if adaptive and scene.post_step and "max_step" not in options:
        options["max_step"] = 10 * preset.default_dt  # events act only between steps
    integrator = create_integrator(integrator_name, scene.system, **options)
    integrator.given_options = given
    warning = stability_warning(scene, integrator_name, None if adaptive else dt)
    if warning:  # warn, never refuse
        print(f"taichi-sim: warning: {warning}", file=sys.stderr)
    result = run(scene, integrator, dt=dt, steps=args.steps, t_end=args.t_end,
                 energy_every=args.energy_every, progress=None if not args.quiet else False, guard=limits,
                 curves=curves, save_every=args.save_every, max_residual=args.max_residual,
                 tolerance=args.tolerance)
    arrays = io.run_arrays(scene, result, integrator=integrator, dt=dt)
    if curves:
        import numpy as np

        from .curves import curves_json

        arrays["curves"] = np.asarray(curves_json(curves, scene.name))  # the curves it ran with
    path = io.save_npz(args.out, arrays)
    exported = export_frames(exporting, arrays, args) if exporting else None
    if result.message:
        print(f"taichi-sim: {result.message}", file=sys.stderr)
    for warning in result.warnings:
        print(f"taichi-sim: warning: {warning}", file=sys.stderr)
    replaced = getattr(integrator, "replaces_parts", ())  # parts whose work the method did in its solve
    for part in scene.parts:
        if part.name not in replaced and part.warning():
            print(f"taichi-sim: warning: {part.warning()}", file=sys.stderr)
    if not args.quiet:
        rejected = f" ({result.rejected_steps} rejected)" if result.rejected_steps else ""
        label = method_label(integrator_name, options)
        print(f"{scene.name}: {result.steps} steps{rejected} of {label} to t = {result.t:.6g} s, "
              f"{result.f_evals} f-evals, {result.wall_time:.3f} s on {runtime.backend()}{_rate(result)}, "
              f"status {result.status.value} -> {path}")
        if exported:
            print(exported)
        if len(result.error_estimate):
            worst = result.worst_error_estimate
            verdict = "within" if worst <= result.tolerance else "OVER"
            print(f"{scene.name}: estimated error <= {format_metres(worst)} (t = {_worst_time(result):.6g} s) over "
                  f"{len(result.error_estimate)} sampled steps, {verdict} --tolerance {format_metres(result.tolerance)} "
                  f"(solver residual at most {result.worst_residual:.3g}; the samples took "
                  f"{result.estimate_time:.2g} s, left out of steps/s)")
        elif result.residual_note and integrator.equation is not None:
            print(f"{scene.name}: error not estimated: {result.residual_note}")
        for part in scene.parts:
            if part.name in replaced:
                print(f"{scene.name}: {part.name}: done in {integrator_name}'s solve (its post-step event did not run)")
            elif part.summary():
                print(f"{scene.name}: {part.summary()}")
        if result.constraint_violation is not None and len(result.constraint_violation):
            print(f"{scene.name}: largest |C| over the constraints {float(result.constraint_violation.max()):.3g} m "
                  f"over the run, {result.constraint_violation[-1]:.3g} m at the end")
    return 0 if result.status.value == "ok" else 1


def _rate(result) -> str:
    """" (N steps/s after the first)" for the summary line: the rate with the first step's
    compiling left out, which on a short run is most of the wall time; "" for a run of one step."""
    rate = result.steps_per_second
    if not math.isfinite(rate):
        return ""
    return f" ({rate:,.0f} steps/s after the first)" if rate >= 100 else f" ({rate:.3g} steps/s after the first)"


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


def _worst_time(result) -> float:
    """The time (s) of the run's largest estimated error."""
    import numpy as np

    values = np.nan_to_num(result.error_estimate, nan=-1.0)
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
    from .integrators import check_options, integrator_class, parse_options
    from .scene import scene_preset
    from .scene.params import resolve, scene_assignments
    from .scene.presets import check_scene_memory

    preset = scene_preset(args.scene)
    integrators = args.side_by_side or [args.integrator or preset.default_integrator]
    for name in integrators:
        integrator_class(name)
    options = {}
    if args.integrator_options:
        if args.side_by_side:
            raise ConfigError("--option sets one integrator's options; drop it with --side-by-side")
        options = {integrators[0]: parse_options(integrators[0],
                                                 scene_assignments(args.integrator_options, "--option"))}
        check_options(integrators[0], options[integrators[0]])
    params = scene_assignments(args.assignments)
    check_scene_memory(preset, resolve(preset.params, preset.name, params), precision=args.precision,
                       integrators=tuple(integrator_class(name) for name in integrators), copies=len(integrators))
    return {"scene": preset.name, "integrators": tuple(integrators), "params": params, "dt": args.dt,
            "curves": _load_curves(args, preset) or {}, "options": options}


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
                          substeps=args.substeps or 10, seed=args.seed, interactive=True,
                          integrator_options=spec["options"])
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
    from .app.showcase import record_showcase, select
    from .render import RenderUnavailable, parse_size
    from .render.video import check_output

    if args.only is not None and args.showcase is None:
        raise ConfigError("--only picks showcase entries: give it with --showcase")
    if args.showcase is not None:
        extra = [flag for flag, given in (("SCENE", args.scene), ("--integrator", args.integrator),
                                          ("--side-by-side", args.side_by_side), ("--dt", args.dt),
                                          ("--set", args.assignments), ("--seconds", args.seconds),
                                          ("--fps", args.fps), ("--size", args.size),
                                          ("--speed", args.speed), ("--curves", args.curves),
                                          ("--energy", args.energy is not None),
                                          ("--strain", args.strain), ("--contacts", args.contacts),
                                          ("--fit", args.fit)) if given]
        if extra:
            raise ConfigError(f"--showcase records its own scenes and settings; drop {', '.join(extra)}")
        entries = select(args.only)
        try:
            runtime.init(arch=args.arch, precision=args.precision)
            record_showcase(args.showcase, progress=None if not args.quiet else False, entries=entries,
                            on_clip=None if args.quiet else _print_clip)
        except RenderUnavailable as exc:
            print(f"taichi-sim: error: {exc}", file=sys.stderr)
            return EXIT_USAGE
        return 0
    if args.scene is None:
        raise ConfigError("record needs a SCENE (or --showcase DIR)")
    spec = _session_args(args)
    clip = Clip(scene=spec["scene"], integrators=spec["integrators"], params=spec["params"],
                dt=spec["dt"], integrator_options=spec["options"], seconds=args.seconds or 5.0, fps=args.fps or 30.0,
                size=parse_size(args.size or "1280x720"), speed=args.speed or 1.0, seed=args.seed,
                curves=spec["curves"], strain=args.strain, contacts=args.contacts, fit=args.fit,
                energy=bool(args.side_by_side) if args.energy is None else args.energy)
    check_clip(clip)
    check_output(args.out, clip.size, clip.fps)
    try:
        runtime.init(arch=args.arch, precision=args.precision)
        result = record(clip, args.out, progress=None if not args.quiet else False,
                        warn=lambda line: print(f"taichi-sim: warning: {line}", file=sys.stderr))
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
    restore = interrupt.install()  # before Taichi loads: Ctrl-C in its import is not lost
    try:
        try:
            code = _main(argv)
        except Exception:
            if interrupt.pending():  # Taichi swallowed the KeyboardInterrupt and failed in its place
                return _interrupted()
            raise
        if code != EXIT_INTERRUPTED and interrupt.pending():  # one Taichi swallowed after the last check
            return _interrupted()
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
    finally:
        restore()


EXIT_INTERRUPTED = 128 + 2  # what a shell reports for a program ended by SIGINT


def _interrupted() -> int:
    print("taichi-sim: interrupted", file=sys.stderr)
    return EXIT_INTERRUPTED


def _load_package() -> None:
    """Import Taichi and the package's kernels (a second or more) with Ctrl-C held back until
    they are loaded (:mod:`taichi_sim.interrupt`)."""
    with interrupt.deferred():
        from . import integrators, run, scene  # noqa: F401 - loaded for their kernels


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command != "export":  # export reads and writes files only
            _load_package()
        if args.command in ("simulate", "demo", "record"):
            from .scene_file import apply_scene_file

            apply_scene_file(args, args.command)  # the file's values, then the defaults
        if args.command == "export":
            return cmd_export(args)
        if args.command is None:
            return cmd_default()
        with warnings.catch_warnings():  # input warnings and notes as one line each, like the errors
            shown = warnings.showwarning
            warnings.showwarning = lambda message, category, *rest, **kw: (
                print(f"taichi-sim: warning: {message}", file=sys.stderr) if issubclass(category, InputWarning)
                else print(f"taichi-sim: {message}", file=sys.stderr) if issubclass(category, InputNote)
                else shown(message, category, *rest, **kw))
            return {"list": cmd_list, "simulate": cmd_simulate, "demo": cmd_demo,
                    "record": cmd_record, "bench": cmd_bench, "advise": cmd_advise,
                    "check": cmd_check}[args.command](args)
    except ConfigError as exc:
        print(f"taichi-sim: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return _interrupted()
