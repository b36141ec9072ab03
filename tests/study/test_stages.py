"""`study.sweep.worlds.render_stage` reads a rendered dataset through the opened dataset (`synth.dataset.Dataset`:
config_hash, overlap, split), not raw manifest.json keys: a complete dataset of the same config is reused
with its splits and measured overlap, one of another config is refused. Nothing is rendered."""
from __future__ import annotations

from pathlib import Path

import pytest

from corelib.configlib import ConfigError, config_hash
from study.sweep.config import data_config_for, load_sweep_config, overlap_key
from study.sweep.stages import Counters
from study.sweep.worlds import render_stage

ROOT = Path(__file__).resolve().parents[2]


def test_a_complete_dataset_of_the_same_config_is_reused_and_read_through_the_dataset(tmp_path, write_dataset):
    cfg = load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", [])
    o = cfg.overlaps[0]
    write_dataset(tmp_path / "data" / overlap_key(o), config_hash(data_config_for(cfg, o)), o)
    counters = Counters()
    rec = render_stage(cfg, o, tmp_path, counters, lambda *a: None, False)
    assert rec["render_skipped"] and counters == {"render_skipped": 1}
    assert rec["splits"] == {"train": 2, "val": 0, "test": 1}
    assert rec["measured"]["measured_mean"] == pytest.approx(0.2)  # the pair at the target only
    assert rec["measured"]["pairs_at_target"] == 1 and rec["measured"]["pairs"] == 2


def test_a_dataset_of_another_config_is_refused(tmp_path, write_dataset):
    cfg = load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", [])
    o = cfg.overlaps[0]
    write_dataset(tmp_path / "data" / overlap_key(o), "0" * 64, o)
    with pytest.raises(ConfigError, match="another config"):
        render_stage(cfg, o, tmp_path, Counters(), lambda *a: None, False)
