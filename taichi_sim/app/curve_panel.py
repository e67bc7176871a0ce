"""The launcher's curve editor on screen: the strip drawn on GGUI's canvas and its controls.

What the mouse does and what is drawn is decided by
:class:`~taichi_sim.app.curve_editor.CurveEditor` (tested without a window); this module only
draws it. Its few fields are allocated once per launcher (Taichi never frees fields).
"""
from __future__ import annotations

import os
import textwrap
from pathlib import Path

import numpy as np
import taichi as ti

from ..curves import MAX_POINTS
from ..errors import ConfigError
from .curve_editor import EDITOR_RECT, CurveEditor
from .session import Session

#: The controls: a small window just above the strip (x, y, width, height; y down, as ImGui's).
CURVE_PANEL = (EDITOR_RECT[0], 1.0 - EDITOR_RECT[3] - 0.3, 0.3, 0.3)
CURVE_SAMPLES = 160  # points of the drawn curve
CURVE_BACK = (0.10, 0.11, 0.14)
CURVE_LINE = (1.0, 0.78, 0.25)
CURVE_GRID = (0.35, 0.37, 0.42)
CURVE_NOW = (0.55, 0.85, 1.0)
DEFAULT_CURVES_FILE = "curves.json"


class CurvePanel:
    """The editor strip and its controls for ``session`` in a window of ``size`` pixels;
    **save** / **load** use ``curves_path`` (default ``curves.json`` in the current folder)."""

    def __init__(self, session: Session, size: tuple[int, int], curves_path: str | os.PathLike | None = None):
        self.editor = CurveEditor(session, size)
        self.curves_path = Path(curves_path or DEFAULT_CURVES_FILE)
        self.curve_message = ""
        self._curve_lines = ti.Vector.field(2, ti.f32, shape=2 * (CURVE_SAMPLES - 1))
        self._curve_frame = ti.Vector.field(2, ti.f32, shape=12)  # border, zero line, time marker
        self._curve_back = ti.Vector.field(2, ti.f32, shape=6)
        self._curve_points = ti.Vector.field(2, ti.f32, shape=MAX_POINTS)

    @staticmethod
    def covers(u: float, v: float) -> bool:
        """Whether window point (u, v up) is over the controls window."""
        x, y, w, h = CURVE_PANEL
        return x <= u <= x + w and 1.0 - y - h <= v <= 1.0 - y

    @staticmethod
    def _file_action(action, path) -> str:
        """Run save or load; what it says, or why it failed (one line)."""
        try:
            return action(path)
        except ConfigError as exc:
            return str(exc)
        except OSError as exc:
            return f"{path}: {exc.strerror or exc}"

    def draw(self, canvas, gui, guard) -> None:
        """The curve editor: its strip drawn on the canvas (background, border, the curve, its
        points, the current time) and its controls in a small window above it."""
        editor, s = self.editor, self.editor.session
        editor.sync()
        u0, v0, u1, v1 = EDITOR_RECT
        def pts32(pts):  # the canvas's y runs up, as the editor's v
            return np.array(pts, np.float32)

        self._curve_back.from_numpy(pts32([(u0, v0), (u1, v0), (u1, v1), (u0, v0), (u1, v1), (u0, v1)]))
        canvas.triangles(self._curve_back, color=CURVE_BACK)
        now = editor.time_marker()
        frame = [(u0, v0), (u1, v0), (u1, v0), (u1, v1), (u1, v1), (u0, v1), (u0, v1), (u0, v0)]
        frame += [(now, v0), (now, v1)] if now is not None else [(u0, v0), (u0, v1)]
        view = editor.view()
        zero = min(max(view.to_window(0.0, 0.0)[1], v0), v1)
        frame += [(u0, zero), (u1, zero)]
        self._curve_frame.from_numpy(pts32(frame))
        canvas.lines(self._curve_frame, width=0.002, color=CURVE_GRID)
        if now is not None:  # over the grey one
            self._curve_frame.from_numpy(pts32([(now, v0), (now, v1)] * 6))
            canvas.lines(self._curve_frame, width=0.003, color=CURVE_NOW)
        line = editor.polyline(CURVE_SAMPLES)
        line = [line[0]] * (CURVE_SAMPLES - len(line)) + line  # a flat line pads to the field
        segments = [p for a, b in zip(line, line[1:]) for p in (a, b)]
        self._curve_lines.from_numpy(pts32(segments))
        canvas.lines(self._curve_lines, width=0.004, color=CURVE_LINE)
        markers = editor.markers()
        if markers:
            markers += [markers[-1]] * (MAX_POINTS - len(markers))
            self._curve_points.from_numpy(pts32(markers))
            canvas.circles(self._curve_points, radius=0.007, color=CURVE_LINE)
        with gui.sub_window("Curve", *CURVE_PANEL) as g:
            if editor.param is None:
                g.text("nothing in this scene can follow a curve")
                return
            names = editor.choices()
            def label(n):
                return n + (" *" if n in s.curves else "")

            g.text("curve of (* = driven): " + label(editor.param))
            if g.button("next parameter"):
                guard(editor.select, names[(names.index(editor.param) + 1) % len(names)])
            (t0, t1), (lo, hi) = view.t_range, view.value_range
            g.text(f"t {t0:g}..{t1:.3g} s, value {lo:.3g}..{hi:.3g}")
            g.text("left: add/drag  right: delete")
            if g.button("clear curve"):
                guard(editor.clear)
            if g.button(f"save {self.curves_path.name}"):
                self.curve_message = self._file_action(editor.save, self.curves_path)
            if g.button(f"load {self.curves_path.name}"):
                self.curve_message = self._file_action(editor.load, self.curves_path)
            for part in textwrap.wrap(editor.message or self.curve_message, 44):
                g.text(part)

