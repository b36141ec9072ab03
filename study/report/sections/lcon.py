"""The L_con question (issue 47; docs/results/lcon.md): does training with the consistency loss on a small
overlap make depth better outside it?

Primary comparison (b), named in the presets' headers before their runs: MCDP (w/o L_con) cut - MCDP cut,
abs_rel on non-overlap pixels at the plan's overlap (`study.report.sections.primary.plan_of`), median scaling (with ``none`` and
``rig_median`` beside it), **positive = L_con helps**, one training seed per world, **both arms scored at one
pre-stated step** (the sweep's ``checkpoint: last``; a pair scored at two steps is said so). Read:

- over worlds: the mean with its t interval, the MDE at 80 % power, TOST against the plan's ``delta``
  (`study.stats.power`), and Wilcoxon's signed-rank test with the Hodges-Lehmann estimate and interval
  (`study.stats.design.signed_rank`), so one outlying world cannot carry the verdict alone;
- where the spread between worlds comes from: each world's bootstrap over its test sequences, the split into
  test-sampling noise and heterogeneity, and outlying worlds (`study.stats.variance`), with a forest plot;
- the sweep's ``plan`` (planned worlds, the first look), stated before the run: the two-look O'Brien-Fleming
  reading (`study.stats.design.sequential_look`).

Read from `study.results.summary` only (a results.json with per-sequence records: `mcdp.per_sequence`).
"""
from __future__ import annotations

import math
from pathlib import Path

from study.sweep.config import PLAN_REGIONS, region_words
from study.stats.design import reading_over_worlds, sequential_look, worlds_needed
from study.report.sections.primary import SCALINGS, has_control, measure, plan_of
from study.report.sections.reach import lcon_pairs, local
from study.results.summary import fmt_diff, row_evaluations
from study.sweep.worlds import data_seeds
from study.stats.variance import forest_plot, variance_split
from study.sweep.variants import Evaluation, cut

REGION = "non_overlap"
DRAWS = 2000


def lcon_arms(results: dict) -> tuple[str, str] | None:
    """(the row without L_con, the row with it): the plan's ``arms`` where the run stated them (`plan_of`), else
    the first L_con pair whose two rows the sweep trained (what a sweep recorded before the key was read with)."""
    methods = set(results.get("methods", []))
    stated = plan_of(results)["arms"]
    if stated:
        return (stated[0], stated[1]) if set(stated) <= methods else None
    for nocon, with_con in lcon_pairs():
        if nocon in methods and with_con in methods:
            return nocon, with_con
    return None


def _rows(results: dict, o: float, method: str) -> dict:
    return {r["seed"]: r for r in results["rows"] if r["method"] == method and abs(r["overlap"] - o) < 1e-9
            and r.get("status") == "ok"}


def _world(row: dict, seeds: dict):
    """The row's world: its data seed (recorded since issue 47, else from the sweep's data: `data_seeds`)."""
    w = row.get("world")
    return w if w is not None else seeds.get((row["overlap"], row["seed"]), row["seed"])


def _figure(row: dict, sc: str, region: str = REGION, metric: str = "abs_rel") -> float:
    """The row's cut evaluation at scaling ``sc``: ``metric`` on ``region`` (a metrics section: `PLAN_REGIONS`)."""
    m = (row_evaluations(row).get(cut()) or {}).get("metrics") or {}
    v = ((m.get(sc) or {}).get(region) or {}).get(metric)
    return float(v) if isinstance(v, (int, float)) else math.nan


def _per_seq(row: dict, sc: str, region: str = REGION):
    m = (row_evaluations(row).get(cut()) or {}).get("metrics") or {}
    return ((m.get(sc) or {}).get("per_sequence") or {}).get(region)


def pairs(results: dict, o: float | None = None) -> list[dict]:
    """At overlap ``o`` (default: the plan's, `study.report.sections.primary.plan_of`), per world: {"world", "seed", "steps": (arm a's, arm b's scored step), "same_step", "d": {scaling: a - b}}."""
    arms = lcon_arms(results)
    if arms is None:
        return []
    plan = plan_of(results)
    o = plan["overlap"] if o is None else o
    region, metric = PLAN_REGIONS[plan["region"]], plan["metric"]
    ra, rb = _rows(results, o, arms[0]), _rows(results, o, arms[1])
    seeds = data_seeds(results)
    out = []
    for s in sorted(set(ra) & set(rb)):
        a, b = ra[s], rb[s]
        steps = (a.get("checkpoint_step"), b.get("checkpoint_step"))
        out.append({"world": _world(a, seeds), "seed": s, "steps": steps, "same_step": steps[0] == steps[1],
                    "d": {sc: _figure(a, sc, region, metric) - _figure(b, sc, region, metric) for sc in SCALINGS},
                    "rows": (a, b), "region": region})
    return out


