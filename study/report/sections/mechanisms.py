"""The report's comparison of the mechanisms that use the cameras' overlap, each against Monodepth2.

The paper's Table 1 rows are three ways of using the overlap: FSM (``fsm``: photometric constraints
between cameras in training only), a SurroundDepth-style network (``surround``: geometry-free
attention between cameras at inference) and MCDP (``mcdp_*``: geometry-aware refinement at
inference). Mono2 uses no overlap at all, so *Mono2 − method*, paired over seeds, is what a
mechanism gains from the overlap at a given overlap; *cut − as trained* is what it takes from the
other cameras at inference (0 by construction for a network that never reads them). Every difference is a gain,
worse minus better: positive = helps, the one sign of every page.

Where a method is better than Mono2 (`from_which_overlap`): **at every overlap of the sweep**; **from overlap x
on** when its gain over Mono2 is positive beyond the paired 95 % interval at x and at every larger overlap, at least two of
them; **at x only** (or at x and y only) otherwise; **at no overlap of the sweep** when it never is; in a sweep of
one overlap, **at overlap x**. The
verdict lines themselves are in the report's one verdict section (`study.report.sections.verdicts`). A row that reads ground truth
(an ORACLE, `is_yardstick`) is a yardstick: it is in the table, never among the mechanisms' verdicts. Read from
`study.results.summary` only (nothing computed from raw files here).
"""
from __future__ import annotations

import math

from study.results.paired import paired_gain
from study.sweep.probes import INERT_M
from study.results.summary import BASELINE, USE_FLOOR, evaluations, fmt_diff, gain_word, method_agg
from study.results.summary import fmt_num as _num
from study.sweep.variants import Evaluation, cut

#: (results key, column name) of the paired comparisons against Mono2
#: `from_which_overlap` of a method better than Mono2 nowhere
NOWHERE = "at no overlap of the sweep"
KEYS = (("median.mean.abs_rel", "accuracy, all px"), ("median.overlap.abs_rel", "overlap px"),
        ("median.non_overlap.abs_rel", "non-overlap px"), ("dep_con.mean", "Dep Con (ratio)"))


def _pd(pd: dict, digits: int = 3, word: bool = False, floor: float = 0.0) -> str:
    """'mean ± half-width', with its verdict word, or in bold when beyond the interval (and not below `floor`)."""
    s = fmt_diff(pd, digits)
    if word:
        s += f": {gain_word(pd, floor)}"
    elif pd["differs"] and abs(pd["mean"]) >= floor:
        s = f"**{s}**"
    return s


def from_which_overlap(diffs: dict[float, dict]) -> str:
    """Where a method is better than Mono2, from {overlap: its gain over Mono2 (Mono2 − method, positive =
    helps)}: 'at every overlap of the sweep', 'from overlap x on' (x and at least one larger overlap, every one of
    them), 'at x only' / 'at x and y only', 'at overlap x' when the sweep has that one overlap, or 'at no overlap
    of the sweep'; then where it is worse, if anywhere."""
    xs = sorted(diffs)
    better = [o for o in xs if diffs[o]["differs"] > 0]
    worse = [o for o in xs if diffs[o]["differs"] < 0]
    tail = "; worse at " + _overlaps(worse) if worse else ""
    if not better:
        return NOWHERE + tail
    if len(xs) == 1:
        return f"at overlap {xs[0]:.2f}" + tail
    if better == xs:
        return "at every overlap of the sweep" + tail
    if len(better) >= 2 and better == xs[len(xs) - len(better):]:
        return f"from overlap {better[0]:.2f} on" + tail
    return f"at {_overlaps(better)} only" + tail


def _overlaps(xs: list[float]) -> str:
    return _join([f"{o:.2f}" for o in xs])


def _join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def is_yardstick(results: dict, m: str) -> bool:
    """A row that reads ground truth: its network reads an input field that holds it (``reads_ground_truth()``, ORACLE-local) or its
    scale comes from it (an ORACLE run, ``scale.source=oracle_gt_median``). A yardstick, never a mechanism."""
    from mcdp.methods import METHODS, network_class

    if any(r.get("oracle") for r in results.get("rows", []) if r.get("method") == m):
        return True
    return m in METHODS and network_class(METHODS[m]).reads_ground_truth()


def paired_all(results: dict, methods: list[str]) -> tuple[dict, dict, dict]:
    """Each method against Mono2 per overlap, every difference a gain (worse minus better, positive = helps):
    ({method: {key of `KEYS`: {overlap: Mono2 − method}}}, cut − as trained ({method: {overlap: pd}}, reading
    methods only) and the mean depth change when cut ({method: {overlap: m}})."""
    evs, c = evaluations(results), cut()
    diffs: dict[str, dict[str, dict[float, dict]]] = {m: {k: {} for k, _ in KEYS} for m in methods}
    cuts: dict[str, dict[float, dict]] = {m: {} for m in methods}
    change: dict[str, dict[float, float]] = {m: {} for m in methods}
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            for key, _ in KEYS:
                diffs[m][key][o] = paired_gain(results, o, BASELINE, m, key)
            if c is not None and Evaluation(m, c) in evs:
                cuts[m][o] = paired_gain(results, o, Evaluation(m, c), m, "median.mean.abs_rel")
                change[m][o] = method_agg(results, o, m, "cut.depth_change_m").get("mean", math.nan)
    return diffs, cuts, change


