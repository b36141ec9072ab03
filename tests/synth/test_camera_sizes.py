"""A camera of its own image size (issue 30, item 3: ``rig.cameras.<CAM>.width`` / ``.height``): rendered at
that size (a framebuffer of its own), recorded in rig.json and the manifest's ``camera_sizes``, checked by
the reader and by `verify`, and read right by training, evaluation, prediction, preview, info and the
nuScenes export. Two tiny renders (2 sequences x 3 frames at 64x48): one plain, one whose CAM_BACK is
96x64 with a 110-degree lens."""
from __future__ import annotations

import json
import math
import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from corelib.configlib import ConfigError
from synth.config import load_data_config
from synth.verify import verify_dataset
from synth.files import DatasetError, read_json, stored_size, write_png
from synth.open import open_dataset
from synth.rig import intrinsics_from_hfov

QUIET = dict(progress=False, log=lambda *a: None)
BASE = ["camera.width=64", "camera.height=48", "dataset.sequences=2", "dataset.frames=3",
        "dataset.val_fraction=0.0", "dataset.test_fraction=0.5"]
BACK = ["rig.cameras.CAM_BACK.width=96", "rig.cameras.CAM_BACK.height=64", "rig.cameras.CAM_BACK.hfov_deg=110.0"]
OTHERS = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """{"plain": path, "mixed": path} of the two renders."""
    from synth.render import render_dataset

    out = {}
    for name, extra in (("plain", []), ("mixed", BACK)):
        out[name] = tmp_path_factory.mktemp(name) / "data"
        render_dataset(load_data_config("configs/data/tiny.yaml", BASE + extra), out[name], **QUIET)
    return out


def test_a_camera_of_its_own_size_renders_verifies_and_is_recorded(renders):
    root = renders["mixed"]
    assert verify_dataset(root) == []
    man = read_json(root / "manifest.json")
    assert man["schema_version"] == 1 and man["image_size"] == {"width": 64, "height": 48}
    assert man["camera_sizes"] == {n: ([96, 64] if n == "CAM_BACK" else [64, 48]) for n in man["cameras"]}
    assert "camera_sizes" not in read_json(renders["plain"] / "manifest.json")  # one size: as before
    rig = {c["name"]: c for c in read_json(root / "rig.json")["cameras"]}
    assert (rig["CAM_BACK"]["width"], rig["CAM_BACK"]["height"]) == (96, 64)
    assert np.allclose(rig["CAM_BACK"]["K"], intrinsics_from_hfov(96, 64, 110.0))  # its own size and hfov
    assert rig["CAM_BACK"]["K"][0][2] == 48.0 and rig["CAM_BACK"]["K"][1][2] == 32.0
    ds = open_dataset(root, verify=True)
    seq = ds.sequences[0]
    for cam in ds.cameras:
        w, h = (96, 64) if cam.name == "CAM_BACK" else (64, 48)
        assert (cam.width, cam.height) == (w, h)
        for f in range(ds.n_frames(seq)):
            assert stored_size(ds.rgb_path(seq, cam.name, f)) == (w, h) == stored_size(ds.depth_path(seq, cam.name, f))
        assert stored_size(root / "masks" / f"{cam.name}.png") == (w, h)
        assert ds.read_rgb(seq, cam.name, 0).shape == (h, w, 3) and ds.read_depth(seq, cam.name, 0).shape == (h, w)
        assert ds.mask(cam.name).shape == (h, w)
    with pytest.raises(DatasetError, match=r"different image sizes \(64x48, CAM_BACK 96x64\)"):
        ds.width  # noqa: B018 - no dataset-wide size: the consumer reads each camera's
    assert open_dataset(renders["plain"]).width == 64


def test_the_other_cameras_render_exactly_as_without_it(renders):
    """CAM_BACK's own framebuffer changes no byte of the other cameras (nor their masks)."""
    plain, mixed = (read_json(renders[k] / "manifest.json")["files"] for k in ("plain", "mixed"))
    others = [k for k in plain if any(f"/{c}" in f"/{k}" for c in OTHERS)]
    assert len(others) == 5 + 2 * 3 * 5 * 4  # masks + 2 sequences x 3 frames x 5 cameras x (png, exr, semantic, instance)
    assert {k: mixed[k] for k in others} == {k: plain[k] for k in others}
    assert all(mixed[k] != plain[k] for k in plain if "CAM_BACK/" in k or k.endswith("/CAM_BACK.png"))


def test_a_wider_cam_back_sees_more_of_its_neighbours(renders):
    plain, mixed = (read_json(renders[k] / "manifest.json")["overlap"]["per_pair_measured"] for k in ("plain", "mixed"))
    for pair, into_back in (("CAM_BACK_RIGHT-CAM_BACK", "CAM_BACK_RIGHT->CAM_BACK"),
                            ("CAM_BACK-CAM_BACK_LEFT", "CAM_BACK_LEFT->CAM_BACK")):
        assert mixed[pair]["measured"] > plain[pair]["measured"] + 0.05
        assert mixed[pair][into_back] > plain[pair][into_back] + 0.1  # the neighbour's pixels CAM_BACK sees
    assert mixed["CAM_FRONT-CAM_FRONT_RIGHT"] == plain["CAM_FRONT-CAM_FRONT_RIGHT"]


