"""The sweep's plots (matplotlib, Agg), every one read from `study.results`' dict:

- paired_vs_mono2.png: each method − Mono2, paired over seeds, with its 95 % interval
  (`study.results.paired_difference`, the numbers of the report's paired table and verdicts), per overlap:
  median-scaled abs_rel on all and on non-overlap pixels, and Dep Con; a filled marker is beyond the interval;
- abs_rel_vs_overlap.png, dep_con_vs_overlap.png: the absolute numbers, the methods on their own axes and the
  yardsticks (constant depth, flat-road prior) on a panel of their own, so the methods are not squashed;
- overlap_vs_non_overlap_abs_rel.png, measured_overlap.png; propagation_by_distance.png (`distance_plot`).
"""
from __future__ import annotations

import math
from pathlib import Path

from mcdp.methods import label
from study.mechanisms import KEYS
from study.results import (BASELINE, PRIOR_LABEL, REF_LABEL, SCALE_LABEL, method_agg, paired_difference,
                           yardstick_agg)
from study.variants import CUT, Evaluation

XLABEL = "target overlap (fraction of hfov)"
#: the paired figure's panels: (results key, title) of `study.mechanisms.KEYS`, in its order
PAIRED_KEYS = tuple((k, n) for k, n in KEYS if k in ("median.mean.abs_rel", "median.non_overlap.abs_rel",
                                                     "dep_con.mean"))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: Path, **kw) -> Path:
    """Save with the figure-level legend (if any) kept inside the canvas (bbox_inches='tight', unless given),
    whole or not at all and never through a link (`corelib.atomic`: a linked plot file is replaced, a linked
    plots folder refused)."""
    import io

    from corelib.atomic import atomic_write_bytes, make_folder

    make_folder(path.parent)
    buf = io.BytesIO()
    fig.savefig(buf, format=path.suffix.lstrip(".") or "png", dpi=110, **({"bbox_inches": "tight"} | kw))
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue(), fsync=False)
    return path


def _legend(fig, axes, ncol: int | None = None) -> None:
    """One legend for the figure, below the panels (never over a line)."""
    handles, names = [], []
    for ax in axes:
        for h, n in zip(*ax.get_legend_handles_labels()):
            if n not in names:
                handles.append(h)
                names.append(n)
    if handles:
        fig.legend(handles, names, loc="upper center", bbox_to_anchor=(0.5, 0.0), fontsize=8,
                   ncol=ncol or min(len(names), 4), frameon=False)


def x_axis(results: dict) -> tuple[str, list[str]]:
    """The overlap axis of every figure: its label and tick labels "target (measured)", the measured pixel
    overlap over the pairs at the target (`study.worlds.measured_overlap`) under each target, so the axis
    reads as the overlap the data has. With ``rig.overlap_target=pixels`` the target is itself a pixel
    overlap (the calibrated knob); with ``angle`` it is the shared fraction of the hfov."""
    xs = results["overlaps"]
    data = results.get("data") or []
    meas = [(d.get("measured") or {}).get("measured_mean") for d in data]
    knobs = {(d.get("measured") or {}).get("knob") or "angle" for d in data}
    label = ("pixel overlap: target (measured)" if knobs == {"pixels"}
             else f"{XLABEL} (measured pixel overlap)")
    if len(meas) != len(xs) or not all(isinstance(m, (int, float)) and math.isfinite(m) for m in meas):
        return XLABEL, [f"{o:.2f}" for o in xs]
    return label, [f"{o:.2f}\n({m:.2f})" for o, m in zip(xs, meas)]


def _style(ax, title: str, ylabel: str, xs, axis: tuple[str, list[str]] | None = None) -> None:
    label, ticks = axis or (XLABEL, [f"{o:.2f}" for o in xs])
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(label, fontsize=9)
    ax.set_ylabel(ylabel, fontsize=9)
    ax.set_xticks(xs, ticks)
    ax.grid(alpha=0.3)


def _step(xs) -> float:
    """The x offset between the dodged methods of one overlap."""
    return 0.035 * (max(xs) - min(xs) if len(xs) > 1 else 1.0)