def verdict_line(m: str, diffs: dict, cuts: dict, change: dict, label) -> str:
    """One method's verdict against Mono2 (`paired_all`'s entries for it)."""
    acc = from_which_overlap(diffs["median.mean.abs_rel"])
    non = from_which_overlap(diffs["median.non_overlap.abs_rel"])
    dc = from_which_overlap(diffs["dep_con.mean"])
    inf = _reads_others(cuts, change) if cuts else "reads no other camera at inference (by construction)"
    return (f"- **{label(m)}**: more accurate than Mono2 {acc}; on non-overlap pixels {non}; more consistent "
            f"(Dep Con) {dc}; {inf}.")


def format_mechanisms(results: dict, label) -> str:
    """Markdown: Mono2 − each method per overlap (accuracy, overlap / non-overlap px, Dep Con, cut) and
    the verdict lines; '' without Mono2 or a second method."""
    methods = [m for m in results["methods"] if m != BASELINE]
    if BASELINE not in results["methods"] or not methods:
        return ""
    evs = evaluations(results)
    L: list[str] = []
    add = L.append
    add("## Which mechanism gains from the overlap? Mono2 − each method, paired over seeds\n")
    add("Mono2 uses no overlap; each other row uses it one way (FSM: photometric terms between cameras in "
        "training only; SurroundDepth: attention between cameras at inference; MCDP: warped neighbour features "
        "weighting depth bases at inference). Median-scaled abs_rel and Dep Con (the paper's ratio mean "
        "|D − D̂| / D_gt), Mono2 − method, mean over seeds ± 95 % half-width" + interval_note(results) + "; "
        "**bold** = beyond the interval; **positive = helps** (worse minus better, the page's one sign). *Cut − "
        "as trained* (all px) is what the network takes from the other cameras at inference; for a network that "
        "never reads them it is 0 by construction.\n")
    yard = [label(m) for m in methods if is_yardstick(results, m)]
    if yard:
        add(f"{_join(yard)} read{'s' if len(yard) == 1 else ''} ground truth: a yardstick of what the overlap could "
            "give, not a mechanism; in the table, never among the verdicts.\n")
    if len(results["seeds"]) < 2:
        add("One seed only: no interval, no verdict.\n")
        return "\n".join(L)
    diffs, _, _ = _table(results, methods, evs, label, add)
    add("")
    add("The verdicts: section 'Verdicts' above.\n")
    add("Per overlap, every paired comparison in words:\n")
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            add(f"- overlap {o:.2f}, Mono2 − {label(m)}: "
                + "; ".join(f"{name} {_pd(diffs[m][key][o], 3, word=True)}" for key, name in KEYS))
    add("")
    return "\n".join(L)


def _table(results: dict, methods: list[str], evs: list[Evaluation], label, add) -> tuple[dict, dict, dict]:
    """The table (one row per overlap and method, through `add`); returns `paired_all`'s differences."""
    meas = {d["overlap"]: d["measured"]["measured_mean"] for d in results["data"]}
    add("| overlap | measured | Method | " + " | ".join(name for _, name in KEYS)
        + " | cut − as trained | mean abs(trained − cut) depth, m |")
    add("|---|---|---|" + "---|" * (len(KEYS) + 2))
    diffs, cuts, change = paired_all(results, methods)
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            cells = [_pd(diffs[m][key][o]) for key, _ in KEYS]
            if o in cuts[m]:
                cut = _pd(cuts[m][o], 4, floor=USE_FLOOR)
                ch = method_agg(results, o, m, "cut.depth_change_m")
                moved = _num(ch.get("mean"), 4) + (f" ± {_num(ch.get('ci95'), 4)}" if ch.get("n", 0) > 1 else "")
            else:
                cut, moved = "0 (reads no other camera)", "0"
            add(f"| {o:.2f} | {_num(meas.get(o))} | {label(m)} | " + " | ".join(cells) + f" | {cut} | {moved} |")
    return diffs, cuts, change


def _reads_others(cuts: dict[float, dict], change: dict[float, float]) -> str:
    """The verdict's clause on a network that reads the other cameras: how much cutting them moves its depth,
    and whether its accuracy depends on them (cut − as trained per overlap: `cuts`; depth change: `change`)."""
    used = [o for o, pd in sorted(cuts.items()) if pd["differs"] != 0 and abs(pd["mean"]) >= USE_FLOOR]
    moved = [v for v in change.values() if math.isfinite(v)]
    if not moved:
        depth = "how much cutting them changes its depth was not recorded"
    elif max(moved) < INERT_M:
        depth = (f"**its depth barely reads the other cameras**: cutting them changes it by {_span(moved)} m on "
                 f"average (< {INERT_M * 100:.0f} cm: inert)")
    else:
        depth = f"its depth reads the other cameras: cutting them changes it by {_span(moved)} m on average"
    acc_use = ("and its accuracy with them differs from without (cut − as trained beyond the interval and >= "
               f"{USE_FLOOR}) at " + ", ".join(f"{o:.2f}" for o in used) if used else
               f"**{'and' if moved and max(moved) < INERT_M else 'but'} its accuracy does not depend on them** "
               "(cut − as trained within the interval or below "
               f"{USE_FLOOR} " + ("at every overlap)" if len(cuts) > 1 else f"at {_overlaps(sorted(cuts))})"))
    return f"{depth}, {acc_use}"


def _span(values: list[float]) -> str:
    """'a to b' of the values (4 decimals), or the one value when they all round to it."""
    lo, hi = f"{min(values):.4f}", f"{max(values):.4f}"
    return lo if lo == hi else f"{lo} to {hi}"


def interval_note(results: dict) -> str:
    """How the page's paired intervals are taken (`study.results.paired.paired_columns`)."""
    from study.results.paired import clustered

    return (" (clustered by world, as the primary comparisons: t over the world means)" if clustered(results)
            else " (t over the seeds)")
