"""Benchmark: linear solvers for the Newton systems of exact backward Euler, on the matrices
``benchmarks/export_newton_matrices.py`` wrote (64 x 64 cloth, f64, dt = 1/60 s).

    .venv/bin/python benchmarks/bench_linear_candidates.py [--dir /tmp/newton_matrices] [--repeats 3]

For each stiffness, the Newton systems of one step (step S, after S - 1 steps of history) are
solved in order, each to the relative residual its Newton iteration asked for (the forcing
term), by each candidate; reported: the median over ``--repeats`` runs (after one warm-up run)
of the total time for the step's systems, the iterations, and the worst final relative
residual. Candidates:

* ``splu``: scipy SuperLU (symmetric mode, MMD on A + A^T), a factorisation per system;
* ``splu-reused``: that factor of the step's first system as the preconditioner of CG on every
  system of the step (refactorised when a solve needs more than ``REFACTOR_AFTER`` iterations);
* ``splu-previous``: the factor of the previous step's first system, reused across the step;
* ``pyamg``: smoothed-aggregation AMG (pyamg, 3x3 blocks, built per system) preconditioning CG
  (pyamg is not a dependency of the package: ``pip install pyamg`` to run these two);
* ``pyamg-reused``: its hierarchy built once per step;
* ``pd``: projective dynamics' constant matrix M + tau^2 L (x) I3, factorised once, as CG's
  preconditioner;
* ``jacobi``: block Jacobi CG in scipy (what the kernels' CG does, for the iteration count).
"""
import argparse
import glob
import os
import statistics
import time

import numpy as np
import scipy.sparse as sparse
import scipy.sparse.linalg as sla

REFACTOR_AFTER = 20
MAX_ITERATIONS = 500  # a candidate that needs more is out of the running anyway


def load(path):
    data = np.load(path)
    n = data["rhs"].size
    matrix = sparse.csr_matrix((data["data"], data["indices"], data["indptr"]), shape=(n, n))
    return matrix, data["rhs"], float(data["tolerance"]), int(data["cg_iterations"])


def load_pd(path, n):
    data = np.load(path)
    return sparse.csr_matrix((data["data"], data["indices"], data["indptr"]), shape=(n, n))


def factor(matrix):
    return sla.splu(matrix.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                    options={"SymmetricMode": True})


def pcg(matrix, rhs, tolerance, apply_preconditioner):
    counter = [0]

    def count(_):
        counter[0] += 1

    preconditioner = sla.LinearOperator(matrix.shape, apply_preconditioner)
    x, _ = sla.cg(matrix, rhs, rtol=tolerance, atol=0.0, maxiter=MAX_ITERATIONS, M=preconditioner,
                  callback=count)
    return x, counter[0]


def block_jacobi(matrix):
    n = matrix.shape[0] // 3
    blocks = matrix.tobsr(blocksize=(3, 3))
    diag = np.zeros((n, 3, 3))
    for i in range(n):  # once per system; outside the timing would flatter it, so it is inside
        start, end = blocks.indptr[i], blocks.indptr[i + 1]
        where = np.nonzero(blocks.indices[start:end] == i)[0]
        diag[i] = blocks.data[start + where].sum(axis=0)
    inverse = np.linalg.inv(diag)
    return lambda r: np.einsum("nij,nj->ni", inverse, r.reshape(n, 3)).ravel()


def run_candidate(name, systems, previous_first, pd_factor):
    iterations, worst = 0, 0.0
    state = {}
    for index, (matrix, rhs, tolerance, _) in enumerate(systems):
        if name == "splu":
            x = factor(matrix).solve(rhs)
            count = 1
        elif name in ("splu-reused", "splu-previous"):
            if "factor" not in state:
                state["factor"] = factor(previous_first if name == "splu-previous" else matrix)
            x, count = pcg(matrix, rhs, tolerance, state["factor"].solve)
            if count > REFACTOR_AFTER:
                state["factor"] = factor(matrix)
        elif name in ("pyamg", "pyamg-reused"):
            import pyamg
            if name == "pyamg" or "amg" not in state:
                state["amg"] = pyamg.smoothed_aggregation_solver(matrix.tobsr(blocksize=(3, 3)), max_coarse=500)
            amg = state["amg"]
            x, count = pcg(matrix, rhs, tolerance, lambda r: amg.solve(r, tol=1e-30, maxiter=1, cycle="V"))
        elif name == "pd":
            x, count = pcg(matrix, rhs, tolerance, pd_factor.solve)
        elif name == "jacobi":
            x, count = pcg(matrix, rhs, tolerance, block_jacobi(matrix))
        iterations += count
        worst = max(worst, np.linalg.norm(rhs - matrix @ x) / np.linalg.norm(rhs) / tolerance)
    return iterations, worst


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", default="/tmp/newton_matrices")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--systems", type=int, default=None, help="only the step's first SYSTEMS systems")
    parser.add_argument("--stiffness", default="10000,1e+08", help="as in the file names")
    parser.add_argument("--candidates", default="splu,splu-reused,splu-previous,pyamg,pyamg-reused,pd,jacobi")
    args = parser.parse_args()
    print(f"load average (1 min) {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    for stiffness in args.stiffness.split(","):
        files = sorted(glob.glob(os.path.join(args.dir, f"k{stiffness}_s*_n*.npz")))
        steps = sorted({int(os.path.basename(f).split("_s")[1].split("_")[0]) for f in files})
        last, before = steps[-1], steps[-2]
        systems = [load(f) for f in files if f"_s{last}_" in f][:args.systems]
        previous_first = load(sorted(f for f in files if f"_s{before}_" in f)[0])[0]
        n = systems[0][1].size
        start = time.perf_counter()
        pd_factor = factor(load_pd(os.path.join(args.dir, f"k{stiffness}_pd.npz"), n))
        pd_seconds = time.perf_counter() - start
        start = time.perf_counter()
        factor(systems[0][0])
        one_factor = time.perf_counter() - start
        print(f"\nk = {float(stiffness):g} N/m: step {last}, {len(systems)} Newton systems, 3n = {n}, "
              f"nnz(A) = {systems[0][0].nnz}; kernel CG (block SSOR) took "
              f"{sum(s[3] for s in systems)} iterations; one splu factorisation {1e3 * one_factor:.1f} ms "
              f"(PD's: {1e3 * pd_seconds:.1f} ms, once, not counted below)")
        print(f"  {'candidate':<15}{'ms/step':>10}{'iterations':>12}{'worst res/tol':>15}")
        for name in args.candidates.split(","):
            run_candidate(name, systems[:3], previous_first, pd_factor)  # warm-up
            times = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                iterations, worst = run_candidate(name, systems, previous_first, pd_factor)
                times.append(time.perf_counter() - start)
            print(f"  {name:<15}{1e3 * statistics.median(times):>10.1f}{iterations:>12}{worst:>15.2f}")


if __name__ == "__main__":
    main()
