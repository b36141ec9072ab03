"""What the camera as a sensor does to cross-camera consistency (issue 48, item 7; docs/results/sensor.md).

Each condition is one sweep of configs/sweep/cpu_sensor.yaml (the ideal camera, and the same worlds rendered
with a sensor knob on); conditions share the worlds' geometry, the pretraining and the training seeds, so each
method's change is paired by world and follows the project's one sign convention (docs/DESIGN.md): **ideal -
condition, positive = the condition helps** (abs_rel and Dep Con are both lower-is-better, so a condition that
hurts reads negative). Read over the worlds: the mean with its 95 % t interval and the MDE at 80 % power
(`study.stats.power`). The paper's argument, tested directly: FSM's photometric loss between cameras suffers from a
brightness change and MCDP's depth comparison does not, so MCDP's change minus FSM's change, paired by world,
is given with its interval: positive = MCDP (the candidate) suffers less (the same number as FSM's extra cost).

Read from `study.results.summary` only: each condition's results.json (the flat rows of the as-trained evaluation).
"""
from __future__ import annotations

import math

from mcdp.methods import short_label
from study.stats.design import reading_over_worlds
from study.results.summary import flat_of, fmt_diff

#: what the sensor sweeps were analysed with before their plan held it (`study.report.sections.primary.plan_of`'s page defaults):
#: the pair whose changes are compared, [base, changed] (the photometric cross-camera loss against the depth one;
#: the contrast is the changed arm's change - the base arm's, positive = the changed arm suffers less), on all pixels
PLAN_DEFAULTS = {"arms": ["fsm", "mcdp_m2"], "region": "all"}
#: the figures compared (flat-row keys), each lower-is-better, at the default plan: the primary figure (the plan's
#: metric, scaling and region: `figures`) and cross-camera consistency, a secondary one
FIGURES = (("median.mean.abs_rel", "abs_rel (median)"), ("dep_con.mean", "Dep Con"))
CONTRAST = tuple(PLAN_DEFAULTS["arms"])


def plan(results: dict) -> dict:
    """The sensor sweep's plan (`study.report.sections.primary.plan_of` with `PLAN_DEFAULTS`)."""
    from study.report.sections.primary import plan_of

    return plan_of(results, PLAN_DEFAULTS)


def figures(results: dict) -> tuple[tuple[str, str], ...]:
    """(flat-row key, label) of the primary figure (the plan's) and of Dep Con."""
    from study.report.sections.primary import primary_key

    p = plan(results)
    return (primary_key(p), f"{p['metric']} ({p['scaling']})"), FIGURES[1]


def contrast_arms(results: dict) -> tuple[str, str]:
    """(base, changed): the plan's arms."""
    a, b = plan(results)["arms"]
    return a, b


def _by_world(results: dict, method: str, key: str) -> dict:
    """{world: value} of one method's as-trained runs at the plan's overlap (`plan`; the row's ``world``, else its
    seed)."""
    o = plan(results)["overlap"]
    out = {}
    for f in flat_of(results, o, method):
        v = f.get(key)
        if f.get("status", "ok") == "ok" and isinstance(v, (int, float)) and math.isfinite(v):
            out[f.get("world", f["seed"])] = float(v)
    return out


def _over_worlds(diffs: dict) -> dict:
    """`study.stats.design.reading_over_worlds` of one paired difference per world (no equivalence bound: the sensor
    study states none)."""
    return reading_over_worlds({w: [diffs[w]] for w in sorted(diffs)}, {})


def _diffs(ideal: dict, cond: dict, method: str, key: str) -> dict:
    """{world: ideal - cond} of one method and figure (lower-is-better: positive = the condition helps), over the
    worlds both have."""
    a, b = _by_world(ideal, method, key), _by_world(cond, method, key)
    return {w: a[w] - b[w] for w in set(a) & set(b)}


def change(ideal: dict, cond: dict, method: str, key: str) -> dict:
    """`study.stats.design.reading_over_worlds` of ideal - cond (positive = the condition helps) for one method and
    figure, paired by world, with the ideal's mean (``ideal``)."""
    n = _over_worlds(_diffs(ideal, cond, method, key))
    b = _by_world(ideal, method, key)
    n["ideal"] = math.fsum(b.values()) / len(b) if b else math.nan
    return n


def contrast(ideal: dict, cond: dict, key: str, pair: tuple[str, str] | None = None) -> dict:
    """(pair[1]'s change) - (pair[0]'s change), each ideal - cond, paired by world: positive = the candidate
    (pair[1]) suffers less, i.e. the reference (pair[0]) suffers more. ``pair``: default the plan's arms."""
    pair = contrast_arms(ideal) if pair is None else pair
    ca, cb = (_diffs(ideal, cond, m, key) for m in pair)
    return _over_worlds({w: cb[w] - ca[w] for w in set(ca) & set(cb)})


