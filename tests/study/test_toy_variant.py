"""A variant is one entry of study/sweep/variants.py plus its probe (issue 42, item 3): from the probe loop to the
results a run's evaluations travel as {variant: entry}, with no stage name, file suffix or row key in between.
A toy variant registered here (and removed after) reaches the run's row, the flat rows, the aggregate and the
results' evaluations of a real sweep without any other edit; rows written before ``row["evaluations"]`` give
the same flat rows."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from study.sweep import variants
from study.results.summary import flat_rows, row_evaluations
from study.sweep.variants import TRAINED, Evaluation, Variant

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
DATA = Path(__file__).resolve().parent / "data"

TOY = "doubled"


class _Doubled:
    """The toy variant's probe: the as-trained prediction at twice the depth (median scaling undoes it)."""

    def __init__(self, pred):
        from study.sweep.probes import Probed

        self.inner = Probed(pred)

    def predict(self, seq: str, frame: int) -> dict:
        return {k: 2.0 * v for k, v in self.inner.predict(seq, frame).items()}

    @property
    def refinement(self) -> dict:
        return self.inner.refinement


def _doubled_probe(pred, oracle_range, earlier, stages):
    assert TRAINED in earlier  # the passes made before it
    return _Doubled(pred)


@pytest.fixture
def toy_variant():
    variants.register(Variant(TOY, "as trained at twice the depth", _doubled_probe))
    yield TOY
    variants.unregister(TOY)


def test_rows_written_before_evaluations_give_the_same_flat_rows():
    """A legacy row (metrics, metrics_cut, metrics_oracle, ... keys: results_v1.json) and the same run as
    ``{variant: entry}`` make the same flat rows, in the same order."""
    old = json.loads((DATA / "results_v1.json").read_text())
    for row in old["rows"]:
        legacy = {k: v for k, v in row.items() if not k.startswith(("metrics", "refinement"))}
        new = {**legacy, "evaluations": row_evaluations(row)}
        assert json.dumps(flat_rows(new)) == json.dumps(flat_rows(row))
    assert set(row_evaluations(old["rows"][2])) == {"trained", "cut", "oracle", "oracle_overlap"}  # mcdp_m2


def test_a_toy_variant_is_refused_once_unregistered(toy_variant):
    assert Evaluation("mono2", TOY).variant == TOY
    variants.unregister(TOY)
    with pytest.raises(ValueError, match="variant 'doubled' is not one of"):
        Evaluation("mono2", TOY)
    variants.register(Variant(TOY, "again", _doubled_probe))  # for the fixture's teardown


@pytest.mark.slow  # the smallest sweep's worlds and pretraining, one run trained and evaluated
def test_a_toy_variant_reaches_the_results_of_a_sweep(toy_variant, mini_sweep, tmp_path):
    from study import cli as study_cli

    dst = mini_sweep.copy_to(tmp_path / "sweep", "data", "pretrain")  # its worlds and pretraining, no run
    assert study_cli.main(["sweep", str(CI), "--out", str(dst), *mini_sweep.args]) == 0
    res = json.loads((dst / "results.json").read_text())
    assert (res["counters"]["trained"], res["counters"]["evaluated"]) == (1, 1)
    row = res["rows"][0]
    assert list(row["evaluations"])[-1] == TOY and (Path(row["run_dir"]) / f"metrics_test_{TOY}.json").is_file()
    assert {"method": "mono2", "variant": TOY} in res["evaluations"]
    flat = {f["variant"]: f for f in res["flat"]}
    agg = {a["variant"]: a["metrics"] for a in res["aggregate"]}
    assert TOY in flat and TOY in agg
    # twice the depth: the same median-scaled error, another metric one
    assert flat[TOY]["median.mean.abs_rel"] == pytest.approx(flat[TRAINED]["median.mean.abs_rel"], rel=1e-4)
    assert flat[TOY]["none.mean.abs_rel"] != pytest.approx(flat[TRAINED]["none.mean.abs_rel"], rel=1e-2)
    assert f",{TOY}," in (dst / "results.csv").read_text()
