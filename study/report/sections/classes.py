"""The report's section by class group and motion (a sweep whose worlds have semantic labels, `synth.labels`).

Read from `study.results.summary` (nothing is computed from raw files): median-scaled abs_rel of the class groups
(road, building, vehicle: parked / moving, vegetation, other) and of static / moving pixels
(`mcdp.label_regions`), Mono2's value beside the constant-depth yardstick, Mono2 − every other method, paired
over (world, seed) pairs (positive = helps, the one sign of every page); where a method is better or worse
beyond the interval, in words, with the number of distinct tests (rows that hold the same pixels count once); then the "infinite depth" hole: the share of
moving vehicles' pixels predicted beyond twice their depth, against parked vehicles' (the same kind of
object standing still) as the yardstick.
"""
from __future__ import annotations

import math

from study.results.paired import paired_columns
from study.results.summary import BASELINE, flat_of, fmt_diff, mean_std, yardstick_row

KEY = "median.{kind}.{region}.abs_rel"
ROWS = (("class", "road", "road"), ("class", "building", "building"), ("class", "vehicle", "vehicle"),
        ("class", "vehicle_parked", "  parked"), ("class", "vehicle_moving", "  moving"),
        ("class", "vegetation", "vegetation"), ("class", "other", "other"), ("motion", "static", "static pixels"),
        ("motion", "moving", "moving pixels"))
#: a method's depth on movers "collapses" when at least this share of their pixels is beyond 2x their depth
#: and at least twice the share of parked vehicles'
HOLE_SHARE = 0.2


def has_classes(results: dict) -> bool:
    return any(k.startswith("median.class.") for f in results.get("flat", []) for k in f)


def _cell(pd: dict) -> str:
    return "—" if not pd.get("n") else fmt_diff(pd, 3) + (" *" if pd["differs"] else "")


def _hole_line(results: dict, o: float, m: str, label) -> str | None:
    rows = flat_of(results, o, m)
    mov = mean_std([f.get("median.holes.moving", math.nan) for f in rows])
    par = mean_std([f.get("median.holes.parked", math.nan) for f in rows])
    px = sum(int(f.get("median.holes.moving_pixels", 0) or 0) for f in rows if math.isfinite(
        f.get("median.holes.moving_pixels", math.nan)))
    if not mov["n"]:
        return None
    collapsed = mov["mean"] >= HOLE_SHARE and (not math.isfinite(par["mean"]) or mov["mean"] >= 2 * par["mean"])
    word = "**collapses** (the infinite-depth hole)" if collapsed else "does not collapse"
    par_txt = f"{100 * par['mean']:.1f} %" if par["n"] else "no parked vehicle in view"
    return (f"- {label(m)}: {100 * mov['mean']:.1f} % of moving vehicles' pixels beyond 2x their depth (parked: "
            f"{par_txt}; {px} moving-vehicle pixels over {mov['n']} runs): {word}")


def format_classes(results: dict, label) -> str:
    """The section (markdown); "" when no run was evaluated with semantic labels."""
    if not has_classes(results):
        return ""
    methods = [m for m in results["methods"] if m != BASELINE]
    L = ["### By class group and motion (median-scaled abs_rel; the worlds' semantic labels)\n",
         f"{label(BASELINE)} - each method on the same class's pixels, paired over (world, seed) pairs (positive = "
         "helps; * = beyond the 95 % interval). Classes: the renderer's exact labels, vehicles split into parked "
         "and moving; 'moving pixels' are every mover's, 'static pixels' the rest. Exploratory: "
         f"{len(ROWS) * len(methods) * len(results['data'])} comparisons, uncorrected.\n"]
    add = L.append
    for d in results["data"]:
        o = d["overlap"]
        add(f"**Overlap {o:.2f}**\n")
        add(f"| pixels | constant (ref.) | {label(BASELINE)} | " + " | ".join(f"{label(BASELINE)} - {label(m)}"
                                                                             for m in methods) + " |")
        add("|---|---|---|" + "---|" * len(methods))
        ref = yardstick_row(results, o, "reference")
        for kind, region, name in ROWS:
            key = KEY.format(kind=kind, region=region)
            mono = mean_std([f.get(key, math.nan) for f in flat_of(results, o, BASELINE)])
            r = ref.get(key, math.nan)
            cells = [_cell(paired_columns(results, o, (BASELINE, key), (m, key))) for m in methods]
            add(f"| {name} | {r:.3f} | " + (f"{mono['mean']:.3f}" if mono["n"] else "—") + " | "
                + " | ".join(cells) + " |")
        add("")
    add(class_verdicts(results, label))
    add("**Depth on moving objects** (median-scaled; the hole self-supervision digs where an object moves "
        "with the camera):\n")
    for d in results["data"]:
        o = d["overlap"]
        lines = [x for x in (_hole_line(results, o, m, label) for m in results["methods"]) if x]
        if lines:
            add(f"Overlap {o:.2f}:")
            L.extend(lines)
            add("")
    return "\n".join(L)


def _pairs(results: dict, o: float, m: str, key: str) -> tuple:
    """A comparison's per-pair values (seed, Mono2, method), rounded, so two rows over the same pixels compare equal."""
    a = {f["seed"]: f.get(key) for f in flat_of(results, o, BASELINE)}
    b = {f["seed"]: f.get(key) for f in flat_of(results, o, m)}
    return tuple((s, round(a[s], 9), round(b[s], 9)) for s in sorted(a) if s in b
                 and all(isinstance(x, (int, float)) and math.isfinite(x) for x in (a[s], b[s])))


def class_verdicts(results: dict, label) -> str:
    """The by-class table in words: per method, where it is better and where worse than Mono2 beyond the 95 %
    interval, and how many distinct tests the table holds (a row over the same pixels as another, e.g. "vehicle",
    "moving" and "moving pixels" when nothing is parked and only vehicles move, counts once), with the caveat."""
    methods = [m for m in results["methods"] if m != BASELINE]
    n_cells, seen = 0, set()
    better: dict[str, list[str]] = {m: [] for m in methods}
    worse: dict[str, list[str]] = {m: [] for m in methods}
    for d in results["data"]:
        o = d["overlap"]
        for m in methods:
            done: dict[tuple, str] = {}
            for kind, region, name in ROWS:
                key = KEY.format(kind=kind, region=region)
                vals = _pairs(results, o, m, key)
                if not vals:
                    continue
                n_cells += 1
                seen.add((o, m, vals))
                if vals in done:
                    continue
                done[vals] = name.strip()
                same = [n.strip() for k, r, n in ROWS if _pairs(results, o, m, KEY.format(kind=k, region=r)) == vals]
                pd = paired_columns(results, o, (BASELINE, key), (m, key))
                where = f"{' = '.join(same)} at {o:.2f} ({fmt_diff(pd, 3)})"
                if pd["differs"] > 0:
                    better[m].append(where)
                elif pd["differs"] < 0:
                    worse[m].append(where)
    lines = [f"In words (exploratory, {n_cells} comparisons, {len(seen)} distinct tests, uncorrected: at 95 % about "
             f"{0.05 * len(seen):.1f} would fall beyond their interval by chance; rows joined by '=' hold the same "
             "pixels):\n"]
    for m in methods:
        lines.append(f"- {label(m)}: better than {label(BASELINE)} on " + ("; ".join(better[m]) or "no class")
                     + "; **worse** on " + ("; ".join(worse[m]) or "no class") + ".")
    return "\n".join(lines) + "\n"
