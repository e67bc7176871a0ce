"""The uniform grid through which the mesh collider finds its triangles (and vbd's solve the
mesh's sharp features: integrators/positional/vbd/mesh_faces.py), listed with numpy once per
frame segment. Its geometry (origin, cell, dims) is fixed for the run, since the kernels take
it as compile-time constants (:func:`cells`, :func:`cell_id`); its lists are refilled when a
frame sequence moves to its next segment.
"""
from dataclasses import dataclass

import numpy as np
import taichi as ti

# The grid's most cells: its cells are the mesh's median edge, or larger to stay below this.
MAX_CELLS = 32**3


@dataclass(frozen=True)
class TriangleGrid:
    """A uniform grid: ``origin`` (3,) m, cubic ``cell`` (m), ``dims`` cells along x, y, z."""

    origin: tuple[float, float, float]
    cell: float
    dims: tuple[int, int, int]

    @classmethod
    def covering(cls, frames: np.ndarray, triangles: np.ndarray, margin: float,
                 cell: float | None = None) -> "TriangleGrid":
        """The grid over every vertex of ``frames`` (F, V, 3) m grown by ``margin`` (m), its
        cells ``cell`` (m) or, without it, about the first frame's median edge of ``triangles``
        ((T, 3) ids), larger where more than ``MAX_CELLS`` would be needed."""
        lo = frames.min(axis=(0, 1)) - margin
        extent = frames.max(axis=(0, 1)) + margin - lo
        if cell is None:
            corners = frames[0][triangles]
            cell = float(np.median(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)))
        cell = max(cell, float(np.prod(extent) / MAX_CELLS) ** (1 / 3), 1e-6)
        dims = np.maximum(1, np.ceil(extent / cell).astype(np.int64))
        while np.prod(dims) > MAX_CELLS:  # a flat mesh: the volume rule above allows too many
            cell *= 1.25
            dims = np.maximum(1, np.ceil(extent / cell).astype(np.int64))
        return cls(tuple(float(c) for c in lo), float(cell), tuple(int(d) for d in dims))

    @property
    def cell_count(self) -> int:
        return int(np.prod(self.dims))

    def _spans(self, lo: np.ndarray, hi: np.ndarray):
        """Each box's first cell (T, 3) and its cell counts along each axis (T, 3)."""
        dims = np.asarray(self.dims)
        origin = np.asarray(self.origin)
        first = np.clip(np.floor((lo - origin) / self.cell).astype(np.int64), 0, dims - 1)
        last = np.clip(np.floor((hi - origin) / self.cell).astype(np.int64), 0, dims - 1)
        return first, last - first + 1

    def entries(self, lo: np.ndarray, hi: np.ndarray) -> int:
        """How many (cell, triangle) entries :meth:`lists` makes for these boxes."""
        return int(self._spans(lo, hi)[1].prod(axis=1).sum())

    def lists(self, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(cell_start (cells + 1,), cell_triangles) in CSR form: triangle k in every cell its
        box [lo[k], hi[k]] (m, each (T, 3)) reaches."""
        first, span = self._spans(lo, hi)
        counts = span.prod(axis=1)
        owner = np.repeat(np.arange(len(lo)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        sy, sz = span[owner, 1], span[owner, 2]
        ix = first[owner, 0] + local // (sy * sz)
        iy = first[owner, 1] + (local // sz) % sy
        iz = first[owner, 2] + local % sz
        cells = (ix * self.dims[1] + iy) * self.dims[2] + iz
        order = np.argsort(cells, kind="stable")
        start = np.zeros(self.cell_count + 1, np.int64)
        np.cumsum(np.bincount(cells, minlength=self.cell_count), out=start[1:])
        return start, owner[order]


@ti.func
def cells(grid: ti.template(), lo, hi):
    """The cell range (first, last, each an int vector) of ``grid`` (a :class:`TriangleGrid`)
    that the box [lo, hi] (m, the grid's frame) reaches; first > last on some axis when it lies
    outside the grid."""
    origin = ti.Vector(grid.origin)
    dims = ti.Vector(grid.dims)
    first = ti.cast(ti.floor((lo - origin) / grid.cell), ti.i32)
    last = ti.cast(ti.floor((hi - origin) / grid.cell), ti.i32)
    return ti.max(first, 0), ti.min(last, dims - 1)


@ti.func
def cell_id(grid: ti.template(), first, span, k):
    """The index in ``grid`` of the k-th cell of the block of ``span`` cells from ``first``."""
    ix = first[0] + k // (span[1] * span[2])
    iy = first[1] + (k // span[2]) % span[1]
    iz = first[2] + k % span[2]
    return (ix * grid.dims[1] + iy) * grid.dims[2] + iz