def make_plots(results: dict, plot_dir: Path) -> list[Path]:
    plt = _plt()
    xs = results["overlaps"]
    methods = results["methods"]
    paths = []
    extra = paired_plot(results, plot_dir)
    paths += [extra] if extra is not None else []

    def series(method, key):  # mean and 95 % t half-width over seeds
        a = [method_agg(results, o, method, key) for o in xs]
        return [x["mean"] for x in a], [x.get("ci95", 0.0) if x["n"] > 1 else 0.0 for x in a]

    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    step = _step(xs)

    def methods_on(ax, key):  # dodged, so the intervals of one overlap do not hide each other
        for i, m in enumerate(methods):
            y, e = series(m, key)
            x = [o + step * (i - (len(methods) - 1) / 2) for o in xs]
            ax.errorbar(x, y, yerr=e, marker="o", ms=5, capsize=2, elinewidth=0.8, color=colors[i % len(colors)],
                        label=label(m))

    def band(ax, key, name):  # the methods' range, for scale next to the yardsticks
        lo = [min(series(m, key)[0][i] for m in methods) for i in range(len(xs))]
        hi = [max(series(m, key)[0][i] for m in methods) for i in range(len(xs))]
        ax.fill_between(xs, lo, hi, color="0.6", alpha=0.4, label=name)

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    for ax, sc in zip(axes, ("none", "median")):
        methods_on(ax, f"{sc}.mean.abs_rel")
        _style(ax, f"methods, {SCALE_LABEL[sc]} scaling", "abs_rel (lower is better)", xs, x_axis(results))
    ax = axes[2]
    for sc, ls in (("none", "-"), ("median", "--")):
        ax.plot(xs, [yardstick_agg(results, o, f"{sc}.mean.abs_rel")["mean"] for o in xs], "k" + ls, marker="^",
                label=f"{REF_LABEL}, {SCALE_LABEL[sc]}")
        ax.plot(xs, [yardstick_agg(results, o, f"{sc}.mean.abs_rel", "prior")["mean"] for o in xs], ls,
                color="darkgoldenrod", marker="v", label=f"{PRIOR_LABEL}, {SCALE_LABEL[sc]}")
    band(ax, "median.mean.abs_rel", "range of the methods, median")
    _style(ax, "yardsticks (no training)", "abs_rel", xs, x_axis(results))
    fig.suptitle("abs_rel vs overlap, test split, all pixels (mean ± 95 % interval over seeds, unpaired; the "
                 "comparison with Mono2: paired_vs_mono2.png)", fontsize=11)
    fig.tight_layout()
    _legend(fig, axes, ncol=4)
    paths.append(_save(plt, fig, plot_dir / "abs_rel_vs_overlap.png"))

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    methods_on(axes[0], "dep_con.mean")
    _style(axes[0], "methods", "Dep Con (lower is better)", xs, x_axis(results))
    axes[1].plot(xs, [yardstick_agg(results, o, "dep_con.mean")["mean"] for o in xs], "k--", marker="^",
                 label=REF_LABEL)
    band(axes[1], "dep_con.mean", "range of the methods")
    _style(axes[1], "yardstick", "Dep Con", xs, x_axis(results))
    fig.suptitle("Dep Con (unscaled ratio |D − D̂| / D_gt, mean over camera pairs)", fontsize=11)
    fig.tight_layout()
    _legend(fig, axes)
    paths.append(_save(plt, fig, plot_dir / "dep_con_vs_overlap.png"))

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for ax, sc in zip(axes, ("none", "median")):
        for i, m in enumerate(methods):
            c = colors[i % len(colors)]
            ax.plot(xs, series(m, f"{sc}.overlap.abs_rel")[0], marker="o", color=c, label=label(m))
            ax.plot(xs, series(m, f"{sc}.non_overlap.abs_rel")[0], marker="s", ls="--", color=c)
        _style(ax, f"{SCALE_LABEL[sc]} scaling", "abs_rel (lower is better)", xs, x_axis(results))
    axes[0].plot([], [], "k-", marker="o", label="overlap pixels (solid)")
    axes[0].plot([], [], "k--", marker="s", label="non-overlap pixels (dashed)")
    fig.suptitle("abs_rel on overlap vs non-overlap pixels (mean over seeds)", fontsize=11)
    fig.tight_layout()
    _legend(fig, axes)
    paths.append(_save(plt, fig, plot_dir / "overlap_vs_non_overlap_abs_rel.png"))

    fig, ax = plt.subplots(figsize=(5, 4))
    meas = [d["measured"]["measured_mean"] for d in results["data"]]
    ax.plot(xs, xs, "k:", label="target (geometric)")
    ax.plot(xs, meas, "o-", label="measured pixel overlap")
    _style(ax, "measured vs target overlap\n(pairs at the target)", "overlap", xs, x_axis(results))
    ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(_save(plt, fig, plot_dir / "measured_overlap.png"))
    return paths


def paired_series(results: dict) -> dict[str, dict[str, list[dict]]]:
    """What paired_vs_mono2.png draws: {key of `PAIRED_KEYS`: {method: [`paired_difference` vs Mono2 per overlap]}}."""
    return {key: {m: [paired_difference(results, o, m, BASELINE, key) for o in results["overlaps"]]
                  for m in results["methods"] if m != BASELINE} for key, _ in PAIRED_KEYS}


