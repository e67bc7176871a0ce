"""Time warp's cloth benchmark integrator, unmodified: ``python -m taichi_sim.bench.peer_warp``.

The peer is ``WpIntegrator`` of ``warp/examples/benchmarks/benchmark_cloth_warp.py`` as shipped
in the ``warp-lang`` wheel (optional: when it is not installed the peer is reported
unavailable): one kernel evaluates every spring (with a dashpot) and scatters its force with
atomics, a second integrates symplectic Euler with gravity. Its driver,
``benchmark_cloth.py``, cannot be imported (it imports ``pxr``, USD, at the top and runs its
whole benchmark at import), so the cloth it would hand the integrator is rebuilt here with
numpy to the same recipe as its ``Cloth`` class (an n x n grid 0.1 apart, stretch, shear and
bend springs of stiffness 1000 and damping 10 in the same order, mass 0.1, two corners fixed:
the same spring set as our ``cloth``), and ``simulate(dt, substeps)`` is timed with its
substep 1/960 s. Warp runs on the CPU device, where it launches kernels on one thread.

Usage: python -m taichi_sim.bench.peer_warp --n N [--repeats R] [--batch-seconds S] [--serve]
Prints one ``@@ {json}`` line on stdout (with ``--serve`` it answers batches instead, see
:mod:`taichi_sim.bench.protocol`). Warp's benchmark is f32 only.
"""
import argparse
import os
import sys
import time

import numpy as np

SUBSTEP = 1.0 / 60.0 / 16.0  # benchmark_cloth.py: 60 fps, 16 substeps


class ClothArrays:
    """The arrays of warp's ``benchmark_cloth.Cloth(lower=(0, 0, 0), dx=n, dy=n, radius=0.1,
    stretch/bend/shear stiffness 1000, mass=0.1, fix_corners=True)``, built with numpy."""

    def __init__(self, n: int, radius: float = 0.1, stiffness: float = 1000.0, damping: float = 10.0,
                 mass: float = 0.1):
        dx = dy = n
        ys, xs = np.meshgrid(np.arange(dy), np.arange(dx), indexing="ij")  # row y, column x
        exact = np.stack([radius * xs.ravel().astype(float), np.zeros(dx * dy), radius * ys.ravel().astype(float)],
                         axis=1)  # float64, as Cloth computes rest lengths before converting
        self.positions = exact.astype(np.float32)
        self.velocities = np.zeros_like(self.positions)
        fixed = (ys == 0) & ((xs == 0) | (xs == dx - 1))
        self.inv_masses = np.where(fixed, 0.0, 1.0 / mass).ravel().astype(np.float32)
        index = ys * dx + xs
        # Horizontal pass (y outer, x inner): stretch (x-1), bend (x-2), shear (y-1, x+1), (y-1, x-1).
        other = np.stack([index - 1, index - 2, (ys - 1) * dx + xs + 1, (ys - 1) * dx + xs - 1], axis=-1)
        keep = np.stack([xs > 0, xs > 1, (ys > 0) & (xs < dx - 1), (ys > 0) & (xs > 0)], axis=-1)
        first = np.stack([np.repeat(index[..., None], 4, axis=-1)[keep], other[keep]], axis=1)
        # Vertical pass (x outer, y inner): stretch (y-1), bend (y-2).
        index_t, ys_t = index.T, ys.T
        other_t = np.stack([index_t - dx, index_t - 2 * dx], axis=-1)
        keep_t = np.stack([ys_t > 0, ys_t > 1], axis=-1)
        second = np.stack([np.repeat(index_t[..., None], 2, axis=-1)[keep_t], other_t[keep_t]], axis=1)
        pairs = np.concatenate([first, second])
        self.spring_indices = pairs.ravel().astype(np.int32)
        self.spring_lengths = np.linalg.norm(exact[pairs[:, 0]] - exact[pairs[:, 1]], axis=1).astype(np.float32)
        self.spring_stiffness = np.full(len(pairs), stiffness, np.float32)
        self.spring_damping = np.full(len(pairs), damping, np.float32)
        self.num_particles = dx * dy
        self.num_springs = len(pairs)
        self.num_tris = 2 * (dx - 1) * (dy - 1)


class WarpCloth:
    """warp's integrator on the benchmark's cloth, warmed up; ``batch()`` times substeps."""

    def __init__(self, n: int, batch_seconds: float):
        try:
            import warp as wp
        except ImportError:
            raise RuntimeError("warp-lang is not installed (pip install warp-lang)") from None
        wp.config.quiet = True
        folder = os.path.join(os.path.dirname(wp.__file__), "examples", "benchmarks")
        if not os.path.exists(os.path.join(folder, "benchmark_cloth_warp.py")):
            raise RuntimeError(f"{folder}/benchmark_cloth_warp.py is not in this warp-lang wheel")
        sys.path.insert(0, folder)
        start = time.perf_counter()
        import benchmark_cloth_warp  # noqa: E402  (calls wp.clear_kernel_cache() at import)

        self.info = {"kind": "peer", "name": "warp benchmark_cloth", "precision": "f32", "n": n,
                     "source": os.path.join(folder, "benchmark_cloth_warp.py"), "warp": wp.config.version,
                     "import_s": time.perf_counter() - start}
        self.cloth = ClothArrays(n)
        self.integrator = benchmark_cloth_warp.WpIntegrator(self.cloth, "cpu")
        start = time.perf_counter()
        self.integrator.simulate(SUBSTEP, 1)  # compiles and loads the module
        self.info["first_step_s"] = time.perf_counter() - start
        start = time.perf_counter()
        self.integrator.simulate(SUBSTEP, 1)
        one = time.perf_counter() - start
        self.steps = max(1, min(5000, int(batch_seconds / max(one, 1e-7))))
        self.info.update(particles=n * n, springs=self.cloth.num_springs, f_evals_per_step=1.0,
                         batch_steps=self.steps, dt=SUBSTEP,
                         note="warp's CPU device runs each kernel on one thread")

    def batch(self) -> dict:
        self.integrator.positions.assign(self.cloth.positions)  # back to the start, untimed
        self.integrator.velocities.zero_()
        start = time.perf_counter()
        self.integrator.simulate(SUBSTEP * self.steps, self.steps)  # returns positions.numpy() once
        return {"step_s": (time.perf_counter() - start) / self.steps}


def main(argv=None) -> int:
    from taichi_sim.bench.peer_taichi import run_peer

    parser = argparse.ArgumentParser(allow_abbrev=False)
    parser.add_argument("--n", type=int, required=True)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batch-seconds", type=float, default=0.25)
    parser.add_argument("--serve", action="store_true", help="answer `batch` lines on stdin (protocol.py)")
    args = parser.parse_args(argv)
    return run_peer(lambda: WarpCloth(args.n, args.batch_seconds),
                    {"kind": "peer", "name": "warp benchmark_cloth", "precision": "f32", "n": args.n},
                    args.repeats, args.serve)


if __name__ == "__main__":
    sys.exit(main())
