"""Motion blur and rolling shutter (issue 48, item 4): off, nothing changes; on, the image is the mean of its
sub-frames in linear light and the ground truth is that of each band's mid-exposure instant, exactly."""
import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from corelib.configlib import ConfigError, config_hash, hashed_dict, load_config
from synth.sensor import SHUTTER_KEYS
from synth.shutter import Shutter, average_linear, band_offsets_s, band_rows, subframe_offsets_s

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
TINY_HASH = "4c93be54b2f0ddb35c56d70e7fd2b087d4a0e648eeb11eb99ebc6a5727a1c9d8"  # tests/synth/test_sensor.py
KNOBS = ["sensor.exposure_ms=20", "sensor.subframes=3", "sensor.rolling_shutter_ms=30", "sensor.rolling_bands=2",
         "dataset.frames=3"]  # 6 renders an image, 54 images: seconds


def _tiny(overrides=()):
    from synth.config import DataConfig

    return load_config(DataConfig, TINY, list(overrides))


def test_off_keeps_every_hash_and_renders_once():
    off = _tiny(["sensor.exposure_ms=0", "sensor.subframes=1", "sensor.rolling_shutter_ms=0", "sensor.rolling_bands=8"])
    assert config_hash(off) == TINY_HASH and Shutter.for_config(off) is None  # render.py: one r.render per image
    # a sensor config's hash is the one it had before the shutter (computed on integ at f8f07ef)
    photometric = _tiny(["sensor.noise=0.01", "weather.fog_density=0.02", "rig.trigger=lidar_sweep"])
    assert config_hash(photometric) == "1545d592c252ab43d2304a732264ff1c81b0befc5d7ab91f22f770513037e264"
    assert not set(SHUTTER_KEYS) & set(hashed_dict(photometric)["sensor"])
    assert off.sensor.is_identity()
    on = _tiny(["sensor.exposure_ms=10", "sensor.subframes=3"])
    assert config_hash(on) != TINY_HASH and on.sensor.is_identity()  # not a photometric knob: no sRGB round trip
    assert config_hash(_tiny(["sensor.rolling_shutter_ms=20"])) != TINY_HASH


def test_a_bad_shutter_names_its_fields():
    with pytest.raises(ConfigError, match=r"sensor.exposure_ms > 0 and sensor.subframes >= 2"):
        _tiny(["sensor.exposure_ms=10"])
    with pytest.raises(ConfigError, match=r"sensor.exposure_ms > 0 and sensor.subframes >= 2"):
        _tiny(["sensor.subframes=4"])
    with pytest.raises(ConfigError, match=r"sensor.subframes"):
        _tiny(["sensor.exposure_ms=10", "sensor.subframes=17"])
    with pytest.raises(ConfigError, match=r"sensor.rolling_shutter_ms"):
        _tiny(["sensor.rolling_shutter_ms=500"])
    with pytest.raises(ConfigError, match=r"labels.flow cannot go with sensor.rolling_shutter_ms"):
        _tiny(["sensor.rolling_shutter_ms=20", "labels.flow=true"])


def test_the_times_are_midpoints_centred_on_the_trigger():
    assert np.allclose(subframe_offsets_s(30.0, 3), [-0.01, 0.0, 0.01]) and subframe_offsets_s(30.0, 3)[1] == 0.0
    assert np.allclose(subframe_offsets_s(20.0, 4), [-0.0075, -0.0025, 0.0025, 0.0075])
    assert np.allclose(band_offsets_s(40.0, 4), [-0.015, -0.005, 0.005, 0.015])
    assert band_rows(10, 4) == [(0, 2), (2, 5), (5, 7), (7, 10)]
    assert Shutter(10, 3, 0, 8, 10).renders_per_image() == 3 and Shutter(10, 4, 0, 8, 10).renders_per_image() == 5
    assert Shutter(0, 1, 20, 4, 10).renders_per_image() == 4 and Shutter(10, 3, 20, 4, 10).renders_per_image() == 12


def test_the_mean_is_taken_in_linear_light():
    black, white = np.zeros((2, 2, 3), np.uint8), np.full((2, 2, 3), 255, np.uint8)
    assert np.all(average_linear([black, white]) == 188)  # sRGB of linear 0.5, not 128
    img = np.random.default_rng(0).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    assert np.array_equal(average_linear([img, img, img]), img)