def levels(results: dict, ps: list[dict], sc: str) -> str:
    """The level beside (b): each arm's figure (mean over the pairs' worlds) and the yardsticks that use no
    training (a constant depth, the flat-road prior) on the same region, scaling and overlap; "" without pairs."""
    from study.results.summary import yardstick_agg

    if not ps:
        return ""
    plan = plan_of(results)
    mean = (lambda v: math.fsum(v) / len(v))
    by_world: dict = {}  # a world's mean over its seeds, as the reading clusters them
    for p in ps:
        by_world.setdefault(p["world"], []).append([_figure(r, sc, p["region"], plan["metric"]) for r in p["rows"]])
    a, b = ([mean([x[k] for x in v]) for v in by_world.values()] for k in (0, 1))
    key = f"{sc}.{PLAN_REGIONS[plan['region']]}.{plan['metric']}"
    ref, prior = (yardstick_agg(results, plan["overlap"], key, which)["mean"] for which in ("reference", "prior"))
    return (f"The arms' level: w/o L_con {mean(a):.4f}, with L_con {mean(b):.4f} ({sc} {plan['metric']} on "
            f"{region_words(plan['region'])}, mean over the {len(by_world)} worlds); the yardsticks that use no "
            f"training: a constant depth {_f(ref).lstrip('+')}, the flat-road prior {_f(prior).lstrip('+')}.")


def world_means(ps: list[dict], sc: str) -> dict:
    """{world: [its pairs' differences]} at one scaling (one pair per world unless seeds share a world)."""
    out: dict = {}
    for p in ps:
        out.setdefault(p["world"], []).append(p["d"][sc])
    return out


def reading(ps: list[dict], sc: str, plan: dict) -> dict:
    """(b) over the worlds at one scaling: `study.stats.design.reading_over_worlds` (nested, clustered by world; MDE;
    TOST against ``plan["delta"]``; the signed-rank test over the world means)."""
    return reading_over_worlds(world_means(ps, sc), plan)


def answer(n: dict) -> str:
    """The one sentence that answers (b) at one scaling, by the primary test: helps / hurts beyond the interval,
    equivalent within ±delta (the plan's, carried by the reading), or not resolved with its MDE."""
    if n["n_worlds"] < 2:
        return "Not measured (fewer than 2 worlds)"
    if n["differs"] == 1:
        return f"L_con improves non-overlap depth by {fmt_diff(n, 4)}"
    if n["differs"] == -1:
        return f"L_con makes non-overlap depth worse: {fmt_diff(n, 4)}"
    if n["tost"]["equivalent"]:
        return f"Equivalent to 0 within ±{n['delta']:g} ({fmt_diff(n, 4)}, TOST p = {n['tost']['p']:.3f})"
    return (f"Not resolved with {n['n_worlds']} worlds ({fmt_diff(n, 4)}); detectable at "
            f"{n['mde80']:.4f}")


def split_of(ps: list[dict], sc: str, draws: int = DRAWS) -> dict | None:
    """`study.stats.variance.variance_split` of (b) at one scaling, or None without per-sequence records."""
    worlds = {}
    for p in ps:
        a, b = (_per_seq(r, sc, p["region"]) for r in p["rows"])
        if not (a and b) or p["world"] in worlds:  # no records, or seeds sharing a world: no per-world split
            return None
        worlds[p["world"]] = (a, b)
    return variance_split(worlds, draws=draws) if len(worlds) >= 2 else None


def _level(r: dict) -> str:
    """The Hodges-Lehmann interval's exact level where the signed-rank distribution makes it other than 95 %
    (few worlds: at n = 5 or fewer it is the Walsh averages' whole range, 100 %)."""
    lv = r.get("ci_level", math.nan)
    return f" ({100 * lv:.1f} %)" if math.isfinite(lv) and abs(lv - 0.95) > 0.0005 else ""


def _f(x: float, d: int = 4) -> str:
    return f"{x:+.{d}f}" if isinstance(x, (int, float)) and math.isfinite(x) else "—"


