"""The report's section on the paper's claim itself: does MCDP's refinement act, use the neighbours,
and carry what it sees in the overlap to the rest of the image?

Read from `study.results.summary` (nothing is computed from raw files here). Per MCDP run with refinement
the sweep evaluates the same checkpoint twice (`study.sweep.stages.evaluate_run`): as trained, and with
its neighbours cut at inference (variant ``cut``, `study.sweep.variants`); and it fits the ORACLE weights of
the run's own bases to ground truth (variant ``oracle``). Hence, per overlap and method, paired over seeds:

- **propagation** = cut - as trained on NON-overlap pixels (median-scaled abs_rel; positive = the
  neighbours help where they are not seen: worse minus better, the one sign of every page), **direct use** = the
  same on overlap pixels;
- **refinement gain** = init - final stage of the same network (positive = the refinement helps);
- **headroom closed** = (init - final) / (init - ORACLE): the fraction of what the bases could gain
  with perfect per-image weights that the weight networks found;
- **acting**: mean |w - 1/n| of the refined weights and mean |refined - init| depth; a run whose
  refined depth moves < 1 cm from init on average is flagged INERT (like a collapsed run).
"""
from __future__ import annotations

import math

from study.results.paired import paired_columns, paired_gain
from study.sweep.probes import INERT_M
from study.results.summary import USE_FLOOR, evaluations, flat_of, fmt_diff, gain_word, method_agg
from study.results.summary import fmt_num as _num
from study.report.sections.mechanisms import interval_note
from study.sweep.variants import Evaluation, cut, having

def refined_methods(results: dict) -> list[str]:
    """Methods of the sweep that were also evaluated with their neighbours cut."""
    evs, c = evaluations(results), cut()
    return [m for m in results["methods"] if c is not None and Evaluation(m, c) in evs]


def _pd(pd: dict, digits: int = 3, floor: float = 0.0) -> str:
    return f"{fmt_diff(pd, digits)}: {gain_word(pd, floor)}"


def _cut_diff(results: dict, o: float, m: str, key: str) -> dict:
    """Cut - as trained: what reading the other cameras gains (positive = helps)."""
    return paired_gain(results, o, Evaluation(m, cut()), m, key)


def _self_diff(results: dict, o: float, m: str, a: str, b: str) -> dict:
    """Paired over seeds (clustered by world where the design has worlds): column a - column b of the same run
    (e.g. init - final)."""
    return paired_columns(results, o, (m, a), (m, b))


def inert_runs(results: dict) -> list[str]:
    """'overlap/method/seed' of every run whose refinement is inert (refined depth < 1 cm from init)."""
    return [f"{f['overlap']:.2f}/{f['method']}/s{f['seed']}" for f in results["flat"]
            if f.get("refine.inert") is True]


def format_propagation(results: dict, label) -> str:
    """Markdown: acting table, propagation verdicts, headroom; '' when no run was evaluated cut."""
    methods = refined_methods(results)
    if not methods:
        return ""
    L: list[str] = []
    add = L.append
    add("## Does the refinement act, use the neighbours, and propagate?\n")
    add("Every run whose network reads the other cameras at inference (MCDP with refinement, SurroundDepth) is "
        "evaluated twice on the same checkpoint: as trained and with its neighbours **cut** at inference (MCDP: "
        "the weight networks see zeros and valid = 0 for both neighbours, as a camera without neighbours; "
        "SurroundDepth: attention within each camera only). *As trained − cut* on **non-overlap** pixels is the propagation the paper "
        "claims; on overlap pixels it is the direct use. **ORACLE** = the run's own bases at per-image weights "
        "fitted to ground truth (scale-invariant log error, 100 Adam steps on the n logits): the best its bases "
        "can express, a yardstick that reads ground truth. Median-scaled abs_rel; mean over seeds ± 95 % "
        "t half-width; differences are paired over seeds" + interval_note(results) + " and taken worse minus "
        "better: **positive = helps** (cut − as trained, init − final).\n")
    c, ceilings = cut(), having("ceiling")  # the cut, and a column per ceiling (a yardstick of the bases)
    add(f"| overlap | Method | init | final | {c} | " + "".join(f"{v.short} | " for v in ceilings)
        + "headroom closed | mean abs(w − 1/n) | mean abs(refined − init) m | inert runs |")
    add("|---|---|---|---|---|" + "---|" * len(ceilings) + "---|---|---|---|")
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            fr = flat_of(results, o, m)
            n_inert = sum(1 for f in fr if f.get("refine.inert") is True)
            add(f"| {o:.2f} | {label(m)} | {_a(results, o, m, 'init.median.mean.abs_rel')} | "
                f"{_a(results, o, m, 'median.mean.abs_rel')} | "
                f"{_a(results, o, Evaluation(m, c), 'median.mean.abs_rel')} | "
                + "".join(f"{_a(results, o, Evaluation(m, v.name), 'median.mean.abs_rel')} | " for v in ceilings)
                + f"{_a(results, o, m, 'refine.headroom_closed', 2)} | "
                f"{_a(results, o, m, 'refine.weight_move', 4)} | {_a(results, o, m, 'refine.depth_change_m', 3)} | "
                f"{n_inert}/{len(fr)} |")
    add("")
    inert = inert_runs(results)
    add(f"**Inert refinements** (refined depth < {INERT_M * 100:.0f} cm from init on average): "
        + (", ".join(inert) if inert else "none") + ".\n")
    if len(results["seeds"]) < 2:
        add("One seed only: no interval, no verdict.\n")
        return "\n".join(L)
    add("### Per overlap, in words: propagation and refinement\n")
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            prop = _cut_diff(results, o, m, "median.non_overlap.abs_rel")
            direct = _cut_diff(results, o, m, "median.overlap.abs_rel")
            allp = _cut_diff(results, o, m, "median.mean.abs_rel")
            dc = _cut_diff(results, o, m, "dep_con.mean")
            gain = _self_diff(results, o, m, "init.median.mean.abs_rel", "median.mean.abs_rel")
            closed = method_agg(results, o, m, "refine.headroom_closed")
            refine = (f"; refinement init − final {_pd(gain, 4, USE_FLOOR)}; headroom closed {_num(closed['mean'], 2)}"
                      if math.isfinite(gain["mean"]) else "")  # a network without an init stage: no refinement
            add(f"- overlap {o:.2f}, {label(m)}: propagation (cut − as trained, non-overlap px) "
                f"{_pd(prop, 4, USE_FLOOR)}; direct use (overlap px) {_pd(direct, 4, USE_FLOOR)}; all px "
                f"{_pd(allp, 4, USE_FLOOR)}; Dep Con (ratio) {_pd(dc, 4, USE_FLOOR)}" + refine)
    add("")
    return "\n".join(L)


def _a(results: dict, o: float, m: str | Evaluation, key: str, digits: int = 3) -> str:
    a = method_agg(results, o, m, key)
    mu, hw = a.get("mean", math.nan), a.get("ci95", math.nan)
    if not (isinstance(mu, (int, float)) and math.isfinite(mu)):
        return "—"
    return f"{mu:.{digits}f}" + (f" ± {hw:.{digits}f}" if isinstance(hw, float) and math.isfinite(hw) else "")
