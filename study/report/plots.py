"""The sweep's plots (matplotlib, Agg), every one read from `study.results.summary`' dict:

- paired_vs_mono2.png: Mono2 − each method, paired over seeds, with its 95 % interval
  (`study.results.paired.paired_difference`, the numbers of the report's paired table and verdicts), per overlap:
  median-scaled abs_rel on all and on non-overlap pixels, and Dep Con; a filled marker is beyond the interval;
- abs_rel_vs_overlap.png, dep_con_vs_overlap.png: the absolute numbers, the methods on their own axes and the
  yardsticks (constant depth, flat-road prior) on a panel of their own, so the methods are not squashed;
- overlap_vs_non_overlap_abs_rel.png (one panel per method and scaling), measured_overlap.png;
  propagation_by_distance.png (`distance_plot`).

One sign in every figure of a difference, the pages' one: worse minus better (Mono2 − method, cut − as trained,
emptied − filled), positive = helps.
"""
from __future__ import annotations

import math
from pathlib import Path

from mcdp.methods import label
from study.report.sections.mechanisms import KEYS
from study.results.paired import paired_gain
from study.results.summary import BASELINE, PAIRED_PLOT, PRIOR_LABEL, REF_LABEL, SCALE_LABEL, method_agg, yardstick_agg
from study.sweep.variants import Evaluation, cut
from synth.overlap import OverlapKnob

