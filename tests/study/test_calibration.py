"""The calibration's anchors file and its statistics (issue 57): the file is refused in one line naming the row,
the rates and rank statistics match scipy / hand values on fixed inputs, an anchor is resolved and agrees only
when its interval says so."""
from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from corelib.configlib import ConfigError
from study.report.sections.anchors import load_anchors
from study.report.sections.calibration import agreement, mmrv, paired, rank_stats, read_anchor, wilson

ANCHORS = Path(__file__).resolve().parents[2] / "configs" / "calibration" / "anchors.yaml"


def test_the_committed_anchors_hold_twelve_or_more_rows_split_before_the_runs():
    a = load_anchors(ANCHORS)
    sets = [x.set for x in a.anchors]
    assert len(a.anchors) >= 12
    assert sets.count("tuning") >= 4 and sets.count("test") >= 4
    by = {x.name: x for x in a.anchors}
    assert by["ego_masks_off"].set == "tuning"  # the first case to close is a tuning anchor
    assert by["ego_masks_off"].real.delta == pytest.approx(0.138)
    assert by["mcdp_vs_mono2"].real.delta == pytest.approx(-0.027)


def _write(tmp_path: Path, mutate) -> Path:
    raw = yaml.safe_load(ANCHORS.read_text())
    mutate(raw)
    p = tmp_path / "anchors.yaml"
    p.write_text(yaml.safe_dump(raw))
    return p


@pytest.mark.parametrize("mutate, words", [
    (lambda r: r["anchors"][1].pop("source"), "anchor 'automask_off': source: Field required"),
    (lambda r: r["anchors"][2]["real"].update(after=0.115), "anchor 'min_reprojection_off': real.before equals"),
    (lambda r: r["anchors"][3]["real"].pop("before"), "anchor 'full_res_off': real.before: Field required"),
    (lambda r: r["anchors"][0].update(changed="nope"), "anchor 'ego_masks_off': changed: arm 'nope' is not declared"),
    (lambda r: r["anchors"][0].update(set="later"), "anchor 'ego_masks_off': set:"),
])
def test_a_bad_row_is_refused_in_one_line_naming_it(tmp_path, mutate, words):
    with pytest.raises(ConfigError) as exc:
        load_anchors(_write(tmp_path, mutate))
    msg = str(exc.value)
    assert words in msg and "\n" not in msg


def test_wilson_matches_the_closed_form():
    for k, n in [(4, 6), (0, 5), (9, 9), (7, 12)]:
        lo, hi = wilson(k, n)
        z = 1.959963984540054
        p = k / n
        c = (p + z * z / (2 * n)) / (1 + z * z / n)
        h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
        assert lo == pytest.approx(max(0.0, c - h), abs=1e-9) and hi == pytest.approx(min(1.0, c + h), abs=1e-9)
    assert wilson(4, 6) == pytest.approx((0.2999, 0.9032), abs=1e-3)  # the probe: [0.30, 0.90]


def test_rank_statistics_match_scipy_and_hand_values():
    from scipy import stats

    real = [0.138, 0.005, 0.002, 0.017, -0.027, -0.018, 0.096]
    syn = [0.001, 0.017, 0.003, 0.034, 0.002, -0.011, 0.086]
    r = rank_stats(real, syn, boot=200)
    assert r["spearman"] == pytest.approx(stats.spearmanr(real, syn).statistic)
    assert r["kendall"] == pytest.approx(stats.kendalltau(real, syn).statistic)
    lo, hi = r["spearman_ci"]
    assert -1 <= lo <= r["spearman"] <= hi <= 1
    assert rank_stats([1, 2, 3, 4], [10, 20, 30, 40], boot=50)["spearman"] == pytest.approx(1.0)
    assert rank_stats([1, 2, 3, 4], [4, 3, 2, 1], boot=50)["kendall"] == pytest.approx(-1.0)
    assert rank_stats(real, syn, boot=200) == r  # seeded: the page rebuilds byte-identically


def test_mmrv_on_a_hand_built_case():
    # items 0 and 1 are inverted (real gap 0.1), item 2 keeps its order with both
    assert mmrv([0.0, 0.1, 0.5], [0.2, 0.1, 0.9]) == pytest.approx((0.1 + 0.1 + 0.0) / 3)
    assert mmrv([0.0, 0.1, 0.5], [1, 2, 3]) == 0.0


def test_paired_interval_and_mde():
    from scipy import stats

    d = [0.05, 0.07, 0.04, 0.06]
    st = paired(d)
    se = stats.tstd(d) / 2
    assert st["half"] == pytest.approx(stats.t.ppf(0.975, 3) * se)
    assert st["p"] == pytest.approx(stats.ttest_1samp(d, 0).pvalue)
    assert st["mde"] > st["half"]


