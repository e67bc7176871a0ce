"""The interactive launcher: a GGUI window with a control panel, a HUD and a help overlay.

Everything it decides lives in :class:`~taichi_sim.app.session.Session`,
:class:`~taichi_sim.app.input.CameraControl` and :class:`~taichi_sim.app.pacing.Pacer` (tested
without a window); this module only draws widgets and passes events on.
"""
from __future__ import annotations

import json
import math
import os
import signal
import textwrap
import threading
import time

import numpy as np
import taichi as ti

from .. import runtime
from ..atomic import write_atomically
from ..errors import ConfigError
from ..render import RenderUnavailable
from ..render.chart import Rect
from ..render.renderer import Renderer
from ..render.vulkan import open_window, take_back_imgui_ini, watch_imgui_ini
from ..scene import SCENES
from .contacts_view import GREY, ContactsView
from .curve_panel import CurvePanel
from .display import display_problem, fit_window, screen_area
from .energy import curves_of
from .energy_view import EnergyView, panel_centres
from .input import KEYMAP, CameraControl, GrabberHook, apply_key, help_lines
from .notice import RUN, SWITCH, CompileNotice
from .pacing import FrameClock
from .session import DT_RANGE, SUBSTEPS_MAX, Session, compatible_integrators

PANEL = (0.0, 0.0, 0.27, 1.0)  # control panel: x, y, width, height (fractions of the window)
HUD = (0.62, 0.0, 0.38, 0.3)
HUD_CHAR_PX = 7.5  # width of a character of GGUI's font, for wrapping the HUD's lines
HELP = (0.33, 0.1, 0.36, 0.68)  # x, y, width and the most height (help_window fits it to the lines)
NOTICE = (0.34, 0.5, 0.4)  # the compile notice's x, y and width: below the middle of the view
LINE_PX = 17  # height of a line of GGUI's text, for sizing a panel to its lines
WARNING = (1.0, 0.45, 0.38)
CURRENT = (0.55, 0.85, 1.0)  # the current entry of a list
#: The energy charts (normalised, y up): the curve editor's strip, which hides them when shown.
CHART_AREA = Rect(0.29, 0.03, 0.98, 0.28)
LEGEND = Rect(0.955, 0.36, 0.975, 0.64)  # the strain colour bar
#: Environment variable naming a JSON file the launcher writes its status to, about every
#: STATUS_EVERY seconds and when it closes (what the real-window test reads).
STATUS_ENV = "TAICHI_SIM_STATUS"
STATUS_EVERY = 0.25  # s
def help_window(size: tuple[int, int]) -> tuple[tuple[float, float, float, float], list[str]]:
    """The help overlay's (x, y, width, height), fractions of a window of ``size`` pixels, and
    its lines wrapped to that width: GGUI clips text at a panel's edges, which cut off the
    mouse help's last line. The panel is as tall as its lines (a title bar and margins over),
    moved up where the window is too short for it below HELP's y."""
    width = max(20, int(HELP[2] * size[0] / HUD_CHAR_PX) - 2)
    lines = [part for line in help_lines()
             for part in (textwrap.wrap(line, width, subsequent_indent="    ") or [""])]
    height = min(0.98, (len(lines) + 3) * LINE_PX / size[1])
    return (HELP[0], max(0.01, min(HELP[1], 0.99 - height)), HELP[2], height), lines


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


FIRST = ("cloth", "symplectic_euler")  # what the bare `taichi-sim` opens: the cheapest lively start


def first_session():
    """The session the bare ``taichi-sim`` opens the launcher on (:data:`FIRST`)."""
    scene, method = FIRST
    return Session(scene, [method], interactive=True)


