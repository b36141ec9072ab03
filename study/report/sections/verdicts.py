"""The report's one verdict section: every verdict line of a sweep's report.md in one place, read from the same
paired differences as the tables below it (`study.report.sections.mechanisms.paired_all`, `study.results.summary`).

- the primary comparisons' headline, for a sweep that names them (`study.report.sections.primary.headline`);
- each mechanism against Mono2, where it is more accurate, on non-overlap pixels, more consistent, and what it
  takes from the other cameras at inference; then the same in metric scaling (`METRIC_KEYS`), where it is better
  and where worse, so every scaling the report tabulates for the methods stands in a verdict; a row that reads ground truth (`study.report.sections.mechanisms.is_yardstick`) is a
  yardstick and stands in no verdict;
- "In one line": where each mechanism is more accurate than Mono2 ("at 0.30 only", "from overlap 0.30 on") and
  where it is less accurate, in either scaling;
- how many paired comparisons these verdicts rest on, each at 95 % and uncorrected, against how many a world
  without any difference would put beyond the interval by chance (5 %);
- each method against the yardsticks (constant depth, flat-road prior) and, in metric scaling, Mono2.

Every other section of the report gives tables and, per overlap, its comparisons in words; none is titled a verdict.
"""
from __future__ import annotations

import math

from mcdp.methods import label as method_label
from study.report.sections.mechanisms import KEYS, NOWHERE, from_which_overlap, is_yardstick, paired_all, verdict_line
from study.results.paired import paired_gain
from study.results.summary import BASELINE, PAIRED_PLOT, SCALE_LABEL, fmt_diff, gain_word, method_agg, yardstick_agg

#: the per-comparison level of every interval in the report
ALPHA = 0.05
#: (results key, name) of the metric-scaling comparisons with Mono2 that the verdicts read beside `KEYS`
METRIC_KEYS = (("none.mean.abs_rel", "metric abs_rel, all px"), ("none.non_overlap.abs_rel", "metric, non-overlap px"))


def format_verdicts(results: dict, label) -> str:
    """Markdown: the section ``## Verdicts``."""
    base = method_label(BASELINE)
    L = ["## Verdicts\n", "Every verdict of this report; the sections below give the numbers they read. They cover "
         "both scalings the report tabulates for the methods, median-scaled and metric (unscaled) abs_rel, and Dep "
         "Con (unscaled); the primary comparisons also read `rig_median`. Every difference is a gain, worse minus "
         f"better: positive = helps. A method is better or worse than {base} only where the paired 95 % interval "
         "excludes 0.\n"]
    from study.report.sections.primary import has_control, headline

    if has_control(results):
        L.append(f"- **Primary comparisons** (the section above): {headline(results)}.")
    L += mechanism_lines(results, label)
    L += ["", f"Against the yardsticks (abs_rel, mean over seeds) and, in metric scaling, {base} (paired over seeds):\n",
          yardstick_lines(results)]
    return "\n".join(L) + "\n"


def mechanism_lines(results: dict, label) -> list[str]:
    """Each mechanism's line, the line "In one line" and the multiple-comparison note; [] without Mono2, a second
    method or a second seed."""
    methods = [m for m in results["methods"] if m != BASELINE]
    if BASELINE not in results["methods"] or not methods or len(results["seeds"]) < 2:
        return []
    mech = [m for m in methods if not is_yardstick(results, m)]
    base = method_label(BASELINE)
    diffs, cuts, change = paired_all(results, methods)
    metric = {m: {key: {d["overlap"]: paired_gain(results, d["overlap"], BASELINE, m, key)
                        for d in results["data"]} for key, _ in METRIC_KEYS} for m in mech}
    L = [verdict_line(m, diffs[m], cuts[m], change[m], label)[:-1] + "; " + _metric_clause(metric[m]) + "."
         for m in mech]
    yard = [label(m) for m in methods if m not in mech]
    if yard:
        L.append(f"- {', '.join(yard)}: reads ground truth, a yardstick, not a mechanism: in the tables only.")
    if not mech:
        return L
    if mech:
        where = {m: from_which_overlap(diffs[m]["median.mean.abs_rel"]).split("; worse")[0] for m in mech}
        better = [f"{label(m)} {w}" for m, w in where.items() if w != NOWHERE]
        never = [label(m) for m, w in where.items() if w == NOWHERE]
        worse = [f"{label(m)} at {_at(pds)} ({name})" for m in mech
                 for key, name in (("median.mean.abs_rel", "median"), ("none.mean.abs_rel", "metric"))
                 for pds in [diffs[m][key] if key in diffs[m] else metric[m][key]] if _at(pds)]
        L.append("- **In one line**: " + (f"more accurate than {base}: " + "; ".join(better) if better else
                                          f"no mechanism is more accurate than {base} at any overlap")
                 + (f"; at no overlap: {', '.join(never)}" if better and never else "")
                 + " (median-scaled abs_rel, all pixels, beyond the paired 95 % interval); less accurate than "
                 + f"{base} (all pixels, either scaling): " + ("; ".join(worse) if worse else "none") + ".")
    both = {m: {**diffs[m], **metric[m]} for m in mech}
    keys = [k for k in [k for k, _ in KEYS] + [k for k, _ in METRIC_KEYS]  # the measures the sweep recorded
            if any(pd.get("n") for m in mech for pd in both[m][k].values())]
    n = sum(1 for m in mech for key in keys for o in both[m][key])
    hits = sum(1 for m in mech for key in keys for pd in both[m][key].values() if pd["differs"])
    L.append(f"- **Multiple comparisons**: these lines read {n} paired comparisons with {base} "
             f"({len(mech)} mechanism(s) x {len(results['data'])} overlap(s) x {len(keys)} measures), each at 95 % and "
             f"not corrected for the others: were no mechanism different from {base}, about {ALPHA * n:.1f} of them would "
             f"fall beyond their interval by chance; {hits} do. A single 'at x only' is weak evidence on its own.")
    return L