def test_a_file_or_record_of_another_size_is_refused_naming_the_camera(renders, tmp_path):
    from synth.sizes import size_problems

    root = tmp_path / "copy"
    shutil.copytree(renders["mixed"], root)
    write_png(root / "masks" / "CAM_BACK.png", np.full((48, 64), 255, np.uint8))
    with pytest.raises(DatasetError, match=r"CAM_BACK.png: the mask is 64x48, CAM_BACK's images are 96x64"):
        open_dataset(root).mask("CAM_BACK")
    assert size_problems(root / "masks" / "CAM_BACK.png", "masks/CAM_BACK.png", {"CAM_BACK": (96, 64)}) == [
        f"{root / 'masks' / 'CAM_BACK.png'}: is 64x48, the manifest gives CAM_BACK 96x64"]
    assert any("CAM_BACK.png: checksum mismatch" in p for p in verify_dataset(root))
    man = read_json(root / "manifest.json")
    for edit, said in ((lambda m: m["camera_sizes"].update(CAM_BACK=[64, 48]), r"cameras\[CAM_BACK\].width is 96, "
                        r"the manifest's camera_sizes.CAM_BACK gives 64"),
                       (lambda m: m.pop("camera_sizes"), r"cameras\[CAM_BACK\].width is 96, the manifest's "
                        r"image_size.width gives 64"),
                       (lambda m: m["camera_sizes"].pop("CAM_FRONT"), "camera_sizes must give"),
                       (lambda m: m["camera_sizes"].update(CAM_BACK=[96, 0]), r"camera_sizes.CAM_BACK must be")):
        m = json.loads(json.dumps(man))
        edit(m)
        (root / "manifest.json").write_text(json.dumps(m))
        with pytest.raises(DatasetError, match=said):
            open_dataset(root)


def test_an_out_of_range_size_is_one_line_naming_the_key():
    with pytest.raises(ConfigError) as err:
        load_data_config("configs/data/tiny.yaml", ["rig.cameras.CAM_BACK.width=8"])
    problems = str(err.value).splitlines()[1:]
    assert len(problems) == 1 and problems[0].strip().startswith("rig.cameras.CAM_BACK.width:"), problems
    with pytest.raises(ConfigError, match=r"rig.cameras.CAM_BACK.height: .*less than or equal to 4096"):
        load_data_config("configs/data/tiny.yaml", ["rig.cameras.CAM_BACK.height=5000"])


def test_training_evaluation_prediction_and_preview_read_each_camera_at_its_size(renders, tmp_path):
    import torch

    from mcdp import evaluate as E
    from mcdp.priors import constant_depth_predictor
    from mcdp.data import RigDataset, scaled_K
    from mcdp.predict import Predictor
    from mcdp.visual import depth_grid
    from synth.info import dataset_info, format_info
    from synth.preview import make_preview

    ds = open_dataset(renders["mixed"])
    back = ds.camera_names.index("CAM_BACK")
    item = RigDataset(ds, "train", 32, 48)[0]  # training size 48x32 for every camera
    assert item["rgb"].shape == (6, 3, 3, 32, 48) and item["mask"].shape == (6, 1, 32, 48)
    for c, cam in enumerate(ds.cameras):
        assert np.allclose(item["K"][c].numpy(), scaled_K(cam.K, (cam.height, cam.width), (32, 48)), atol=1e-5)
    assert item["K"][back][0, 0] == pytest.approx(0.5 * 48 / math.tan(math.radians(55)), rel=1e-6)
    m = E.evaluate(ds, constant_depth_predictor(ds, 10.0), "test", progress=False)
    per = m["stages"]["final"]["none"]["per_camera"]
    assert set(per) == set(ds.camera_names) and all(math.isfinite(v["abs_rel"]) for v in per.values())
    small = {"init": torch.full((6, 1, 8, 12), 5.0)}
    up = Predictor.upsample(SimpleNamespace(ds=ds), small)["init"]  # each camera's dataset size: a list
    assert [a.shape for a in up] == [(64, 96) if n == "CAM_BACK" else (48, 64) for n in ds.camera_names]
    rgbs = [ds.read_rgb(ds.sequences[0], n, 0) for n in ds.camera_names]
    assert depth_grid(rgbs, {"init": up}).shape == (2 * 64, 5 * 64 + 96, 3)
    sheet = make_preview(ds, tmp_path / "sheet.png")
    from synth.preview import key_row
    from synth.preview_labels import legend

    # 4 tiles + the class map per camera (default labels: no flow; the widest row: CAM_BACK's), the legend and the
    # depth colour bar below
    assert stored_size(sheet) == (5 * 96, 5 * 48 + 64 + legend(ds.classes, 5 * 96).shape[0]
                                  + key_row(5 * 96, flow=False).shape[0])
    assert "64x48, CAM_BACK 96x64" in format_info(dataset_info(renders["mixed"]))


def test_the_nuscenes_export_writes_and_reads_back_each_channels_size(renders, tmp_path):
    from synth.nuscenes.export import export_nuscenes
    from synth.nuscenes.read import open_nuscenes

    out = tmp_path / "ns"
    export_nuscenes(open_dataset(renders["mixed"]), out, lidar=None)
    ns = open_nuscenes(out)
    assert {c.name: (c.width, c.height) for c in ns.cameras} == {
        c.name: (c.width, c.height) for c in open_dataset(renders["mixed"]).cameras}
    seq = ns.sequences[0]
    assert ns.read_rgb(seq, "CAM_BACK", 0).shape == (64, 96, 3) and ns.mask("CAM_BACK").shape == (64, 96)
    assert ns.manifest["camera_sizes"]["CAM_BACK"] == [96, 64]
    with pytest.raises(DatasetError, match="CAM_BACK 96x64"):
        ns.width  # noqa: B018
