"""rig.overlap_target=pixels: the layout's angle is solved so that the measured pixel overlap is the target."""
import json

import pytest

from synth.calibrate import TOL, calibration, geometric_rig
from synth.config import load_data_config


@pytest.mark.parametrize("target", [0.10, 0.40])
def test_calibrated_knob_hits_its_target_in_pixels(tmp_path, target):
    from synth.render import render_dataset

    cfg = load_data_config("configs/data/tiny.yaml", [f"rig.overlap={target}", "rig.overlap_target=pixels",
                                                      "dataset.sequences=2", "dataset.frames=3"])
    cal = calibration(cfg)
    assert abs(cal["measured"] - target) <= TOL + 1e-9  # on the calibration sample
    assert cal["geometric"] > target  # pixels measure less than the angle: the solved angle overlap is larger
    assert geometric_rig(cfg).overlap == cal["geometric"]
    s = render_dataset(cfg, tmp_path / "d", progress=False, log=lambda *a: None)
    man = json.loads((tmp_path / "d" / "manifest.json").read_text())
    ov = man["overlap"]
    assert ov["knob"] == "pixels" and ov["target"] == target and ov["geometric"] == pytest.approx(cal["geometric"])
    assert ov["calibration"]["measured"] == pytest.approx(cal["measured"])
    at = [v["measured"] for v in ov["per_pair_measured"].values() if abs(v["target"] - ov["geometric"]) < 1e-3]
    assert len(at) == 4  # spacing mode: the four pairs around CAM_FRONT and CAM_BACK
    assert abs(sum(at) / len(at) - target) <= 0.02  # the whole (tiny) dataset, every frame
    assert s["overlap"]["knob"] == "pixels"


def test_angle_knob_is_unchanged_and_keeps_its_hash():
    from corelib.configlib import config_hash

    a = load_data_config("configs/data/tiny.yaml", ["rig.overlap=0.3"])
    b = load_data_config("configs/data/tiny.yaml", ["rig.overlap=0.3", "rig.overlap_target=angle"])
    assert geometric_rig(a) is a.rig and config_hash(a) == config_hash(b)
