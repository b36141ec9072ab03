"""Hardening, round two (issue 20): no command overwrites what it did not write, no file leaves its
dataset through a symlink, every export file is whole on a full disk, a JPEG under a .png name is
refused where it is read, and outputs are not written inside a dataset.

Each test runs the command as a user would (the CLI's `main`) and asserts the exit code, a one-line
message naming the file, and that nothing outside the command's own output changed.
"""
from __future__ import annotations


import os
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from synth.cli import main as synth_main
from synth.preview import key_row

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "data" / "tiny.yaml"
SEQ_CAM = "seq_00000/CAM_FRONT"


@pytest.fixture
def data(tiny_dataset, tmp_path) -> Path:
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    return d


def _err_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


# --------------------------------------------------------------------------- 1: preview --out
def test_preview_refuses_a_path_it_did_not_write(data, tmp_path, capsys, tree_hash):
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    before = tree_hash(data)
    for target, said in [(data / "manifest.json", "is not a preview sheet written by synth preview"),
                         (notes, "is not a preview sheet written by synth preview"),
                         (fifo, "is not a regular file"),
                         (tmp_path, "is a folder"),
                         (data / "seq_00000" / "sheet.png", "inside the dataset")]:
        assert synth_main(["preview", str(data), "--out", str(target)]) == 2, target
        line = _err_line(capsys)
        assert str(target) in line and said in line, line
    assert tree_hash(data) == before and notes.read_text() == "mine"
    assert (tmp_path / "fifo").is_fifo()


def test_preview_rewrites_its_own_sheet_and_refuses_a_user_png(data, tmp_path, capsys):
    sheet = tmp_path / "sheet.png"
    assert synth_main(["preview", str(data), "--out", str(sheet)]) == 0
    first = sheet.read_bytes()
    assert synth_main(["preview", str(data), "--out", str(sheet), "--frame", "1"]) == 0
    assert sheet.read_bytes() != first  # its own sheet: rewritten
    img = cv2.imread(str(sheet))
    # 6 cameras x 5 tiles of 96x64 (the class map), a legend, the depth colour bar
    assert img.shape == (6 * 64 + 54 + key_row(5 * 96, flow=False).shape[0], 5 * 96, 3)
    photo = tmp_path / "photo.png"
    cv2.imwrite(str(photo), np.zeros((8, 8, 3), np.uint8))
    held = photo.read_bytes()
    capsys.readouterr()
    assert synth_main(["preview", str(data), "--out", str(photo)]) == 2
    assert "not a preview sheet" in _err_line(capsys) and photo.read_bytes() == held


# --------------------------------------------------------------------------- 2: file symlinks
def _link_depth_outside(data: Path, tmp_path: Path) -> tuple[Path, bytes]:
    """seq_00000/CAM_FRONT/000000.depth.exr -> a mode-600 file outside the dataset (a valid EXR)."""
    secret = tmp_path / "secret.exr"
    link = data / SEQ_CAM / "000000.depth.exr"
    shutil.copyfile(link, secret)
    secret.chmod(0o600)
    link.unlink()
    link.symlink_to(secret)
    return link, secret.read_bytes()


def test_export_refuses_a_depth_file_symlinked_out_of_the_dataset(data, tmp_path, capsys):
    link, secret = _link_depth_outside(data, tmp_path)
    out = tmp_path / "ns"
    assert synth_main(["export", str(data), "--format", "nuscenes", "--out", str(out), "--no-lidar",
                       "--no-progress"]) == 2
    line = _err_line(capsys)
    assert str(link) in line and "outside the dataset root" in line, line
    copied = [p for p in out.rglob("*") if p.is_file() and p.read_bytes() == secret]
    assert copied == []


def test_readers_and_verify_refuse_a_file_symlinked_out_of_the_dataset(data, tmp_path, capsys):
    from synth.open import open_dataset
    from synth.files import DatasetError

    link, _ = _link_depth_outside(data, tmp_path)
    ds = open_dataset(data)
    with pytest.raises(DatasetError, match="outside the dataset root"):
        ds.read_depth("seq_00000", "CAM_FRONT", 0)
    rgb = data / SEQ_CAM / "000001.png"
    outside = tmp_path / "img.png"
    shutil.move(rgb, outside)
    rgb.symlink_to(outside)
    with pytest.raises(DatasetError, match="000001.png: is a link to .*outside the dataset root"):
        ds.read_rgb("seq_00000", "CAM_FRONT", 1)
    assert synth_main(["verify", str(data)]) == 1
    err = capsys.readouterr().err
    assert f"{link}: is a link to" in err and f"{rgb}: is a link to" in err


