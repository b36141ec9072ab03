"""Hardening, round three, finding 8 (issue 32): what was still open from round two.

a. a manifest.json or rig.json that is not UTF-8 is one line naming it, in every command that reads it;
b. a disk full from the start names the file that could not be written (was ``(unnamed file)``), exit 4;
c. nesting is bounded before anything recurses, a dotted override key too;
d. a config holds a bounded number of keys, and an error echoes a bounded length.
"""
from __future__ import annotations

import errno
import os
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MONO2 = ROOT / "configs" / "train" / "tiny" / "mono2.yaml"
NOT_UTF8 = b'\xff\xfe{"schema_version": 1}'


# --------------------------------------------------------------------------- a: not UTF-8
@pytest.mark.parametrize("name", ["manifest.json", "rig.json"])
@pytest.mark.parametrize("command", ["synth info", "synth verify", "mcdp train", "mcdp eval", "mcdp predict"])
def test_a_manifest_or_rig_that_is_not_utf8_is_one_line_naming_it(tiny_dataset, tmp_path, capsys, name, command):
    from study.cli import main as mcdp_main
    from synth.cli import main as synth_main

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    (d / name).write_bytes(NOT_UTF8)
    out = tmp_path / "out"
    prog, cmd = command.split()
    argv = {"info": ["info", str(d)], "verify": ["verify", str(d)],
            "train": ["train", str(MONO2), "--data", str(d), "--out", str(out)],
            "eval": ["eval", str(tmp_path / "norun"), "--data", str(d), "--out", str(tmp_path / "m.json")],
            "predict": ["predict", str(tmp_path / "norun"), "--data", str(d), "--out", str(out)]}[cmd]
    rc = (synth_main if prog == "synth" else mcdp_main)(argv)
    captured = capsys.readouterr()
    text = (captured.out + captured.err).strip()
    lines = [line for line in text.splitlines() if "not UTF-8" in line]
    assert rc == (1 if cmd == "verify" else 2), text  # verify: "found problems" (exit 1), the others: exit 2
    assert len(lines) == 1 and f"{d / name}: not UTF-8" in lines[0], text
    assert "Traceback" not in text and len(text.splitlines()) <= 3, text
    assert not out.exists() and not (tmp_path / "m.json").exists()


# --------------------------------------------------------------------------- b: a disk full from the start
@pytest.fixture(scope="module")
def tiny_run(tiny_dataset, tmp_path_factory) -> Path:
    from study.method_commands import main

    run = tmp_path_factory.mktemp("bounded") / "run"
    assert main(["train", str(MONO2), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
                 "train.steps=1"]) == 0
    return run


@pytest.mark.slow  # whole commands (train, predict, export) as subprocesses on a tmpfs
@pytest.mark.parametrize("command", ["train", "predict", "export"])
def test_a_disk_full_from_the_start_names_the_file_exit_4(tiny_dataset, tmp_path, small_disk, command, request):
    """A real tmpfs, full before the command starts: the first write is the output folder's lock file."""
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    out = mnt / "out"
    py = [sys.executable, "-m", "synth.cli" if command == "export" else "mcdp"]
    argv = {"train": ["train", str(MONO2), "--data", str(tiny_dataset), "--out", str(out), "train.steps=1",
                      "--no-progress"],
            "predict": ["predict", str(request.getfixturevalue("tiny_run")) if command == "predict" else "",
                        "--data", str(tiny_dataset), "--out", str(out), "--max-samples", "1"],
            "export": ["export", str(tiny_dataset), "--format", "nuscenes", "--out", str(out), "--no-progress"]}
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    res, left = small_disk(py + argv[command], mnt, full=True, timeout=600, env=env)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 4, res.stderr[-2000:]
    assert "(unnamed file)" not in res.stderr and "Traceback" not in res.stderr, res.stderr[-2000:]
    assert f"{out / '.lock'}: no space left on device" in err[-1], err


def test_a_lock_file_that_cannot_be_written_is_named(tmp_path, monkeypatch):
    from corelib import rundir
    from corelib.atomic import DiskFullError

    def full(fd, data, *offset):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(rundir.os, "pwrite", full)  # the pid, written by the lock's on_acquired hook
    with pytest.raises(DiskFullError) as e:
        rundir.claim(tmp_path / "run", "run")
    assert e.value.filename == str(tmp_path / "run" / ".lock")
    monkeypatch.undo()
    rundir.claim(tmp_path / "run", "run").release()  # the failed claim left no lock held


