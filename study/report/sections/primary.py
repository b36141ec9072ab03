"""The propagation experiment's primary comparisons, with their power and bounds (docs/results/propagation.md).

A null result is only as strong as its positive control and its power. This section of the report opens
with the control's **copy test**, then gives each comparison named before the run
(configs/sweep/cpu_propagation.yaml's header) with:

- its mean over the (world, seed) pairs and a 95 % interval **clustered by world** (`study.stats.power.nested`:
  the mean of the world means, t with worlds - 1 degrees of freedom), and the split of its spread into a
  world part and a seed part;
- its **minimum detectable effect** at 80 % power (`study.stats.power.mde`) from that observed spread;
- for a null, an **equivalence test** at 95 % (two one-sided tests, `study.stats.power.tost`) against the bound
  ``delta`` of the sweep's pre-stated plan (`plan_of`: the preset's ``plan``, saved with the run);
- the figure at ``none`` and ``rig_median`` scaling next to ``median`` (per-image median scaling erases
  a scale-only effect, which is what the overlap is known to carry).

Every gain is **positive when it helps** (worse minus better). The comparisons, at the plan's ``overlap``:

- (a) inference-time propagation of MCDP (m = 2) and MCDP-local: cut - as trained, non-overlap pixels;
- (b) training-time propagation of L_con: MCDP (w/o L_con) cut - MCDP (m = 2) cut, non-overlap pixels;
- (c) the positive control (ORACLE-local emptied - filled) and the hand-built propagator (Mono2 - Mono2
  corrected from the overlap's ground truth alone, variant ``oracle_spread``: no training, so no budget
  limits it; a yardstick of what a simple propagator makes of a perfect overlap, not an upper bound) per
  distance band.

The copy test: ORACLE-local filled must score at most `COPY_MAX` x Mono2's median abs_rel on the overlap
pixels (the pixels it was handed) at every overlap. If it fails, every verdict that leans on the control
((a), (b) and the control's own gain) reads "inconclusive". Read from `study.results.summary` only.
"""
from __future__ import annotations

import math

from study.stats.design import reading_over_worlds
from study.stats.power import nested
from mcdp.methods import baseline, reading, short_label
from study.report.sections.reach import band_names, lcon_pairs, local
from study.results.summary import flat_of, fmt_diff
from study.sweep.variants import Evaluation, cut, having

#: the copy test's bound: ORACLE-local filled / Mono2, median abs_rel on the overlap pixels
COPY_MAX = 0.5
SCALINGS = ("median", "none", "rig_median")


def plan_of(results: dict, defaults: dict | None = None) -> dict:
    """The sweep's pre-stated analysis (`study.sweep.config.SweepPlan`: ``arms``, ``metric``, ``scaling``, ``region``,
    ``overlap``, ``delta``, ``stopping``, ``worlds``, ``first_look``, ``tuning_worlds``, ``why``) as its run recorded
    it (``sweep_config.plan``). A key a sweep recorded before it existed reads as what that sweep was analysed
    with: the page's own value in ``defaults`` (the sensor page: its arms and all pixels), else the key's default
    (delta 0.005, overlap 0.10, or where the sweep did not run 0.10, its first overlap; ``stopping``
    ``obrien_fleming`` where a first look was recorded)."""
    from study.sweep.config import SweepPlan

    rec = (results.get("sweep_config") or {}).get("plan") or {}
    out = {k: rec.get(k, f.get_default(call_default_factory=True)) for k, f in SweepPlan.model_fields.items()}
    out.update({k: v for k, v in (defaults or {}).items() if k not in rec})
    if "stopping" not in rec and out.get("first_look"):
        out["stopping"] = "obrien_fleming"
    swept = results.get("overlaps") or []
    if "overlap" not in rec and swept and not any(abs(o - out["overlap"]) < 1e-9 for o in swept):
        out["overlap"] = swept[0]
    return out


def primary_key(plan: dict) -> str:
    """The flat-row key of the plan's primary figure: ``<scaling>.<region section>.<metric>`` (e.g.
    ``median.non_overlap.abs_rel``; region ``all`` is the metrics' ``mean`` section)."""
    from study.sweep.config import PLAN_REGIONS

    return f"{plan['scaling']}.{PLAN_REGIONS[plan['region']]}.{plan['metric']}"


def world_of(results: dict):
    """seed -> world id of the sweep (`study.results.paired.world_of`)."""
    from study.results.paired import world_of as _world_of

    return _world_of(results)