# --------------------------------------------------------------------------- 3: full disk in export
@pytest.mark.parametrize("part", [".pcd.bin", ".depth.exr"])
def test_a_full_disk_during_export_exits_4_and_leaves_no_part_file(data, tmp_path, capsys, monkeypatch, part,
                                                                    full_disk_after):
    import corelib.atomic

    full_open = full_disk_after(0, part)  # the first write of such a file stores half and fails

    out = tmp_path / "ns"
    args = ["export", str(data), "--format", "nuscenes", "--out", str(out), "--no-progress"]
    monkeypatch.setattr(corelib.atomic, "open", full_open, raising=False)
    assert synth_main(args) == 4
    line = _err_line(capsys)
    assert "no space left on device" in line and part in line, line
    assert [p for p in out.rglob(f"*{part}*")] == []  # neither the final name nor a temporary one
    monkeypatch.undo()
    assert synth_main(args) == 0  # space freed: the same command writes the export
    bins = sorted((out / "samples" / "LIDAR_TOP").iterdir())
    assert bins and all(p.stat().st_size % 20 == 0 and p.stat().st_size > 0 for p in bins)  # 5 float32 a point
    exrs = sorted((out / "mcdp_synth" / "depth" / "CAM_FRONT").iterdir())
    assert exrs[0].read_bytes() == (data / SEQ_CAM / "000000.depth.exr").read_bytes()


# --------------------------------------------------------------------------- 8: a JPEG under .png
def test_a_jpeg_under_a_png_name_is_refused_where_it_is_read(data, tmp_path, capsys):
    from synth.open import open_dataset
    from synth.files import DatasetError

    png = data / SEQ_CAM / "000000.png"
    img = cv2.imread(str(png))
    ok, jpg = cv2.imencode(".jpg", img)
    png.write_bytes(jpg.tobytes())
    assert cv2.imread(str(png)).shape == img.shape  # what the old reader accepted
    with pytest.raises(DatasetError, match=r"000000.png: not a readable PNG \(a JPEG file"):
        open_dataset(data).read_rgb("seq_00000", "CAM_FRONT", 0)
    assert synth_main(["export", str(data), "--format", "nuscenes", "--out", str(tmp_path / "ns"),
                       "--no-lidar", "--no-progress"]) == 2
    line = _err_line(capsys)
    assert str(png) in line and "a JPEG file" in line, line


