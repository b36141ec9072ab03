"""Hardening, round four (issue 41), items 5 and 6: what a dataset's files claim is bounded before it is used.

5. a manifest's ``image_size`` / ``camera_sizes`` above the config's camera bound (`synth.rig.MAX_CAMERA_PX`) is
   refused naming the field, and a PNG or EXR whose header claims more is refused before it is decoded;
6. ``synth verify`` refuses a ``manifest.json`` (or ``rig.json``) linked out of the dataset, as every other command
   does, and refuses a listed file over `synth.files.MAX_READ_BYTES` by its size without reading it.
"""
from __future__ import annotations

import json
import shutil
import zlib
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BIG = 30000  # what the finding's manifest claimed


def _copy(tiny_dataset, tmp_path) -> Path:
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    return d


def _claim_size(d: Path, w: int, h: int, per_camera: bool) -> None:
    """The manifest and rig.json claim every camera is w x h (so they agree with each other)."""
    m = json.loads((d / "manifest.json").read_text())
    if per_camera:
        m["camera_sizes"] = {c: [w, h] for c in m["cameras"]}
    else:
        m["image_size"] = {"width": w, "height": h}
    (d / "manifest.json").write_text(json.dumps(m))
    rig = json.loads((d / "rig.json").read_text())
    for c in rig["cameras"]:
        c["width"], c["height"] = w, h
    (d / "rig.json").write_text(json.dumps(rig))


@pytest.mark.parametrize("per_camera, field", [(False, "image_size.width"), (True, "camera_sizes.CAM_FRONT")])
def test_a_manifest_claiming_30000_px_is_refused_naming_the_field(tiny_dataset, tmp_path, capsys, per_camera, field):
    from study.cli import main as mcdp_main
    from synth.cli import main as synth_main
    from synth.files import DatasetError
    from synth.open import open_dataset

    d = _copy(tiny_dataset, tmp_path)
    _claim_size(d, BIG, BIG, per_camera)
    with pytest.raises(DatasetError, match=rf"{field}.*\[1, 4096\]"):  # the config's bound
        open_dataset(d)
    capsys.readouterr()
    assert synth_main(["verify", str(d)]) == 1
    err = capsys.readouterr().err
    assert field in err and "Traceback" not in err and len(err.splitlines()) <= 2, err
    # mcdp eval refuses in one line (it went past 3 GB before): the dataset is opened before any run is read
    assert mcdp_main(["eval", str(tmp_path / "norun"), "--data", str(d), "--out", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert field in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "m.json").exists()


def test_the_manifest_bound_is_the_configs(tiny_dataset, tmp_path):
    """The largest side the config accepts is accepted in a manifest too (one bound)."""
    from synth.dataset import check_manifest_keys
    from synth.rig import MAX_CAMERA_PX, CameraConfig

    assert CameraConfig.model_fields["width"].metadata[-1].le == MAX_CAMERA_PX
    m = json.loads((tiny_dataset / "manifest.json").read_text())
    m["image_size"] = {"width": MAX_CAMERA_PX, "height": MAX_CAMERA_PX}
    check_manifest_keys(m, tmp_path / "manifest.json")


def _png_claiming(w: int, h: int) -> bytes:
    """A small, well-formed PNG header (IHDR with its CRC) claiming w x h gray pixels, and a little data."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return len(body).to_bytes(4, "big") + kind + body + zlib.crc32(kind + body).to_bytes(4, "big")

    ihdr = w.to_bytes(4, "big") + h.to_bytes(4, "big") + bytes([8, 0, 0, 0, 0])
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 4096))
            + chunk(b"IEND", b""))


@pytest.mark.parametrize("gray", [False, True])
def test_a_png_whose_header_claims_more_than_the_bound_is_refused_before_decoding(tmp_path, monkeypatch, gray):
    from synth import files

    p = tmp_path / "big.png"
    p.write_bytes(_png_claiming(5000, 5000))
    monkeypatch.setattr(files.cv2, "imdecode", lambda *a: pytest.fail("decoded"))
    with pytest.raises(files.DatasetError, match=r"big\.png: its header claims 5000x5000 pixels"):
        files.read_png(p, gray=gray)
    with pytest.raises(files.DatasetError, match=r"big\.png: its header claims 5000x5000 pixels"):
        files.read_image(p)


def test_an_exr_whose_header_claims_more_than_the_bound_is_refused_before_its_pixels_are_read(tmp_path):
    import OpenEXR

    from synth import files

    p = tmp_path / "big.depth.exr"
    files.write_depth_exr(p, np.ones((8, 8), np.float32))
    with OpenEXR.File(str(p), header_only=True) as f:  # the same pixels, claimed over a larger window
        hdr = f.header()
    hdr["dataWindow"] = (np.array([0, 0], np.int32), np.array([4999, 7], np.int32))
    with OpenEXR.File(hdr, {"Z": np.zeros((8, 5000), np.float32)}) as f:
        f.write(str(p))
    with pytest.raises(files.DatasetError, match=r"big\.depth\.exr: its header claims 5000x8 pixels"):
        files.read_depth_exr(p)


def test_a_dataset_png_claiming_a_huge_size_is_one_error_naming_it(tiny_dataset, tmp_path):
    from synth.files import DatasetError
    from synth.open import open_dataset

    d = _copy(tiny_dataset, tmp_path)
    ds = open_dataset(d)
    seq = ds.split("test")[0]
    p = ds.rgb_path(seq, "CAM_FRONT", 0)
    p.write_bytes(_png_claiming(BIG, BIG))
    with pytest.raises(DatasetError) as e:
        ds.read_rgb(seq, "CAM_FRONT", 0)
    assert str(p) in str(e.value) and f"{BIG}x{BIG}" in str(e.value), e.value


# --------------------------------------------------------------------------- 6: synth verify
@pytest.mark.parametrize("name", ["manifest.json", "rig.json"])
def test_verify_refuses_a_manifest_or_rig_linked_out_of_the_dataset(tiny_dataset, tmp_path, capsys, name):
    from synth.cli import main as synth_main

    d = _copy(tiny_dataset, tmp_path / "in")
    outside = tmp_path / f"outside_{name}"
    shutil.move(str(d / name), outside)  # the same, valid file, outside the root
    (d / name).symlink_to(outside)
    capsys.readouterr()
    assert synth_main(["verify", str(d)]) == 1
    out = capsys.readouterr()
    assert f"{d / name}: is a link to {outside}" in out.err, out.err
    assert not out.out.startswith("OK"), out.out


def test_verify_refuses_a_file_over_the_read_bound_by_its_size_without_hashing_it(tiny_dataset, tmp_path, capsys,
                                                                                  monkeypatch):
    from synth import dataset
    from synth.cli import main as synth_main
    from synth.files import MAX_READ_BYTES

    d = _copy(tiny_dataset, tmp_path)
    seq = json.loads((d / "manifest.json").read_text())["splits"]["test"][0]
    big = d / seq / "CAM_BACK" / "000001.png"
    big.unlink()
    with open(big, "wb") as f:  # sparse: no disk
        f.truncate(3 * 2**30)
    hashed = []
    import synth.verify

    real = synth.verify.sha256_file
    monkeypatch.setattr(synth.verify, "sha256_file", lambda p: hashed.append(Path(p)) or real(p))
    capsys.readouterr()
    assert synth_main(["verify", str(d)]) == 1
    err = capsys.readouterr().err
    assert f"{big}: {3 * 2**30} bytes, more than any dataset file may hold ({MAX_READ_BYTES} bytes)" in err, err
    assert big not in hashed and len(hashed) > 10
