"""The report's section on how far the overlap reaches: two yardsticks of what a perfectly known overlap
could give the rest of the image, the inference-time and training-time propagation of every mechanism
against them, and all of it by distance from the overlap (docs/results/propagation.md).

Read from `study.results.summary` (nothing is computed from raw files). Median-scaled abs_rel throughout;
differences are paired over (world, seed) pairs (`study.results.paired.paired_difference`, clustered by world in a
design with worlds), each a gain: worse minus better, positive = helps.

- **Yardstick, global** (variant ``oracle_overlap``, `study.sweep.variants`): a run's own bases at per-image
  weights fitted to the ground truth of the OVERLAP pixels only, scored on the non-overlap pixels: what
  MCDP's one weight vector per image could carry from a perfect overlap. Its headroom = init - ORACLE-overlap.
- **Yardstick, local** (``oracle_local``): Mono2's network given the overlap's ground-truth depth as an
  input, evaluated filled and emptied (its cut); headroom = emptied - filled on non-overlap pixels: what
  a network free to carry it anywhere makes of a perfect overlap at this budget.
- **Inference-time propagation** of a network that reads other cameras: cut - as trained (> 0: reading
  them helps where they are not seen).
- **Training-time propagation**: what a training term on the overlap changes in a network evaluated
  without reading any other camera: MCDP (m = 2) cut - MCDP (w/o L_con, m = 2) cut (L_con), FSM - Mono2.
- **Recovered**: a gain / the local yardstick's headroom (the global one for the ORACLE-overlap weights).
"""
from __future__ import annotations

import math

from mcdp.methods import baseline, label, nocon_twins, reading, short_label
from study.results.paired import paired_columns
from study.results.summary import flat_of, fmt_diff, mean_std
from study.sweep.variants import Evaluation, cut, having

NON = "median.non_overlap.abs_rel"
#: the name of the local yardstick's headroom in `quantities` starts so, and the global one's
LOCAL_HEAD, GLOBAL_HEAD = "local headroom", "global headroom"


def local_headroom(q: dict[str, dict], empty: dict) -> dict:
    """The local yardstick's headroom among `quantities`, or ``empty``."""
    return next((pd for name, pd in q.items() if name.startswith(LOCAL_HEAD)), empty)


def readers() -> list[str]:
    """The rows whose inference-time propagation is reported (as trained vs cut), in this order: each mechanism
    (``reach`` "mechanism", `mcdp.methods.Method`), followed by its twins trained without L_con, then the other
    readers (``reach`` "reader")."""
    out: list[str] = []
    for m in reading("mechanism"):
        out += [m] + [t for t in nocon_twins(m) if t not in out]
    return out + [m for m in reading("reader") if m not in out]


def local() -> str | None:
    """The local yardstick's row (``reach`` "local"), or None."""
    return next(iter(reading("local")), None)


def global_of() -> str | None:
    """The row whose bases give the global yardstick (``reach`` "global"), or None."""
    return next(iter(reading("global")), None)


def lcon_pairs() -> list[tuple[str, str]]:
    """(twin trained without L_con, the row with it) of every row that has such a twin (``nocon_of``)."""
    from mcdp.methods import METHODS

    return [(m.name, m.nocon_of) for m in METHODS.values() if m.nocon_of is not None]


def band_names(results: dict) -> list[str]:
    """The distance bands present in the results (`synth.overlap.BAND_NAMES` order)."""
    for f in results["flat"]:
        names = [k[len("median.band."):-len(".abs_rel")] for k in f if k.startswith("median.band.")]
        if names:
            return names
    return []


#: paired over (world, seed) pairs: column a[1] of evaluation a[0] minus column b[1] of evaluation b[0]
paired = paired_columns


def _has(results: dict, ev: str | Evaluation) -> bool:
    ev = Evaluation.of(ev)
    return any(ev.matches(f) for f in results["flat"])


def _cut(m: str) -> Evaluation:
    return Evaluation(m, cut())


def _global(results: dict) -> bool:
    """Whether the results have the global yardstick: the ``reach`` "global" row evaluated at an overlap ceiling."""
    glob = global_of()
    return glob is not None and any(_has(results, Evaluation(glob, v.name)) for v in having("overlap_ceiling"))


