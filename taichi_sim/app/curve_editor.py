"""The curve editor's logic, without a window: a rectangle of the window where the mouse adds,
drags and deletes the control points of one parameter's curve (t in s across, the value up).

The launcher draws what :class:`CurveEditor` says (the polyline, the points, the current time)
and feeds it the cursor and buttons; every edit goes to the session at once, so the running
scene follows the curve from its next step.

Mouse: a left press on a point picks it up (drag to move it: its time stays between its
neighbours', its value within the parameter's allowed range), a left press elsewhere adds a
point there and picks it up; a right press on a point deletes it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ..curves import MAX_POINTS, Spline, load_curves, save_curves
from ..errors import ConfigError
from ..scene import scene_preset
from .session import Session, slider_range

#: Where the editor sits: u0, v0, u1, v1 in window units (0..1, v up): a strip along the
#: bottom, right of the control panel.
EDITOR_RECT = (0.29, 0.03, 0.98, 0.30)
PICK_PX = 9.0  # a press this close (pixels) to a point picks it
DEFAULT_SPAN = 10.0  # s shown across the editor


@dataclass(frozen=True)
class CurveView:
    """The mapping between window units (u, v up) and curve coordinates (t in s, value)."""

    rect: tuple[float, float, float, float]
    t_range: tuple[float, float]
    value_range: tuple[float, float]

    def contains(self, u: float, v: float) -> bool:
        u0, v0, u1, v1 = self.rect
        return u0 <= u <= u1 and v0 <= v <= v1

    def to_window(self, t: float, value: float) -> tuple[float, float]:
        u0, v0, u1, v1 = self.rect
        (t0, t1), (lo, hi) = self.t_range, self.value_range
        return u0 + (u1 - u0) * (t - t0) / (t1 - t0), v0 + (v1 - v0) * (value - lo) / (hi - lo)

    def to_curve(self, u: float, v: float) -> tuple[float, float]:
        u0, v0, u1, v1 = self.rect
        (t0, t1), (lo, hi) = self.t_range, self.value_range
        return t0 + (t1 - t0) * (u - u0) / (u1 - u0), lo + (hi - lo) * (v - v0) / (v1 - v0)


class CurveEditor:
    """Edits the session's curves with the mouse.

    Args:
        session: whose curves are edited (:meth:`Session.set_curve` applies every change).
        size: the window's (width, height) in pixels (picking is measured in pixels).
        rect: where the editor is in the window (see EDITOR_RECT).

    Attributes:
        param: the parameter being edited (None: the scene has nothing a curve can drive).
        span: seconds shown across the editor.
        message: the last refusal (a point past MAX_POINTS, a value the parameter refuses).
    """

    def __init__(self, session: Session, size: tuple[int, int], rect=EDITOR_RECT):
        self.session = session
        self.size = size
        self.rect = rect
        self.span = DEFAULT_SPAN
        self.message = ""
        self.held: int | None = None  # index of the point being dragged
        self._left_before = self._right_before = False
        self._scene = None
        self.param: str | None = None
        self.sync()

    # -- what is edited -----------------------------------------------------------------------

    def choices(self) -> list[str]:
        """Parameters of the current scene a curve can drive."""
        return [c.param.name for c in self.session.drivable_params()]

    def sync(self) -> None:
        """Follow a scene switch: edit the first drivable parameter of the new scene."""
        if self._scene != self.session.scene_name or self.param not in self.choices():
            self._scene = self.session.scene_name
            names = self.choices()
            self.param = names[0] if names else None
            self.held = None

    def select(self, name: str) -> None:
        if name not in self.choices():
            raise ConfigError(f"{name!r} cannot be driven by a curve in {self.session.scene_name}")
        self.param, self.held = name, None

    def points(self) -> list[tuple[float, float]]:
        """The control points (t in s, value) of the edited curve (empty: not driven)."""
        spline = self.session.curves.get(self.param) if self.param else None
        return list(spline.points) if spline is not None else []

    def _limits(self) -> tuple[float, float]:
        """The lowest value the parameter allows (None-free) and the slider's top."""
        p = scene_preset(self.session.scene_name).param(self.param)
        low, high = slider_range(p)
        if p.minimum is not None:
            low = float(p.minimum)
            if p.exclusive:
                low += 1e-6 * max(1.0, abs(high - low))
        return low, high

    def view(self) -> CurveView:
        """The editor's axes: 0..span s across; the parameter's slider range up, widened to hold
        every control point and the current value."""
        low, high = self._limits() if self.param else (0.0, 1.0)
        values = [v for _, v in self.points()]
        if self.param:
            values.append(float(self.session.params[self.param]))
        lo, hi = min([low, *values]), max([high, *values])
        if hi - lo <= 0:
            hi = lo + 1.0
        t_end = max([self.span, *(t * 1.05 for t, _ in self.points())])
        return CurveView(self.rect, (0.0, t_end), (lo, hi))

    # -- editing ------------------------------------------------------------------------------

    def _apply(self, points: list[tuple[float, float]]) -> None:
        self.session.set_curve(self.param, Spline(tuple(points)) if points else None)

    def hit(self, u: float, v: float) -> int | None:
        """Index of the control point within PICK_PX pixels of (u, v), the nearest, or None."""
        view, best, best_d = self.view(), None, PICK_PX
        for k, (t, value) in enumerate(self.points()):
            pu, pv = view.to_window(t, value)
            d = math.hypot((pu - u) * self.size[0], (pv - v) * self.size[1])
            if d <= best_d:
                best, best_d = k, d
        return best

    def _clamped(self, k: int, points, t: float, value: float) -> tuple[float, float]:
        """(t, value) kept strictly between the neighbours' times and within the limits."""
        view = self.view()
        gap = 1e-3 * (view.t_range[1] - view.t_range[0])
        t_low = points[k - 1][0] + gap if k > 0 else 0.0
        t_high = points[k + 1][0] - gap if k + 1 < len(points) else math.inf
        low, _ = self._limits()
        t = min(max(t, t_low), t_high)
        return t, max(value, low)

    def add(self, t: float, value: float) -> int | None:
        """Add a point at (t, value) (clamped to t >= 0 and the parameter's minimum); returns its
        index, or None (with :attr:`message`) past MAX_POINTS or on a time already taken."""
        points = self.points()
        if len(points) >= MAX_POINTS:
            self.message = f"a curve holds at most {MAX_POINTS} points"
            return None
        t = max(t, 0.0)
        value = max(value, self._limits()[0])
        if any(abs(t - pt) < 1e-9 for pt, _ in points):
            self.message = f"a point at t = {t:.3g} s exists"
            return None
        points.append((t, value))
        points.sort()
        self._apply(points)
        self.message = ""
        return points.index((t, value))

    def move(self, k: int, t: float, value: float) -> None:
        """Move point ``k`` toward (t, value), clamped (see :meth:`_clamped`)."""
        points = self.points()
        points[k] = self._clamped(k, points, t, value)
        self._apply(points)

    def delete(self, k: int) -> None:
        points = self.points()
        del points[k]
        self._apply(points)

    def clear(self) -> None:
        """No curve for the edited parameter (it goes back to its set value)."""
        if self.param:
            self.session.set_curve(self.param, None)
        self.held = None

    def update(self, u: float, v: float, *, left: bool, right: bool, clicked: dict | None = None) -> bool:
        """Feed one frame's cursor (window units, v up) and buttons (held now), and ``clicked``
        ({"left": bool, "right": bool}: a press event this frame, which catches a click
        released before the frame polled). Returns whether the editor took the mouse (the
        caller then keeps it from the camera and the grab)."""
        clicked = clicked or {}
        pressed_left = (left and not self._left_before) or clicked.get("left", False)
        pressed_right = (right and not self._right_before) or clicked.get("right", False)
        self._left_before, self._right_before = left, right
        if self.param is None:
            return False
        view = self.view()
        if self.held is not None:
            if left:
                self.move(self.held, *view.to_curve(u, v))
                return True
            self.held = None
            return True
        if not view.contains(u, v):
            return False
        if pressed_left:
            k = self.hit(u, v)
            self.held = k if k is not None else self.add(*view.to_curve(u, v))
        elif pressed_right:
            k = self.hit(u, v)
            if k is not None:
                self.delete(k)
        return True

    # -- drawing ------------------------------------------------------------------------------

    def polyline(self, count: int = 200) -> list[tuple[float, float]]:
        """``count`` points of the curve across the editor (window units); the set value as a
        flat line when the parameter is not driven."""
        view = self.view()
        t0, t1 = view.t_range
        spline = self.session.curves.get(self.param) if self.param else None
        if spline is None:
            value = float(self.session.params[self.param]) if self.param else view.value_range[0]
            return [view.to_window(t0, value), view.to_window(t1, value)]
        return [view.to_window(t, value) for t, value in spline.sample(t0, t1, count)]

    def markers(self) -> list[tuple[float, float]]:
        """The control points in window units."""
        view = self.view()
        return [view.to_window(t, value) for t, value in self.points()]

    def time_marker(self) -> float | None:
        """u of the current simulated time, or None when it is past the editor's right edge."""
        view = self.view()
        t = max(r.t for r in self.session.runners)
        return view.to_window(t, 0.0)[0] if t <= view.t_range[1] else None

    # -- files --------------------------------------------------------------------------------

    def save(self, path) -> str:
        """Write the session's curves to ``path``; returns a line saying what was written."""
        save_curves(path, self.session.curves, self.session.scene_name)
        return f"saved {len(self.session.curves)} curve(s) to {path}"

    def load(self, path) -> str:
        """Read ``path`` and drive the session with its curves (ConfigError, nothing changed, for
        a bad file)."""
        curves = load_curves(path, scene_preset(self.session.scene_name))
        self.session.set_curves(curves)
        self.held = None
        self.sync()
        return f"loaded {len(curves)} curve(s) from {path}"