@pytest.fixture(scope="module")
def cam_render():
    """(render_at(x, scene=None) for CAM_FRONT_LEFT of tiny's sequence 0, its height, the scene): a side camera,
    so the ego's forward motion moves the image."""
    from synth.gl_backend import LightState
    from synth.pipeline import build_sequence_scene
    from synth.render import make_ego_mesh, make_rig, renderer_for

    cfg = _tiny()
    rig, scene = make_rig(cfg), build_sequence_scene(cfg, 0)
    cam = rig.cameras[rig.names.index("CAM_FRONT_LEFT")]
    r = renderer_for(cfg)
    light = LightState((0.3, 0.2, 0.9), (1, 1, 1), (0.3, 0.3, 0.3), (0.5, 0.6, 0.8), (0.7, 0.7, 0.8), shadows=True)
    loaded = {}

    def render_at(x, sc=scene):
        if loaded.get("scene") is not sc:
            r.load_scene(sc, make_ego_mesh(cfg))
            loaded["scene"] = sc
        return r.render(cam.K, sc.ego_pose_at(x) @ cam.T_ego_cam, x, light, size=(cam.width, cam.height),
                        labels=True)

    return render_at, cam.height, scene


def test_a_static_scene_blurs_to_itself(cam_render):
    render_at, H, scene = cam_render
    still = dataclasses.replace(scene, T_world_ego=np.repeat(scene.T_world_ego[2:3], len(scene.T_world_ego), 0),
                                movers=[dataclasses.replace(m, T_world_obj=np.repeat(m.T_world_obj[2:3],
                                        len(m.T_world_obj), 0)) for m in scene.movers])
    sharp = render_at(2, still)
    for k in (3, 4):
        blurred = Shutter(40.0, k, 0.0, 8, 10.0).render(lambda x: render_at(x, still), 2, H)
        assert np.abs(blurred["rgb"].astype(int) - sharp["rgb"]).max() <= 1
        assert np.array_equal(blurred["depth"], sharp["depth"])


def test_a_moving_ego_blurs_and_the_ground_truth_is_mid_exposure(cam_render):
    render_at, H, _ = cam_render
    sharp = render_at(3)
    for k in (3, 4):  # odd: the middle sub-frame is the mid instant; even: it is rendered once more
        blurred = Shutter(40.0, k, 0.0, 8, 10.0).render(render_at, 3, H)
        diff = np.abs(blurred["rgb"].astype(int) - sharp["rgb"])
        assert (diff > 2).mean() > 0.01  # 40 % of a frame's motion
        for key in ("depth", "ego", "instance", "layer"):
            assert blurred[key].tobytes() == sharp[key].tobytes()


def test_rolling_shutter_bands_are_renders_at_their_own_times(cam_render):
    render_at, H, _ = cam_render
    sh = Shutter(0.0, 1, 50.0, 4, 10.0)  # bands at -18.75, -6.25, 6.25, 18.75 ms: -0.1875 .. 0.1875 frames
    out = sh.render(render_at, 3, H)
    rows = band_rows(H, 4)
    top, bottom = render_at(3 - 0.1875), render_at(3 + 0.1875)
    for key in ("rgb", "depth", "instance"):
        assert np.array_equal(out[key][: rows[0][1]], top[key][: rows[0][1]])
        assert np.array_equal(out[key][rows[-1][0]:], bottom[key][rows[-1][0]:])
    assert not np.array_equal(out["depth"], render_at(3)["depth"])  # the ego moved between the bands
    both = Shutter(20.0, 3, 50.0, 4, 10.0).render(render_at, 3, H)  # blur around each band's time
    assert np.array_equal(both["depth"], out["depth"]) and not np.array_equal(both["rgb"], out["rgb"])


@pytest.fixture(scope="module")
def shutter_dataset(tmp_path_factory):
    from synth.render import render_dataset

    out = tmp_path_factory.mktemp("shutter") / "data"
    render_dataset(_tiny(KNOBS), out, workers=1, progress=False, log=lambda *a: None)
    return out


def test_the_dataset_verifies_and_records_the_shutter(shutter_dataset):
    from synth.verify import verify_dataset

    m = json.loads((shutter_dataset / "manifest.json").read_text())
    s = m["shutter"]
    assert s["subframes"] == 3 and s["bands"] == 2 and "top first" in s["convention"]
    assert np.allclose(s["subframe_offsets_ms"], [-20 / 3, 0, 20 / 3]) and np.allclose(s["band_offsets_ms"], [-7.5, 7.5])
    assert verify_dataset(shutter_dataset) == []


def test_the_shutter_render_is_deterministic_under_the_seed(shutter_dataset, tmp_path):
    from corelib.configlib import config_to_dict
    from synth.render import render_sequence

    shutil.copytree(shutter_dataset / "masks", tmp_path / "masks")
    rec = render_sequence(config_to_dict(_tiny(KNOBS)), str(tmp_path), 1)
    files = json.loads((shutter_dataset / "manifest.json").read_text())["files"]
    assert rec["files"] and all(files[k] == v for k, v in rec["files"].items())
