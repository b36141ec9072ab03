"""The sweep's figures (study/report/plots.py) from committed data: the paired-difference figure draws
study.results.summary' paired differences, a results.csv alone rebuilds the plots' numbers, and the committed
propagation report is what the code writes from its committed results.json."""
from __future__ import annotations

import math
from pathlib import Path

import pytest

from study.report.plots import PAIRED_KEYS, make_plots, paired_plot, paired_series
from study.report.compose import format_report
from study.results.paired import paired_difference
from study.results.summary import BASELINE, method_agg, yardstick_agg
from study.results.files import read_results, results_from_csv

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
            assert pd == paired_difference(prop, o, BASELINE, "mcdp_local", key)  # the report's numbers: Mono2 − method
            assert pd["n"] == len(prop["seeds"]) == 6  # 3 worlds x 2 seeds


def test_no_paired_figure_without_mono2(prop, tmp_path):
    assert paired_plot(_small(prop, ("fsm", "mcdp_local")), tmp_path) is None


def test_make_plots_writes_the_paired_and_absolute_figures(prop, tmp_path):
    names = [p.name for p in make_plots(_small(prop), tmp_path)]
    assert names == ["paired_vs_mono2.png", "abs_rel_vs_overlap.png", "dep_con_vs_overlap.png",
                     "overlap_vs_non_overlap_abs_rel.png", "measured_overlap.png"]


def test_results_csv_rebuilds_the_numbers_the_plots_read(prop):
    csv = results_from_csv(PROP / "results.csv.gz")
    assert csv["overlaps"] == prop["overlaps"] and csv["methods"] == prop["methods"]
    # results.csv holds no design (worlds x seeds): given the sweep's, its paired intervals are clustered by world
    # as results.json's are (issue 49, item 10)
    csv["sweep_config"] = {k: prop["sweep_config"].get(k) for k in ("worlds", "seeds_per_world")}
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
    from study.report.sections.propagation import format_propagation

    results = read_results(ROOT / "docs" / "results" / "sweep_compare" / "results.json")
    lines = [ln for ln in format_propagation(results, label).splitlines() if ", SurroundDepth: propagation" in ln]
    assert len(lines) == 4 and any("negligible" in ln for ln in lines), lines
    assert not any("(worse)" in ln or "(better)" in ln for ln in lines), lines


def test_the_verdict_section_says_better_only_where_the_paired_interval_does(prop):
    text = format_report(prop, [])
    start = text.index("Against the yardsticks (abs_rel, mean over seeds)")
    sec = text[start:text.index("\n## ", start)]
    assert "beat Mono2" not in sec and "beats Mono2" not in sec  # no raw-mean comparison with Mono2
    assert "Mono2 − each method (positive = helps), paired over seeds" in sec
    # the words follow the paired intervals (metric scaling, all and non-overlap pixels), whatever the data
    from study.results.summary import gain_word as verdict_word

    from study.report.sections.mechanisms import is_yardstick

    words = [verdict_word(paired_difference(prop, o, BASELINE, m, f"none.{region}.abs_rel"))
             for o in prop["overlaps"] for m in prop["methods"] if m != BASELINE and not is_yardstick(prop, m)
             for region in ("mean", "non_overlap")]
    assert sec.count("**helps**") == words.count("**helps**")
    assert sec.count("**hurts**") == words.count("**hurts**")
    assert sec.count("no difference beyond the interval") == words.count("no difference beyond the interval")
    assert "paired over seeds: " in sec and "ORACLE-local (GT overlap input) -" not in sec  # a yardstick: no verdict
    headings = [ln for ln in text.splitlines() if ln.startswith("#") and "verdict" in ln.lower()]
    assert headings == ["## Verdicts"], headings  # one verdict section (issue 41)


