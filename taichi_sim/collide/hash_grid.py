"""A spatial hash of primitives' swept boxes (triangles or edges), rebuilt in kernels each stage."""
import taichi as ti

from .. import field_io, runtime

MAX_CELLS_PER_AXIS = 4  # a box spanning more cells is clipped and counted as overflow


@ti.func
def cell_order(a, b):
    """-1, 0 or 1 as cell a comes before, is, or comes after cell b (by x, then y, then z): a
    query over home cells that takes a pair only from the primitive whose home comes first
    finds each pair once and skips the cells before its own home."""
    order = 0
    for k in ti.static(range(3)):
        if order == 0:
            order = ti.select(a[k] > b[k], 1, ti.select(a[k] < b[k], -1, 0))
    return order


@ti.data_oriented
class PrimitiveHash:
    """Primitives of ``corners`` vertices (3: triangles, 2: edges) bucketed by the cells their
    boxes overlap (a counting sort, no limit per bucket).

    A primitive's box covers its corners at the start and the end of a step, grown by ``margin``
    (m); it is kept per primitive (``lo``, ``hi``, ``cell_lo``, ``cell_hi``) for the queries.
    Cells are cubes of side ``cell`` (m), hashed into ``buckets`` (a power of two) lists sharing
    one array of ``entries_per_primitive`` x count entries. A box clipped to
    :data:`MAX_CELLS_PER_AXIS` cells per axis, or entries past the array's end, add to
    ``overflow`` (:meth:`overflowed`): pairs there can be missed, and the stage reports it.

    With ``home_cell_only`` a primitive is bucketed once, in the cell of its box's lower
    corner (:meth:`is_home`): with cells at least as wide as the longest box, every box that
    overlaps a query box [lo, hi] has its home in the cells from ``cell_of(lo) - 1`` to
    ``cell_of(hi)`` (:meth:`home_range`), so a box-against-box query visits each candidate once
    and reads each cell's own primitives only (not every box reaching into it). Each entry then
    carries its primitive's home cell and box (``entry_home``, ``entry_lo``, ``entry_hi``), so a
    query reads a bucket in sequence and looks up only the candidates whose boxes overlap.
    """

    def __init__(self, count: int, corners: int, cell: float, margin: float, *,
                 entries_per_primitive: int = 16, home_cell_only: bool = False):
        real = runtime.real()
        self.home_cell_only = bool(home_cell_only)
        self.n, self.corners = count, corners
        self.serial = runtime.serial_loops(count)  # for loops whose order cannot change a bit
        self.buckets = 1 << max(10, (4 * count - 1).bit_length())
        self.capacity = max(1, entries_per_primitive * count)
        self.cell = ti.field(real, shape=())
        self.margin = ti.field(real, shape=())
        field_io.write((self.cell, float(cell)), (self.margin, float(margin)))  # one kernel, not two
        self.lo = ti.Vector.field(3, real, shape=max(count, 1))
        self.hi = ti.Vector.field(3, real, shape=max(count, 1))
        self.cell_lo = ti.Vector.field(3, ti.i32, shape=max(count, 1))
        self.cell_hi = ti.Vector.field(3, ti.i32, shape=max(count, 1))
        self.count = ti.field(ti.i32, shape=self.buckets)
        self.start = ti.field(ti.i32, shape=self.buckets + 1)  # bucket b: items[start[b]:start[b+1]]
        self.fill = ti.field(ti.i32, shape=self.buckets)
        self.items = ti.field(ti.i32, shape=self.capacity)
        self.overflow = ti.field(ti.i32, shape=())
        self.extent = ti.field(real, shape=())
        if self.home_cell_only:
            self.entry_home = ti.Vector.field(3, ti.i32, shape=self.capacity)
            self.entry_lo = ti.Vector.field(3, real, shape=self.capacity)
            self.entry_hi = ti.Vector.field(3, real, shape=self.capacity)

    @ti.func
    def cell_of(self, p):
        return ti.floor(p / self.cell[None]).cast(ti.i32)

    @ti.func
    def bucket(self, c):
        h = (c[0] * 73856093) ^ (c[1] * 19349663) ^ (c[2] * 83492791)
        return h & (self.buckets - 1)

    @ti.func
    def box_cells(self, lo, hi):
        """The cell range (inclusive) of box [lo, hi], clipped to MAX_CELLS_PER_AXIS per axis, and
        whether it was clipped."""
        c_lo = self.cell_of(lo)
        c_hi = self.cell_of(hi)
        clipped = 0
        for k in ti.static(range(3)):
            if c_hi[k] - c_lo[k] >= MAX_CELLS_PER_AXIS:
                c_hi[k] = c_lo[k] + MAX_CELLS_PER_AXIS - 1
                clipped = 1
        return c_lo, c_hi, clipped

    @ti.func
    def entries(self, b):
        """The range of bucket b's entries in ``items`` (clipped to the array)."""
        return self.start[b], ti.min(self.start[b + 1], self.capacity)

    @ti.func
    def first_shared_cell(self, cell, c_lo, c_hi, p):
        """Whether ``cell`` is the first cell that query range [c_lo, c_hi] shares with primitive
        p's range: so that each pair is handled once, however many cells they share."""
        first = ti.max(c_lo, self.cell_lo[p])
        last = ti.min(c_hi, self.cell_hi[p])
        return all(cell == first) and all(first <= last)

    @ti.func
    def home_range(self, p):
        """With ``home_cell_only``: the cells (inclusive) holding the home of every box that
        can overlap primitive p's (cells at least as wide as the longest box)."""
        return self.cell_lo[p] - 1, self.cell_hi[p]

    @ti.func
    def is_home(self, cell, e):
        """With ``home_cell_only``: whether ``cell`` is the home of entry e's primitive (an
        entry in a bucket that other cells hash to as well is skipped there)."""
        return all(cell == self.entry_home[e])

    @ti.func
    def entry_overlaps(self, e, lo, hi):
        """With ``home_cell_only``: whether entry e's box overlaps the box [lo, hi]."""
        return all(self.entry_lo[e] <= hi) and all(lo <= self.entry_hi[e])

    @ti.func
    def _home_or_box(self, p):
        """The cells a primitive is bucketed in: its home alone, or every cell of its box."""
        c_lo, c_hi = self.cell_lo[p], self.cell_hi[p]
        if ti.static(self.home_cell_only):
            c_hi = c_lo
        return c_lo, c_hi

    @ti.func
    def swept_box(self, x0, x1, ids):
        """The box of a primitive's corners ``ids`` at positions x0 and x1, grown by the margin."""
        lo = ti.min(x0[ids[0]], x1[ids[0]])
        hi = ti.max(x0[ids[0]], x1[ids[0]])
        for k in ti.static(range(1, self.corners)):
            lo = ti.min(lo, ti.min(x0[ids[k]], x1[ids[k]]))
            hi = ti.max(hi, ti.max(x0[ids[k]], x1[ids[k]]))
        return lo - self.margin[None], hi + self.margin[None]

    @ti.kernel
    def longest_box(self, x0: ti.template(), x1: ti.template(), prims: ti.template(),
                    alive: ti.template()) -> ti.f64:
        """The longest side (m) of any live primitive's swept box, as :meth:`build` would make it."""
        self.extent[None] = 0.0
        ti.loop_config(serialize=self.serial)  # a maximum: the same in any order
        for p in range(self.n):
            if alive[p]:
                lo, hi = self.swept_box(x0, x1, prims[p])
                ti.atomic_max(self.extent[None], (hi - lo).max())
        return self.extent[None]

    @ti.kernel
    def build(self, x0: ti.template(), x1: ti.template(), prims: ti.template(), alive: ti.template()):
        """Bucket every primitive ``prims[p]`` (a vector of vertex ids) with ``alive[p]`` != 0 by
        its swept box from positions x0 to x1."""
        for b in self.count:
            self.count[b] = 0
        self.overflow[None] = 0
        for p in range(self.n):
            lo, hi = self.swept_box(x0, x1, prims[p])
            self.lo[p], self.hi[p] = lo, hi
            c_lo, c_hi, clipped = self.box_cells(lo, hi)
            self.cell_lo[p], self.cell_hi[p] = c_lo, c_hi
            if alive[p]:
                if clipped:
                    ti.atomic_add(self.overflow[None], 1)
                c_lo, c_hi = self._home_or_box(p)
                for i, j, k in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
                    ti.atomic_add(self.count[self.bucket(ti.Vector([i, j, k]))], 1)
        ti.loop_config(serialize=True)
        for b in range(self.buckets):  # exclusive prefix sum: a few thousand additions
            if b == 0:
                self.start[0] = 0
            self.start[b + 1] = self.start[b] + self.count[b]
            self.fill[b] = self.start[b]
        for p in range(self.n):
            if alive[p]:
                c_lo, c_hi = self._home_or_box(p)
                for i, j, k in ti.ndrange((c_lo[0], c_hi[0] + 1), (c_lo[1], c_hi[1] + 1), (c_lo[2], c_hi[2] + 1)):
                    slot = ti.atomic_add(self.fill[self.bucket(ti.Vector([i, j, k]))], 1)
                    if slot < self.capacity:
                        self.items[slot] = p
                        if ti.static(self.home_cell_only):
                            self.entry_home[slot] = c_lo
                            self.entry_lo[slot], self.entry_hi[slot] = self.lo[p], self.hi[p]
                    else:
                        ti.atomic_add(self.overflow[None], 1)

    def overflowed(self) -> int:
        return int(self.overflow[None])
