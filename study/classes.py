"""The report's section by class group and motion (a sweep whose worlds have semantic labels, `synth.labels`).

Read from `study.results` (nothing is computed from raw files): median-scaled abs_rel of the class groups
(road, building, vehicle: parked / moving, vegetation, other) and of static / moving pixels
(`mcdp.label_regions`), Mono2's value beside the constant-depth yardstick, every other method's difference to
Mono2 paired over (world, seed) pairs (negative = better); then the "infinite depth" hole: the share of
moving vehicles' pixels predicted beyond twice their depth, against parked vehicles' (the same kind of
object standing still) as the yardstick.
"""
from __future__ import annotations

import math

from study.results import BASELINE, flat_of, fmt_diff, mean_std, paired_columns, yardstick_row

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
         f"Each method - {label(BASELINE)} on the same class's pixels, paired over (world, seed) pairs (negative = "
         "better; * = beyond the 95 % interval). Classes: the renderer's exact labels, vehicles split into parked "
         "and moving; 'moving pixels' are every mover's, 'static pixels' the rest. Exploratory: "
         f"{len(ROWS) * len(methods) * len(results['data'])} comparisons, uncorrected.\n"]
    add = L.append
    for d in results["data"]:
        o = d["overlap"]
        add(f"**Overlap {o:.2f}**\n")
        add(f"| pixels | constant (ref.) | {label(BASELINE)} | " + " | ".join(f"{label(m)} - {label(BASELINE)}"
                                                                             for m in methods) + " |")
        add("|---|---|---|" + "---|" * len(methods))
        ref = yardstick_row(results, o, "reference")
        for kind, region, name in ROWS:
            key = KEY.format(kind=kind, region=region)
            mono = mean_std([f.get(key, math.nan) for f in flat_of(results, o, BASELINE)])
            r = ref.get(key, math.nan)
            cells = [_cell(paired_columns(results, o, (m, key), (BASELINE, key))) for m in methods]
            add(f"| {name} | {r:.3f} | " + (f"{mono['mean']:.3f}" if mono["n"] else "—") + " | "
                + " | ".join(cells) + " |")
        add("")
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