def yardstick_lines(results: dict) -> str:
    """The verdict lines: each method against the yardsticks (their single numbers, so the mean over seeds), and
    against Mono2 only through paired differences and their 95 % interval (`verdict_word`), never raw means: in
    median scaling those are the lines of the mechanisms' section (`study.report.sections.mechanisms`), in metric scaling here."""
    methods = results["methods"]
    base = method_label(BASELINE)
    others = [m for m in methods if m != BASELINE and not is_yardstick(results, m)]
    lines = []
    paired = BASELINE in methods and others and len(results["seeds"]) > 1
    for d in results["data"]:
        o = d["overlap"]
        for sc in ("none", "median"):
            head = f"- overlap {o:.2f}, {SCALE_LABEL[sc]}: "
            cref = yardstick_agg(results, o, f"{sc}.mean.abs_rel")["mean"]
            pref = yardstick_agg(results, o, f"{sc}.mean.abs_rel", "prior")["mean"]
            if sc == "median" and math.isfinite(cref) and math.isfinite(pref):
                means = {m: method_agg(results, o, m, f"{sc}.mean.abs_rel")["mean"] for m in methods}
                short = [f"{method_label(m)} {v:.3f}" for m, v in means.items() if not (v <= 0.5 * cref and v < pref)]
                lines.append(head + (f"**not all methods reach <= 0.5 x constant ({0.5 * cref:.3f}) and below the "
                                     f"flat-road prior ({pref:.3f})**: " + ", ".join(short) if short else
                                     f"every method (mean over seeds) is at <= 0.5 x constant ({0.5 * cref:.3f}) "
                                     f"and below the flat-road prior ({pref:.3f}); worst "
                                     f"{max(means.values()):.3f}"))
            if math.isfinite(cref):
                worse = [method_label(m) for m in methods
                         if not method_agg(results, o, m, f"{sc}.mean.abs_rel")["mean"] < cref]
                lines.append(head + (f"**not better than the constant-depth reference** ({cref:.3f}): "
                                     + ", ".join(worse) if worse else
                                     f"every method beats the constant-depth reference ({cref:.3f})"))
            if paired and sc == "none":
                cells = []
                for m in others:
                    pa = paired_gain(results, o, BASELINE, m, f"{sc}.mean.abs_rel")
                    pn = paired_gain(results, o, BASELINE, m, f"{sc}.non_overlap.abs_rel")
                    cells.append(f"{method_label(m)} {fmt_diff(pa)}: {gain_word(pa)} (non-overlap px "
                                 f"{fmt_diff(pn)}: {gain_word(pn)})")
                lines.append(head + f"{base} − each method (positive = helps), paired over seeds: " + "; ".join(cells))
    if BASELINE not in methods:
        lines.append(f"- {base} is not part of this sweep: no comparison with it.")
    elif not others:
        lines.append(f"- Only {base} is part of this sweep: no comparison with it.")
    elif paired:
        lines.append(f"- Against {base} in median scaling: the lines above (and {PAIRED_PLOT}); a method is said "
                     f"to be better or worse than {base} only where the paired 95 % interval excludes 0.")
    if len(results["seeds"]) == 1:
        lines.append(f"- One training seed only: no paired interval, so no verdict against {base}; differences smaller "
                     "than the seed-to-seed spread (unknown here) are not evidence either way.")
    return "\n".join(lines)


def _at(pds: dict[float, dict]) -> str:
    """The overlaps where a gain over Mono2 is negative beyond its interval (the method is worse), '' if none."""
    return ", ".join(f"{o:.2f}" for o, pd in sorted(pds.items()) if pd["differs"] < 0)


def _metric_clause(metric: dict[str, dict[float, dict]]) -> str:
    """A mechanism's verdict in metric scaling: where it is better and where worse than Mono2, with the numbers of
    every comparison beyond its interval (`METRIC_KEYS`: Mono2 − method, positive = helps)."""
    parts = []
    for key, name in METRIC_KEYS:
        where = from_which_overlap(metric[key])
        hits = [f"{fmt_diff(pd)} at {o:.2f}" for o, pd in sorted(metric[key].items()) if pd["differs"]]
        parts.append(f"{name} more accurate {where}" + (f" ({', '.join(hits)})" if hits else ""))
        if any(pd["differs"] < 0 for pd in metric[key].values()):
            parts[-1] = "**" + parts[-1] + "**"
    return "in metric scaling: " + "; ".join(parts)
