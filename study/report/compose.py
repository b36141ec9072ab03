"""Report of an overlap sweep: report.md from measured numbers (`format_report`).

`study.results.summary.build_results` turns the sweep's per-run rows into one JSON-able dict;
`study.report.outputs.write_all` writes::

    SWEEP/results.json    build_results' dict
    SWEEP/results.csv     one row per (overlap, method, variant, seed), every metric flattened (variant:
                          trained, cut, oracle, oracle_overlap: `study.sweep.variants`), then the yardsticks
    SWEEP/plots/paired_vs_mono2.png (each method − Mono2, paired), abs_rel_vs_overlap.png, dep_con_vs_overlap.png,
                overlap_vs_non_overlap_abs_rel.png,
                measured_overlap.png
    SWEEP/report.md       tables laid out like the paper's Table 1 (metric and median scaling)
                          and Table 2 (per-camera Dep Con), per overlap; the relative change of
                          every MCDP row against mono2; overlap vs non-overlap abs_rel; timings

Nothing here chooses or filters numbers: a method that does worse than mono2 is
reported as worse, NaN stays NaN.

Example::

    python -c "import study.report.outputs as o, study.results.files as s; o.write_all(s.read_results('SWEEP/results.json'), 'SWEEP')"
    # (read_results: also a results.json written before the variant field; write_all writes it anew)
"""
from __future__ import annotations

import math
from pathlib import Path

from mcdp.diagnostics import COLLAPSE_RATIO
from mcdp.methods import label
from mcdp.metrics import better_words, metric_names
from study.report.sections.mechanisms import format_mechanisms
from study.report.sections.lcon import format_lcon
from study.sweep.pretrain import warm_start_line, weights_in_sweep
from study.report.sections.primary import format_primary
from study.report.sections.propagation import format_propagation
from study.report.sections.classes import format_classes
from study.report.sections.reach import format_reach
from study.results.recorded import fallback_note, run_configs
from study.report.sections.verdicts import format_verdicts
from study.results.summary import (BASELINE, PRIOR_LABEL, REF_LABEL, SCALE_LABEL, YARDSTICKS, method_agg, row_evaluations,
                           yardstick_agg)
from study.results.summary import fmt_num as _num
from study.sweep.variants import TRAINED, Evaluation


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
    """The relative gain of an error x over Mono2's ref, (ref - x) / ref in %: positive = helps, the one sign of
    every page."""
    if not (math.isfinite(x) and math.isfinite(ref)) or ref == 0:
        return float("nan")
    return (ref - x) / ref * 100.0


def _pct(p: float) -> str:
    return "nan" if not math.isfinite(p) else f"{p:+.1f} %"


_CHECKPOINT_WORDS = {"auto": "`auto` = each run's own lowest self-supervised val loss, else its last checkpoint",
                     "best": "`best` = each run's own lowest self-supervised val loss",
                     "last": "`last` = every run at the end of its budget, one step for all"}


def _mixed_steps(results: dict) -> str:
    """One paragraph when a paired comparison with the baseline was scored at two steps (a selection by each run's
    own val loss): how many pairs, and why the report's paired differences are not re-read at one step."""
    steps = {(r["overlap"], r["method"], r["seed"]): r.get("checkpoint_step") for r in results["rows"]}
    base = BASELINE
    pairs = [(k, v) for k, v in steps.items() if k[1] != base and (k[0], base, k[2]) in steps]
    mixed = [k for k, v in pairs if v != steps[k[0], base, k[2]]]
    if not mixed:
        return ""
    return (f"**{len(mixed)} of {len(pairs)} paired runs (each method against {label(base)}, same overlap and seed) "
            "were scored at two different steps**: the checkpoint each run's own val loss picked, which for MCDP "
            "with L_con includes λ·L_con and for the baseline does not (docs/results/lcon.md measures what such a "
            "selection adds to the spread). Its paired differences are read as they were selected; "
            + ("reading them at one step needs every run's last checkpoint, which this sweep removed after evaluation "
               "(`keep_last: false`), so a rerun with `checkpoint: last` retrains.\n"
               if not results["sweep_config"].get("keep_last", True) else
               "a rerun with `checkpoint: last` reads them at one step (each run's last checkpoint was kept).\n"))


