"""vbd's kernels over one state, closures made once per state (a method kernel with a template
argument costs about twice the Python per launch: see ParticleSystem._launcher). Each calls the
kernel functions of :class:`~.solver.VBD`, which read its parts (springs, contact, cap) at
compile time."""
import taichi as ti

from .... import runtime
from ..chebyshev import chebyshev_weight
from .active import FULL_SWEEP_EVERY

# Below this many particles plus springs (times spare threads) the colour loops run on one
# thread and a whole substep is one kernel launch: a colour of a 64 x 64 cloth is ~450
# vertices, too few to pay a parallel loop's hand-off (see XPBD's SERIAL_SPRINGS, measured the
# same way); never on a GPU.
SERIAL_WORK = 2_000_000
# With self-contact in the solve a vertex's block also sums its contact pairs (several times a
# spring's work), so the colours pay a parallel loop from far fewer vertices: the break-even in
# particles (times spare threads). cloth-fold's first second on a 2-vCPU machine (two cores, no
# shared core), parallel against serial sweeps: 1.2 times slower at 64 x 64 (4096 particles),
# 1.5 times faster at 90 x 90 (8100), 2.0 times at 128 x 128 (docs/vbd.md).
SERIAL_CONTACT_PARTICLES = 6_000


def serial_sweeps(work: int, particles: int, self_contact: bool) -> bool:
    """Whether a substep's sweeps run as one serial task: a sweep's ``work`` (particles plus
    springs plus a membrane's work, :attr:`MembraneTerms.work <.membranes.MembraneTerms.work>`)
    below SERIAL_WORK and, with self-contact in the solve, ``particles`` below
    SERIAL_CONTACT_PARTICLES too; never on a GPU."""
    serial = runtime.serial_loops(work, SERIAL_WORK)
    if self_contact:
        return serial and runtime.serial_loops(particles, SERIAL_CONTACT_PARTICLES)
    return serial


def bind_kernels(vbd, y) -> dict:
    """The kernels of ``vbd`` (a :class:`~.solver.VBD`) over the state ``y``: a whole serial
    substep, and the parts the Python loops drive (begin, sweeps, a colour, end)."""

    # the active set where the solve holds self-contact on a closed scene (active.py)
    active = vbd.active if vbd.uses_active_set else None
    has_active = active is not None
    pairs = vbd.has_self_contact  # (its pairs couple vertices)

    @ti.func
    def serial_vertex(i, dt, t):
        """Vertex i's step in the serial sweeps, passed by where the active set has it settled."""
        if ti.static(not has_active):
            vbd._solve_vertex(i, dt, t)
        else:
            if active.take(i):
                active.moved(i, vbd._solve_vertex(i, dt, t), vbd.contact, pairs)

    @ti.kernel
    def substep(dt: float, t: float, use_acceleration: ti.i32, previous_dt: float, iterations: ti.i32) -> ti.i32:
        vbd._begin(y, dt, use_acceleration, previous_dt, t, 0)
        ti.loop_config(serialize=True)
        for _ in range(1):  # one serial task: every sweep, colour after colour
            omega = 1.0
            rho2 = vbd.chebyshev_rho ** 2
            for sweep in range(iterations):
                if ti.static(has_active):
                    if sweep % FULL_SWEEP_EVERY == 0:
                        active.all_stale(vbd.system.particle_count)
                for c in range(vbd.colour_count):
                    for q in range(vbd.colour_start[c], vbd.colour_start[c + 1]):
                        serial_vertex(vbd.order[q], dt, t)
                if ti.static(vbd.has_multipliers):
                    vbd.spring_terms.update_multipliers(vbd.point.x)
                if ti.static(vbd.chebyshev):
                    omega = chebyshev_weight(rho2, sweep, omega)
                    for i in range(vbd.system.particle_count):
                        vbd._accelerate(i, dt, omega, sweep, t)
        return vbd._finish(y, dt)

    @ti.kernel
    def begin(dt: float, use_acceleration: ti.i32, previous_dt: float, t: float, again: ti.i32):
        vbd._begin(y, dt, use_acceleration, previous_dt, t, again)

    @ti.kernel
    def sweeps(dt: float, t: float, first: ti.i32, count: ti.i32):
        ti.loop_config(serialize=True)
        for _ in range(1):  # one serial task: the sweeps first .. first + count - 1
            omega = 1.0
            rho2 = vbd.chebyshev_rho ** 2
            for sweep in range(first + count):
                if ti.static(vbd.chebyshev):
                    omega = chebyshev_weight(rho2, sweep, omega)
                if sweep >= first:
                    if ti.static(has_active):
                        if (sweep - first) % FULL_SWEEP_EVERY == 0:
                            active.all_stale(vbd.system.particle_count)
                    vbd._query_faces(t)
                    for c in range(vbd.colour_count):
                        for q in range(vbd.colour_start[c], vbd.colour_start[c + 1]):
                            serial_vertex(vbd.order[q], dt, t)
                    vbd._after_colours(dt, t, omega, sweep)

    # The parallel sweep (_sweep): all colours in one launch (unrolled: the vertex solve
    # compiled once per colour), or, where the solve meets objects and their geometry makes
    # it large, the query, one launch per colour and the tail (docs/vbd.md).
    @ti.kernel
    def sweep_unrolled(dt: float, t: float, omega: float, index: ti.i32):
        for c in ti.static(range(vbd.colour_count)):
            for q in range(vbd.starts[c], vbd.starts[c + 1]):
                vbd._solve_vertex(vbd.order[q], dt, t)
        vbd._after_colours(dt, t, omega, index)

    @ti.kernel
    def query(t: float):
        vbd._query_faces(t)

    @ti.kernel
    def colour(dt: float, t: float, c: ti.i32):
        for q in range(vbd.colour_start[c], vbd.colour_start[c + 1]):
            vbd._solve_vertex(vbd.order[q], dt, t)

    @ti.kernel
    def after_colours(dt: float, t: float, omega: float, index: ti.i32):
        vbd._after_colours(dt, t, omega, index)

    @ti.kernel
    def end(dt: float) -> ti.i32:
        return vbd._finish(y, dt)

    return {"substep": substep, "begin": begin, "sweeps": sweeps, "sweep_unrolled": sweep_unrolled,
            "query": query, "colour": colour, "after_colours": after_colours, "end": end}