# --------------------------------------------------------------------------- issue 41, item 14: the figures
def test_the_distance_figure_uses_its_canvas_one_sign_and_clips_a_wild_band(prop):
    """propagation_by_distance.png: the legend below the panels (it took the right 22 % of the canvas), every
    line a − b, worse minus better, positive = helps (issue 49: the pages' one sign),
    and a band whose mean is far out is drawn at the edge with its value written instead of setting the range."""
    import copy

    from study.report.plots import distance_figure, distance_lines
    from study.report.sections.reach import paired

    fig = distance_figure(prop)
    assert max(ax.get_position().x1 for ax in fig.axes) > 0.9
    names = [n for n, _, _ in distance_lines(prop)]
    assert "Mono2 − MCDP (m = 2)" in names and "MCDP (m = 2): cut − as trained" in names
    assert "ORACLE-local (yardstick): emptied − filled" in names
    ax = fig.axes[0]
    line = next(c for c in ax.containers if c.get_label() == "Mono2 − MCDP (m = 2)").lines[0]
    want = paired(prop, 0.1, ("mono2", "median.band.>0.35.abs_rel"), ("mcdp_m2", "median.band.>0.35.abs_rel"))
    assert line.get_ydata()[-1] == pytest.approx(max(-ax.get_ylim()[1], min(ax.get_ylim()[1], want["mean"])), rel=0.06)
    wild = copy.deepcopy(prop)
    for f in wild["flat"]:
        if f["method"] == "mcdp_m2" and f["variant"] == "trained" and f["overlap"] == 0.1:
            f["median.band.>0.35.abs_rel"] -= 5.0
    fig = distance_figure(wild)
    assert fig.axes[0].get_ylim()[1] < 0.05  # one band at +5 does not set the panel's range (the others: < 0.03)
    assert any(t.get_text().startswith("+5.0") for t in fig.axes[0].texts)
    assert "clipped" in fig.axes[0].get_title()


def test_overlap_figure_is_one_small_panel_per_method_and_scaling(prop):
    """overlap_vs_non_overlap_abs_rel.png drew 2 x (methods) lines on each of two panels (12 for the propagation
    sweep's rows); now one panel per method and scaling, two lines each."""
    from study.report.plots import overlap_figure

    fig = overlap_figure(prop)
    assert len(fig.axes) == 2 * len(prop["methods"])
    assert all(len(ax.get_lines()) == 2 for ax in fig.axes)


def test_the_measured_overlap_legend_says_what_is_drawn(prop):
    """With the pixels knob the dotted y = x line is the target pixel overlap, not the geometric one (the legend
    said "target (geometric)"); the geometric overlap of the solved layout is drawn as a line of its own."""
    from study.report.plots import measured_figure

    names = [t.get_text() for t in measured_figure(prop).axes[0].get_legend().get_texts()]
    assert names == ["target pixel overlap (the knob; y = x)", "measured pixel overlap",
                     "geometric overlap of the solved layout"]
    angle = {**prop, "data": [{**d, "measured": {**d["measured"], "knob": "angle"}} for d in prop["data"]]}
    names = [t.get_text() for t in measured_figure(angle).axes[0].get_legend().get_texts()]
    assert names == ["target = geometric overlap, shared fraction of hfov (y = x)", "measured pixel overlap"]


@pytest.mark.parametrize("name", ["propagation", "propagation_budget", "sweep_cpu", "sweep_compare"])
def test_committed_reports_have_one_verdict_section_free_of_yardsticks(name):
    """Issue 41, item 13: each generated report had four headings of verdicts, and its line "In one line" named
    MCDP (w/o L_con) better at 0.60 alone "from some overlap on" (sweep_cpu) and the ground-truth yardstick
    ORACLE-local as a mechanism that gains (propagation); sweep_compare said no mechanism gains where its table has
    FSM and MCDP (m = 2) better at 0.30. Whatever results.json is committed, the report says it so."""
    from study.report.sections.mechanisms import from_which_overlap, is_yardstick, paired_all

    results = read_results(ROOT / "docs" / "results" / name / "results.json")
    text = (ROOT / "docs" / "results" / f"{name}.md").read_text()
    body = text[text.index("> Generated by"):]
    assert [ln for ln in body.splitlines() if ln.startswith("#") and "verdict" in ln.lower()] == ["## Verdicts"]
    one = next(ln for ln in body.splitlines() if ln.startswith("- **In one line**"))
    assert "from some overlap on" not in one and "ORACLE" not in one
    mech = [m for m in results["methods"] if m != BASELINE and not is_yardstick(results, m)]
    diffs = paired_all(results, mech)[0]
    from mcdp.methods import label

    for m in mech:
        where = from_which_overlap(diffs[m]["median.mean.abs_rel"]).split("; worse")[0]
        if where != "at no overlap of the sweep":
            assert f"{label(m)} {where}" in one, (m, one)
    assert "- **Multiple comparisons**: these lines read" in body
