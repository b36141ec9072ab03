"""`synth.nuscenes.read`: our export read back through the devkit gives the source dataset's rig, poses,
splits and frames; its LiDAR depth agrees with the exact depth; metrics on the export equal the source's
metrics on the same LiDAR pixels; broken dataroots fail with one line naming the token / file / channel."""
from __future__ import annotations

import json
import math
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("nuscenes", reason="nuscenes-devkit not installed (pip install -e '.[nuscenes]')")

import mcdp.trainer  # noqa: F401,E402  torch before the in-process GL renderer (tests/conftest.py)
from study.method_commands import main  # noqa: E402
from mcdp.evaluate import EvalConfig, evaluate  # noqa: E402
from mcdp.predict import Predictor  # noqa: E402
from synth.open import open_dataset  # noqa: E402
from synth.files import DatasetError, read_png  # noqa: E402
from synth.nuscenes.dataset import NuScenesDataset  # noqa: E402
from synth.nuscenes.layout import NUSCENES_CAMERAS  # noqa: E402
from synth.nuscenes.read import NO_MASKS, open_nuscenes  # noqa: E402

VERSION = "v1.0-synth"
TINY_TRAIN = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny" / "mono2.yaml"
JPEG_MEAN_ABS = 4.0  # mean |JPEG - PNG| per channel (0..255) at quality 95 on the tiny images (measured ~1.9)


@pytest.fixture(scope="module")
def pair(ns_root, tiny_dataset):
    return open_nuscenes(ns_root), open_dataset(tiny_dataset)


@pytest.fixture(scope="module")
def run(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("nsrun") / "run"
    assert main(["train", str(TINY_TRAIN), "--data", str(tiny_dataset), "--out", str(out), "--no-progress",
                 "train.steps=2"]) == 0
    return out


def test_open_dataset_detects_the_dataroot(ns_root):
    ds = open_dataset(ns_root)
    assert isinstance(ds, NuScenesDataset) and ds.version == VERSION
    assert ds.ground_truth["kind"] == "lidar" and ds.has_depth
    with pytest.raises(DatasetError, match="no checksums"):
        open_dataset(ns_root, verify=True)


def test_rig_poses_splits_frames_match_the_source(pair):
    ns, src = pair
    assert ns.camera_names == src.camera_names == list(NUSCENES_CAMERAS)
    assert ns.neighbours == src.neighbours
    assert (ns.width, ns.height, ns.fps) == (src.width, src.height, src.fps)
    for a, b in zip(ns.cameras, src.cameras):
        assert (a.width, a.height) == (b.width, b.height)
        np.testing.assert_array_equal(a.K, b.K)  # camera_intrinsic = K exactly, pixel centres at +0.5
        np.testing.assert_allclose(a.T_ego_cam, b.T_ego_cam, rtol=0, atol=1e-6)
        assert abs(a.yaw_deg - b.yaw_deg) < 1e-6 and abs(a.hfov_deg - b.hfov_deg) < 1e-6
        np.testing.assert_array_equal(ns.mask(a.name), src.mask(b.name))
    for s in ("train", "val", "test"):
        assert ns.split(s) == src.split(s)
    assert ns.sequences == src.sequences
    for q in src.sequences:
        assert ns.n_frames(q) == src.n_frames(q)
        np.testing.assert_allclose(ns.T_world_ego(q), src.T_world_ego(q), rtol=0, atol=1e-6)
        assert [round(e["timestamp_s"], 6) for e in ns.ego(q)] == [round(e["timestamp_s"], 6) for e in src.ego(q)]
    q = src.sequences[0]
    for cam in src.camera_names:
        a, b = ns.read_rgb(q, cam, 1), src.read_rgb(q, cam, 1)
        assert a.shape == b.shape and a.dtype == np.uint8
        assert np.abs(a.astype(int) - b).mean() < JPEG_MEAN_ABS


def test_lidar_depth_agrees_with_the_exact_depth(pair):
    """docs/NUSCENES.md: pixel (floor(u), floor(v)) against the depth map: median < 2 %, >= 85 % within 5 %."""
    ns, src = pair
    rel, n = [], 0
    for q in src.sequences:
        for f in range(src.n_frames(q)):
            for cam in src.camera_names:
                d = ns.read_depth(q, cam, f)
                assert d.dtype == np.float32 and d.shape == (src.height, src.width)
                lid = d > 0
                n += lid.sum()
                assert d[lid].min() >= 0.1 and d[lid].max() <= 80.0
                g = src.read_depth(q, cam, f)
                v = lid & (g > 0) & src.mask(cam)
                rel.append(np.abs(d[v] - g[v]) / g[v])
    rel = np.concatenate(rel)
    assert rel.size > 0.9 * n > 100_000
    assert np.median(rel) < 0.02 and (rel < 0.05).mean() >= 0.85


def _same(a, b, path="") -> None:
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            _same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, float):
        assert (math.isnan(a) and math.isnan(b)) or abs(a - b) <= 1e-9, (path, a, b)
    else:
        assert a == b, path


