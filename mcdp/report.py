"""Report of an overlap sweep: report.md, results.csv, results.json and plots from measured numbers.

`build_results` turns the sweep's per-run rows (`mcdp.sweep.run_stage`) into one
JSON-able dict (every number, mean/std over seeds); `write_all` writes::

    SWEEP/results.json    build_results' dict
    SWEEP/results.csv     one row per (overlap, method, seed), every metric flattened
    SWEEP/plots/abs_rel_vs_overlap.png, dep_con_vs_overlap.png, overlap_vs_non_overlap_abs_rel.png,
                measured_overlap.png
    SWEEP/report.md       tables laid out like the paper's Table 1 (metric and median scaling)
                          and Table 2 (per-camera Dep Con), per overlap; the relative change of
                          every MCDP row against mono2; overlap vs non-overlap abs_rel; timings

Nothing here chooses or filters numbers: a method that does worse than mono2 is
reported as worse, NaN stays NaN.

Example::

    python -c "import json, mcdp.report as r; r.write_all(json.load(open('SWEEP/results.json')), 'SWEEP')"
"""
from __future__ import annotations

import csv
import io
import math
import time
from pathlib import Path
from typing import Any

from corelib.atomic import atomic_write_json, atomic_write_text

from mcdp.diagnostics import COLLAPSE_RATIO
from mcdp.metrics import METRIC_NAMES

LABELS = {
    "mono2": "Mono2",
    "mcdp_m0": "MCDP (m = 0)",
    "mcdp_m1_nocon": "MCDP (w/o L_con, m = 1)",
    "mcdp_m1": "MCDP (m = 1)",
    "mcdp_m2": "MCDP (m = 2)",
}
SCALE_LABEL = {"none": "metric", "median": "median", "rig_median": "rig median"}
LOWER_BETTER = {"abs_rel", "sq_rel", "rmse", "rmse_log"}


# --------------------------------------------------------------------------- numbers
def _f(x) -> float:
    return float(x) if isinstance(x, (int, float)) and x is not None else float("nan")


def flat_row(row: dict) -> dict[str, Any]:
    """One run's numbers as a flat dict of scalars (the CSV row)."""
    out: dict[str, Any] = {k: row.get(k) for k in ("overlap", "method", "seed", "status", "steps", "checkpoint_step",
                                                     "train_s", "eval_s", "train_skipped", "eval_skipped")}
    m = row.get("metrics")
    if not m:
        return out
    for sc in ("none", "median", "rig_median"):
        if sc not in m:
            continue
        for region in ("mean", "overlap", "non_overlap"):
            for k in METRIC_NAMES:
                out[f"{sc}.{region}.{k}"] = _f(m[sc][region].get(k))
        for cam, v in m[sc]["per_camera_abs_rel"].items():
            out[f"{sc}.camera.{cam}.abs_rel"] = _f(v)
    out["dep_con.mean"] = _f(m["dep_con"]["mean"])
    out["spread.ratio"] = _f(m.get("spread", {}).get("ratio"))
    for cam, v in m["dep_con"]["per_camera"].items():
        out[f"dep_con.camera.{cam}"] = _f(v)
    for pair, v in m["dep_con"]["per_pair"].items():
        out[f"dep_con.pair.{pair}"] = _f(v)
    return out


#: two-sided 95 % Student-t quantiles t_{0.975, df} for df = 1..30 (larger df: 1.96)
T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
        2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
        2.045, 2.042)


def t_halfwidth(sd: float, n: int) -> float:
    """Half-width of the 95 % t-interval of a mean of n values with sample std sd (NaN for n < 2)."""
    if n < 2 or not math.isfinite(sd):
        return float("nan")
    t = T975[n - 2] if n - 1 <= len(T975) else 1.96
    return t * sd / math.sqrt(n)