def _yardstick(results: dict) -> float:
    """The constant-depth reference's median-scaled abs_rel, the mean over the worlds (NaN without it)."""
    vals = []
    for d in results.get("data", []):
        for w in d.get("worlds") or [d]:
            ref = (w.get("reference") or {}).get("metrics", {}).get("median", {}).get("mean", {}).get("abs_rel")
            if isinstance(ref, (int, float)) and math.isfinite(ref):
                vals.append(float(ref))
    return math.fsum(vals) / len(vals) if vals else math.nan


def _cell(n: dict, marks: tuple[str, str] = ("better", "worse")) -> str:
    """The paired difference with its interval, and ``marks`` (positive, negative) where the interval excludes 0."""
    if not n.get("n_worlds"):
        return "—"
    mark = f" **({marks[0]})**" if n["differs"] == 1 else f" **({marks[1]})**" if n["differs"] == -1 else ""
    return fmt_diff(n, 4) + mark


def _pair_table(base: dict, cond: dict, methods: list[str], intro: str) -> list[str]:
    """Markdown lines: each method's change base - cond per figure (MDE in brackets), then the MCDP - FSM
    contrast with its reading on median abs_rel. ``intro``: the sentence above the table."""
    figs, pair = figures(base), contrast_arms(base)
    L = [intro + " ± the 95 % t interval over worlds, MDE at 80 % power in brackets.\n",
         "| method | " + " | ".join(label for _, label in figs) + " |",
         "|---|" + "---|" * len(figs)]
    for m in methods:
        cells = []
        for k, _ in figs:
            n = change(base, cond, m, k)
            cells.append(f"{_cell(n)} [{n['mde80']:.4f}]" if math.isfinite(n["mde80"]) else _cell(n))
        L.append(f"| {short_label(m)} | " + " | ".join(cells) + " |")
    if all(m in methods for m in pair):
        a, b = (short_label(m) for m in pair)
        L.append(f"| {b}'s change - {a}'s | " + " | ".join(
            _cell(contrast(base, cond, k), (f"{a} suffers more", f"{b} suffers more")) for k, _ in figs) + " |")
        n = contrast(base, cond, figs[0][0])
        verdict = (f"{a} suffers more than {b}, beyond the interval" if n["differs"] == 1 else
                   f"{b} suffers more than {a}, beyond the interval" if n["differs"] == -1 else
                   f"not resolved with {n['n_worlds']} worlds (detectable at {n['mde80']:.4f})")
        L.append(f"\nThe paper's argument ({a}'s photometric loss between cameras suffers, {b}'s depth "
                 f"comparison does not), on {_words(base)}: {verdict}.\n")
    else:
        L.append("")
    return L


def _words(results: dict) -> str:
    """The primary figure in words: 'median abs_rel' (all pixels), 'median abs_rel on non-overlap pixels'."""
    from study.sweep.config import region_words

    p = plan(results)
    return f"{p['scaling']} {p['metric']}" + ("" if p["region"] == "all" else f" on {region_words(p['region'])}")


def _methods(results: dict) -> list[str]:
    return [m for m in results.get("methods", []) if _by_world(results, m, figures(results)[0][0])]


def format_sensor(ideal: dict, conditions: list[tuple[str, str, dict]]) -> str:
    """Markdown: per condition (name, what it changes, results), each method's change from the ideal camera
    for every figure, and the FSM - MCDP contrast, beside the ideal's values and the constant-depth yardstick."""
    methods, figs = _methods(ideal), figures(ideal)
    L = ["| method | " + " | ".join(f"ideal {label}" for _, label in figs) + " |",
         "|---|" + "---|" * len(figs)]
    for m in methods:
        L.append(f"| {short_label(m)} | " + " | ".join(
            f"{change(ideal, ideal, m, k)['ideal']:.4f}" for k, _ in figs) + " |")
    L.append(f"\nYardstick: the constant-depth reference scores {_yardstick(ideal):.4f} (median abs_rel) on the "
             "ideal worlds.\n")
    for name, what, cond in conditions:
        L.append(f"### {name}: {what}\n")
        L += _pair_table(ideal, cond, methods, f"Constant-depth reference on these worlds: {_yardstick(cond):.4f}. "
                         "Change from the ideal camera, ideal - condition, paired by world, "
                         "**positive = the condition helps**;")
    return "\n".join(L)


def format_between(base: tuple[str, dict], cond: tuple[str, dict]) -> str:
    """Markdown: each method's change from one condition to another on the same worlds (``base - cond``, both
    given as (name, results): positive = ``cond`` helps), e.g. what ignoring the trigger offsets costs: ``sync:
    assume`` against ``compensate`` on the same rendered data. A method with no cross-camera warp should read
    exactly 0."""
    (bn, b), (cn, c) = base, cond
    return "\n".join(_pair_table(b, c, _methods(b), f"{bn} - {cn}, paired by world, **positive = {cn} helps**;"))


