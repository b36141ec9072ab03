"""The sweep's plots (matplotlib, Agg): abs_rel and Dep Con against overlap with 95 % intervals,
overlap vs non-overlap abs_rel, and the measured overlap against the target.
"""
from __future__ import annotations

from pathlib import Path

from mcdp.methods import label
from study.results import PRIOR_LABEL, REF_LABEL, SCALE_LABEL, method_agg, yardstick_agg


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