def quantities(results: dict, o: float, key: str = NON) -> dict[str, dict]:
    """Every paired quantity of the section at one overlap on one column (`key`), by name; a gain is positive
    when it helps (headrooms and gains are 'worse - better')."""
    q: dict[str, dict] = {}
    base, loc, glob = baseline(), local(), global_of()
    if _global(results) and key == NON:  # the headrooms from the global row's init stage, non-overlap pixels
        init_key = "init." + key
        for head, cap in ((GLOBAL_HEAD, "overlap_ceiling"), ("all-pixel headroom", "ceiling")):
            for v in (v for v in having(cap) if _has(results, Evaluation(glob, v.name))):
                q[f"{head} (init - {v.label})"] = paired(results, o, (glob, init_key), (Evaluation(glob, v.name), key))
        q[f"{short_label(glob)} refinement gain (init - final)"] = paired(results, o, (glob, init_key), (glob, key))
    for v in having("spread"):  # a propagator from the overlap's ground truth, of the baseline
        if _has(results, Evaluation(base, v.name)):
            q[f"{v.label} ({label(base)} - {label(base)} {v.short} from the overlap's ground truth)"] = \
                paired(results, o, (base, key), (Evaluation(base, v.name), key))
    if loc is not None and _has(results, _cut(loc)):
        q[f"{LOCAL_HEAD} ({short_label(loc)} emptied - filled)"] = paired(results, o, (_cut(loc), key), (loc, key))
    for m in readers():
        if _has(results, _cut(m)):
            q[f"{m}: inference-time ({cut()} - as trained)"] = paired(results, o, (_cut(m), key), (m, key))
    pairs = [(t, m) for t, m in lcon_pairs() if _has(results, _cut(m)) and _has(results, _cut(t))]
    for t, m in pairs:
        q[("" if len(pairs) == 1 else f"{m}: ") + "L_con: training-time (w/o L_con cut - with L_con cut)"] = paired(
            results, o, (_cut(t), key), (_cut(m), key))
    for m in reading("mechanism"):
        if _has(results, m) and _has(results, base):
            q[f"{m}: vs {label(base)} ({label(base)} - {m})"] = paired(results, o, (base, key), (m, key))
    return q


def _cell(pd: dict, digits: int = 4) -> str:
    return fmt_diff(pd, digits) if pd["n"] else "—"


def _frac(gain: dict, head: dict) -> str:
    """The gain as a share of the local headroom, only where that headroom is positive beyond its interval
    (a share of a headroom that may be zero says nothing) and the gain itself beyond its interval (a share of a
    gain that may be zero says no more than the primary test does)."""
    g, h = gain.get("mean", math.nan), head.get("mean", math.nan)
    if not (math.isfinite(g) and math.isfinite(h)) or head.get("differs") != 1 or not gain.get("differs"):
        return "—"
    return f"{100 * g / h:.0f} %"


def _propagation(name: str) -> bool:
    """A quantity that is propagation (reading the neighbours, or a training term), not a comparison."""
    return "inference-time" in name or "training-time" in name or "refinement gain" in name