def paired_plot(results: dict, plot_dir: Path) -> Path | None:
    """paired_vs_mono2.png: per panel of `PAIRED_KEYS`, each method − Mono2 per overlap with the 95 % t-interval
    of the paired difference (`paired_difference`: same seed, same world); filled = beyond the interval, i.e. the
    report's **lower (better)** / **higher (worse)**. None without Mono2 and a second method."""
    others = [m for m in results["methods"] if m != BASELINE]
    if BASELINE not in results["methods"] or not others:
        return None
    plt = _plt()
    xs = results["overlaps"]
    one_seed = len(results["seeds"]) < 2
    fig, axes = plt.subplots(1, len(PAIRED_KEYS), figsize=(4.6 * len(PAIRED_KEYS), 4.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]  # a method's colour as in the absolute figures
    step = _step(xs)
    series = paired_series(results)
    for ax, (key, name) in zip(axes, PAIRED_KEYS):
        for i, m in enumerate(others):
            c = colors[results["methods"].index(m) % len(colors)]
            pds = series[key][m]
            x = [o + step * (i - (len(others) - 1) / 2) for o in xs]
            y = [p["mean"] for p in pds]
            e = [p["ci95"] if p["n"] > 1 else 0.0 for p in pds]
            ax.errorbar(x, y, yerr=e, color=c, ls="-", lw=1, capsize=3, label=label(m))
            for xi, yi, p in zip(x, y, pds):  # filled: beyond the interval
                ax.plot([xi], [yi], "o", color=c, mfc=c if p["differs"] else "white", ms=6)
        ax.axhline(0.0, color="k", lw=0.8)
        unit = "abs_rel, median scaling" if key.startswith("median.") else "ratio"
        _style(ax, name, f"{name} − Mono2 ({unit})", xs, x_axis(results))
    fig.suptitle("Each method − Mono2, paired over seeds" + (" (one seed: no interval)" if one_seed else
                 ", 95 % t-interval; < 0 = better than Mono2; filled = beyond the interval"), fontsize=11)
    fig.tight_layout()
    _legend(fig, axes)
    return _save(plt, fig, plot_dir / "paired_vs_mono2.png")


def distance_plot(results: dict, plot_dir: Path) -> Path | None:
    """propagation_by_distance.png: per overlap (one panel each), the paired gain (positive = helps) by
    distance band from the overlap: each mechanism vs Mono2, reading the neighbours (cut - as trained), and
    the ORACLE-local yardstick (emptied - filled), with 95 % intervals over the (world, seed) pairs."""
    from study.reach import LOCAL, band_names, paired

    bands = band_names(results)
    have = {Evaluation.of(f) for f in results["flat"]}
    lines = [(f"{label(m)} vs Mono2", ("mono2", m), "-") for m in ("fsm", "mcdp_m2", "mcdp_local")
             if Evaluation(m) in have and Evaluation("mono2") in have]
    lines += [(f"{label(m)}: cut - as trained", (Evaluation(m, CUT), m), "--") for m in ("mcdp_m2", "mcdp_local")
              if Evaluation(m, CUT) in have]
    if Evaluation(LOCAL, CUT) in have:
        lines.append(("ORACLE-local: emptied - filled", (Evaluation(LOCAL, CUT), LOCAL), ":"))
    if not bands or not lines:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    overlaps = results["overlaps"]
    # no shared y: a band with few pixels (far from a wide overlap) has a wide interval that would flatten
    # every other panel; each panel's axis covers its means and is clipped at 3x the largest of them
    fig, axes = plt.subplots(1, len(overlaps), figsize=(4.2 * len(overlaps) + 1.5, 4.2), squeeze=False)
    x = list(range(len(bands)))
    axis = x_axis(results)[1]
    for ax, o, tick in zip(axes[0], overlaps, axis):
        reach, top = 0.0, 0.0
        for k, (name, (a, b), ls) in enumerate(lines):
            pds = [paired(results, o, (a, f"median.band.{bd}.abs_rel"), (b, f"median.band.{bd}.abs_rel")) for bd in bands]
            y = [p["mean"] for p in pds]
            e = [p["ci95"] if p["n"] > 1 else 0.0 for p in pds]
            fin = [(abs(v), abs(v) + d) for v, d in zip(y, e) if math.isfinite(v) and math.isfinite(d)]
            top = max([top] + [v for v, _ in fin])
            reach = max([reach] + [r for _, r in fin])
            ax.errorbar([xi + 0.04 * (k - len(lines) / 2) for xi in x], y, yerr=e, marker="o", ls=ls, capsize=3,
                        label=name)
        lim = max(0.005, min(reach, 3.0 * top)) * 1.1
        ax.set_ylim(-lim, lim)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xticks(x, bands, rotation=30, fontsize=8)
        clipped = " (intervals clipped)" if reach > lim else ""
        ax.set_title(f"overlap {tick.replace(chr(10), ' ')}{clipped}", fontsize=10)
        ax.set_xlabel("distance to the overlap (fraction of width)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("abs_rel gain (median scaling; > 0 helps)")
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, loc="center right", fontsize=8)
    fig.tight_layout(rect=(0, 0, 0.78, 1))
    return _save(plt, fig, plot_dir / "propagation_by_distance.png", bbox_inches=None)