def test_tensorboard_on_a_full_disk_names_its_folder(tmp_path):
    from corelib.atomic import DiskFullError
    from mcdp.logger import TrainLogger

    class FullWriter:
        def add_scalar(self, *a):
            raise OSError(errno.ENOSPC, "No space left on device")  # as its writer thread re-raises it: no name

        close = flush = add_scalar

    log = TrainLogger(None)
    log.writer, log.folder = FullWriter(), tmp_path / "tensorboard"
    with pytest.raises(DiskFullError) as e:
        log.scalars({"train/loss": 0.5}, 1)
    assert e.value.filename == str(tmp_path / "tensorboard")
    with pytest.raises(DiskFullError):
        log.close()
    assert log.writer is None  # closed once, even when closing failed


def test_a_full_disk_that_names_no_file_names_the_output_folder(capsys):
    from corelib.cli import Command, main

    def add(p):
        p.add_argument("--out")

    def run(args):
        raise OSError(errno.ENOSPC, "No space left on device")

    assert main("prog", "", [Command("write", "", add, run)], ["write", "--out", "/x/OUT"], []) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "a file under /x/OUT: no space left on device" in err[0], err


# --------------------------------------------------------------------------- c: nesting
def test_a_dotted_override_key_is_bounded_in_depth(tmp_path, capsys):
    from study.method_commands import main

    assert main(["train", str(MONO2), "--data", str(tmp_path), "--out", str(tmp_path / "run"),
                 "train." + "a." * 1000 + "b=1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nested more than 32 levels deep (1002 dotted parts)" in err[0] and len(err[0]) < 300
    assert not (tmp_path / "run").exists()


def test_a_key_and_a_value_nested_together_are_bounded():
    from corelib.configlib import ConfigError, load_config
    from mcdp.config import RunConfig

    with pytest.raises(ConfigError, match="nested more than 32 levels deep"):  # 20 + 20 levels, each below 32
        load_config(RunConfig, None, ["train." + "a." * 19 + "b=" + "[" * 20 + "]" * 20])


# --------------------------------------------------------------------------- d: keys and echoes
def test_60000_keys_are_refused_by_their_count_naming_the_file(tmp_path, capsys):
    from study.method_commands import main

    cfg = tmp_path / "many.yaml"
    cfg.write_text("model: {method: mono2}\n" + "".join(f"k{i}: 1\n" for i in range(60000)))
    assert main(["train", str(cfg), "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"config file {cfg}: more than 10000 keys and list items" in err[0], err


def test_10000_overrides_are_refused_by_their_count():
    from corelib.configlib import ConfigError, parse_overrides

    with pytest.raises(ConfigError, match="^10001 overrides, more than the 10000 keys a config may have$"):
        parse_overrides([f"k{i}=1" for i in range(10001)])


@pytest.mark.parametrize("item, said", [("x" * 100_000, "is not of the form key=value"),
                                        ("x" * 100_000 + "..=1", "has an empty key")])
def test_an_override_is_echoed_to_80_characters(item, said):
    from corelib.configlib import ConfigError, parse_overrides

    with pytest.raises(ConfigError) as e:
        parse_overrides([item])
    assert said in str(e.value) and "x" * 80 + "..." in str(e.value) and len(str(e.value)) < 200, str(e.value)[:300]


def test_a_config_name_longer_than_the_file_system_allows_is_one_bounded_line(tmp_path, capsys):
    from study.method_commands import main

    assert main(["train", str(tmp_path / ("x" * 5000)), "--data", str(tmp_path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "config file" in err[0] and "File name too long" in err[0] and len(err[0]) < 500, err


def test_a_message_is_cut_to_2000_characters_with_the_rest_counted(capsys):
    from corelib.cli import Command, main

    def run(args):
        raise ValueError("v" * 10_000)

    assert main("prog", "", [Command("go", "", lambda p: None, run)], ["go"], [((ValueError,), 2, "error")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("v... (8000 more characters)") and len(err) < 2100, err[-200:]
