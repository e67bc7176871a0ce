"""Drawing :mod:`taichi_sim.render.chart` geometry on GGUI's canvas (2D, over the 3D scene).

GGUI's ``canvas.lines`` and ``canvas.triangles`` draw whole fields, with no vertex count: the
fields are allocated once, at the largest size asked for, and the unused tail is parked off the
canvas. One call each for lines and triangles per frame, whatever the number of charts.
"""
from __future__ import annotations

import numpy as np
import taichi as ti

from .chart import OFF

LINE_WIDTH = 0.0035  # normalised (GGUI's unit: a fraction of the window height)


class ChartCanvas:
    """Fields for up to ``lines`` segment ends and ``triangles`` triangle vertices.

    Args:
        lines: capacity in vertices (two per segment).
        triangles: capacity in vertices (three per triangle).
    """

    def __init__(self, lines: int, triangles: int):
        if lines < 2 or triangles < 3:
            raise ValueError(f"lines must be >= 2 and triangles >= 3, got {lines} and {triangles}")
        self.line_capacity = 2 * (int(lines) // 2)
        self.triangle_capacity = 3 * (int(triangles) // 3)
        self.line_verts = ti.Vector.field(2, ti.f32, self.line_capacity)
        self.line_colours = ti.Vector.field(3, ti.f32, self.line_capacity)
        self.tri_verts = ti.Vector.field(2, ti.f32, self.triangle_capacity)
        self.tri_colours = ti.Vector.field(3, ti.f32, self.triangle_capacity)

    def draw(self, canvas, lines: np.ndarray, line_colours: np.ndarray, triangles: np.ndarray,
             triangle_colours: np.ndarray) -> None:
        """Draw ``triangles`` ((k, 2), normalised, y up; k a multiple of 3) and then ``lines``
        ((m, 2) segment ends) with their per-vertex colours ((k, 3), (m, 3) RGB in [0, 1]) on
        ``canvas``. ValueError when either exceeds the capacity."""
        if len(lines) > self.line_capacity or len(triangles) > self.triangle_capacity:
            raise ValueError(f"chart geometry ({len(lines)} line and {len(triangles)} triangle vertices) "
                             f"exceeds the capacity ({self.line_capacity}, {self.triangle_capacity})")
        self._fill(self.tri_verts, self.tri_colours, triangles, triangle_colours)
        self._fill(self.line_verts, self.line_colours, lines, line_colours)
        canvas.triangles(self.tri_verts, per_vertex_color=self.tri_colours)
        canvas.lines(self.line_verts, LINE_WIDTH, per_vertex_color=self.line_colours)

    @staticmethod
    def _fill(verts, colours, points, rgb) -> None:
        n = verts.shape[0]
        v = np.full((n, 2), OFF, np.float32)
        c = np.zeros((n, 3), np.float32)
        v[:len(points)] = points
        c[:len(points)] = rgb
        verts.from_numpy(v)
        colours.from_numpy(c)