def test_an_anchor_is_resolved_and_agrees_only_as_its_interval_says():
    a = load_anchors(ANCHORS)
    ego = next(x for x in a.anchors if x.name == "ego_masks_off")
    col = a.metric_of(ego)
    base = {w: {col: 0.20} for w in range(4)}
    worse = {w: {col: 0.20 + 0.05 + 0.001 * w} for w in range(4)}
    better = {w: {col: 0.20 - 0.05 - 0.001 * w} for w in range(4)}
    noisy = {w: {col: 0.20 + (0.01 if w % 2 else -0.01)} for w in range(4)}
    rows = [read_anchor(a, ego, {"mono2": base, "mono2_nomask": v}) for v in (worse, better, noisy)]
    assert [(r["resolved"], r["agrees"]) for r in rows] == [(True, True), (True, False), (False, False)]
    fig = agreement(rows)
    assert (fig["resolved"], fig["agree"]) == (2, 1) and fig["unresolved"] == ["ego_masks_off"]
    missing = read_anchor(a, ego, {"mono2": base})
    assert missing["n"] == 0 and not missing["resolved"]


def test_the_page_builds_from_values_with_its_headline_and_scatter(tmp_path, monkeypatch):
    import importlib.util
    import sys

    spec = importlib.util.spec_from_file_location("publish_calibration",
                                                  ANCHORS.parents[2] / "scripts" / "publish_calibration.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["publish_calibration"] = mod
    spec.loader.exec_module(mod)
    monkeypatch.setattr(mod, "DIR", tmp_path)
    a = load_anchors(ANCHORS)
    cols = {"median.mean.abs_rel": 0.2, "none.mean.abs_rel": 0.25, "dep_con.mean": 0.1,
            **{f"median.camera.{c}.abs_rel": 0.2 for c in ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT",
                                                            "CAM_BACK_LEFT", "CAM_FRONT_LEFT")}}
    shift = {"mono2_nomask": 0.05, "mono2_scratch": 0.03, "mcdp_m2": -0.01, "fsm": 0.02}
    arms = {name: {str(w): {k: v + shift.get(name, 0.0) + 0.002 * w * (name != "mono2") for k, v in cols.items()}
                   for w in range(4)} for name in a.arms if name in ("mono2", *shift)}
    page = mod.build({"base": {"arms": arms, "yardsticks": {}, "train_s": {}}})
    assert "**The benchmark reproduces 5 of 6 resolved real-data effects in sign**" in page
    assert "> Generated by `python scripts/publish_calibration.py`" in page
    assert "| mcdp_vs_mono2 | test |" in page and "**agrees**" in page and "**disagrees**" in page
    assert (tmp_path / "scatter.png").stat().st_size > 10_000


def test_calibrate_dry_run_names_every_arm_in_order_with_its_overrides(capsys, tmp_path):
    from study.calibrate_command import main

    preset = ANCHORS.parents[1] / "sweep" / "cpu_calibration.yaml"
    assert main([str(ANCHORS), str(preset), "--out", str(tmp_path), "--dry-run", "--extra", "train.steps=800"]) == 0
    lines = [x for x in capsys.readouterr().err.splitlines() if x.startswith("mcdp calibrate: arm ")]
    a = load_anchors(ANCHORS)
    assert [x.split()[3].rstrip(":") for x in lines] == a.order
    nomask = next(x for x in lines if "arm mono2_nomask:" in x)
    assert "loss.photometric_ego_mask=false]" in nomask and "train.steps=800" in nomask
    assert not any(tmp_path.iterdir())  # a dry run writes nothing
    assert main([str(ANCHORS), str(preset), "--out", str(tmp_path), "--arms", "nope"]) == 2


def test_the_scale_point_takes_every_unresolved_or_disagreeing_anchor_and_three_agreeing():
    from study.report.sections.calibration import scale_point_arms

    a = load_anchors(ANCHORS)
    rows = [{"name": x.name, "n": 4, "agrees": x.name in ("pretraining_off", "side_cameras", "mcdp_vs_mono2",
                                                          "metric_scale"),
             "real": x.real.delta, "base": x.base, "changed": x.changed} for x in a.anchors]
    arms = scale_point_arms(a, [r for r in rows if r["name"] in ("ego_masks_off", "pretraining_off", "side_cameras",
                                                                 "mcdp_vs_mono2", "metric_scale")])
    # ego disagrees: its arms; agreeing by |real|: side_cameras 0.096, mcdp_vs_mono2 0.027, pretraining 0.017
    assert arms == ["mono2", "mono2_nomask", "mono2_scratch", "mcdp_m2"]
    assert len(scale_point_arms(a, rows)) == 8  # capped, in the file's order


def test_link_shared_hard_links_the_first_arms_folders_and_marker(tmp_path):
    from study.calibrate_command import link_shared

    first = tmp_path / "mono2"
    (first / "data" / "w").mkdir(parents=True)
    (first / "data" / "w" / "x.exr").write_bytes(b"x")
    (first / "pretrain").mkdir()
    (first / ".mcdp").write_text("sweep\n")
    assert link_shared(first, tmp_path / "arm") == ["pretrain", "data", ".mcdp"]
    assert (tmp_path / "arm" / "data" / "w" / "x.exr").stat().st_ino == (first / "data" / "w" / "x.exr").stat().st_ino
    assert (tmp_path / "arm" / ".mcdp").stat().st_ino == (first / ".mcdp").stat().st_ino
    assert link_shared(first, tmp_path / "arm") == []  # already there: nothing again
    (first / "data" / "w2").mkdir()  # a world the first arm rendered later (more seeds)
    assert link_shared(first, tmp_path / "arm") == ["data/w2"]
