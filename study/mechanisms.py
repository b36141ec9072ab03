"""The report's comparison of the mechanisms that use the cameras' overlap, each against Monodepth2.

The paper's Table 1 rows are three ways of using the overlap: FSM (``fsm``: photometric constraints
between cameras in training only), a SurroundDepth-style network (``surround``: geometry-free
attention between cameras at inference) and MCDP (``mcdp_*``: geometry-aware refinement at
inference). Mono2 uses no overlap at all, so *method − Mono2*, paired over seeds, is what a
mechanism gains from the overlap at a given overlap; *as trained − cut* is what it takes from the
other cameras at inference (0 by construction for a network that never reads them).

Verdicts: a method **gains from overlap x on** when it is lower than Mono2 beyond the paired 95 %
interval at x and at every larger overlap of the sweep; **better at x only** when it is lower at some
overlaps but not from one on; **gains at no overlap** when it is never lower. Read from
`study.results` only (nothing computed from raw files here).
"""
from __future__ import annotations

import math

from study.results import (BASELINE, INERT_M, USE_FLOOR, evaluations, fmt_diff, method_agg, paired_difference,
                           verdict_word)
from study.results import fmt_num as _num
from study.variants import CUT, Evaluation

#: (results key, column name) of the paired comparisons against Mono2
KEYS = (("median.mean.abs_rel", "accuracy, all px"), ("median.overlap.abs_rel", "overlap px"),
        ("median.non_overlap.abs_rel", "non-overlap px"), ("dep_con.mean", "Dep Con (ratio)"))


def _pd(pd: dict, digits: int = 3, word: bool = False, floor: float = 0.0) -> str:
    """'mean ± half-width', with its verdict word, or in bold when beyond the interval (and not below `floor`)."""
    s = fmt_diff(pd, digits)
    if word:
        s += f": {verdict_word(pd, floor)}"
    elif pd["differs"] and abs(pd["mean"]) >= floor:
        s = f"**{s}**"
    return s


def from_which_overlap(diffs: dict[float, dict]) -> str:
    """Verdict from {overlap: paired difference vs Mono2}: 'from x on', 'at x only', or 'at no overlap'."""
    xs = sorted(diffs)
    better = [o for o in xs if diffs[o]["differs"] < 0]
    worse = [o for o in xs if diffs[o]["differs"] > 0]
    tail = ""
    if worse:
        tail = "; worse at " + ", ".join(f"{o:.2f}" for o in worse)
    if not better:
        return "gains at no overlap of the sweep" + tail
    for i, o in enumerate(xs):
        if all(diffs[x]["differs"] < 0 for x in xs[i:]):
            return f"gains from overlap {o:.2f} on" + (" (every overlap of the sweep)" if i == 0 else "") + tail
    return "better at " + ", ".join(f"{o:.2f}" for o in better) + " only, not from one overlap on" + tail


def format_mechanisms(results: dict, label) -> str:
    """Markdown: each method − Mono2 per overlap (accuracy, overlap / non-overlap px, Dep Con, cut) and
    the verdict lines; '' without Mono2 or a second method."""
    methods = [m for m in results["methods"] if m != BASELINE]
    if BASELINE not in results["methods"] or not methods:
        return ""
    evs = evaluations(results)
    L: list[str] = []
    add = L.append
    add("## Which mechanism gains from the overlap? Each method − Mono2, paired over seeds\n")
    add("Mono2 uses no overlap; each other row uses it one way (FSM: photometric terms between cameras in "
        "training only; SurroundDepth: attention between cameras at inference; MCDP: warped neighbour features "
        "weighting depth bases at inference). Median-scaled abs_rel and Dep Con (the paper's ratio mean "
        "|D − D̂| / D_gt), mean difference over seeds ± 95 % t half-width; **bold** = beyond the interval "
        "(negative = better than Mono2). *As trained − cut* (all px) is what the network takes from the other "
        "cameras at inference; for a network that never reads them it is 0 by construction.\n")
    if len(results["seeds"]) < 2:
        add("One seed only: no interval, no verdict.\n")
        return "\n".join(L)
    diffs, cuts, change = _table(results, methods, evs, label, add)
    add("")
    add("### Verdicts: which mechanism gains from overlap, and from which overlap on\n")
    for m in methods:
        acc = from_which_overlap(diffs[m]["median.mean.abs_rel"])
        non = from_which_overlap(diffs[m]["median.non_overlap.abs_rel"])
        dc = from_which_overlap(diffs[m]["dep_con.mean"])
        inf = _reads_others(cuts[m], change[m]) if cuts[m] else "reads no other camera at inference (by construction)"
        add(f"- **{label(m)}**: accuracy vs Mono2 {acc}; on non-overlap pixels {non}; Dep Con {dc}; {inf}.")
    gainers = [label(m) for m in methods if "from overlap" in from_which_overlap(diffs[m]["median.mean.abs_rel"])]
    add("- **In one line**: " + (", ".join(gainers) + " gain(s) accuracy over Mono2 from some overlap on"
                                 if gainers else "no mechanism is more accurate than Mono2 from any overlap on")
        + " (median-scaled abs_rel, all pixels, beyond the paired 95 % interval).")
    add("")
    add("Per overlap, every paired comparison in words:\n")
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            add(f"- overlap {o:.2f}, {label(m)} − Mono2: "
                + "; ".join(f"{name} {_pd(diffs[m][key][o], 3, word=True)}" for key, name in KEYS))
    add("")
    return "\n".join(L)