def format_reach(results: dict, label) -> str:
    """Markdown: yardsticks, both kinds of propagation, fraction recovered, the distance table; '' when the
    sweep has no run with the instruments (no ORACLE-overlap stage and no ORACLE-local run)."""
    loc = local()
    if not (_global(results) or (loc is not None and _has(results, loc))):
        return ""
    L: list[str] = []
    add = L.append
    add("## How far does the overlap reach? Yardsticks, two kinds of propagation, distance\n")
    add("Non-overlap pixels, median-scaled abs_rel; every number is a paired difference over (world, seed) pairs, "
        "mean ± 95 % t half-width, **positive = helps** (worse minus better), as on the whole page. The two yardsticks read ground truth "
        "(ORACLE): *global* = MCDP (m = 2)'s own bases at per-image weights fitted on the overlap pixels only; "
        "*local* = Mono2's network given the overlap's ground-truth depth as input, filled vs emptied. "
        "*Recovered* = a propagation's gain as a share of the local headroom, given only where that headroom "
        "is positive beyond its interval and the gain itself is beyond its own.\n")
    seeds = results.get("seeds", [])
    worlds = results.get("sweep_config", {}).get("worlds", "shared")
    per = int(results.get("sweep_config", {}).get("seeds_per_world", 1) or 1)
    how = ("seeds on one shared world: the intervals cover the training seed only" if worlds != "per_seed" else
           "world k trained with seed k: the intervals cover the scene sample and the seed together" if per == 1 else
           f"{len(seeds) // per} worlds x {per} seeds; every interval here is clustered by world, as the primary "
           "comparisons' (t over the world means)")
    add(f"Pairs: {len(seeds)} ({how}).\n")
    for d in results["data"]:
        o = d["overlap"]
        q = quantities(results, o)
        head = local_headroom(q, {})
        add(f"**Overlap {o:.2f}** (measured {d['measured']['measured_mean']:.3f})\n")
        add("| quantity | non-overlap px | recovered (of local headroom) |")
        add("|---|---|---|")
        for name, pd in q.items():
            rec = _frac(pd, head) if _propagation(name) else ""
            add(f"| {name} | {_cell(pd)} | {rec} |")
        add("")
    bands = band_names(results)
    if bands:
        add("### By distance from the overlap (bands in fractions of the image width)\n")
        L += _band_table(results, bands, "median.band.{b}.abs_rel")
    if bands and any(k.startswith("median.road_band.") for f in results["flat"] for k in f):
        add("### The road alone, by distance from the overlap (the surface the neighbours share most)\n")
        L += _band_table(results, bands, "median.road_band.{b}.abs_rel")
    add(format_in_words(results))
    return "\n".join(L)


def _band_table(results: dict, bands: list[str], key_of: str) -> list[str]:
    """The band table of column `key_of` (``{b}``: the band): the baseline's value and each mechanism's gain."""
    base, loc, mech = baseline(), local(), reading("mechanism")
    b = short_label(base)
    c = cut()
    # (name, (evaluation a, evaluation b), the one whose rows make the column): a - b per band
    cols = ([(f"{short_label(m)} {c} - trained", (_cut(m), m), _cut(m)) for m in mech]
            + ([(f"{short_label(loc)} emptied - filled", (_cut(loc), loc), _cut(loc))] if loc is not None else [])
            + [(f"propagator: {b} - {v.short}", (base, Evaluation(base, v.name)), Evaluation(base, v.name))
               for v in having("spread")]
            + [(f"{b} - {short_label(m)}", (base, m), m) for m in mech])
    cols = [(n, ab) for n, ab, needed in cols if _has(results, needed)]
    L = [f"| overlap | band | {b} abs_rel | " + " | ".join(n for n, _ in cols) + " |",
         "|---|---|---|" + "---|" * len(cols)]
    for d in results["data"]:
        o = d["overlap"]
        for band in bands:
            key = key_of.format(b=band)
            mono = mean_std([f.get(key, math.nan) for f in flat_of(results, o, base)])
            cells = []
            for _, (a, b_) in cols:
                cells.append(_cell(paired(results, o, (a, key), (b_, key))))
            L.append(f"| {o:.2f} | {band} | {mono['mean']:.4f} | " + " | ".join(cells) + " |")
    return L + [""]


def _word(pd: dict) -> str:
    if not pd.get("n"):
        return "not measured"
    return {1: "helps", -1: "hurts", 0: "no difference beyond the interval"}[pd["differs"]]


def format_in_words(results: dict) -> str:
    """One verdict line per overlap: each mechanism's propagation next to the yardsticks' headroom."""
    L = ["### Per overlap, in words (non-overlap pixels)\n"]
    for d in results["data"]:
        o = d["overlap"]
        q = quantities(results, o)
        head = local_headroom(q, {"n": 0})
        glob = next((pd for name, pd in q.items() if name.startswith(GLOBAL_HEAD)), {"n": 0})
        L.append(f"- overlap {o:.2f}: local headroom {_cell(head)} ({_word(head)}), global headroom {_cell(glob)} "
                 f"({_word(glob)})")
        for name, pd in q.items():
            if "headroom" in name:
                continue
            share = _frac(pd, head) if _propagation(name) else "—"
            L.append(f"  - {name} {_cell(pd)}: {_word(pd)}" + ("" if share == "—" else f" ({share} of the local headroom)"))
    L.append("")
    return "\n".join(L)