def design(results: dict) -> str:
    """One line: how many worlds x seeds, and which interval the primary comparisons use."""
    cfg = results.get("sweep_config", {})
    seeds = list(results.get("seeds", []))
    per = int(cfg.get("seeds_per_world", 1) or 1)
    if cfg.get("worlds") != "per_seed":
        return (f"{len(seeds)} training seed(s) on one shared world per overlap: the intervals cover the training "
                "seed only, not the scene sample")
    n_w = len(seeds) // per
    return (f"{n_w} worlds x {per} training seed(s) per world ({len(seeds)} (world, seed) pairs); intervals "
            f"clustered by world (mean of the world means, t with {n_w - 1} degrees of freedom)")


def paired_groups(results: dict, o: float, a: tuple, b: tuple) -> dict:
    """{world: [column a[1] of evaluation a[0] minus column b[1] of evaluation b[0], per seed of that world]}."""
    wo = world_of(results)
    va = {f["seed"]: f.get(a[1]) for f in flat_of(results, o, a[0])}
    vb = {f["seed"]: f.get(b[1]) for f in flat_of(results, o, b[0])}
    groups: dict = {}
    for s, x in va.items():
        y = vb.get(s)
        if s in wo and all(isinstance(v, (int, float)) and math.isfinite(v) for v in (x, y)):
            groups.setdefault(wo[s], []).append(float(x) - float(y))
    return groups


def paired_nested(results: dict, o: float, a: tuple, b: tuple) -> dict:
    """`study.stats.power.nested` of `paired_groups`: a - b per (world, seed) pair, grouped by world."""
    return nested(paired_groups(results, o, a, b))


def _has(results: dict, ev) -> bool:
    ev = Evaluation.of(ev)
    return any(ev.matches(f) for f in results["flat"])


def _mean_of(results: dict, o: float, ev, key: str) -> float:
    v = [f.get(key) for f in flat_of(results, o, ev)]
    v = [float(x) for x in v if isinstance(x, (int, float)) and math.isfinite(x)]
    return sum(v) / len(v) if v else math.nan


def has_control(results: dict) -> bool:
    """Whether the sweep has the positive control: a run of the local yardstick (``reach`` "local")."""
    loc = local()
    return loc is not None and _has(results, loc)


def copy_test(results: dict) -> list[dict]:
    """Per overlap: ORACLE-local filled and Mono2 on the overlap pixels at every scaling, their ratio and
    whether the median-scaled ratio is at most `COPY_MAX`; [] without both rows."""
    loc, base_m = local(), baseline()
    if not (loc is not None and _has(results, loc) and _has(results, base_m)):
        return []
    out = []
    for d in results["data"]:
        o = d["overlap"]
        row = {"overlap": o}
        for sc in SCALINGS:
            key = f"{sc}.overlap.abs_rel"
            filled, base = _mean_of(results, o, loc, key), _mean_of(results, o, base_m, key)
            row[sc] = (filled, base, filled / base if base > 0 else math.nan)
        ratio = row["median"][2]
        row["passes"] = bool(math.isfinite(ratio) and ratio <= COPY_MAX)
        out.append(row)
    return out


def control_passes(results: dict) -> bool | None:
    """Whether the positive control passes its copy test at every overlap; None without a control."""
    rows = copy_test(results)
    return all(r["passes"] for r in rows) if rows else None


def comparisons(results: dict, o: float | None = None) -> list[tuple[str, str, tuple, tuple, str]]:
    """The primary comparisons present: (id, name, a, b, region) with a - b = the gain (positive helps); a and
    b are (evaluation, column prefix) and region a column suffix's region (``non_overlap`` or a band)."""
    out = []
    base, loc, c = baseline(), local(), cut()
    for m in reading("mechanism"):
        if _has(results, Evaluation(m, c)):
            out.append(("a", f"{short_label(m)} inference-time propagation ({c} - as trained)", Evaluation(m, c),
                        Evaluation(m), "non_overlap"))
    for t, m in lcon_pairs():
        if _has(results, Evaluation(m, c)) and _has(results, Evaluation(t, c)):
            out.append(("b", "L_con training-time propagation (w/o L_con cut - with L_con cut)",
                        Evaluation(t, c), Evaluation(m, c), "non_overlap"))
    if loc is not None and _has(results, Evaluation(loc, c)):
        out.append(("c", f"positive control: {short_label(loc)} emptied - filled", Evaluation(loc, c),
                    Evaluation(loc), "non_overlap"))
    for v in having("spread"):  # a propagator from the overlap's ground truth, of the baseline
        if _has(results, Evaluation(base, v.name)):
            b = short_label(base)
            out.append(("c", f"{v.label}: {b} - {b} {v.short} from the overlap's ground truth",
                        Evaluation(base), Evaluation(base, v.name), "non_overlap"))
    return out


def _key(sc: str, region: str) -> str:
    return f"{sc}.{region}.abs_rel" if region in ("overlap", "non_overlap", "mean") else f"{sc}.band.{region}.abs_rel"