def _mean_std(values: list[float]) -> dict:
    v = [x for x in values if isinstance(x, (int, float)) and math.isfinite(x)]
    n_nan = len(values) - len(v)
    if not v:
        return {"mean": float("nan"), "std": float("nan"), "ci95": float("nan"), "n": 0, "n_nan": n_nan,
                "values": values}
    mu = sum(v) / len(v)
    sd = math.sqrt(sum((x - mu) ** 2 for x in v) / (len(v) - 1)) if len(v) > 1 else 0.0
    return {"mean": mu, "std": sd, "ci95": t_halfwidth(sd, len(v)), "n": len(v), "n_nan": n_nan, "values": values}


def paired_difference(results: dict, overlap: float, a: str, b: str, key: str) -> dict:
    """Mean and 95 % t-interval over seeds of (a - b) for the same seed (seeds pair the runs:
    same data order and pretraining); {"mean", "ci95", "n", "differs"} where differs is
    -1 (a lower), +1 (a higher) or 0 (the interval contains 0)."""
    va = {f["seed"]: f.get(key) for f in results["flat"] if f["overlap"] == overlap and f["method"] == a}
    vb = {f["seed"]: f.get(key) for f in results["flat"] if f["overlap"] == overlap and f["method"] == b}
    d = [va[s] - vb[s] for s in va if s in vb and all(isinstance(x, (int, float)) and math.isfinite(x)
                                                      for x in (va[s], vb[s]))]
    ms = _mean_std(d)
    mu, hw = ms["mean"], ms["ci95"]
    differs = 0
    if math.isfinite(mu) and math.isfinite(hw):
        differs = -1 if mu + hw < 0 else (1 if mu - hw > 0 else 0)
    return {"mean": mu, "ci95": hw, "n": ms["n"], "differs": differs}


def build_results(cfg, data: list[dict], rows: list[dict], counters: dict, total_s: float,
                  previews: list[str]) -> dict:
    """Everything the report shows, JSON-able (NaN allowed)."""
    from corelib.configlib import config_hash, config_to_dict

    flats = [flat_row(r) for r in rows]
    aggregate = []
    for d in data:
        o = d["overlap"]
        for method in cfg.methods:
            fr = [f for f in flats if f["overlap"] == o and f["method"] == method]
            keys = [k for k in (fr[0] if fr else {}) if "." in k]
            aggregate.append({"overlap": o, "method": method, "seeds": [f["seed"] for f in fr],
                              "status": sorted({f["status"] for f in fr}),
                              "metrics": {k: _mean_std([f.get(k, float("nan")) for f in fr]) for k in keys}})
    timing = {
        "render_s": sum(_nz(d["render_s"]) for d in data),
        "train_s": sum(_nz(r.get("train_s")) for r in rows),
        "eval_s": sum(_nz(r.get("eval_s")) for r in rows),
        "this_invocation_s": total_s,
        "note": "render/train/eval seconds are those of the invocation that did the work (skipped stages keep "
                "their recorded time); this_invocation_s is the wall time of the latest invocation",
    }
    return {
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "sweep_config": config_to_dict(cfg),
        "sweep_config_hash": config_hash(cfg),
        "split": "test",
        "overlaps": list(cfg.overlaps),
        "methods": list(cfg.methods),
        "seeds": list(cfg.seeds),
        "counters": counters,
        "timing": timing,
        "data": data,
        "rows": rows,
        "flat": flats,
        "aggregate": aggregate,
        "previews": previews,
    }


def _nz(x) -> float:
    return x if isinstance(x, (int, float)) and math.isfinite(x) else 0.0


def _agg(results: dict, overlap: float, method: str, key: str) -> dict:
    for a in results["aggregate"]:
        if a["overlap"] == overlap and a["method"] == method:
            return a["metrics"].get(key, {"mean": float("nan"), "std": float("nan"), "n": 0})
    return {"mean": float("nan"), "std": float("nan"), "n": 0}


REF_LABEL = "Constant depth (ref.)"
PRIOR_LABEL = "Flat-road prior (ref.)"
#: the yardstick rows: (results["data"] key, table label, csv method name)
YARDSTICKS = (("reference", REF_LABEL, "constant_reference"), ("prior", PRIOR_LABEL, "flat_road_prior"))