def format_lcon(results: dict, plot_dir: Path | None = None, o: float | None = None) -> tuple[str, list]:
    """Markdown of the L_con section for every overlap of the sweep (the primary one first), and the forest plots
    written into ``plot_dir`` (their paths); ('', []) for a sweep without an L_con pair or without worlds."""
    arms = lcon_arms(results)
    cfg = results.get("sweep_config", {})
    if arms is None or cfg.get("worlds") != "per_seed":
        return "", []
    plan = plan_of(results)
    o = plan["overlap"] if o is None else o
    overlaps = sorted(d["overlap"] for d in results["data"])
    overlaps = [x for x in overlaps if abs(x - o) < 1e-9] + [x for x in overlaps if abs(x - o) >= 1e-9]
    L, plots = [], []
    add = L.append
    add("## (b) L_con's training-time effect outside the overlap\n")
    per = int(cfg.get("seeds_per_world", 1) or 1)
    ck = cfg.get("checkpoint", "auto")
    add("MCDP (w/o L_con, m = 2) cut - MCDP (m = 2) cut, "
        f"{plan['metric']} on {region_words(plan['region'])}, **positive = L_con helps**; "
        + ("one training seed per world" if per == 1 else f"{per} training seeds per world, clustered by world (the "
           "signed-rank test over the world means)") + "; "
        + ("both arms of a world scored at one step, the end of the budget (`checkpoint: last`)" if ck == "last" else
           f"each run scored at the checkpoint `{ck}` picks (`auto`: its own lowest validation loss, which for MCDP "
           "(m = 2) includes λ·L_con and for the arm without it does not)")
        + ". Over worlds: mean ± 95 % t interval, MDE at 80 % power, TOST against "
        f"±{plan['delta']:g}, and Wilcoxon's signed-rank test with the Hodges-Lehmann estimate and its interval. Primary: "
        f"overlap {o:.2f}, median scaling; every other overlap is exploratory.\n")
    for ov in overlaps:
        ps = pairs(results, ov)
        if not ps:
            continue
        tag = "primary" if abs(ov - o) < 1e-9 else "exploratory"
        n_w = len({p["world"] for p in ps})
        add(f"### Overlap {ov:.2f} ({tag}): {n_w} worlds" + (f", {len(ps)} (world, seed) pairs" if len(ps) > n_w
                                                               else "") + "\n")
        mixed = [p for p in ps if not p["same_step"]]
        add(("**Every pair scored at one step** (" + ", ".join(sorted({str(p['steps'][0]) for p in ps})) + ").\n")
            if not mixed else f"**{len(mixed)} of {len(ps)} pairs were scored at two different steps**: "
            + ", ".join(f"world {p['world']}: {p['steps'][0]} / {p['steps'][1]}" for p in mixed) + ".\n")
        add("| scaling | mean ± 95 % | MDE 80 % | TOST p | Wilcoxon p | Hodges-Lehmann [95 %] | worlds > 0 | answer |")
        add("|---|---|---|---|---|---|---|---|")
        readings = {}
        for sc in SCALINGS:
            n = reading(ps, sc, plan)
            readings[sc] = n
            r = n["rank"]
            pos = sum(1 for v in world_means(ps, sc).values() if math.fsum(v) > 0)
            add(f"| {sc} | {fmt_diff(n, 4)} | {n['mde80']:.4f} | {n['tost']['p']:.3f} | "
                f"{r['p']:.3f} | {_f(r['hl'])} [{_f(r['ci'][0])}, {_f(r['ci'][1])}]{_level(r)} | {pos} / {n['n_worlds']} | "
                f"{answer(n)} |")
        add("")
        n = readings["median"]
        if n["n_worlds"] >= 2 and math.isfinite(n["se"]):
            sd = n["se"] * math.sqrt(n["n_worlds"])
            add(f"Spread between worlds (median): sd {sd:.4f}; worlds for an MDE of {plan['delta']:g} at 80 % power at "
                f"this spread: {worlds_needed(sd, plan['delta'])}.\n")
        if abs(ov - o) < 1e-9 and plan["stopping"] == "obrien_fleming":
            add(_looks(ps, plan))
        sp = split_of(ps, "median")
        if sp is not None:
            add(_split_text(sp, ps))
            if plot_dir is not None:
                Path(plot_dir).mkdir(parents=True, exist_ok=True)
                path = Path(plot_dir) / f"lcon_forest_{ov:.2f}.png"
                r = n["rank"]
                forest_plot(sp, path, f"(b) per world, overlap {ov:.2f}, median abs_rel, non-overlap px",
                            hl=(r["hl"], *r["ci"]) if math.isfinite(r["hl"]) else None,
                            xlabel="w/o L_con - with L_con (positive = L_con helps)")
                plots.append(path)
        add("| world | seed | steps (w/o / with) | " + " | ".join(SCALINGS) + " | median: 95 % over its test sequences |")
        add("|---|---|---|" + "---|" * len(SCALINGS) + "---|")
        for p in ps:
            b = (sp or {}).get("per_world", {}).get(p["world"])
            add(f"| {p['world']} | {p['seed']} | {p['steps'][0]} / {p['steps'][1]} | " + " | ".join(_f(p["d"][sc]) for sc in SCALINGS)
                + f" | {('[' + _f(b['lo']) + ', ' + _f(b['hi']) + ']') if b else '—'} |")
        add("")
    return "\n".join(L), plots


