"""`mcdp sweep --engine ray` on a local Ray (2 CPUs): the local engine's rows, numbers and counters;
skipping across engines; a run that raises is rerun once, then reported by name as ``failed`` while
the other runs finish, and the sweep exits 5.

Training and evaluation on the CPU with one thread (the tiny presets' ``train.threads: 1``) are
deterministic, so the numbers are compared exactly (every numeric cell of results.csv but the
timings), not within a tolerance.
"""
from __future__ import annotations

import csv
import json
import math
import re
import shutil
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # minutes of training, rendering or processes: `pytest -m "not slow"` skips it
import yaml

pytest.importorskip("ray")

from study import cli as study_cli  # noqa: E402
from study.sweep.engines import EXIT_RUN_FAILED, errors_path  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
# one overlap, two methods, no shared pretraining, no preview: the engines' plumbing, quickly
SMALL = ["--no-progress", "overlaps=[0.3]", "methods=[mono2,mcdp_m1]", "pretrain=null", "preview=false"]
TIMINGS = {"train_s", "eval_s"}


def sweep_main(argv):
    return study_cli.main(["sweep", *argv])


def _csv(out: Path) -> list[dict]:
    return list(csv.DictReader((out / "results.csv").open()))


def _same_cells(a: dict, b: dict, ignore=TIMINGS) -> None:
    assert a.keys() == b.keys()
    for k in a:
        if k in ignore:
            continue
        try:
            x, y = float(a[k]), float(b[k])
        except ValueError:
            assert a[k] == b[k], k
            continue
        assert x == y or (math.isnan(x) and math.isnan(y)), (a["method"], k, x, y)


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    """The small sweep with the local engine (one run after the other, in process)."""
    out = tmp_path_factory.mktemp("local") / "sweep"
    assert sweep_main([str(CI), "--out", str(out), "jobs=1", *SMALL]) == 0
    yield out
    shutil.rmtree(out, ignore_errors=True)


def test_ray_sweep_gives_the_local_engines_results(local_ray, local_sweep, tmp_path, capsys):
    out = tmp_path / "ray"
    capsys.readouterr()
    assert sweep_main([str(CI), "--out", str(out), "--engine", "ray", *SMALL]) == 0
    err = capsys.readouterr().err.splitlines()
    # --no-progress: the same progress lines as the local engine, every Ray run counted as it finishes
    prog = [ln for ln in err if ln.startswith("[sweep] progress: ")]
    done = [int(re.match(r"\[sweep\] progress: (\d+)/2 runs done, elapsed \S+, ", ln).group(1)) for ln in prog]
    assert done == sorted(done) and done[-1] == 2, prog
    runs = [ln for ln in prog if ln.endswith("stage: runs")]
    assert [int(ln.split("/")[0].rsplit(" ", 1)[1]) for ln in runs] == [0, 1, 2], prog
    assert "ETA after the first run" in runs[0] and re.search(r"ETA \S+ \(\d+\.\d s/run over 2 run\(s\)\)", runs[2])
    assert any(ln.endswith("stage: render of overlap 0.30") for ln in prog), prog
    assert re.fullmatch(rf"\[sweep\] finished: 2/2 runs in \S+ wall time; report: {re.escape(str(out / 'report.md'))}",
                        [ln for ln in err if ln.startswith("[sweep] ")][-1]), err[-3:]
    loc, ray = json.loads((local_sweep / "results.json").read_text()), json.loads((out / "results.json").read_text())
    assert ray["sweep_config"]["engine"] == "ray" and loc["sweep_config"]["engine"] == "local"
    assert [(r["overlap"], r["method"], r["seed"], r["status"]) for r in ray["rows"]] == \
        [(r["overlap"], r["method"], r["seed"], r["status"]) for r in loc["rows"]] == \
        [(0.3, "mono2", 0, "ok"), (0.3, "mcdp_m1", 0, "ok")]
    assert ray["counters"] == loc["counters"]
    a, b = _csv(local_sweep), _csv(out)
    assert [(r["method"], r["variant"]) for r in a] == [(r["method"], r["variant"]) for r in b] == \
        [("mono2", "trained"), ("mono2", "oracle_spread"), ("mcdp_m1", "trained"), ("mcdp_m1", "cut"),
         ("mcdp_m1", "oracle"), ("mcdp_m1", "oracle_overlap"), ("constant_reference", ""), ("flat_road_prior", "")]
    for ra, rb in zip(a, b):
        _same_cells(ra, rb)


