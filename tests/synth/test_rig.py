import math

import numpy as np
import pytest

from synth.overlap import overlap_mask
from synth.rig import (CAMERA_NAMES, CameraConfig, RigConfig, build_rig, intrinsics_from_hfov, rotation_ego_cam,
                       solve_layout)


def test_rotation_conventions():
    # yaw 0 camera looks along ego +x, its x axis (right) is ego -y, its y axis (down) is ego -z
    R = rotation_ego_cam(0.0, 0.0)
    np.testing.assert_allclose(R @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    # yaw +90 deg looks left (+y); pitch up tilts the optical axis up
    np.testing.assert_allclose(rotation_ego_cam(math.pi / 2, 0) @ [0, 0, 1], [0, 1, 0], atol=1e-12)
    assert (rotation_ego_cam(0, 0.2) @ [0, 0, 1])[2] > 0
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1)


def test_intrinsics_hfov():
    K = intrinsics_from_hfov(320, 192, 90.0)
    assert K[0, 0] == pytest.approx(160.0) and K[0, 2] == 160.0 and K[1, 2] == 96.0
    # the image edge (u = 0) is at hfov/2
    assert math.degrees(math.atan((K[0, 2] - 0) / K[0, 0])) == pytest.approx(45.0)


@pytest.mark.parametrize("o", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
def test_overlap_solver(o):
    hfov, s = solve_layout(o, "spacing", 70.0)
    assert hfov == 70.0 and (hfov - s) / hfov == pytest.approx(o)
    hfov, s = solve_layout(o, "fov", 70.0)
    assert s == 60.0 and (hfov - s) / hfov == pytest.approx(o)
    rig = build_rig(RigConfig(overlap=o, overlap_mode="fov"), CameraConfig())
    assert all(v == pytest.approx(o) for v in rig.pair_target_overlap().values())
    rig = build_rig(RigConfig(overlap=o, overlap_mode="spacing"), CameraConfig())
    t = rig.pair_target_overlap()
    for pair in ["CAM_FRONT-CAM_FRONT_RIGHT", "CAM_BACK_RIGHT-CAM_BACK", "CAM_BACK-CAM_BACK_LEFT",
                 "CAM_FRONT_LEFT-CAM_FRONT"]:
        assert t[pair] == pytest.approx(o)
    assert rig.names == list(CAMERA_NAMES)


def test_overlap_of_a_far_wall_is_the_geometric_overlap():
    # a far wall of constant depth: the pixel fraction seen by the neighbour ~ the hfov overlap
    rig = build_rig(RigConfig(overlap=0.3, overlap_mode="fov"), CameraConfig(width=200, height=100))
    a, b = rig.cameras[0], rig.cameras[1]
    far = np.full((100, 200), 1e4, np.float32)
    frac = overlap_mask(far, a.K, a.T_ego_cam, np.full((100, 200), 1e9), b.K, b.T_ego_cam).mean()
    # far wall: translation is negligible, the boundary is where FR's left edge (yaw -60 + hfov/2) falls
    u_edge = a.K[0, 2] + a.K[0, 0] * math.tan(math.radians(60.0 - a.hfov_deg / 2))
    assert frac == pytest.approx((a.width - u_edge) / a.width, abs=0.02)


def test_per_camera_overrides_reach_the_rig_and_widen_a_camera():
    from corelib.configlib import ConfigError, load_config
    from synth.config import DataConfig
    from synth.rig import build_rig

    base = load_config(DataConfig, None, [])
    wide = load_config(DataConfig, None, ["rig.cameras.CAM_BACK.hfov_deg=110.0", "rig.cameras.CAM_FRONT.mount_m=[2.0,0.0,1.5]",
                                          "rig.cameras.CAM_FRONT_LEFT.yaw_deg=50.0"])
    r0, r1 = build_rig(base.rig, base.camera), build_rig(wide.rig, wide.camera)
    back0, back1 = r0.cameras[3], r1.cameras[3]
    assert back1.hfov_deg == 110.0 and back1.K[0, 0] < back0.K[0, 0]  # shorter focal length: sees more
    assert back1.to_json()["hfov_deg"] == 110.0 and back1.to_json()["K"][0][0] == back1.K[0, 0]
    ov0, ov1 = r0.pair_target_overlap(), r1.pair_target_overlap()
    assert ov1["CAM_BACK_RIGHT-CAM_BACK"] > ov0["CAM_BACK_RIGHT-CAM_BACK"]  # the wider CAM_BACK overlaps more
    assert tuple(r1.cameras[0].T_ego_cam[:3, 3]) == (2.0, 0.0, 1.5)
    assert r1.cameras[5].yaw_deg == 50.0
    for o in (["rig.cameras.CAM_TOP.hfov_deg=90.0"], ["rig.cameras.CAM_BACK.hfov_deg=200.0"],
              ["rig.cameras.CAM_BACK.mount_m=[0.0,0.0,50.0]"], ["rig.cameras.CAM_BACK.focal=3.0"]):
        with pytest.raises(ConfigError, match="rig.cameras"):
            load_config(DataConfig, None, o)


def test_a_camera_of_its_own_size_has_its_K_from_that_size_and_its_hfov():
    from corelib.configlib import config_hash, load_config
    from synth.config import DataConfig, render_size
    from synth.rig import build_rig, camera_sizes_of, intrinsics_from_hfov

    base = load_config(DataConfig, None, ["rig.cameras.CAM_BACK.hfov_deg=110.0"])
    cfg = load_config(DataConfig, None, ["rig.cameras.CAM_BACK.hfov_deg=110.0", "rig.cameras.CAM_BACK.width=480",
                                         "rig.cameras.CAM_FRONT.height=240"])
    r0, r1 = build_rig(base.rig, base.camera), build_rig(cfg.rig, cfg.camera)
    back, front = r1.cameras[3], r1.cameras[0]
    assert (back.width, back.height) == (480, 192) and (front.width, front.height) == (320, 240)
    assert np.allclose(back.K, intrinsics_from_hfov(480, 192, 110.0)) and back.K[0, 2] == 240.0
    assert back.K[0, 0] == pytest.approx(1.5 * r0.cameras[3].K[0, 0])  # the same hfov over 1.5x the pixels
    assert front.K[1, 2] == 120.0 and front.K[0, 0] == r0.cameras[0].K[0, 0]  # taller: the same focal length
    assert back.T_ego_cam.tolist() == r0.cameras[3].T_ego_cam.tolist() and back.hfov_deg == 110.0
    assert [c.to_json() for c in r1.cameras[1:3]] == [c.to_json() for c in r0.cameras[1:3]]
    assert camera_sizes_of(cfg.rig, cfg.camera)["CAM_BACK"] == (480, 192)
    assert r1.size_text() == "320x192, CAM_FRONT 320x240, CAM_BACK 480x192" and r0.size_text() == "320x192"
    extra = (480 * 192 - 320 * 192) + (320 * 240 - 320 * 192)
    assert render_size(cfg)["max_bytes"] - render_size(base)["max_bytes"] == extra * 10 * render_size(cfg)["rig_frames"]
    assert config_hash(cfg) != config_hash(base)


def test_an_added_key_at_its_default_keeps_every_hash():
    """rig.cameras, rig.overlap_target and the sweep's worlds and seeds_per_world were added after datasets and
    runs were cached: at their defaults they leave the config hash as it was (the hash of the dict without
    them), set they change it."""
    from corelib.configlib import config_hash, config_to_dict, load_config
    from corelib.hashing import json_sha256
    from synth.config import DataConfig

    cfg = load_config(DataConfig, None, [])
    d = config_to_dict(cfg)
    assert d["rig"]["cameras"] == {} and d["rig"]["overlap_target"] == "angle"
    del d["rig"]["cameras"], d["rig"]["overlap_target"], d["labels"]  # labels: added with issue 40, all on
    del d["sensor"], d["weather"]  # the sensor model and fog (issue 48): every knob off by default
    del d["ego"]  # the ego body's appearance (issue 57): static by default
    del d["rig"]["trigger"], d["rig"]["trigger_offsets_ms"], d["rig"]["lidar_hz"]  # trigger times (issue 48): synchronous
    del d["rig"]["active_cameras"]  # a subset of the cameras (issue 59): all six by default
    assert d["scene"]["family_weights"] == {"urban": 1.0, "residential": 1.0, "highway": 1.0}
    d["scene"]["family_weights"] = [1.0, 1.0, 1.0]  # hashed in its positional form of old (SceneConfig.hashed_form)
    assert config_hash(cfg) == json_sha256(d)
    assert config_hash(load_config(DataConfig, None, ["rig.cameras.CAM_BACK.hfov_deg=110.0"])) != config_hash(cfg)
    # a camera's width / height (added later still) at null: an entry of rig.cameras keeps its hash
    back = load_config(DataConfig, None, ["rig.cameras.CAM_BACK.hfov_deg=110.0"])
    bd = config_to_dict(back)
    assert bd["rig"]["cameras"]["CAM_BACK"]["width"] is None and bd["rig"]["cameras"]["CAM_BACK"]["height"] is None
    del bd["rig"]["cameras"]["CAM_BACK"]["width"], bd["rig"]["cameras"]["CAM_BACK"]["height"]
    for key in ("model", "dist"):  # a camera's lens (issue 59): pinhole by default
        bd["rig"]["cameras"]["CAM_BACK"].pop(key, None)
    del bd["rig"]["overlap_target"], bd["labels"], bd["sensor"], bd["weather"], bd["ego"]
    del bd["rig"]["trigger"], bd["rig"]["trigger_offsets_ms"], bd["rig"]["lidar_hz"], bd["rig"]["active_cameras"]
    bd["scene"]["family_weights"] = [1.0, 1.0, 1.0]
    assert config_hash(back) == json_sha256(bd)
    assert config_hash(load_config(DataConfig, None, ["rig.overlap_target=pixels"])) != config_hash(cfg)
    assert config_hash(load_config(DataConfig, None, ["rig.active_cameras=[CAM_FRONT,CAM_BACK]"])) != config_hash(cfg)
    assert config_hash(load_config(DataConfig, None, ["labels.flow=true"])) != config_hash(cfg)
    from study.sweep.config import SweepConfig

    s = SweepConfig()
    sd = config_to_dict(s)
    del sd["worlds"], sd["keep_best"], sd["seeds_per_world"], sd["plan"]  # all added later, defaults that change nothing
    assert config_hash(s) == json_sha256(sd) != config_hash(SweepConfig(worlds="per_seed"))
    assert config_hash(SweepConfig(worlds="per_seed", seeds=[0, 1], seeds_per_world=2)) \
        != config_hash(SweepConfig(worlds="per_seed", seeds=[0, 1]))
    assert config_hash(SweepConfig(keep_last=False)) != config_hash(SweepConfig(keep_best=False, keep_last=False))