def _looks(ps: list[dict], plan: dict) -> str:
    """The two-look reading of the plan stated before the run (median scaling)."""
    planned, first = int(plan["worlds"]), int(plan.get("first_look") or 0)
    ordered = sorted(ps, key=lambda p: p["seed"])
    lines = [f"Plan stated before the run: {planned} worlds, O'Brien-Fleming looks at {first} and {planned} "
             f"(`plan` in the preset; {plan.get('why', '')}).\n"]
    for n_look, final in ((first, False), (planned, True)):
        if not n_look or len(ordered) < n_look:
            lines.append(f"- look at {n_look} worlds: not reached ({len(ordered)} worlds measured)")
            continue
        lk = sequential_look([p["d"]["median"] for p in ordered[:n_look]], planned, final, t1=first / planned)
        lines.append(f"- look at {n_look} worlds: mean {_f(lk['mean'])}, t = {lk['t']:.2f} (df {lk['df']}), "
                     f"p = {lk['p']:.4f} against the look's nominal level {lk['nominal']:.4f} (|z| ≥ "
                     f"{lk['bound_z']:.3f}): " + (("**beyond the final bound**" if final else "**stop: beyond the bound**")
                                                 if lk["stop"] else "continue" if not final else
                                                 "not beyond the final bound"))
    return "\n".join(lines) + "\n"


def _split_text(sp: dict, ps: list[dict]) -> str:
    n_seq = sorted({b["n_seq"] for b in sp["per_world"].values()})
    out = (f"Where the spread comes from (median; bootstrap over each world's {'/'.join(map(str, n_seq))} test "
           f"sequences, {DRAWS} draws, paired): between-world variance {sp['var_between']:.2e} = test-sampling noise "
           f"{sp['var_noise']:.2e} ({100 * sp['noise_share']:.0f} %) + heterogeneity {sp['tau2']:.2e}. ")
    if sp["outliers"]:
        out += "Outlying worlds (|z| > 3, leave-one-out): " + ", ".join(f"{w} (z = {z:+.1f})" for w, z in sp["outliers"]) + "."
    else:
        out += "No outlying world (every leave-one-out |z| ≤ 3)."
    return out + "\n"


def selection_effect(last: dict, auto: dict, o: float | None = None) -> dict | None:
    """The same runs read twice, every arm at the last step and each at its own `auto` checkpoint: per world the
    steps and (b) (median scaling) both ways, the between-world variance each way, and the share of the `auto`
    reading's variance that the selection added (1 - var_last / var_auto). None without common worlds."""
    pl = {p["world"]: p for p in pairs(last, o)}
    pa = {p["world"]: p for p in pairs(auto, o)}
    common = [w for w in pl if w in pa]
    if len(common) < 2:
        return None

    def var(xs: list[float]) -> float:
        m = math.fsum(xs) / len(xs)
        return math.fsum((x - m) ** 2 for x in xs) / (len(xs) - 1)

    out = {"worlds": common, "per_world": {}}
    for sc in SCALINGS:
        dl = [pl[w]["d"][sc] for w in common]
        da = [pa[w]["d"][sc] for w in common]
        out[sc] = {"var_last": var(dl), "var_auto": var(da), "mean_last": math.fsum(dl) / len(dl),
                   "mean_auto": math.fsum(da) / len(da)}
        out[sc]["share_from_selection"] = (1.0 - out[sc]["var_last"] / out[sc]["var_auto"]
                                           if out[sc]["var_auto"] > 0 else math.nan)
    for w in common:
        out["per_world"][w] = {"steps_auto": pa[w]["steps"], "steps_last": pl[w]["steps"],
                               "d_auto": pa[w]["d"]["median"], "d_last": pl[w]["d"]["median"]}
    return out


