"""An integrator's options, declared once in its constructor's signature.

An option is a keyword-only argument of the integrator's ``__init__``: its name, its type (the
annotation) and its default are Python's; what a person reads about it rides on the annotation
as an :class:`Option`::

    def __init__(self, system, *,
                 substeps: Annotated[int, Option("substeps per step", flag=True, at_least=1)] = 20):

Everything else is generated from that one place (:func:`option_specs`): ``--option
NAME=VALUE`` parses by the type, ``simulate``'s ``--NAME`` flags (``flag=True``) and their help,
``taichi-sim list``, and the bounds checked before anything is built
(:func:`~taichi_sim.integrators.check_options`). A plug-in declares its options the same way
(docs/plugins.md). A keyword argument without an :class:`Option` is still an option (typed by
its default), with no help and no flag.
"""
from __future__ import annotations

import inspect
import math
import numbers
import types
import typing
from dataclasses import dataclass
from functools import cache

from ..errors import ConfigError

_KINDS = (bool, int, float, str)


@dataclass(frozen=True)
class Option:
    """What the command line says about one option (the annotation's metadata).

    Attributes:
        help: what the option sets, in a few words ("substeps per step").
        unit: its unit ("m", "s", "1/s"; "" for a count or a ratio).
        flag: True: ``simulate --NAME`` (underscores as dashes) sets it too; a string: that flag
            instead (``"--pd-tolerance"``, where ``--tolerance`` is the run's own); False: only
            ``--option NAME=VALUE``.
        at_least, above, at_most, below: bounds a number must keep (None: none).
        finite: a float must be finite (``max_step`` may be inf).
        choices: the values a str may take (empty: any).
        default_text: what the help says of the default when the signature's says too little
            (a default of None that means "chosen by the method").
    """

    help: str
    unit: str = ""
    flag: bool | str = False
    at_least: float | None = None
    above: float | None = None
    at_most: float | None = None
    below: float | None = None
    finite: bool = True
    choices: tuple = ()
    default_text: str = ""


@dataclass(frozen=True)
class OptionSpec:
    """One option of one integrator class, as declared (:func:`option_specs`).

    Attributes:
        name: the keyword; default: its default; kinds: the types a value may have, tried in
        order when parsing text (None is allowed when the default is None); declared: the
        :class:`Option`, or None for an undeclared keyword.
    """

    name: str
    default: object
    kinds: tuple
    declared: Option | None

    @property
    def flag(self) -> str | None:
        """The ``simulate`` flag that sets this option, or None."""
        flag = self.declared.flag if self.declared is not None else False
        if flag is True:
            return "--" + self.name.replace("_", "-")
        return flag or None

    @property
    def help(self) -> str:
        return self.declared.help if self.declared is not None else ""

    @property
    def unit(self) -> str:
        return self.declared.unit if self.declared is not None else ""

    def default_label(self, unit: bool = True) -> str:
        """The default as help and ``list`` print it ("20", "0.001 m", "automatic"); ``unit``:
        with its unit."""
        if self.declared is not None and self.declared.default_text:
            return self.declared.default_text
        if self.default is None:
            return "automatic"
        text = str(self.default).lower() if isinstance(self.default, bool) else f"{self.default:g}" \
            if isinstance(self.default, float) else str(self.default)
        return f"{text} {self.unit}" if unit and self.unit and not isinstance(self.default, (bool, str)) else text

    def requirement(self) -> str:
        """What a value must be, for messages: "an integer >= 1", "a number in (0, 1)"."""
        spec = self.declared
        kind = self.kinds[0] if self.kinds else str
        if kind is bool:
            return "true or false"
        if spec is not None and spec.choices:
            return "one of " + ", ".join(map(str, spec.choices))
        noun = {int: "an integer", float: "a finite number" if spec is None or spec.finite else "a number"}.get(
            kind, "a value")
        if spec is None:
            return noun
        low = (f"[{spec.at_least:g}" if spec.at_least is not None else f"({spec.above:g}"
               if spec.above is not None else None)
        high = (f"{spec.at_most:g}]" if spec.at_most is not None else f"{spec.below:g})"
                if spec.below is not None else None)
        if low and high:
            return f"{noun} in {low}, {high}"
        if low:
            return f"{noun} {'>=' if spec.at_least is not None else '>'} {low[1:]}"
        if high:
            return f"{noun} {'<=' if spec.at_most is not None else '<'} {high[:-1]}"
        return noun

    def problem(self, value) -> str:
        """Why ``value`` cannot be this option's ("" when it can)."""
        if value is None and self.default is None:
            return ""
        spec, kind = self.declared, self.kinds[0] if self.kinds else None
        if kind is bool:
            return "" if isinstance(value, bool) or type(value).__name__ == "bool_" else self.requirement()
        if kind in (int, float):
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or (
                    kind is int and not isinstance(value, numbers.Integral)):
                return self.requirement()
        if spec is None:  # undeclared: any value of its type
            return ""
        if kind in (int, float) and (math.isnan(value) or (math.isinf(value) and spec.finite)):
            return self.requirement()
        if spec.choices and value not in spec.choices:
            return self.requirement()
        if isinstance(value, numbers.Real) and not isinstance(value, bool) and not (
                (spec.at_least is None or value >= spec.at_least) and (spec.above is None or value > spec.above)
                and (spec.at_most is None or value <= spec.at_most) and (spec.below is None or value < spec.below)):
            return self.requirement()
        return ""

    def parse(self, text: str):
        """The value that ``text`` (as typed on the command line) gives this option; ValueError
        saying what was expected when it gives none or one out of bounds."""
        text = text.strip()
        for kind in self.kinds or (int, float, str):
            value = _parse(kind, text)
            if value is not _NO_VALUE:
                break
        else:
            raise ValueError(f"expects {' or '.join(k.__name__ for k in self.kinds)}, got {text!r}")
        problem = self.problem(value)
        if problem:
            raise ValueError(f"must be {problem}, got {text}")
        return value