def _primary_line(n: dict, rank: dict, a: str, b: str) -> str:
    """The follow-up's primary reading: the t interval with its p and MDE, the rank-based reading, the verdict."""
    p = n["p"]  # two-sided t (study.stats.design.t_p_two_sided)
    lo, hi = rank["ci"]
    line = (f"**Primary: {b}'s change - {a}'s = {fmt_diff(n, 4)}** (95 % t over {n['n_worlds']} "
            f"worlds, {n['df']} df, p = {p:.3f}; detectable at 80 % power: {n['mde80']:.4f}). Rank-based: "
            f"Wilcoxon p = {rank['p']:.3f}, Hodges-Lehmann {rank['hl']:+.4f} [{lo:+.4f}, {hi:+.4f}] "
            f"({100 * rank['ci_level']:.1f} %).")
    agree = rank["p"] < 0.05
    if n["differs"] == 1:
        verdict = (f"{a} suffers more than {b} from the exposure spread, beyond the interval"
                   + ("; the rank-based reading agrees." if agree else
                      "; the rank-based reading does not reject, so a few worlds may carry it."))
    elif n["differs"] == -1:
        verdict = (f"{b} suffers more than {a}, the opposite of the paper's argument, beyond the interval"
                   + ("; the rank-based reading agrees." if agree else "; the rank-based reading does not reject."))
    else:
        verdict = (f"not resolved: {a}'s extra cost is between {n['mean'] - n['ci95']:+.4f} and "
                   f"{n['mean'] + n['ci95']:+.4f} (95 %), and a difference of {n['mde80']:.4f} would have been "
                   "seen with 80 % power.")
    return line + " " + verdict[0].upper() + verdict[1:]


def format_followup(ideal: dict, cond: dict, planned: int, what: str) -> str:
    """Markdown: the pre-planned follow-up of one condition on more worlds (``planned`` of them, stated in the
    preset's header before the runs): the primary contrast (MCDP's change - FSM's on median abs_rel) with its
    t interval, p, MDE and the rank-based reading (`study.stats.design.signed_rank`), each method's change, and the
    per-world values, so that no world is hidden behind the mean."""
    pair = contrast_arms(ideal)
    a, b = (short_label(m) for m in pair)
    key = figures(ideal)[0][0]
    n = contrast(ideal, cond, key)
    rank = n["rank"]
    L = [f"Planned before the runs (configs/sweep/cpu_sensor.yaml's header): {planned} worlds, one look at the end, "
         f"{what}. Read here: {n['n_worlds']} worlds with every run of both conditions.\n",
         _primary_line(n, rank, a, b) + "\n"]
    methods = _methods(ideal)
    L += _pair_table(ideal, cond, methods, f"Constant-depth reference on these worlds: "
                     f"{_yardstick(cond):.4f}. Change from the ideal camera, ideal - condition, paired by world, "
                     "**positive = the condition helps**;")[:-1]  # its verdict: the primary line above replaces it
    L.append("")
    per = {m: _diffs(ideal, cond, m, key) for m in methods}
    L += [f"Per world, {_words(ideal)}, ideal - condition (positive = the condition helps):\n",
          "| world | " + " | ".join(short_label(m) for m in methods) + f" | {b} - {a} |",
          "|---|" + "---|" * (len(methods) + 1)]
    for w, v in sorted(n["values"], key=lambda wv: wv[0]):
        L.append(f"| {w} | " + " | ".join(f"{per[m][w]:+.4f}" if w in per[m] else "—" for m in methods)
                 + f" | {v:+.4f} |")
    return "\n".join(L) + "\n"


def _values(base: dict, cond: dict) -> dict:
    """One pair of conditions' figures for a preface (`study.report.preface`): ``change.<method>`` and ``depcon.<method>``
    (base - cond), ``contrast`` (the plan's changed arm's change - the base arm's, with ``lo`` / ``hi``, its 95 %
    bounds, and ``hl_lo`` / ``hl_hi``, the Hodges-Lehmann interval's) and ``depcon_contrast``."""
    (key, _), (dep, _) = figures(base)
    ms = _methods(base)
    n = contrast(base, cond, key)
    lo, hi = n["rank"]["ci"]
    return {"change": {m: change(base, cond, m, key) for m in ms},
            "depcon": {m: change(base, cond, m, dep) for m in ms},
            "contrast": {**n, "lo": n["mean"] - n["ci95"], "hi": n["mean"] + n["ci95"], "hl_lo": lo, "hl_hi": hi},
            "depcon_contrast": contrast(base, cond, dep)}


def preface_values(ideal: dict, conditions: dict, followup: tuple[dict, dict] | None) -> dict:
    """The sensor page's preface values (`study.report.preface.fill`): ``<condition>`` (each of ``conditions``, {name:
    results}, against the ideal camera: `_values`), ``between`` (``sensor_trigger_compensate`` - its ``_assume``, where
    both are given: each named by its part, e.g. ``sensor_exposure``) and ``followup`` (the 14-world follow-up's ideal - exposure)."""
    out = {name: _values(ideal, r) for name, r in conditions.items() if r is not None}
    a, c = conditions.get("sensor_trigger_assume"), conditions.get("sensor_trigger_compensate")
    if a is not None and c is not None:
        out["between"] = _values(c, a)
    if followup is not None:
        out["followup"] = _values(*followup)
    return out
