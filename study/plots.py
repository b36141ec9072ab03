"""The sweep's plots (matplotlib, Agg): abs_rel and Dep Con against overlap with 95 % intervals,
overlap vs non-overlap abs_rel, and the measured overlap against the target.
"""
from __future__ import annotations

from pathlib import Path

from mcdp.methods import label
from study.results import CUT, PRIOR_LABEL, REF_LABEL, SCALE_LABEL, method_agg, yardstick_agg


def make_plots(results: dict, plot_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_dir.mkdir(parents=True, exist_ok=True)
    xs = results["overlaps"]
    methods = results["methods"]
    paths = []

    def series(method, key):  # mean and 95 % t half-width over seeds
        a = [method_agg(results, o, method, key) for o in xs]
        return [x["mean"] for x in a], [x.get("ci95", 0.0) if x["n"] > 1 else 0.0 for x in a]

    def save(fig, name: str) -> None:
        fig.tight_layout()
        paths.append(plot_dir / name)
        fig.savefig(paths[-1], dpi=110)
        plt.close(fig)

    def style(ax, title: str, xlabel: str, ylabel: str, legend: bool = True) -> None:
        ax.set_title(title)
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
        if legend:
            ax.legend(fontsize=8)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, sc in zip(axes, ("none", "median")):
        for m in methods:
            y, e = series(m, f"{sc}.mean.abs_rel")
            ax.errorbar(xs, y, yerr=e, marker="o", capsize=3, label=label(m))
        ax.plot(xs, [yardstick_agg(results, o, f"{sc}.mean.abs_rel")["mean"] for o in xs], "k--", label=REF_LABEL)
        ax.plot(xs, [yardstick_agg(results, o, f"{sc}.mean.abs_rel", "prior")["mean"] for o in xs], "k:",
                label=PRIOR_LABEL)
        style(ax, f"abs_rel ({SCALE_LABEL[sc]} scaling), test split", "target overlap (fraction of hfov)",
              "abs_rel (lower is better)", legend=False)
    axes[0].legend(fontsize=8)
    save(fig, "abs_rel_vs_overlap.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    for m in methods:
        y, e = series(m, "dep_con.mean")
        ax.errorbar(xs, y, yerr=e, marker="o", capsize=3, label=label(m))
    ax.plot(xs, [yardstick_agg(results, o, "dep_con.mean")["mean"] for o in xs], "k--", label=REF_LABEL)
    style(ax, "Dep Con (unscaled; ratio |D - D_hat| / D_gt), mean over camera pairs", "target overlap (fraction of hfov)",
          "Dep Con (lower is better)")
    save(fig, "dep_con_vs_overlap.png")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, sc in zip(axes, ("none", "median")):
        for i, m in enumerate(methods):
            c = colors[i % len(colors)]
            y, _ = series(m, f"{sc}.overlap.abs_rel")
            ax.plot(xs, y, marker="o", color=c, label=f"{label(m)} overlap")
            y, _ = series(m, f"{sc}.non_overlap.abs_rel")
            ax.plot(xs, y, marker="s", ls="--", color=c, label=f"{label(m)} non-overlap")
        style(ax, f"abs_rel on overlap (solid) / non-overlap (dashed), {SCALE_LABEL[sc]}",
              "target overlap (fraction of hfov)", "abs_rel", legend=False)
    axes[0].legend(fontsize=6, ncol=2)
    save(fig, "overlap_vs_non_overlap_abs_rel.png")

    fig, ax = plt.subplots(figsize=(5, 4))
    meas = [d["measured"]["measured_mean"] for d in results["data"]]
    ax.plot(xs, xs, "k:", label="target (geometric)")
    ax.plot(xs, meas, "o-", label="measured pixel overlap")
    style(ax, "measured vs target overlap\n(pairs at the target)", "target overlap", "overlap")
    save(fig, "measured_overlap.png")
    return paths


def distance_plot(results: dict, plot_dir: Path) -> Path | None:
    """propagation_by_distance.png: per overlap (one panel each), the paired gain (positive = helps) by
    distance band from the overlap: each mechanism vs Mono2, reading the neighbours (cut - as trained), and
    the ORACLE-local yardstick (emptied - filled), with 95 % intervals over the (world, seed) pairs."""
    from study.reach import LOCAL, band_names, paired

    bands = band_names(results)
    have = {f["method"] for f in results["flat"]}
    lines = [(f"{label(m)} vs Mono2", ("mono2", m), "-") for m in ("fsm", "mcdp_m2", "mcdp_local")
             if m in have and "mono2" in have]
    lines += [(f"{label(m)}: cut - as trained", (m + CUT, m), "--") for m in ("mcdp_m2", "mcdp_local") if m + CUT in have]
    if LOCAL + CUT in have:
        lines.append(("ORACLE-local: emptied - filled", (LOCAL + CUT, LOCAL), ":"))
    if not bands or not lines:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    overlaps = results["overlaps"]
    fig, axes = plt.subplots(1, len(overlaps), figsize=(4.2 * len(overlaps) + 1.5, 4.2), sharey=True, squeeze=False)
    x = list(range(len(bands)))
    for ax, o in zip(axes[0], overlaps):
        for k, (name, (a, b), ls) in enumerate(lines):
            pds = [paired(results, o, (a, f"median.band.{bd}.abs_rel"), (b, f"median.band.{bd}.abs_rel")) for bd in bands]
            y = [p["mean"] for p in pds]
            e = [p["ci95"] if p["n"] > 1 else 0.0 for p in pds]
            ax.errorbar([xi + 0.04 * (k - len(lines) / 2) for xi in x], y, yerr=e, marker="o", ls=ls, capsize=3,
                        label=name)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xticks(x, bands, rotation=30, fontsize=8)
        ax.set_title(f"overlap {o:.2f}", fontsize=10)
        ax.set_xlabel("distance to the overlap (fraction of width)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("abs_rel gain (median scaling; > 0 helps)")
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, loc="center right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 0.78, 1))
    plot_dir.mkdir(parents=True, exist_ok=True)
    path = plot_dir / "propagation_by_distance.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
