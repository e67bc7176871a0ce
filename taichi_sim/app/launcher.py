"""The interactive launcher: a GGUI window with a control panel, a HUD and a help overlay.

Everything it decides lives in :class:`~taichi_sim.app.session.Session` and
:class:`~taichi_sim.app.input.CameraControl` (tested without a window); this module only draws
widgets and passes events on.
"""
from __future__ import annotations

import math
import textwrap
import time

import numpy as np
import taichi as ti

from ..errors import ConfigError
from ..render.renderer import Renderer
from ..render.vulkan import open_window
from ..scene import SCENES
from .input import CameraControl, GrabberHook, apply_key, help_lines
from .session import DT_RANGE, SUBSTEPS_MAX, Session

PANEL = (0.0, 0.0, 0.27, 1.0)  # control panel: x, y, width, height (fractions of the window)
HUD = (0.62, 0.0, 0.38, 0.3)
HUD_CHAR_PX = 7.5  # width of a character of GGUI's font, for wrapping the HUD's lines
HELP = (0.35, 0.25, 0.32, 0.5)
WARNING = (1.0, 0.45, 0.38)


class Launcher:
    """Runs ``session`` in a window of ``size`` = (width, height) pixels.

    ``window`` defaults to a new on-screen one; pass an offscreen window (see
    :func:`~taichi_sim.render.open_window`) to draw frames with :meth:`draw_frame` without a
    display (input then is not polled).
    """

    def __init__(self, session: Session, size: tuple[int, int] = (1280, 800), *, window=None):
        self.session = session
        self.size = size
        self.window = window if window is not None else open_window("taichi-sim", size, visible=True)
        self.gui = self.window.get_gui()
        self.generation = -1
        self.fps = 0.0
        self.error = ""
        self._rebuild()

    def _rebuild(self) -> None:
        """A new renderer (and grab hooks) for the session's current scenes."""
        self.renderer = Renderer(self.window, self.session.visuals(), self.size, inset=PANEL[2])
        hooks = [GrabberHook(v.grabber, off, reach=0.05 * float(np.linalg.norm(v.extent)))
                 for v, off in zip(self.renderer.visuals, self.renderer.offsets) if v.grabber is not None]
        self.control = CameraControl(self.renderer.camera, self.renderer.home, hooks)
        self.generation = self.session.generation
        self.resets = self.session.resets

    def run(self) -> None:
        """The interactive loop, until the window closes or Escape is pressed."""
        last = time.perf_counter()
        while self.window.running:
            self.poll_input()
            self.draw_frame()
            self.window.show()
            now = time.perf_counter()
            self.fps = 0.9 * self.fps + 0.1 / max(now - last, 1e-6)
            last = now

    def poll_input(self) -> None:
        """Keys and mouse of this frame (on-screen windows only)."""
        for event in self.window.get_events(ti.ui.PRESS):
            if self._guard(apply_key, event.key, self.session, self.control) == "quit":
                self.window.running = False
        self.window.get_events(ti.ui.RELEASE)  # drained: GGUI queues them until read
        u, v = self.window.get_cursor_pos()
        over = u < PANEL[2] or (u > HUD[0] and v > 1.0 - HUD[3])
        self.control.update(u, v, left=self.window.is_pressed(ti.ui.LMB),
                            right=self.window.is_pressed(ti.ui.RMB),
                            middle=self.window.is_pressed(ti.ui.MMB), over_panel=over)

    def draw_frame(self) -> None:
        """Advance the session one frame and draw the scenes, the panel, the HUD and the help."""
        if self.session.generation != self.generation:
            self._rebuild()
        elif self.session.resets != self.resets:
            self.renderer.clear_trails()
            self.resets = self.session.resets
        self.session.frame()
        if not self.control.user_moved:
            self.renderer.follow([r.last_good for r in self.session.runners])
        self.renderer.render([r.display for r in self.session.runners], self.session.options)
        self._panel()
        self._hud()
        if self.session.show_help:
            self._help()

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
            g.text("Scene")
            for name in SCENES:
                if g.button(("> " if name == s.scene_name else "") + name):
                    self._guard(s.select_scene, name)
            g.text("")
            g.text("Integrator" + ("s" if len(s.runners) > 1 else ""))
            for k, r in enumerate(s.runners):
                if g.button(f"<##prev{k}"):
                    self._guard(s.cycle_integrator, k, -1)
                if g.button(f"{r.integrator.name} >##next{k}"):
                    self._guard(s.cycle_integrator, k, 1)
            g.text("")
            exponent = g.slider_float("log10 step", math.log10(s.dt), *map(math.log10, DT_RANGE))
            if abs(exponent - math.log10(s.dt)) > 1e-6:
                self._guard(s.set_dt, float(10.0 ** exponent))
            g.text(f"h = {s.dt:.3g} s")
            substeps = g.slider_int("steps per frame", s.substeps, 1, SUBSTEPS_MAX)
            if substeps != s.substeps:
                self._guard(s.set_substeps, int(substeps))
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
            s.show_help = g.checkbox("help (h)", s.show_help)
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
                g.text(self.error, WARNING)

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
            new = g.slider_int(label, int(value), int(control.low), int(control.high))
        elif p.kind is float and math.isfinite(value):
            new = g.slider_float(label, float(value), control.low, control.high)
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
                colour = WARNING if "diverged" in line or "not converged" in line or "stiff" in line else None
                for part in textwrap.wrap(line, width, subsequent_indent="  ") or [""]:
                    g.text(part, colour)
            if len(s.runners) > 1:
                uv, _ = self.renderer.camera.project(np.array(self.renderer.label_points()))
                order = np.argsort(uv[:, 0])
                g.text("left to right: " + ", ".join(s.runners[k].name for k in order))

    def _help(self) -> None:
        with self.gui.sub_window("Help", *HELP) as g:
            for line in help_lines():
                g.text(line)

