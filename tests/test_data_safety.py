"""Data safety (issue: hardening): a manifest / rig.json edited after the render is named by verify;
malformed manifests, rig files and data files give one clear error naming the key or file; a full
disk leaves nothing half-written, gives one line naming the file, and the rerun resumes; eval
refuses to overwrite a file that is not its own."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TINY_DATA = ROOT / "configs" / "data" / "tiny.yaml"
TINY_TRAIN = ROOT / "configs" / "train" / "tiny"


@pytest.fixture
def data(tiny_dataset, tmp_path) -> Path:
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    return d


def _edit_json(path: Path, fn) -> None:
    obj = json.loads(path.read_text())
    fn(obj)
    path.write_text(json.dumps(obj))


def _verify(d: Path, capsys) -> tuple[int, str]:
    from synth.cli import main

    capsys.readouterr()
    code = main(["verify", str(d)])
    out = capsys.readouterr()
    return code, out.out + out.err


def _set_K(r):
    r["cameras"][0]["K"][0][0] *= 1.01


# --------------------------------------------------------------------------- content edits
@pytest.mark.parametrize("path, edit, named", [
    ("manifest.json", lambda m: m["splits"].update(test=list(m["splits"]["train"])), "splits.test"),
    ("manifest.json", lambda m: m.update(seed=m["seed"] + 1), "seed"),
    ("manifest.json", lambda m: m["config"]["rig"].update(overlap=0.55), "config.rig"),
    ("manifest.json", lambda m: m["integrity"].update(manifest_sha256="0" * 64), "integrity record"),
    ("rig.json", _set_K, "cameras[CAM_FRONT].K"),
    ("rig.json", lambda r: r["neighbours"].reverse(), "neighbours"),
])
def test_verify_names_what_changed_in_the_manifest_or_rig(tree_hash, data, capsys, path, edit, named):
    _edit_json(data / path, edit)
    before = tree_hash(data)
    code, text = _verify(data, capsys)
    assert code == 1 and f"{path}: " in text and named in text, text
    assert len(text.splitlines()) <= 4
    assert tree_hash(data) == before


def test_an_untouched_dataset_verifies(data, capsys):
    code, text = _verify(data, capsys)
    assert code == 0 and text.startswith("OK"), text


# --------------------------------------------------------------------------- malformed manifest / rig
@pytest.mark.parametrize("path, edit, named", [
    ("manifest.json", lambda m: m.pop("cameras"), "missing key 'cameras'"),
    ("manifest.json", lambda m: m.pop("splits"), "missing key 'splits'"),
    ("manifest.json", lambda m: m.update(evil={"x": 1}), "unknown key(s) 'evil'"),
    ("manifest.json", lambda m: m.update(fps="25"), "key 'fps' has the wrong type"),
    ("manifest.json", lambda m: m["sequences"][next(iter(m["sequences"]))].update(frames=-1), ".frames must be"),
    ("rig.json", lambda r: r["cameras"][2].pop("T_ego_cam"), "cameras[CAM_BACK_RIGHT].T_ego_cam"),
    ("rig.json", lambda r: r["cameras"][1].update(width=7), "cameras[CAM_FRONT_RIGHT].width is 7"),
    ("rig.json", lambda r: r["cameras"].pop(), "camera names"),
    ("rig.json", lambda r: r.update(neighbours=[[0, 99]]), "'neighbours' must be"),
])
def test_a_malformed_manifest_or_rig_is_refused_naming_the_key(data, capsys, path, edit, named):
    from synth.open import open_dataset
    from synth.files import DatasetError

    _edit_json(data / path, edit)
    with pytest.raises(DatasetError) as err:
        open_dataset(data)
    assert f"{path}: " in str(err.value) and named in str(err.value)
    code, text = _verify(data, capsys)
    assert code == 1 and named in text and len(text.splitlines()) <= 4, text


# --------------------------------------------------------------------------- malformed data files
def _write_exr(path: Path, arrays: dict, pixel_type=None) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, arrays) as f:
        f.write(str(path))


def _truncate(p: Path):
    p.write_bytes(p.read_bytes()[: len(p.read_bytes()) // 3])


CORRUPT = {
    "truncated png": ("rgb", _truncate, "not a readable PNG"),
    "random-byte png": ("rgb", lambda p: p.write_bytes(os.urandom(500)), "not a readable PNG"),
    "png of another size": ("rgb", lambda p: __import__("cv2").imwrite(str(p), np.zeros((10, 20, 3), np.uint8)),
                            "the image is 20x10"),
    "truncated exr": ("depth", _truncate, "not a readable EXR"),
    "random-byte exr": ("depth", lambda p: p.write_bytes(os.urandom(500)), "not a readable EXR"),
    "half-float depth": ("depth", lambda p: _write_exr(p, {"Z": np.ones((64, 96), np.float16)}), "float16"),
    "depth of another shape": ("depth", lambda p: _write_exr(p, {"Z": np.ones((8, 8), np.float32)}),
                               "its header claims 8x8 pixels, the camera's images are 96x64; refused before decoding"),
    "depth without a Z channel": ("depth", lambda p: _write_exr(p, {"R": np.ones((64, 96), np.float32)}),
                                  "has channel(s) 'R'; a depth map has exactly 'Z'; refused before decoding"),
    "nan depth": ("depth", lambda p: _write_exr(p, {"Z": np.full((64, 96), np.nan, np.float32)}), "non-finite"),
}


@pytest.mark.parametrize("case", list(CORRUPT))
def test_a_corrupt_data_file_is_refused_naming_the_file(tree_hash, data, capsys, case):
    from synth.cli import main
    from synth.open import open_dataset
    from synth.files import DatasetError

    kind, damage, named = CORRUPT[case]
    ds = open_dataset(data)
    seq = ds.sequences[0]
    path = ds.rgb_path(seq, "CAM_BACK", 0) if kind == "rgb" else ds.depth_path(seq, "CAM_BACK", 0)
    damage(path)
    read = ds.read_rgb if kind == "rgb" else ds.read_depth
    with pytest.raises(DatasetError) as err:
        read(seq, "CAM_BACK", 0)
    assert str(path) in str(err.value) and named in str(err.value), str(err.value)
    # through a command: one error line naming the file, nothing written
    capsys.readouterr()
    before = tree_hash(data)
    assert main(["preview", str(data), "--out", str(data.parent / "sheet.png")]) == 2
    err_text = capsys.readouterr().err
    assert str(path) in err_text and len(err_text.splitlines()) <= 2
    assert tree_hash(data) == before and not (data.parent / "sheet.png").exists()
    code, text = _verify(data, capsys)
    assert code == 1 and str(path) in text


# --------------------------------------------------------------------------- full disk
def test_a_full_disk_during_render_leaves_nothing_half_written_and_the_rerun_resumes(tmp_path, capsys,
                                                                                     monkeypatch, full_disk_after):
    import corelib.atomic
    from synth.cli import main

    out = tmp_path / "d"
    args = ["render", str(TINY_DATA), "--out", str(out), "--no-progress", "dataset.frames=3"]
    # 8 static files, then 75 per sequence (18 PNG + 18 EXR + 18 semantic + 18 instance maps + 3 JSON): in the
    # second one
    monkeypatch.setattr(corelib.atomic, "open", full_disk_after(93), raising=False)
    capsys.readouterr()
    assert main(args) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0].startswith("synth render: ") and "rig-frames" in err[0]  # the size statement, before the work
    err = "\n".join(err[1:])
    assert len(err.splitlines()) == 1 and "no space left on device" in err and str(out) in err, err
    monkeypatch.undo()
    files = [p for p in out.rglob("*") if p.is_file()]
    assert files and all(p.stat().st_size > 0 for p in files)
    assert not any(".tmp" in p.name for p in files)
    assert not (out / "manifest.json").exists()
    whole = [p for p in out.iterdir() if p.name.startswith("seq_") and not p.name.endswith(".partial")]
    assert len(whole) == 1 and (whole[0] / "record.json").is_file()
    assert main(args) == 0  # space freed: the same command resumes
    capsys.readouterr()
    assert main(["verify", str(out)]) == 0


@pytest.mark.slow
def test_a_full_disk_while_checkpointing_keeps_the_last_checkpoint_and_training_resumes(tiny_dataset, tmp_path,
                                                                                       capsys, monkeypatch, full_disk_after):
    import corelib.atomic
    from study.method_commands import main
    from mcdp.runs import load_checkpoint

    run = tmp_path / "run"
    base = ["train", str(TINY_TRAIN / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(run),
            "--no-progress", "train.ckpt_every=1", "train.val_every=100"]
    assert main(base + ["train.steps=2"]) == 0
    last = run / "checkpoints" / "last.pt"
    before = last.read_bytes()
    monkeypatch.setattr(corelib.atomic, "open", full_disk_after(0, part=".pt.tmp"), raising=False)
    capsys.readouterr()
    assert main(base + ["train.steps=4"]) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert "no space left on device" in err[-1] and str(run / "checkpoints") in err[-1]
    assert last.read_bytes() == before and load_checkpoint(last)["step"] == 2
    assert not [p for p in (run / "checkpoints").iterdir() if ".tmp" in p.name]
    monkeypatch.undo()
    assert main(base + ["train.steps=4"]) == 0
    assert load_checkpoint(last)["step"] == 4


# --------------------------------------------------------------------------- eval --out
def test_eval_refuses_to_overwrite_a_file_that_is_not_its_metrics(tiny_dataset, tmp_path, capsys, mono2_run):
    from study.method_commands import main

    run = mono2_run  # trained once, copied here (conftest)
    mine = tmp_path / "notes.json"
    mine.write_text('{"my": "notes"}')
    ev = ["eval", str(run), "--data", str(tiny_dataset), "--no-progress", "--out"]
    capsys.readouterr()
    assert main(ev + [str(mine)]) == 2
    assert "not a metrics file written by mcdp eval" in capsys.readouterr().err
    assert mine.read_text() == '{"my": "notes"}'
    assert main(ev + [str(tmp_path)]) == 2 and "is a folder" in capsys.readouterr().err
    ours = tmp_path / "m.json"
    assert main(ev + [str(ours)]) == 0 and main(ev + [str(ours)]) == 0  # its own file: rewritten
    assert json.loads(ours.read_text())["run"]["step"] == 1


def test_a_full_disk_while_writing_exr_raises_disk_full_and_leaves_no_file(tmp_path, monkeypatch, full_disk_after):
    """OpenEXR encodes in memory and `corelib.atomic` writes the file: a full disk is its DiskFullError."""
    import corelib.atomic
    from corelib.atomic import DiskFullError
    from synth.files import write_depth_exr

    monkeypatch.setattr(corelib.atomic, "open", full_disk_after(0), raising=False)
    p = tmp_path / "d.depth.exr"
    with pytest.raises(DiskFullError, match="d.depth.exr: no space left on device"):
        write_depth_exr(p, np.ones((4, 4), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_a_second_render_into_the_same_folder_is_refused_naming_the_pid(tmp_path, capsys):
    from corelib.rundir import lock_folder
    from synth.cli import main
    from synth.config import load_data_config
    from synth.render import prepare_output

    out = tmp_path / "d"
    over = ["dataset.frames=3", "dataset.sequences=1"]
    args = ["render", str(TINY_DATA), "--out", str(out), "--no-progress"] + over
    prepare_output(load_data_config(TINY_DATA, over), out)  # another render of the same config is under way
    held = lock_folder(out, ".synth/lock")
    try:
        capsys.readouterr()
        assert main(args) == 2
        assert f"another process (pid {os.getpid()})" in capsys.readouterr().err
        assert not any(p.name.startswith("seq_") for p in out.iterdir())
    finally:
        held.release()
    assert main(args) == 0
