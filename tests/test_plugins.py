"""Integrators carry their own facts, and can come from outside: the registry's methods declare
every fact the tools read, a plug-in (module:Class, file.py:Class, an entry point) runs through
the command line and the benches, and a bad one is refused with one line."""
import inspect
import math
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

import taichi_sim as ts
from taichi_sim.cli import main
from taichi_sim.errors import ConfigError
from taichi_sim.integrators import INTEGRATORS, ExplicitRK, integrator_class, missing_facts, option_specs
from taichi_sim.memory import Size, estimate_bytes

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "plugin_velocity_verlet.py"
SPEC = f"{EXAMPLE}:VelocityVerlet"


@pytest.mark.parametrize("name", list(INTEGRATORS))
def test_every_registered_method_declares_its_facts(name):
    cls = INTEGRATORS[name]
    assert missing_facts(cls) == []
    assert cls.scratch_bytes(100, 300, 8) > 0
    assert set(cls.options()) <= set(inspect.signature(cls.__init__).parameters)
    # every built-in option is declared: its help, for --help and `list`
    assert [name for name, spec in option_specs(cls).items() if not spec.help] == []


@pytest.mark.parametrize("name", [n for n, c in INTEGRATORS.items() if issubclass(c, ExplicitRK)])
def test_explicit_stability_constants_agree_with_their_tableaux(name):
    """C is declared; the tableau's stability polynomial says where |R(i theta)| passes 1."""
    cls = INTEGRATORS[name]
    c = cls.stability_constant
    if c == 0:
        assert cls.amplification_squared(1e-2) > 1.0
    else:
        assert cls.amplification_squared(0.999 * c) <= 1.0 + 1e-12
        assert cls.amplification_squared(1.001 * c) > 1.0


def _plugin_file(tmp_path, body: str, name: str = "mine.py") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(body))
    return path


INCOMPLETE = """
    import taichi as ti
    from taichi_sim.integrators import Integrator, StepReport

    class NoConstant(Integrator):
        name = "no_constant"
        order = 1
        description = "forgets its stability constant"
        scratch_states = 0

        def step(self, state, t, h):
            return StepReport(True, h, h, 0)

    class Unlimited(NoConstant):
        name = "unlimited"
        stability_constant = float("inf")  # but no advice_note

    class NotAMethod:
        pass
"""


def test_a_method_missing_a_fact_is_named_and_refused(tmp_path):
    path = _plugin_file(tmp_path, INCOMPLETE, "incomplete.py")
    for cls_name, fact in (("NoConstant", "stability_constant"), ("Unlimited", "advice_note")):
        with pytest.raises(ConfigError, match=fact):
            integrator_class(f"{path}:{cls_name}")
    with pytest.raises(ConfigError, match="not a subclass"):
        integrator_class(f"{path}:NotAMethod")

    class Half(INTEGRATORS["rk4"]):  # a subclass inherits facts; a new base class must declare them
        name = "half"
    assert missing_facts(Half) == []
    assert "order (an int >= 1)" in missing_facts(type("Zero", (INTEGRATORS["symplectic_euler"],), {"order": 0}))
    assert "stability_constant (None is only for adaptive methods)" in missing_facts(
        type("Unsure", (INTEGRATORS["symplectic_euler"],), {"stability_constant": None}))


