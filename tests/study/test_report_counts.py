"""The report counts runs, not evaluations: a collapsed run's variant rows (cut, ORACLE weights, ...) are
evaluations of that one run (issue 41, item 15: "COLLAPSED (38 run(s))" for 14 runs)."""
from __future__ import annotations

import copy
import re
from pathlib import Path

from study.report.compose import format_report
from study.results.files import read_results

PROP = Path(__file__).resolve().parents[2] / "docs" / "results" / "propagation" / "results.json"


def test_collapsed_counts_runs_not_their_variant_rows():
    res = copy.deepcopy(read_results(PROP))
    first = res["flat"][0]
    o, seed = first["overlap"], first["seed"]
    hit = [f for f in res["flat"] if f["overlap"] == o and f["seed"] == seed and f["method"] in ("mcdp_m2", "mono2")]
    for f in hit:
        f["spread.ratio"] = 1.0
    text = format_report(res, [])
    line = next(ln for ln in text.splitlines() if "**COLLAPSED**" in ln)
    assert len(hit) == 6 and re.search(r"\(2 run\(s\), 6 evaluations of them:", line), line
