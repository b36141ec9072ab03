"""The sensor model and fog (issue 48, items 2 and 3): off, nothing changes; on, only the RGB does, as modelled."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from corelib.configlib import ConfigError, config_hash, load_config
from synth.sensor import (CameraSensor, SensorConfig, add_noise, linear_to_srgb8, metered_ev, sense,
                          srgb_to_linear, vignetting_gain)
from synth.weather import apply_fog, ray_distance

KNOBS = ["sensor.exposure_ev=[0.5,0,0,-0.5,0,0.25]", "sensor.exposure_spread_ev=0.3",
         "sensor.white_balance_spread=0.05", "sensor.auto_exposure_target=0.18", "sensor.vignetting=0.3",
         "sensor.noise=0.005", "weather.fog_density=[0.01,0.03]"]
TINY_HASH = "4c93be54b2f0ddb35c56d70e7fd2b087d4a0e648eeb11eb99ebc6a5727a1c9d8"  # before the sensor (tests/scenes)
TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
K = np.array([[40.0, 0, 48], [0, 40.0, 32], [0, 0, 1]])


def _tiny(overrides=()):
    from synth.config import DataConfig

    return load_config(DataConfig, TINY, list(overrides))


def test_every_knob_off_keeps_the_config_hash_and_the_renderers_image():
    from synth.photometry import SequencePhotometry

    off = _tiny(["sensor.noise=0.0", "sensor.exposure_ev=0.0", "weather.fog_density=0.0"])  # said, at default
    assert config_hash(_tiny()) == config_hash(off) == TINY_HASH
    assert config_hash(_tiny(["sensor.noise=0.01"])) != TINY_HASH != config_hash(_tiny(["weather.fog_density=0.02"]))
    assert SequencePhotometry.for_sequence(off, 0, None, None) is None  # render.py writes res["rgb"] itself


def test_a_bad_knob_names_its_field():
    with pytest.raises(ConfigError, match=r"sensor.exposure_ev.*one EV offset per camera, 6 in rig order"):
        _tiny(["sensor.exposure_ev=[0.5,0.5]"])
    with pytest.raises(ConfigError, match=r"weather.fog_density.*\[lo, hi\] with lo <= hi"):
        _tiny(["weather.fog_density=[0.03,0.01]"])
    with pytest.raises(ConfigError, match=r"sensor.vignetting"):
        _tiny(["sensor.vignetting=1.5"])


def test_srgb_round_trip_is_exact_and_one_ev_doubles_linear_light():
    x = np.arange(256, dtype=np.uint8).reshape(1, 256, 1).repeat(3, -1)
    assert np.array_equal(linear_to_srgb8(srgb_to_linear(x)), x)
    lin = np.full((4, 4, 3), 0.2)
    out = sense(lin, 1.0, CameraSensor(1.0, (1.0, 0.5, 2.0)), None, SensorConfig(), np.random.default_rng(0))
    assert np.allclose(out[0, 0], [0.4, 0.2, 0.8])
    assert metered_ev(np.full((8, 8, 3), 0.045), 0.18) == pytest.approx(2.0)


def test_noise_statistics_match_the_poisson_gaussian_model_on_a_flat_image():
    gain, read_e, level = 0.01, 2.0, 0.3
    out = add_noise(np.full((200, 200, 3), level), gain, read_e, np.random.default_rng(7))
    assert out.mean() == pytest.approx(level, rel=0.01)
    assert out.var() == pytest.approx(gain * level + (gain * read_e) ** 2, rel=0.1)  # 0.0034
    flat = np.full((8, 8, 3), level)
    assert add_noise(flat, 0.0, read_e, np.random.default_rng(7)) is flat


def test_vignetting_darkens_the_corners_not_the_centre():
    g = vignetting_gain(K, 96, 64, 0.4)
    assert g.shape == (64, 96)
    assert g[31:33, 47:49].min() > 0.999 and g[0, 0] == pytest.approx(1 - 0.4 * (47.5**2 + 31.5**2) / (48**2 + 32**2))
    assert g.argmax() in (31 * 96 + 47, 31 * 96 + 48, 32 * 96 + 47, 32 * 96 + 48) and g.min() >= 0.6


def test_fog_is_the_identity_at_zero_density_and_the_airlight_at_large_density():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (64, 96, 3))
    depth = rng.uniform(1, 80, (64, 96))
    depth[:10] = 0  # the sky
    air = (0.7, 0.75, 0.8)
    assert apply_fog(img, ray_distance(depth, K), 0.0, air) is img
    far = apply_fog(img, ray_distance(depth, K), 1.0, air)  # exp(-1 m^-1 * >= 1 m) <= 0.37; 80 m: 0
    assert np.allclose(far[depth > 10], air, atol=1e-4) and np.allclose(far[:10], air)
    # the formula at one pixel, along the ray: z = 10 m, 0.75 z right of the axis: ray_dist = 12.5 m
    K_c = np.array([[40.0, 0, 47.5], [0, 40.0, 31.5], [0, 0, 1]])  # pixel (77, 31)'s centre: (77.5, 31.5)
    d = np.zeros((64, 96))
    d[31, 77] = 10.0
    assert ray_distance(d, K_c)[31, 77] == pytest.approx(12.5)
    one = apply_fog(img, ray_distance(d, K_c), 0.02, air)[31, 77]
    t = np.exp(-0.02 * 12.5)
    assert np.allclose(one, img[31, 77] * t + np.array(air) * (1 - t))


@pytest.fixture(scope="module")
def sensor_dataset(tmp_path_factory):
    from synth.render import render_dataset

    out = tmp_path_factory.mktemp("sensor") / "data"
    render_dataset(_tiny(KNOBS), out, workers=1, progress=False, log=lambda *a: None)
    return out


def test_only_the_rgb_changes_and_the_dataset_verifies(sensor_dataset, tiny_dataset):
    from synth.verify import verify_dataset

    ideal = json.loads((tiny_dataset / "manifest.json").read_text())["files"]
    files = json.loads((sensor_dataset / "manifest.json").read_text())["files"]
    assert set(files) == set(ideal)
    rgb = {k for k in files if k.startswith("seq_") and k.endswith(".png") and k.count(".") == 1}
    others = [k for k in files if k not in rgb and not k.endswith("ego.json")]  # depth, labels, masks, rig
    assert len(rgb) == 3 * 6 * 6 and len(others) > len(rgb)
    assert all(files[k] == ideal[k] for k in others)
    assert all(files[k] != ideal[k] for k in rgb)
    assert verify_dataset(sensor_dataset) == []


def test_the_manifest_and_ego_json_hold_each_cameras_drawn_values(sensor_dataset):
    m = json.loads((sensor_dataset / "manifest.json").read_text())
    for seq, info in m["sequences"].items():
        cams = info["sensor"]
        assert list(cams) == m["cameras"]
        evs = [c["exposure_ev"] for c in cams.values()]
        assert len(set(evs)) == 6 and all(abs(ev - base) < 1.5 for ev, base in zip(evs, [0.5, 0, 0, -0.5, 0, 0.25]))
        assert all(len(c["white_balance"]) == 3 and c["white_balance"][1] == 1.0 for c in cams.values())
        assert 0.01 <= info["weather"]["fog_density"] <= 0.03
        frames = json.loads((sensor_dataset / seq / "ego.json").read_text())["frames"]
        assert all(set(f["sensor"]["exposure_ev"]) == set(m["cameras"]) for f in frames)  # auto-exposure's EV


def test_the_sensor_render_is_deterministic_under_the_seed(sensor_dataset, tmp_path):
    from corelib.configlib import config_to_dict
    from synth.render import render_sequence

    shutil.copytree(sensor_dataset / "masks", tmp_path / "masks")
    rec = render_sequence(config_to_dict(_tiny(KNOBS)), str(tmp_path), 1)
    files = json.loads((sensor_dataset / "manifest.json").read_text())["files"]
    assert rec["files"] and all(files[k] == v for k, v in rec["files"].items())