def format_report(results: dict, plots: list[str]) -> str:
    """The sweep's report.md: setup, summary and verdicts, one section per overlap, time per stage, plots."""
    cams = None
    for r in results["rows"]:
        trained = row_evaluations(r).get(TRAINED)
        if trained:
            cams = list(trained["metrics"]["dep_con"]["per_camera"])
            break
    L = _setup_section(results)
    primary = format_primary(results)
    if primary:  # a sweep with named primary comparisons opens with them (the copy test first)
        L += [primary, ""]
    lcon = format_lcon(results)[0]
    if lcon:  # (b), L_con's training-time effect, read over worlds at one step (issue 47)
        L += [lcon, ""]
    L += [format_verdicts(results, label), ""]  # the report's one verdict section
    L += _summary_section(results)
    for d in results["data"]:
        L += _overlap_section(results, d, cams)
    L += _timing_section(results)
    add = L.append
    add("## Plots\n")
    for p in plots:
        add(f"![{Path(p).stem}]({p})\n")
    if results.get("previews"):
        add("## Rig previews (smallest and largest overlap)\n")
        for p in results["previews"]:
            add(f"![{Path(p).stem}]({p})\n")
    add("Every number: `results.csv` (one row per overlap × method × seed) and `results.json`.")
    return "\n".join(L) + "\n"


def _setup_section(results: dict) -> list[str]:
    """Title, how the numbers were made (data, methods, seeds, pretraining, evaluation, yardsticks), collapsed,
    ORACLE and failed runs."""
    cfg = results["sweep_config"]
    xs, methods, seeds = results["overlaps"], results["methods"], results["seeds"]
    L: list[str] = []
    add = L.append
    add("# Overlap sweep: MCDP vs Monodepth2 on synthetic six-camera data\n")
    add(f"Generated {results['created']} by `mcdp sweep`. Every number below was measured on the **test split** "
        "of each overlap's dataset; nothing was tuned on it (checkpoint selection: "
        + _CHECKPOINT_WORDS.get(cfg["checkpoint"], f"`{cfg['checkpoint']}`") + "; no ground truth "
        "in training or selection).\n")
    mixed = _mixed_steps(results)
    if mixed:
        add(mixed)
    add("## Setup\n")
    add(f"- overlaps: {', '.join(f'{o:.2f}' for o in xs)} (`{cfg['overlap_mode']}` mode"
        + (": fixed intrinsics, yaw spacing solved, so the overlap is the only variable)" if cfg["overlap_mode"] == "spacing" else ")"))
    add(f"- data preset: `{cfg['data']}`" + (f", overrides `{' '.join(cfg['data_overrides'])}`" if cfg["data_overrides"] else ""))
    add(f"- training presets: `{cfg['train_presets_dir']}/<method>.yaml`"
        + (f", overrides `{' '.join(cfg['train_overrides'])}`" if cfg["train_overrides"] else ""))
    add(f"- methods: {', '.join(label(m) for m in methods)}")
    add(f"- training seeds: {seeds}" + (" (values are mean ± half-width of the 95 % Student-t interval of the "
                                        "mean over seeds)" if len(seeds) > 1 else
                                        " (one seed: no spread available; differences may be within seed noise)"))
    per = int(cfg.get("seeds_per_world", 1) or 1)
    add("- worlds: " + (f"{len(seeds) // per} worlds x {per} training seeds each (`seeds_per_world: {per}`): the i-th "
                        f"seed trains and is tested on world i // {per}, rendered from data seed preset seed + that "
                        "index at every overlap; the tables' paired t-intervals treat the pairs as independent, the "
                        "primary comparisons cluster them by world"
                        if cfg.get("worlds") == "per_seed" and per > 1 else
                        "one per seed (`worlds: per_seed`): seed k trains and is tested on a world rendered from data "
                        "seed k at every overlap, so every interval over seeds covers the scene sample too"
                        if cfg.get("worlds") == "per_seed" else
                        "one per overlap, shared by every seed: the intervals cover the training seed, not the scene "
                        "sample"))
    pre = results.get("pretrain")
    if pre:
        configs, fallback = run_configs(results)
        add(f"- every run starts from one shared self-supervised pretraining (no ground truth; its own world: "
            f"`{' '.join(cfg['pretrain']['data_overrides'])}`): `{weights_in_sweep(pre['weights'])}` in the sweep folder, "
            f"config hash `{pre['config_hash'][:12]}`, "
            f"{pre['step']} steps, render {_sec(pre.get('render_s'))} s + train {_sec(pre.get('train_s'))} s; "
            + warm_start_line(methods, configs) + fallback_note([label(m) for m in fallback]))
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
    runs = {(f["overlap"], f["method"], f.get("seed")) for f in collapsed}  # a run's variants are not runs
    if collapsed:
        add(f"- **COLLAPSED** ({len(runs)} run(s)" + (f", {len(collapsed)} evaluations of them" if len(collapsed)
                                                     != len(runs) else "")
            + f": test depth p90/p10 < {COLLAPSE_RATIO}, a near-constant map): "
            + ", ".join(f"{f['overlap']:.2f} {Evaluation.of(f)} s{f['seed']} ({f['spread.ratio']:.2f})"
                        for f in collapsed))
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
            add(f"- overlap {r['overlap']:.2f} {r['method']} seed {r['seed']}: {r['status']}: {r.get('error', '')}"
                + (f" ({r['failed_attempts']} attempt(s) raised; tracebacks in `runs/overlap_{r['overlap']:.2f}/"
                   f"{r['method']}_s{r['seed']}.errors.jsonl`)" if r.get("status") == "failed" else ""))
        add("")

    return L


