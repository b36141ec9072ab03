"""``sensor.jpeg_quality`` (issue 48, item 2): the RGB images written as JPEG, as nuScenes ships them; the reader,
`synth verify`, the trainer's loader, the preview and the nuScenes export follow the manifest's ``rgb`` record."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from corelib.configlib import ConfigError, config_hash, load_config
from synth.files import DatasetError, JPEG_SIGNATURE, stored_size

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
TINY_HASH = "4c93be54b2f0ddb35c56d70e7fd2b087d4a0e648eeb11eb99ebc6a5727a1c9d8"  # tests/synth/test_sensor.py
NOISE_HASH = "47dda5cee27a18cd5a964a225ae874980dc3b520ed915afa9f2ef71364a79e3d"  # sensor.noise=0.01 before the key
JPEG = ["sensor.jpeg_quality=90"]


def _tiny(overrides=()):
    from synth.config import DataConfig

    return load_config(DataConfig, TINY, list(overrides))


def _rgb_keys(files: dict, suffix: str) -> set[str]:
    return {k for k in files if k.startswith("seq_") and k.endswith(suffix) and k.count(".") == 1}


@pytest.fixture(scope="module")
def jpeg_dataset(tmp_path_factory):
    from synth.render import render_dataset

    out = tmp_path_factory.mktemp("jpeg") / "data"
    render_dataset(_tiny(JPEG), out, workers=1, progress=False, log=lambda *a: None)
    return out


def test_jpeg_quality_is_bounded_and_unset_keeps_every_hash():
    assert config_hash(_tiny()) == TINY_HASH != config_hash(_tiny(JPEG))
    assert config_hash(_tiny(["sensor.noise=0.01"])) == NOISE_HASH  # a sensor section set before the key: same hash
    assert _tiny(JPEG).sensor.is_identity()  # the format alone leaves the pixels to the renderer
    for bad in ("0", "101", "9.5", "true"):
        with pytest.raises(ConfigError, match=r"sensor.jpeg_quality"):
            _tiny([f"sensor.jpeg_quality={bad}"])


def test_only_the_rgb_files_change_to_smaller_jpegs_and_the_dataset_verifies(jpeg_dataset, tiny_dataset):
    from synth.verify import verify_dataset

    m = json.loads((jpeg_dataset / "manifest.json").read_text())
    ideal = json.loads((tiny_dataset / "manifest.json").read_text())
    assert m["rgb"] == {"format": "jpeg", "quality": 90, "file": "<seq>/<CAM>/<frame>.jpg"} and "rgb" not in ideal
    files, png = m["files"], ideal["files"]
    jpg = _rgb_keys(files, ".jpg")
    assert len(jpg) == 3 * 6 * 6 and {k[:-4] for k in jpg} == {k[:-4] for k in _rgb_keys(png, ".png")}
    others = set(files) - jpg
    assert others == set(png) - _rgb_keys(png, ".png") and len(others) > len(jpg)
    assert all(files[k] == png[k] for k in others)  # depth, labels, masks, rig.json, ego.json: byte-identical
    assert all((jpeg_dataset / k).read_bytes().startswith(JPEG_SIGNATURE) for k in jpg)
    jpg_bytes = sum((jpeg_dataset / k).stat().st_size for k in jpg)
    png_bytes = sum((tiny_dataset / k).stat().st_size for k in _rgb_keys(png, ".png"))
    assert jpg_bytes < 0.7 * png_bytes  # 96x64 tiny: about 0.45
    assert stored_size(jpeg_dataset / sorted(jpg)[0]) == (96, 64)
    assert verify_dataset(jpeg_dataset) == []


def test_the_reader_and_the_trainers_loader_return_images_close_to_the_png_render(jpeg_dataset, tiny_dataset):
    from mcdp.data import RigDataset
    from synth.open import open_dataset

    a, b = open_dataset(tiny_dataset), open_dataset(jpeg_dataset, verify=True)
    seq = b.sequences[0]
    assert b.rgb_path(seq, "CAM_FRONT", 0).name == "000000.jpg" and a.rgb_path(seq, "CAM_FRONT", 0).suffix == ".png"
    se = [((a.read_rgb(seq, c, f).astype(float) - b.read_rgb(seq, c, f).astype(float)) ** 2).mean()
          for c in b.camera_names for f in range(b.n_frames(seq))]
    psnr = 10 * np.log10(255.0 ** 2 / np.mean(se))
    assert 30.0 < psnr < 60.0  # quality 90 at 96x64: about 34.6 dB; lossy, so never identical
    assert np.array_equal(a.read_depth(seq, "CAM_BACK", 2), b.read_depth(seq, "CAM_BACK", 2))
    item = RigDataset(b, "train", height=32, width=48)[0]
    batch = RigDataset(a, "train", height=32, width=48)[0]
    assert item.keys() == batch.keys()


def test_verify_names_a_missing_jpeg_and_the_reader_refuses_an_unknown_format(jpeg_dataset, tmp_path):
    from synth.dataset import open_synth
    from synth.verify import verify_dataset

    copy = tmp_path / "data"
    shutil.copytree(jpeg_dataset, copy)
    (copy / "seq_00001" / "CAM_BACK" / "000003.jpg").unlink()
    assert verify_dataset(copy) == [f"{copy / 'seq_00001' / 'CAM_BACK' / '000003.jpg'}: missing"]
    m = json.loads((copy / "manifest.json").read_text())
    for rgb, field in (({"format": "webp"}, "rgb.format"), ({"format": ["jpeg"]}, "rgb.format"),
                       ({"format": "jpeg", "quality": 0}, "rgb.quality")):
        (copy / "manifest.json").write_text(json.dumps({**m, "rgb": rgb}))
        with pytest.raises(DatasetError, match=rf"manifest.json: {field} must be"):
            open_synth(copy)


def test_the_nuscenes_export_copies_the_jpegs_unless_told_a_quality(jpeg_dataset, tmp_path):
    from synth.nuscenes.export import export_nuscenes
    from synth.open import open_dataset

    export_nuscenes(open_dataset(jpeg_dataset), tmp_path / "ns", lidar=None, labels=False)
    marker = json.loads((tmp_path / "ns" / "mcdp_synth" / "export.json").read_text())
    assert (marker["jpeg"], marker["jpeg_quality"]) == ("copied", 90)
    copied = {p.read_bytes() for p in (tmp_path / "ns" / "samples").rglob("*.jpg")}
    assert copied == {p.read_bytes() for p in jpeg_dataset.glob("seq_*/*/*.jpg")}
    export_nuscenes(open_dataset(jpeg_dataset), tmp_path / "ns50", lidar=None, labels=False, jpeg_quality=50)
    marker = json.loads((tmp_path / "ns50" / "mcdp_synth" / "export.json").read_text())
    assert (marker["jpeg"], marker["jpeg_quality"]) == ("encoded", 50)
    assert not {p.read_bytes() for p in (tmp_path / "ns50" / "samples").rglob("*.jpg")} & copied


def test_the_preview_shows_the_images_as_written(jpeg_dataset, tmp_path):
    import cv2

    from synth.open import open_dataset
    from synth.preview import make_preview

    ds = open_dataset(jpeg_dataset)
    sheet = cv2.imread(str(make_preview(ds, tmp_path / "s.png")))[:, :, ::-1]
    rgb = ds.read_rgb(ds.sequences[0], "CAM_FRONT_RIGHT", 0)
    assert np.array_equal(sheet[64 + 30:2 * 64, :96], rgb[30:])  # row 2, first tile, below its caption


def test_the_jpeg_render_is_deterministic(jpeg_dataset, tmp_path):
    from corelib.configlib import config_to_dict
    from synth.render import render_sequence

    shutil.copytree(jpeg_dataset / "masks", tmp_path / "masks")
    rec = render_sequence(config_to_dict(_tiny(JPEG)), str(tmp_path), 2)
    files = json.loads((jpeg_dataset / "manifest.json").read_text())["files"]
    assert _rgb_keys(rec["files"], ".jpg") and all(files[k] == v for k, v in rec["files"].items())
