"""The report describes each run from what it recorded (issue 42, item 2): a row's ``run_config``, or for results
written before it the config the recorded sweep config re-resolves to under the run's recorded hash; the
registry's defaults only where neither is there, and the report says so."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest

from mcdp.methods import METHODS
from study.results.recorded import run_configs
from study.report.compose import format_report
from study.results.files import read_results

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", ["propagation", "propagation_budget", "sweep_cpu", "sweep_compare"])
def test_every_committed_run_is_described_from_the_config_its_hash_records(name):
    res = read_results(ROOT / "docs" / "results" / name / "results.json")
    configs, fallback = run_configs(res)
    assert fallback == [] and set(configs) == set(res["methods"])
    for m, cfg in configs.items():
        assert cfg.refine_steps == METHODS[m].defaults["model.refine_steps"], m  # as its row makes it


def test_a_recorded_run_config_is_read_and_a_missing_one_is_said():
    res = read_results(ROOT / "docs" / "results" / "sweep_compare" / "results.json")
    new = copy.deepcopy(res)
    configs, _ = run_configs(res)
    for r in new["rows"]:  # a row of today's sweep: its resolved config (here with another head size)
        r["run_config"] = {"model": {**configs[r["method"]].model_dump(), "bases": 16}}
    got, fallback = run_configs(new)
    assert fallback == [] and {c.bases for c in got.values()} == {16}
    old = copy.deepcopy(res)
    for r in old["rows"]:
        if r["method"] == "surround":
            r["run_config_hash"] = "0" * 64  # not what the recorded sweep config resolves to
    assert run_configs(old)[1] == ["surround"]
    assert "(SurroundDepth: from the registry's defaults" in format_report(old, [])
    assert "from the registry's defaults" not in format_report(res, [])