def format_selection(sel: dict) -> str:
    """Markdown: the same runs at one step and at each arm's own `auto` checkpoint."""
    L = ["| world | auto steps (w/o / with) | (b) at auto | (b) at the last step |", "|---|---|---|---|"]
    for w, r in sel["per_world"].items():
        L.append(f"| {w} | {r['steps_auto'][0]} / {r['steps_auto'][1]} | {_f(r['d_auto'])} | {_f(r['d_last'])} |")
    L.append("")
    for sc in SCALINGS:
        s = sel[sc]
        L.append(f"- {sc}: mean {_f(s['mean_auto'])} at auto, {_f(s['mean_last'])} at the last step; between-world "
                 f"variance {s['var_auto']:.2e} at auto, {s['var_last']:.2e} at the last step: the selection "
                 + (f"added {100 * s['share_from_selection']:.0f} % of the auto reading's variance"
                    if s["share_from_selection"] >= 0 else
                    f"did not add variance (the last step's is {100 * -s['share_from_selection']:.0f} % larger)"))
    return "\n".join(L) + "\n"


def budget_reading(budget: dict, short: dict | None, o: float | None = None) -> dict:
    """(b) at a longer budget beside its positive control, and against the shorter budget on the same worlds.

    ``budget``: a sweep with the L_con pair and, as the control, the local yardstick (ORACLE-local) trained at the
    same budget; ``short``: a sweep of the same worlds at the shorter budget (or None). Returns {"b": {scaling:
    `reading`}, "control": `study.report.sections.primary.measure` of emptied - filled on non-overlap pixels (None without it),
    "short": {scaling: `reading` of the shorter budget on the worlds both have}, "change": {scaling:
    `study.stats.design.reading_over_worlds` of (b) long - (b) short, paired by world}}."""
    plan = plan_of(budget)
    o = plan["overlap"] if o is None else o
    ps = pairs(budget, o)
    out: dict = {"b": {sc: reading(ps, sc, plan) for sc in SCALINGS}, "control": None, "short": None, "change": None}
    if has_control(budget):
        loc = local()
        out["control"] = measure(budget, o, Evaluation(loc, cut()), Evaluation(loc), REGION)
    if short is not None:
        long_w = {p["world"]: p for p in ps}
        sp = [p for p in pairs(short, o) if p["world"] in long_w]
        if len(sp) >= 2:
            out["short"] = {sc: reading(sp, sc, plan) for sc in SCALINGS}
            out["change"] = {sc: reading_over_worlds({p["world"]: [long_w[p["world"]]["d"][sc] - p["d"][sc]]
                                                      for p in sp}, plan) for sc in SCALINGS}
    return out


def format_budget(r: dict, steps: str, short_steps: str) -> str:
    """Markdown: the control beside (b) at the longer budget, and (b)'s change from the shorter budget."""
    L = []
    c = r["control"]
    if c is None:
        L.append("No positive control in this sweep: a null here cannot be read against a mechanism that propagates.")
    else:
        n = c["median"]
        word = ("**the control propagates**: the overlap's ground truth, handed to ORACLE-local, improves its depth "
                "outside the overlap beyond the interval" if n.get("differs") == 1 else
                "**the control does not propagate beyond its interval here**, so a null in (b) cannot be told from a "
                "budget too short for any propagation")
        L.append(f"Positive control at the same budget ({steps} steps), ORACLE-local emptied - filled, abs_rel on "
                 f"non-overlap pixels, positive = the overlap's depth helps outside it: "
                 + "; ".join(f"{sc} {fmt_diff(c[sc], 4)}" for sc in SCALINGS)
                 + f" over {n.get('n_worlds', 0)} worlds: {word}. (b) at the same budget, median: "
                 f"{fmt_diff(r['b']['median'], 4)}.\n")
    if r["change"] is not None:
        s, ch = r["short"], r["change"]
        L.append(f"The same worlds at {short_steps} steps (the main run, exploratory beside it): (b) "
                 + "; ".join(f"{sc} {fmt_diff(s[sc], 4)}" for sc in SCALINGS)
                 + f". Change from {short_steps} to {steps} steps, paired by world: "
                 + "; ".join(f"{sc} {fmt_diff(ch[sc], 4)}" for sc in SCALINGS)
                 + f" over {ch['median']['n_worlds']} worlds.\n")
    return "\n".join(L)