def _table(results: dict, methods: list[str], evs: list[Evaluation], label, add) -> tuple[dict, dict, dict]:
    """The table (one row per overlap and method, through `add`); returns its paired differences vs Mono2
    ({method: {key: {overlap: pd}}}), as trained − cut ({method: {overlap: pd}}) and the mean depth change
    when cut ({method: {overlap: m}})."""
    meas = {d["overlap"]: d["measured"]["measured_mean"] for d in results["data"]}
    add("| overlap | measured | Method | " + " | ".join(name for _, name in KEYS)
        + " | as trained − cut | mean abs(trained − cut) depth, m |")
    add("|---|---|---|" + "---|" * (len(KEYS) + 2))
    diffs: dict[str, dict[str, dict[float, dict]]] = {m: {k: {} for k, _ in KEYS} for m in methods}
    cuts: dict[str, dict[float, dict]] = {m: {} for m in methods}
    change: dict[str, dict[float, float]] = {m: {} for m in methods}
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            cells = []
            for key, _ in KEYS:
                pd = paired_difference(results, o, m, BASELINE, key)
                diffs[m][key][o] = pd
                cells.append(_pd(pd))
            if Evaluation(m, CUT) in evs:
                cuts[m][o] = paired_difference(results, o, m, Evaluation(m, CUT), "median.mean.abs_rel")
                cut = _pd(cuts[m][o], 4, floor=USE_FLOOR)
                ch = method_agg(results, o, m, "cut.depth_change_m")
                change[m][o] = ch.get("mean", math.nan)
                moved = _num(ch.get("mean"), 4) + (f" ± {_num(ch.get('ci95'), 4)}" if ch.get("n", 0) > 1 else "")
            else:
                cut, moved = "0 (reads no other camera)", "0"
            add(f"| {o:.2f} | {_num(meas.get(o))} | {label(m)} | " + " | ".join(cells) + f" | {cut} | {moved} |")
    return diffs, cuts, change


def _reads_others(cuts: dict[float, dict], change: dict[float, float]) -> str:
    """The verdict's clause on a network that reads the other cameras: how much cutting them moves its depth,
    and whether its accuracy depends on them (as trained − cut per overlap: `cuts`; depth change: `change`)."""
    used = [o for o, pd in sorted(cuts.items()) if pd["differs"] != 0 and abs(pd["mean"]) >= USE_FLOOR]
    moved = [v for v in change.values() if math.isfinite(v)]
    if not moved:
        depth = "how much cutting them changes its depth was not recorded"
    elif max(moved) < INERT_M:
        depth = (f"**its depth barely reads the other cameras**: cutting them changes it by {min(moved):.4f} "
                 f"to {max(moved):.4f} m on average (< {INERT_M * 100:.0f} cm: inert)")
    else:
        depth = (f"its depth reads the other cameras: cutting them changes it by {min(moved):.4f} to "
                 f"{max(moved):.4f} m on average")
    acc_use = ("and its accuracy with them differs from without (as trained − cut beyond the interval and >= "
               f"{USE_FLOOR}) at " + ", ".join(f"{o:.2f}" for o in used) if used else
               f"**{'and' if moved and max(moved) < INERT_M else 'but'} its accuracy does not depend on them** "
               "(as trained − cut within the interval or below "
               f"{USE_FLOOR} at every overlap)")
    return f"{depth}, {acc_use}"
