"""Untrusted files (issue 32, hardening round three): every file a command reads from a dataset or a
nuScenes dataroot is its own (inside the root, not through a link out of it) and a regular file (a FIFO
or a device is refused, never opened for a blocking read); `synth merge` copies no link; numbers read
from a dataroot's tables are validated; outputs never land inside a dataset or dataroot; a dead worker
does not hang its parent. Each refusal is one line naming the file, exit 2, nothing written.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _shard(tiny_dataset, tmp_path) -> Path:
    """A shard folder: the finished tiny dataset without its manifest (a render of every sequence)."""
    d = tmp_path / "shA"
    shutil.copytree(tiny_dataset, d)
    (d / "manifest.json").unlink()
    return d


def _first_seq(d: Path) -> str:
    return sorted(p.name for p in d.glob("seq_*"))[0]


def _link_depth(d: Path, secret: Path) -> Path:
    p = d / _first_seq(d) / "CAM_FRONT" / "000000.depth.exr"
    shutil.copyfile(p, secret)
    os.chmod(secret, 0o600)
    p.unlink()
    p.symlink_to(secret)
    return p


def _link_seq(d: Path, secret: Path) -> Path:
    p = d / _first_seq(d)
    shutil.move(str(p), secret)
    p.symlink_to(secret, target_is_directory=True)
    return p


def _link_rig(d: Path, secret: Path) -> Path:
    p = d / "rig.json"
    shutil.move(str(p), secret)
    p.symlink_to(secret)
    return p


def _link_mask(d: Path, secret: Path) -> Path:
    p = d / "masks" / "CAM_FRONT.png"
    shutil.move(str(p), secret)
    p.symlink_to(secret)
    return p


def _fifo_png(d: Path, secret: Path) -> Path:
    p = d / _first_seq(d) / "CAM_BACK" / "000001.png"
    p.unlink()
    os.mkfifo(p)
    return p


# --------------------------------------------------------------------------- finding 1: merge
@pytest.mark.parametrize("plant", [_link_depth, _link_seq, _link_rig, _link_mask, _fifo_png])
def test_merge_copies_no_link_and_no_special_file(tiny_dataset, tmp_path, capsys, plant):
    from synth.cli import main as synth_main

    shard = _shard(tiny_dataset, tmp_path)
    bad = plant(shard, tmp_path / "secret")
    out = tmp_path / "MG"
    capsys.readouterr()
    assert synth_main(["merge", "--out", str(out), str(shard)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and len(err.splitlines()) == 1, err
    assert not out.exists()  # checked before anything is written


# --------------------------------------------------------------------------- findings 3 and 4: every reader
def _plant(p: Path, kind: str, tmp_path: Path) -> None:
    """Replace the file (or folder) `p` by a FIFO, a character device (/dev/zero's) or a link out of the root."""
    outside = tmp_path / f"outside_{p.name}"
    shutil.move(str(p), outside)
    if kind == "fifo":
        os.mkfifo(p)
    elif kind == "chardev":
        try:
            os.mknod(p, 0o600 | 0o020000, os.makedev(1, 5))  # S_IFCHR, /dev/zero
        except PermissionError:
            pytest.skip("creating a device file needs CAP_MKNOD")
    else:
        p.symlink_to(outside, target_is_directory=outside.is_dir())


@pytest.fixture
def alarm():
    """A reader that blocks on a FIFO fails the test instead of hanging it."""
    import signal

    def boom(*_):
        raise TimeoutError("the reader blocked")

    old = signal.signal(signal.SIGALRM, boom)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


def _read_all_synth(d: Path) -> None:
    from synth.open import open_dataset

    ds = open_dataset(d)
    seq = ds.split("test")[0]
    ds.ego(seq)
    ds.mask("CAM_FRONT")
    ds.read_rgb(seq, "CAM_FRONT", 0)
    ds.read_depth(seq, "CAM_FRONT", 0)


SYNTH_FILES = ["manifest.json", "rig.json", "masks/CAM_FRONT.png", "{seq}/ego.json", "{seq}/CAM_FRONT/000000.png",
               "{seq}/CAM_FRONT/000000.depth.exr"]


@pytest.mark.parametrize("kind", ["fifo", "chardev", "link"])
@pytest.mark.parametrize("rel", SYNTH_FILES)
def test_every_synth_reader_refuses_a_special_file_or_a_link_out_naming_it(tiny_dataset, tmp_path, alarm, rel, kind):
    from synth.files import DatasetError

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    seq = json.loads((d / "manifest.json").read_text())["splits"]["test"][0]
    p = d / rel.format(seq=seq)
    _plant(p, kind, tmp_path)
    with pytest.raises(DatasetError) as e:
        _read_all_synth(d)
    assert str(p) in str(e.value) and len(str(e.value).splitlines()) == 1, e.value


@pytest.mark.parametrize("rel", SYNTH_FILES)
def test_every_synth_reader_refuses_a_file_larger_than_its_bound_before_reading_it(tiny_dataset, tmp_path, rel):
    """Finding 3's size rule: a (sparse) 3 GiB file in place of any dataset file is refused by its size on the
    open descriptor, naming it, before a byte is read (the sparse file costs no disk)."""
    import resource

    from synth.files import MAX_READ_BYTES, DatasetError

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    seq = json.loads((d / "manifest.json").read_text())["splits"]["test"][0]
    p = d / rel.format(seq=seq)
    p.unlink()
    with open(p, "wb") as f:
        f.truncate(3 * 2**30)
    assert p.stat().st_size > MAX_READ_BYTES
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(DatasetError) as e:
        _read_all_synth(d)
    assert str(p) in str(e.value) and "refused before reading" in str(e.value), e.value
    assert len(str(e.value).splitlines()) == 1
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before < 512 * 2**10  # KiB: nothing was read


def test_eval_on_a_dataset_with_a_fifo_image_exits_2_naming_it(tiny_dataset, tmp_path, capsys, alarm, mono2_run):
    from study.method_commands import main

    run = mono2_run  # trained once, copied here (conftest)
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    seq = json.loads((d / "manifest.json").read_text())["splits"]["test"][0]
    p = d / seq / "CAM_BACK" / "000001.png"
    _plant(p, "fifo", tmp_path)
    capsys.readouterr()
    assert main(["eval", str(run), "--data", str(d), "--out", str(tmp_path / "m.json"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert str(p) in err and "FIFO" in err


def _ns_copy(ns_root, tmp_path) -> Path:
    root = tmp_path / "ns"
    shutil.copytree(ns_root, root, symlinks=True)
    return root


def _read_all_ns(root: Path, seq: str) -> None:
    from synth.nuscenes.read import open_nuscenes

    ds = open_nuscenes(root)
    ds.read_rgb(seq, "CAM_FRONT", 0)
    ds.read_depth(seq, "CAM_FRONT", 0)


NS_FILES = ["v1.0-synth/sample_data.json", "v1.0-synth/calibrated_sensor.json", "v1.0-synth/ego_pose.json",
            "mcdp_synth/masks/CAM_FRONT.png", "mcdp_synth/splits.json", "mcdp_synth/export.json", "{rgb}", "{lidar}"]


@pytest.mark.parametrize("kind", ["fifo", "link"])
@pytest.mark.parametrize("rel", NS_FILES)
def test_every_nuscenes_reader_refuses_a_special_file_or_a_link_out_naming_it(ns_root, tmp_path, alarm, rel, kind):
    from synth.files import DatasetError
    from synth.nuscenes.read import open_nuscenes

    root = _ns_copy(ns_root, tmp_path)
    ds = open_nuscenes(root)
    seq = ds.sequences[0]
    lid = ds._seq(seq)[0]["lidar"]["filename"]
    p = root / rel.format(rgb=ds.rgb_path(seq, "CAM_FRONT", 0).relative_to(root), lidar=lid)
    _plant(p, kind, tmp_path)
    with pytest.raises(DatasetError) as e:
        _read_all_ns(root, seq)
    assert str(p) in str(e.value) and len(str(e.value).splitlines()) == 1, e.value


def test_a_version_folder_linked_out_of_the_dataroot_is_refused(ns_root, tmp_path):
    from synth.files import DatasetError
    from synth.nuscenes.read import open_nuscenes

    root = _ns_copy(ns_root, tmp_path)
    _plant(root / "v1.0-synth", "link", tmp_path)
    with pytest.raises(DatasetError, match="outside the dataroot"):
        open_nuscenes(root)


def test_a_manifest_that_is_not_utf8_is_refused_naming_it(tiny_dataset, tmp_path):
    from synth.open import open_dataset
    from synth.files import DatasetError

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    (d / "manifest.json").write_bytes(b'{"a": "\xff\xfe"}')
    with pytest.raises(DatasetError, match=f"{d / 'manifest.json'}: not UTF-8"):
        open_dataset(d)


# --------------------------------------------------------------------------- finding 5: numbers in the tables
def _edit_calib(root: Path, channel: str, fn) -> str:
    """Apply `fn` to the calibrated_sensor record of `channel`; returns its token."""
    tab = root / "v1.0-synth"
    sensor = {s["token"]: s["channel"] for s in json.loads((tab / "sensor.json").read_text())}
    rows = json.loads((tab / "calibrated_sensor.json").read_text())
    rec = next(r for r in rows if sensor[r["sensor_token"]] == channel)
    fn(rec)
    (tab / "calibrated_sensor.json").write_text(json.dumps(rows))
    return rec["token"]


def _set_k(i, j, v):
    return lambda r: r["camera_intrinsic"][i].__setitem__(j, v)


@pytest.mark.parametrize("edit, what", [
    (_set_k(0, 0, float("nan")), "non-finite"),
    (_set_k(0, 0, 1e308), "fx = 1e+308"),
    (_set_k(1, 1, 0.0), "fy = 0"),
    (_set_k(0, 0, -800.0), "fx = -800"),
    (_set_k(2, 0, 1.0), "last row"),
    (lambda r: r.update(rotation=[2.0, 0.0, 0.0, 0.0]), "unit quaternion"),
    (lambda r: r.update(translation=[float("inf"), 0.0, 0.0]), "finite"),
])
def test_a_nuscenes_calibration_that_is_not_a_camera_is_refused_naming_table_and_token(ns_root, tmp_path, edit, what):
    from synth.files import DatasetError
    from synth.nuscenes.read import open_nuscenes

    root = _ns_copy(ns_root, tmp_path)
    token = _edit_calib(root, "CAM_FRONT_LEFT", edit)
    with pytest.raises(DatasetError) as e:
        open_nuscenes(root)
    msg = str(e.value)
    assert "calibrated_sensor.json" in msg and token in msg and what in msg and len(msg.splitlines()) == 1, msg


def test_eval_on_a_dataroot_with_a_zero_focal_length_exits_2_in_one_line(ns_root, tiny_dataset, tmp_path, capsys,
                                                                         mono2_run):
    from study.method_commands import main

    run = mono2_run  # trained once, copied here (conftest)
    root = _ns_copy(ns_root, tmp_path)
    token = _edit_calib(root, "CAM_BACK", _set_k(0, 0, 0.0))
    capsys.readouterr()
    assert main(["eval", str(run), "--data", str(root), "--out", str(tmp_path / "m.json"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert token in err and "fx = 0" in err and "Traceback" not in err and len(err.strip().splitlines()) <= 2, err
    assert not (tmp_path / "m.json").exists()


# --------------------------------------------------------------------------- finding 6: outputs
def test_sweep_and_pretrain_refuse_an_out_inside_a_dataset_before_writing(tiny_dataset, tmp_path, capsys, tree_hash):
    from study.cli import main

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    before = tree_hash(d)
    for argv in (["sweep", str(ROOT / "configs/sweep/ci.yaml"), "--out", str(d / "sw"), "--no-progress"],
                 ["pretrain", str(ROOT / "configs/pretrain/tiny.yaml"), "--out", str(d / "pt"), "--no-progress"]):
        capsys.readouterr()
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"is inside the dataset {d.resolve()}" in err and len(err.strip().splitlines()) == 1, err
    assert tree_hash(d) == before


def test_every_writer_refuses_an_out_inside_a_nuscenes_dataroot(ns_root, tiny_dataset, tmp_path, capsys, tree_hash,
                                                                mono2_run):
    from study.cli import main
    from synth.cli import main as synth_main

    run = mono2_run  # trained once, copied here (conftest)
    root = _ns_copy(ns_root, tmp_path)
    before = tree_hash(root)
    inner = root / "samples"
    mono2 = str(ROOT / "configs/train/tiny/mono2.yaml")
    for code, argv in [
        (main, ["train", mono2, "--data", str(tiny_dataset), "--out", str(inner / "run"), "--no-progress"]),
        (main, ["predict", str(run), "--data", str(tiny_dataset), "--out", str(inner / "pred")]),
        (main, ["eval", str(run), "--data", str(tiny_dataset), "--out", str(inner / "m.json")]),
        (main, ["sweep", str(ROOT / "configs/sweep/ci.yaml"), "--out", str(inner / "sw"), "--no-progress"]),
        (main, ["pretrain", str(ROOT / "configs/pretrain/tiny.yaml"), "--out", str(inner / "pt"), "--no-progress"]),
        (synth_main, ["render", str(ROOT / "configs/data/tiny.yaml"), "--out", str(inner / "d"), "--no-progress"]),
    ]:
        capsys.readouterr()
        assert code(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"is inside the dataset {root.resolve()}" in err, (argv, err)
    assert tree_hash(root) == before


# --------------------------------------------------------------------------- finding 2: dead workers
def _children(pid: int) -> list[int]:
    out = []
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = st.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(st.parent.name))
    return out


def _renders(pid: int) -> bool:
    """The process `pid` has an OpenGL library mapped (a render worker, not the manager or resource tracker)."""
    try:
        maps = Path(f"/proc/{pid}/maps").read_text()
    except OSError:
        return False
    return any(k in maps for k in ("libEGL", "libOSMesa", "libGL", "llvmpipe", "gallium"))


@pytest.mark.slow
def test_a_render_worker_killed_ends_the_render_in_one_line_and_the_rerun_resumes(tmp_path):
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "d"
    argv = [sys.executable, "-m", "synth.cli", "render", str(ROOT / "configs/data/tiny.yaml"), "--out", str(out),
            "--workers", "2", "--no-progress", "dataset.frames=40"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    p = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        victim, t0 = None, time.time()
        while victim is None and time.time() - t0 < 240 and p.poll() is None:
            if list(out.glob("seq_*.partial")):
                victim = next((c for c in _children(p.pid) if _renders(c)), None)
            time.sleep(0.2)
        assert victim is not None, "no render worker seen"
        os.kill(victim, signal.SIGKILL)
        _, err = p.communicate(timeout=240)  # the parent notices; no hang
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 1, err
    line = err.strip().splitlines()[-1]
    assert "worker process died" in line and "seq_0000" in line and "run the same command again" in line, err
    assert "Traceback" not in err and not (out / "manifest.json").exists()
    again = subprocess.run(argv[:-4] + ["--workers", "1", "--no-progress", "dataset.frames=40"], capture_output=True,
                           text=True, env=env, timeout=400)
    assert again.returncode == 0, again.stderr
    assert (out / "manifest.json").is_file() and not list(out.glob("*.partial"))


def _die(*_args):
    """A sweep run whose process is killed, as the out-of-memory killer does."""
    import signal

    os.kill(os.getpid(), signal.SIGKILL)


def test_a_sweep_run_worker_killed_ends_in_one_line_naming_the_runs(tmp_path, monkeypatch):
    from corelib.procs import WorkerLost
    from study.sweep import engines
    from study.sweep.config import load_sweep_config
    from study.sweep.stages import Counters

    cfg = load_sweep_config(ROOT / "configs/sweep/ci.yaml", ["jobs=2"])
    monkeypatch.setattr(engines, "_stage_job", _die)  # pickled by name: the workers run this module's _die
    todo = [({"overlap": 0.2}, "mono2", 0), ({"overlap": 0.5}, "mono2", 0)]
    with pytest.raises(WorkerLost) as e:
        engines._run_parallel(cfg, todo, tmp_path / "sw", Counters(), lambda s: None)
    msg = str(e.value)
    assert "mcdp sweep: a worker process died" in msg and "2 run(s) unfinished" in msg and "mono2" in msg, msg
    assert len(msg.splitlines()) == 1 and "run the same command again" in msg


def test_worker_lost_is_exit_1_in_one_line(capsys):
    from corelib import cli, exitcodes
    from corelib.procs import lost_workers
    from study.cli import RULES

    def boom(_args):
        raise lost_workers("mcdp sweep", ["o0.20/mono2/s0"], "run(s)")

    cmd = cli.Command("boom", "", lambda p: None, boom)
    assert cli.main("mcdp", "", [cmd], ["boom"], RULES) == exitcodes.FAILED
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "o0.20/mono2/s0" in err and "Traceback" not in err


# --------------------------------------------------------------------------- finding 9: choices first
def test_eval_refuses_an_unknown_stage_before_evaluating(tiny_dataset, tmp_path, capsys, monkeypatch, mono2_run):
    import mcdp.evaluate
    from study.method_commands import main

    run = mono2_run  # trained once, copied here (conftest)

    def never(*a, **k):
        raise AssertionError("evaluated before the stage was checked")

    monkeypatch.setattr(mcdp.evaluate, "evaluate", never)
    capsys.readouterr()
    assert main(["eval", str(run), "--data", str(tiny_dataset), "--out", str(tmp_path / "m.json"), "--stage", "bogus",
                 "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--stage 'bogus' is not a stage" in err and "final" in err and len(err.strip().splitlines()) <= 2, err
    assert not (tmp_path / "m.json").exists()


# --------------------------------------------------------------------------- finding 8: configs bounded
@pytest.mark.parametrize("cli", ["mcdp", "synth"])
def test_a_config_nested_1000_deep_is_one_bounded_error_naming_the_file(tmp_path, capsys, cli):
    from study.method_commands import main
    from synth.cli import main as synth_main

    cfg = tmp_path / "deep.yaml"
    cfg.write_text("model: {method: mono2}\nx: " + "[" * 1000 + "]" * 1000 + "\n")
    argv = (["train", str(cfg), "--data", str(tmp_path), "--out", str(tmp_path / "run")] if cli == "mcdp"
            else ["render", str(cfg), "--out", str(tmp_path / "d")])
    assert (main if cli == "mcdp" else synth_main)(argv) == 2
    err = capsys.readouterr().err
    assert str(cfg) in err and "nested more than 32" in err and len(err.splitlines()) <= 3 and len(err) < 600, err


def test_an_override_nested_1000_deep_is_one_bounded_error(tmp_path, capsys):
    from study.method_commands import main

    assert main(["train", str(ROOT / "configs/train/tiny/mono2.yaml"), "--data", str(tmp_path), "--out",
                 str(tmp_path / "run"), "train.lr=" + "[" * 1000 + "]" * 1000]) == 2
    err = capsys.readouterr().err
    assert "train.lr" in err and "nested more than 32" in err and len(err) < 800, err


def test_5000_unknown_keys_and_a_huge_value_give_a_few_lines(tmp_path, capsys):
    """(60000 keys are refused by their count: tests/test_bounded_inputs.py)"""
    from study.method_commands import main

    cfg = tmp_path / "many.yaml"
    cfg.write_text("model: {method: mono2}\ntrain: {lr: '" + "x" * 400_000 + "'}\n"
                   + "".join(f"k{i}: 1\n" for i in range(5000)))
    assert main(["train", str(cfg), "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) <= 12 and len(err) < 2000 and "more)" in err, err[:3000]
