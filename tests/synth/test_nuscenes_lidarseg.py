"""The nuScenes export's labels (`synth.nuscenes.lidarseg`): lidarseg that the official devkit loads and draws, a
class per LiDAR point that agrees with the geometry and the camera it came from, the image labels as side files,
and a dataset without labels exported exactly as before."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("nuscenes", reason="nuscenes-devkit not installed (pip install -e '.[nuscenes]')")

from nuscenes.nuscenes import NuScenes  # noqa: E402
from nuscenes.utils.color_map import get_colormap  # noqa: E402
from nuscenes.utils.data_classes import LidarPointCloud  # noqa: E402
from pyquaternion import Quaternion  # noqa: E402

from corelib.hashing import sha256_file  # noqa: E402
from synth.lidar import LidarConfig, labelled_sweep, luma, simulate_sweep  # noqa: E402
from synth.nuscenes.export import export_nuscenes  # noqa: E402
from synth.nuscenes.lidarseg import NUSCENES_CLASSES, nuscenes_index  # noqa: E402
from synth.nuscenes.records import TABLES  # noqa: E402
from synth.open import open_dataset  # noqa: E402

VERSION = "v1.0-synth"


@pytest.fixture(scope="module")
def nusc(ns_root):
    return NuScenes(version=VERSION, dataroot=str(ns_root), verbose=False)


def _lidar_sd(nusc) -> list[dict]:
    return [sd for sd in nusc.sample_data if sd["filename"].startswith("samples/LIDAR_TOP/")]


def _ego_points(nusc, sd) -> np.ndarray:
    """(N, 3) the sweep's points in the ego frame, through the devkit's own reader and calibration."""
    pc = LidarPointCloud.from_file(str(Path(nusc.dataroot) / sd["filename"]))
    cs = nusc.get("calibrated_sensor", sd["calibrated_sensor_token"])
    pc.rotate(Quaternion(cs["rotation"]).rotation_matrix)
    pc.translate(np.array(cs["translation"]))
    return pc.points[:3].T


def test_category_table_is_nuscenes_lidarseg_and_every_class_maps():
    assert NUSCENES_CLASSES == tuple(get_colormap())  # the devkit's colour map, in index order
    idx = nuscenes_index([{"name": "road", "group": "road"}, {"name": "tram", "group": "vehicle"},
                          {"name": "bollard", "group": "unknown"}])
    assert [NUSCENES_CLASSES[i] for i in idx] == ["flat.driveable_surface", "vehicle.car", "static.other"]


def test_devkit_loads_lidarseg_with_one_label_per_point(nusc, ns_root, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    lidar = _lidar_sd(nusc)
    assert len(lidar) == 18 and len(nusc.lidarseg) == len(lidar)
    assert {c["index"]: c["name"] for c in nusc.category} == dict(enumerate(NUSCENES_CLASSES))
    for sd in lidar:
        rec = nusc.get("lidarseg", sd["token"])
        labels = np.fromfile(Path(ns_root) / rec["filename"], np.uint8)
        n = LidarPointCloud.from_file(str(Path(ns_root) / sd["filename"])).points.shape[1]
        assert len(labels) == n > 1000
        assert rec["filename"] == f"lidarseg/{VERSION}/{sd['token']}_lidarseg.bin"
    out = tmp_path / "lidarseg.png"
    nusc.render_sample_data(lidar[0]["token"], show_lidarseg=True, out_path=str(out), verbose=False)
    assert out.stat().st_size > 10_000
    import matplotlib.pyplot as plt

    plt.close("all")


def test_point_classes_agree_with_geometry_and_the_camera(nusc, ns_root, tiny_dataset):
    """Road points lie on z = 0 of the ego frame, vegetation and vehicles above it; our own class side file maps
    onto the lidarseg file; a point seen by a camera at its own depth has the class of that camera's pixel."""
    ds = open_dataset(tiny_dataset)
    exp = json.loads((Path(ns_root) / "mcdp_synth" / "export.json").read_text())
    to_ns = nuscenes_index(ds.classes)
    names = [c["name"] for c in ds.classes]
    z_of: dict[str, list] = {}
    agree = seen = 0
    for sd in _lidar_sd(nusc):
        e = exp["sample_data"][sd["token"]]
        ns = np.fromfile(Path(ns_root) / e["lidarseg"], np.uint8)
        ours = np.fromfile(Path(ns_root) / e["classes"], np.uint8)
        assert np.array_equal(to_ns[ours], ns)
        P = _ego_points(nusc, sd)
        for k in np.unique(ours):
            z_of.setdefault(names[k], []).append(P[ours == k, 2])
        for cam in ds.cameras:  # project into the camera; keep points at the depth map's depth there
            T = np.linalg.inv(np.asarray(cam.T_ego_cam))
            X = P @ T[:3, :3].T + T[:3, 3]
            uvw = X @ np.asarray(cam.K).T
            ok = X[:, 2] > 0.5
            u = np.floor(uvw[ok, 0] / uvw[ok, 2]).astype(int)
            v = np.floor(uvw[ok, 1] / uvw[ok, 2]).astype(int)
            inside = (u >= 1) & (u < cam.width - 1) & (v >= 1) & (v < cam.height - 1)
            u, v, z, cls = u[inside], v[inside], X[ok, 2][inside], ours[ok][inside]
            d = ds.read_depth(e["sequence"], cam.name, e["frame"])[v, u]
            near = np.abs(d - z) < 0.02 * z
            sem = ds.read_semantic(e["sequence"], cam.name, e["frame"])
            agree += int((sem[v, u][near] == cls[near]).sum())
            seen += int(near.sum())
    z = {k: np.concatenate(v) for k, v in z_of.items()}
    counts = {k: len(v) for k, v in z.items()}
    print("lidarseg points per class:", counts, f"camera agreement {agree / seen:.3f} of {seen}")
    assert {"road", "vegetation"} <= set(z) and "sky" not in z and "ego" not in z
    assert np.median(np.abs(z["road"])) < 0.02 and (np.abs(z["road"]) < 0.1).mean() > 0.99
    assert np.median(z["vegetation"]) > 1.0
    for veh in {"parked_vehicle", "moving_vehicle"} & set(z):
        assert 0.0 < np.median(z[veh]) < 2.5
    assert seen > 10_000 and agree / seen > 0.9


