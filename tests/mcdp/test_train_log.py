"""`mcdp train`'s logging: RUN/train.log (Python logging), -q, the one warning for a method with bases
started without model.init_from, and validation depth metrics + the config text in TensorBoard."""
from __future__ import annotations

from pathlib import Path

import pytest

import mcdp.trainer  # noqa: F401  torch before the in-process GL renderer (tests/mcdp/test_cli.py says why)
from study.method_commands import main
from study.train_command import NO_INIT_WARNING

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny"
WARNING_START = NO_INIT_WARNING.split("{")[0]


def _train(preset, data, run, *extra):
    return main(["train", str(TINY / f"{preset}.yaml"), "--data", str(data), "--out", str(run), "--no-progress",
                 "train.steps=2", *extra])


@pytest.fixture(scope="module")
def m1_run(tiny_dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("log") / "run"
    assert _train("mcdp_m1", tiny_dataset, run) == 0
    return run


def test_train_writes_train_log_with_the_stderr_lines_and_the_steps(m1_run):
    text = (m1_run / "train.log").read_text()
    assert "mcdp train: method=mcdp" in text and "best val loss" in text
    assert "step 1/2 loss" in text and "step 2/2 loss" in text  # DEBUG lines: the file only
    assert WARNING_START in text


def test_stderr_lines_stay_as_before_and_the_warning_comes_once(tiny_dataset, tmp_path, capsys, one_thread):
    assert _train("mcdp_m1", tiny_dataset, tmp_path / "a") == 0
    err = capsys.readouterr().err
    assert err.splitlines()[0].startswith("mcdp train: method=mcdp bases=")
    assert err.count(WARNING_START) == 1 and "step 1/2" not in err
    assert _train("mcdp_m1", tiny_dataset, tmp_path / "a", "train.steps=3") == 0  # a resume: no warning
    assert WARNING_START not in capsys.readouterr().err


def test_no_warning_with_init_from_nor_for_mono2(tiny_dataset, tmp_path, capsys, one_thread, fake_pretraining):
    assert _train("mono2", tiny_dataset, tmp_path / "mono") == 0
    assert WARNING_START not in capsys.readouterr().err
    fake_pretraining(tmp_path / "pretrained.pt")
    assert _train("mcdp_m1", tiny_dataset, tmp_path / "warm", f"model.init_from={tmp_path / 'pretrained.pt'}") == 0
    err = capsys.readouterr().err
    assert WARNING_START not in err and "mcdp train: method=mcdp" in err


def test_quiet_keeps_stderr_to_warnings_and_the_log_whole(tiny_dataset, tmp_path, capsys, one_thread):
    assert _train("mcdp_m1", tiny_dataset, tmp_path / "q", "-q") == 0
    err = capsys.readouterr().err
    assert "mcdp train: method=" not in err and err.count(WARNING_START) == 1
    assert "mcdp train: method=mcdp" in (tmp_path / "q" / "train.log").read_text()
    assert main(["train", str(TINY / "mono2.yaml"), "--print-config"]) == 0  # -q is not sticky
    capsys.readouterr()


def test_tensorboard_holds_val_depth_metrics_and_the_config(m1_run):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(m1_run / "tensorboard"), size_guidance={"scalars": 0, "tensors": 0})
    acc.Reload()
    tags = acc.Tags()
    for k in ("abs_rel", "sq_rel", "rmse", "rmse_log", "a1"):
        assert f"val/depth_{k}" in tags["scalars"]
    abs_rel = acc.Scalars("val/depth_abs_rel")[-1].value
    assert 0 < abs_rel < 10
    assert any(t.startswith("config") for t in tags["tensors"])
