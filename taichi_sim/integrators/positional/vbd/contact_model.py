"""vbd's contact terms as forces of its equation, for the convergence monitor: the same penalty
energies and friction the sweeps solve (:class:`~.contact.SolveContact`), taken at the
step's result (:class:`~taichi_sim.integrators.equation.SolveForces`).

The objects' terms (plane, spheres, capsules, boxes, the triangles against them) touch one
vertex each, so each vertex's 3x3 block is read from the solve's own kernels. A self-contact
pair couples its four vertices: its 12 x 12 block k w w^T (x) n n^T (plus friction's) is
assembled here from the pair's weights, so that two layers moving together along their normal
are not held back by it.
"""
import numpy as np
import scipy.sparse as sp
import taichi as ti

from ...equation import SolveForces, element_stiffness


@ti.kernel
def _object_terms(contact: ti.template(), x: ti.template(), mass: ti.template(), free: ti.template(),
                  dt: float, t: float, force: ti.types.ndarray(), block: ti.types.ndarray()):
    for i in range(x.shape[0]):
        f = ti.Vector.zero(x.dtype, 3)
        H = ti.Matrix.zero(x.dtype, 3, 3)
        if free[i]:
            f, H = contact.object_terms(i, x, mass[i], dt, t, f, H)
        for a in ti.static(range(3)):
            force[i, a] = f[a]
            for b in ti.static(range(3)):
                block[i, a, b] = H[a, b]


@ti.kernel
def _pairs(contact: ti.template(), x: ti.template(), count: ti.i32, ids: ti.types.ndarray(),
           weights: ti.types.ndarray(), gaps: ti.types.ndarray()):
    for s in range(count):
        pair = contact.pair_ids[s]
        gap, w = contact._pair_geometry(pair, contact.pair_kind[s], x)
        for k in ti.static(range(4)):
            ids[s, k] = pair[k]
            weights[s, k] = w[k]
        for a in ti.static(range(3)):
            gaps[s, a] = gap[a]


def solve_forces(contact, system, state, delta: np.ndarray, dt: float, t: float) -> SolveForces:
    """The contact forces of vbd's equation at ``state``'s positions (the step's result) for a
    piece of ``dt`` s ending at time ``t`` (s); ``delta`` (n, 3): the displacement since the
    piece's start (m), which friction's slip is measured from."""
    n = system.particle_count
    force = np.zeros((n, 3))
    stiffness = sp.csr_matrix((3 * n, 3 * n))
    if contact.has_objects:
        f = np.zeros((n, 3), np.float64)
        H = np.zeros((n, 3, 3), np.float64)
        _object_terms(contact, state.x, system.mass, system.free, dt, t, f, H)
        force += f
        stiffness = stiffness + element_stiffness(np.arange(n)[:, None], H[:, None, None], n)
    count = contact.pair_total()
    if count:
        ids = np.zeros((count, 4), np.int32)
        w = np.zeros((count, 4), np.float64)
        gap = np.zeros((count, 3), np.float64)
        _pairs(contact, state.x, count, ids, w, gap)
        # in the pairs' own order, not the detection's threads' (np.add.at sums in array order)
        kinds = contact.pair_kind.to_numpy()[:count]
        order = np.lexsort((ids[:, 3], ids[:, 2], ids[:, 1], ids[:, 0], kinds))
        pair_force, pair_stiffness = _pairs_terms(ids[order].astype(np.int64), w[order], gap[order], delta,
                                                  contact, dt, n)
        force += pair_force
        stiffness = stiffness + pair_stiffness
    return SolveForces(force, stiffness)


def _pairs_terms(ids, w, gap, delta, contact, dt, n):
    """(forces (n, 3), stiffness): the self-contact pairs' penalty 1/2 k (r - d)^2 and friction,
    as the solve's ``_push`` takes them for each vertex, with the couplings between a pair's
    vertices."""
    force = np.zeros((n, 3))
    d = np.linalg.norm(gap, axis=1)
    keep = (d < contact.radius) & (d > 0)
    ids, w, gap, d = ids[keep], w[keep], gap[keep], d[keep]
    if not len(d):
        return force, sp.csr_matrix((3 * n, 3 * n))
    penalty_dt = float(contact.penalty_dt[None])
    k = contact.stiffness * contact.mean_mass / penalty_dt**2
    normal = gap / d[:, None]
    lam = k * (contact.radius - d)
    nn = normal[:, :, None] * normal[:, None, :]
    pair_force = lam[:, None] * normal  # per unit weight
    pair_block = k * nn
    mu = contact.self_friction
    if mu > 0:
        slip = np.einsum("sk,ska->sa", w, delta[ids])
        u = slip - np.einsum("sa,sa->s", slip, normal)[:, None] * normal
        y = np.linalg.norm(u, axis=1)
        eps = contact.friction_epsilon * dt
        ratio = np.where(y < eps, 2.0 / eps - y / eps**2, 1.0 / np.maximum(y, 1e-30))
        scale = mu * lam * ratio
        pair_force = pair_force - scale[:, None] * u
        pair_block = pair_block + scale[:, None, None] * (np.eye(3) - nn)
    for j in range(4):
        np.add.at(force, ids[:, j], w[:, j, None] * pair_force)
    blocks = (w[:, :, None] * w[:, None, :])[:, :, :, None, None] * pair_block[:, None, None]
    return force, element_stiffness(ids, blocks, n)
