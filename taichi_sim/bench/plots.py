"""The bench figures (matplotlib, imported only here; the Agg backend is selected by the caller)."""
from __future__ import annotations

import math

OUTCOME_COLORS = {"ok": "#2ca02c", "reported": "#ffbf00", "refused": "#1f77b4", "silent": "#d62728", "error": "#000000",
                  "timeout": "#7f7f7f"}
DPI = 72


def _log_axes(ax, x=True, y=True):
    from matplotlib.ticker import NullFormatter

    if x:
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
    if y:
        ax.set_yscale("log")
        ax.yaxis.set_minor_formatter(NullFormatter())


def _color(name):
    """A method's colour: its class's ``plot_colour`` (a label "NAME(OPTION=VALUE)" takes its
    method's), else one from a palette by its name."""
    from ..integrators import colour_of

    return colour_of(name.split("(", 1)[0])


def _finite(v):
    return isinstance(v, (int, float)) and v is not None and math.isfinite(v) and v > 0


def work_precision(rows: list[dict], details: dict, out) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.transforms import blended_transform_factory

    scenes = list(details["problems"])
    panels = [("cost", "pos_error", "f evaluations (+ linear iterations)", "position error at T (m)"),
              ("wall_s", "pos_error", "wall time (s, median)", "position error at T (m)"),
              ("cost", "energy_error", "f evaluations (+ linear iterations)", "relative energy error at T"),
              ("cost", "strain_error", "f evaluations (+ linear iterations)", "max spring strain error at T")]
    fig, axes = plt.subplots(len(scenes), len(panels), figsize=(4.2 * len(panels), 3.3 * len(scenes)),
                             squeeze=False)
    orders = {(o["scene"], o["integrator"]): o for o in details.get("orders", [])}
    for i, scene in enumerate(scenes):
        scene_rows = [r for r in rows if r["scene"] == scene]
        names = list(dict.fromkeys(r["integrator"] for r in scene_rows))
        for j, (xkey, ykey, xlabel, ylabel) in enumerate(panels):
            ax = axes[i][j]
            top = blended_transform_factory(ax.transData, ax.transAxes)
            drawn = False
            for name in names:
                mine = [r for r in scene_rows if r["integrator"] == name]
                good = [(r[xkey], r[ykey]) for r in mine
                        if r.get("status") == "ok" and _finite(r.get(xkey)) and _finite(r.get(ykey))]
                good.sort()
                o = orders.get((scene, name), {})
                label = name
                if o.get("observed") is not None and _finite(o.get("observed")):
                    label += f" (p={o['observed']:.2f})"
                if good:
                    ax.plot(*zip(*good), "o-", color=_color(name), ms=3.5, lw=1.2, label=label)
                    drawn = True
                failed = [r[xkey] for r in mine if r.get("status") not in ("ok", "not applicable", "skipped")
                          and _finite(r.get(xkey))]
                if failed:  # failures are shown, at the top edge, not dropped
                    ax.plot(failed, [0.97] * len(failed), "x", color=_color(name), ms=7, mew=2,
                            transform=top, clip_on=False)
                    drawn = True
            if drawn:
                _log_axes(ax)
            else:
                ax.text(0.5, 0.5, "no springs" if ykey == "strain_error" else "no data", ha="center",
                        va="center", transform=ax.transAxes, color="gray")
                ax.set_xticks([])
                ax.set_yticks([])
            ax.grid(True, which="major", alpha=0.3)
            ax.set_xlabel(xlabel, fontsize=8)
            ax.set_ylabel(ylabel, fontsize=8)
            ax.tick_params(labelsize=7)
            problem = details["problems"][scene]
            if j == 0:
                ax.set_title(f"{scene}: {problem['truth']}, T = {problem['t_end']:.3g} s", fontsize=9,
                             loc="left")
                handles, labels = ax.get_legend_handles_labels()
        axes[i][-1].legend(handles, labels, fontsize=7, loc="center left", bbox_to_anchor=(1.03, 0.5),
                           title="observed order p", title_fontsize=7)
    fig.suptitle("Work-precision (x at the top edge: run failed, e.g. diverged)", fontsize=11)
    fig.tight_layout(rect=(0, 0, 0.86, 0.98))
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)