def _ref_flat(results: dict, overlap: float, which: str = "reference") -> dict:
    for d in results["data"]:
        if d["overlap"] == overlap and d.get(which):
            return flat_row({"metrics": d[which]["metrics"]})
    return {}


def _ref(results: dict, overlap: float, key: str, which: str = "reference") -> dict:
    """A yardstick's value of `key` at one overlap (``which``: reference = constant, prior = flat road),
    in `_agg`'s shape (NaN if absent)."""
    v = _ref_flat(results, overlap, which).get(key, float("nan"))
    return {"mean": v, "std": 0.0, "n": 1 if math.isfinite(v) else 0}


# --------------------------------------------------------------------------- files
def write_all(results: dict, out: str | Path) -> None:
    out = Path(out)
    atomic_write_json(out / "results.json", results, allow_nan=True)
    write_csv(results, out / "results.csv")
    plots = make_plots(results, out / "plots")
    atomic_write_text(out / "report.md", format_report(results, [p.relative_to(out).as_posix() for p in plots]))


def write_csv(results: dict, path: Path) -> None:
    flats = results["flat"]
    meas = {d["overlap"]: d["measured"] for d in results["data"]}
    keys: list[str] = []
    for f in flats:
        for k in f:
            if k not in keys:
                keys.append(k)
    keys = keys[:3] + ["target_overlap", "measured_overlap"] + keys[3:]
    fh = io.StringIO(newline="")
    with fh:
        w = csv.DictWriter(fh, fieldnames=keys, restval="")
        w.writeheader()
        for f in flats:
            m = meas.get(f["overlap"], {})
            w.writerow({**f, "target_overlap": m.get("target"), "measured_overlap": m.get("measured_mean")})
        for which, _, name in YARDSTICKS:  # the yardsticks, one row per overlap each
            for d in results["data"]:
                ref = _ref_flat(results, d["overlap"], which)
                if ref:
                    w.writerow({**{k: v for k, v in ref.items() if k in keys}, "overlap": d["overlap"],
                                "method": name, "status": "reference",
                                "target_overlap": d["measured"].get("target"),
                                "measured_overlap": d["measured"].get("measured_mean")})
        atomic_write_text(path, fh.getvalue())