def _summary_section(results: dict) -> list[str]:
    """abs_rel vs overlap per method and scaling, the paired verdict, propagation, verdicts."""
    methods = results["methods"]
    base = label(BASELINE)
    L: list[str] = []
    add = L.append
    add("## Summary: abs_rel vs overlap\n")
    for sc in ("none", "median"):
        add(f"**{SCALE_LABEL[sc]} scaling** (abs_rel, {better_words('abs_rel')}; in brackets: gain vs {base}, ({base} − method) / {base}, positive = helps)\n")
        add("| overlap | measured | " + " | ".join(label(m) for m in methods) + f" | {REF_LABEL} | {PRIOR_LABEL} |")
        add("|---|---|" + "---|" * (len(methods) + 2))
        for d in results["data"]:
            o = d["overlap"]
            ref = (method_agg(results, o, BASELINE, f"{sc}.mean.abs_rel")["mean"] if BASELINE in methods
                   else float("nan"))
            cells = []
            for m in methods:
                a = method_agg(results, o, m, f"{sc}.mean.abs_rel")
                c = _fmt(a)
                if m != BASELINE and BASELINE in methods:
                    c += f" ({_pct(_rel(a['mean'], ref))})"
                cells.append(c)
            add(f"| {o:.2f} | {d['measured']['measured_mean']:.3f} | " + " | ".join(cells)
                + f" | {_fmt(yardstick_agg(results, o, f'{sc}.mean.abs_rel'))}"
                + f" | {_fmt(yardstick_agg(results, o, f'{sc}.mean.abs_rel', 'prior'))} |")
        add("")
    add(format_mechanisms(results, label))
    add("")
    add(format_propagation(results, label))
    add("")
    add(format_reach(results, label))
    add("")
    classes = format_classes(results, label)
    if classes:
        L += [classes, ""]
    return L