class _SourceWithExportedInputs:
    """The source dataset, but its images are the exported JPEGs and its depth the reader's LiDAR depth."""

    def __init__(self, src, ns):
        self._src, self._ns = src, ns

    label_kinds = ()  # the reader of the export has no labels: compare the same regions

    def __getattr__(self, name):
        return getattr(self._src, name)

    def read_rgb(self, seq, cam, frame):
        return self._ns.read_rgb(seq, cam, frame)

    def read_depth(self, seq, cam, frame):
        return self._ns.read_depth(seq, cam, frame)


def test_metrics_on_the_export_equal_the_source_on_the_same_lidar_pixels(pair, run):
    """The issue's done-criterion. Same images (the exported JPEGs) and the same LiDAR depth, so what is
    compared is the reader's geometry: rig (K, T_ego_cam from quaternions), masks, splits, frame order."""
    ns, src = pair
    cfg = EvalConfig()
    m_ns = evaluate(ns, Predictor(run, ns, device="cpu").predict, "test", cfg, progress=False)
    wrapped = _SourceWithExportedInputs(src, ns)
    m_src = evaluate(wrapped, Predictor(run, wrapped, device="cpu").predict, "test", cfg, progress=False)
    assert m_ns["ground_truth"]["kind"] == "lidar" and m_ns["ground_truth"]["max_depth"] == 80.0
    assert m_src["ground_truth"]["kind"] == "dense z-depth (rendered)"  # the wrapper does not rename it
    m_src["ground_truth"] = m_ns["ground_truth"]
    _same(m_ns, m_src)
    # recorded, not asserted: dense (rendered PNG + exact depth) against LiDAR (JPEG + sparse depth)
    m_dense = evaluate(src, Predictor(run, src, device="cpu").predict, "test", cfg, progress=False)
    a, b = m_dense["stages"]["final"], m_ns["stages"]["final"]
    print("\n2-step mono2, test split, scaling median (dense -> lidar):",
          {k: (round(a["median"]["mean"][k], 4), round(b["median"]["mean"][k], 4)) for k in ("abs_rel", "rmse", "a1")},
          "dep_con", (round(a["dep_con"]["mean"], 4), round(b["dep_con"]["mean"], 4)))


def test_cli_eval_on_the_dataroot_records_lidar_ground_truth(ns_root, run, tmp_path, capsys):
    out = tmp_path / "m.json"
    assert main(["eval", str(run), "--data", str(ns_root), "--out", str(out), "--no-progress"]) == 0
    assert "ground truth: lidar" in capsys.readouterr().out
    m = json.loads(out.read_text())
    assert m["ground_truth"]["kind"] == "lidar" and m["ground_truth"]["min_depth"] == 0.1
    assert m["cameras"] == list(NUSCENES_CAMERAS) and m["n_samples"] == 4


def test_cli_trains_on_the_dataroot(ns_root, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", str(TINY_TRAIN), "--data", str(ns_root), "--out", str(run), "--no-progress",
                 "train.steps=1"]) == 0
    assert json.loads((run / "run.json").read_text())["data"] == str(ns_root.resolve())