def measure(results: dict, o: float, a, b, region: str) -> dict:
    """One comparison at every scaling: {scaling: `study.stats.design.reading_over_worlds` of a - b}."""
    return {sc: reading_over_worlds(paired_groups(results, o, (a, _key(sc, region)), (b, _key(sc, region))),
                                    plan_of(results)) for sc in SCALINGS}


def verdict(cid: str, m: dict, control: bool | None) -> str:
    """The verdict of one primary comparison (median scaling), honest about its power and its control."""
    n = m["median"]
    if not n.get("n_worlds"):
        return "not measured"
    if n["n_worlds"] < 2:
        return "one world: no interval, no verdict"
    t, delta = n["tost"] or {}, n["delta"]
    if n["differs"] == 1:
        word = f"**helps**: {fmt_diff(n, 4)}, beyond the interval"
    elif n["differs"] == -1:
        word = f"**hurts**: {fmt_diff(n, 4)}, beyond the interval"
    elif t.get("equivalent"):
        word = f"**no effect larger than ±{delta:g}** (equivalent at 95 %, TOST p = {t['p']:.3f})"
    else:
        word = (f"inconclusive: neither beyond the interval nor within ±{delta:g} "
                f"(TOST p = {t.get('p', math.nan):.3f}); "
                f"detectable at 80 % power: ±{n['mde80']:.4f}")
    if control is False and cid in ("a", "b"):  # a null of a mechanism leans on the control
        return "inconclusive (the positive control fails its copy test); measured: " + word
    return word


def _cell(n: dict, digits: int = 4) -> str:
    return fmt_diff(n, digits) if n.get("n") else "—"


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %" if math.isfinite(x) else "—"


def format_primary(results: dict, o: float | None = None) -> str:
    """Markdown: the copy test, then the primary comparisons with power, bounds and scalings, the variance split,
    the control and the hand-built propagator by distance band, and how much of each yardstick the mechanisms
    recover; '' for a sweep without the positive control (ORACLE-local): the propagation experiment's section only."""
    if not has_control(results):  # the propagation experiment is the sweep with the positive control
        return ""
    plan = plan_of(results)
    o = plan["overlap"] if o is None else o
    comps = comparisons(results, o)
    ct = copy_test(results)
    control = control_passes(results)
    L: list[str] = []
    add = L.append
    add("## The primary comparisons: copy test, power and bounds\n")
    add(f"Named in the preset's header before the run; every other table of this report is exploratory. Design: "
        f"{design(results)}. Equivalence bound δ = {plan['delta']:g} median abs_rel (two one-sided tests at 95 %); MDE = "
        "the effect a two-sided test at 5 % would detect with 80 % power, from the observed spread. Positive = "
        "helps.\n")
    if ct:
        add("### Copy test of the positive control\n")
        add(f"ORACLE-local filled against Mono2 on the overlap pixels, the pixels whose ground-truth depth it was "
            f"handed (mean over the pairs). It passes where filled ≤ {COPY_MAX:g} x Mono2 (median scaling).\n")
        add("| overlap | ORACLE-local filled (median) | Mono2 (median) | ratio | passes | filled / Mono2 (none) | "
            "filled / Mono2 (rig_median) |")
        add("|---|---|---|---|---|---|---|")
        for r in ct:
            f, b, q = r["median"]
            add(f"| {r['overlap']:.2f} | {f:.4f} | {b:.4f} | {q:.2f} | {'yes' if r['passes'] else '**no**'} | "
                f"{r['none'][0]:.4f} / {r['none'][1]:.4f} | {r['rig_median'][0]:.4f} / {r['rig_median'][1]:.4f} |")
        add("")
        add("**The control passes its copy test at every overlap.**\n" if control else
            "**The control FAILS its copy test: every verdict that leans on it is inconclusive.**\n")
    if not any(d["overlap"] == o for d in results["data"]):
        return "\n".join(L)
    add(f"### Primary comparisons at overlap {o:.2f}, non-overlap pixels\n")
    add("| id | comparison | median: mean ± 95 % (clustered) | MDE 80 % | TOST p (δ) | world share of spread | "
        "none | rig_median | verdict |")
    add("|---|---|---|---|---|---|---|---|---|")
    measured = []
    for cid, name, a, b, region in comps:
        m = measure(results, o, a, b, region)
        measured.append((cid, name, m))
        n = m["median"]
        t = n.get("tost") or {}
        add(f"| ({cid}) | {name} | {_cell(n)} | {n.get('mde80', math.nan):.4f} | {t.get('p', math.nan):.3f} | "
            f"{_pct(n.get('share_world', math.nan))} | {_cell(m['none'])} | {_cell(m['rig_median'])} | "
            f"{verdict(cid, m, control)} |")
    add("")
    if any(math.isfinite(m["median"].get("var_seed", math.nan)) for _, _, m in measured):
        add("Spread split (one-way random effects, seeds nested in worlds; median scaling): "
            + "; ".join(f"({cid}) {name.split(':')[0]}: world var {m['median'].get('var_world', math.nan):.2e}, "
                        f"seed var {m['median'].get('var_seed', math.nan):.2e}" for cid, name, m in measured) + ".\n")
    else:
        add("Spread split: not separable (one training seed per world: the intervals cover world and seed together).\n")
    add(_recovered(measured))
    bands = band_names(results)
    band_comps = [(cid, name, a, b) for cid, name, a, b, _ in comps if cid == "c"]
    if bands and band_comps:
        add(f"### (c) by distance from the overlap, overlap {o:.2f} (bands in fractions of the image width)\n")
        add(f"| band | {short_label(baseline())} abs_rel | " + " | ".join(f"{name.split(':')[0]} (median) | MDE 80 % | none | rig_median"
                                                  for _, name, _, _ in band_comps) + " |")
        add("|---|---|" + "---|---|---|---|" * len(band_comps))
        for band in bands:
            base = _mean_of(results, o, baseline(), f"median.band.{band}.abs_rel")
            cells = []
            for _, _, a, b in band_comps:
                m = measure(results, o, a, b, band)
                cells += [_cell(m["median"]), f"{m['median'].get('mde80', math.nan):.4f}", _cell(m["none"]),
                          _cell(m["rig_median"])]
            add(f"| {band} | {base:.4f} | " + " | ".join(cells) + " |")
        add("")
    return "\n".join(L)


