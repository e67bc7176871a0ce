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
from ...loops import anchor
from .term import Springs

# The forward half of the 12-neighbour stencil (structural, shear, flex): every spring of a
# cloth grid is one of these offsets from one of its ends.
STENCIL = ((1, 0), (0, 1), (1, 1), (1, -1), (2, 0), (0, 2))
# Zero rows and columns around the slot buffer, as far as the stencil reaches back (i - 2,
# j - 2 .. j + 1): a point's gather then reads every offset's incoming slot without a bounds test.
PAD_I, PAD_J = 2, 2

# Grid points from which an f64 grid's spring pass runs in parallel on a CPU, without the
# vectorising. A symplectic Euler step on the 2-vCPU development machine with the pass serial
# against parallel (benchmarks/bench_serial_loops.py --pass, 2026-11-25): in f32, 296 against
# 710 us at 128 x 128, 1.03 against 1.53 ms at 256 x 256 and 4.5 against 7.8 ms at 512 x 512,
# so f32 has no limit. In f64 a vector holds half as many springs and the pass moves twice the
# bytes: 427 against 747 us at 128 x 128, a toss-up at 256 x 256 (2.3 against 2.7 ms in that
# run, 2.2-2.5 against 1.7-2.2 ms in others) and 10.6 against 8.4 ms at 512 x 512. Measured
# again once the pass read the state directly (no copy): 650 against 750 us, 2.86 against
# 2.64 ms and 11.8 against 9.5 ms.
SERIAL_PASS_F64_POINTS = 40_000
SERIAL_PASS_F32_POINTS = 10**12


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
        # (k, r, c) of every spring of each offset, used instead while `uniform` is 1 (each
        # offset's slots all hold springs with the same values: a cloth, unless per-spring
        # values are set): the serial pass vectorises only with these, not with per-slot reads.
        self.offset_parameters = ti.Vector.field(3, real, shape=len(layout.offsets))
        self.offset_steps = ti.Vector.field(2, ti.i32, shape=len(layout.offsets))  # (oi, oj)
        self.uniform = ti.field(ti.i32, shape=())
        # the force of each slot's spring on its starting point (i, j), at [o, i + PAD_I, j + PAD_J];
        # slots without a spring are never written and stay zero
        self.slot_force = ti.Vector.field(3, real, shape=(shape[0], layout.nx + PAD_I, layout.ny + 2 * PAD_J))
        # On a CPU the spring pass runs on one thread: Taichi compiles a parallel loop's body as
        # a function called per iteration, where the same inner loops do not vectorise (see
        # SERIAL_PASS_F64_POINTS for the exception).
        limit = SERIAL_PASS_F32_POINTS if real == ti.f32 else SERIAL_PASS_F64_POINTS
        self.serial_pass = runtime.cpu_backend() and layout.nx * layout.ny < limit
        # the grid is every particle (a cloth scene): the gather needs no range test
        self.covers_all = layout.first == 0 and layout.nx * layout.ny == particle_count
        super().__init__(particle_count, ends, rest_length, stiffness, damping, kind)

    def _allocate_force_buffer(self) -> None:
        pass  # the slots are the buffer

    def anchored_fields(self) -> tuple:
        return (self.slot_force,)

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
        self._upload_grid(table, per_offset, np.asarray(lay.offsets, np.int32).reshape(-1, 2), int(uniform))

    @ti.kernel
    def _upload_grid(self, table: ti.types.ndarray(ndim=4), per_offset: ti.types.ndarray(ndim=2),
                     steps: ti.types.ndarray(dtype=ti.i32, ndim=2), uniform: ti.i32):
        for o, i, j in self.slot_parameters:
            self.slot_parameters[o, i, j] = ti.Vector([table[o, i, j, 0], table[o, i, j, 1], table[o, i, j, 2]])
        for o in self.offset_parameters:
            self.offset_parameters[o] = ti.Vector([per_offset[o, 0], per_offset[o, 1], per_offset[o, 2]])
            self.offset_steps[o] = ti.Vector([steps[o, 0], steps[o, 1]])
        self.uniform[None] = uniform

    @ti.func
    def precompute(self, y):
        """Every slot's spring force at ``y``. On a CPU (:attr:`serial_pass`): rows of the grid
        in the outer loop, and for each offset a branch-free inner loop over the points of the
        row that have that spring, which the compiler turns into SIMD code (the loop it
        replaced, one point and its six offsets per iteration with a bounds test each, did not
        vectorise and took 2-3 times as long). Each row first anchors the fields its loops use
        (:mod:`taichi_sim.loops`): without, the state's base address is re-read for every
        spring and the loops stay scalar (the pass used to copy the state next to the slots
        for the same end, which cost a tenth of a step). Elsewhere (a GPU): one thread per grid
        point."""
        first, nx, ny = ti.static(self.layout.first, self.layout.nx, self.layout.ny)
        if ti.static(self.serial_pass):
            ti.loop_config(serialize=True)
            for i in range(nx):
                for field in ti.static(self._row_fields(y)):
                    anchor(field)
                if self.uniform[None]:
                    for o in ti.static(range(len(self.layout.offsets))):
                        if i + ti.static(self.layout.offsets[o][0]) < nx:
                            self._offset_row(y, i, o)
                else:
                    self._row_per_slot(y, i)
        else:
            for i, j in ti.ndrange(nx, ny):
                p = first + i * ny + j
                for o in ti.static(range(len(self.layout.offsets))):
                    oi, oj = ti.static(self.layout.offsets[o])
                    if i + oi < nx and 0 <= j + oj < ny:
                        q = p + oi * ny + oj
                        c = self.offset_parameters[o]
                        if not self.uniform[None]:
                            c = self.slot_parameters[o, i, j]
                        dv = ti.Vector.zero(y.x.dtype, 3)
                        if ti.static(self.damped):
                            dv = y.v[p] - y.v[q]
                        self.slot_force[o, i + PAD_I, j + PAD_J] = self.pair_force(y.x[p] - y.x[q], dv,
                                                                                  c[0], c[1], c[2])

    def _row_fields(self, y) -> tuple:
        return (y.x, self.slot_force, self.offset_parameters, self.slot_parameters) + ((y.v,) if self.damped else ())

    @ti.func
    def _offset_row(self, y, i, o: ti.template()):
        """Row i's springs at offset o into their slots, with the offset's shared (k, r, c).
        It spells out the slot's store that :meth:`_row_per_slot` and the parallel pass also
        spell out: with the store in a shared function taking the offset and the two particle
        ids as arguments, this loop lost most of its vectorising (a symplectic step at 128 x 128
        took 436-607 us against 285)."""
        first, ny = ti.static(self.layout.first, self.layout.ny)
        oi, oj = ti.static(self.layout.offsets[o])
        c = self.offset_parameters[o]
        for j in range(ti.static(max(0, -oj)), ti.static(ny - max(0, oj))):
            p = first + i * ny + j
            q = p + oi * ny + oj
            dv = ti.Vector.zero(y.x.dtype, 3)
            if ti.static(self.damped):
                dv = y.v[p] - y.v[q]
            self.slot_force[o, i + PAD_I, j + PAD_J] = self.pair_force(y.x[p] - y.x[q], dv,
                                                                      c[0], c[1], c[2])

    @ti.func
    def _row_per_slot(self, y, i):
        """Row i's springs with each slot's own (k, r, c): one loop over the offsets at run
        time, which does not vectorise (neither did one per offset, which reading per-slot
        values stopped too) but keeps the kernel small."""
        first, nx, ny = ti.static(self.layout.first, self.layout.nx, self.layout.ny)
        for o in range(ti.static(len(self.layout.offsets))):
            oi, oj = self.offset_steps[o][0], self.offset_steps[o][1]
            if i + oi < nx:
                for j in range(ti.max(0, -oj), ny - ti.max(0, oj)):
                    p = first + i * ny + j
                    q = p + oi * ny + oj
                    c = self.slot_parameters[o, i, j]
                    dv = ti.Vector.zero(y.x.dtype, 3)
                    if ti.static(self.damped):
                        dv = y.v[p] - y.v[q]
                    self.slot_force[o, i + PAD_I, j + PAD_J] = self.pair_force(
                        y.x[p] - y.x[q], dv, c[0], c[1], c[2])

    @ti.func
    def precomputed_force(self, i, y, mass_i, t):
        """The springs' force on particle i (N): the slots starting at its grid point minus the
        slots ending there (the padding holds zeros where the grid has no spring)."""
        first, nx, ny = ti.static(self.layout.first, self.layout.nx, self.layout.ny)
        f = ti.Vector.zero(y.x.dtype, 3)
        p = i - first
        if ti.static(self.covers_all) or 0 <= p < nx * ny:
            gi = p // ny
            gj = p - gi * ny
            for o in ti.static(range(len(self.layout.offsets))):
                oi, oj = ti.static(self.layout.offsets[o])
                f += self.slot_force[o, gi + PAD_I, gj + PAD_J] - self.slot_force[o, gi + PAD_I - oi, gj + PAD_J - oj]
        return f

    @ti.func
    def energy_and_strain(self, y):
        """(the springs' energy (J), their largest strain |d|/r - 1 (0 if none)) at ``y``: the
        blow-up guard's reading, in row passes over each spring once (the list term's gather
        meets each spring from both ends) that read ``y`` and write nothing (a non-finite
        position gives a non-finite energy, which the guard catches too)."""
        nx, ny = ti.static(self.layout.nx, self.layout.ny)
        energy = ti.cast(0.0, y.x.dtype)
        worst = ti.cast(0.0, y.x.dtype)
        ti.loop_config(serialize=self.serial_pass)
        for i in range(nx):
            for o in range(ti.static(len(self.layout.offsets))):
                if i + self.offset_steps[o][0] < nx:
                    e, w = self._offset_row_energy(y, i, o)
                    energy += e
                    ti.atomic_max(worst, w)
        return energy, worst

    @ti.func
    def _offset_row_energy(self, y, i, o):
        """(energy (J), largest strain) of row i's springs at offset o. It reads each slot's
        own (k, r, c) whether or not they are uniform: one loop rather than two keeps the
        kernel small (Taichi lowers each kernel's Python anew in every process, cache or no
        cache), and the check runs once per hundred steps."""
        first, ny = ti.static(self.layout.first, self.layout.ny)
        oi, oj = self.offset_steps[o][0], self.offset_steps[o][1]
        energy = ti.cast(0.0, y.x.dtype)
        worst = ti.cast(0.0, y.x.dtype)
        for j in range(ti.max(0, -oj), ny - ti.max(0, oj)):
            p = first + i * ny + j
            c = self.slot_parameters[o, i, j]
            length = (y.x[p] - y.x[p + oi * ny + oj]).norm()
            energy += 0.5 * c[0] * (length - c[1]) * (length - c[1])
            # springs with k = 0 or r = 0 (an empty slot) have no strain
            worst = ti.max(worst, ti.select(c[0] > 0.0 and c[1] > 0.0, length / ti.max(c[1], 1e-30) - 1.0, 0.0))
        return energy, worst
