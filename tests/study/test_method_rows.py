"""The report chooses methods by their registry row (issue 42, item 2), never by name: a toy method registered
here, a mechanism in its row, appears in the paired figure's series, the reach section and the distance figure
with no edit of the study; the README's ``model.method`` choices are the registry's."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from mcdp import methods
from study.report.plots import PAIRED_KEYS, distance_lines, paired_series
from study.report.sections.reach import format_reach, quantities, readers
from study.results.paired import paired_difference
from study.results.summary import BASELINE
from study.results.files import read_results

ROOT = Path(__file__).resolve().parents[2]
PROP = ROOT / "docs" / "results" / "propagation" / "results.json"


@pytest.fixture
def toy():
    """A toy method's one row (its network is never built here), registered for one test and removed after."""
    row = methods.register(methods.Method("toy", "Toy net", {"model.method": "toy"}, "mcdp.methods.base:DepthNetwork",
                                          reach=("mechanism",)))
    yield row
    methods.unregister("toy")


def _with_toy(res: dict, like: str = "mcdp_local") -> dict:
    """The committed propagation results with a method "toy" whose runs are a copy of ``like``'s (every variant)."""
    def copy(rows):
        return rows + [{**r, "method": "toy"} for r in rows if r["method"] == like]

    return {**res, "methods": [*res["methods"], "toy"], "flat": copy(res["flat"]), "aggregate": copy(res["aggregate"]),
            "evaluations": copy(res["evaluations"])}


def test_a_toy_method_is_in_the_paired_figure_and_the_reach_section_without_a_study_edit(toy):
    res = _with_toy(read_results(PROP))
    series = paired_series(res)
    for key, _ in PAIRED_KEYS:
        assert series[key]["toy"] == [paired_difference(res, o, BASELINE, "toy", key) for o in res["overlaps"]]
        assert series[key]["toy"] == series[key]["mcdp_local"]  # the same runs, the same numbers
    assert readers()[-2:] == ["toy", "surround"]  # the mechanisms (with their twins), then the other readers
    o = res["overlaps"][0]
    q = quantities(res, o)
    assert q["toy: inference-time (cut - as trained)"] == q["mcdp_local: inference-time (cut - as trained)"]
    assert q["toy: vs Mono2 (Mono2 - toy)"] == q["mcdp_local: vs Mono2 (Mono2 - mcdp_local)"]
    text = format_reach(res, methods.label)
    assert "Toy net cut - trained" in text and "Mono2 - Toy net" in text  # the band table's columns
    assert [n for n, _, _ in distance_lines(res) if "Toy net" in n] == ["Mono2 − Toy net", "Toy net: cut − as trained"]


def test_without_the_toy_the_reach_section_is_the_committed_one(toy):
    """Registered but absent from the results, the toy changes nothing (the committed reports rebuild: test_plots)."""
    res = read_results(PROP)
    text = format_reach(res, methods.label)
    methods.unregister("toy")
    try:
        assert format_reach(res, methods.label) == text and "toy" not in text
    finally:
        methods.register(toy)


def test_the_rows_flags_name_the_baseline_the_yardsticks_and_the_twins():
    assert methods.baseline() == BASELINE == "mono2"
    assert [m.name for m in methods.METHODS.values() if m.role == "yardstick"] == ["oracle_local"]
    assert methods.nocon_twins("mcdp_m2") == ["mcdp_m2_nocon"] and methods.nocon_twins("mcdp_m1") == ["mcdp_m1_nocon"]
    for m in methods.METHODS.values():
        assert m.role in ("baseline", "method", "yardstick"), m.name
        assert set(m.reach) <= {"mechanism", "reader", "global", "local"}, m.name
        assert m.nocon_of is None or m.nocon_of in methods.METHODS, m.name


def test_mcdp_presets_lists_every_row_and_the_readme_points_there(toy, capsys):
    """The README lists no method by hand: it points to ``mcdp presets methods``, which lists every registered row
    (a toy one too), its ``model.method`` and its role, in table order."""
    from study.method_commands import main

    text = (ROOT / "docs" / "GUIDE.md").read_text()  # moved from the README (issue 60)
    assert re.search(r"`model\.method`\s*\(the network a registered method trains: `mcdp presets methods`", text)
    assert not re.search(r"`model\.method`\s*\(`\w+`\s*\|", text)  # no hand-written list to keep in step
    assert main(["presets", "methods"]) == 0
    rows = capsys.readouterr().out.splitlines()[1:]
    assert [r.split()[0] for r in rows] == list(methods.METHODS) and rows[-1].split()[0] == "toy"
    for r in rows:
        m = methods.METHODS[r.split()[0]]
        assert f"model.method={m.defaults['model.method']} " in r and r.endswith(f"{m.label} ({m.role})"), r
