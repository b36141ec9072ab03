"""The statistics of the sweep's results (study.results.summary): Student-t intervals and paired differences."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from study.results.paired import paired_difference
from study.stats.power import t_halfwidth
from study.results.summary import (SCHEMA, aggregate_flat, evaluations, evaluations_of, flat_rows, method_agg,
                           upgrade_results)
from study.results.files import read_results
from study.sweep.variants import CUT, TRAINED, Evaluation


def test_t_halfwidth_matches_the_t_table():
    # n = 3: t(0.975, 2) = 4.303; sd 1 -> 4.303 / sqrt(3)
    assert t_halfwidth(1.0, 3) == pytest.approx(4.303 / math.sqrt(3))
    assert t_halfwidth(2.0, 10) == pytest.approx(2.262 * 2 / math.sqrt(10))
    assert math.isnan(t_halfwidth(1.0, 1))


def _results(a, b):
    flat = [{"overlap": 0.3, "method": "mcdp_m2", "variant": "trained", "seed": s, "x": v} for s, v in enumerate(a)]
    flat += [{"overlap": 0.3, "method": "mono2", "variant": "trained", "seed": s, "x": v} for s, v in enumerate(b)]
    return {"flat": flat}


def test_paired_difference_pairs_by_seed_and_says_which_side():
    # the seeds move both methods together: paired, the difference is clear though each spread is wide
    r = _results([1.10, 2.12, 3.09], [1.00, 2.00, 3.00])
    d = paired_difference(r, 0.3, "mcdp_m2", "mono2", "x")
    assert d["n"] == 3 and d["mean"] == pytest.approx(0.1033, abs=1e-3) and d["differs"] == 1
    same = paired_difference(_results([1.0, 2.1, 2.9], [1.05, 2.0, 3.0]), 0.3, "mcdp_m2", "mono2", "x")
    assert same["differs"] == 0
    nan = paired_difference(_results([float("nan"), 1.0], [1.0, 1.0]), 0.3, "mcdp_m2", "mono2", "x")
    assert nan["n"] == 1 and nan["differs"] == 0


def test_a_difference_that_rounds_to_zero_is_still_written_and_a_negligible_one_is_not_called_better():
    from study.results.summary import fmt_diff, verdict_word

    tiny = {"mean": 1.5e-05, "ci95": 1.3e-05, "differs": 1}
    assert fmt_diff(tiny, 4) == "+1.5e-05 ± 1.3e-05"  # not '+0.0000 ± 0.0000'
    assert fmt_diff({"mean": -0.0123, "ci95": 0.004, "differs": -1}, 3) == "-0.012 ± 0.004"
    assert fmt_diff({"mean": 0.0, "ci95": 0.0, "differs": 0}, 3) == "+0.000 ± 0.000"
    assert fmt_diff({"mean": float("nan"), "ci95": float("nan"), "differs": 0}) == "—"  # nothing measured
    assert verdict_word(tiny, 0.0005, key="abs_rel").startswith("beyond the interval but negligible")
    assert "worse" in verdict_word(tiny, key="abs_rel")  # without a floor it is a difference
    assert "better" in verdict_word({"mean": -0.01, "ci95": 0.004, "differs": -1}, 0.0005, key="none.mean.abs_rel")
    # a1 is higher-is-better (`mcdp.metrics.Metric.better`): the same difference reads the other way
    assert verdict_word(tiny, key="none.mean.a1") == "**higher (better)**"
    assert verdict_word({"mean": -0.01, "ci95": 0.004, "differs": -1}, key="a1") == "**lower (worse)**"


def test_the_setup_names_only_the_sweeps_methods_and_the_head_each_starts_from():
    from study.sweep.pretrain import warm_start_line

    assert warm_start_line(["mono2", "mcdp_m1_nocon", "mcdp_m2"]) == (
        "Mono2 starts from its mono head; MCDP (w/o L_con, m = 1) and MCDP (m = 2) from its basis channels; "
        "MCDP (w/o L_con, m = 1)'s weight networks and MCDP (m = 2)'s weight networks start fresh")
    assert warm_start_line(["mono2", "fsm", "surround", "mcdp_m2"]) == (
        "Mono2, FSM and SurroundDepth start from its mono head; MCDP (m = 2) from its basis channels; "
        "SurroundDepth's cross-view blocks and MCDP (m = 2)'s weight networks start fresh")
    assert warm_start_line(["mcdp_m0", "mcdp_m2"]) == (
        "MCDP (m = 0) and MCDP (m = 2) start from its basis channels; MCDP (m = 2)'s weight networks start fresh")
    assert warm_start_line(["mono2"]) == "Mono2 starts from its mono head"


def test_the_warm_start_line_reads_the_network_not_its_name():
    """A row named nothing like a built-in method gets the line its network's declared members give."""
    from mcdp import methods
    from mcdp.methods.surround import SurroundDepthModel
    from study.sweep.pretrain import warm_start_line

    methods.register(methods.Method("xview", "X-View", {"model.method": "surround", "model.refine_steps": 0},
                                    SurroundDepthModel))
    try:
        assert warm_start_line(["xview"]) == "X-View starts from its mono head; X-View's cross-view blocks start fresh"
    finally:
        methods.METHODS.pop("xview")


