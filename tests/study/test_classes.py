"""The report's section by class group and motion (study/report/sections/classes.py), from results alone."""
from __future__ import annotations

import re

from study.report.sections.classes import format_classes, has_classes


def _results(moving_hole: float, parked_hole: float) -> dict:
    flat = []
    for seed in range(3):
        for m, road in (("mono2", 0.10), ("mcdp_m2", 0.08)):
            row = {"overlap": 0.1, "method": m, "variant": "trained", "seed": seed,
                   "median.class.road.abs_rel": road + 0.001 * seed, "median.class.vehicle_moving.abs_rel": 0.5,
                   "median.motion.moving.abs_rel": 0.5, "median.motion.static.abs_rel": 0.2,
                   "median.holes.moving": moving_hole, "median.holes.parked": parked_hole,
                   "median.holes.moving_pixels": 100}
            flat.append(row)
    data = [{"overlap": 0.1, "reference": {"row": {"median.class.road.abs_rel": 0.4}}}]
    return {"methods": ["mono2", "mcdp_m2"], "data": data, "flat": flat}


def test_the_section_pairs_each_method_with_mono2_by_class_and_says_when_movers_collapse():
    label = {"mono2": "Mono2", "mcdp_m2": "MCDP (m = 2)"}.get
    text = format_classes(_results(0.6, 0.05), label)
    assert "| road | 0.400 | 0.101 | +0.020 ± 0.000 * |" in text   # one sign per page: Mono2 - method, positive = helps
    assert "Mono2 - MCDP (m = 2)" in text and "comparisons, uncorrected" in text
    # one line per method on its moving vehicles: the share beyond 2x their depth, the parked ones', the pixels
    # and runs it rests on (the numbers, in order), and the verdict
    for moving_hole, parked_hole, verdict in ((0.6, 0.05, "**collapses**"), (0.02, 0.01, "does not collapse")):
        movers = [ln for ln in format_classes(_results(moving_hole, parked_hole), label).splitlines()
                  if ln.startswith("- ") and "moving" in ln]
        assert [ln.split(":")[0] for ln in movers] == ["- Mono2", "- MCDP (m = 2)"], movers
        for ln in movers:
            numbers = re.findall(r"(?<!\w)\d+(?:\.\d+)?", ln.split(":", 1)[1])  # 60.0 % ... 2x ... 5.0 %; 300 ... 3
            assert numbers == [f"{100 * moving_hole:.1f}", "2", f"{100 * parked_hole:.1f}", "300", "3"], ln
            assert ln.endswith(verdict) or f": {verdict} " in ln, ln


def test_no_section_without_labels():
    r = _results(0.0, 0.0)
    r["flat"] = [{k: v for k, v in f.items() if not k.startswith("median.class")} for f in r["flat"]]
    assert not has_classes(r) and format_classes(r, str) == ""
