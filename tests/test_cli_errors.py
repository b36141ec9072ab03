"""Hardening, round two (issue 20, items 11 and 12): every error a user can cause ends in a few lines
naming the file or key, with the README's exit code and no traceback, in both CLIs; a config is
checked before torch is imported; a writer killed with SIGKILL leaves no temporary file after the
next run.

The table runs each case as a user would (``python -m synth.cli`` / ``python -m mcdp`` in a
subprocess). What each operating-system case exercises, honestly (the tests run as root, so a
chmod-ed folder would not refuse anything):

- ``name too long``: a file name of 300 bytes (ENAMETOOLONG), refused by the file system whoever runs;
- ``path through a file``: ``--out`` below a regular file (ENOTDIR);
- ``read-only file system``: a read-only tmpfs mounted in a private mount namespace (``unshare -rm``;
  skipped where unprivileged namespaces are not allowed);
- ``permission denied``: a file in ``/sys`` (sysfs refuses new files, root included; skipped where it
  does not).
"""
from __future__ import annotations

import errno
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY_TRAIN = "configs/train/tiny/mono2.yaml"
LONG = "x" * 300  # longer than any common file system's 255 bytes per name
SYNTH = [sys.executable, "-m", "synth.cli"]
MCDP = [sys.executable, "-m", "mcdp"]


