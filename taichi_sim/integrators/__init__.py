"""Integrators behind one contract, looked up by name: a built-in's, an installed plug-in's
(entry-point group ``taichi_sim.integrators``), or ``package.module:Class`` /
``path/to/file.py:Class`` (:mod:`.plugins`)."""
from __future__ import annotations

from ..errors import ConfigError, unknown_name
from .adaptive import DormandPrince45, EmbeddedRK, Fehlberg45
from .base import Integrator, Status, StepReport, missing_facts
from .explicit_rk import RK4, Euler, ExplicitRK, Midpoint, Trapezoid
from .implicit import ImplicitEuler, ImplicitEulerLinearised, ImplicitMidpoint, LinearSolverStats
from .options import Option, OptionSpec, check_values, flag_help, flag_options, option_specs
from .plugins import ENTRY_POINT_GROUP, installed_plugins, is_spec, load_entry_point, load_spec, loaded_plugin
from .positional import XPBD, ProjectiveDynamics
from .positional.vbd import VBD
from .symplectic import SymplecticEuler
from .tableau import ButcherTableau

# Adding a method: its class (with its facts, see Integrator) and one entry here.
INTEGRATORS: dict[str, type[Integrator]] = {
    cls.name: cls for cls in (Euler, Trapezoid, Midpoint, RK4, SymplecticEuler, DormandPrince45, Fehlberg45,
                              ImplicitEuler, ImplicitEulerLinearised, ImplicitMidpoint, ProjectiveDynamics, XPBD, VBD)
}


def integrator_class(name: str) -> type[Integrator]:
    """The class of integrator ``name``: a built-in, an installed plug-in, or a
    ``module:Class`` spec (ConfigError with one line when there is none)."""
    if name in INTEGRATORS:
        return INTEGRATORS[name]
    if is_spec(name):
        return load_spec(name, INTEGRATORS)
    if loaded_plugin(name) is not None:
        return loaded_plugin(name)
    plugins = installed_plugins()
    if name in plugins:
        return load_entry_point(name, plugins[name], INTEGRATORS)
    raise ConfigError(unknown_name("unknown integrator", name, [*INTEGRATORS, *plugins],
                                   otherwise=", or name your own class as package.module:Class or "
                                             "path/to/file.py:Class"))


def check_options(name: str, options: dict) -> type[Integrator]:
    """The class of integrator ``name``, after checking it takes every keyword in ``options``
    and each value's type and bounds (:class:`~.options.Option`); ConfigError otherwise.
    Nothing is allocated."""
    cls = integrator_class(name)
    accepted = cls.options()
    unknown = sorted(set(options) - set(accepted))
    if unknown:
        raise ConfigError(f"integrator {name!r} takes no option {unknown[0]!r}"
                          + (f" (it takes: {', '.join(sorted(accepted))})" if accepted else ""))
    check_values(cls, options, name)
    return cls


def parse_options(name: str, assignments: dict[str, str]) -> dict:
    """Command-line option strings (``--option NAME=VALUE``) of integrator ``name`` as Python
    values, typed by the option's annotation (else its default: bool, int, float or str);
    ConfigError naming the option for a value that does not parse or is out of its bounds, or
    an option the method does not take."""
    cls = integrator_class(name)
    specs = option_specs(cls)
    unknown = sorted(set(assignments) - set(specs))
    if unknown:
        check_options(name, {key: None for key in unknown})
    values = {}
    for key, text in assignments.items():
        try:
            values[key] = specs[key].parse(text)
        except ValueError as exc:
            raise ConfigError(f"integrator {name!r} option {key}: {exc}") from None
    return values


PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f",
           "#bcbd22", "#17becf", "#393b79", "#637939", "#8c6d31", "#843c39", "#7b4173")
"""Colours a method that declares none takes one of, by its name (matplotlib's tab10, then
tab20b's darker tones)."""


def colour_of(name: str) -> str:
    """The plot colour of integrator ``name``: the ``plot_colour`` its class declares itself
    (a subclass does not inherit its parent's line colour), else one of :data:`PALETTE` picked
    by the name (the same every run); a name that is no integrator (a peer, a label) gets a
    palette colour too."""
    import zlib

    try:
        declared = vars(integrator_class(name)).get("plot_colour", "")
    except ConfigError:
        declared = ""
    return declared or PALETTE[zlib.crc32(name.encode()) % len(PALETTE)]


def method_label(name: str, options: dict) -> str:
    """``xpbd(substeps=50)``: a method's name and its options, as the CLI and the benches print
    them (the name alone without options)."""
    if not options:
        return name
    return f"{name}({', '.join(f'{k}={v}' for k, v in options.items())})"


def parse_method_label(text: str) -> tuple[str, dict]:
    """The inverse of :func:`method_label`: ``xpbd(substeps=50, linear_solver=direct)`` ->
    ``("xpbd", {"substeps": 50, "linear_solver": "direct"})`` (values as Python literals; a
    bare word, as method_label writes a text, is that text)."""
    import ast

    text = text.strip()
    if "(" not in text:
        return text, {}
    name, rest = text.split("(", 1)
    call = ast.parse(f"f({rest}", mode="eval").body

    def value(node):
        return node.id if isinstance(node, ast.Name) else ast.literal_eval(node)

    return name.strip(), {kw.arg: value(kw.value) for kw in call.keywords}


def split_method_labels(text: str) -> list[str]:
    """A comma-separated list of :func:`method_label` texts, split at the commas outside
    parentheses."""
    out, depth, current = [], 0, ""
    for ch in text:
        depth += (ch == "(") - (ch == ")")
        if ch == "," and depth == 0:
            out.append(current)
            current = ""
        else:
            current += ch
    return [m for m in out + [current] if m.strip()]


def create_integrator(name: str, system, **options) -> Integrator:
    """Bind the integrator called ``name`` to ``system`` (allocates its scratch once).

    ``options`` are the method's keyword-only settings (e.g. ``rtol`` for rk45); an option the
    method does not take raises ConfigError. The integrator's ``given_options`` names them:
    the options a run leaves as given (``--tolerance`` does not raise them).
    """
    integrator = check_options(name, options)(system, **options)
    integrator.given_options = frozenset(options)
    return integrator


__all__ = ["INTEGRATORS", "ENTRY_POINT_GROUP", "Integrator", "Option", "OptionSpec", "option_specs",
           "flag_options", "flag_help", "colour_of", "PALETTE", "Status", "StepReport", "ButcherTableau",
           "ExplicitRK", "EmbeddedRK", "LinearSolverStats", "missing_facts", "installed_plugins",
           "integrator_class", "check_options", "parse_options", "create_integrator", "method_label",
           "Euler", "Trapezoid", "Midpoint", "RK4", "SymplecticEuler", "DormandPrince45", "Fehlberg45",
           "ImplicitEuler", "ImplicitEulerLinearised", "ImplicitMidpoint", "ProjectiveDynamics", "XPBD"]
