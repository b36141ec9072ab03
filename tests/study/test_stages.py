"""`study.worlds.render_stage` reads a rendered dataset through the opened dataset (`synth.dataset.Dataset`:
config_hash, overlap, split), not raw manifest.json keys: a complete dataset of the same config is reused
with its splits and measured overlap, one of another config is refused. Nothing is rendered."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from corelib.configlib import ConfigError, config_hash
from study.config import data_config_for, load_sweep_config, overlap_key
from study.stages import Counters
from study.worlds import render_stage

ROOT = Path(__file__).resolve().parents[2]
CAMS = ["CAM_A", "CAM_B"]


def _write_dataset(out: Path, h: str, target: float, **extra) -> None:
    out.mkdir(parents=True)
    eye = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    rig = {"cameras": [{"name": n, "width": 8, "height": 6, "K": [[4, 0, 4], [0, 4, 3], [0, 0, 1]], "T_ego_cam": eye,
                        "hfov_deg": 90.0, "yaw_deg": 0.0} for n in CAMS], "neighbours": [[0, 1]]}
    overlap = {"target": target, "mode": "spacing", "per_pair_measured": {
        "CAM_A-CAM_B": {"target": target, "measured": 0.2}, "CAM_B-CAM_A": {"target": -0.1, "measured": 0.0}}}
    manifest = {"schema_version": 1, "generator": "mcdp-synth", "cameras": CAMS, "image_size": {"width": 8, "height": 6},
                "fps": 10, "splits": {"train": ["seq_0000", "seq_0001"], "val": [], "test": ["seq_0002"]},
                "sequences": {f"seq_000{i}": {"frames": 3} for i in range(3)}, "files": {}, "config_hash": h,
                "overlap": overlap, **{k: v for k, v in extra.items() if v is not None}}
    (out / "rig.json").write_text(json.dumps(rig))
    (out / "manifest.json").write_text(json.dumps(manifest))


def test_a_complete_dataset_of_the_same_config_is_reused_and_read_through_the_dataset(tmp_path):
    cfg = load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", [])
    o = cfg.overlaps[0]
    _write_dataset(tmp_path / "data" / overlap_key(o), config_hash(data_config_for(cfg, o)), o)
    counters = Counters()
    rec = render_stage(cfg, o, tmp_path, counters, lambda *a: None, False)
    assert rec["render_skipped"] and counters == {"render_skipped": 1}
    assert rec["splits"] == {"train": 2, "val": 0, "test": 1}
    assert rec["measured"]["measured_mean"] == pytest.approx(0.2)  # the pair at the target only
    assert rec["measured"]["pairs_at_target"] == 1 and rec["measured"]["pairs"] == 2


def test_a_dataset_of_another_config_is_refused(tmp_path):
    cfg = load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", [])
    o = cfg.overlaps[0]
    _write_dataset(tmp_path / "data" / overlap_key(o), "0" * 64, o)
    with pytest.raises(ConfigError, match="another config"):
        render_stage(cfg, o, tmp_path, Counters(), lambda *a: None, False)