def _recovered(measured: list) -> str:
    """How much of each yardstick's non-overlap gain each mechanism recovers (median scaling), only where the
    yardstick's gain is positive beyond its interval and the mechanism's own gain is beyond its interval (a share of
    a gain the primary test does not resolve would say more than that test)."""
    yard = [(name.split(":")[0], m["median"]) for cid, name, m in measured if cid == "c"]
    mech = [(name, m["median"]) for cid, name, m in measured if cid in ("a", "b")]
    lines = []
    for yname, y in yard:
        if not (y.get("n") and y["differs"] == 1):
            lines.append(f"- {yname}: its gain is not positive beyond its interval, so no share of it is given.")
            continue
        parts = [f"{name.split(' (')[0] if name.startswith('L_con') else name.split(' inference')[0]} "
                 + (f"{100 * g['mean'] / y['mean']:.0f} %" if g["differs"] else "— (its gain is within its interval)")
                 for name, g in mech if g.get("n")]
        lines.append(f"- of the {yname}'s gain ({y['mean']:+.4f}): " + (", ".join(parts) if parts else "—"))
    return ("Share of each yardstick's gain that a mechanism recovers (median scaling):\n\n" + "\n".join(lines) + "\n"
            if lines else "")


def headline(results: dict, o: float | None = None) -> str:
    """The one-line answer: "nothing propagates (< δ)" only when the control passes and every mechanism's gain
    is equivalent to 0 within δ; otherwise what propagates, or why the answer is inconclusive (δ and the
    overlap: the sweep's plan, `plan_of`)."""
    plan = plan_of(results)
    o, delta = plan["overlap"] if o is None else o, plan["delta"]
    control = control_passes(results)
    mech = [(name, measure(results, o, a, b, r)["median"]) for cid, name, a, b, r in comparisons(results, o)
            if cid in ("a", "b")]
    if control is not True:
        return "inconclusive: the positive control fails its copy test" if control is False else "no positive control"
    helps = [f"{name} {n['mean']:+.4f}" for name, n in mech if n.get("n") and n["differs"] == 1]
    if helps:
        return "propagates: " + "; ".join(helps)
    if mech and all((n.get("tost") or {}).get("equivalent") for _, n in mech):
        return f"nothing propagates (< {delta:g})"
    short = lambda name: (name.replace(" inference-time propagation (cut - as trained)", " at inference")  # noqa: E731
                          .replace(" training-time propagation (w/o L_con cut - with L_con cut)", " in training"))
    eq = [short(name) for name, n in mech if (n.get("tost") or {}).get("equivalent")]
    open_ = [f"{short(name)} (detectable at 80 %: {n.get('mde80', math.nan):.4f})" for name, n in mech
             if not (n.get("tost") or {}).get("equivalent")]
    return ("nothing is seen to propagate: " + (f"{', '.join(eq)} below ±{delta:g}; " if eq else "")
            + "not resolved: " + ", ".join(open_))