def _overlap_section(results: dict, d: dict, cams: list[str] | None) -> list[str]:
    """One overlap: measured overlap per pair, Table 1 and Table 2 layouts, overlap vs non-overlap pixels."""
    methods = results["methods"]
    base = label(BASELINE)
    o = d["overlap"]
    mo = d["measured"]
    L: list[str] = []
    add = L.append
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
    add(f"**Table 1 layout** (test split; Δ = relative gain in abs_rel over {base}, ({base} − method) / {base}, positive = helps)\n")
    add("| Method | Scale | " + " | ".join(metric_names()) + " | Δ abs_rel |")
    add("|---|---|" + "---|" * (len(metric_names()) + 1))
    for sc in ("none", "median"):
        ref = method_agg(results, o, BASELINE, f"{sc}.mean.abs_rel")["mean"]
        for m in methods:
            cells = [_fmt(method_agg(results, o, m, f"{sc}.mean.{k}")) for k in metric_names()]
            abs_rel = method_agg(results, o, m, f"{sc}.mean.abs_rel")["mean"]
            delta = "—" if m == BASELINE else _pct(_rel(abs_rel, ref))
            add(f"| {label(m)} | {SCALE_LABEL[sc]} | " + " | ".join(cells) + f" | {delta} |")
        for which, ylabel, _ in YARDSTICKS:
            cells = [_fmt(yardstick_agg(results, o, f"{sc}.mean.{k}", which)) for k in metric_names()]
            add(f"| *{ylabel}* | {SCALE_LABEL[sc]} | " + " | ".join(cells)
                + f" | {_pct(_rel(yardstick_agg(results, o, f'{sc}.mean.abs_rel', which)['mean'], ref))} |")
    add("")
    if cams:
        add(f"**Table 2 layout: Dep Con per camera** (unscaled predictions, {better_words('dep_con')}; Δ = relative gain of the mean over {base}, positive = helps)\n")
        add("| Method | " + " | ".join(cams) + " | mean | Δ mean |")
        add("|---|" + "---|" * (len(cams) + 2))
        ref = method_agg(results, o, BASELINE, "dep_con.mean")["mean"]
        for m in methods:
            cells = [_fmt(method_agg(results, o, m, f"dep_con.camera.{c}")) for c in cams]
            a = method_agg(results, o, m, "dep_con.mean")
            delta = "—" if m == BASELINE else _pct(_rel(a["mean"], ref))
            add(f"| {label(m)} | " + " | ".join(cells) + f" | {_fmt(a)} | {delta} |")
        a = yardstick_agg(results, o, "dep_con.mean")
        add(f"| *{REF_LABEL}* | " + " | ".join(_fmt(yardstick_agg(results, o, f"dep_con.camera.{c}")) for c in cams)
            + f" | {_fmt(a)} | {_pct(_rel(a['mean'], ref))} |")
        add("")
    add(f"**Overlap vs non-overlap pixels** (abs_rel; Δ = relative gain over {label(BASELINE)} on the same region, positive = helps)\n")
    add("| Method | Scale | overlap | non-overlap | Δ overlap | Δ non-overlap |")
    add("|---|---|---|---|---|---|")
    for sc in ("none", "median"):
        r_ov = method_agg(results, o, BASELINE, f"{sc}.overlap.abs_rel")["mean"]
        r_no = method_agg(results, o, BASELINE, f"{sc}.non_overlap.abs_rel")["mean"]
        for m in methods:
            a_ov = method_agg(results, o, m, f"{sc}.overlap.abs_rel")
            a_no = method_agg(results, o, m, f"{sc}.non_overlap.abs_rel")
            d_ov = "—" if m == BASELINE else _pct(_rel(a_ov["mean"], r_ov))
            d_no = "—" if m == BASELINE else _pct(_rel(a_no["mean"], r_no))
            add(f"| {label(m)} | {SCALE_LABEL[sc]} | {_fmt(a_ov)} | {_fmt(a_no)} | {d_ov} | {d_no} |")
        for which, ylabel, _ in YARDSTICKS:
            a_ov = yardstick_agg(results, o, f"{sc}.overlap.abs_rel", which)
            a_no = yardstick_agg(results, o, f"{sc}.non_overlap.abs_rel", which)
            add(f"| *{ylabel}* | {SCALE_LABEL[sc]} | {_fmt(a_ov)} | {_fmt(a_no)} | "
                f"{_pct(_rel(a_ov['mean'], r_ov))} | {_pct(_rel(a_no['mean'], r_no))} |")
    add("")

    return L


def _timing_section(results: dict) -> list[str]:
    """Seconds per stage and overlap, totals, the latest invocation's counters."""
    methods = results["methods"]
    L: list[str] = []
    add = L.append
    add("## Time per stage\n")
    add("Seconds of the invocation that did the work (a stage reused by a rerun keeps its recorded time; "
        "an interrupted and resumed stage counts only its last part).\n")
    add("| overlap | render s | " + " | ".join(f"{label(m)} train s / eval s" for m in methods) + " |")
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
    ray = results.get("sweep_config", {}).get("engine") == "ray"
    add(f"\nTotals (seconds): render {_sec(t['render_s'])}, train {_sec(t['train_s'])}, eval {_sec(t['eval_s'])}; "
        f"latest invocation {_sec(t['this_invocation_s'])} wall"
        + (" (runs as Ray tasks, in parallel: train + eval seconds may add up to more than the wall time)." if ray
           else f" ({jobs} runs at a time, so train + eval seconds add up to more than the wall time)." if jobs > 1
           else "."))
    c = results["counters"]
    add("Latest invocation: " + ", ".join(f"{k} {v}" for k, v in c.items()) + ".\n")

    return L


def _sec(x) -> str:
    return f"{x:.1f}" if isinstance(x, (int, float)) and math.isfinite(x) else "n/a"