def stability(rows: list[dict], details: dict, out) -> None:
    import matplotlib.pyplot as plt

    systems = list(details["systems"])
    fig, axes = plt.subplots(1, len(systems), figsize=(5.4 * len(systems), 5.6), squeeze=False)
    for ax, system in zip(axes[0], systems):
        mine = [r for r in rows if r["system"] == system and _finite(r.get("omega_max"))]
        omegas = sorted({r["omega_max"] for r in mine})
        names = list(dict.fromkeys(r["integrator"] for r in mine))
        for name in names:
            pts = [r for r in mine if r["integrator"] == name]
            c = pts[0].get("C") if pts else None
            if c is not None and math.isfinite(c) and c > 0 and omegas:
                ax.plot(omegas, [c / w for w in omegas], "--", color=_color(name), lw=1, alpha=0.8)
            limits = [(r["omega_max"], r["measured"]) for r in pts if r["kind"] == "limit" and _finite(r.get("measured"))]
            if limits:
                label = name
                ratios = [r["ratio"] for r in pts if _finite(r.get("ratio"))]
                if ratios:
                    top = max([r["ratio_above"] for r in pts if _finite(r.get("ratio_above"))] or ratios)
                    label += f" (limit in [{min(ratios):.4f}, {top:.4f}] C/w)"
                ax.plot(*zip(*limits), "o", color=_color(name), ms=6, label=label)
            solver = [(r["omega_max"], r["measured"]) for r in pts if r["kind"] == "solver limit"]
            if solver:
                ax.plot(*zip(*solver), "o", color=_color(name), ms=7, mfc="none", mew=1.5,
                        label=f"{name} (solver fails above this h)")
            uncond = [(r["omega_max"], r["measured"]) for r in pts if r["kind"] == "unconditional"]
            if uncond:
                ax.plot(*zip(*uncond), "^", color=_color(name), ms=7, label=f"{name} (stable at 1000/w)")
            horizon = [(r["omega_max"], r["measured"]) for r in pts if r["kind"] == "horizon" and _finite(r.get("measured"))]
            if horizon:
                ax.plot(*zip(*horizon), "s", color=_color(name), ms=6, mfc="none",
                        label=f"{name} (growth < 2 over the horizon)")
            none = [(r["omega_max"], r.get("smallest_tried_s")) for r in pts if r["kind"] == "none"]
            none = [(w, h) for w, h in none if _finite(h)]
            if none:
                ax.plot(*zip(*none), "v", color=_color(name), ms=6, mfc="none",
                        label=f"{name} (unstable down to this h)")
        _log_axes(ax)
        ax.grid(True, alpha=0.3)
        ax.set_xlabel("omega_max (rad/s, power iteration)", fontsize=8)
        ax.set_ylabel("largest stable step h (s)", fontsize=8)
        ax.set_title(f"{system}: {details['systems'][system].get('description', '')}", fontsize=9)
        ax.legend(fontsize=6.5, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
        ax.tick_params(labelsize=7)
    fig.suptitle(f"Stability: measured (markers) against C / omega_max (dashed), "
                 f"{details['periods']:g} periods of the fastest mode", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)


def extremes(rows: list[dict], out) -> None:
    """One cell per run: integrators down, (scene, stiffness, step) across, coloured by outcome."""
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    names = list(dict.fromkeys(r["integrator"] for r in rows))
    runs = [r for r in rows if r.get("stiffness") is not None]
    stopped = [r for r in rows if r.get("stiffness") is None]  # a case that timed out or crashed: no runs
    columns = list(dict.fromkeys((r["scene"], r["stiffness"], r["dt"]) for r in runs))
    columns += [(scene, None, None) for scene in dict.fromkeys(r["scene"] for r in stopped)
                if not any(c[0] == scene for c in columns)]
    codes = {name: i for i, name in enumerate(OUTCOME_COLORS)}
    grid = [[math.nan] * len(columns) for _ in names]
    for r in runs:
        grid[names.index(r["integrator"])][columns.index((r["scene"], r["stiffness"], r["dt"]))] = codes[r["outcome"]]
    for r in stopped:  # every run of the case is shown as its outcome
        for j, column in enumerate(columns):
            if column[0] == r["scene"]:
                grid[names.index(r["integrator"])][j] = codes[r["outcome"]]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.32 * len(columns) + 3), 0.32 * len(names) + 2.4))
    ax.imshow(grid, cmap=ListedColormap(list(OUTCOME_COLORS.values())), vmin=-0.5, vmax=len(codes) - 0.5,
              aspect="auto", interpolation="nearest")
    ax.set_yticks(range(len(names)), names, fontsize=7)
    ax.set_xticks(range(len(columns)), [f"{s} k={k:g} h={h:.3g}" if k is not None else f"{s} (stopped)"
                                           for s, k, h in columns], fontsize=6,
                  rotation=90)
    ax.legend(handles=[Patch(color=c, label=o) for o, c in OUTCOME_COLORS.items()], fontsize=7, ncol=4,
              loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.tight_layout()
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)


