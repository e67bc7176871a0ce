"""The launcher's state and actions, in plain Python (tested without a window).

A :class:`Session` holds one scene per integrator (one normally, two or three side by side),
all built with the same parameters and stepped in lockstep by :class:`Runner` objects, plus the
control panel's state: step size, substeps per frame, pause, what to show, the help overlay.
The GGUI launcher only translates widgets and keys into calls on it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Sequence

from ..convergence import format_metres
from ..errors import ConfigError
from ..integrators import INTEGRATORS, integrator_class
from ..integrators.base import elastic_models
from ..render.drawer import DrawOptions
from ..scene import SCENES, build_scene, scene_preset
from ..scene.live import LIVE_SETTERS, applies_live
from ..scene.params import Param, resolve
from ..scene.scene import Scene
from ..scene.visual import describe
from ..stepper import check_dt
from ..theory import step_limited
from .pacing import Pacer, factor_text
from .runner import Runner

MAX_PANELS = 3
SUBSTEPS_MAX = 500
DT_RANGE = (1e-5, 0.5)  # s, the step-size slider's range
COMPILE_NOTE_S = 4.0  # s the HUD shows a first frame's compile time in place of its ms/frame


@dataclass(frozen=True)
class ParamControl:
    """How the panel edits one scene parameter.

    Attributes:
        param: the parameter (name, unit, meaning, type).
        live: whether a change applies at once (else on the next reset).
        low, high: the slider's range (numbers only).
    """

    param: Param
    live: bool
    low: float = 0.0
    high: float = 1.0


def slider_range(p: Param) -> tuple[float, float]:
    """A slider range for a numeric parameter: from its minimum (or -4x its default) to 4x its
    default (or 1 when the default is 0)."""
    d = float(p.default) if math.isfinite(float(p.default)) else 1.0
    span = 4.0 * abs(d) if d != 0 else 1.0
    low = float(p.minimum) if p.minimum is not None else -span
    high = max(span, low + 1.0)
    if p.kind is int:
        return float(math.ceil(low)), float(max(math.floor(high), math.ceil(low) + 1))
    return low, high


def compatible_integrators(scene: Scene, plugins: Sequence[str] = ()) -> list[str]:
    """Integrator names (the built-ins, then ``plugins``) that can step ``scene`` (first-order
    systems have no velocities; a constrained one takes only the methods that evaluate forces
    through eval_f)."""
    constrained = getattr(scene.system, "constraints", None) is not None
    elastic = bool(elastic_models(scene.system))
    classes = {**INTEGRATORS, **{name: integrator_class(name) for name in plugins}}
    return [name for name, cls in classes.items()
            if not (cls.requires_second_order and not scene.system.second_order)
            and not (constrained and not cls.takes_constraints)
            and not (elastic and not getattr(cls, "takes_elastic_models", True))]


class Session:
    """Scenes, runners and the control state of the launcher (or of a recording).

    Args:
        scene: preset name.
        integrators: one name, or two or three for a side-by-side comparison.
        params: parameter overrides (values or command-line strings).
        dt: step size (s); default: the preset's.
        substeps: steps of ``dt`` per drawn frame when not pacing to the wall clock.
        seed: random seed of the scenes.
        interactive: the launcher's defaults: scenes that can be grabbed are built with
            ``grab`` on (unless ``params`` say otherwise) and :meth:`frame` paces simulated time
            to the wall clock (:attr:`real_time`). Off, a scene gets no grab force term and
            each frame is ``substeps`` steps (what recording and tests want).
        integrator_options: integrator name -> its keyword options (``create_integrator``),
            used whenever a panel runs that method (a scene file's ``[integrator]`` table).
    """

    def __init__(self, scene: str, integrators: Sequence[str], *, params: dict | None = None,
                 dt: float | None = None, substeps: int = 10, seed: int = 0,
                 interactive: bool = False, integrator_options: dict | None = None):
        preset = scene_preset(scene)
        integrators = list(integrators)
        if not 1 <= len(integrators) <= MAX_PANELS:
            raise ConfigError(f"give 1 to {MAX_PANELS} integrators, got {len(integrators)}")
        # a plug-in goes by its class's name from here on (its spec loaded it once; the picker
        # offers it beside the built-ins)
        integrators = [name if name in INTEGRATORS else integrator_class(name).name for name in integrators]
        self.plugins = list(dict.fromkeys(name for name in integrators if name not in INTEGRATORS))
        self.seed = int(seed)
        self.integrator_options = {name: dict(opts) for name, opts in (integrator_options or {}).items()}
        self.interactive = bool(interactive)
        self.scene_name = preset.name
        self.params = self._resolve(preset, dict(params or {}))
        self.pending: dict[str, Any] = {}
        self.dt = float(dt if dt is not None else preset.default_dt)
        self._check_dt(self.dt)
        # without a step of its own the session takes each built scene's default: a fine cloth's
        # explicit stable step is shorter than its preset's (see _build)
        self.follow_default_dt = dt is None
        self.substeps = self._check_substeps(substeps)
        self.real_time = self.interactive
        self.pacer = Pacer()
        self.steps_per_frame = 0.0  # panel 0's steps per frame, smoothed: the raw count flickers
        self.paused = False
        self._paused_by_failure = False
        self.show_help = False
        self.show_setup = False
        self.generation = 0  # bumped when the scenes are rebuilt: renderers must be too
        self.resets = 0  # bumped by every reset: drawn trails must restart
        self.runners: list[Runner] = []
        self.curves: dict = {}  # parameter name -> Spline driving it over time (see set_curve)
        self._built: dict[tuple, list[Runner]] = {}  # see _build
        self._build(integrators)

    # -- building -----------------------------------------------------------------------------

    def _resolve(self, preset, overrides: dict) -> dict:
        """The preset's parameters with ``overrides``; an interactive session grabs by default."""
        if self.interactive and any(p.name == "grab" for p in preset.params):
            overrides = {"grab": True, **overrides}
        return resolve(preset.params, preset.name, overrides)

    def _build(self, integrators: Sequence[str], fallback: str | None = None) -> None:
        """Build one scene per integrator; an integrator that cannot step the scene is replaced
        by ``fallback``, or raises ConfigError without one.

        Scenes built for a (preset, parameters, seed, panel count) are kept and reused, back at
        t = 0, when the session comes back to them: Taichi 1.7 gives back neither the fields
        of a scene nor the kernels compiled for it, so rebuilding on every switch would grow
        the process by megabytes per switch (and recompile for seconds)."""
        key = self._key(self.scene_name, self.params, len(integrators))
        runners = self._built.get(key)
        scenes = [r.scene for r in runners] if runners is not None else \
            [build_scene(self.scene_name, self.params, seed=self.seed) for _ in integrators]
        if self.follow_default_dt:  # the scene's explicit stable step where a panel needs one
            preset_dt = scene_preset(self.scene_name).default_dt
            self.dt = float(scenes[0].explicit_step if any(step_limited(n) for n in integrators) else preset_dt)
        allowed = compatible_integrators(scenes[0], self.plugins)
        if fallback is not None:
            integrators = [n if n in allowed else fallback for n in integrators]
        for name in integrators:
            if name not in allowed:
                raise ConfigError(f"integrator {name!r} cannot step scene {self.scene_name!r} "
                                  f"(choose from {', '.join(allowed)})")
        if runners is None:
            runners = self._built[key] = [Runner(s, name, self.dt, self.integrator_options)
                                                for s, name in zip(scenes, integrators)]
        else:
            for r, name in zip(runners, integrators):
                # Live changes made on an earlier visit are undone: these are the params now.
                for setter in LIVE_SETTERS.values():
                    setter(r.scene, self.params)
                if r.scene.grabber is not None:
                    r.scene.grabber.release()
                r.set_integrator(name)
                r.set_dt(self.dt)
                if r.steps or r.frozen or r.t:
                    r.reset()
                else:
                    r.restart()  # the guard's reference must see the parameters just set
        self.runners = runners
        self.options = DrawOptions.for_visual(describe(runners[0].scene))
        self.generation += 1
        # Curves go on driving a rebuilt scene, unless it no longer has what they tune.
        self.curves = {k: c for k, c in self.curves.items() if applies_live(runners[0].scene, k)}
        for r in runners:
            r.set_curves(self.curves)

    def _key(self, name: str, params: dict, panels: int) -> tuple:
        return name, tuple(sorted((k, repr(v)) for k, v in params.items())), self.seed, panels

    def is_built(self, name: str) -> bool:
        """Whether :meth:`select_scene` (``name``) would reuse scenes built before (no field
        to allocate, no kernel to compile) rather than build them."""
        preset = scene_preset(name)
        return self._key(preset.name, self._resolve(preset, {}), len(self.runners)) in self._built

    @property
    def integrators(self) -> list[str]:
        return [r.integrator.name for r in self.runners]

    @property
    def scenes(self) -> list[Scene]:
        return [r.scene for r in self.runners]

    def visuals(self):
        """One :class:`~taichi_sim.scene.visual.SceneVisual` per panel (build a renderer from
        them whenever :attr:`generation` changes)."""
        return [describe(r.scene) for r in self.runners]

    def select_scene(self, name: str) -> None:
        """Switch to preset ``name`` with its default parameters and step size; integrators
        that cannot step it fall back to the preset's default."""
        preset = scene_preset(name)
        old = self.integrators
        self.scene_name = preset.name
        self.params = self._resolve(preset, {})
        self.pending = {}
        self.curves = {}  # curves belong to a scene's parameters
        self.dt = preset.default_dt
        self.follow_default_dt = True
        self._build(old, fallback=preset.default_integrator)
        self.pacer.reset()

    def cycle_scene(self, step: int = 1) -> str:
        """Switch to the next (step=1) or previous (-1) preset, in the registry's order."""
        names = list(SCENES)
        k = names.index(self.scene_name) if self.scene_name in names else -1
        name = names[(k + step) % len(names)]
        self.select_scene(name)
        return name

    # -- controls -----------------------------------------------------------------------------

    def param_controls(self) -> list[ParamControl]:
        """The scene's parameters, live ones first, each with its slider range."""
        live, setup = [], []
        for p in scene_preset(self.scene_name).params:
            is_live = p.name in LIVE_SETTERS and self._applies_live(p.name)
            low, high = slider_range(p) if p.kind in (int, float) else (0.0, 1.0)
            (live if is_live else setup).append(ParamControl(p, is_live, low, high))
        return live + setup

    def _applies_live(self, name: str) -> bool:
        return applies_live(self.runners[0].scene, name)

    # -- curves -------------------------------------------------------------------------------

    def drivable_params(self) -> list[ParamControl]:
        """The numeric parameters a curve can drive in the running scene (the live ones)."""
        return [c for c in self.param_controls() if c.live and c.param.kind in (int, float)]

    def set_curve(self, name: str, spline) -> None:
        """Drive parameter ``name`` along ``spline`` (a :class:`~taichi_sim.curves.Spline` of
        (t in s, value)) from the next step on; None stops driving it (it goes back to its set
        value). Raises ConfigError for a parameter that cannot be driven or a value it refuses."""
        from ..curves import check_curves

        if spline is None:
            if self.curves.pop(name, None) is not None:
                for r in self.runners:
                    r.set_curves(self.curves)
                    LIVE_SETTERS[name](r.scene, self.params)
                    r.system_changed()
            return
        check_curves({name: spline}, scene_preset(self.scene_name))
        if not self._applies_live(name):
            raise ConfigError(f"curve {name}: {self.scene_name} as built cannot change {name!r} while it runs")
        self.curves[name] = spline
        for r in self.runners:
            r.set_curves(self.curves)

    def set_curves(self, curves: dict) -> None:
        """Replace every curve (name -> Spline; checked first, nothing changes on an error)."""
        from ..curves import check_curves

        check_curves(dict(curves), scene_preset(self.scene_name))
        bad = [name for name in curves if not self._applies_live(name)]
        if bad:
            raise ConfigError(f"curve {bad[0]}: {self.scene_name} as built cannot change {bad[0]!r} while it runs")
        for name in list(self.curves):
            self.set_curve(name, None)
        self.curves = dict(curves)
        for r in self.runners:
            r.set_curves(self.curves)

    def value(self, name: str) -> Any:
        """The parameter's value as shown: a pending change, else the running one."""
        return self.pending.get(name, self.params[name])

    def set_param(self, name: str, value: Any) -> bool:
        """Change a parameter. Returns True when it applied at once; otherwise it is pending and
        applies at the next :meth:`reset`. Raises ConfigError for a bad value."""
        preset = scene_preset(self.scene_name)
        checked = resolve(preset.params, preset.name, {name: value})[name]
        if name in LIVE_SETTERS and self._applies_live(name):
            self.params[name] = checked
            for r in self.runners:
                LIVE_SETTERS[name](r.scene, self.params)
                r.system_changed()
            return True
        if checked == self.params[name]:
            self.pending.pop(name, None)
        else:
            self.pending[name] = checked
        return False

    def set_integrator(self, panel: int, name: str) -> None:
        """Use integrator ``name`` for panel ``panel`` (keeps the state and the time)."""
        allowed = compatible_integrators(self.runners[panel].scene, self.plugins)
        if name not in allowed:
            raise ConfigError(f"integrator {name!r} cannot step scene {self.scene_name!r}")
        self.runners[panel].set_integrator(name)
        self.pacer.reset()

    def cycle_integrator(self, panel: int, step: int = 1) -> str:
        """Switch panel ``panel`` to the next (step=1) or previous (-1) compatible integrator."""
        allowed = compatible_integrators(self.runners[panel].scene, self.plugins)
        current = self.runners[panel].integrator.name
        k = allowed.index(current) if current in allowed else -1
        name = allowed[(k + step) % len(allowed)]
        self.set_integrator(panel, name)
        return name

    def _check_dt(self, dt: float) -> float:
        return check_dt(dt)  # before any scene is built or changed

    def _check_substeps(self, substeps: int) -> int:
        if isinstance(substeps, bool) or not isinstance(substeps, int) or not 1 <= substeps <= SUBSTEPS_MAX:
            raise ConfigError(f"substeps must be an integer in 1..{SUBSTEPS_MAX}, got {substeps!r}")
        return substeps

    def set_dt(self, dt: float) -> None:
        """Step size (s) of every panel from the next step on."""
        self.dt = self._check_dt(dt)
        self.follow_default_dt = False
        for r in self.runners:
            r.set_dt(self.dt)
        self.pacer.reset()

    def set_substeps(self, substeps: int) -> None:
        """Steps of ``dt`` per drawn frame (when not pacing to the wall clock)."""
        self.substeps = self._check_substeps(substeps)

    def set_real_time(self, on: bool) -> None:
        """Pace frames to the wall clock (on) or take :attr:`substeps` steps per frame (off)."""
        self.real_time = bool(on)
        self.pacer.reset()

    def toggle_pause(self) -> None:
        self.paused = not self.paused
        self.pacer.reset()  # the pause is not time the simulation fell behind

    def step(self) -> None:
        """Pause, and advance every panel by exactly one step."""
        self.paused = True
        for r in self.runners:
            r.step_once()

    def reset(self) -> None:
        """Back to t = 0. Pending parameter changes apply now (the scenes are rebuilt). A pause
        that a failure caused ends."""
        self.resets += 1
        self.pacer.reset()
        if self._paused_by_failure:
            self.paused = self._paused_by_failure = False
        if self.pending:
            self.params.update(self.pending)
            self.pending = {}
            options = self.options
            self._build(self.integrators)
            self.options = options
            return
        scenes = self.scenes
        for r in self.runners:
            r.reset()
        if any(a is not b for a, b in zip(scenes, self.scenes)):
            self.generation += 1  # a scene was rebuilt: the renderer must be too

    # -- running ------------------------------------------------------------------------------

    def advance(self, duration: float) -> None:
        """Advance every panel by ``duration`` simulated seconds (the recorder's clock). When
        the last running panel stops (diverged, not converged, stiff), the session pauses, so
        the message stays on screen over the last good state."""
        for r in self.runners:
            r.advance(duration)
        if self.frozen and not self.paused:
            self.paused = self._paused_by_failure = True

    def frame(self, interval: float | None = None) -> None:
        """One launcher frame, unless paused: with :attr:`real_time` and the wall ``interval``
        (s) since the previous frame, as much simulated time as went by on the clock (cut to
        what the frame budget can simulate: see :class:`~taichi_sim.app.pacing.Pacer`);
        otherwise ``substeps`` steps of ``dt``."""
        if self.paused:
            return
        pacing = self.real_time and interval is not None
        duration = self.pacer.plan(interval, self.dt) if pacing else self.substeps * self.dt
        lead = self.runners[0]
        t0, steps0 = max(r.t for r in self.runners), lead.steps
        start = time.perf_counter()
        self.advance(duration)
        wall = time.perf_counter() - start
        simulated = max(r.t for r in self.runners) - t0
        steps = lead.steps - steps0
        self.steps_per_frame = steps if not self.steps_per_frame else \
            self.steps_per_frame + 0.25 * (steps - self.steps_per_frame)
        if interval is not None and not self.frozen:
            self.pacer.observe(interval, simulated, wall)

    def about_to_compile(self) -> list[Runner]:
        """The runners whose next step compiles their method's kernels: those the next
        :meth:`frame` steps (none while paused; not the frozen ones) for the first time with
        their current method."""
        if self.paused:
            return []
        return [r for r in self.runners if not r.frozen and not r.compiled]

    @property
    def frozen(self) -> bool:
        """Whether every panel has stopped (diverged or failed)."""
        return all(r.frozen for r in self.runners)

    def status(self) -> str:
        """The run status for the HUD: paused, running, or what stopped every run."""
        failed = [r for r in self.runners if r.frozen]
        if len(failed) == len(self.runners):  # the runners' lines say why
            return f"stopped ({failed[0].status.value})" if len(failed) == 1 else "every run stopped"
        return "paused" if self.paused else "running"

    def hud_lines(self, fps: float | None = None) -> list[str]:
        """The heads-up display: time, step, integrators, cost per frame, fps, energy, status."""
        t = max(r.t for r in self.runners)  # runs that froze stopped their clocks
        if self.real_time:
            pace = f"h = {self.dt:.3g} s x {self.steps_per_frame:.0f} per frame (real time)"
        else:
            pace = f"h = {self.dt:.3g} s x {self.substeps} per frame"
        lines = [f"{self.scene_name}   t = {t:.3f} s", pace + ("" if fps is None else f"   {fps:.1f} fps")]
        behind = "" if self.paused or self.frozen else factor_text(self.pacer.factor)
        if behind:
            slow = self.real_time and self.pacer.factor < 1.0
            lines.append(behind + (": the simulation cannot keep up with the clock" if slow else ""))
        for r in self.runners:
            energy = "n/a" if r.energy is None else f"{r.energy:.5g} J"
            state = r.failure if r.frozen else f"E = {energy}"
            if r.drift is not None and not r.frozen:
                state += f"   max |C| = {r.drift:.2e} m"
            if r.error_estimate is not None and not r.frozen:
                state += (f"   error ~{format_metres(r.error_estimate)}"
                          + ("" if r.converged else f" > tolerance {format_metres(r.stepper.monitor.tolerance)}"))
            compiled_just_now = r.compile_s is not None and time.perf_counter() - r.compiled_at < COMPILE_NOTE_S
            cost = f"first frame {r.compile_s:.1f} s (compiling kernels)" if compiled_just_now else \
                f"{r.sim_ms:.1f} ms/frame" if r.sim_ms else "ms/frame: not measured yet"
            lines.append(f"{r.name}: {cost}   {state}")
        lines.append(f"status: {self.status()}")
        for advice in dict.fromkeys(r.advice for r in self.runners if r.frozen):
            lines.extend(part.strip() for part in advice.split("; "))
        return lines