XLABEL = "target overlap (fraction of hfov)"
#: the paired figure's panels: (results key, title) of `study.report.sections.mechanisms.KEYS`, in its order
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
    overlap over the pairs at the target (`study.sweep.worlds.measured_overlap`) under each target, so the axis
    reads as the overlap the data has. With ``rig.overlap_target=pixels`` the target is itself a pixel
    overlap (the calibrated knob); with ``angle`` it is the shared fraction of the hfov."""
    xs = results["overlaps"]
    data = results.get("data") or []
    meas = [(d.get("measured") or {}).get("measured_mean") for d in data]
    knobs = {OverlapKnob.of(d.get("measured") or {}).knob for d in data}
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
                 f"comparison with {label(BASELINE)}: {PAIRED_PLOT})", fontsize=11)
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

    paths.append(_save(plt, overlap_figure(results), plot_dir / "overlap_vs_non_overlap_abs_rel.png"))

    paths.append(_save(plt, measured_figure(results), plot_dir / "measured_overlap.png"))
    return paths


def overlap_figure(results: dict):
    """overlap_vs_non_overlap_abs_rel.png as small multiples: one panel per method (columns) and scaling (rows, each
    row on one y-range), two lines each: overlap pixels (solid) and non-overlap pixels (dashed), mean over seeds."""
    plt = _plt()
    xs, methods = results["overlaps"], results["methods"]
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    fig, axes = plt.subplots(2, len(methods), figsize=(2.9 * len(methods) + 1, 6.4), squeeze=False, sharey="row")
    for row, sc in zip(axes, ("none", "median")):
        for j, (ax, m) in enumerate(zip(row, methods)):
            c = colors[j % len(colors)]
            for region, mk, ls, name in (("overlap", "o", "-", "overlap pixels"),
                                         ("non_overlap", "s", "--", "non-overlap pixels")):
                ax.plot(xs, [method_agg(results, o, m, f"{sc}.{region}.abs_rel")["mean"] for o in xs], marker=mk,
                        ls=ls, color=c, label=name)
            _style(ax, f"{label(m)}\n{SCALE_LABEL[sc]} scaling", "abs_rel (lower is better)" if j == 0 else "", xs,
                   x_axis(results))
            if sc == "none":
                ax.set_xlabel("")
    fig.suptitle("abs_rel on overlap (solid) vs non-overlap (dashed) pixels, one panel per method "
                 "(mean over seeds)", fontsize=11)
    fig.tight_layout()
    _legend(fig, [axes[0][0]])
    return fig


def measured_figure(results: dict):
    """measured_overlap.png: the target (y = x: with ``rig.overlap_target=pixels`` a pixel overlap, the knob; else the
    geometric overlap, the shared fraction of the hfov), the measured pixel overlap and, for the pixels knob, the
    geometric overlap of the solved layout."""
    plt = _plt()
    xs = results["overlaps"]
    measured = [d["measured"] for d in results["data"]]
    pixels = {OverlapKnob.of(m).knob for m in measured} == {"pixels"}
    fig, ax = plt.subplots(figsize=(5, 4))
    ax.plot(xs, xs, "k:", label="target pixel overlap (the knob; y = x)" if pixels else
            "target = geometric overlap, shared fraction of hfov (y = x)")
    ax.plot(xs, [m["measured_mean"] for m in measured], "o-", label="measured pixel overlap")
    geo = [m.get("geometric") for m in measured]
    if pixels and all(isinstance(g, (int, float)) for g in geo):
        ax.plot(xs, geo, "^--", color="0.5", label="geometric overlap of the solved layout")
    _style(ax, "measured vs target overlap\n(pairs at the target)", "overlap", xs, x_axis(results))
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def paired_series(results: dict) -> dict[str, dict[str, list[dict]]]:
    """What paired_vs_mono2.png draws: {key of `PAIRED_KEYS`: {method: [Mono2 − method per overlap]}}, the
    `paired_gain`: worse minus better as on every page, positive = helps."""
    return {key: {m: [paired_gain(results, o, BASELINE, m, key) for o in results["overlaps"]]
                  for m in results["methods"] if m != BASELINE} for key, _ in PAIRED_KEYS}


def paired_plot(results: dict, plot_dir: Path) -> Path | None:
    """paired_vs_mono2.png: per panel of `PAIRED_KEYS`, Mono2 − each method per overlap (positive = helps, the
    page's one sign) with the 95 % interval of the paired difference (`paired_difference`: same seed, same world;
    clustered by world in a design with worlds); filled = beyond the interval, i.e. the report's **helps** /
    **hurts**. None without Mono2 and a second method."""
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
        _style(ax, name, f"{name}: {label(BASELINE)} − method ({unit}; > 0 = helps)", xs, x_axis(results))
    fig.suptitle(f"{label(BASELINE)} − each method, paired over seeds" + (" (one seed: no interval)" if one_seed else
                 f", 95 % interval; positive = helps (better than {label(BASELINE)}); filled = beyond the interval"),
                 fontsize=11)
    fig.tight_layout()
    _legend(fig, axes)
    return _save(plt, fig, plot_dir / PAIRED_PLOT)


def distance_lines(results: dict) -> list[tuple[str, tuple, str]]:
    """The lines of propagation_by_distance.png, (name, (a, b), line style), each drawn as a − b per band, worse
    minus better as on every page (positive = helps): Mono2 − each mechanism, a reading network cut − as trained,
    and the ORACLE-local yardstick emptied − filled."""
    from mcdp.methods import reading, short_label
    from study.report.sections.reach import local

    have = {Evaluation.of(f) for f in results["flat"]}
    mech, loc = reading("mechanism"), local()
    lines = [(f"{label(BASELINE)} − {label(m)}", (BASELINE, m), "-") for m in mech
             if Evaluation(m) in have and Evaluation(BASELINE) in have]
    c = cut()
    lines += [(f"{label(m)}: {c} − as trained", (Evaluation(m, c), m), "--") for m in mech
              if Evaluation(m, c) in have]
    if loc is not None and Evaluation(loc, c) in have:
        lines.append((f"{short_label(loc)} (yardstick): emptied − filled", (Evaluation(loc, c), loc), ":"))
    return lines


def robust_limit(values: list[float], floor: float = 0.005) -> float:
    """A panel's half-range: the 85th percentile of |mean| and |mean ± interval| over its points, with 15 % to
    spare, at least `floor`, so one wild band is clipped (and annotated) instead of flattening every other line."""
    v = sorted(abs(x) for x in values if math.isfinite(x))
    if not v:
        return floor
    return max(floor, v[min(len(v) - 1, int(0.85 * len(v)))] * 1.15)


def distance_figure(results: dict):
    """propagation_by_distance.png's figure, or None without bands or lines: per overlap (one panel each), a − b of
    `distance_lines` by distance band (median-scaled abs_rel, positive = helps) with 95 % intervals over the (world,
    seed) pairs; each panel's range from `robust_limit`, a mean beyond it drawn at the edge with its value
    written; the legend below the panels, which use the full width."""
    from study.report.sections.reach import band_names, paired

    bands, lines = band_names(results), distance_lines(results)
    if not bands or not lines:
        return None
    plt = _plt()
    overlaps = results["overlaps"]
    fig, axes = plt.subplots(1, len(overlaps), figsize=(5.2 * len(overlaps), 4.4), squeeze=False)
    x = list(range(len(bands)))
    for ax, o, tick in zip(axes[0], overlaps, x_axis(results)[1]):
        drawn = []
        for k, (name, (a, b), ls) in enumerate(lines):
            pds = [paired(results, o, (a, f"median.band.{bd}.abs_rel"), (b, f"median.band.{bd}.abs_rel")) for bd in bands]
            y = [p["mean"] for p in pds]
            e = [p["ci95"] if p["n"] > 1 and math.isfinite(p["ci95"]) else 0.0 for p in pds]
            drawn.append(([xi + 0.05 * (k - (len(lines) - 1) / 2) for xi in x], y, e, name, ls))
        lim = robust_limit([v + s * d for _, y, e, _, _ in drawn for v, d in zip(y, e) for s in (-1, 0, 1)])
        clipped = False
        for k, (xk, y, e, name, ls) in enumerate(drawn):
            c = f"C{k}"
            yc = [max(-lim, min(lim, v)) if math.isfinite(v) else math.nan for v in y]
            ax.errorbar(xk, yc, yerr=e, marker="o", ls=ls, capsize=3, color=c, label=name)
            for xi, v, d in zip(xk, y, e):
                if math.isfinite(v) and abs(v) > lim:  # outside the range: at the edge, its value written
                    ax.annotate(f"{v:+.3f}", (xi, math.copysign(lim, v)), textcoords="offset points",
                                xytext=(4, -10 if v > 0 else 4), fontsize=7, color=c)
                    clipped = True
                clipped = clipped or (math.isfinite(v) and abs(v) + d > lim)
        ax.set_ylim(-lim * 1.05, lim * 1.05)
        ax.axhline(0.0, color="k", lw=0.8)
        ax.set_xticks(x, bands, rotation=30, fontsize=8)
        ax.set_title(f"overlap {tick.replace(chr(10), ' ')}" + (" (clipped: values written)" if clipped else ""),
                     fontsize=10)
        ax.set_xlabel("distance to the overlap (fraction of width)")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("abs_rel gain (median scaling; > 0 = helps)")
    fig.suptitle("By distance from the overlap: each gain a − b, worse minus better, positive = helps (95 % intervals over the "
                 "(world, seed) pairs)", fontsize=10)
    fig.tight_layout()
    _legend(fig, axes[0], ncol=min(len(lines), 3))
    return fig


def distance_plot(results: dict, plot_dir: Path) -> Path | None:
    """propagation_by_distance.png (`distance_figure`); None when there is nothing to draw."""
    fig = distance_figure(results)
    return None if fig is None else _save(_plt(), fig, plot_dir / "propagation_by_distance.png")
