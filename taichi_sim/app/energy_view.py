"""The energy plots under the panels and the strain legend, for the launcher and ``record``.

Composes :mod:`taichi_sim.app.energy` (the samples each :class:`~taichi_sim.app.runner.Runner`
keeps) with :mod:`taichi_sim.render.chart` (where things go) and
:mod:`taichi_sim.render.chart_canvas` (GGUI's canvas). Per frame it costs copying the ring
buffers into two small fields; nothing is read from the simulation.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..render.chart import (
    CURVE_COLOURS,
    ChartGeometry,
    Rect,
    chart_labels,
    chart_rects,
    energy_charts,
    legend_bar,
    legend_labels,
)
from ..render.overlay import Label
from .energy import CAPACITY, COMPONENTS, curves_of

MAX_PANELS = 3
LEGEND_BANDS = 32


class EnergyView:
    """What to draw over the scenes: an energy chart per panel inside ``area`` (each under its
    panel), and the strain colour bar in ``legend`` when the cloth is coloured by strain.

    Args:
        area: where the charts go (normalised canvas coordinates, y up).
        legend: where the strain colour bar goes.
    """

    def __init__(self, area: Rect, legend: Rect):
        self.area = area
        self.legend = legend
        self.geometry: ChartGeometry | None = None
        self.names: tuple[str, ...] = ()
        self.strain_scale: float | None = None
        self._panels: list = []
        self._canvas = None  # ChartCanvas, allocated at the first draw (needs Taichi)

    def update(self, runners: Sequence, centres: Sequence[float], *, energy: bool = True,
               strain_scale: float | None = None) -> None:
        """Lay out this frame: ``runners`` (one per panel) and each panel's horizontal centre on
        the canvas (``centres``, u in [0, 1]); ``energy``: draw the charts (only for scenes with
        an energy); ``strain_scale``: the strain drawn hottest, or None for no legend."""
        names = curves_of(runners[0].scene) if energy and runners else ()
        self.names = names
        self.geometry = None
        if names:
            panels = []
            for r in runners:
                data = r.energy_trace.array()
                panels.append((data[:, 0], {n: data[:, 1 + COMPONENTS.index(n)] for n in names}))
            self._panels = panels
            rects = energy_rects(self.area, centres)
            self.geometry = energy_charts(panels, rects)
        self.strain_scale = strain_scale

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(line vertices, their colours, triangle vertices, their colours) of this frame."""
        lines, line_rgb = np.zeros((0, 2)), np.zeros((0, 3))
        tris, tri_rgb = np.zeros((0, 2)), np.zeros((0, 3))
        if self.geometry is not None:
            g = self.geometry
            lines, line_rgb, tris, tri_rgb = g.lines, g.line_colours, g.triangles, g.triangle_colours
        if self.strain_scale is not None:
            bar, bar_rgb = legend_bar(self.legend, LEGEND_BANDS)
            tris, tri_rgb = np.concatenate([tris, bar]), np.concatenate([tri_rgb, bar_rgb])
        return lines, line_rgb, tris, tri_rgb

    def draw(self, canvas) -> None:
        """Draw this frame's charts and legend on ``canvas`` (a GGUI canvas)."""
        lines, line_rgb, tris, tri_rgb = self.arrays()
        if not len(lines) and not len(tris):
            return
        if self._canvas is None:
            from ..render.chart_canvas import ChartCanvas

            per_panel = 2 * (len(COMPONENTS) * (CAPACITY - 1) + 1 + 4)  # curves, zero line, frame
            self._canvas = ChartCanvas(MAX_PANELS * per_panel, MAX_PANELS * 6 + 6 * LEGEND_BANDS)
        self._canvas.draw(canvas, lines, line_rgb, tris, tri_rgb)

    def hud_lines(self) -> list[tuple[str, tuple | None]]:
        """(text, RGB or None) lines for the launcher's HUD (its ImGui text is what labels the
        charts on screen): the axes, each curve's name in its colour with each panel's newest
        value, and the strain legend's range."""
        out: list[tuple[str, tuple | None]] = []
        g = self.geometry
        if g is not None:
            out.append((f"energy plot: {g.v_range[0]:.3g} to {g.v_range[1]:.3g} J, "
                        f"t = {g.t_range[0]:.3g} to {g.t_range[1]:.3g} s", None))
            for name in self.names:
                values = "   ".join(f"{v:.4g}" for v in self._newest(name))
                out.append((f"  {name}: {values} J", CURVE_COLOURS[name]))
        if self.strain_scale is not None:
            out.append((f"strain colours: 0 % (blue) to {100 * self.strain_scale:.3g} % (red) "
                        "of rest length", None))
        return out

    def _newest(self, name: str) -> list[float]:
        return [float(values[name][-1]) for _, values in self._panels if len(values[name])]

    def labels(self, size: tuple[int, int]) -> list[Label]:
        """Text for a recorded frame of ``size`` (width, height) pixels."""
        out = []
        if self.geometry is not None:
            out += chart_labels(self.geometry, self.names, size)
        if self.strain_scale is not None:
            out += legend_labels(self.legend, self.strain_scale, size)
        return out


def energy_rects(area: Rect, centres: Sequence[float]) -> list[Rect]:
    """One chart per panel in ``area``: under each panel side by side; for a single panel, half
    of ``area``'s width in its middle."""
    if len(centres) <= 1:
        return chart_rects([0.5 * (area.x0 + area.x1)], area, fill=0.5)
    return chart_rects(centres, area)


def panel_centres(renderer) -> list[float]:
    """Each panel's horizontal centre on the canvas (u in [0, 1]), as the camera sees it."""
    uv, _ = renderer.camera.project(np.array(renderer.label_points()))
    return [float(u) for u in uv[:, 0]]
