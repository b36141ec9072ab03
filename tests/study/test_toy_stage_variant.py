"""A variant with a stage of its own is one row of the variant table (issue 50, item 1): declared here, registered
through `study.sweep.variants.register` (and removed after), it rides on the as-trained pass (`Probed.stages`, its
``predict_stage``), becomes an entry of the run (`entries_of`), and, declaring the capability "spread", reaches
report.md's reach section and its primary comparisons with no edit of the report."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from study.sweep import variants
from study.sweep.probes import TRAINED, Probed
from study.report.compose import format_report
from study.results.files import read_results
from study.sweep.variants import Evaluation, Variant, entries_of, having, stages_on

ROOT = Path(__file__).resolve().parents[2]
PROP = ROOT / "docs" / "results" / "propagation" / "results.json"
TOY = "toy_spread"


def _halved(probe, seq, frame, out, depth):
    """The toy's stage: the last stage's depth, halved."""
    return 0.5 * depth


@pytest.fixture
def toy():
    v = variants.register(Variant(TOY, "as trained at half the depth", adds_stage=lambda pred, rng: rng is not None,
                                  predict_stage=_halved, capabilities=("spread",), label="toy propagator",
                                  short="halved"))
    yield v
    variants.unregister(TOY)


class _FakePredictor:
    """What `Probed` and the table's ``adds_stage`` read of a `mcdp.predict.Predictor`: a mono network (one output,
    reads no other camera) with one stage "init" of two 2x3 cameras, at 4 m."""

    stages = ["init"]
    n_out = 1
    network = type("Net", (), {"uses_neighbours": False})()

    def __init__(self):
        self.mask = torch.ones(1, 2, 2, 3, dtype=torch.bool)

    def inputs(self, seq, frame):
        return None

    def forward(self, inp):
        return {("depth", "init", 0): torch.full((2, 1, 2, 3), 4.0)}

    def stages_of(self, out):
        return {"init": out["depth", "init", 0]}

    def upsample(self, small):
        return {k: v[:, 0].numpy() for k, v in small.items()}


def test_a_toy_stage_rides_on_the_as_trained_pass_and_becomes_an_entry(toy):
    pred = _FakePredictor()
    assert stages_on(TRAINED, pred, None) == []
    assert [v.name for v in stages_on(TRAINED, pred, (0.5, 80.0))] == ["oracle_spread", TOY]
    p = Probed(pred, oracle_range=(0.5, 80.0), stages=[toy])
    out = p.predict("seq", 0)
    assert p.stages == list(out) == ["init", "final", TOY]
    assert float(out["final"].max()) == 4.0 and float(out[TOY].max()) == 2.0
    summary = {"none": {}, "dep_con": {"mean": 0.1, "per_camera": {}, "per_pair": {}}}
    stage = {"none": {"mean": {"abs_rel": 0.2}, "overlap": {}, "non_overlap": {}, "per_camera": {}},
             "dep_con": summary["dep_con"]}
    metrics = {"stages": {"init": stage, "final": stage, TOY: {**stage, "none": {**stage["none"],
                                                                               "mean": {"abs_rel": 0.3}}}}}
    entries = entries_of({TRAINED: metrics})
    assert list(entries) == [TRAINED, TOY]
    assert entries[TOY]["metrics"]["none"]["mean"]["abs_rel"] == 0.3


def _with_toy(res: dict) -> dict:
    """The committed propagation results with the baseline also evaluated as the toy: a copy of its
    ``oracle_spread`` rows (the hand-built propagator's numbers under the toy's name)."""
    def copy(rows):
        return rows + [{**r, "variant": TOY} for r in rows if r["method"] == "mono2" and r["variant"] == "oracle_spread"]

    return {**res, "flat": copy(res["flat"]), "aggregate": copy(res["aggregate"]),
            "evaluations": copy(res["evaluations"])}


def test_a_toy_variant_with_a_capability_reaches_report_md(toy):
    res = _with_toy(read_results(PROP))
    assert [v.name for v in having("spread")] == ["oracle_spread", TOY]
    text = format_report(res, [])
    want = "toy propagator (Mono2 - Mono2 halved from the overlap's ground truth)"
    theirs = "hand-built propagator (Mono2 - Mono2 corrected from the overlap's ground truth)"
    rows = {ln.split(" | ")[0]: ln.split(" | ")[1:] for ln in text.splitlines() if ln.startswith(f"| {want}")
            or ln.startswith(f"| {theirs}")}
    assert len(rows) == 2 and rows[f"| {want}"] == rows[f"| {theirs}"]  # the same rows, the same numbers
    assert "propagator: Mono2 - halved" in text  # the band table's column
    assert "toy propagator: Mono2 - Mono2 halved from the overlap's ground truth" in text  # a primary comparison
    assert "toy propagator" not in format_report(read_results(PROP), [])  # registered, absent from the results


def test_a_variant_is_a_probe_or_a_stage_and_has_known_capabilities():
    with pytest.raises(ValueError, match="either a probe of its own or a stage"):
        Variant("both", "x", lambda *a: None, adds_stage=lambda p, r: True, predict_stage=_halved)
    with pytest.raises(ValueError, match="capability 'roof' is not one of"):
        Variant("roof", "x", adds_stage=lambda p, r: True, predict_stage=_halved, capabilities=("roof",))
    with pytest.raises(ValueError, match="capability 'cut' is 'cut''s already"):
        variants.register(Variant("cut2", "x", lambda *a: None, capabilities=("cut",)))
    assert "cut2" not in variants.VARIANTS and Evaluation("mono2", "cut").variant == "cut"
