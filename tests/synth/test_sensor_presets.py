"""The sensor presets (issue 48, item 5): configs/data/realistic.yaml turns every built camera and weather knob
on; configs/data/nuscenes_like_sensor.yaml is nuscenes_like.yaml's rig and scenes with nuScenes-like cameras."""
import json
from pathlib import Path

import pytest

from corelib.configlib import config_to_dict
from synth.config import load_data_config
from synth.sensor import SHUTTER_KEYS, SensorConfig
from synth.weather import WeatherConfig

DATA = Path(__file__).resolve().parents[2] / "configs" / "data"
#: the built knobs, each of which realistic.yaml turns on; the other fields are parameters of a knob
KNOBS = {"sensor": ("exposure_spread_ev", "auto_exposure_target", "white_balance_spread", "vignetting", "noise",
                    "jpeg_quality", "exposure_ms", "subframes", "rolling_shutter_ms"),
         "weather": ("fog_density",)}
PARAMS = {"sensor": ("exposure_ev", "auto_exposure_tau_s", "white_balance", "read_noise_e", "rolling_bands"),
          "weather": ("airlight_rgb",)}
#: at a test's size: one sequence of three frames, 96x64
SMALL = ["camera.width=96", "camera.height=64", "dataset.sequences=1", "dataset.frames=3", "scene.texture_size=128",
         "render.shadow_map_size=1024"]


@pytest.mark.parametrize("section, model", [("sensor", SensorConfig), ("weather", WeatherConfig)])
def test_realistic_turns_every_built_knob_on(section, model):
    cfg = getattr(load_data_config(DATA / "realistic.yaml"), section)
    assert set(model.model_fields) == set(KNOBS[section]) | set(PARAMS[section])  # a new knob: add it to the preset
    off = model()
    assert [k for k in KNOBS[section] if getattr(cfg, k) == getattr(off, k)] == []


def test_nuscenes_like_sensor_is_nuscenes_like_with_jpeg_and_its_cameras():
    base = config_to_dict(load_data_config(DATA / "nuscenes_like.yaml"))
    cfg = load_data_config(DATA / "nuscenes_like_sensor.yaml")
    ours = config_to_dict(cfg)
    assert ours["rig"].pop("trigger") == "lidar_sweep" and base["rig"].pop("trigger") == "synchronous"
    assert {k: v for k, v in ours.items() if k != "sensor"} == {k: v for k, v in base.items() if k != "sensor"}
    assert cfg.sensor.jpeg_quality == 90 and cfg.sensor.auto_exposure_target is not None and cfg.weather.is_identity()


def test_realistic_renders_verifies_and_only_its_rgb_differs(tmp_path):
    from synth.render import render_dataset
    from synth.verify import verify_dataset

    outs = {}
    for name in ("ideal", "realistic"):
        cfg = load_data_config(DATA / "realistic.yaml", SMALL)
        if name == "ideal":  # every photometric knob off; the same trigger and shutter times
            times = {k: getattr(cfg.sensor, k) for k in SHUTTER_KEYS}
            cfg = cfg.model_copy(update={"sensor": SensorConfig(**times), "weather": WeatherConfig()})
        outs[name] = tmp_path / name
        render_dataset(cfg, outs[name], workers=1, progress=False, log=lambda *a: None)
    ideal, real = (json.loads((outs[n] / "manifest.json").read_text()) for n in ("ideal", "realistic"))
    assert verify_dataset(outs["realistic"]) == [] and real["rgb"]["format"] == "jpeg"
    rgb = {k for k in real["files"] if k.endswith(".jpg")}
    assert len(rgb) == 18 and {k[:-4] + ".png" for k in rgb} <= set(ideal["files"])
    same = [k for k in real["files"] if k not in rgb and not k.endswith("ego.json")]
    assert all(real["files"][k] == ideal["files"][k] for k in same)  # depth, masks, labels, rig.json
    seq = real["sequences"]["seq_00000"]
    assert set(seq["sensor"]) == set(real["cameras"]) and 0.0 <= seq["weather"]["fog_density"] <= 0.015