def make_plots(results: dict, plot_dir: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_dir.mkdir(parents=True, exist_ok=True)
    xs = results["overlaps"]
    methods = results["methods"]
    paths = []

    def series(method, key):  # mean and 95 % t half-width over seeds
        a = [_agg(results, o, method, key) for o in xs]
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
            ax.errorbar(xs, y, yerr=e, marker="o", capsize=3, label=LABELS[m])
        ax.plot(xs, [_ref(results, o, f"{sc}.mean.abs_rel")["mean"] for o in xs], "k--", label=REF_LABEL)
        ax.plot(xs, [_ref(results, o, f"{sc}.mean.abs_rel", "prior")["mean"] for o in xs], "k:", label=PRIOR_LABEL)
        style(ax, f"abs_rel ({SCALE_LABEL[sc]} scaling), test split", "target overlap (fraction of hfov)",
              "abs_rel (lower is better)", legend=False)
    axes[0].legend(fontsize=8)
    save(fig, "abs_rel_vs_overlap.png")

    fig, ax = plt.subplots(figsize=(6, 4))
    for m in methods:
        y, e = series(m, "dep_con.mean")
        ax.errorbar(xs, y, yerr=e, marker="o", capsize=3, label=LABELS[m])
    ax.plot(xs, [_ref(results, o, "dep_con.mean")["mean"] for o in xs], "k--", label=REF_LABEL)
    style(ax, "Dep Con (unscaled), mean over camera pairs", "target overlap (fraction of hfov)",
          "Dep Con (lower is better)")
    save(fig, "dep_con_vs_overlap.png")

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, sc in zip(axes, ("none", "median")):
        for i, m in enumerate(methods):
            c = colors[i % len(colors)]
            y, _ = series(m, f"{sc}.overlap.abs_rel")
            ax.plot(xs, y, marker="o", color=c, label=f"{LABELS[m]} overlap")
            y, _ = series(m, f"{sc}.non_overlap.abs_rel")
            ax.plot(xs, y, marker="s", ls="--", color=c, label=f"{LABELS[m]} non-overlap")
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


# --------------------------------------------------------------------------- markdown
def _fmt(a: dict, digits: int = 3) -> str:
    mu = a.get("mean", float("nan"))
    if not isinstance(mu, (int, float)) or not math.isfinite(mu):
        return "nan"
    s = f"{mu:.{digits}f}"
    if a.get("n", 0) > 1:
        hw = a.get("ci95", float("nan"))
        s += f" ± {hw:.{digits}f}" if math.isfinite(hw) else f" ± {a['std']:.{digits}f} (sd)"
    if a.get("n_nan"):
        s += f" ({a['n_nan']} nan)"
    return s


def _rel(x: float, ref: float) -> float:
    if not (math.isfinite(x) and math.isfinite(ref)) or ref == 0:
        return float("nan")
    return (x - ref) / ref * 100.0


def _pct(p: float) -> str:
    return "nan" if not math.isfinite(p) else f"{p:+.1f} %"


def format_report(results: dict, plots: list[str]) -> str:
    cfg = results["sweep_config"]
    xs, methods, seeds = results["overlaps"], results["methods"], results["seeds"]
    cams = None
    for r in results["rows"]:
        if r.get("metrics"):
            cams = list(r["metrics"]["dep_con"]["per_camera"])
            break
    L: list[str] = []
    add = L.append
    add("# Overlap sweep: MCDP vs Monodepth2 on synthetic six-camera data\n")
    add(f"Generated {results['created']} by `mcdp sweep`. Every number below was measured on the **test split** "
        "of each overlap's dataset; nothing was tuned on it (checkpoint selection: "
        f"`{cfg['checkpoint']}` = lowest self-supervised val loss, else the last checkpoint; no ground truth "
        "in training or selection).\n")
    add("## Setup\n")
    add(f"- overlaps: {', '.join(f'{o:.2f}' for o in xs)} (`{cfg['overlap_mode']}` mode"
        + (": fixed intrinsics, yaw spacing solved, so the overlap is the only variable)" if cfg["overlap_mode"] == "spacing" else ")"))
    add(f"- data preset: `{cfg['data']}`" + (f", overrides `{' '.join(cfg['data_overrides'])}`" if cfg["data_overrides"] else ""))
    add(f"- training presets: `{cfg['train_presets_dir']}/<method>.yaml`"
        + (f", overrides `{' '.join(cfg['train_overrides'])}`" if cfg["train_overrides"] else ""))
    add(f"- methods: {', '.join(LABELS[m] for m in methods)}")
    add(f"- training seeds: {seeds}" + (" (values are mean ± half-width of the 95 % Student-t interval of the "
                                        "mean over seeds)" if len(seeds) > 1 else
                                        " (one seed: no spread available; differences may be within seed noise)"))
    pre = results.get("pretrain")
    if pre:
        add(f"- every run starts from one shared self-supervised pretraining (no ground truth; its own world: "
            f"`{' '.join(cfg['pretrain']['data_overrides'])}`): `{pre['weights']}`, config hash `{pre['config_hash'][:12]}`, "
            f"{pre['step']} steps, render {_sec(pre.get('render_s'))} s + train {_sec(pre.get('train_s'))} s; "
            "mono2 starts from its mono head, every MCDP variant from its bases; weight networks start fresh")
    else:
        add("- every (overlap, method, seed) is trained from scratch on its own dataset; no pretraining is shared "
            "between overlaps or methods")
    ev = cfg["eval"]
    add(f"- evaluation: depth range [{ev['min_depth']}, {ev['max_depth']}] m, frame stride {ev['frame_stride']}, "
        f"skip_ends={ev['skip_ends']}; self-occlusion (ego body) pixels excluded; Dep Con on unscaled predictions")
    refs = [d["reference"] for d in results["data"] if d.get("reference")]
    if refs:
        add(f"- reference row **{REF_LABEL}**: every pixel of every camera at one depth, the median ground-truth "
            f"depth of the train split ({', '.join(format(r['depth_m'], '.1f') for r in refs)} m per overlap). It uses "
            "ground truth, so it is a yardstick, not a method: with median scaling it scores what a depth map "
            "with no structure at all scores. A method above it has not learnt usable depth structure")
    if any(d.get("prior") for d in results["data"]):
        add(f"- reference row **{PRIOR_LABEL}**: no training; knows the rig (camera height and pitch) and that the road "
            "is flat: the road plane's depth where a ray meets it, the constant above elsewhere. A method above it "
            "has learnt less than the ground plane")
    collapsed = [f for f in results["flat"] if isinstance(f.get("spread.ratio"), (int, float))
                 and math.isfinite(f["spread.ratio"]) and f["spread.ratio"] < COLLAPSE_RATIO]
    if collapsed:
        add(f"- **COLLAPSED** ({len(collapsed)} run(s): test depth p90/p10 < {COLLAPSE_RATIO}, a near-constant map): "
            + ", ".join(f"{f['overlap']:.2f} {f['method']} s{f['seed']} ({f['spread.ratio']:.2f})" for f in collapsed))
    else:
        add(f"- no run ended collapsed (every run's test depth has p90/p10 >= {COLLAPSE_RATIO})")
    oracle = [r for r in results["rows"] if r.get("oracle")]
    if oracle:
        add(f"- **ORACLE**: {len(oracle)} run(s) use ground-truth median scaling (scale.source=oracle_gt_median)")
    add(f"- sweep config hash `{results['sweep_config_hash'][:16]}`; full resolved config in `sweep_config.yaml`, "
        "each run's in `runs/overlap_*/<method>_s<seed>/config.yaml`\n")

    bad = [r for r in results["rows"] if r.get("status") != "ok"]
    if bad:
        add("**Failed runs** (their metrics are missing / NaN below):\n")
        for r in bad:
            add(f"- overlap {r['overlap']:.2f} {r['method']} seed {r['seed']}: {r['status']}: {r.get('error', '')}")
        add("")

    # ---- summary
    add("## Summary: abs_rel vs overlap\n")
    for sc in ("none", "median"):
        add(f"**{SCALE_LABEL[sc]} scaling** (abs_rel, lower is better; in brackets: change vs Mono2)\n")
        add("| overlap | measured | " + " | ".join(LABELS[m] for m in methods) + f" | {REF_LABEL} | {PRIOR_LABEL} |")
        add("|---|---|" + "---|" * (len(methods) + 2))
        for d in results["data"]:
            o = d["overlap"]
            ref = _agg(results, o, "mono2", f"{sc}.mean.abs_rel")["mean"] if "mono2" in methods else float("nan")
            cells = []
            for m in methods:
                a = _agg(results, o, m, f"{sc}.mean.abs_rel")
                c = _fmt(a)
                if m != "mono2" and "mono2" in methods:
                    c += f" ({_pct(_rel(a['mean'], ref))})"
                cells.append(c)
            add(f"| {o:.2f} | {d['measured']['measured_mean']:.3f} | " + " | ".join(cells)
                + f" | {_fmt(_ref(results, o, f'{sc}.mean.abs_rel'))}"
                + f" | {_fmt(_ref(results, o, f'{sc}.mean.abs_rel', 'prior'))} |")
        add("")
    add("### Verdict per overlap: MCDP (m = 2) vs Mono2\n")
    add("Paired over seeds (same seed = same data order and start): mean difference MCDP (m = 2) − Mono2 with "
        "its 95 % Student-t interval; *differs* only when the interval excludes 0. Median-scaled abs_rel "
        "(accuracy) and Dep Con in metres (consistency), on all, overlap and non-overlap pixels.\n")
    add(_pair_verdicts(results))
    add("")
    add("### Verdicts (abs_rel, mean over seeds)\n")
    add(_verdicts(results))
    add("")

    # ---- per overlap
    for d in results["data"]:
        o = d["overlap"]
        mo = d["measured"]
        add(f"## Overlap {o:.2f}\n")
        add(f"Target overlap {mo['target']:.2f}, measured pixel overlap {mo['measured_mean']:.3f} (mean over the "
            f"{mo['pairs_at_target']} of {mo['pairs']} adjacent pairs whose geometric target is {mo['target']:.2f}; "
            f"over all pairs {mo['measured_all']:.3f}); hfov {_num(mo.get('hfov_deg'))}°, yaw spacing {_num(mo.get('yaw_spacing_deg'))}°. "
            f"Dataset `{Path(d['path']).name}` ({d['splits']}), render {_sec(d['render_s'])} s"
            + (" (reused)" if d["render_skipped"] else "") + ".\n")
        add("| pair | target | measured |")
        add("|---|---|---|")
        for k, v in mo["per_pair"].items():
            add(f"| {k} | {_num(v['target'])} | {_num(v['measured'])} |")
        add("")
        add(f"**Table 1 layout** (test split; Δ = relative change of abs_rel vs Mono2, negative = better)\n")
        add("| Method | Scale | " + " | ".join(METRIC_NAMES) + " | Δ abs_rel |")
        add("|---|---|" + "---|" * (len(METRIC_NAMES) + 1))
        for sc in ("none", "median"):
            ref = _agg(results, o, "mono2", f"{sc}.mean.abs_rel")["mean"]
            for m in methods:
                cells = [_fmt(_agg(results, o, m, f"{sc}.mean.{k}")) for k in METRIC_NAMES]
                delta = "—" if m == "mono2" else _pct(_rel(_agg(results, o, m, f"{sc}.mean.abs_rel")["mean"], ref))
                add(f"| {LABELS[m]} | {SCALE_LABEL[sc]} | " + " | ".join(cells) + f" | {delta} |")
            for which, label, _ in YARDSTICKS:
                cells = [_fmt(_ref(results, o, f"{sc}.mean.{k}", which)) for k in METRIC_NAMES]
                add(f"| *{label}* | {SCALE_LABEL[sc]} | " + " | ".join(cells)
                    + f" | {_pct(_rel(_ref(results, o, f'{sc}.mean.abs_rel', which)['mean'], ref))} |")
        add("")
        if cams:
            add("**Table 2 layout: Dep Con per camera** (unscaled predictions, lower is better; Δ = mean vs Mono2)\n")
            add("| Method | " + " | ".join(cams) + " | mean | Δ mean |")
            add("|---|" + "---|" * (len(cams) + 2))
            ref = _agg(results, o, "mono2", "dep_con.mean")["mean"]
            for m in methods:
                cells = [_fmt(_agg(results, o, m, f"dep_con.camera.{c}")) for c in cams]
                a = _agg(results, o, m, "dep_con.mean")
                delta = "—" if m == "mono2" else _pct(_rel(a["mean"], ref))
                add(f"| {LABELS[m]} | " + " | ".join(cells) + f" | {_fmt(a)} | {delta} |")
            a = _ref(results, o, "dep_con.mean")
            add(f"| *{REF_LABEL}* | " + " | ".join(_fmt(_ref(results, o, f"dep_con.camera.{c}")) for c in cams)
                + f" | {_fmt(a)} | {_pct(_rel(a['mean'], ref))} |")
            add("")
        add("**Overlap vs non-overlap pixels** (abs_rel; Δ vs Mono2 on the same region, negative = better)\n")
        add("| Method | Scale | overlap | non-overlap | Δ overlap | Δ non-overlap |")
        add("|---|---|---|---|---|---|")
        for sc in ("none", "median"):
            r_ov = _agg(results, o, "mono2", f"{sc}.overlap.abs_rel")["mean"]
            r_no = _agg(results, o, "mono2", f"{sc}.non_overlap.abs_rel")["mean"]
            for m in methods:
                a_ov = _agg(results, o, m, f"{sc}.overlap.abs_rel")
                a_no = _agg(results, o, m, f"{sc}.non_overlap.abs_rel")
                d_ov = "—" if m == "mono2" else _pct(_rel(a_ov["mean"], r_ov))
                d_no = "—" if m == "mono2" else _pct(_rel(a_no["mean"], r_no))
                add(f"| {LABELS[m]} | {SCALE_LABEL[sc]} | {_fmt(a_ov)} | {_fmt(a_no)} | {d_ov} | {d_no} |")
            for which, label, _ in YARDSTICKS:
                a_ov = _ref(results, o, f"{sc}.overlap.abs_rel", which)
                a_no = _ref(results, o, f"{sc}.non_overlap.abs_rel", which)
                add(f"| *{label}* | {SCALE_LABEL[sc]} | {_fmt(a_ov)} | {_fmt(a_no)} | "
                    f"{_pct(_rel(a_ov['mean'], r_ov))} | {_pct(_rel(a_no['mean'], r_no))} |")
        add("")

    # ---- timing
    add("## Time per stage\n")
    add("Seconds of the invocation that did the work (a stage reused by a rerun keeps its recorded time; "
        "an interrupted and resumed stage counts only its last part).\n")
    add("| overlap | render s | " + " | ".join(f"{LABELS[m]} train s / eval s" for m in methods) + " |")
    add("|---|---|" + "---|" * len(methods))
    for d in results["data"]:
        o = d["overlap"]
        cells = []
        for m in methods:
            rs = [r for r in results["rows"] if r["overlap"] == o and r["method"] == m]
            cells.append(" ; ".join(f"{_sec(r.get('train_s'))} / {_sec(r.get('eval_s'))}" for r in rs))
        add(f"| {o:.2f} | {_sec(d['render_s'])} | " + " | ".join(cells) + " |")
    t = results["timing"]
    jobs = results.get("sweep_config", {}).get("jobs", 1)
    add(f"\nTotals (seconds): render {_sec(t['render_s'])}, train {_sec(t['train_s'])}, eval {_sec(t['eval_s'])}; "
        f"latest invocation {_sec(t['this_invocation_s'])} wall"
        + (f" ({jobs} runs at a time, so train + eval seconds add up to more than the wall time)." if jobs > 1 else "."))
    c = results["counters"]
    add("Latest invocation: " + ", ".join(f"{k} {v}" for k, v in c.items()) + ".\n")

    add("## Plots\n")
    for p in plots:
        add(f"![{Path(p).stem}]({p})\n")
    if results.get("previews"):
        add("## Rig previews (smallest and largest overlap)\n")
        for p in results["previews"]:
            add(f"![{Path(p).stem}]({p})\n")
    add("Every number: `results.csv` (one row per overlap × method × seed) and `results.json`.")
    return "\n".join(L) + "\n"


def _pair_verdicts(results: dict, a: str = "mcdp_m2", b: str = "mono2") -> str:
    """One line per overlap: does method a differ from b beyond the paired 95 % interval?"""
    if a not in results["methods"] or b not in results["methods"]:
        return f"- {a} or {b} is not part of this sweep: no verdict.\n"
    if len(results["seeds"]) < 2:
        return "- One seed only: no interval, no verdict.\n"
    lines = []
    word = {-1: "**lower (better)**", 1: "**higher (worse)**", 0: "no difference beyond the interval"}
    for d in results["data"]:
        o = d["overlap"]
        parts = []
        for key, name, unit in (("median.mean.abs_rel", "accuracy", ""),
                                ("median.overlap.abs_rel", "overlap px", ""),
                                ("median.non_overlap.abs_rel", "non-overlap px", ""),
                                ("dep_con.mean", "Dep Con", " m")):
            pd = paired_difference(results, o, a, b, key)
            parts.append(f"{name} {pd['mean']:+.3f} ± {pd['ci95']:.3f}{unit}: {word[pd['differs']]}")
        lines.append(f"- overlap {o:.2f}: " + "; ".join(parts))
    return "\n".join(lines)


def _verdicts(results: dict) -> str:
    methods = results["methods"]
    if "mono2" not in methods:
        return "- Mono2 is not part of this sweep: no comparison.\n"
    if len(methods) == 1:
        return "- Only Mono2 is part of this sweep: no MCDP comparison.\n"
    lines = []
    for d in results["data"]:
        o = d["overlap"]
        for sc in ("none", "median"):
            ref = _agg(results, o, "mono2", f"{sc}.mean.abs_rel")["mean"]
            ref_no = _agg(results, o, "mono2", f"{sc}.non_overlap.abs_rel")["mean"]
            beat, lost = [], []
            for m in methods:
                if m == "mono2":
                    continue
                v = _agg(results, o, m, f"{sc}.mean.abs_rel")["mean"]
                v_no = _agg(results, o, m, f"{sc}.non_overlap.abs_rel")["mean"]
                if not (math.isfinite(v) and math.isfinite(ref)):
                    lost.append(f"{LABELS[m]} (not comparable: NaN)")
                    continue
                no = ("non-overlap also better" if v_no < ref_no else "non-overlap NOT better") \
                    if math.isfinite(v_no) and math.isfinite(ref_no) else "non-overlap NaN"
                entry = f"{LABELS[m]} {v:.3f} vs {ref:.3f}" + (" (tie)" if v == ref else "") + f", {no}"
                (beat if v < ref else lost).append(entry)
            head = f"- overlap {o:.2f}, {SCALE_LABEL[sc]}: "
            cref = _ref(results, o, f"{sc}.mean.abs_rel")["mean"]
            pref = _ref(results, o, f"{sc}.mean.abs_rel", "prior")["mean"]
            if sc == "median" and math.isfinite(cref) and math.isfinite(pref):
                means = {m: _agg(results, o, m, f"{sc}.mean.abs_rel")["mean"] for m in methods}
                short = [f"{LABELS[m]} {v:.3f}" for m, v in means.items() if not (v <= 0.5 * cref and v < pref)]
                lines.append(head + (f"**not all methods reach <= 0.5 x constant ({0.5 * cref:.3f}) and below the "
                                     f"flat-road prior ({pref:.3f})**: " + ", ".join(short) if short else
                                     f"every method (mean over seeds) is at <= 0.5 x constant ({0.5 * cref:.3f}) "
                                     f"and below the flat-road prior ({pref:.3f}); worst "
                                     f"{max(means.values()):.3f}"))
            if math.isfinite(cref):
                worse = [LABELS[m] for m in methods
                         if not _agg(results, o, m, f"{sc}.mean.abs_rel")["mean"] < cref]
                lines.append(head + (f"**not better than the constant-depth reference** ({cref:.3f}): "
                                     + ", ".join(worse) if worse else
                                     f"every method beats the constant-depth reference ({cref:.3f})"))
            if not lost:
                lines.append(head + "every MCDP variant beats Mono2 (" + "; ".join(beat) + ")")
            elif not beat:
                lines.append(head + "**no MCDP variant beats Mono2** (" + "; ".join(lost) + ")")
            else:
                lines.append(head + "beat Mono2: " + "; ".join(beat) + ". **Did not beat Mono2**: " + "; ".join(lost))
    if len(results["seeds"]) == 1:
        lines.append("- One training seed only: differences smaller than the seed-to-seed spread (unknown here) "
                     "are not evidence either way.")
    return "\n".join(lines)


def _num(x, digits: int = 3) -> str:
    return f"{x:.{digits}f}" if isinstance(x, (int, float)) and math.isfinite(x) else "nan"


def _sec(x) -> str:
    return f"{x:.1f}" if isinstance(x, (int, float)) and math.isfinite(x) else "n/a"
