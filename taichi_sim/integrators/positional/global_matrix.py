"""Projective dynamics' global step: one constant SPD matrix, factorised once, solved for x, y
and z in one call.

SuperLU (scipy) in symmetric mode, with a minimum-degree ordering of A + Aᵀ and no pivoting
away from the diagonal, factorises the n x n matrix; a solve takes the (n, 3) right-hand side
whole, so the factor is read once for the three axes. On a 64 x 64 cloth (2 cores, f32) that
solve took 0.48 ms against 3 x 0.22 ms for Taichi's sparse Cholesky (``ti.linalg``, one axis
per call, and a copy of the right-hand side out of a field and the solution back into one).

The factor and the solves are f64 whatever the simulation's precision. In f32 a stiff cloth's
matrix loses its mass term: at k = 1e8 N/m a diagonal entry is about 1e9 and its rounding
(about 70) exceeds m / h^2 (about 1 on a 64 x 64 cloth at 1/60 s), so the factor was that of
the bare spring Laplacian, whose smooth modes the rounding of the right-hand side then drove.
A 64 x 64 f32 cloth at k = 1e8 (10 iterations a step at 1/60 s, started from y) gained up to
2570 J over its 401 J in 2 s; with the factor in f64 it gained 310 J, as the same run in f64
did (the start ``ProjectiveDynamics`` now chooses removes that too). Softer cloths lose less,
but not nothing: after 0.5 s (5 iterations with Chebyshev, 1/60 s, no dashpots) f32 runs were
2.5-3.7 mm rms from the f64 run at k = 1e4 and 10-20 cm at k = 1e6 (64 x 64 and 128 x 128)
with the factor in f32, 1e-5 m with it in f64. The price is the solve's memory traffic:
0.50 against 0.52 ms a solve at 64 x 64, 2.9 against 3.8 ms at 128 x 128.
"""

import numpy as np


class GlobalMatrix:
    """A factorised sparse SPD matrix A (n x n) assembled from COO triplets.

    Args:
        n: rows (the particles).
        triplet_count: the most (row, column, value) triplets an assembly writes; duplicates
            are summed, unused triplets keep the value 0.

    Values, right-hand sides and solutions are f64 (see the module doc).

    :attr:`rows`, :attr:`cols` and :attr:`vals` are the triplet arrays an assembly kernel
    fills (numpy arrays passed to a Taichi kernel are written in place on the CPU).
    """

    dtype = np.dtype(np.float64)

    def __init__(self, n: int, triplet_count: int):
        self.n = int(n)
        self.rows = np.zeros(triplet_count, np.int32)
        self.cols = np.zeros(triplet_count, np.int32)
        self.vals = np.zeros(triplet_count, self.dtype)
        self._factor = None

    @property
    def factorised(self) -> bool:
        return self._factor is not None

    def factorise(self) -> bool:
        """Factorise the assembled triplets; False (and no factor) when A is not symmetric
        positive definite (a zero or negative pivot on the diagonal)."""
        # Imported here: scipy.sparse.linalg takes ~0.17 s to import, which every start of
        # the command line would pay for a method few runs use.
        import scipy.sparse as sparse
        import scipy.sparse.linalg as sparse_linalg

        matrix = sparse.csc_matrix((self.vals, (self.rows, self.cols)), shape=(self.n, self.n))
        self._factor = None
        try:
            factor = sparse_linalg.splu(matrix, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                        options={"SymmetricMode": True})
        except RuntimeError:  # exactly singular
            return False
        # Symmetric elimination (the same permutation of rows and columns) with every pivot
        # positive is a Cholesky factorisation in disguise: A is SPD.
        pivots = factor.U.diagonal()
        if not (np.array_equal(factor.perm_r, factor.perm_c) and np.all(pivots > 0)
                and np.all(np.isfinite(pivots))):
            return False
        self._factor = factor
        return True

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """A⁻¹ rhs for an (n, 3) f64 right-hand side (one column per axis), as a new C-ordered
        (n, 3) f64 array."""
        return np.ascontiguousarray(self._factor.solve(rhs), dtype=self.dtype)
