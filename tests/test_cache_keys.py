"""Caches keyed on what made the artefact (issue 31, item 2): a key added with `added_key` at a default that
leaves the artefact as it was keeps an existing dataset's and run's hash, and with them every cached render
and run; set to another value, it changes them. The new keys are real fields of subclassed sections, so the
test adds a key exactly as a change to the code would."""
from __future__ import annotations

from pathlib import Path

from corelib.configlib import added_key, config_hash, load_config

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "data" / "tiny.yaml"
MONO2 = ROOT / "configs" / "train" / "tiny" / "mono2.yaml"


def _data_with_a_new_scene_key():
    from scenes.config import SceneConfig
    from synth.config import DataConfig

    class NewScene(SceneConfig):
        puddle_density: float = added_key(0.0)  # a knob whose default renders what was rendered before

    class NewData(DataConfig):
        scene: NewScene = NewScene()

    return NewData


def _run_with_a_new_loss_weight():
    from mcdp.config import LossConfig, RunConfig

    class NewLoss(LossConfig):
        smoothness_2nd_weight: float = added_key(0.0)  # a new loss term, off by default

    class NewRun(RunConfig):
        loss: NewLoss = NewLoss()

    return NewRun


def test_a_key_added_with_its_default_keeps_a_datasets_hash():
    from synth.config import DataConfig

    NewData = _data_with_a_new_scene_key()
    before, after = load_config(DataConfig, TINY), load_config(NewData, TINY)
    assert after.scene.puddle_density == 0.0
    assert config_hash(after) == config_hash(before)
    assert config_hash(load_config(NewData, TINY, ["scene.puddle_density=0.5"])) != config_hash(before)


def test_a_key_added_with_its_default_keeps_a_runs_hash(tmp_path):
    from mcdp.config import RunConfig
    from mcdp.runs import run_hash

    NewRun = _run_with_a_new_loss_weight()
    weights = tmp_path / "pretrained.pt"
    weights.write_bytes(b"weights")
    for values in ({"train.seed": 0}, {"train.seed": 0, "model.init_from": str(weights)}):  # a sweep's run, warm too
        before, after = load_config(RunConfig, MONO2, values=values), load_config(NewRun, MONO2, values=values)
        assert run_hash(after) == run_hash(before) and config_hash(after) == config_hash(before)
        changed = load_config(NewRun, MONO2, ["loss.smoothness_2nd_weight=0.1"], values=values)
        assert run_hash(changed) != run_hash(before)