def throughput(rows: list[dict], details: dict, out) -> None:
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, 3, figsize=(16, 5.6))
    ax, ax_first, ax_feat = axes
    styles = {"f32": "-", "f64": "--"}
    ours = [r for r in rows if r.get("kind") == "ours" and r.get("status") == "ok"]
    peers = [r for r in rows if r.get("kind") == "peer" and r.get("status") == "ok"]
    handles = {}
    for (name, precision) in dict.fromkeys((r["name"], r["precision"]) for r in ours):
        pts = sorted((r["n"], r["particle_steps_per_s"], r["first_step_s"]) for r in ours
                     if r["name"] == name and r["precision"] == precision)
        ns, rates, firsts = zip(*pts)
        ax.plot(ns, rates, styles.get(precision, "-"), marker="o", ms=3.5, color=_color(name), lw=1.2)
        ax_first.plot(ns, firsts, styles.get(precision, "-"), marker="o", ms=3.5, color=_color(name), lw=1.2)
        handles.setdefault(name, Line2D([], [], color=_color(name), marker="o", ms=3.5, label=name))
    for (name, precision) in dict.fromkeys((r["name"], r["precision"]) for r in peers):
        pts = sorted((r["n"], r["particle_steps_per_s"], r.get("first_step_s") or math.nan) for r in peers
                     if r["name"] == name and r["precision"] == precision)
        ns, rates, firsts = zip(*pts)
        color = "black" if name.startswith("taichi") else "#777777"
        marker = "s" if name.startswith("taichi") else "D"
        ax.plot(ns, rates, styles.get(precision, "-"), marker=marker, ms=5, color=color, lw=2.2)
        ax_first.plot(ns, firsts, styles.get(precision, "-"), marker=marker, ms=5, color=color, lw=2.2)
        handles.setdefault(name, Line2D([], [], color=color, marker=marker, ms=5, lw=2.2, label=f"peer: {name}"))
    for precision, style in styles.items():
        handles[precision] = Line2D([], [], color="gray", ls=style, label=precision)
    for a in (ax, ax_first):
        a.set_xscale("log", base=2)
        _log_axes(a, x=False)
        a.set_xlabel("grid side n (n x n cloth, 12-neighbour springs)", fontsize=8)
        a.grid(True, alpha=0.3)
        a.tick_params(labelsize=7)
    ax.set_ylabel("particle-steps per second (median)", fontsize=8)
    ax.set_title("Throughput (solid f32, dashed f64)", fontsize=9)
    ax_first.set_ylabel("compile + first step (s)", fontsize=8)
    ax_first.set_title("First step (kernel compilation)", fontsize=9)
    fig.legend(handles=list(handles.values()), loc="lower center", ncol=7, fontsize=7, frameon=False)
    feats = [r for r in rows if r.get("kind") == "feature" and r.get("status") == "ok"]
    if feats:
        labels = list(dict.fromkeys(r["name"] for r in feats))
        precisions = list(dict.fromkeys(r["precision"] for r in feats))
        width = 0.8 / len(precisions)
        for k, precision in enumerate(precisions):
            values = [next((1e3 * r["step_s"] for r in feats if r["name"] == label and r["precision"] == precision),
                           0.0) for label in labels]
            ax_feat.barh([i + k * width for i in range(len(labels))], values, height=width,
                         label=precision, color=["#2ca02c", "#98df8a"][k % 2])
        ax_feat.set_yticks([i + width * (len(precisions) - 1) / 2 for i in range(len(labels))])
        ax_feat.set_yticklabels(labels, fontsize=7)
        ax_feat.invert_yaxis()
        ax_feat.set_xlabel("ms per symplectic Euler step (median)", fontsize=8)
        ax_feat.set_title(f"Features on/off, {feats[0]['n']} x {feats[0]['n']} cloth", fontsize=9)
        ax_feat.legend(fontsize=7)
        ax_feat.tick_params(labelsize=7)
        ax_feat.grid(True, axis="x", alpha=0.3)
    else:
        ax_feat.axis("off")
    fig.tight_layout(rect=(0, 0.09, 1, 1))
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)


