import pytest

from synth.config import DataConfig, load_data_config
from corelib.configlib import ConfigError, config_hash, diff_configs, parse_overrides


def test_defaults_and_overrides():
    cfg = load_data_config(None, ["rig.overlap=0.4", "camera.width=160", "dataset.fps=5", "seed=7"])
    assert cfg.rig.overlap == 0.4 and cfg.camera.width == 160 and cfg.dataset.fps == 5.0 and cfg.seed == 7
    assert cfg.rig.overlap_mode == "spacing"


@pytest.mark.parametrize("override, key", [
    ("rig.overlap=0.7", "rig.overlap"),
    ("rig.overlap=0.05", "rig.overlap"),
    ("rig.overlap_mode=ring", "rig.overlap_mode"),
    ("camera.width=abc", "camera.width"),
    ("camera.width=12.5", "camera.width"),
    ("dataset.frames=2", "dataset.frames"),
    ("dataset.sequences=0", "dataset.sequences"),
    ("rig.bogus=1", "rig.bogus"),
    ("nosuchsection.x=1", "nosuchsection"),
    ("seed=-1", "seed"),
])
def test_bad_values_name_the_key(override, key):
    with pytest.raises(ConfigError) as e:
        load_data_config(None, [override])
    assert key in str(e.value)


def test_override_syntax_and_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="key=value"):
        parse_overrides(["rig.overlap"])
    with pytest.raises(ConfigError, match="does not exist"):
        load_data_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="mapping"):
        load_data_config(bad)


def test_frozen_and_hash():
    a, b = DataConfig(), load_data_config(None, ["rig.overlap=0.5"])
    with pytest.raises(Exception):
        a.seed = 3
    assert config_hash(a) == config_hash(DataConfig()) != config_hash(b)
    assert diff_configs(a.model_dump(), b.model_dump()) == ["rig.overlap"]


def test_presets_load():
    from pathlib import Path
    for p in sorted(Path(__file__).resolve().parents[2].glob("configs/data/*.yaml")):
        load_data_config(p)
