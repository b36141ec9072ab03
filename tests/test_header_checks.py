"""Every image header checked before its pixels are decoded (issue 49, items 2, 3 and 8): an EXR's size against its
camera's and its channel list against the contract's, a JPEG's frame header against the pixel bound of PNG and EXR,
a 16-bit PNG where 8 bits are the contract, and a truncated EXR refused in one line with OpenEXR kept quiet."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest


@pytest.fixture
def no_decoding(monkeypatch):
    """OpenEXR.File may read headers only (or write a file, from a header dict): opening a file to decode its
    pixels fails the test."""
    import OpenEXR

    real = OpenEXR.File

    def header_only(*args, **kwargs):
        if not isinstance(args[0], dict) and not kwargs.get("header_only"):
            pytest.fail("the EXR's pixels were decoded")
        return real(*args, **kwargs)

    monkeypatch.setattr(OpenEXR, "File", header_only)


def _exr(path, channels: dict[str, np.ndarray]) -> None:
    from synth.files import _encode_exr

    path.write_bytes(_encode_exr(channels))


# --------------------------------------------------------------------------- item 2: EXR channels and size
def test_a_flow_exr_with_a_channel_beyond_u_and_v_is_refused_before_decoding(tmp_path, no_decoding):
    from synth.files import DatasetError, read_flow_exr

    p = tmp_path / "f.flow.exr"
    z = np.zeros((6, 8), np.float32)
    _exr(p, {"U": z, "V": z, **{f"X{k}": z for k in range(10)}})  # 12 channels: a small file, much once decoded
    with pytest.raises(DatasetError) as e:
        read_flow_exr(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: has channel(s) 'U', 'V', 'X0'") and "and 4 more" in msg, msg
    assert "a flow map has exactly 'U', 'V'; refused before decoding" in msg and len(msg.splitlines()) == 1


def test_a_depth_exr_without_its_z_channel_is_refused_before_decoding(tmp_path, no_decoding):
    from synth.files import DatasetError, read_depth_exr

    p = tmp_path / "d.depth.exr"
    _exr(p, {"Y": np.ones((6, 8), np.float32)})
    with pytest.raises(DatasetError, match=r"has channel\(s\) 'Y'; a depth map has exactly 'Z'; refused before"):
        read_depth_exr(p)


def test_an_exr_of_another_size_than_the_cameras_is_refused_before_decoding(tmp_path, no_decoding):
    from synth.files import DatasetError, read_depth_exr, read_flow_exr

    d, f = tmp_path / "d.depth.exr", tmp_path / "f.flow.exr"
    _exr(d, {"Z": np.ones((6, 8), np.float32)})
    _exr(f, {"U": np.ones((6, 8), np.float32), "V": np.ones((6, 8), np.float32)})
    for read, p in ((read_depth_exr, d), (read_flow_exr, f)):
        with pytest.raises(DatasetError) as e:
            read(p, (16, 12))
        assert str(e.value) == (f"{p}: its header claims 8x6 pixels, the camera's images are 16x12; refused before "
                                "decoding"), e.value


def test_the_exr_readers_return_the_pixels_at_the_cameras_size(tmp_path):
    from synth.files import read_depth_exr, read_flow_exr, write_depth_exr, write_flow_exr

    depth = np.arange(48, dtype=np.float32).reshape(6, 8)
    flow = np.stack([depth, -depth], -1)
    write_depth_exr(tmp_path / "d.exr", depth)
    write_flow_exr(tmp_path / "f.exr", flow)
    assert np.array_equal(read_depth_exr(tmp_path / "d.exr", (8, 6)), depth)
    assert np.array_equal(read_flow_exr(tmp_path / "f.exr", (8, 6)), flow)


def test_a_dataset_depth_map_of_another_size_is_refused_before_decoding(tiny_dataset, tmp_path, request):
    from synth.files import DatasetError
    from synth.open import open_dataset

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    ds = open_dataset(d)
    seq = ds.split("test")[0]
    w, h = ds._size("CAM_FRONT")
    p = ds.depth_path(seq, "CAM_FRONT", 0)
    _exr(p, {"Z": np.ones((h + 1, w), np.float32)})
    request.getfixturevalue("no_decoding")
    with pytest.raises(DatasetError) as e:
        ds.read_depth(seq, "CAM_FRONT", 0)
    assert str(e.value) == (f"{p}: its header claims {w}x{h + 1} pixels, the camera's images are {w}x{h}; refused "
                            "before decoding"), e.value


# --------------------------------------------------------------------------- item 8: a truncated EXR, quietly
def test_a_truncated_exr_is_one_line_and_openexr_prints_nothing(tmp_path, capfd):
    from synth.files import DatasetError, read_depth_exr, write_depth_exr

    p = tmp_path / "t.depth.exr"
    write_depth_exr(p, np.random.default_rng(0).random((64, 64), np.float32))
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    capfd.readouterr()
    with pytest.raises(DatasetError) as e:
        read_depth_exr(p)
    assert str(e.value).startswith(f"{p}: not a readable EXR depth map, truncated or corrupt ("), e.value
    assert capfd.readouterr().err == ""  # before: 'Warning: Exception raised reading pixel data ...' and 2 more


def test_what_is_written_to_stderr_while_an_exr_decodes_well_still_reaches_it(capfd):
    import os

    from synth.files import _quiet_fd2

    capfd.readouterr()
    with _quiet_fd2():
        os.write(2, b"kept\n")
    with pytest.raises(ZeroDivisionError), _quiet_fd2():
        os.write(2, b"dropped\n")
        1 / 0
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "kept\nafter\n"


# --------------------------------------------------------------------------- item 3: a JPEG's frame header
def _jpeg_claiming(w: int, h: int) -> bytes:
    """A real 16x8 JPEG whose frame header (SOF0) is edited to claim w x h pixels."""
    ok, buf = cv2.imencode(".jpg", np.full((8, 16, 3), 128, np.uint8))
    data = bytearray(buf.tobytes())
    i = data.index(b"\xff\xc0")
    assert data[i + 5:i + 9] == (8).to_bytes(2, "big") + (16).to_bytes(2, "big")
    data[i + 5:i + 9] = h.to_bytes(2, "big") + w.to_bytes(2, "big")
    return bytes(data)


def test_a_jpeg_claiming_32000_px_is_refused_before_decoding(tmp_path, monkeypatch):
    from synth import files

    p = tmp_path / "big.jpg"
    p.write_bytes(_jpeg_claiming(32000, 32000))
    assert len(p.read_bytes()) < 4000
    monkeypatch.setattr(files.cv2, "imdecode", lambda *a: pytest.fail("decoded"))
    with pytest.raises(files.DatasetError) as e:
        files.read_image(p)
    assert str(e.value) == (f"{p}: its header claims 32000x32000 pixels, above the {files.MAX_CAMERA_PX} px a "
                            "camera's side may have; refused before decoding"), e.value


@pytest.mark.parametrize("w,h", [(0, 8), (16, 0)])
def test_a_jpeg_of_no_size_is_refused_before_decoding(tmp_path, monkeypatch, w, h):
    from synth import files

    p = tmp_path / "zero.jpg"
    p.write_bytes(_jpeg_claiming(w, h))
    monkeypatch.setattr(files.cv2, "imdecode", lambda *a: pytest.fail("decoded"))
    with pytest.raises(files.DatasetError, match=rf"claims {w}x{h} pixels \(a size given later in the file\)"):
        files.read_image(p)


def test_a_jpeg_with_no_frame_header_is_refused(tmp_path):
    from synth import files

    p = tmp_path / "nosof.jpg"
    p.write_bytes(b"\xff\xd8\xff\xe0\x00\x04ab\xff\xda\x00\x02" + b"\0" * 64)
    with pytest.raises(files.DatasetError, match=r"nosof\.jpg: not a readable JPEG \(no frame header"):
        files.read_image(p)


def test_a_jpeg_within_the_bound_is_read_at_its_size(tmp_path):
    from synth import files

    p = tmp_path / "ok.jpg"
    p.write_bytes(_jpeg_claiming(16, 8))
    img = files.read_image(p)
    assert img.shape == (8, 16, 3) and abs(int(img.mean()) - 128) <= 2


def test_a_dataroot_jpeg_claiming_32000_px_is_one_error_naming_it(ns_root, tmp_path, monkeypatch):
    from synth import files
    from synth.nuscenes.read import open_nuscenes

    root = tmp_path / "ns"
    shutil.copytree(ns_root, root, symlinks=True)
    ds = open_nuscenes(root)
    seq = ds.sequences[0]
    p = ds.rgb_path(seq, "CAM_FRONT", 0)
    assert p.suffix == ".jpg"
    p.write_bytes(_jpeg_claiming(32000, 32000))
    monkeypatch.setattr(files.cv2, "imdecode", lambda *a: pytest.fail("decoded"))
    with pytest.raises(files.DatasetError) as e:
        open_nuscenes(root).read_rgb(seq, "CAM_FRONT", 0)
    assert str(p) in str(e.value) and "32000x32000" in str(e.value) and len(str(e.value).splitlines()) == 1


# --------------------------------------------------------------------------- item 8: a 16-bit semantic map
def test_a_16_bit_semantic_png_is_refused_not_narrowed(tiny_dataset, tmp_path):
    from synth.files import DatasetError, write_png
    from synth.open import open_dataset

    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    ds = open_dataset(d)
    seq = ds.split("test")[0]
    assert "semantic" in ds.label_kinds
    sem = ds.read_semantic(seq, "CAM_FRONT", 0)
    p = d / seq / "CAM_FRONT" / "000000.semantic.png"
    write_png(p, sem.astype(np.uint16) + 256)  # every index + 256: 8 bits would keep the high byte, 1
    with pytest.raises(DatasetError) as e:
        ds.read_semantic(seq, "CAM_FRONT", 0)
    assert str(e.value) == f"{p}: is a 16-bit PNG; the contract is an 8-bit gray PNG"
    assert json.loads((d / "manifest.json").read_text())["labels"]["kinds"][0] == "semantic"
