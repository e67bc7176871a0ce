"""The commands that draw: ``demo`` (the launcher), ``record`` (clips and the showcase) and
the bare ``taichi-sim`` (either, by what the machine has)."""
from __future__ import annotations

import sys

from ..errors import ConfigError
from .parser import EXIT_USAGE
from .simulate import load_curves


def _session_args(args) -> dict:
    """Scene, integrators, parameters and step of ``demo`` / ``record``, checked before any
    Taichi work (ConfigError names the culprit)."""
    from ..integrators import check_options, integrator_class, parse_options
    from ..scene import scene_preset
    from ..scene.params import resolve, scene_assignments
    from ..scene.presets import check_scene_memory

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
            "curves": load_curves(args, preset) or {}, "options": options}


def cmd_demo(args) -> int:
    from .. import runtime
    from ..app.launcher import Launcher
    from ..app.session import Session
    from ..render import RenderUnavailable, has_display, parse_size

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
    from .. import runtime
    from ..app.record import Clip, check_clip, record
    from ..app.showcase import record_showcase, select
    from ..render import RenderUnavailable, parse_size
    from ..render.video import check_output

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

    from .. import runtime
    from ..app.display import display_problem
    from ..app.launcher import Launcher, first_session
    from ..app.showcase import QUICK_SHOWCASE, record_showcase
    from ..render import RenderUnavailable

    try:
        runtime.init(arch="cpu", precision="f64")
        problem = display_problem()
        if problem is None:
            Launcher(first_session()).run()
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


