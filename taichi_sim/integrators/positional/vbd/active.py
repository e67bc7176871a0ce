"""The serial sweeps' active set: vertices whose block nothing has changed are not solved again.

A vertex's Newton step reads its own displacement and those of the vertices it shares a term
with: its springs' and a membrane's element neighbours (the pairs the colouring separates) and
the other vertices of its contact pairs. When a vertex's last step moved it by at most
``skip_move`` metres and none of those moved by more since, its next step would move it by
about as little again, so the sweeps pass it by. A vertex that moves more than ``skip_move``
marks itself and its neighbours to be solved in their next turn (those later in the same sweep
see the move at once, Gauss-Seidel's order). Every ``FULL_SWEEP_EVERY``-th sweep of a piece
(its first, and the first after a detection, included) solves every vertex: a vertex whose
steps are each below ``skip_move`` but all the same way (the slow, smooth part of the error
Gauss-Seidel is slow on) would otherwise stop short, and many sweeps stalled 0.8 mm from their
fixed point in a 16 x 16 pile (tests/test_error_estimate_contact.py); with the full sweeps
they reach it. A settled pile then costs the sweeps a fraction of what 20 full sweeps did
(docs/lab/vbd.md, "The fold, cheaper").

Used where the solve holds self-contact (the piles it is for; a cloth without contact sweeps
as before) on a closed scene (a moving object, a scripted pin or wind changes a vertex's block
with no cloth vertex moving: a kicking leg reached 0.38 mm into a skirt's faces past vertices
passed by), where the sweeps run as one serial task (a mark from a same-coloured contact
partner could race with the vertex's own clearing in a parallel loop), without Chebyshev's
over-relaxation or augmented springs (they move or re-weigh every vertex after each sweep),
and where every other force term reads its own particle only (wind reads a triangle's).
"""

import numpy as np
import taichi as ti

from .... import field_io

# Every this many sweeps (the first of a piece's, or of those after a detection, included) every
# vertex is solved: the vertices passed by still converge (module docstring).
FULL_SWEEP_EVERY = 8
# m: the least threshold a run's tolerance lowers skip_move to (every vertex that moves at all
# then marks itself: the sweeps solve nearly every vertex)
SKIP_MOVE_FLOOR = 1e-7


@ti.data_oriented
class ActiveSet:
    """Which vertices the serial sweeps still solve (module docstring).

    Args:
        particle_count: n.
        ends: (P, 2) the vertex pairs that share a spring, a triangle or a bending stencil
            (the pairs the colouring separates).
        skip_move: the move (m, > 0) below which a vertex does not mark itself or its
            neighbours (kept in :attr:`threshold`, a 0-d field, so that it may change).
    """

    def __init__(self, particle_count: int, ends: np.ndarray, skip_move: float):
        n = particle_count
        ends = np.asarray(ends, np.int64).reshape(-1, 2)
        both = np.concatenate([ends, ends[:, ::-1]])
        both = both[np.argsort(both[:, 0], kind="stable")]
        offsets = np.searchsorted(both[:, 0], np.arange(n + 1))
        # a field, not a constant compiled in: a run's tolerance lowers it (VBD.work_options)
        self.threshold = ti.field(ti.f64, shape=())
        self.offsets = ti.field(ti.i32, shape=n + 1)
        self.neighbours = ti.field(ti.i32, shape=max(1, len(both)))
        self.stale = ti.field(ti.i32, shape=max(1, n))  # 1: to be solved at its next turn
        self.solves = ti.field(ti.i64, shape=())  # vertex steps taken since construction
        field_io.write((self.offsets, offsets), (self.neighbours, both[:, 1] if len(both) else np.zeros(1)),
                       (self.threshold, float(skip_move)))

    @ti.func
    def all_stale(self, n):
        """Mark every vertex to be solved (every FULL_SWEEP_EVERY-th sweep); a loop inside the
        serial task."""
        for i in range(n):
            self.stale[i] = 1

    @ti.func
    def take(self, i) -> bool:
        """Whether vertex i is to be solved now; clears its mark."""
        out = self.stale[i] != 0
        self.stale[i] = 0
        return out

    @ti.func
    def moved(self, i, distance, contact: ti.template(), pairs: ti.template()):
        """After vertex i's step of ``distance`` metres: above ``skip_move``, mark it, its
        element neighbours and, where ``pairs`` (a compile-time bool), its contact pairs'
        vertices (``contact``: the :class:`~.contact.SolveContact`, self-contact in the solve)."""
        self.solves[None] += 1
        if distance > self.threshold[None]:
            self.stale[i] = 1
            for e in range(self.offsets[i], self.offsets[i + 1]):
                self.stale[self.neighbours[e]] = 1
            if ti.static(pairs):
                for s in range(ti.min(contact.vertex_pair_count[i], contact.per_vertex)):
                    ids = contact.pair_ids[contact.vertex_pairs[i, s]]
                    for k in ti.static(range(4)):
                        self.stale[ids[k]] = 1


def active_set(particle_count: int, ends: np.ndarray, skip_move: float, every_sweep_moves: bool,
               others: list) -> ActiveSet | None:
    """The :class:`ActiveSet` of a solve, or None where it may not be used: ``skip_move`` 0,
    ``every_sweep_moves`` (Chebyshev's over-relaxation or augmented springs move or re-weigh
    every vertex after each sweep), or one of the ``others`` force terms reads particles other
    than the one it pushes (``reads_other_particles``: wind reads a triangle's corners)."""
    if skip_move <= 0 or every_sweep_moves or any(term.reads_other_particles for term in others):
        return None
    return ActiveSet(particle_count, ends, skip_move)