# --------------------------------------------------------------------------- 5: the size of a render
def test_a_render_states_its_size_and_refuses_a_huge_one_without_yes(tmp_path, capsys, tiny_config):
    from synth.config import MAX_RENDER_BYTES, render_size

    assert render_size(tiny_config) == {"rig_frames": 18, "images": 108, "max_bytes": 108 * 96 * 64 * (7 + 1 + 2)}
    assert render_size(tiny_config, shard_of=2)["rig_frames"] == 12  # sequences 0 and 2 of 3
    out = tmp_path / "big"
    huge = ["camera.width=4096", "camera.height=4096", "dataset.sequences=100000", "dataset.frames=10000"]
    assert synth_main(["render", str(TINY), "--out", str(out), "--no-progress", *huge]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("synth render: 1000000000 rig-frames, 6000000000 images of 4096x4096")
    assert len(err) == 2 and "--yes" in err[1] and f"more than {MAX_RENDER_BYTES // 10**9} GB" in err[1], err
    assert not out.exists()


HUGE_WORLD = "camera.width=4096,camera.height=4096,dataset.sequences=100,dataset.frames=4"  # 282 GB a world


@pytest.mark.parametrize("argv, said", [
    # two overlaps of 282 GB each: every render under the cap, the sweep's renders together above it
    (["sweep", "configs/sweep/ci.yaml", f"data_overrides=[{HUGE_WORLD}]", "pretrain=null"],
     "mcdp sweep: its renders: 800 rig-frames, 4800 images"),
    (["sweep", "configs/sweep/ci.yaml", f"pretrain.data_overrides=[{HUGE_WORLD},seed=1000]",
      "data_overrides=[camera.width=4096,camera.height=4096,dataset.sequences=100,dataset.frames=3]"],
     "mcdp sweep: its renders: 1000 rig-frames"),  # 282 GB of pretraining world + 2 x 211 GB
    (["pretrain", "configs/pretrain/tiny.yaml", "data_overrides=[camera.width=4096,camera.height=4096,"
                                                 "dataset.sequences=100,dataset.frames=10]"],
     "mcdp pretrain: its world: 1000 rig-frames"),
], ids=["sweep-overlaps", "sweep-with-pretraining", "pretrain"])
def test_a_sweep_or_pretraining_refuses_renders_above_the_cap_before_its_folder(tmp_path, capsys, argv, said):
    """The cap of `synth render` holds for the renders a sweep or a pretraining does: all of them stated
    and checked before the folder is claimed, refused above the cap without --yes."""
    from synth.config import MAX_RENDER_BYTES
    from study.cli import main as study_main

    out = tmp_path / "out"
    assert study_main([argv[0], argv[1], "--out", str(out), "--no-progress", *argv[2:]]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and err[0].startswith(said), err
    assert "--yes" in err[1] and f"more than {MAX_RENDER_BYTES // 10**9} GB" in err[1], err
    assert not out.exists()


def test_run_sweep_checks_every_render_and_yes_lets_it_through(tmp_path):
    from corelib.configlib import ConfigError
    from study.sweep.config import check_nested_configs, load_sweep_config
    from study.sweep_command import run_sweep

    cfg = load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", [f"data_overrides=[{HUGE_WORLD}]"])
    with pytest.raises(ConfigError, match=r"sweep: its 3 world\(s\) \(2 overlap\(s\) of configs/data/tiny.yaml "
                                          r"and the pretraining's\): this render is up to 805 GB"):
        run_sweep(cfg, tmp_path / "s", progress=False, log=lambda s: None)
    assert not (tmp_path / "s").exists()
    size = check_nested_configs(cfg, yes=True)  # told to: the size is returned, nothing refused
    assert size == {"rig_frames": 2 * 400 + 3 * 4, "images": 6 * (800 + 12),
                    "max_bytes": (6 * 800 * 4096 * 4096 + 6 * 12 * 96 * 64) * (7 + 1 + 2)}  # RGB, depth, labels


# --------------------------------------------------------------------------- 9: outputs inside a dataset
def test_outputs_inside_a_dataset_are_refused(data, tmp_path, capsys, tree_hash):
    from study.method_commands import main as mcdp_main

    before = tree_hash(data)
    inner = data / "seq_00000"
    mono2 = str(ROOT / "configs" / "train" / "tiny" / "mono2.yaml")
    for code, argv in [
        (synth_main, ["render", str(TINY), "--out", str(inner / "d"), "--no-progress"]),
        (synth_main, ["export", str(data), "--format", "nuscenes", "--out", str(inner / "ns")]),
        (mcdp_main, ["train", mono2, "--data", str(data), "--out", str(inner / "run"), "--no-progress"]),
        (mcdp_main, ["predict", str(tmp_path / "run"), "--data", str(data), "--out", str(inner / "pred")]),
        (mcdp_main, ["eval", str(tmp_path / "run"), "--data", str(data), "--out", str(inner / "m.json")]),
        (mcdp_main, ["predict", str(tmp_path / "run"), "--data", str(data), "--rrd", str(inner / "p.rrd")]),
        (synth_main, ["merge", "--out", str(inner / "merged"), str(data)]),
        (synth_main, ["view", str(data), "--out", str(inner / "rig.rrd")]),
    ]:
        assert code(argv) == 2, argv
        line = _err_line(capsys)
        assert f"is inside the dataset {data.resolve()}" in line, line
    assert tree_hash(data) == before


def test_predict_refuses_a_folder_of_another_dataset_or_run(tiny_dataset, data, tmp_path, capsys, mono2_run):
    import json

    from study.method_commands import main as mcdp_main

    run = mono2_run  # trained once, copied here (conftest)
    pred = tmp_path / "pred"
    argv = ["predict", str(run), "--out", str(pred), "--max-samples", "1", "--data"]
    assert mcdp_main(argv + [str(tiny_dataset)]) == 0
    rec = json.loads((pred / "predict.json").read_text())
    assert rec["run"] == str(run.resolve()) and rec["data"] == str(tiny_dataset.resolve()) and rec["step"] == 1
    files = sorted(p for p in pred.rglob("*") if p.is_file())
    assert mcdp_main(argv + [str(tiny_dataset)]) == 0  # the same run and dataset: rewritten
    capsys.readouterr()
    assert mcdp_main(argv + [str(data)]) == 2  # a copy elsewhere is another dataset
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert "holds predictions of another run or dataset" in line and str(pred) in line, line
    assert sorted(p for p in pred.rglob("*") if p.is_file()) == files


# --------------------------------------------------------------------------- 10: eval on another rig
def test_eval_on_another_rig_warns_and_records_the_difference(tiny_dataset, tmp_path, capsys, mono2_run):
    import json

    from study.method_commands import main as mcdp_main

    run = mono2_run  # trained once, copied here (conftest)
    assert len(json.loads((run / "run.json").read_text())["rig"]) == 6
    other = tmp_path / "wide"
    assert synth_main(["render", str(TINY), "--out", str(other), "--no-progress", "rig.overlap=0.5"]) == 0
    capsys.readouterr()
    ev = ["eval", str(run), "--no-progress", "--data"]
    assert mcdp_main(ev + [str(tiny_dataset), "--out", str(tmp_path / "same.json")]) == 0
    assert "warning" not in capsys.readouterr().err
    same = json.loads((tmp_path / "same.json").read_text())["run"]
    assert same["rig_as_trained"] is True and same["rig_differences"] == []
    assert mcdp_main(ev + [str(other), "--out", str(tmp_path / "wide.json")]) == 0
    err = capsys.readouterr().err
    assert f"warning: {other}'s rig differs from the one {run} was trained on: CAM_FRONT_RIGHT T_ego_cam" in err
    wide = json.loads((tmp_path / "wide.json").read_text())["run"]
    assert wide["rig_as_trained"] is False and "CAM_FRONT_RIGHT T_ego_cam" in wide["rig_differences"]
    assert "CAM_FRONT T_ego_cam" not in wide["rig_differences"]  # spacing mode: the front camera stays put
