"""Export the Newton systems of exact backward Euler on the 64 x 64 cloth (f64, dt = 1/60 s) for
``benchmarks/bench_linear_candidates.py``.

    .venv/bin/python benchmarks/export_newton_matrices.py [--stiffness 1e4,1e8] [--steps 20]
        [--out /tmp/newton_matrices]

The scene is the issue's: ``cloth`` with nx = ny = 64 and ``stiffness`` (structural springs;
shear and flex keep their defaults). The integrator (``implicit_euler``, CG) runs ``--steps``
steps; every Newton system of the last two steps is written to ``OUT/k<K>_s<step>_n<newton>.npz``
as the CSR arrays of A (3n x 3n, from the Jacobian cache CG fills), the right-hand side, the
tolerance the solve was asked for, and PD's constant matrix P = M + tau^2 L (x) I3 (the springs'
Laplacian at their stiffness, pinned rows the identity's), the seed of a PD-preconditioned
solve.
"""
import argparse
import os

import numpy as np
import scipy.sparse as sparse

import taichi_sim as ts
from taichi_sim.scene.cloth import fixed_particle_cloth

DT = 1 / 60


def assemble_block_matrix(system, diagonal: np.ndarray):
    """A (3n x 3n scipy CSR, f64) from the blocks ``system.cache_system_matrix_row`` last
    stored: ``diagonal`` (n, 3, 3) holds A_ii (the identity for a pinned particle), each coupling
    term's cache the blocks J = alpha I + beta u u^T of its entries (see
    :meth:`taichi_sim.forces.Springs.bind_jacobian_cache`). Rows of pinned particles keep only
    their identity block (their cache entries are not refreshed)."""
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


def pd_matrix(system, tau: float) -> sparse.csr_matrix:
    n = system.particle_count
    free = system.free.to_numpy().astype(bool)
    mass = system.mass.to_numpy()
    laplacian = sparse.csr_matrix((n, n))
    for term in system.terms:
        if not getattr(term, "couples_particles", False):
            continue
        ends = term.ends.to_numpy()
        k = term.stiffness.to_numpy()
        i, j = ends[:, 0], ends[:, 1]
        rows = np.concatenate([i, j, i, j])
        cols = np.concatenate([i, j, j, i])
        vals = np.concatenate([k, k, -k, -k])
        laplacian = laplacian + sparse.csr_matrix((vals, (rows, cols)), shape=(n, n))
    scalar = sparse.diags(mass) + tau * tau * laplacian
    keep = sparse.diags(free.astype(float))
    scalar = (keep @ scalar @ keep + sparse.diags((~free).astype(float))).tocsr()
    return sparse.kron(scalar, sparse.identity(3), format="csr")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stiffness", default="1e4,1e8")
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--out", default="/tmp/newton_matrices")
    args = parser.parse_args()
    os.makedirs(args.out, exist_ok=True)
    ts.init(arch="cpu", precision="f64")
    for stiffness in (float(k) for k in args.stiffness.split(",")):
        scene = ts.build_scene("cloth", {"nx": args.size, "ny": args.size, "stiffness": stiffness,
                                          **fixed_particle_cloth(args.size, args.size)})
        integrator = ts.create_integrator("implicit_euler", scene.system)
        stage = integrator._stage
        original = stage.solve
        step = {"index": 0, "newton": 0}

        def capture(tau, t, tolerance, max_iterations, stats, warm=False):
            outcome = original(tau, t, tolerance, max_iterations, stats, warm)
            if step["index"] >= args.steps - 2:
                step["newton"] += 1
                matrix = assemble_block_matrix(scene.system, stage.linear.diagonal.to_numpy())
                name = f"k{stiffness:g}_s{step['index']}_n{step['newton']:02d}.npz"
                np.savez(os.path.join(args.out, name), indptr=matrix.indptr, indices=matrix.indices,
                         data=matrix.data, rhs=stage.rhs.to_numpy().ravel(), tolerance=tolerance,
                         cg_iterations=outcome.iterations)
            return outcome

        stage.solve = capture
        t = 0.0
        for index in range(args.steps):
            step["index"], step["newton"] = index, 0
            report = integrator.step(scene.state, t, DT)
            print(f"k={stiffness:g} step {index}: {report.status.value}, newton so far "
                  f"{integrator.stats.newton_iterations}, cg it {report.linear_iterations}")
            t += DT
        p = pd_matrix(scene.system, DT)
        np.savez(os.path.join(args.out, f"k{stiffness:g}_pd.npz"), indptr=p.indptr, indices=p.indices,
                 data=p.data)


if __name__ == "__main__":
    main()
