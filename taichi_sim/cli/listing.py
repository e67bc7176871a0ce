"""The commands that read and report: ``list``, ``check``, and the doors to ``bench`` and
``advise`` (:mod:`taichi_sim.bench.commands`)."""
from __future__ import annotations

from ..errors import ConfigError


def cmd_check(args) -> int:
    """Self-intersections, and vertices inside the scene's objects, in every frame of a saved
    run (x_history, or the final x): exit 0 when none, 1 when some frame has any."""
    from ..frame_check import check_run, load_run

    lines, passed = check_run(load_run(args.npz), progress=_frame_bar)
    print("\n".join(lines))
    return 0 if passed else 1


def _frame_bar(frames):
    from tqdm import tqdm

    return tqdm(frames, unit="frame", leave=False, disable=None, mininterval=0.5)


def cmd_list(args) -> int:
    from ..integrators import ENTRY_POINT_GROUP, INTEGRATORS, installed_plugins, integrator_class, method_label
    from ..scene import SCENES, scene_preset

    if args.scene_file is not None:
        from ..scene_file import scene_file_text

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
    """The method's line, then one line per option: its default, what it sets and its flag
    (all from the class's declarations, :func:`~taichi_sim.integrators.option_specs`)."""
    from ..integrators import option_specs

    print(f"  {name:<18} order {cls.order}  {cls.description}")
    for spec in option_specs(cls).values():
        explained = spec.declared is not None and spec.declared.default_text
        value = "auto" if spec.default is None else spec.default_label(unit=False) if not explained else \
            f"{spec.default:g}" if isinstance(spec.default, float) else str(spec.default)
        said = (spec.help + (f", in {spec.unit}" if spec.unit else "") + (f" ({spec.flag})" if spec.flag else "")
                + (f"; default {spec.declared.default_text}" if explained else ""))
        print(f"  {'':<18}   {f'{spec.name}={value}':<26} {said}".rstrip())


def cmd_bench(args) -> int:
    from ..bench.commands import bench_main

    return bench_main(args)


def cmd_advise(args) -> int:
    from ..bench.commands import advise_main

    return advise_main(args)


