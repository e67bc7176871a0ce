"""Time Taichi's own cloth example, unmodified: ``python -m taichi_sim.bench.peer_taichi``.

The peer is ``taichi/examples/ggui_examples/mass_spring_3d_ggui.py`` as shipped in the taichi
wheel: an n x n cloth (n = 128) whose ``substep`` kernel gathers, for every particle, the
springs to its 12 neighbours (|di| + |dj| <= 2: the same structural, shear and flex set as our
``cloth``) with dashpots, then applies gravity, drag and a ball collision, and advances with
symplectic Euler. Its file is imported as it is (its GGUI window opens only under
``__main__``); it calls ``ti.init`` at import, so it runs in its own process, on the CPU via
Taichi's ``TI_ARCH`` environment variable and in the precision asked via ``TI_DEFAULT_FP``
(the example allocates ``float`` fields, which follow the default precision).

For another grid size than its own, the module's grid globals (``n``, ``quad_size``, ``dt``,
``substeps``) and its ``x`` and ``v`` fields are rebound right after import, before any kernel
that reads them is compiled (Taichi reads globals when it compiles a kernel); its source is
untouched and its own ``dt = 4e-2 / n`` rule is kept.

Usage: python -m taichi_sim.bench.peer_taichi --n N [--precision f32|f64] [--repeats R]
       [--batch-seconds S] [--arch x64] [--serve]
Prints one ``@@ {json}`` line on stdout; with ``--serve`` it answers batches instead
(:mod:`taichi_sim.bench.protocol`).
"""
import argparse
import importlib.util
import os
import statistics
import sys
import time

EXAMPLE = os.path.join("examples", "ggui_examples", "mass_spring_3d_ggui.py")


def stencil_springs(n: int) -> int:
    """Springs of the 12-neighbour stencil on an n x n grid (each counted once)."""
    return 2 * n * (n - 1) + 2 * (n - 1) ** 2 + 2 * n * max(n - 2, 0)


class TaichiExample:
    """The example module, imported, resized if asked, warmed up; ``batch()`` times substeps."""

    def __init__(self, n: int, precision: str, batch_seconds: float, arch: str = "x64"):
        os.environ["TI_ARCH"] = arch
        os.environ["TI_DEFAULT_FP"] = "64" if precision == "f64" else "32"
        import taichi as ti

        self.ti = ti
        self.info = {"kind": "peer", "name": "taichi example", "precision": precision, "n": n}
        path = os.path.join(os.path.dirname(ti.__file__), EXAMPLE)
        self.info["source"] = path
        if not os.path.exists(path):
            raise FileNotFoundError(f"{path} is not in this taichi wheel")
        start = time.perf_counter()
        spec = importlib.util.spec_from_file_location("mass_spring_3d_ggui", path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)  # calls ti.init, allocates an n = 128 grid
        self.info["import_s"] = time.perf_counter() - start
        own = int(module.n)
        if n != own:
            module.n = n
            module.quad_size = 1.0 / n
            module.dt = 4e-2 / n
            module.substeps = int(1 / 60 // module.dt)
            module.x = ti.Vector.field(3, dtype=float, shape=(n, n))
            module.v = ti.Vector.field(3, dtype=float, shape=(n, n))
        self.module = module
        springs = stencil_springs(n)
        self.info.update(own_n=own, resized=n != own, dt=module.dt, bending_springs=bool(module.bending_springs),
                         stencil=len(module.spring_offsets), particles=n * n, springs=springs,
                         f_evals_per_step=1.0)
        module.initialize_mass_points()
        start = time.perf_counter()
        module.substep()
        ti.sync()
        self.info["first_step_s"] = time.perf_counter() - start
        start = time.perf_counter()
        module.substep()
        ti.sync()
        one = time.perf_counter() - start
        self.steps = max(1, min(5000, int(batch_seconds / max(one, 1e-7))))
        self.info["batch_steps"] = self.steps

    def batch(self) -> dict:
        self.module.initialize_mass_points()  # back to the start, untimed
        start = time.perf_counter()
        for _ in range(self.steps):
            self.module.substep()
        self.ti.sync()
        return {"step_s": (time.perf_counter() - start) / self.steps}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(allow_abbrev=False)
    parser.add_argument("--n", type=int, required=True)
    parser.add_argument("--precision", choices=("f32", "f64"), default="f32")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--batch-seconds", type=float, default=0.25)
    parser.add_argument("--arch", default="x64")
    parser.add_argument("--serve", action="store_true", help="answer `batch` lines on stdin (protocol.py)")
    args = parser.parse_args(argv)
    return run_peer(lambda: TaichiExample(args.n, args.precision, args.batch_seconds, args.arch),
                    {"kind": "peer", "name": "taichi example", "precision": args.precision, "n": args.n},
                    args.repeats, args.serve)


def run_peer(make, base: dict, repeats: int, serve: bool) -> int:
    """Prepare a peer (``make()``: an object with ``info`` and ``batch()``), then either serve
    batches or time ``repeats`` of them and print one record."""
    from taichi_sim.bench.protocol import emit
    from taichi_sim.bench.protocol import serve as serve_batches

    try:
        peer = make()
    except Exception as exc:
        emit({**base, "status": "unavailable", "note": f"{type(exc).__name__}: {exc}".splitlines()[0][:300]})
        return 0
    if serve:
        serve_batches({**peer.info, "status": "ok"}, peer.batch)
        return 0
    samples = [peer.batch()["step_s"] for _ in range(repeats)]
    emit(finish(peer.info, samples))
    return 0


def finish(info: dict, samples: list[float]) -> dict:
    """The peer's record from its batch times (s per step)."""
    step_s = statistics.median(samples)
    return {**info, "step_s": step_s, "step_min_s": min(samples), "step_max_s": max(samples),
            "particle_steps_per_s": info["particles"] / step_s, "spring_evals_per_s": info["springs"] / step_s,
            "repeats": len(samples), "status": "ok"}


if __name__ == "__main__":
    sys.exit(main())