def test_a_report_names_the_pretraining_inside_its_sweep_folder_not_by_a_machines_path():
    from study.sweep.pretrain import weights_in_sweep as _in_sweep

    assert _in_sweep("/work/sweeps/cpu/pretrain/d204638a9d4d/pretrained.pt") == "pretrain/d204638a9d4d/pretrained.pt"
    assert _in_sweep("/x/pretrain/sweep/pretrain/abc/pretrained.pt") == "pretrain/abc/pretrained.pt"  # the last one
    assert _in_sweep("pretrain/abc/pretrained.pt") == "pretrain/abc/pretrained.pt"
    assert _in_sweep("/elsewhere/weights.pt") == "/elsewhere/weights.pt"  # not a sweep's: as recorded


def test_the_t_table_is_scipys_quantile_to_three_decimals():
    """study.results.summary keeps a 30-entry table instead of depending on scipy (its comment says why); where
    scipy is installed (the nuScenes devkit pulls it in), every entry is its t.ppf(0.975, df)."""
    stats = pytest.importorskip("scipy.stats")
    from study.stats.power import T975

    assert len(T975) == 30
    for df, t in enumerate(T975, start=1):
        assert t == pytest.approx(round(float(stats.t.ppf(0.975, df)), 3), abs=1e-9), df


DATA = Path(__file__).resolve().parent / "data"


def _json(x) -> str:
    return json.dumps(x, sort_keys=True)  # NaN-safe equality (NaN != NaN in a plain ==)


def _current(old: dict) -> dict:
    """The results today's code makes of the legacy fixture's per-run rows (unchanged between the formats)."""
    flats = [f for r in old["rows"] for f in flat_rows(r)]
    evs = evaluations_of(old["methods"], flats)
    return {**old, "schema": SCHEMA, "evaluations": [e.record() for e in evs], "flat": flats,
            "aggregate": aggregate_flat(flats, old["overlaps"], evs)}


def test_a_results_json_written_before_the_variant_field_reads_as_its_current_twin():
    """results_v1.json (schema 1: "mcdp_m2@cut" method names; tests/study/data/make_results_v1.py) loads to the
    flat rows, evaluations and aggregates that today's code makes of the same runs."""
    raw = json.loads((DATA / "results_v1.json").read_text())
    assert "schema" not in raw and "mcdp_m2@cut" in raw["evaluations"]  # the fixture is the old format
    old, new = read_results(DATA / "results_v1.json"), _current(raw)
    assert old["schema"] == SCHEMA
    for part in ("evaluations", "flat", "aggregate"):
        assert _json(old[part]) == _json(new[part]), part
    assert Evaluation("mcdp_m2", CUT) in evaluations(old) and Evaluation("mono2", CUT) not in evaluations(old)
    assert [str(e) for e in evaluations(old)][:3] == ["mono2", "mcdp_m2", "mcdp_m2 (cut)"]
    for o in old["overlaps"]:
        for ev in evaluations(new):
            for key in ("median.mean.abs_rel", "dep_con.mean", "refine.headroom_closed"):
                assert _json(method_agg(old, o, ev, key)) == _json(method_agg(new, o, ev, key)), (o, ev, key)
        cut = Evaluation("surround", CUT)
        assert paired_difference(old, o, "surround", cut, "median.mean.abs_rel")["n"] == 2
    assert upgrade_results(new) is new  # the current schema passes as it is


def test_a_results_csv_written_before_the_variant_field_reads_as_its_current_twin(tmp_path):
    """results_v1.csv (no variant column) rebuilds the same numbers as the results.csv today's code writes of the
    same runs; in that one a cut evaluation's row has the registry name as method and variant "cut"."""
    import csv

    from study.results.files import write_csv

    new = _current(json.loads((DATA / "results_v1.json").read_text()))
    write_csv(new, tmp_path / "results.csv")
    rows = list(csv.DictReader((tmp_path / "results.csv").open()))
    assert list(rows[0])[:7] == ["overlap", "method", "variant", "seed", "world", "target_overlap", "measured_overlap"]
    cut = [r for r in rows if r["variant"] == CUT]
    assert {r["method"] for r in cut} == {"mcdp_m2", "surround"} and len(cut) == 8
    assert not any("@" in r["method"] for r in rows)
    assert {(r["method"], r["variant"]) for r in rows if r["status"] == "reference"} == {
        ("constant_reference", ""), ("flat_road_prior", "")}
    old, cur = read_results(DATA / "results_v1.csv"), read_results(tmp_path / "results.csv")
    for part in ("overlaps", "methods", "seeds", "evaluations", "data", "flat", "aggregate"):
        assert _json(old[part]) == _json(cur[part]), part
    for o in new["overlaps"]:  # and the numbers of the results.json itself
        for ev in evaluations(new):
            a, b = (method_agg(r, o, ev, "median.non_overlap.abs_rel") for r in (old, new))
            assert a["mean"] == pytest.approx(b["mean"], rel=1e-12) and a["n"] == b["n"] == 2, (o, ev)


def test_a_legacy_name_with_an_unknown_variant_or_a_newer_schema_is_refused():
    with pytest.raises(ValueError, match="variant 'bogus' is not one of trained, cut, oracle, oracle_overlap"):
        upgrade_results({"flat": [{"overlap": 0.3, "method": "mcdp_m2@bogus", "seed": 0}]})
    with pytest.raises(ValueError, match="results schema 3"):
        upgrade_results({"schema": 3, "flat": []})
    with pytest.raises(ValueError, match="the variant is a field"):
        method_agg(read_results(DATA / "results_v1.json"), 0.3, "mcdp_m2@cut", "median.mean.abs_rel")
    assert Evaluation.of("mono2") == Evaluation("mono2", TRAINED)
    assert Evaluation.of({"method": "mcdp_m2", "variant": "cut"}) == Evaluation("mcdp_m2", CUT)