@pytest.mark.parametrize("spec, message", [
    ("no_such_module_here:X", "no module named 'no_such_module_here'"),
    ("json:JSONDecoder", "not a subclass"),
    ("taichi_sim.integrators.base:Nope", "has no 'Nope'"),
    ("a:b:c", "package.module:Class"),
    ("/no/such/file.py:X", "no file"),
    ("taichi_sim.integrators.explicit_rk:RK4", "name of a built-in"),
    ("nonesuch", "unknown integrator"),
])
def test_bad_plugin_specs_are_one_line_errors(tmp_path, capsys, spec, message):
    code = main(["simulate", "spring", "--integrator", spec, "--steps", "2", "--out", str(tmp_path / "r.npz")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1
    assert not (tmp_path / "r.npz").exists()


def test_bad_option_values_are_one_line_errors(tmp_path, capsys):
    out = str(tmp_path / "r.npz")
    assert main(["simulate", "spring", "--integrator", "rk45", "--option", "safety=much", "--t-end", "0.1",
                 "--out", out]) == 2
    assert "option safety: expects float, got 'much'" in capsys.readouterr().err
    assert main(["simulate", "spring", "--integrator", SPEC, "--option", "safety=0.5", "--steps", "2",
                 "--out", out]) == 2
    assert "takes no option 'safety'" in capsys.readouterr().err
    assert main(["simulate", "spring", "--integrator", "rk45", "--rtol", "1e-3", "--option", "rtol=1e-4",
                 "--t-end", "0.1", "--out", out]) == 2
    assert "--option rtol repeats" in capsys.readouterr().err


def test_the_example_runs_through_simulate_and_is_saved(tmp_path, capsys):
    out = tmp_path / "vv.npz"
    assert main(["simulate", "pendulum", "--integrator", SPEC, "--steps", "200", "--out", str(out)]) == 0
    assert "200 steps of" in capsys.readouterr().out
    with np.load(out) as run:
        assert str(run["integrator"]) == "velocity_verlet" and str(run["status"]) == "ok"
        assert int(run["f_evals"]) == 400 and np.isfinite(run["x"]).all()
    # built-in options travel through --option too, typed by the signature's default
    assert main(["simulate", "spring", "--integrator", "rk45", "--option", "safety=0.8", "--option",
                 "max_step=0.05", "--t-end", "0.2", "--quiet", "--out", str(tmp_path / "a.npz")]) == 0


def test_the_example_converges_at_its_declared_order(f64):
    """Velocity Verlet with the Euler-predicted velocity is second order also with dashpots and
    drag (a plain velocity Verlet on these would measure 1)."""
    cls = integrator_class(SPEC)
    params = {"damping": 0.5, "drag": 0.3}
    scene = ts.build_scene("spring", params)
    t_end = 1.0

    def final(method, h):
        scene.reset()
        result = ts.run(scene, ts.create_integrator(method, scene.system), dt=h, t_end=t_end, energy_every=0)
        assert result.status.value == "ok"
        return scene.state.to_numpy()[0].astype(float)

    reference = final("rk4", 1e-4)
    hs = [0.02, 0.01, 0.005]
    errors = [float(np.abs(final(SPEC, h) - reference).max()) for h in hs]
    observed = np.polyfit(np.log(hs), np.log(errors), 1)[0]
    assert abs(observed - cls.order) < 0.1, (errors, observed)


def test_the_example_runs_through_advise_and_a_bench(tmp_path, capsys):
    assert main(["advise", "spring", "--integrators", f"{SPEC},rk4", "--target-error", "1e-2",
                 "--t-end", "0.5"]) == 0
    text = capsys.readouterr().out
    row = next(line for line in text.splitlines() if line.startswith(SPEC))
    assert row.split()[1:4] == ["2", "2", "2"]  # order, f-evals per step, C: the class's facts
    assert text.count(SPEC) >= 2  # in the stability table and among the recommendations
    code = main(["bench", "extremes", "--quick", "--quiet", "--scenes", "spring", "--integrators", SPEC,
                 "--out", str(tmp_path / "ex")])
    assert code == 0  # no silent blow-up: a diverged step says so
    rows = (tmp_path / "ex" / "extremes.csv").read_text().splitlines()
    assert sum(SPEC in line for line in rows) == 9  # 3 stiffnesses x 3 steps


def test_plugin_memory_and_launcher_session(f64):
    size = Size(10_000, 30_000)
    assert estimate_bytes(size, integrators=(integrator_class(SPEC),)) - estimate_bytes(size) == 3 * 6 * 8 * 10_000
    from taichi_sim.app.session import Session, compatible_integrators

    session = Session("pendulum", [SPEC, "symplectic_euler"], params={"particle_count": 4})
    assert session.integrators[0] == "velocity_verlet"
    assert "velocity_verlet" in compatible_integrators(session.scenes[0], session.plugins)
    session.advance(0.05)
    runner = session.runners[0]
    assert runner.integrator.name == "velocity_verlet" and not runner.frozen and runner.t > 0.04
    session.cycle_integrator(0)  # the picker moves on from the plug-in to the next method
    assert session.runners[0].integrator.name != "velocity_verlet"


def _write_example_subclass(path: Path, class_name: str, name: str, description: str) -> None:
    """A module at ``path`` whose ``class_name`` is the example's method under its own ``name``."""
    path.write_text(textwrap.dedent(f"""
        import importlib.util
        spec = importlib.util.spec_from_file_location("{path.stem}_base", {str(EXAMPLE)!r})
        base = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(base)

        class {class_name}(base.VelocityVerlet):
            name = {name!r}
            description = {description!r}
    """))


def test_an_installed_entry_point_is_listed_and_resolved(tmp_path, monkeypatch, capsys):
    site = tmp_path / "site"
    site.mkdir()
    _write_example_subclass(site / "ep_verlet.py", "EntryVerlet", "entry_verlet",
                            "velocity Verlet, installed by entry point")
    info = site / "ep_verlet-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: ep-verlet\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[taichi_sim.integrators]\nentry_verlet = ep_verlet:EntryVerlet\n"
                                           "broken = ep_verlet:Missing\n")
    monkeypatch.syspath_prepend(str(site))
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    assert "entry_verlet       order 2  velocity Verlet, installed by entry point" in text
    assert "broken" in text and "not usable" in text
    assert integrator_class("entry_verlet").name == "entry_verlet"
    with pytest.raises(ConfigError, match="failed to load"):
        integrator_class("broken")
    assert math.isclose(integrator_class("entry_verlet").stability_constant, 2.0)
    sys.modules.pop("ep_verlet", None)


def test_a_module_in_the_working_directory_is_found_without_it_on_the_path(tmp_path, monkeypatch, capsys):
    # the installed `taichi-sim` script, unlike `python -m taichi_sim`, does not put the working
    # directory on sys.path
    _write_example_subclass(tmp_path / "cwd_verlet.py", "CwdVerlet", "cwd_verlet", "velocity Verlet, beside the user")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p and Path(p).resolve() != tmp_path.resolve()])
    out = tmp_path / "r.npz"
    assert main(["simulate", "spring", "--integrator", "cwd_verlet:CwdVerlet", "--steps", "5", "--out", str(out)]) == 0
    assert "5 steps of cwd_verlet:CwdVerlet" in capsys.readouterr().out and out.exists()
    assert Path(sys.path[-1]).resolve() == tmp_path.resolve()  # appended: it shadows no package
    sys.modules.pop("cwd_verlet", None)