class Launcher:
    """Runs ``session`` in a window of ``size`` = (width, height) pixels.

    ``window`` defaults to a new on-screen one, ``size`` cut to fit the screen it opens on
    (:func:`~taichi_sim.app.display.fit_window`; :attr:`size` is the size it got) (raises
    :class:`~taichi_sim.render.RenderUnavailable` with a one-line reason when no usable display
    or Vulkan exists); pass an offscreen window (see :func:`~taichi_sim.render.open_window`) to
    draw frames with :meth:`draw_frame` without a display (input then is not polled).
    """

    def __init__(self, session: Session, size: tuple[int, int] = (1280, 800), *, window=None,
                 curves_path: str | os.PathLike | None = None):
        self.session = session
        self.owns_window = window is None
        self._ini = watch_imgui_ini()
        if window is None:
            problem = display_problem()
            if problem is not None:  # GLFW would end the process with "cannot initialize GLFW"
                raise RenderUnavailable(f"an on-screen window needs a usable display: {problem}; "
                                        "record a video instead with `taichi-sim record`")
            pos, size = fit_window(size, screen_area())  # a 1280 x 800 window hid the Status panel
            window = open_window("taichi-sim", size, visible=True, pos=pos)
        self.size = tuple(size)
        self.window = window
        self.gui = self.window.get_gui()
        self.generation = -1
        self.fps = 0.0
        self.frames = 0
        self.error = ""
        self.picking: int | None = None  # the panel whose integrator list is open
        self.notice = CompileNotice()
        self.compiled = False  # whether the last frame drawn built or first stepped something
        self._renderers: dict = {}  # one per set of scenes, reused when the session comes back
        self.status_path = os.environ.get(STATUS_ENV) or None
        self._status_at = 0.0
        self.curve_panel = CurvePanel(session, size, curves_path)  # shown on demand
        self.editor = self.curve_panel.editor
        self.show_curves = bool(session.curves)
        self.energy_view = EnergyView(CHART_AREA, LEGEND)
        self.contacts_view = ContactsView()  # gathers only while its toggle is on
        if self.owns_window:  # the renderer and the first frame compile: say so in a frame first
            self.show_notice_only(f"compiling {session.scene_name}... (building the renderer)")
        self._rebuild()

    def _rebuild(self) -> None:
        """The renderer (and grab hooks) of the session's current scenes: built once per set of
        scenes and reused when the session switches back to them (a renderer holds fields and
        compiled kernels, which Taichi never gives back)."""
        key = tuple(id(scene) for scene in self.session.scenes)
        renderer = self._renderers.get(key)
        if renderer is None:
            # framed beside the control panel and below the Status panel, which hid the cloth's
            # pinned corners and the pendulum's pin
            renderer = Renderer(self.window, self.session.visuals(), self.size, inset=PANEL[2], top=HUD[3])
            self._renderers[key] = renderer
        else:
            renderer.clear_trails()
            renderer.home()
        self.renderer = renderer
        hooks = [GrabberHook(v.grabber, off, reach=0.05 * float(np.linalg.norm(v.extent)))
                 for v, off in zip(self.renderer.visuals, self.renderer.offsets) if v.grabber is not None]
        self.control = CameraControl(self.renderer.camera, self.renderer.home, hooks)
        self.generation = self.session.generation
        self.resets = self.session.resets

    def run(self) -> None:
        """The interactive loop, until the window closes or Escape is pressed; then
        :meth:`close`."""
        clock = FrameClock(time.perf_counter())
        interval = None
        # A polite kill (SIGTERM) ends the loop like Escape, so close() still cleans up.
        previous = signal.signal(signal.SIGTERM, _terminate) if _main_thread() else None
        try:
            while self.window.running:
                self.poll_input()
                self.draw_frame(interval)
                self.window.show()
                now = time.perf_counter()
                interval = clock.tick(now, compiled=self.compiled)
                self.fps = clock.fps
                if self.status_path and now - self._status_at >= STATUS_EVERY:
                    self.write_status()
                    self._status_at = now
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
            self.close()

    def close(self) -> None:
        """Write the final status (when asked for), close a window this launcher opened, and
        take back the ``imgui.ini`` that ImGui saves into the current directory."""
        if self.status_path:
            self.write_status(final=True)
        if not self.owns_window:
            return  # its owner destroys it; the ini file it writes then is taken back at exit
        try:
            self.window.destroy()  # ImGui writes its ini file now
        finally:
            take_back_imgui_ini(self._ini)

    def write_status(self, *, final: bool = False) -> None:
        """Write the status JSON to :attr:`status_path` (through a temporary file, so a reader
        never sees half of it): scene, integrators, step, time, steps, frames, real-time factor,
        the compile notice on screen (or null), grab moves, and for panel 0 the window pixel (x right, y down) of the free particle
        nearest the middle of the free ones; with ``final``, panel 0's positions (m) too."""
        s, r = self.session, self.session.runners[0]
        x = np.asarray(r.display.to_numpy() if hasattr(r.display, "to_numpy") else r.display, np.float64)
        free = np.ones(len(x), bool)
        if hasattr(r.scene.system, "free"):
            free = r.scene.system.free.to_numpy().astype(bool)
        status = {"scene": s.scene_name, "params": {k: v for k, v in s.params.items()
                                                     if isinstance(v, (bool, int, float, str))},
                  "integrators": s.integrators, "dt": s.dt, "seed": s.seed, "precision": runtime.precision(),
                  "t": r.t, "steps": r.steps,
                  "frames": self.frames, "real_time": s.real_time, "factor": s.pacer.factor,
                  "status": s.status(), "notice": self.notice.text(s), "grab_moves": -1 if r.scene.grabber is None else r.scene.grabber.moves,
                  "final": final}
        if free.any() and np.all(np.isfinite(x[free])):
            middle = x[free].mean(axis=0)
            index = int(np.flatnonzero(free)[np.argmin(np.linalg.norm(x[free] - middle, axis=1))])
            uv, depth = self.renderer.camera.project(x[index] + self.renderer.offsets[0])
            if depth[0] > 0:
                status["probe"] = {"particle": index, "px": [float(uv[0][0] * self.size[0]),
                                                              float((1.0 - uv[0][1]) * self.size[1])]}
        if r.drift is not None:
            status["constraint_violation"] = r.drift
        if r.residual is not None:
            status["solver_residual"] = r.residual
            status["error_estimate_m"] = r.error_estimate
        if final:
            status["x"] = x.tolist()
        write_atomically(self.status_path, lambda f: f.write(json.dumps(status)), binary=False)

    def poll_input(self) -> None:
        """Keys and mouse of this frame (on-screen windows only)."""
        scene_steps = 0  # scene keys pressed in one frame make one switch, not a build per press
        clicked = {"left": False, "right": False}  # a click shorter than a frame is seen here only
        for event in self.window.get_events(ti.ui.PRESS):
            if event.key in (ti.ui.LMB, ti.ui.RMB):
                clicked["left" if event.key == ti.ui.LMB else "right"] = True
                continue
            action = KEYMAP.get(event.key, ("",))[0]
            if action in ("next_scene", "previous_scene"):
                scene_steps += 1 if action == "next_scene" else -1
            elif self._guard(apply_key, event.key, self.session, self.control) == "quit":
                self.window.running = False
        if scene_steps:
            names = list(SCENES)
            k = names.index(self.session.scene_name) if self.session.scene_name in names else -1
            self.request_scene(names[(k + scene_steps) % len(names)])
        self.window.get_events(ti.ui.RELEASE)  # drained: GGUI queues them until read
        u, v = self.window.get_cursor_pos()
        over = u < PANEL[2] or (u > HUD[0] and v > 1.0 - HUD[3])
        left, right = self.window.is_pressed(ti.ui.LMB), self.window.is_pressed(ti.ui.RMB)
        if self.show_curves:
            over = over or self.curve_panel.covers(u, v)
            if not over and self.control.held is None:
                try:  # not _guard: that would clear the panel's error line every frame
                    took = self.editor.update(u, v, left=left, right=right, clicked=clicked)
                except ConfigError as exc:
                    took, self.error = True, str(exc)
                if took:
                    over, right = True, False  # the editor has the mouse: no grab, no orbit
        self.control.update(u, v, left=left, right=right,
                            middle=self.window.is_pressed(ti.ui.MMB), over_panel=over)

    def request_scene(self, name: str) -> None:
        """Switch to preset ``name`` once a frame saying so has been shown (see
        :mod:`~taichi_sim.app.notice`: building a scene and compiling its kernels holds the
        window for up to a minute on a first visit)."""
        self.notice.request_scene(name)

    def show_notice_only(self, text: str) -> None:
        """Show a frame with nothing but ``text`` over a blank view (an on-screen window
        before its first scene is drawn: the renderer's build compiles)."""
        for _ in range(2):  # ImGui draws a panel from its second frame on (the first sizes it)
            self.window.get_canvas().set_background_color((0.07, 0.07, 0.09))
            self._notice_box(text)
            self.window.show()

    def draw_frame(self, interval: float | None = None) -> None:
        """Advance the session one frame (``interval``: wall seconds since the last one, for
        pacing to the clock) and draw the scenes, the panel, the HUD and the help. A frame whose
        step would compile, or that builds a requested scene, waits for a frame that says so
        (:class:`~taichi_sim.app.notice.CompileNotice`); :attr:`compiled` says whether this
        one built or first stepped anything."""
        plan = self.notice.plan(self.session)
        self.compiled = plan != RUN or bool(self.session.about_to_compile())
        if plan == SWITCH:
            self._guard(self.session.select_scene, self.notice.take_scene())
        if self.session.generation != self.generation:
            self._rebuild()
        elif self.session.resets != self.resets:
            self.renderer.clear_trails()
            self.resets = self.session.resets
        if plan == RUN:  # a new scene or method is drawn unstepped until its notice is up
            self.session.frame(interval)
        self.frames += 1
        if not self.control.user_moved:
            self.renderer.follow([r.last_good for r in self.session.runners])
        self._update_overlay()
        self.contacts_view.update(self.session.runners, self.renderer, on=self.session.options.contacts)
        self.renderer.render([r.display for r in self.session.runners], self.session.options,
                             overlay=self.energy_view.draw, extras=self.contacts_view.draw)
        self._panel()
        self._hud()
        if self.show_curves:
            self._curves()
        if self.session.show_help:
            self._help()
        text = self.notice.text(self.session)  # after the panel: a click there shows at once
        if text is not None:
            self._notice_box(text)
        self.notice.shown(text)

    def _notice_box(self, text: str) -> None:
        """The compile notice, wrapped, in a panel over the middle of the view."""
        width = max(20, int(NOTICE[2] * self.size[0] / HUD_CHAR_PX) - 2)
        lines = textwrap.wrap(text, width, subsequent_indent="  ")
        height = min(0.45, (len(lines) + 2.5) * LINE_PX / self.size[1])
        # one ImGui id per line count: ImGui keeps the size a panel had when it first showed
        with self.gui.sub_window(f"Please wait##{len(lines)}", NOTICE[0], NOTICE[1], NOTICE[2], height) as g:
            for line in lines:
                g.text(line, CURRENT)

    def _update_overlay(self) -> None:
        """Lay out the energy charts (hidden while the curve editor has their strip) and the
        strain legend; the framing leaves the charts' strip free while they are shown."""
        s = self.session
        runners = s.runners
        charts = s.options.energy and not self.show_curves and bool(curves_of(runners[0].scene))
        bottom = CHART_AREA.y1 + 0.02 if charts else 0.0
        if self.renderer.camera.bottom != bottom:
            self.renderer.camera.bottom = bottom
            if not self.control.user_moved:
                self.renderer.home()  # frame again for the height now free
        legend = s.options.strain and s.options.mesh and self.renderer.visuals[0].mesh is not None
        self.energy_view.update(runners, panel_centres(self.renderer), energy=charts,
                                strain_scale=s.options.strain_scale if legend else None)

    def _guard(self, action, *args):
        """Run a control action and return its result; a bad value is shown in the panel
        instead of ending the app."""
        try:
            result = action(*args)
        except ConfigError as exc:
            self.error = str(exc)
            return None
        self.error = ""
        return result

    def _panel(self) -> None:
        s = self.session
        with self.gui.sub_window("Controls", *PANEL) as g:
            g.text("Scene (Up / Down keys)")
            for name in SCENES:
                current = name == s.scene_name
                if g.button(("> " if current else "  ") + name + "##scene"):
                    self.request_scene(name)
                    self.picking = None
            g.text("")
            self._integrator_picker(g)
            g.text("")
            real_time = g.checkbox("real time (pace to the clock)", s.real_time)
            if real_time != s.real_time:
                s.set_real_time(real_time)
            if not s.real_time:
                g.text("steps per frame")
                substeps = g.slider_int("##substeps", s.substeps, 1, SUBSTEPS_MAX)
                if substeps != s.substeps:
                    self._guard(s.set_substeps, int(substeps))
            g.text(f"step h = {s.dt:.3g} s (log10 below)")
            exponent = g.slider_float("##log10 step", math.log10(s.dt), *map(math.log10, DT_RANGE))
            if abs(exponent - math.log10(s.dt)) > 1e-6:
                self._guard(s.set_dt, float(10.0 ** exponent))
            if g.button("Resume (space)" if s.paused else "Pause (space)"):
                s.toggle_pause()
            if g.button("Single step (n)"):
                s.step()
            if g.button("Reset (r)"):
                self._guard(s.reset)
            if g.button("Frame view (f)"):
                self.control.home()
            g.text("")
            o = s.options
            o.mesh = g.checkbox("mesh (m)", o.mesh)
            o.springs = g.checkbox("springs (k)", o.springs)
            o.particles = g.checkbox("particles (p)", o.particles)
            o.strain = g.checkbox("strain colours (c)", o.strain)
            o.trail = g.checkbox("trail (t)", o.trail)
            o.energy = g.checkbox("energy plot (e)", o.energy)
            o.contacts = g.checkbox("contacts (x)", o.contacts)
            note = self.contacts_view.panel_note()
            for part in textwrap.wrap(note or "", self._panel_chars(), subsequent_indent="  "):
                g.text(part, GREY)  # greyed, under the toggle: why it draws nothing
            s.show_help = g.checkbox("help (h)", s.show_help)
            self.show_curves = g.checkbox("curve editor", self.show_curves)
            g.text("")
            g.text("Parameters (live)")
            controls = s.param_controls()
            for c in controls:
                if c.live:
                    self._param_widget(g, c)
            s.show_setup = g.checkbox("more (apply on reset)", s.show_setup)
            if s.show_setup:
                for c in controls:
                    if not c.live:
                        self._param_widget(g, c)
            if s.pending:
                g.text(f"{len(s.pending)} change(s) pending: press Reset", WARNING)
            if self.error:
                for part in textwrap.wrap(self.error, self._panel_chars()):
                    g.text(part, WARNING)

    def _panel_chars(self) -> int:
        """Characters of GGUI's font that fit across the control panel."""
        return max(20, int(PANEL[2] * self.size[0] / HUD_CHAR_PX) - 3)

    def _integrator_picker(self, g) -> None:
        """One combo-like picker per panel: a button showing the current integrator opens the
        list of those that can step the scene (the current one marked); a choice closes it."""
        s = self.session
        for k, r in enumerate(s.runners):
            prefix = "Integrator" if len(s.runners) == 1 else f"Panel {k + 1}"
            opened = self.picking == k
            if g.button(f"{prefix}: {r.integrator.name} {'(close)' if opened else '(change)'}##pick{k}"):
                self.picking = None if opened else k
            if self.picking != k:
                continue
            for name in compatible_integrators(r.scene, s.plugins):
                if g.button(("> " if name == r.integrator.name else "  ") + f"{name}##int{k}"):
                    self._guard(s.set_integrator, k, name)
                    self.picking = None

    def _param_widget(self, g, control) -> None:
        p, s = control.param, self.session
        value = s.value(p.name)
        label = f"{p.name}" + (f" ({p.unit})" if p.unit else "")
        if p.kind is bool:
            new = g.checkbox(label, value)
        elif p.choices:
            new = value
            if g.button(f"{label}: {value}"):
                new = p.choices[(p.choices.index(value) + 1) % len(p.choices)]
        elif p.kind is int:
            g.text(label)  # above the slider: beside it, GGUI cuts long labels off
            new = g.slider_int(f"##{p.name}", int(value), int(control.low), int(control.high))
        elif p.kind is float and math.isfinite(value):
            g.text(label)
            new = g.slider_float(f"##{p.name}", float(value), control.low, control.high)
            new = value if abs(new - value) <= 1e-7 * max(1.0, abs(value)) else new
        else:
            g.text(f"{label}: {value}")
            return
        if new != value:
            self._guard(s.set_param, p.name, new)

    def _hud(self) -> None:
        s = self.session
        with self.gui.sub_window("Status", *HUD) as g:
            # GGUI clips text at the panel's edge: wrap it (the monospace font is ~7.5 px wide).
            width = max(20, int(HUD[2] * self.size[0] / HUD_CHAR_PX) - 2)
            for line in s.hud_lines(self.fps):
                colour = WARNING if any(word in line for word in ("diverged", "not converged", "stiff",
                                                                  "x real time")) else None
                for part in textwrap.wrap(line, width, subsequent_indent="  ") or [""]:
                    g.text(part, colour)
            if len(s.runners) > 1:
                uv, _ = self.renderer.camera.project(np.array(self.renderer.label_points()))
                order = np.argsort(uv[:, 0])
                g.text("left to right: " + ", ".join(s.runners[k].name for k in order))
            for text, colour in self.energy_view.hud_lines():
                g.text(text, colour)
            for text, colour in self.contacts_view.notes:
                for part in textwrap.wrap(text, width, subsequent_indent="  "):
                    g.text(part, colour)

    def _curves(self) -> None:
        self.curve_panel.draw(self.renderer.canvas, self.gui, self._guard)

    def _help(self) -> None:
        rect, lines = help_window(self.size)
        with self.gui.sub_window("Help", *rect) as g:
            for line in lines:
                g.text(line)

