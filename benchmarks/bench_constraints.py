"""Benchmark: how far constrained particles drift off their constraints, against the feedback
gains k_s, k_d and the integrator. The scene is the double pendulum of rods
(``rod-pendulum``, both rods horizontal at the start: chaotic), run for ``--t-end`` s.

Run from the repository root (outside pytest):

    .venv/bin/python benchmarks/bench_constraints.py [--t-end 10] [--out media/bench]

Each run is ``ts.run`` with an energy sample (and so a drift sample, the largest |C| over the
constraints: ``RunResult.constraint_violation``) every 10 ms of simulated time. Two sweeps:

* gains: rk4 at h = 5 ms and symplectic Euler at h = 1 ms, each with (k_s, k_d) = (0, 0) and
  k_s = 10, 100, 1000 1/s² at critical damping k_d = 2 sqrt(k_s); |C| over time (left panel);
* steps: euler, midpoint, rk4 and symplectic Euler at h = 1, 2, 5, 10 ms, without feedback and
  with (100, 20); the largest |C| over the run against h (right panel).

Writes constraint-drift.csv / .json (with the machine and this command line) / .png.
"""
import argparse
import math
import shlex
import sys

import numpy as np

import taichi_sim as ts
from taichi_sim.bench.common import machine_info, prepare_out_dir, write_outputs
from taichi_sim.scene import build_scene

GAINS = [(0.0, 0.0)] + [(ks, 2.0 * math.sqrt(ks)) for ks in (10.0, 100.0, 1000.0)]
STEPS = [1e-3, 2e-3, 5e-3, 1e-2]
SAMPLE = 0.01  # s between drift samples


class Rig:
    """One scene and one integrator (compiled once), rerun with other gains and steps."""

    def __init__(self, integrator: str):
        self.scene = build_scene("rod-pendulum")
        self.integrator = ts.create_integrator(integrator, self.scene.system)

    def run(self, ks: float, kd: float, h: float, t_end: float) -> dict:
        scene = self.scene
        scene.reset()
        scene.constraints.set_gains(ks, kd)
        self.integrator.reset()
        result = ts.run(scene, self.integrator, dt=h, t_end=t_end,
                        energy_every=max(1, round(SAMPLE / h)))
        drift = result.constraint_violation
        ok = result.status is ts.Status.OK
        return {"integrator": self.integrator.name, "h": h, "ks": ks, "kd": kd,
                "status": result.status.value, "t": result.t,
                "max_violation": float(np.max(drift)) if ok else math.nan,
                "final_violation": float(drift[-1]) if ok else math.nan,
                "energy_drift": float(np.max(np.abs(result.energy - result.energy[0]))) if ok else math.nan,
                "_t": result.energy_t, "_c": drift}


def plot(rows: list[dict], traces: list[dict], t_end: float, out) -> None:
    import matplotlib.pyplot as plt

    from taichi_sim.bench.plots import DPI, _color, _log_axes

    fig, (left, right) = plt.subplots(1, 2, figsize=(11.5, 4.4))
    shades = {g: c for g, c in zip(GAINS, ["#000000", "#d62728", "#1f77b4", "#2ca02c"])}
    for trace in traces:
        style = "-" if trace["integrator"] == "rk4" else ":"
        c = np.maximum(trace["_c"], 1e-12)  # |C| = 0 at t = 0 on a log axis
        left.plot(trace["_t"], c, style, color=shades[(trace["ks"], trace["kd"])], linewidth=1.0,
                  label=f"{trace['integrator']} h={trace['h'] * 1e3:g} ms, ks={trace['ks']:g}, kd={trace['kd']:.3g}")
    left.set_yscale("log")
    left.set_xlabel("t (s)")
    left.set_ylabel("largest |C| (m)")
    left.set_title("drift against the feedback gains (double pendulum)")
    left.legend(fontsize=6, loc="lower right")
    left.grid(True, alpha=0.3)
    for name in dict.fromkeys(r["integrator"] for r in rows):
        for (ks, kd), style in (((0.0, 0.0), "-"), ((100.0, 20.0), "--")):
            mine = sorted((r for r in rows if r["integrator"] == name and r["ks"] == ks
                           and r["status"] == "ok" and r["max_violation"] > 0), key=lambda r: r["h"])
            if mine:
                right.plot([r["h"] for r in mine], [r["max_violation"] for r in mine], style, marker="o",
                           markersize=4, color=_color(name), label=f"{name}, ks={ks:g}, kd={kd:g}")
    _log_axes(right)
    right.set_xlabel("h (s)")
    right.set_ylabel(f"largest |C| over {t_end:g} s (m)")
    right.set_title("drift against the step (runs that diverged are left out)")
    right.legend(fontsize=6, loc="lower right")
    right.grid(True, which="major", alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], allow_abbrev=False)
    parser.add_argument("--t-end", type=float, default=10.0)
    parser.add_argument("--out", default="media/bench")
    args = parser.parse_args()
    if not (math.isfinite(args.t_end) and args.t_end > 0):
        print("--t-end must be a number > 0", file=sys.stderr)
        raise SystemExit(2)
    out_dir = prepare_out_dir(args.out)
    ts.init(arch="cpu", precision="f64")
    rigs = {name: Rig(name) for name in ("euler", "midpoint", "rk4", "symplectic_euler")}
    traces = [rigs[name].run(ks, kd, h, args.t_end)
              for name, h in (("rk4", 5e-3), ("symplectic_euler", 1e-3)) for ks, kd in GAINS]
    rows = [rigs[name].run(ks, kd, h, args.t_end)
            for name in rigs for ks, kd in ((0.0, 0.0), (100.0, 20.0)) for h in STEPS]
    table = [{k: v for k, v in r.items() if not k.startswith("_")} for r in traces + rows]
    for r in table:
        print(f"{r['integrator']:>16} h={r['h']:<6g} ks={r['ks']:<6g} kd={r['kd']:<6.3g} {r['status']:>8} "
              f"max|C|={r['max_violation']:.3g} m  final|C|={r['final_violation']:.3g} m  "
              f"max|dE|={r['energy_drift']:.3g} J")
    command = shlex.join([".venv/bin/python", "benchmarks/bench_constraints.py", *sys.argv[1:]])
    payload = {"machine": machine_info(), "command": command, "scene": "rod-pendulum",
               "t_end": args.t_end, "sample_s": SAMPLE}
    paths = write_outputs(out_dir, "constraint-drift", table, payload,
                          lambda out: plot(rows, traces, args.t_end, out))
    for kind, path in paths.items():
        if path is not None:
            print(f"wrote {path}")


if __name__ == "__main__":
    main()
