"""The Newton system of a particle system as a scipy sparse matrix, from the Jacobian cache."""
import numpy as np


def assemble_block_matrix(system, diagonal: np.ndarray):
    """A (3n x 3n scipy CSR, f64) from the blocks ``system.cache_system_matrix_row`` last
    stored: ``diagonal`` (n, 3, 3) holds A_ii (the identity for a pinned particle), each coupling
    term's cache the blocks J = alpha I + beta u u^T of its entries (see
    :meth:`taichi_sim.forces.Springs.bind_jacobian_cache`). Rows of pinned particles keep only
    their identity block (their cache entries are not refreshed)."""
    import scipy.sparse as sparse

    n = system.particle_count
    free = system.free.to_numpy().astype(bool)
    matrix = sparse.bsr_matrix((np.ascontiguousarray(diagonal, dtype=np.float64), np.arange(n),
                                np.arange(n + 1)), shape=(3 * n, 3 * n))
    for term in system.terms:
        if not getattr(term, "caches_jacobian", False):
            continue
        offsets = term.offsets.to_numpy()
        entries = term.entry_block.to_numpy().astype(np.float64)
        others = term.entry_other.to_numpy()
        u, beta, alpha = entries[:, :3], entries[:, 3], entries[:, 4]
        blocks = beta[:, None, None] * (u[:, :, None] * u[:, None, :])
        blocks[:, (0, 1, 2), (0, 1, 2)] += alpha[:, None]
        blocks[np.repeat(~free, np.diff(offsets))] = 0.0
        matrix = matrix + sparse.bsr_matrix((blocks, others, offsets), shape=(3 * n, 3 * n))
    matrix = matrix.tocsr()
    matrix.sum_duplicates()
    return matrix
