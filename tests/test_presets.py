"""Preset listing (`mcdp presets`, `synth presets`, the list in the "does not exist" error) and
``--print-config`` (the resolved config on stdout, nothing written) on train, sweep, pretrain, synth render."""
from __future__ import annotations

import yaml
import pytest

from corelib.presets import KINDS, list_presets
from study.cli import main as mcdp
from synth.cli import main as synth


def test_every_kind_lists_the_presets_in_its_folder():
    for kind in KINDS:
        names = list_presets(kind)
        assert names and all(n.startswith(KINDS[kind][1] + "/") and n.endswith(".yaml") for n in names)
    assert "configs/train/tiny/mcdp_m1.yaml" in list_presets("train")


@pytest.mark.parametrize("argv, kind", [
    (["train", "configs/train/mcdp_m3.yaml", "--data", "D", "--out", "R"], "train"),
    (["sweep", "configs/sweep/smoke.yaml", "--out", "S"], "sweep"),
    (["pretrain", "configs/pretrain/nope.yaml", "--out", "P"], "pretrain"),
])
def test_a_wrong_preset_lists_the_presets_in_one_line(argv, kind, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert mcdp(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err and argv[1] in err
    assert all(p in err for p in list_presets(kind)) and f"mcdp presets {kind}" in err
    assert list(tmp_path.iterdir()) == []


def test_synth_render_wrong_preset_lists_data_presets(capsys, tmp_path):
    assert synth(["render", "configs/data/tinyy.yaml", "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "configs/data/tiny.yaml" in err and "synth presets" in err
    assert not (tmp_path / "d").exists()


def test_presets_commands_list_them(capsys):
    assert mcdp(["presets", "sweep"]) == 0
    out = capsys.readouterr().out
    assert "configs/sweep/ci.yaml" in out and "configs/train" not in out
    assert synth(["presets"]) == 0
    assert "configs/data/tiny.yaml" in capsys.readouterr().out


@pytest.mark.parametrize("prog, argv, key", [
    (mcdp, ["train", "configs/train/tiny/mcdp_m1.yaml", "--print-config", "train.steps=7"], ("train", "steps", 7)),
    (mcdp, ["train", "configs/train/tiny/mcdp_m1.yaml", "--data", "{tmp}/nodata", "--out", "{tmp}/run",
            "--print-config", "model.bases=4"], ("model", "bases", 4)),
    (mcdp, ["sweep", "configs/sweep/ci.yaml", "--out", "{tmp}/sweep", "--print-config", "seeds=[3]"], ("seeds", None, [3])),
    (mcdp, ["pretrain", "configs/pretrain/tiny.yaml", "--print-config", "workers=1"], ("workers", None, 1)),
    (synth, ["render", "configs/data/tiny.yaml", "--out", "{tmp}/data", "--print-config", "rig.overlap=0.35"],
     ("rig", "overlap", 0.35)),
])
def test_print_config_prints_the_override_and_writes_nothing(prog, argv, key, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert prog([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    section, field, value = key
    assert (cfg[section] if field is None else cfg[section][field]) == value
    assert list(tmp_path.iterdir()) == []  # no run, sweep, dataset folder, lock or log


def test_without_print_config_out_is_still_required(capsys):
    assert mcdp(["train", "configs/train/tiny/mcdp_m1.yaml"]) == 2
    assert "required: --data, --out" in capsys.readouterr().err
    assert synth(["render", "configs/data/tiny.yaml"]) == 2
    assert "required: --out" in capsys.readouterr().err


def test_load_config_finds_configs_from_any_folder(tmp_path, monkeypatch):
    from corelib.configlib import load_config
    from mcdp.config import RunConfig

    monkeypatch.chdir(tmp_path)
    assert load_config(RunConfig, "configs/train/mcdp_m2.yaml", ["train.steps=100"]).train.steps == 100