def _run(argv: list[str], timeout: float = 600, **env_vars: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", **env_vars}
    return subprocess.run(argv, cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout)


def _assert_one_error(res: subprocess.CompletedProcess, code: int, *names: str, max_lines: int = 3) -> None:
    err = res.stderr.strip()
    assert res.returncode == code, (res.returncode, err[-3000:])
    assert "Traceback" not in err, err[-3000:]
    assert 1 <= len(err.splitlines()) <= max_lines, err[-3000:]
    for n in names:
        assert n in err, (n, err)


@pytest.fixture(scope="module")
def work(tiny_dataset, tmp_path_factory) -> dict[str, Path]:
    t = tmp_path_factory.mktemp("cli_errors")
    (t / "afile").write_text("a file, not a folder")
    bad_run = t / "run_pickle" / "checkpoints"
    bad_run.mkdir(parents=True)
    import torch

    class _RunsCode:
        def __reduce__(self):
            return (os.system, (f"touch {t / 'pwned'}",))

    torch.save({"version": 1, "config": {}, "payload": _RunsCode()}, bad_run / "last.pt")
    return {"tmp": t, "data": tiny_dataset, "file": t / "afile", "pickle_run": bad_run.parent}


# (id, argv with {tmp} {data} {file} {pickle_run}, exit code, strings stderr must hold, paths that must not exist)
CASES = [
    ("synth-bad-key", SYNTH + ["render", "configs/data/tiny.yaml", "--out", "{tmp}/r1", "bad.key=1"], 2, ["bad"],
     ["{tmp}/r1"]),
    ("synth-render-workers-unbounded", SYNTH + ["render", "configs/data/tiny.yaml", "--out", "{tmp}/r3", "--workers",
                                                "100000"], 2, ["--workers must be in [1, 256]"], ["{tmp}/r3"]),
    ("synth-missing-config", SYNTH + ["render", "{tmp}/nope.yaml", "--out", "{tmp}/r2"], 2, ["nope.yaml"],
     ["{tmp}/r2"]),
    ("synth-missing-dataset", SYNTH + ["preview", "{tmp}/nodata", "--out", "{tmp}/p.png"], 2, ["nodata"],
     ["{tmp}/p.png"]),
    ("synth-preview-name-too-long", SYNTH + ["preview", "{data}", "--out", "{tmp}/" + LONG + ".png"], 2,
     ["name too long", LONG], []),
    ("synth-render-out-through-a-file", SYNTH + ["render", "configs/data/tiny.yaml", "--out", "{file}/d"], 2,
     ["{file}"], []),
    ("synth-export-name-too-long", SYNTH + ["export", "{data}", "--format", "nuscenes", "--no-lidar", "--out",
                                            "{tmp}/" + LONG], 2, ["name too long", LONG], []),
    ("mcdp-bad-key", MCDP + ["train", TINY_TRAIN, "--data", "{data}", "--out", "{tmp}/t1", "bad.key=1"], 2,
     ["bad: unknown key"], ["{tmp}/t1"]),
    ("mcdp-missing-preset", MCDP + ["train", "{tmp}/nope.yaml", "--data", "{data}", "--out", "{tmp}/t2"], 2,
     ["nope.yaml"], ["{tmp}/t2"]),
    ("mcdp-train-out-name-too-long", MCDP + ["train", TINY_TRAIN, "--data", "{data}", "--out", "{tmp}/" + LONG], 2,
     ["name too long", LONG], []),
    ("mcdp-train-out-through-a-file", MCDP + ["train", TINY_TRAIN, "--data", "{data}", "--out", "{file}/run"], 2,
     ["{file}"], []),
    ("mcdp-eval-out-name-too-long", MCDP + ["eval", "{tmp}/norun", "--data", "{data}", "--out",
                                            "{tmp}/" + LONG + ".json"], 2, ["name too long", LONG], []),
    ("mcdp-eval-bad-key", MCDP + ["eval", "{tmp}/norun", "--data", "{data}", "eval.bad=1"], 2, ["eval.bad"], []),
    ("mcdp-predict-out-through-a-file", MCDP + ["predict", "{tmp}/norun", "--data", "{data}", "--out",
                                                "{file}/pred"], 2, ["{file}"], []),
    ("mcdp-sweep-nested-bad-key", MCDP + ["sweep", "configs/sweep/ci.yaml", "--out", "{tmp}/s1",
                                          "train_overrides=[train.bad=1]"], 2, ["train.bad"], ["{tmp}/s1"]),
    ("mcdp-eval-pickle-checkpoint", MCDP + ["eval", "{pickle_run}", "--data", "{data}", "--out", "{tmp}/m.json"], 2,
     ["last.pt", "could run code"], ["{tmp}/m.json", "{tmp}/pwned"]),
]


@pytest.mark.parametrize("argv, code, says, absent", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_user_error_ends_in_one_line_with_its_exit_code(work, argv, code, says, absent):
    fill = {k: str(v) for k, v in work.items()}
    res = _run([a.format(**fill) for a in argv])
    _assert_one_error(res, code, *[s.format(**fill) for s in says])
    assert "weights_only" not in res.stderr  # never torch's advice to load a file unsafely
    for p in absent:
        assert not Path(p.format(**fill)).exists(), p


def _ro_wrap(folder: Path) -> list[str]:
    """``sh -c 'mount a read-only tmpfs on folder, then run ...'`` in a private mount namespace."""
    folder.mkdir(parents=True, exist_ok=True)
    probe = subprocess.run(["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o ro none {folder} && ! touch {folder}/x"],
                           capture_output=True, text=True) if shutil.which("unshare") else None
    if probe is None or probe.returncode != 0:
        pytest.skip("no unprivileged mount namespace here (unshare -rm) for a read-only file system")
    return ["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o ro none {folder} && exec \"$0\" \"$@\""]


@pytest.mark.parametrize("argv", [
    SYNTH + ["render", "configs/data/tiny.yaml", "--out", "{ro}/d"],
    SYNTH + ["preview", "{data}", "--out", "{ro}/sheet.png"],
    MCDP + ["train", TINY_TRAIN, "--data", "{data}", "--out", "{ro}/run"],
    MCDP + ["eval", "{tmp}/norun", "--data", "{data}", "--out", "{ro}/m.json"],  # before the run is even read
], ids=["synth-render", "synth-preview", "mcdp-train", "mcdp-eval"])
def test_a_read_only_file_system_ends_in_one_line(work, tmp_path, argv):
    ro = tmp_path / "ro"
    wrap = _ro_wrap(ro)
    fill = {**{k: str(v) for k, v in work.items()}, "ro": str(ro)}
    argv = [a.format(**fill) for a in argv]
    res = subprocess.run([*wrap, *argv], cwd=ROOT, capture_output=True, text=True, timeout=600)
    _assert_one_error(res, 2, "read-only file system", str(ro))


def test_permission_denied_ends_in_one_line(work):
    target = Path("/sys/mcdp_cli_errors_probe.json")
    try:
        os.close(os.open(target, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(target)
        pytest.skip("/sys accepts new files here")
    except OSError as exc:
        if exc.errno not in (errno.EACCES, errno.EPERM):
            pytest.skip(f"/sys refuses with {exc.strerror}, not permission denied")
    res = _run(MCDP + ["eval", str(work["tmp"] / "norun"), "--data", str(work["data"]), "--out", str(target)])
    _assert_one_error(res, 2, "permission denied", str(target))
    res = _run(SYNTH + ["preview", str(work["data"]), "--out", "/sys/mcdp_sheet.png"])
    _assert_one_error(res, 2, "permission denied", "/sys/mcdp_sheet.png")


# --------------------------------------------------------------------------- a legal name, its temporary name
def test_a_legal_name_whose_temporary_name_would_be_too_long_is_written(work, tmp_path):
    from corelib.atomic import _name_max, atomic_write_text

    name = "s" * (_name_max(tmp_path) - 4) + ".png"  # legal; ".NAME.tmpPID" would not be
    atomic_write_text(tmp_path / name, "x")
    assert (tmp_path / name).read_text() == "x" and os.listdir(tmp_path) == [name]
    res = _run(SYNTH + ["preview", str(work["data"]), "--out", str(tmp_path / ("p" * 251 + ".png"))])
    assert res.returncode == 0, res.stderr[-2000:]
    assert sorted(os.listdir(tmp_path)) == sorted([name, "p" * 251 + ".png"])  # no temporary file left


def test_an_os_error_on_the_temporary_file_names_the_users_file(tmp_path):
    from corelib.atomic import atomic_path

    target = tmp_path / "out.json"
    with pytest.raises(PermissionError) as err:
        with atomic_path(target) as tmp:
            raise PermissionError(errno.EACCES, "Permission denied", str(tmp))
    assert err.value.filename == str(target) and os.listdir(tmp_path) == []


# --------------------------------------------------------------------------- the README's exit-code table
def _readme_exit_codes() -> dict[int, list[str]]:
    """code -> the commands the README's table says return it (``every command`` as ["*"])."""
    rows = re.findall(r"^\| (\d+) \| .+ \| (.+) \|$", (ROOT / "docs" / "TRUST.md").read_text(), re.M)  # from the README
    return {int(c): ["*"] if who.startswith("every command") else re.findall(r"`((?:synth|mcdp) \w+)", who)
            for c, who in rows}


def test_the_readme_table_lists_every_exit_code_once():
    import corelib.exitcodes as ec

    table = _readme_exit_codes()
    assert sorted(table) == sorted(v for k, v in vars(ec).items() if k.isupper() and isinstance(v, int))
    assert table[5] == ["mcdp sweep"] and table[2] == ["*"] and table[130] == ["*"]


@pytest.mark.slow
def test_no_opengl_back_end_is_exit_6_in_exactly_the_commands_the_readme_names(work, tmp_path):
    """PYOPENGL_PLATFORM=glx: a platform we do not support, as on a machine without EGL and OSMesa."""
    argv = {"synth render": SYNTH + ["render", "configs/data/tiny.yaml", "--out", str(tmp_path / "r")],
            "mcdp pretrain": MCDP + ["pretrain", "configs/pretrain/tiny.yaml", "--out", str(tmp_path / "p")],
            "mcdp sweep": MCDP + ["sweep", "configs/sweep/ci.yaml", "--out", str(tmp_path / "s"), "methods=[mono2]"]}
    assert sorted(_readme_exit_codes()[6]) == sorted(argv)
    for name, cmd in argv.items():
        res = _run(cmd + ["--no-progress"], PYOPENGL_PLATFORM="glx")
        err = res.stderr.strip().splitlines()
        assert res.returncode == 6 and "Traceback" not in res.stderr, (name, res.returncode, res.stderr[-3000:])
        assert err[-1] == f"{name}: error: PYOPENGL_PLATFORM='glx' is not supported here; use egl or osmesa", err
    res = _run(SYNTH + ["preview", str(work["data"]), "--out", str(tmp_path / "sheet.png")], PYOPENGL_PLATFORM="glx")
    assert res.returncode == 0, res.stderr[-2000:]  # no OpenGL in a preview: not in the table's row, rightly


@pytest.mark.slow  # a long command started as a subprocess, signalled once it works
@pytest.mark.parametrize("argv, started", [
    (SYNTH + ["render", "configs/data/tiny.yaml", "--out", "{tmp}/big", "dataset.frames=400", "--no-progress"],
     "synth render: "),
    (MCDP + ["train", TINY_TRAIN, "--data", "{data}", "--out", "{tmp}/long", "train.steps=100000", "--no-progress"],
     "  6 cameras"),
], ids=["synth-render", "mcdp-train"])
def test_sigint_to_the_command_alone_is_exit_130_in_one_line(work, tmp_path, argv, started, default_signals):
    fill = {"tmp": str(tmp_path), "data": str(work["data"])}
    argv = [a.format(**fill) for a in argv]
    proc = subprocess.Popen(argv, preexec_fn=default_signals, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"},
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        while not (lines and lines[-1].startswith(started)):
            line = proc.stderr.readline()
            assert line, lines
            lines.append(line)
        time.sleep(2.0)  # inside the work
        proc.send_signal(signal.SIGINT)
        rest = proc.communicate(timeout=120)[1]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    name = ("synth " if argv[2] == "synth.cli" else "mcdp ") + argv[3]
    assert proc.returncode == 130 and rest.strip().splitlines()[-1] == f"{name}: interrupted", rest[-3000:]
    assert "Traceback" not in rest


# --------------------------------------------------------------------------- item 12: config before torch
def test_a_bad_key_fails_before_torch_is_imported(work):
    for argv in (["train", TINY_TRAIN, "--data", str(work["data"]), "--out", str(work["tmp"] / "t9"), "bad.key=1"],
                 ["eval", str(work["tmp"] / "norun"), "--data", str(work["data"]), "eval.bad=1"],
                 ["pretrain", "configs/pretrain/tiny.yaml", "--out", str(work["tmp"] / "p9"), "bad=1"],
                 ["sweep", "configs/sweep/ci.yaml", "--out", str(work["tmp"] / "s9"), "data_overrides=[bad=1]"]):
        res = _run([sys.executable, "-X", "importtime", "-m", "mcdp", *argv])
        assert res.returncode == 2, res.stderr[-2000:]
        imported = {line.rsplit("|", 1)[1].strip() for line in res.stderr.splitlines() if line.startswith("import time:")}
        assert "mcdp" in imported and "torch" not in imported, argv
        assert "unknown key" in res.stderr and "Traceback" not in res.stderr


# --------------------------------------------------------------------------- kill -9 during a write
_WRITER = """
import sys, time
from corelib.atomic import atomic_path
with atomic_path(sys.argv[1]) as tmp:
    tmp.write_bytes(b"half")
    print(tmp, flush=True)
    time.sleep(600)
"""


def _killed_writer(target: Path) -> Path:
    """A writer of ``target`` killed with SIGKILL mid-write; the temporary file it left."""
    target.parent.mkdir(parents=True, exist_ok=True)
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(target)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    tmp = Path(proc.stdout.readline().strip())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert tmp.is_file()
    return tmp


def test_a_write_killed_with_sigkill_leaves_no_temporary_file_after_the_next_run(work, tmp_path):
    sheet = tmp_path / "sheet.png"  # a file output: cleaned beside it when the next preview checks it
    left = _killed_writer(sheet)
    live = tmp_path / f".sheet.png.tmp{os.getpid()}"  # a live writer's temporary file is kept
    live.write_bytes(b"busy")
    res = _run(SYNTH + ["preview", str(work["data"]), "--out", str(sheet)])
    assert res.returncode == 0, res.stderr[-2000:]
    assert not left.exists() and live.exists() and sheet.is_file()
    data = tmp_path / "data"  # a folder output: cleaned under its lock when the next render resumes it
    shutil.copytree(work["data"], data)
    left = _killed_writer(data / "seq_00000" / "CAM_FRONT" / "000000.png")
    time.sleep(0.1)
    res = _run(SYNTH + ["render", "configs/data/tiny.yaml", "--out", str(data), "--no-progress"])
    assert res.returncode == 0, res.stderr[-2000:]
    assert not left.exists()
    assert not [p for p in data.rglob("*") if ".tmp" in p.name]


@pytest.mark.slow
def test_every_writer_removes_a_killed_writers_temporary_file_on_its_next_run(work, tmp_path):
    """export, train (a checkpoint), predict: a writer killed with SIGKILL in the output folder (its
    ``.NAME.tmpPID``, exactly as `corelib.atomic` leaves it) is gone after the command's next run there."""
    d, run, ns, pred = str(work["data"]), tmp_path / "run", tmp_path / "ns", tmp_path / "pred"
    cases = [(SYNTH + ["export", d, "--format", "nuscenes", "--no-lidar", "--out", str(ns), "--no-progress"],
              ns / "samples" / "CAM_FRONT" / "x.jpg"),
             (MCDP + ["train", TINY_TRAIN, "--data", d, "--out", str(run), "--no-progress", "train.steps=1"],
              run / "checkpoints" / "last.pt"),
             (MCDP + ["predict", str(run), "--data", d, "--out", str(pred), "--max-samples", "1"],
              pred / "seq_00000" / "x.exr")]
    for argv, target in cases:
        res = _run(argv)
        assert res.returncode == 0, res.stderr[-2000:]
        target.parent.mkdir(parents=True, exist_ok=True)
        left = _killed_writer(target)
        res = _run(argv)
        assert res.returncode == 0, res.stderr[-2000:]
        assert not left.exists(), argv[3]
        assert [p for p in target.parents[1].rglob("*") if ".tmp" in p.name] == [], argv[3]


@pytest.mark.parametrize("command", ["sweep", "pretrain"])
def test_a_sweep_or_pretraining_removes_killed_writers_temporary_files_when_it_claims_its_folder(tmp_path,
                                                                                                 monkeypatch, command):
    """What a killed run, render or checkpoint left anywhere under the sweep's (pretraining's) folder is
    removed when the next run of the command locks it, before it does anything else (here: nothing else)."""
    import study.sweep.pretrain
    import study.sweep_command
    from corelib.rundir import claim

    out = tmp_path / command
    claim(out, command).release()
    left = [_killed_writer(out / "runs" / "overlap_0.20" / "mono2_s0" / "checkpoints" / "last.pt"),
            _killed_writer(out / "data" / "seq_00000" / "CAM_FRONT" / "000000.png")]
    if command == "sweep":
        monkeypatch.setattr(study.sweep_command, "_run_sweep", lambda *a: {"counters": {}})
        from study.sweep.config import load_sweep_config

        cfg = load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", ["pretrain=null"])
        study.sweep_command.run_sweep(cfg, out, progress=False, log=lambda s: None)
    else:
        monkeypatch.setattr(study.sweep.pretrain, "_pretrain", lambda *a: {})
        study.sweep.pretrain.run_pretrain(study.sweep.pretrain.load_pretrain_config(ROOT / "configs" / "pretrain" / "tiny.yaml"),
                                    out, progress=False, log=lambda s: None)
    assert [p for p in left if p.exists()] == [] and not [p for p in out.rglob("*") if ".tmp" in p.name]
