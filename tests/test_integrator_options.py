"""An integrator's options, their help and its plot colour come from its class: the command
line and the plots name no method, and a plug-in's declared option gets a flag, help and checks
like a built-in's."""
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest

from taichi_sim.cli import build_parser, main
from taichi_sim.errors import ConfigError
from taichi_sim.integrators import INTEGRATORS, PALETTE, colour_of, create_integrator, option_specs, parse_options

PACKAGE = Path(__file__).resolve().parent.parent / "taichi_sim"
#: The files that once held lists of methods (per-method help, a colour dict keyed by name).
GENERIC = sorted((PACKAGE / "cli").glob("*.py")) + [PACKAGE / "bench" / "plots.py"]


def test_no_method_is_named_in_the_command_line_or_the_plots():
    # A name inside a longer word (implicit_euler in "implicit_euler_linearised") or the
    # mathematician's (Euler) is not a method's; any other mention is a list that a new
    # method would have to join.
    found = []
    for path in GENERIC:
        text = path.read_text()
        for name in INTEGRATORS:
            for match in re.finditer(rf"(?<![\w-]){re.escape(name)}(?![\w-])", text):
                line = text.count("\n", 0, match.start()) + 1
                found.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {name}")
    assert found == []


PLUGIN = '''
from typing import Annotated

from taichi_sim.integrators import Option, SymplecticEuler, StepReport


class Damped(SymplecticEuler):
    """Symplectic Euler, then every velocity times exp(-damping h)."""

    name = "damped_symplectic"
    description = "symplectic Euler with an extra velocity damping (a test's plug-in)"

    def __init__(self, system, *,
                 damping: Annotated[float, Option("extra velocity damping rate", unit="1/s", flag=True,
                                                  at_least=0)] = 0.0):
        super().__init__(system)
        self.damping = damping

    def step(self, state, t, h) -> StepReport:
        import math

        report = super().step(state, t, h)
        state.v.from_numpy(state.v.to_numpy() * math.exp(-self.damping * h))
        return report
'''


@pytest.fixture(scope="module")
def plugin(tmp_path_factory):
    # one file for the module: a second file whose class has the same name would be refused
    path = tmp_path_factory.mktemp("plugin") / "damped.py"
    path.write_text(textwrap.dedent(PLUGIN))
    return f"{path}:Damped"


def test_a_plugins_declared_option_is_a_flag_with_its_help(plugin, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["simulate", "spring", "--integrator", plugin, "--help"])
    assert exc.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--damping DAMPING extra velocity damping rate, in 1/s (damped_symplectic: default 0)" in text
    # without the plug-in named, simulate has no such flag
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    assert "--damping" not in capsys.readouterr().out


def test_a_plugins_flag_reaches_it_and_is_checked(plugin, tmp_path, capsys):
    def final(*flags):
        out = tmp_path / f"run{len(list(tmp_path.glob('run*.npz')))}.npz"
        assert main(["simulate", "spring", "--integrator", plugin, "--steps", "50", "--dt", "0.01",
                     "--quiet", "--out", str(out), *flags]) == 0
        with np.load(out) as run:
            return run["v"].copy()

    free, damped, by_option = final(), final("--damping", "5"), final("--option", "damping=5")
    speed = float(np.abs(free).max())
    assert speed > 0.1
    assert np.allclose(damped, by_option)  # the flag and --option are one option
    # 0.5 s at 5 /s of extra damping: the spring moves at less than half the free speed
    assert float(np.abs(damped).max()) < 0.5 * speed
    out = tmp_path / "bad.npz"
    assert main(["simulate", "spring", "--integrator", plugin, "--steps", "5", "--damping", "-1",
                 "--out", str(out)]) == 2
    assert "--damping: must be a finite number >= 0, got -1" in capsys.readouterr().err
    assert not out.exists()


def test_a_plugin_without_a_colour_takes_one_from_the_palette(plugin):
    from taichi_sim.integrators import integrator_class

    cls = integrator_class(plugin)  # a subclass of symplectic Euler, declaring no colour
    assert colour_of(cls.name) != colour_of(cls.__mro__[1].name)
    assert colour_of(cls.name) in PALETTE and colour_of(cls.name) == colour_of(cls.name)
    assert colour_of("xpbd") == INTEGRATORS["xpbd"].plot_colour
    # each built-in declares a colour of its own
    colours = [cls.plot_colour for cls in INTEGRATORS.values()]
    assert all(colours) and len(set(colours)) == len(colours)


def test_flags_and_option_values_are_checked_from_the_declarations(f64):
    import taichi_sim as ts

    # a declared bound holds for every way in: the API, --option and the flag
    scene = ts.build_scene("cloth", {"nx": 4, "ny": 4})
    with pytest.raises(ConfigError, match="option substeps: must be an integer >= 1, got 0"):
        create_integrator("xpbd", scene.system, substeps=0)
    with pytest.raises(ConfigError, match="option chebyshev_rho: must be a finite number in \\[0, 1\\), got 1.5"):
        parse_options("projective_dynamics", {"chebyshev_rho": "1.5"})
    with pytest.raises(ConfigError, match="must be one of cg, direct, got lu"):
        build_parser().parse_args(["simulate", "spring", "--linear-solver", "lu"])
    args = build_parser().parse_args(["simulate", "cloth", "--pd-tolerance", "0.5", "--substeps", "3"])
    assert args.flag_options == {"tolerance": 0.5, "substeps": 3}  # the flag's option, by its own name
    spec = option_specs(INTEGRATORS["rk45"])["max_step"]
    assert spec.parse("inf") == float("inf") and spec.unit == "s"


def test_a_method_label_reads_back_as_the_method_and_its_options():
    from taichi_sim.integrators import method_label, parse_method_label, split_method_labels

    for name, options in [("vbd", {}), ("xpbd", {"substeps": 50, "iterations": 4}),
                          ("implicit_euler", {"newton_tolerance": 1e-8, "linear_solver": "direct"})]:
        assert parse_method_label(method_label(name, options)) == (name, options)
    assert split_method_labels("vbd,xpbd(substeps=50, iterations=4), rk4") == \
        ["vbd", "xpbd(substeps=50, iterations=4)", " rk4"]