_NO_VALUE = object()
_TRUE, _FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off")


def _parse(kind, text: str):
    if kind is bool:
        lowered = text.lower()
        return True if lowered in _TRUE else False if lowered in _FALSE else _NO_VALUE
    if kind is float and text.lower() in ("nan", "+nan", "-nan"):
        return _NO_VALUE
    try:
        return kind(text)
    except ValueError:
        return _NO_VALUE


@cache
def option_specs(cls) -> dict[str, OptionSpec]:
    """The options of integrator class ``cls`` by name, in signature order: the keyword-only
    arguments of its ``__init__`` with their defaults, types and :class:`Option` (read once
    per class)."""
    init = cls.__init__
    specs = {}
    for parameter in inspect.signature(init).parameters.values():
        if parameter.kind is not inspect.Parameter.KEYWORD_ONLY:
            continue
        annotation, declared = _annotation(parameter.annotation, getattr(init, "__globals__", {}))
        specs[parameter.name] = OptionSpec(parameter.name, parameter.default,
                                           _kinds(parameter.default, annotation), declared)
    return specs


def _annotation(annotation, namespace: dict):
    """(the type, the Option) of a parameter's annotation; a string (``from __future__ import
    annotations``) is evaluated in the constructor's module, and one that cannot be is kept as
    text (its type words still count)."""
    if isinstance(annotation, str):
        try:
            annotation = eval(annotation, {"typing": typing, **namespace})  # noqa: S307 - the class's own source
        except Exception:  # a name only imported for type checkers: the words still say the type
            return annotation, None
    if typing.get_origin(annotation) is typing.Annotated:
        base, *extras = typing.get_args(annotation)
        return base, next((extra for extra in extras if isinstance(extra, Option)), None)
    return annotation, None


def _kinds(default, annotation) -> tuple:
    """The types a value may take: the annotation's (None dropped), else the default's, else
    any of int, float, str."""
    if isinstance(annotation, str):
        named = tuple(kind for kind in _KINDS if kind.__name__ in annotation)
    else:
        members = typing.get_args(annotation) if isinstance(annotation, types.UnionType) or \
            typing.get_origin(annotation) is typing.Union else (annotation,)
        named = tuple(kind for kind in _KINDS if kind in members)
    if named:
        return named
    if default is not None and type(default) in _KINDS:
        return (type(default),)
    return (int, float, str)


def check_values(cls, options: dict, label: str) -> None:
    """ConfigError naming the first value of ``options`` that ``cls`` cannot take (its type
    or bounds), as ``integrator 'xpbd' option substeps: must be ..., got 0``."""
    specs = option_specs(cls)
    for key, value in options.items():
        problem = specs[key].problem(value) if key in specs else ""
        if problem:
            raise ConfigError(f"integrator {label!r} option {key}: must be {problem}, got {value!r}")


def flag_options(classes) -> dict[str, list[tuple[type, OptionSpec]]]:
    """``simulate``'s integrator flags: flag -> the (class, option) pairs it sets, over
    ``classes`` (in their order), for every option declared with a flag. ConfigError when one
    flag would set options of different names."""
    flags: dict[str, list] = {}
    for cls in classes:
        for spec in option_specs(cls).values():
            if spec.flag:
                entries = flags.setdefault(spec.flag, [])
                if entries and entries[0][1].name != spec.name:
                    raise ConfigError(f"integrator {cls.name!r} option {spec.name}: its flag {spec.flag} "
                                      f"sets option {entries[0][1].name} of {entries[0][0].name!r}; pick "
                                      f"another flag")
                entries.append((cls, spec))
    return flags


def flag_help(entries: list[tuple[type, OptionSpec]]) -> str:
    """One flag's help from its options' declarations: each different text once, with its
    unit and each default and the methods that have it ("substeps per step (xpbd: default 20;
    vbd: default 1)")."""
    texts: dict[tuple, dict[str, list[str]]] = {}
    for cls, spec in entries:
        defaults = texts.setdefault((spec.help or "an option", spec.unit), {})
        defaults.setdefault(spec.default_label(unit=False), []).append(cls.name)
    parts = []
    for (text, unit), defaults in texts.items():
        said = "; ".join(f"{', '.join(names)}: default {default}" for default, names in defaults.items())
        parts.append(f"{text}{f', in {unit}' if unit else ''} ({said})")
    return "; ".join(parts)


__all__ = ["Option", "OptionSpec", "option_specs", "check_values", "flag_options", "flag_help"]
