"""``simulate``'s integrator flags (``--substeps``, ``--rtol``, ...), generated from the options
the integrator classes declare (:mod:`taichi_sim.integrators.options`): the command line names
no method and no option of one; a plug-in's declared flags come the same way."""
from __future__ import annotations

import argparse


def integrator_classes(argv: list[str] | None) -> list | None:
    """The integrator classes whose flags ``simulate`` takes for ``argv``: the built-ins, and
    a plug-in named by ``--integrator`` (loaded here: ConfigError when it cannot be); None when
    ``argv`` runs another command (the integrators are then not imported). Without ``argv``,
    the built-ins."""
    if argv is not None and command_of(argv) != "simulate":
        return None
    from ..integrators import INTEGRATORS, integrator_class

    classes = list(INTEGRATORS.values())
    named = _integrator_named(argv or [])
    if named and named not in INTEGRATORS:
        classes.append(integrator_class(named))
    return classes


def command_of(argv: list[str]) -> str | None:
    """The command ``argv`` runs: its first word that is no option (the top level's options
    take no value)."""
    return next((token for token in argv if not token.startswith("-")), None)


def _integrator_named(argv: list[str]) -> str | None:
    """The value of ``--integrator`` in ``argv`` (the last one given), or None."""
    named = None
    for k, token in enumerate(argv):
        if token == "--":
            break
        if token == "--integrator" and k + 1 < len(argv):
            named = argv[k + 1]
        elif token.startswith("--integrator="):
            named = token.split("=", 1)[1]
    return named


class _StoreOption(argparse.Action):
    """Keep a flag's value in ``args.flag_options`` under its option's name (so that a flag
    whose name differs from its option's, ``--pd-tolerance``, needs no list of exceptions)."""

    def __init__(self, option_strings, dest, option_name: str, **kwargs):
        super().__init__(option_strings, dest, **kwargs)
        self.option_name = option_name

    def __call__(self, parser, namespace, values, option_string=None):
        given = dict(getattr(namespace, self.dest, None) or {})
        given[self.option_name] = values
        setattr(namespace, self.dest, given)


def add_integrator_flags(parser: argparse.ArgumentParser, classes) -> None:
    """Add to ``parser`` a flag for every option of ``classes`` declared with one, its help
    and check from the declarations (:func:`~taichi_sim.integrators.flag_help`)."""
    from ..integrators import flag_help, flag_options

    parser.set_defaults(flag_options={})
    for flag, entries in flag_options(classes).items():
        spec = entries[0][1]
        choices = spec.declared.choices if spec.declared is not None else ()
        parser.add_argument(flag, dest="flag_options", action=_StoreOption, option_name=spec.name,
                            type=_parser_of([s for _, s in entries]),
                            metavar="{" + ",".join(choices) + "}" if choices else flag[2:].replace("-", "_").upper(),
                            help=flag_help(entries))


def _parser_of(specs):
    """argparse's ``type`` for a flag: the value the first of ``specs`` that takes the text
    makes of it (each method checks its own bounds again when built)."""
    def parse(text: str):
        problems = []
        for spec in specs:
            try:
                return spec.parse(text)
            except ValueError as exc:
                problems.append(str(exc))
        raise argparse.ArgumentTypeError(problems[0])
    return parse


def tolerance_help(classes) -> str:
    """What ``--tolerance`` makes each method do past it, from the classes' ``work_option``,
    ``work_cap`` and equation."""
    from ..integrators import option_specs
    from ..integrators.equation import EXACT

    raised: dict[str, list[str]] = {}  # what past the tolerance does -> the methods it does that
    warn, fail = [], []
    for cls in classes:
        option = getattr(cls, "work_option", "")
        if not option or option not in option_specs(cls):
            continue
        spec = option_specs(cls)[option]
        name = spec.flag or f"--option {option}"
        count = spec.kinds[0] is int  # a count doubles, a tolerance shrinks tenfold (Stepper._raise_work)
        does = f"{name} doubled up to {cls.work_cap:g}" if count else f"{name} divided by ten down to {cls.work_cap:g}"
        note = getattr(cls, "work_note", "")
        raised.setdefault(f"{does} ({note})" if note else does, []).append(cls.name)
        promise = getattr(getattr(cls, "equation", None), "promise", "")
        (fail if promise == EXACT else warn).append(cls.name)
    if not raised:
        return ""
    ends = [f"{', '.join(warn)} warn" if warn else "", f"{', '.join(fail)} end not_converged (exit 1)" if fail else ""]
    said = "; ".join(f"{', '.join(names)}: {does}" for does, names in raised.items())
    return f"past it the step is solved again with more work ({said}), unless given; then " \
           f"{' and '.join(e for e in ends if e)}"


def flag_values(args) -> dict:
    """The integrator options given by their flags: option name -> value."""
    return dict(getattr(args, "flag_options", None) or {})
