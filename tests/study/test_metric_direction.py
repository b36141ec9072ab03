"""A metric is one row with a direction (issue 50, item 3): a toy higher-is-better metric is worded right in a
report (its gains are new − ref, its verdicts "higher (better)"), and results written before a metric read the
same from results.json and results.csv (the metric absent in both, never a NaN column in one)."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from mcdp import metrics as M
from study.results.paired import paired_difference, paired_gain
from study.results.summary import BASELINE, aggregate_flat, evaluations, verdict_word, yardstick_row
from study.results.files import read_results

ROOT = Path(__file__).resolve().parents[2]
PROP = ROOT / "docs" / "results" / "propagation"


@pytest.fixture
def toy_acc(monkeypatch):
    """A higher-is-better toy metric, one row added to `METRICS` for one test."""
    monkeypatch.setattr(M, "METRICS", M.METRICS + (M.Metric("toy_acc", lambda x: -x.d, better="higher"),))
    return "toy_acc"


def _with_toy(res: dict) -> dict:
    """The committed propagation results with a column ``none.mean.toy_acc`` = −``none.mean.abs_rel`` in every flat
    row: an accuracy that is exactly as much better as abs_rel is lower."""
    flat = [{**f, **({"none.mean.toy_acc": -f["none.mean.abs_rel"]} if "none.mean.abs_rel" in f else {})}
            for f in res["flat"]]
    return {**res, "flat": flat, "aggregate": aggregate_flat(flat, res["overlaps"], evaluations(res))}


def test_a_toy_higher_is_better_metric_is_worded_right_in_the_report(toy_acc, monkeypatch):
    from mcdp.methods import label
    from study.report.sections import verdicts
    res = _with_toy(read_results(PROP / "results.json"))
    o, m = res["overlaps"][0], "mcdp_m2"
    acc, err = paired_gain(res, o, BASELINE, m, "none.mean.toy_acc"), paired_gain(res, o, BASELINE, m, "none.mean.abs_rel")
    assert acc["mean"] == pytest.approx(err["mean"], abs=1e-15) and acc["differs"] == err["differs"]
    raw = paired_difference(res, o, BASELINE, m, "none.mean.toy_acc")  # Mono2 − method: the other sign
    assert raw["mean"] == pytest.approx(-err["mean"], abs=1e-15)
    hit = next(pd for mm in res["methods"] if mm != BASELINE for oo in res["overlaps"]
               for pd in [paired_difference(res, oo, mm, BASELINE, "none.mean.toy_acc")] if pd["differs"])
    assert verdict_word(hit, key="none.mean.toy_acc") == {1: "**higher (better)**", -1: "**lower (worse)**"}[hit["differs"]]
    # each mechanism's verdict in metric scaling, read on abs_rel and on the toy accuracy side by side: the same words
    monkeypatch.setattr(verdicts, "METRIC_KEYS", (("none.mean.abs_rel", "metric, all px"),
                                                  ("none.mean.toy_acc", "metric, all px")))
    lines = [ln for ln in verdicts.format_verdicts(res, label).splitlines() if "in metric scaling: " in ln]
    assert len(lines) >= 2
    for ln in lines:
        tail = ln.split("in metric scaling: ")[1].rstrip(".")
        part = tail[:(len(tail) - 2) // 2]
        assert tail == f"{part}; {part}" and "more accurate" in part, ln
    assert any("more accurate at" in ln or "more accurate from" in ln for ln in lines)  # a gain worded as one

def _finite(row: dict) -> set[str]:
    return {k for k, v in row.items() if "." in k and isinstance(v, (int, float)) and math.isfinite(v)}


def test_results_written_before_a_metric_read_the_same_from_json_and_csv(toy_acc):
    from study.report.compose import format_report

    js, cs = read_results(PROP / "results.json"), read_results(PROP / "results.csv.gz")
    for o in js["overlaps"]:
        for which in ("reference", "prior"):
            a, b = yardstick_row(js, o, which), yardstick_row(cs, o, which)
            assert a and not [k for k in a if k.endswith(".toy_acc")] and not [k for k in b if k.endswith(".toy_acc")]
            assert _finite(a) == _finite(b) and len(_finite(a)) > 20
    for part in ("flat", "aggregate"):
        for rec in js[part] + cs[part]:
            keys = rec.get("metrics", rec)
            assert not [k for k in keys if k.endswith("toy_acc")]
    # the report tabulates the toy's column, empty ('nan') for both readers alike
    assert "| toy_acc |" in format_report(js, [])