def test_ray_rerun_of_a_local_sweep_skips_everything(local_ray, local_sweep):
    before = _csv(local_sweep)
    assert sweep_main([str(CI), "--out", str(local_sweep), "--engine", "ray", *SMALL]) == 0
    c = json.loads((local_sweep / "results.json").read_text())["counters"]
    assert (c["rendered"], c["trained"], c["evaluated"], c["failed"]) == (0, 0, 0, 0)
    assert (c["render_skipped"], c["train_skipped"], c["eval_skipped"], c["reference_skipped"]) == (1, 2, 2, 1)
    for ra, rb in zip(before, _csv(local_sweep)):
        assert rb["train_skipped"] in ("True", "") and rb["eval_skipped"] in ("True", "")
        _same_cells(ra, rb, TIMINGS | {"train_skipped", "eval_skipped"})


def test_a_failing_run_is_retried_once_then_reported_and_the_others_finish(local_ray, local_sweep, tmp_path, capsys):
    """mcdp_m0's preset (a copy of the tiny presets) starts from a file that is no pretraining: its
    trainer raises in the worker, every attempt; mono2 and mcdp_m1 (unchanged presets) are reused."""
    presets = tmp_path / "presets"
    shutil.copytree(ROOT / "configs" / "train" / "tiny", presets)
    bogus = tmp_path / "not_a_pretraining.pt"
    bogus.write_bytes(b"not a checkpoint")
    p = yaml.safe_load((presets / "mcdp_m0.yaml").read_text())
    p["model"]["init_from"] = str(bogus)
    (presets / "mcdp_m0.yaml").write_text(yaml.safe_dump(p))

    out = local_sweep  # the finished local sweep: its two runs are skipped, the new one fails
    argv = [str(CI), "--out", str(out), "--engine", "ray", *SMALL, "methods=[mono2,mcdp_m0,mcdp_m1]",
            f"train_presets_dir={presets}"]
    capsys.readouterr()
    assert sweep_main(argv) == EXIT_RUN_FAILED == 5
    err = capsys.readouterr().err
    assert "overlap 0.30 mcdp_m0 seed 0: FAILED (rerun once; 2 attempt(s) raised): WarmStartError: " in err

    res = json.loads((out / "results.json").read_text())
    assert [(r["method"], r["status"]) for r in res["rows"]] == [("mono2", "ok"), ("mcdp_m0", "failed"),
                                                                  ("mcdp_m1", "ok")]
    bad = res["rows"][1]
    assert bad["error"].startswith("WarmStartError: model.init_from: ") and "\n" not in bad["error"]
    assert bad["failed_attempts"] == 2
    lines = errors_path(out, 0.3, "mcdp_m0", 0).read_text().splitlines()
    assert len(lines) == 2 and "Traceback" in json.loads(lines[0])["traceback"]
    c = res["counters"]
    assert (c["failed"], c["train_skipped"], c["eval_skipped"], c["trained"]) == (1, 2, 2, 0)
    report = (out / "report.md").read_text()
    assert "**Failed runs**" in report and "overlap 0.30 mcdp_m0 seed 0: failed: WarmStartError" in report
    rows = {r["method"]: r for r in _csv(out)}
    assert rows["mcdp_m0"]["status"] == "failed" and rows["mcdp_m0"]["none.mean.abs_rel"] == ""
    assert math.isfinite(float(rows["mcdp_m1"]["none.mean.abs_rel"]))


def test_a_cuda_sweep_on_a_cluster_without_gpus_is_refused_not_left_pending(local_ray, local_sweep, tmp_path,
                                                                             capsys):
    out = tmp_path / "sweep"
    shutil.copytree(local_sweep, out)  # data and yardsticks there: only the runs are new
    capsys.readouterr()
    assert sweep_main([str(CI), "--out", str(out), "--engine", "ray", "device=cuda", *SMALL]) == 2
    assert "the Ray cluster has no GPU" in capsys.readouterr().err
