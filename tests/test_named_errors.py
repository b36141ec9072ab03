"""Hardening, round four (issue 41), item 8: errors that were tracebacks, or named nothing, are one line naming
the key or variable, exit 2, before anything is created.

- ``method_params.max_cameras`` below the rig's camera count (a 46-line traceback after the run folder was made);
- ``WORLD_SIZE=abc``, ``RANK=abc``, a missing ``MASTER_ADDR`` (tracebacks), ``RANK=5`` with ``WORLD_SIZE=2``
  (hung waiting for its peers);
- ``MCDP_EGL_DEVICE=abc`` (an int() error that did not name the variable).

Round five (issue 49, item 8): ``LOCAL_RANK=abc`` and ``WORLD_SIZE=1 RANK=1`` ran silently as one process.
"""
from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SURROUND = ROOT / "configs" / "train" / "tiny" / "surround.yaml"
MONO2 = ROOT / "configs" / "train" / "tiny" / "mono2.yaml"


def _one_line(capsys, prefix: str, *names: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(prefix), err
    assert "Traceback" not in err
    for n in names:
        assert n in err, (n, err)
    return err


def test_max_cameras_below_the_rigs_camera_count_is_refused_before_the_run_folder_is_made(tiny_dataset, tmp_path,
                                                                                          capsys):
    from study.method_commands import main

    run = tmp_path / "run"
    assert main(["train", str(SURROUND), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
                 "train.steps=1", "method_params.max_cameras=4"]) == 2
    _one_line(capsys, "mcdp train: error: method_params.max_cameras=4", "the rig has 6",
              "method_params.max_cameras=6")
    assert not run.exists()


def test_check_run_takes_the_rig_where_the_method_can():
    from corelib.configlib import ConfigError, build_config
    from mcdp.config import RunConfig
    from mcdp.methods import check_run

    cfg = build_config(RunConfig, {"model": {"method": "surround", "refine_steps": 0},
                                   "loss": {"consistency_weight": 0.0}, "method_params": {"max_cameras": 6}})
    check_run(cfg, 6)
    with pytest.raises(ConfigError, match="method_params.max_cameras=6"):
        check_run(cfg, 7)
    check_run(build_config(RunConfig, {}), 64)  # a method without the bound takes any rig


# (environment, what the one line names)
TORCHRUN_CASES = [
    ({"WORLD_SIZE": "abc"}, "environment variable WORLD_SIZE='abc' must be an integer"),
    ({"WORLD_SIZE": "2", "RANK": "abc", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29511"},
     "environment variable RANK='abc' must be an integer in [0, 1]"),
    ({"WORLD_SIZE": "2", "RANK": "5", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29511"},
     "environment variable RANK='5' must be an integer in [0, 1]"),
    ({"WORLD_SIZE": "2", "RANK": "0"}, "environment variable MASTER_ADDR is not set"),
    ({"WORLD_SIZE": "2", "RANK": "0", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "x"},
     "environment variable MASTER_PORT='x' must be an integer"),
    ({"LOCAL_RANK": "abc"}, "environment variable LOCAL_RANK='abc' must be an integer in [0, 0]; WORLD_SIZE is unset "
                            "or 1, one process of rank 0"),
    ({"WORLD_SIZE": "1", "RANK": "1"}, "environment variable RANK='1' must be an integer in [0, 0]; WORLD_SIZE is "
                                       "unset or 1, one process of rank 0"),
    ({"WORLD_SIZE": "2", "RANK": "1", "LOCAL_RANK": "abc", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29511"},
     "environment variable LOCAL_RANK='abc' must be an integer in [0, 1]"),
]


@pytest.mark.parametrize("env, says", TORCHRUN_CASES, ids=["world-abc", "rank-abc", "rank-5-of-2", "no-master-addr",
                                                           "master-port-x", "local-rank-abc-alone",
                                                           "rank-1-of-1", "local-rank-abc-of-2"])
def test_a_malformed_torchrun_variable_is_one_line_naming_it(tiny_dataset, tmp_path, capsys, monkeypatch, env, says):
    from study.method_commands import main

    for k in ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(k, raising=False)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    run = tmp_path / "run"
    assert main(["train", str(MONO2), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
                 "train.steps=1"]) == 2
    _one_line(capsys, "mcdp train: error: ", says)
    assert not run.exists()


def test_a_malformed_egl_device_is_one_line_naming_it_before_anything_is_written(tmp_path, capsys, monkeypatch):
    from synth.cli import main

    monkeypatch.setenv("MCDP_EGL_DEVICE", "abc")
    out = tmp_path / "d"
    assert main(["render", str(ROOT / "configs/data/tiny.yaml"), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "Traceback" not in "\n".join(err)
    assert err[-1].startswith("synth render: error: environment variable MCDP_EGL_DEVICE='abc' must be an integer"), err
    assert not out.exists()


def test_an_egl_device_beyond_the_machines_is_named_with_the_devices_there(monkeypatch):
    from corelib.configlib import ConfigError
    from synth.gl_context import egl_device

    monkeypatch.setenv("MCDP_EGL_DEVICE", "5")
    with pytest.raises(ConfigError, match=r"MCDP_EGL_DEVICE='5' must be an integer in \[0, 1\]; the machine's EGL "
                                          r"devices are 0 to 1"):
        egl_device(2)
    monkeypatch.setenv("MCDP_EGL_DEVICE", "1")
    assert egl_device(2) == 1
    monkeypatch.delenv("MCDP_EGL_DEVICE")
    assert egl_device(2) is None
