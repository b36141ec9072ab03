"""`mcdp.runs.rig_differences` compares each camera's lens (issue 59): a radtan rig whose distortion changes while
its K stays (p1 does not enter the focal length `synth.rig.intrinsics_for` solves) was reported as the same rig,
so ``mcdp eval`` of a run on a dataset of another lens said nothing. A pinhole rig still compares equal to itself."""
from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np

ROOT = __import__("pathlib").Path(__file__).resolve().parents[2]


def _rig(path: str, *overrides: str):
    from synth.config import load_data_config
    from synth.rig import build_rig

    cfg = load_data_config(ROOT / "configs" / "data" / path, list(overrides))
    return build_rig(cfg.rig, cfg.camera)


def _differences(tmp_path, trained, now):
    from mcdp.runs import rig_differences

    (tmp_path / "run.json").write_text(json.dumps({"rig": [c.to_json() for c in trained.cameras]}))
    return rig_differences(tmp_path, SimpleNamespace(cameras=now.cameras))


def test_a_changed_distortion_with_the_same_K_is_a_rig_difference(tmp_path):
    a = _rig("distorted.yaml")
    b = _rig("distorted.yaml", "rig.cameras.CAM_FRONT.dist=[-0.10,0.02,0.01,-0.0003,0.0]")
    assert np.array_equal(a.cameras[0].K, b.cameras[0].K)  # the case: K alone cannot tell
    assert _differences(tmp_path, a, a) == []
    assert _differences(tmp_path, a, b) == ["CAM_FRONT lens radtan dist"]


def test_a_changed_lens_model_is_named_and_a_pinhole_rig_equals_itself(tmp_path):
    p = _rig("default.yaml")
    assert _differences(tmp_path, p, p) == []
    d = _rig("distorted.yaml")
    diffs = _differences(tmp_path, p, d)
    assert "CAM_FRONT lens pinhole -> radtan" in diffs and "CAM_BACK lens pinhole -> radtan" in diffs
