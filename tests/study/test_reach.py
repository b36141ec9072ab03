"""The propagation instruments end to end on the CI sweep: worlds paired with seeds, the distance bands,
the ORACLE of the overlap, MCDP-local and ORACLE-local, and the report's reach section and figure."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pytest

from study import cli as study_cli
from study.report.sections.reach import band_names, format_reach, paired, quantities
from study.results.summary import evaluations
from study.sweep.variants import CUT, ORACLE_OVL, Evaluation

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
METHODS = "methods=[mono2,fsm,mcdp_m2_nocon,mcdp_m2,mcdp_local,oracle_local]"


@pytest.fixture(scope="module")
def reach_sweep(tmp_path_factory, mini_sweep):
    out = tmp_path_factory.mktemp("reach") / "sw"
    mini_sweep.copy_to(out, "pretrain")  # ci.yaml's pretraining, made once for the session (conftest), reused
    rc = study_cli.main(["sweep", str(CI), "--out", str(out), "--no-progress", METHODS, "overlaps=[0.5]",
                         "seeds=[0,1]", "worlds=per_seed", "jobs=1", "keep_last=false"])
    assert rc == 0
    res = json.loads((out / "results.json").read_text())
    assert res["pretrain"]["sha256"] == mini_sweep.results["pretrain"]["sha256"]
    return out, res


@pytest.mark.slow  # a sweep of 12 runs (reach_sweep)
def test_worlds_are_paired_with_seeds(reach_sweep):
    out, res = reach_sweep
    d = res["data"][0]
    assert d["world"] == "per_seed" and d["data_seeds"] == [0, 1]  # tiny.yaml's seed 0, + k for seed k
    paths = {w["path"] for w in d["worlds"]}
    assert len(paths) == 2 and all(Path(p).name in ("overlap_0.50_w0", "overlap_0.50_w1") for p in paths)
    hashes = {w["config_hash"] for w in d["worlds"]}
    assert len(hashes) == 2  # two worlds, not one world twice
    for r in res["rows"]:  # seed k trained on world k
        rd = json.loads((Path(r["run_dir"]) / "metrics_test.json").read_text())
        assert Path(rd["run"]["data"]).name == f"overlap_0.50_w{r['seed']}"
    ref = [w["reference"]["metrics"]["median"]["mean"]["abs_rel"] for w in d["worlds"]]
    assert d["reference"]["metrics"]["median"]["mean"]["abs_rel"] == pytest.approx(sum(ref) / 2)


@pytest.mark.slow  # a sweep of 12 runs (reach_sweep)
def test_every_instrument_is_in_the_results(reach_sweep):
    out, res = reach_sweep
    names = set(evaluations(res))
    for m, v in (("mcdp_m2", CUT), ("mcdp_m2_nocon", CUT), ("mcdp_local", CUT), ("oracle_local", CUT),
                 ("mcdp_m2", ORACLE_OVL), ("mcdp_local", ORACLE_OVL)):
        assert Evaluation(m, v) in names, (m, v)
    assert Evaluation("mono2", CUT) not in names and Evaluation("fsm", CUT) not in names  # they read no other camera
    bands = band_names(res)
    assert bands == ["overlap", "0-0.10", "0.10-0.20", "0.20-0.35", ">0.35"]
    with open(out / "results.csv") as f:
        header = next(csv.reader(f))
    assert "median.band.overlap.abs_rel" in header and "median.band.>0.35.abs_rel" in header
    q = quantities(res, 0.5)
    for k in ("global headroom (init - ORACLE-overlap weights)", "local headroom (ORACLE-local emptied - filled)",
              "L_con: training-time (w/o L_con cut - with L_con cut)", "mcdp_local: inference-time (cut - as trained)"):
        assert q[k]["n"] == 2, k  # paired over both (world, seed) pairs
    # the band of the overlap is the overlap region: the same pixels, the same number
    for f in res["flat"]:
        a, b = f.get("median.band.overlap.abs_rel"), f.get("median.overlap.abs_rel")
        if isinstance(a, float) and math.isfinite(a):
            assert a == pytest.approx(b, rel=1e-9)


@pytest.mark.slow  # a sweep of 12 runs (reach_sweep)
def test_report_has_the_reach_section_and_figure(reach_sweep):
    out, res = reach_sweep
    text = (out / "report.md").read_text()
    assert "How far does the overlap reach?" in text and "By distance from the overlap" in text
    assert "Per overlap, in words (non-overlap pixels)" in text
    assert "plots/propagation_by_distance.png" in text and (out / "plots" / "propagation_by_distance.png").is_file()
    assert format_reach(res, str) in text
    assert "world k trained with seed k" in text


def test_paired_difference_over_columns():
    res = {"flat": [{"overlap": 0.3, "method": "a", "variant": "trained", "seed": s, "x": 1.0 + s, "y": 0.5}
                    for s in range(3)]
           + [{"overlap": 0.3, "method": "b", "variant": "trained", "seed": s, "x": 0.5 + s} for s in range(3)]}
    pd = paired(res, 0.3, ("a", "x"), ("b", "x"))
    assert pd["mean"] == pytest.approx(0.5) and pd["n"] == 3 and pd["ci95"] == pytest.approx(0.0)
    assert pd["differs"] == 1
    assert paired(res, 0.3, ("a", "y"), ("b", "y"))["n"] == 0  # b has no y: nothing to pair
