"""The ``simulate`` command: a scene run headless into an .npz, with its summary lines."""
from __future__ import annotations

import math
import sys

from ..errors import ConfigError
from .export import export_frames, export_request
from .integrator_flags import flag_values

# The most steps one `simulate` takes. The cheapest scene (the circle ODE, RK4) runs at about a
# thousand steps a second on a loaded 2-core machine, a few thousand on an idle one: 10^8 steps
# are already a day or more, so a larger count (--steps 100000000000000, or --t-end 1e6 --dt
# 1e-6) is a typo, not a plan. A long run wants a larger --dt or an adaptive integrator.
MAX_STEPS = 10**8

def cmd_simulate(args) -> int:
    from .. import io, runtime
    from ..convergence import check_max_residual, check_tolerance, format_metres
    from ..guard import GuardLimits
    from ..integrators import check_options, create_integrator, integrator_class, method_label, parse_options
    from ..run import check_run_args, planned_steps, run
    from ..scene import build_scene, scene_preset
    from ..scene.params import resolve, scene_assignments
    from ..scene.presets import check_scene_memory
    from ..theory import stability_warning, step_limited

    preset = scene_preset(args.scene)
    missing = [what for what, absent in (
        ("--steps N or --t-end T (or a scene file's [run] steps or duration)", args.steps is None and args.t_end is None),
        ("--out FILE.npz (or a scene file's [output] npz)", args.out is None)) if absent]
    if missing:  # both at once: one round of errors, not two
        raise ConfigError(f"simulate needs {' and '.join(missing)}")
    exporting = export_request(args)
    integrator_name = args.integrator or preset.default_integrator
    options = flag_values(args)  # the integrator options given by their own flags
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
    curves = load_curves(args, preset)

    runtime.init(arch=args.arch, precision=args.precision)
    scene = build_scene(args.scene, params, seed=args.seed)
    start_warning = scene.start_warning()
    if start_warning:
        print(f"taichi-sim: warning: {start_warning}", file=sys.stderr)
    explicit_dt = scene.explicit_step
    if args.dt is None and not adaptive and step_limited(integrator_name) and explicit_dt < dt:
        # a fine cloth's particles are light: its explicit stable step is shorter than the preset's;
        # and the contact cloths' default method takes frame-sized steps
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

        from ..curves import curves_json

        arrays["curves"] = np.asarray(curves_json(curves, scene.name))  # the curves it ran with
    path = io.save_npz(args.out, arrays)
    exported = export_frames(exporting, arrays, args) if exporting else None
    if result.message:
        print(f"taichi-sim: {result.message}", file=sys.stderr)
    for warning in result.warnings:
        print(f"taichi-sim: warning: {warning}", file=sys.stderr)
    replaced = scene.takeover.parts  # parts whose work the method did in its solve
    for part in scene.parts:
        if part.name not in replaced and part.warning():
            print(f"taichi-sim: warning: {part.warning()}", file=sys.stderr)
    if not args.quiet:
        rejected = f" ({result.rejected_steps} rejected)" if result.rejected_steps else ""
        label = method_label(integrator_name, _options_at_end(integrator, options))
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


def _options_at_end(integrator, options: dict) -> dict:
    """The options as the run ended: the one a tolerance raises (``work_option``) shown as
    ``50->100`` where the run raised it, so the summary names the work it paid for."""
    name = integrator.work_option
    if not name or not hasattr(integrator, name):
        return options
    start, end = options.get(name), getattr(integrator, name)
    if start is None or start == end:
        return options
    return {**options, name: f"{start}->{end}"}


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
    from ..memory import available_bytes, format_bytes

    if steps is None:
        return
    frames = steps // save_every + 2
    need = 2 * frames * preset.size(values).particles * 3 * 8  # kept, then stacked for the npz
    available = available_bytes()
    if available is not None and need > available:
        raise ConfigError(f"--save-every {save_every}: {frames:,} frames need about {format_bytes(need)} but "
                          f"only {format_bytes(available)} of memory is available; save less often")



def load_curves(args, preset) -> dict | None:
    """The curves of ``--curves FILE``, checked against the scene's parameters (ConfigError
    naming the file otherwise), or None."""
    if getattr(args, "curves", None) is None:
        return None
    from ..curves import load_curves

    return load_curves(args.curves, preset)