# --------------------------------------------------------------------------- broken dataroots
def _copy(ns_root, tmp_path, keep_extras=True) -> Path:
    root = tmp_path / "broken"
    shutil.copytree(ns_root, root, ignore=None if keep_extras else shutil.ignore_patterns("mcdp_synth"))
    return root


def _edit(root, table, fn) -> None:
    p = root / VERSION / f"{table}.json"
    p.write_text(json.dumps(fn(json.loads(p.read_text()))))


def _cam_sd(root, channel="CAM_BACK_LEFT", k=3) -> dict:
    sensor = {s["token"]: s["channel"] for s in json.loads((root / VERSION / "sensor.json").read_text())}
    cs = {c["token"]: sensor[c["sensor_token"]] for c in json.loads((root / VERSION / "calibrated_sensor.json").read_text())}
    sds = [sd for sd in json.loads((root / VERSION / "sample_data.json").read_text())
           if cs[sd["calibrated_sensor_token"]] == channel]
    return sds[k]


def _cli_fails(root, run, capsys, tmp_path, *needles) -> None:
    rc = main(["eval", str(run), "--data", str(root), "--out", str(tmp_path / "m.json"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and "Traceback" not in err and len(err.strip().splitlines()) <= 3, err
    for n in needles:
        assert n in err, err


def test_missing_camera_channel(ns_root, tmp_path, run, capsys):
    root = _copy(ns_root, tmp_path)
    sd = _cam_sd(root)
    _edit(root, "sample_data", lambda t: [r for r in t if r["token"] != sd["token"]])
    with pytest.raises(DatasetError, match=f"sample {sd['sample_token']} .*has no key-frame CAM_BACK_LEFT"):
        open_nuscenes(root)
    _cli_fails(root, run, capsys, tmp_path, sd["sample_token"], "CAM_BACK_LEFT")


def test_missing_image_file(ns_root, tmp_path, run, capsys):
    root = _copy(ns_root, tmp_path)
    sd = _cam_sd(root, "CAM_FRONT", 5)
    (root / sd["filename"]).unlink()
    with pytest.raises(DatasetError, match=f"{sd['filename']}: image file is missing .*{sd['token']}"):
        open_nuscenes(root)
    _cli_fails(root, run, capsys, tmp_path, sd["filename"])


@pytest.mark.parametrize("field", ["ego_pose_token", "sample_token", "calibrated_sensor_token"])
def test_broken_token(ns_root, tmp_path, run, capsys, field):
    """ego_pose_token is first looked up by the reader; sample_token and calibrated_sensor_token make the
    devkit itself raise KeyError while indexing, which the reader names."""
    root = _copy(ns_root, tmp_path)
    sd = _cam_sd(root, "CAM_BACK", 2)
    bad = "0123456789abcdef0123456789abcdef"
    _edit(root, "sample_data", lambda t: [dict(r, **{field: bad}) if r["token"] == sd["token"] else r for r in t])
    with pytest.raises(DatasetError) as exc:
        open_nuscenes(root)
    msg = str(exc.value)
    assert sd["token"] in msg and bad in msg and field in msg, msg
    assert "\n" not in msg
    _cli_fails(root, run, capsys, tmp_path, sd["token"], bad)


def test_dataroot_without_our_extras_warns_once_and_masks_everything(ns_root, tmp_path, pair):
    root = _copy(ns_root, tmp_path, keep_extras=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = open_nuscenes(root)
    msgs = [str(w.message) for w in caught]
    assert len(msgs) == 1 and NO_MASKS in msgs[0] and str(root / "mcdp_synth" / "masks") in msgs[0], msgs
    for cam in ds.camera_names:
        m = ds.mask(cam)
        assert m.shape == (ds.height, ds.width) and m.all()
    # no export.json: nuScenes' integer pixel centres are assumed, so K moves by +0.5 (docs/NUSCENES.md)
    src = pair[1]
    assert ds.pixel_centre == "integer"
    np.testing.assert_array_equal(ds.cameras[0].K[:2, 2], src.cameras[0].K[:2, 2] + 0.5)
    # no splits.json and no official nuScenes scene: an empty split says what to write
    assert ds.fps == pytest.approx(10.0)
    with pytest.raises(DatasetError, match="splits.json"):
        ds.split("train")
    # a masks= folder is used when the dataroot has none
    folder = tmp_path / "masks"
    shutil.copytree(ns_root / "mcdp_synth" / "masks", folder)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ds = open_nuscenes(root, masks=folder)
    np.testing.assert_array_equal(ds.mask("CAM_BACK"), read_png(folder / "CAM_BACK.png", gray=True) > 127)


def test_ambiguous_version_is_refused(ns_root, tmp_path):
    root = _copy(ns_root, tmp_path)
    shutil.copytree(root / VERSION, root / "v1.0-other")
    if (root / "lidarseg" / VERSION).is_dir():  # the export's lidarseg labels, which the devkit loads per version
        shutil.copytree(root / "lidarseg" / VERSION, root / "lidarseg" / "v1.0-other")
    with pytest.raises(DatasetError, match="several nuScenes versions.*v1.0-other, v1.0-synth"):
        open_nuscenes(root)
    assert open_nuscenes(root, version="v1.0-other").version == "v1.0-other"


def test_without_the_devkit_the_plain_json_reader_gives_the_same_dataset(ns_root, pair, monkeypatch):
    """Beside the viz extra (numpy >= 2) the devkit cannot be installed: the plain-JSON tables, LiDAR
    reader, projection and quaternion give what the devkit gives."""
    ns, _ = pair
    for m in ("nuscenes", "nuscenes.nuscenes", "nuscenes.utils.data_classes", "nuscenes.utils.geometry_utils",
              "nuscenes.utils.splits", "pyquaternion"):
        monkeypatch.setitem(sys.modules, m, None)  # importing it raises ImportError
    plain = open_nuscenes(ns_root)
    assert plain.manifest == ns.manifest
    for a, b in zip(plain.cameras, ns.cameras):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_allclose(a.T_ego_cam, b.T_ego_cam, rtol=0, atol=1e-12)
    for q in ns.sequences:
        np.testing.assert_allclose(plain.T_world_ego(q), ns.T_world_ego(q), rtol=0, atol=1e-9)
        assert [e["sample_token"] for e in plain.ego(q)] == [e["sample_token"] for e in ns.ego(q)]
    q = ns.sequences[0]
    np.testing.assert_allclose(plain.lidar_points_world(q, 2), ns.lidar_points_world(q, 2), rtol=0, atol=1e-9)
    for cam in ns.camera_names:
        np.testing.assert_array_equal(plain.read_depth(q, cam, 2), ns.read_depth(q, cam, 2))


def test_an_image_out_of_the_dataroot_or_of_another_format_is_refused(ns_root, tmp_path, run, capsys):
    """Issue 20 (items 2 and 8) for a nuScenes dataroot: a camera file that is a symlink out of the root, or
    that a table names outside it, is never read; a PNG under a .jpg name is refused by its first bytes."""
    import cv2

    root = _copy(ns_root, tmp_path)
    ds = open_nuscenes(root)
    seq = ds.sequences[0]
    linked, renamed = ds.rgb_path(seq, "CAM_FRONT", 1), ds.rgb_path(seq, "CAM_FRONT", 2)
    outside = tmp_path / "secret.jpg"
    shutil.move(linked, outside)
    linked.symlink_to(outside)
    with pytest.raises(DatasetError, match=f"{linked}: resolves to {outside}, outside the dataroot"):
        ds.read_rgb(seq, "CAM_FRONT", 1)
    ok, png = cv2.imencode(".png", cv2.imread(str(renamed)))
    renamed.write_bytes(png.tobytes())
    with pytest.raises(DatasetError, match=f"{renamed}: not a readable JPEG"):
        ds.read_rgb(seq, "CAM_FRONT", 2)
    sd = _cam_sd(root, "CAM_FRONT", 0)  # a table naming a file outside the root: refused when it is opened
    shutil.copyfile(outside, tmp_path / "up.jpg")
    _edit(root, "sample_data", lambda t: [{**r, "filename": "../up.jpg"} if r["token"] == sd["token"] else r
                                          for r in t])
    _cli_fails(root, run, capsys, tmp_path, "../up.jpg: resolves to", "outside the dataroot")
