"""The sweep's figures (study/plots.py) from committed data: the paired-difference figure draws
study.results' paired differences, a results.csv alone rebuilds the plots' numbers, and the committed
propagation report is what the code writes from its committed results.json."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from study.plots import PAIRED_KEYS, make_plots, paired_plot, paired_series
from study.report import format_report
from study.results import (BASELINE, method_agg, paired_difference, read_results, results_from_csv,
                           yardstick_agg)

ROOT = Path(__file__).resolve().parents[2]
PROP = ROOT / "docs" / "results" / "propagation"


@pytest.fixture(scope="module")
def prop():
    return read_results(PROP / "results.json")  # written before the variant field: read through upgrade_results


def _small(res: dict, methods=("mono2", "mcdp_local")) -> dict:
    """A small results dict: two methods of the committed propagation sweep (their rows as trained, aggregate,
    data)."""
    keep = {(m, "trained") for m in methods}
    return {**res, "methods": list(methods), "evaluations": [{"method": m, "variant": "trained"} for m in methods],
            "flat": [f for f in res["flat"] if (f["method"], f["variant"]) in keep],
            "aggregate": [a for a in res["aggregate"] if (a["method"], a["variant"]) in keep]}


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b, rel=1e-9, abs=1e-12)


def test_paired_figure_from_a_small_results(prop, tmp_path):
    small = _small(prop)
    path = paired_plot(small, tmp_path)
    assert path == tmp_path / "paired_vs_mono2.png" and path.stat().st_size > 10_000
    from PIL import Image

    w, h = Image.open(path).size
    assert w > 2 * h  # three panels side by side, the legend below
    series = paired_series(small)
    assert set(series) == {k for k, _ in PAIRED_KEYS} == {"median.mean.abs_rel", "median.non_overlap.abs_rel",
                                                          "dep_con.mean"}
    for key, per_method in series.items():
        assert list(per_method) == ["mcdp_local"]
        for o, pd in zip(small["overlaps"], per_method["mcdp_local"]):
            assert pd == paired_difference(prop, o, "mcdp_local", BASELINE, key)  # the report's numbers
            assert pd["n"] == len(prop["seeds"]) == 6  # 3 worlds x 2 seeds


def test_no_paired_figure_without_mono2(prop, tmp_path):
    assert paired_plot(_small(prop, ("fsm", "mcdp_local")), tmp_path) is None


def test_make_plots_writes_the_paired_and_absolute_figures(prop, tmp_path):
    names = [p.name for p in make_plots(_small(prop), tmp_path)]
    assert names == ["paired_vs_mono2.png", "abs_rel_vs_overlap.png", "dep_con_vs_overlap.png",
                     "overlap_vs_non_overlap_abs_rel.png", "measured_overlap.png"]


def test_results_csv_rebuilds_the_numbers_the_plots_read(prop):
    csv = results_from_csv(PROP / "results.csv")
    assert csv["overlaps"] == prop["overlaps"] and csv["methods"] == prop["methods"]
    assert csv["seeds"] == prop["seeds"]
    for o in prop["overlaps"]:
        for m in prop["methods"]:
            for key in ("median.mean.abs_rel", "none.non_overlap.abs_rel", "dep_con.mean"):
                a, b = method_agg(csv, o, m, key), method_agg(prop, o, m, key)
                assert _same(a["mean"], b["mean"]) and _same(a["ci95"], b["ci95"]), (o, m, key)
                if m != BASELINE:
                    pa, pb = paired_difference(csv, o, m, BASELINE, key), paired_difference(prop, o, m, BASELINE, key)
                    assert _same(pa["mean"], pb["mean"]) and pa["differs"] == pb["differs"], (o, m, key)
        for which in ("reference", "prior"):
            for key in ("median.mean.abs_rel", "none.mean.abs_rel"):
                assert _same(yardstick_agg(csv, o, key, which)["mean"], yardstick_agg(prop, o, key, which)["mean"])


def test_results_csv_without_rows_is_one_line_naming_the_file(tmp_path):
    bad = tmp_path / "results.csv"
    bad.write_text("a,b\n")
    with pytest.raises(ValueError, match=r"results\.csv: not a sweep's results\.csv"):
        results_from_csv(bad)


@pytest.mark.parametrize("name", ["propagation", "propagation_budget", "sweep_cpu", "sweep_compare"])
def test_committed_sweep_reports_are_what_the_publishing_command_writes(name):
    """docs/results/<name>.md is, byte for byte, what scripts/publish_sweep.py writes from the committed
    docs/results/<name>/results.json and preface.md: no report is edited by hand."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("publish_sweep", ROOT / "scripts" / "publish_sweep.py")
    publish = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(publish)
    results = read_results(ROOT / "docs" / "results" / name / "results.json")
    plots = [f"{name}/plots/{n}.png" for n in ("paired_vs_mono2", "abs_rel_vs_overlap", "dep_con_vs_overlap",
                                               "overlap_vs_non_overlap_abs_rel", "measured_overlap",
                                               "propagation_by_distance")]
    assert all((ROOT / "docs" / "results" / p).is_file() for p in plots)
    text = (ROOT / "docs" / "results" / f"{name}.md").read_text()
    assert text == publish.report_text(name, results, plots)


def test_a_cut_that_moves_the_depth_by_a_tenth_of_a_millimetre_is_negligible_not_worse():
    """sweep_compare's SurroundDepth: cutting its other cameras changes Dep Con by ~1e-8, once beyond its interval;
    the propagation verdict calls that negligible (USE_FLOOR), never better or worse."""
    from mcdp.methods import label
    from study.propagation import format_propagation

    results = read_results(ROOT / "docs" / "results" / "sweep_compare" / "results.json")
    lines = [ln for ln in format_propagation(results, label).splitlines() if ", SurroundDepth: propagation" in ln]
    assert len(lines) == 4 and any("negligible" in ln for ln in lines), lines
    assert not any("(worse)" in ln or "(better)" in ln for ln in lines), lines


def test_the_verdict_section_says_better_only_where_the_paired_interval_does(prop):
    text = format_report(prop, [])
    sec = text[text.index("### Verdicts: against the yardsticks"):text.index("## Overlap 0.10")]
    assert "beat Mono2" not in sec and "beats Mono2" not in sec  # no raw-mean comparison with Mono2
    assert "each method − Mono2, paired over seeds" in sec
    # the words follow the paired intervals (metric scaling, all and non-overlap pixels), whatever the data
    from study.results import verdict_word

    words = [verdict_word(paired_difference(prop, o, m, BASELINE, f"none.{region}.abs_rel"))
             for o in prop["overlaps"] for m in prop["methods"] if m != BASELINE for region in ("mean", "non_overlap")]
    assert sec.count("**lower (better)**") == words.count("**lower (better)**")
    assert sec.count("**higher (worse)**") == words.count("**higher (worse)**")
    assert sec.count("no difference beyond the interval") == words.count("no difference beyond the interval")
    assert any(w != "no difference beyond the interval" for w in words)  # the committed data has a verdict to say
    assert text.count("### Verdicts") == 1 + text.count("### Verdicts: which mechanism")