def stiff_cloth(rows: list[dict], details: dict, out) -> None:
    """One panel per stiffness: rms position error at T against wall time, a line per method
    through its step sizes (marked by size: larger marker, larger step)."""
    import matplotlib.pyplot as plt

    stiffnesses = sorted({r["k"] for r in rows})
    fig, axes = plt.subplots(1, len(stiffnesses), figsize=(5.6 * len(stiffnesses), 4.8), squeeze=False)
    methods = list(dict.fromkeys(r["method"] for r in rows))
    styles = ["-", "--", ":", "-."]
    for ax, k in zip(axes[0], stiffnesses):
        for m, method in enumerate(methods):
            mine = sorted((r for r in rows if r["k"] == k and r["method"] == method and r["status"] == "ok"
                           and _finite(r.get("error_rms")) and _finite(r.get("wall_s"))), key=lambda r: -r["h"])
            if not mine:
                continue
            name = mine[0]["integrator"]
            ax.plot([r["wall_s"] for r in mine], [r["error_rms"] for r in mine], styles[m % len(styles)],
                    color=_color(name), label=method, marker="o", markersize=4)
        _log_axes(ax)
        ax.set_title(f"k = {k:g} N/m ({details['size']}x{details['size']} cloth, T = {details['t_end']:g} s)")
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("rms position error at T (m)")
        ax.grid(True, which="major", alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="best")
    fig.tight_layout()
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)


def precision(rows: list[dict], disagree: float, out) -> None:
    """Per scene: how far each method's f32 run ends from its f64 run (over the cloth's size),
    with the line above which an ``ok`` f32 run is a finding (hatched)."""
    import matplotlib.pyplot as plt

    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.6 * len(scenes), 4.4), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        mine = [r for r in rows if r["scene"] == scene and r.get("precision") == "f32"]
        names = [r["integrator"] for r in mine]
        values = [r.get("f32_vs_f64_rel") if _finite(r.get("f32_vs_f64_rel")) else math.nan for r in mine]
        bars = ax.bar(range(len(names)), [max(v, 1e-18) if math.isfinite(v) else 0.0 for v in values],
                      color=[_color(r["integrator"]) for r in mine])
        for bar, r in zip(bars, mine):
            if r.get("finding"):  # disagrees and says ok
                bar.set_hatch("///")
                bar.set_edgecolor("black")
        for i, (r, v) in enumerate(zip(mine, values)):
            if not math.isfinite(v):
                ax.text(i, 1e-17, str(r.get("status")), rotation=90, fontsize=6, ha="center", va="bottom")
        ax.axhline(disagree, color="k", linestyle="--", linewidth=0.8, label=f"finding above {disagree:g}")
        ax.set_yscale("log")
        ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
        ax.set_ylabel("|x_f32 - x_f64| max / cloth size")
        ax.set_title(f"{scene} cloth")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, format="png", dpi=DPI)
    plt.close(fig)
