"""Where the energy plot and the strain legend go: pure numpy layout, no window.

Everything here is in GGUI's normalised canvas coordinates: (0, 0) the bottom-left corner of
the window, (1, 1) the top-right, y up. :mod:`taichi_sim.render.chart_canvas` hands the
results to GGUI's canvas; :func:`chart_labels` and :func:`legend_labels` give the text for
recorded frames (pixels, y down, for :func:`taichi_sim.render.overlay.burn`), since GGUI draws
no text into an offscreen frame (its ImGui widgets are not in ``get_image_buffer_as_numpy``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from .overlay import Label

#: Curve colours (RGB in [0, 1]), by energy component.
CURVE_COLOURS = {
    "kinetic": (0.35, 0.75, 1.00),
    "gravity": (0.55, 0.90, 0.40),
    "spring": (1.00, 0.62, 0.20),
    "total": (0.97, 0.97, 0.97),
}
PLOT_BACKGROUND = (0.03, 0.035, 0.045)
FRAME = (0.38, 0.40, 0.44)
#: The strain colour map's stops (blue, teal, yellow, red), evenly spaced over [0, 1]; the
#: drawer's kernel (``render.drawer._colormap``) interpolates the same stops.
STRAIN_STOPS = ((0.20, 0.35, 0.85), (0.15, 0.75, 0.55), (0.96, 0.85, 0.25), (0.90, 0.18, 0.14))
OFF = -2.0  # a coordinate off the canvas: where unused vertices go


@dataclass(frozen=True)
class Rect:
    """A rectangle on the canvas, normalised coordinates (y up): x0 < x1, y0 < y1."""

    x0: float
    y0: float
    x1: float
    y1: float

    def __post_init__(self):
        if not (self.x0 < self.x1 and self.y0 < self.y1):
            raise ValueError(f"rect must have x0 < x1 and y0 < y1, got {self}")

    @property
    def width(self) -> float:
        return self.x1 - self.x0

    @property
    def height(self) -> float:
        return self.y1 - self.y0


def chart_rects(centres: Sequence[float], area: Rect, *, fill: float = 0.92) -> list[Rect]:
    """One chart per panel, in ``area``, centred under each panel's horizontal centre
    (``centres``: u in [0, 1], in any order; the result follows that order). Charts are as wide
    as the closest two centres allow (``fill`` of the spacing), at most ``area``'s width over
    their count, and kept inside ``area``."""
    u = np.asarray(centres, float).reshape(-1)
    if not len(u):
        return []
    width = area.width / len(u)
    if len(u) > 1:
        width = min(width, float(np.min(np.diff(np.sort(u)))))
    width *= fill
    rects = []
    for c in u:
        x0 = float(np.clip(c - 0.5 * width, area.x0, area.x1 - width))
        rects.append(Rect(x0, area.y0, x0 + width, area.y1))
    return rects


def common_ranges(panels: Sequence[tuple[np.ndarray, Mapping[str, np.ndarray]]]) -> tuple[
        tuple[float, float], tuple[float, float]]:
    """((t_lo, t_hi) (s), (e_lo, e_hi) (J)) shared by every panel's curves, so that side-by-side
    charts compare on the same axes. ``panels``: (times (n,), name -> values (n,)) each. The
    energy range gets 5 % margins; an empty or flat one is widened to a unit around its value."""
    ts = [np.asarray(t, float) for t, _ in panels if len(t)]
    vs = [np.asarray(v, float) for _, curves in panels for v in curves.values() if len(v)]
    vs = [v[np.isfinite(v)] for v in vs]
    vs = [v for v in vs if len(v)]
    t_lo = min((float(t[0]) for t in ts), default=0.0)
    t_hi = max((float(t[-1]) for t in ts), default=1.0)
    if not t_hi > t_lo:
        t_hi = t_lo + 1.0
    if not vs:
        return (t_lo, t_hi), (-1.0, 1.0)
    lo = min(float(v.min()) for v in vs)
    hi = max(float(v.max()) for v in vs)
    span = hi - lo
    if not span > 1e-12 * max(abs(lo), abs(hi), 1e-300):
        pad = max(abs(hi), 1.0) * 0.5
        return (t_lo, t_hi), (lo - pad, hi + pad)
    return (t_lo, t_hi), (lo - 0.05 * span, hi + 0.05 * span)


def curve_points(t: np.ndarray, values: np.ndarray, rect: Rect, t_range: tuple[float, float],
                 v_range: tuple[float, float]) -> np.ndarray:
    """(n, 2) canvas points of the curve ``values`` (J) over ``t`` (s) in ``rect``: t_range maps
    onto its width, v_range onto its height; points outside (and non-finite values) are held
    at its edges."""
    t = np.asarray(t, float)
    v = np.nan_to_num(np.asarray(values, float), nan=v_range[0], posinf=v_range[1], neginf=v_range[0])
    a = np.clip((t - t_range[0]) / (t_range[1] - t_range[0]), 0.0, 1.0)
    b = np.clip((v - v_range[0]) / (v_range[1] - v_range[0]), 0.0, 1.0)
    return np.stack([rect.x0 + a * rect.width, rect.y0 + b * rect.height], axis=1)


def segments(points: np.ndarray) -> np.ndarray:
    """(2 (n - 1), 2): the polyline through ``points`` ((n, 2)) as segment end pairs (what
    GGUI's ``canvas.lines`` draws without indices)."""
    p = np.asarray(points, float)
    if len(p) < 2:
        return np.zeros((0, 2))
    out = np.empty((2 * (len(p) - 1), 2))
    out[0::2], out[1::2] = p[:-1], p[1:]
    return out


def frame_segments(rect: Rect) -> np.ndarray:
    """(8, 2): the rectangle's outline as four segments."""
    c = np.array([[rect.x0, rect.y0], [rect.x1, rect.y0], [rect.x1, rect.y1], [rect.x0, rect.y1]])
    return segments(np.vstack([c, c[:1]]))


def quad(rect: Rect) -> np.ndarray:
    """(6, 2): the rectangle as two triangles."""
    return np.array([[rect.x0, rect.y0], [rect.x1, rect.y0], [rect.x1, rect.y1],
                     [rect.x0, rect.y0], [rect.x1, rect.y1], [rect.x0, rect.y1]])


@dataclass
class ChartGeometry:
    """What to hand GGUI's canvas: ``lines`` (m, 2) segment ends with ``line_colours`` (m, 3),
    ``triangles`` (k, 2) with ``triangle_colours`` (k, 3); plus the axes used (``t_range``,
    ``v_range``) and the chart rectangles (``rects``) for the labels."""

    lines: np.ndarray
    line_colours: np.ndarray
    triangles: np.ndarray
    triangle_colours: np.ndarray
    rects: list
    t_range: tuple = (0.0, 1.0)
    v_range: tuple = (-1.0, 1.0)


def energy_charts(panels: Sequence[tuple[np.ndarray, Mapping[str, np.ndarray]]],
                  rects: Sequence[Rect]) -> ChartGeometry:
    """The energy plots: panel k's curves ((times (n,) s, name -> values (n,) J), names from
    :data:`CURVE_COLOURS`) in ``rects[k]`` on a dark background with a frame, on axes common to
    every panel (:func:`common_ranges`)."""
    if len(panels) != len(rects):
        raise ValueError(f"rects must hold one rect per panel ({len(panels)}), got {len(rects)}")
    t_range, v_range = common_ranges(panels)
    lines, colours, tris, tri_colours = [], [], [], []
    for (t, curves), rect in zip(panels, rects):
        tris.append(quad(rect))
        tri_colours.append(np.tile(PLOT_BACKGROUND, (6, 1)))
        if v_range[0] < 0.0 < v_range[1]:  # the zero line
            y = rect.y0 + (0.0 - v_range[0]) / (v_range[1] - v_range[0]) * rect.height
            lines.append(np.array([[rect.x0, y], [rect.x1, y]]))
            colours.append(np.tile(np.asarray(FRAME) * 0.6, (2, 1)))
        for name, values in curves.items():
            seg = segments(curve_points(t, values, rect, t_range, v_range))
            lines.append(seg)
            colours.append(np.tile(CURVE_COLOURS[name], (len(seg), 1)))
        lines.append(frame_segments(rect))
        colours.append(np.tile(FRAME, (8, 1)))
    return ChartGeometry(_stack(lines), _stack(colours, 3), _stack(tris), _stack(tri_colours, 3),
                         list(rects), t_range, v_range)


def strain_colours(s: np.ndarray) -> np.ndarray:
    """(n, 3) RGB of the strain colour map at ``s`` ((n,), 0 coolest, 1 hottest, clamped):
    linear between :data:`STRAIN_STOPS`, as the drawer colours the cloth."""
    u = np.clip(np.asarray(s, float), 0.0, 1.0) * (len(STRAIN_STOPS) - 1)
    k = np.minimum(np.floor(u).astype(int), len(STRAIN_STOPS) - 2)
    stops = np.asarray(STRAIN_STOPS)
    f = (u - k)[:, None]
    return stops[k] + (stops[k + 1] - stops[k]) * f


def legend_bar(rect: Rect, bands: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """The strain colour bar in ``rect``, coolest at the bottom: ``bands`` quads as triangle
    vertices (6 bands, 2) and their colours (each band the map at its middle)."""
    mids = (np.arange(bands) + 0.5) / bands
    verts = []
    for k in range(bands):
        y0 = rect.y0 + rect.height * k / bands
        y1 = rect.y0 + rect.height * (k + 1) / bands
        verts.append(quad(Rect(rect.x0, y0, rect.x1, y1)))
    return np.concatenate(verts), np.repeat(strain_colours(mids), 6, axis=0)


def _stack(parts, dim: int = 2) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros((0, dim))


def _px(u: float, v: float, size: tuple[int, int]) -> tuple[float, float]:
    return u * size[0], (1.0 - v) * size[1]


def chart_labels(geometry: ChartGeometry, names: Sequence[str], size: tuple[int, int]) -> list[Label]:
    """Text for recorded frames of ``size`` (width, height) pixels: the energy range (J) at the
    top and bottom left of each chart, and above the first chart the curves' names in their
    colours."""
    labels = []
    hi, lo = geometry.v_range[1], geometry.v_range[0]
    for rect in geometry.rects:
        x, y = _px(rect.x0, rect.y1, size)
        labels.append(Label(f"{hi:.3g} J", x + 3, y + 2, anchor="lt"))
        x, y = _px(rect.x0, rect.y0, size)
        labels.append(Label(f"{lo:.3g} J", x + 3, y - 2, anchor="lb"))
    if geometry.rects:
        rect = geometry.rects[0]
        x, y = _px(rect.x0, rect.y1, size)
        step = 0.0
        for name in names:
            colour = tuple(int(round(255 * c)) for c in CURVE_COLOURS[name])
            labels.append(Label(name, x + step, y - 4, colour, anchor="lb"))
            step += (len(name) + 2) * 0.6 * max(11, round(size[1] / 30))
    return labels


def legend_labels(rect: Rect, scale: float, size: tuple[int, int]) -> list[Label]:
    """Text for the strain colour bar in ``rect``: 0 % at its bottom, ``scale`` (a strain,
    (length - rest) / rest) as a percentage at its top, and its title above."""
    x, y_top = _px(0.5 * (rect.x0 + rect.x1), rect.y1, size)
    _, y_bottom = _px(rect.x0, rect.y0, size)
    line = max(11, round(size[1] / 30)) * 1.5
    return [Label("strain", x, y_top - 0.2 * line - line, anchor="mb"),
            Label(f"{100 * scale:.3g} %", x, y_top - 0.2 * line, anchor="mb"),
            Label("0 %", x, y_bottom + 0.2 * line, anchor="mt")]
