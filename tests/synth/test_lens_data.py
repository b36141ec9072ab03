"""The camera's lens travels with the data (issue 59 item 1): the rig config's per-camera ``model`` / ``dist``
(added keys: a pinhole rig keeps its hash), `synth.rig.CameraSpec`'s JSON (a pinhole camera's rig.json entry has
the same keys and bytes as before lenses), the reader's check of rig.json, and the refusals of what is pinhole
by its format (the nuScenes and glTF exports); rendering a lens is formed by `synth.lens_image`."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from synth import camera
from synth.rig import CameraConfig, CameraSpec, RigConfig, build_rig, intrinsics_for, intrinsics_from_hfov

KB = {"model": "kannala_brandt", "dist": [0.05, -0.01, 0.002, -0.0003], "hfov_deg": 190.0}


def _rig(**cams):
    return build_rig(RigConfig(overlap=0.3, cameras=cams), CameraConfig(width=64, height=48))


def test_a_pinhole_camera_json_is_the_json_of_before():
    c = _rig().cameras[0]
    assert list(c.to_json()) == ["name", "width", "height", "K", "T_ego_cam", "hfov_deg", "yaw_deg", "pitch_deg"]
    assert c.model == "pinhole" and c.dist == () and c.intrinsics == camera.Intrinsics("pinhole", c.K)
    back = CameraSpec.from_json(json.loads(json.dumps(c.to_json())))
    assert back.model == "pinhole" and np.array_equal(back.K, c.K)


def test_a_lens_round_trips_through_rig_json():
    rig = _rig(CAM_FRONT=KB, CAM_BACK={"model": "radtan", "dist": [-0.05, 0.01, 0.001, -0.001, 0.0]})
    f, b = rig.cameras[0], rig.cameras[3]
    d = f.to_json()
    assert d["model"] == "kannala_brandt" and d["dist"] == {"k1": 0.05, "k2": -0.01, "k3": 0.002, "k4": -0.0003}
    assert list(d)[:4] == ["name", "width", "height", "K"]  # K stays where it was
    for c in (f, b):
        back = CameraSpec.from_json(json.loads(json.dumps(c.to_json())))
        assert back.intrinsics == c.intrinsics and back.to_json() == c.to_json()
    assert [c.model for c in rig.cameras] == ["kannala_brandt", "pinhole", "pinhole", "radtan", "pinhole", "pinhole"]


def test_a_lens_K_maps_half_the_field_of_view_to_the_image_edge():
    K = intrinsics_for(64, 48, 190.0, "kannala_brandt", KB["dist"])
    cam = camera.Intrinsics("kannala_brandt", K, tuple(KB["dist"]))
    a = math.radians(95.0)  # the edge ray of a 190 degree lens, behind the camera's plane
    uv, ok = camera.project(cam, np.array([[math.sin(a), -math.sin(a)], [0, 0], [math.cos(a), math.cos(a)]]))
    assert ok.all() and np.allclose(uv[0], [64.0, 0.0], atol=1e-9)
    rt = (-0.2, 0.05, 0.0, 0.0, 0.0)  # barrel: the edge ray lands nearer the centre than tan says, so fx grows
    assert intrinsics_for(64, 48, 90.0, "radtan", rt)[0, 0] > intrinsics_from_hfov(64, 48, 90.0)[0, 0] * 1.15
    assert np.array_equal(intrinsics_for(64, 48, 90.0), intrinsics_from_hfov(64, 48, 90.0))


def test_the_rig_config_refuses_a_wrong_lens_naming_the_key():
    from corelib.configlib import ConfigError, load_config
    from synth.config import DataConfig

    with pytest.raises(ConfigError, match=r"unknown camera model 'fisheye'; the table has pinhole, radtan"):
        load_config(DataConfig, overrides=["rig.cameras.CAM_FRONT.model=fisheye"])
    with pytest.raises(ConfigError, match=r"dist must be 4 finite numbers .*k1, k2, k3, k4.* kannala_brandt"):
        load_config(DataConfig, overrides=["rig.cameras.CAM_FRONT.model=kannala_brandt"])
    with pytest.raises(ConfigError, match=r"hfov_deg 190 needs a range-depth \(fisheye\) camera model"):
        load_config(DataConfig, overrides=["rig.cameras.CAM_FRONT.hfov_deg=190"])


def test_a_pinhole_rig_keeps_its_hash_and_a_lens_changes_it():
    from corelib.configlib import config_hash, hashed_dict, load_config
    from synth.config import DataConfig

    base = load_config(DataConfig, overrides=["rig.cameras.CAM_FRONT.yaw_deg=10"])
    assert hashed_dict(base)["rig"]["cameras"]["CAM_FRONT"] == {
        k: v for k, v in base.rig.cameras["CAM_FRONT"].model_dump().items() if k not in ("model", "dist", "width", "height")}
    lens = load_config(DataConfig, overrides=["rig.cameras.CAM_FRONT.yaw_deg=10", "rig.cameras.CAM_FRONT.model=radtan",
                                              "rig.cameras.CAM_FRONT.dist=[-0.05,0.01,0,0,0]"])
    assert config_hash(lens) != config_hash(base)
    assert hashed_dict(lens)["rig"]["cameras"]["CAM_FRONT"]["dist"] == [-0.05, 0.01, 0, 0, 0]


def test_a_lens_renders_and_the_rig_refuses_what_it_cannot_form_in_one_line():
    """Rendering a lens is no longer refused (`synth.lens_image` forms it); a fisheye field of view on a z-depth
    camera is, naming the camera, and so is a wrong camera subset (rig.active_cameras)."""
    from corelib.configlib import ConfigError, load_config
    from synth.calibrate import geometric_rig
    from synth.config import DataConfig
    from synth.render import make_rig

    cfg = load_config(DataConfig, overrides=["rig.cameras.CAM_BACK.model=radtan",
                                             "rig.cameras.CAM_BACK.dist=[-0.05,0.01,0,0,0]"])
    assert geometric_rig(cfg) is cfg.rig and make_rig(cfg).cameras[3].model == "radtan"
    wide = load_config(DataConfig, overrides=["camera.hfov_deg=190", "rig.cameras.CAM_FRONT.model=kannala_brandt",
                                              "rig.cameras.CAM_FRONT.dist=[0,0,0,0]"])
    with pytest.raises(ValueError, match=r"^camera.hfov_deg 190 needs a range-depth \(fisheye\) camera model; "
                                         r"rig.cameras.CAM_FRONT_RIGHT.model is pinhole \(up to 150 degrees\)$"):
        make_rig(wide)
    four = load_config(DataConfig, overrides=["rig.active_cameras=[CAM_BACK,CAM_FRONT,CAM_FRONT_LEFT]"])
    rig = make_rig(four)
    assert rig.names == ["CAM_FRONT", "CAM_BACK", "CAM_FRONT_LEFT"] and rig.neighbours == ((0, 1), (1, 2), (2, 0))
    with pytest.raises(ConfigError, match=r"rig.active_cameras must name at least 2 distinct cameras"):
        load_config(DataConfig, overrides=["rig.active_cameras=[CAM_FRONT,CAM_TOP]"])
    with pytest.raises(ConfigError, match=r"rig.cameras sets CAM_BACK, not in rig.active_cameras"):
        load_config(DataConfig, overrides=["rig.active_cameras=[CAM_FRONT,CAM_FRONT_LEFT]",
                                           "rig.cameras.CAM_BACK.yaw_deg=170"])


def test_the_reader_refuses_a_bad_lens_in_rig_json():
    from synth.dataset import check_rig
    from synth.files import DatasetError

    rig = _rig(CAM_FRONT=KB)
    j = rig.to_json()
    manifest = {"cameras": rig.names, "image_size": {"width": 64, "height": 48}}
    check_rig(j, manifest, "rig.json")  # a good lens passes
    j["cameras"][0]["dist"] = {"k1": 0.1}
    with pytest.raises(DatasetError, match=r"rig.json: cameras\[CAM_FRONT\]: camera model 'kannala_brandt': dist "
                                           r"must have the keys \['k1', 'k2', 'k3', 'k4'\]"):
        check_rig(j, manifest, "rig.json")
    j["cameras"][0]["model"] = None
    with pytest.raises(DatasetError, match=r"cameras\[CAM_FRONT\]: model must be a camera model's name, got None"):
        check_rig(j, manifest, "rig.json")


def test_the_pinhole_exports_refuse_a_lens_in_one_line(tmp_path, monkeypatch):
    from types import SimpleNamespace

    import synth.gltf_export as G
    import synth.open
    from synth.files import DatasetError
    from synth.nuscenes.export import export_nuscenes
    from synth.nuscenes.layout import ExportError

    ds = SimpleNamespace(format="synth", root=tmp_path / "ds", cameras=_rig(CAM_BACK=KB).cameras,
                         manifest={"config": {}})
    with pytest.raises(ExportError, match=r"^.*ds: a nuScenes export \(camera_intrinsic: a pinhole K\) is pinhole only; "
                                          r"camera\(s\) CAM_BACK \(kannala_brandt\) have another lens model"):
        export_nuscenes(ds, tmp_path / "out")
    monkeypatch.setattr(G, "import_trimesh", lambda: None)
    monkeypatch.setattr(synth.open, "open_dataset", lambda src: ds)
    with pytest.raises(DatasetError, match=r"a glTF export \(glTF cameras are perspective\) is pinhole only; "
                                           r"camera\(s\) CAM_BACK \(kannala_brandt\)"):
        G.export_gltf(tmp_path / "ds", tmp_path / "out")
    assert not (tmp_path / "out").exists()  # refused before a byte is written