def test_image_labels_are_side_files(ns_root, tiny_dataset):
    root, ds = Path(ns_root), open_dataset(tiny_dataset)
    exp = json.loads((root / "mcdp_synth" / "export.json").read_text())
    assert exp["labels"]["classes"] == ds.classes and exp["labels"]["kinds"] == ["semantic", "instance"]
    assert sum(exp["labels"]["lidarseg_points"].values()) == sum(
        e["points"] for e in exp["sample_data"].values() if "points" in e)
    n = 0
    for e in exp["sample_data"].values():
        if "camera" not in e:
            continue
        stem = Path(e["depth"]).name.removesuffix(".depth.exr")
        assert e["semantic"] == f"mcdp_synth/labels/{e['channel']}/{stem}.semantic.png"
        for kind in ("semantic", "instance"):
            src = ds.root / e["sequence"] / e["camera"] / f"{e['frame']:06d}.{kind}.png"
            assert sha256_file(root / e[kind]) == sha256_file(src)
        n += 1
    assert n == 6 * 18
    for seq in ds.sequences:
        assert (root / "mcdp_synth" / "labels" / f"{seq}.instances.json").read_bytes() == \
            (ds.root / seq / "instances.json").read_bytes()


def test_a_dataset_without_labels_exports_as_before(ns_root, tiny_dataset, tiny_dataset_without_labels, tmp_path):
    """The same dataset without its labels record (as rendered before labels existed) or exported with
    labels=False: the 13 tables byte for byte those of the labelled export but an empty category, the same
    point clouds as each other (a coarse LiDAR, for time), no lidarseg and no label files."""
    src = tiny_dataset_without_labels
    assert open_dataset(src).label_kinds == ()
    outs = [tmp_path / "old_ns", tmp_path / "off_ns"]
    coarse = LidarConfig(azimuth_res_deg=2.0)
    s_old = export_nuscenes(open_dataset(src), outs[0], version=VERSION, lidar=coarse)
    s_off = export_nuscenes(open_dataset(tiny_dataset), outs[1], version=VERSION, lidar=coarse, labels=False)
    assert s_old["lidarseg"] == s_off["lidarseg"] == 0
    ref = Path(ns_root)
    for out in outs:
        assert sorted(p.name for p in (out / VERSION).iterdir()) == sorted(f"{t}.json" for t in TABLES)
        for t in TABLES:
            want = b"[]" if t == "category" else (ref / VERSION / f"{t}.json").read_bytes()
            assert (out / VERSION / f"{t}.json").read_bytes().strip() == want.strip(), t
        assert not (out / "lidarseg").exists() and not (out / "mcdp_synth" / "labels").exists()
        assert not (out / "mcdp_synth" / "lidarseg").exists()
        assert "labels" not in json.loads((out / "mcdp_synth" / "export.json").read_text())
    for p in sorted((outs[0] / "samples").rglob("*.*")):
        assert (outs[1] / p.relative_to(outs[0])).read_bytes() == p.read_bytes()


def test_a_labelled_sweep_has_the_points_of_a_sweep(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    seq, cams, cfg = ds.sequences[0], list(ds.cameras), LidarConfig(azimuth_res_deg=1.0)
    depths = {c.name: ds.read_depth(seq, c.name, 2) for c in cams}
    masks = {c.name: ds.mask(c.name) for c in cams}
    grays = {c.name: luma(ds.read_rgb(seq, c.name, 2)) for c in cams}
    pts, lab = labelled_sweep(cfg, cams, depths, masks, grays, {c.name: ds.read_semantic(seq, c.name, 2) for c in cams})
    assert pts.tobytes() == simulate_sweep(cfg, cams, depths, masks, grays).tobytes()
    assert lab.dtype == np.uint8 and lab.shape == (len(pts),) and len(pts) > 1000
    assert labelled_sweep(cfg, cams, depths, masks, grays)[1] is None
