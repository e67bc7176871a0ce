"""The fast path for springs on a regular grid: the same springs, summed through a stencil.

A cloth's springs join each grid point (i, j) to neighbours at a few fixed offsets. Stored per
(offset, i, j) slot instead of per list entry, a spring's ends and parameters are found by
arithmetic, not by reading index arrays: one pass over the grid computes every spring's force
once, each point then adds the slots it owns and subtracts those pointing at it. Everything
else (energy, strain, Jacobians, the implicit methods' per-particle force) is inherited from
the list term, whose data the grid term keeps too.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from ... import runtime
from .term import Springs

# The forward half of the 12-neighbour stencil (structural, shear, flex): every spring of a
# cloth grid is one of these offsets from one of its ends.
STENCIL = ((1, 0), (0, 1), (1, 1), (1, -1), (2, 0), (0, 2))


@dataclass(frozen=True)
class GridLayout:
    """Where each spring of a list sits in an nx x ny grid whose point (i, j) is particle
    ``first + i * ny + j``.

    Attributes:
        first, nx, ny: the grid's first particle id and its size.
        offsets: the stencil offsets that hold springs (a sub-tuple of :data:`STENCIL`).
        slot: (S,) index into ``offsets`` of each spring.
        i, j: (S,) grid point of the end the offset starts from.
    """

    first: int
    nx: int
    ny: int
    offsets: tuple[tuple[int, int], ...]
    slot: np.ndarray
    i: np.ndarray
    j: np.ndarray


def grid_layout(ends: np.ndarray, first: int, nx: int, ny: int) -> GridLayout | None:
    """The grid layout of springs ``ends`` ((S, 2) particle ids), or None when they are not a
    stencil grid: an end outside the grid, an offset outside :data:`STENCIL` or two springs in
    one slot. Slots without a spring (an offset only some points use) hold zero parameters and
    so exert no force."""
    ends = np.asarray(ends, np.int64).reshape(-1, 2) - first
    if len(ends) == 0 or ends.min() < 0 or ends.max() >= nx * ny:
        return None
    pi, pj = np.divmod(ends[:, 0], ny)
    qi, qj = np.divmod(ends[:, 1], ny)
    di, dj = qi - pi, qj - pj
    code = np.full(len(ends), -1)
    forward = np.zeros(len(ends), bool)
    for o, (oi, oj) in enumerate(STENCIL):  # the stencil and its negation share no offset
        ahead = (di == oi) & (dj == oj)
        forward |= ahead
        code[ahead | ((di == -oi) & (dj == -oj))] = o
    if np.any(code < 0):
        return None
    start_i = np.where(forward, pi, qi)
    start_j = np.where(forward, pj, qj)
    used = sorted(set(code.tolist()))
    slot = np.searchsorted(used, code)
    offsets = tuple(STENCIL[o] for o in used)
    keys = (slot * nx + start_i) * ny + start_j
    if len(np.unique(keys)) != len(keys):
        return None
    return GridLayout(first, nx, ny, offsets, slot.astype(np.int64), start_i.astype(np.int64),
                      start_j.astype(np.int64))


@ti.data_oriented
class GridSprings(Springs):
    """:class:`Springs` whose whole-system force runs through a grid stencil (see the module
    docstring); built by the scene builder for cloth grids without tearing, where it gives the
    list term's forces up to the order of summation.

    Args: those of :class:`Springs` (no ``tear_strain``), and ``layout``, from
    :func:`grid_layout` of the same ``ends``.
    """

    def __init__(self, particle_count, ends, rest_length, stiffness, damping, kind, *, layout: GridLayout):
        self.layout = layout
        shape = (len(layout.offsets), layout.nx, layout.ny)
        real = runtime.real()
        # (k, r, c) of the spring in each slot, zero where there is none
        self.slot_parameters = ti.Vector.field(3, real, shape=shape)
        # (k, r, c) of every spring of each offset, used instead while `uniform` is 1: when each
        # offset's slots all hold springs with the same values (a cloth, unless per-spring
        # values are set), reading 6 numbers instead of 3 per spring is 15-20 % faster.
        self.offset_parameters = ti.Vector.field(3, real, shape=len(layout.offsets))
        self.uniform = ti.field(ti.i32, shape=())
        # the force of each slot's spring on its starting point (i, j)
        self.slot_force = ti.Vector.field(3, real, shape=shape)
        super().__init__(particle_count, ends, rest_length, stiffness, damping, kind)

    def _allocate_force_buffer(self) -> None:
        pass  # the slots are the buffer

    def _upload_columns(self, rest_length, stiffness, damping, tear_strain) -> None:
        super()._upload_columns(rest_length, stiffness, damping, tear_strain)
        lay = self.layout
        table = np.zeros((len(lay.offsets), lay.nx, lay.ny, 3), runtime.np_real())
        columns = np.stack([np.broadcast_to(np.asarray(v, float), (self.spring_count,))
                            for v in (stiffness, rest_length, damping)], axis=1)
        table[lay.slot, lay.i, lay.j] = columns
        per_offset = np.zeros((len(lay.offsets), 3), runtime.np_real())
        uniform = True
        for o, (oi, oj) in enumerate(lay.offsets):
            mine = columns[lay.slot == o]
            full = len(mine) == (lay.nx - oi) * (lay.ny - abs(oj))  # no empty slot would get a spring
            # equal up to rounding: a flat grid's rest lengths differ in their last bits
            same = np.all(np.abs(mine - mine[0]) <= 4 * np.finfo(runtime.np_real()).eps * np.abs(mine[0]))
            uniform = uniform and full and bool(same)
            per_offset[o] = mine[0]
        # one kernel for all three: each from_numpy or field write would compile its own
        self._upload_grid(table, per_offset, int(uniform))

    @ti.kernel
    def _upload_grid(self, table: ti.types.ndarray(ndim=4), per_offset: ti.types.ndarray(ndim=2), uniform: ti.i32):
        for o, i, j in self.slot_parameters:
            self.slot_parameters[o, i, j] = ti.Vector([table[o, i, j, 0], table[o, i, j, 1], table[o, i, j, 2]])
        for o in self.offset_parameters:
            self.offset_parameters[o] = ti.Vector([per_offset[o, 0], per_offset[o, 1], per_offset[o, 2]])
        self.uniform[None] = uniform

    @ti.func
    def precompute(self, y):
        """Every slot's spring force at ``y`` (one pass over the grid points)."""
        first, nx, ny = ti.static(self.layout.first, self.layout.nx, self.layout.ny)
        ti.loop_config(serialize=self.serial_loops)
        for i, j in ti.ndrange(nx, ny):
            p = first + i * ny + j
            xp = y.x[p]
            vp = y.v[p]
            for o in ti.static(range(len(self.layout.offsets))):
                oi, oj = ti.static(self.layout.offsets[o])
                g = ti.Vector.zero(y.x.dtype, 3)
                if i + oi < nx and 0 <= j + oj < ny:
                    q = p + oi * ny + oj
                    c = self.offset_parameters[o]
                    if not self.uniform[None]:
                        c = self.slot_parameters[o, i, j]
                    g = self.pair_force(xp - y.x[q], vp - y.v[q], c[0], c[1], c[2])
                self.slot_force[o, i, j] = g

    @ti.func
    def precomputed_force(self, i, y, mass_i, t):
        """The springs' force on particle i (N): the slots starting at its grid point minus the
        slots ending there."""
        first, nx, ny = ti.static(self.layout.first, self.layout.nx, self.layout.ny)
        f = ti.Vector.zero(y.x.dtype, 3)
        p = i - first
        if 0 <= p < nx * ny:
            gi = p // ny
            gj = p - gi * ny
            for o in ti.static(range(len(self.layout.offsets))):
                oi, oj = ti.static(self.layout.offsets[o])
                f += self.slot_force[o, gi, gj]
                if gi >= oi and 0 <= gj - oj < ny:
                    f -= self.slot_force[o, gi - oi, gj - oj]
        return f
