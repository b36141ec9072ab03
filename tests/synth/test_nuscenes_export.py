"""`synth export --format nuscenes`: the official devkit loads the dataroot, conventions round-trip, and the
synthetic LIDAR_TOP agrees with the exact depth maps when projected with the devkit's own chain
(map_pointcloud_to_image: lidar -> ego -> global -> ego(cam time) -> camera, view_points)."""
from __future__ import annotations

import contextlib
import io
import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("nuscenes", reason="nuscenes-devkit not installed (pip install -e '.[nuscenes]')")

from nuscenes.nuscenes import NuScenes  # noqa: E402
from nuscenes.utils.data_classes import LidarPointCloud  # noqa: E402
from nuscenes.utils.geometry_utils import view_points  # noqa: E402
from pyquaternion import Quaternion  # noqa: E402

from corelib.hashing import sha256_file  # noqa: E402
from synth.open import open_dataset  # noqa: E402
from synth.files import read_depth_exr, read_png  # noqa: E402
from synth.lidar import LidarConfig  # noqa: E402
from synth.nuscenes.export import export_nuscenes  # noqa: E402
from synth.nuscenes.geometry import rotation_to_quaternion  # noqa: E402
from synth.nuscenes.layout import NUSCENES_CAMERAS, ExportError  # noqa: E402
from synth.nuscenes.records import TABLES  # noqa: E402

VERSION = "v1.0-synth"


def _load(root, version=VERSION):
    """NuScenes(...) with stdout and every Python warning captured."""
    buf = io.StringIO()
    with warnings.catch_warnings(record=True) as caught, contextlib.redirect_stdout(buf):
        warnings.simplefilter("always")
        nusc = NuScenes(version=version, dataroot=str(root), verbose=True)
        nusc.list_scenes()
    return nusc, buf.getvalue(), [str(w.message) for w in caught]


@pytest.fixture(scope="module")
def nusc(ns_root):
    return _load(ns_root)


def test_devkit_loads_without_warnings(nusc, tiny_dataset):
    ns, out, caught = nusc
    assert caught == []
    assert "warn" not in out.lower() and "error" not in out.lower(), out
    ds = open_dataset(tiny_dataset)
    n_frames = sum(ds.n_frames(s) for s in ds.sequences)
    assert len(ns.scene) == len(ds.sequences) and len(ns.sample) == n_frames
    assert len(ns.sample_data) == 7 * n_frames and len(ns.ego_pose) == 7 * n_frames
    for t in ("attribute", "visibility", "instance", "sample_annotation"):
        assert getattr(ns, t) == []
    assert [c["index"] for c in ns.category] == list(range(32))  # tiny has labels: lidarseg's categories


def test_channels_intrinsics_extrinsics(nusc, tiny_dataset):
    ns, _, _ = nusc
    rig = json.loads((Path(tiny_dataset) / "rig.json").read_text())
    cams = {c["name"]: c for c in rig["cameras"]}
    assert sorted(s["channel"] for s in ns.sensor) == sorted(NUSCENES_CAMERAS + ("LIDAR_TOP",))
    for s in ns.sample:
        assert sorted(s["data"]) == sorted(NUSCENES_CAMERAS + ("LIDAR_TOP",))
    for ch in NUSCENES_CAMERAS:  # our names are nuScenes' channels (yaw checked by channel_map)
        sd = ns.get("sample_data", ns.sample[0]["data"][ch])
        cs = ns.get("calibrated_sensor", sd["calibrated_sensor_token"])
        assert cs["camera_intrinsic"] == cams[ch]["K"]  # exactly, pixel centres at +0.5 (docs/NUSCENES.md)
        assert (sd["width"], sd["height"]) == (cams[ch]["width"], cams[ch]["height"])
        T = np.asarray(cams[ch]["T_ego_cam"])
        np.testing.assert_allclose(cs["translation"], T[:3, 3], atol=0)
        np.testing.assert_allclose(Quaternion(cs["rotation"]).rotation_matrix, T[:3, :3], atol=1e-12)
    lidar_sd = ns.get("sample_data", ns.sample[0]["data"]["LIDAR_TOP"])
    lidar = ns.get("calibrated_sensor", lidar_sd["calibrated_sensor_token"])
    R = Quaternion(lidar["rotation"]).rotation_matrix  # LIDAR_TOP: x right, y forward, z up
    np.testing.assert_allclose(R @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 1, 0], [1, 0, 0], atol=1e-12)
    assert lidar["camera_intrinsic"] == []


def test_prev_next_chains_and_timestamps(nusc, tiny_dataset):
    ns, _, _ = nusc
    ds = open_dataset(tiny_dataset)
    dt_us = 1e6 / ds.fps
    starts = []
    for scene in ns.scene:
        tokens, tok = [], scene["first_sample_token"]
        while tok:
            tokens.append(tok)
            tok = ns.get("sample", tok)["next"]
        assert len(tokens) == scene["nbr_samples"] == ds.n_frames(scene["name"])
        assert tokens[-1] == scene["last_sample_token"]
        samples = [ns.get("sample", t) for t in tokens]
        assert samples[0]["prev"] == "" and all(b["prev"] == a["token"] for a, b in zip(samples, samples[1:]))
        ts = np.array([s["timestamp"] for s in samples])
        assert np.all(np.abs(np.diff(ts) - dt_us) <= 1)
        starts.append(ts[0])
        for ch in NUSCENES_CAMERAS + ("LIDAR_TOP",):
            sds = [ns.get("sample_data", s["data"][ch]) for s in samples]
            assert [sd["timestamp"] for sd in sds] == list(ts)
            assert all(sd["is_key_frame"] and sd["sample_token"] == s["token"] for sd, s in zip(sds, samples))
            assert sds[0]["prev"] == "" and sds[-1]["next"] == ""
            assert all(a["next"] == b["token"] and b["prev"] == a["token"] for a, b in zip(sds, sds[1:]))
            assert all(ns.get("ego_pose", sd["ego_pose_token"])["timestamp"] == sd["timestamp"] for sd in sds)
            assert all((Path(ns.dataroot) / sd["filename"]).is_file() for sd in sds)
    assert len(set(starts)) == len(starts)  # scenes do not overlap in time


def test_rotation_to_quaternion():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = Quaternion(rng.normal(size=4)).normalised
        R = q.rotation_matrix
        np.testing.assert_allclose(Quaternion(rotation_to_quaternion(R)).rotation_matrix, R, atol=1e-12)


def test_conventions_round_trip_a_point(nusc, tiny_dataset):
    """A point in camera i's frame, to the world by our T_world_ego @ T_ego_cam, equals the devkit-style
    chain (Quaternion(rotation).rotation_matrix + translation of calibrated_sensor, then of ego_pose)."""
    ns, _, _ = nusc
    ds = open_dataset(tiny_dataset)
    rng = np.random.default_rng(1)
    for scene in ns.scene:
        seq = scene["name"]
        T_world_ego = ds.T_world_ego(seq)
        tok, f = scene["first_sample_token"], 0
        while tok:
            s = ns.get("sample", tok)
            for i, cam in enumerate(ds.cameras):
                p_cam = rng.uniform([-5, -3, 0.5], [5, 3, 40], size=3)
                ours = (T_world_ego[f] @ cam.T_ego_cam @ np.append(p_cam, 1))[:3]
                sd = ns.get("sample_data", s["data"][cam.name])
                cs = ns.get("calibrated_sensor", sd["calibrated_sensor_token"])
                pose = ns.get("ego_pose", sd["ego_pose_token"])
                p_ego = Quaternion(cs["rotation"]).rotation_matrix @ p_cam + np.array(cs["translation"])
                p_world = Quaternion(pose["rotation"]).rotation_matrix @ p_ego + np.array(pose["translation"])
                np.testing.assert_allclose(p_world, ours, atol=1e-9)
            tok, f = s["next"], f + 1


def _mesh_depth(D, valid, u, v):
    """z-depth of the depth-map mesh at continuous (u, v) (pixel centres at +0.5): the same two triangles per
    2x2 block as synth.lidar, 1/z affine inside each (exact for a plane). nan where the triangle is not whole."""
    H, W = D.shape
    x, y = u - 0.5, v - 0.5
    c0 = np.clip(np.floor(x).astype(int), 0, W - 2)
    r0 = np.clip(np.floor(y).astype(int), 0, H - 2)
    fu, fv = np.clip(x - c0, 0, 1), np.clip(y - r0, 0, 1)
    corner = lambda dr, dc: (D[r0 + dr, c0 + dc], valid[r0 + dr, c0 + dc])  # noqa: E731
    (za, va), (zb, vb), (zc, vc), (zd, vd) = corner(0, 0), corner(0, 1), corner(1, 0), corner(1, 1)
    inv = lambda z, ok: np.where(ok, 1.0 / np.where(ok, z, 1.0), np.nan)  # noqa: E731
    upper = fu + fv <= 1  # triangle (a, b, c), else (b, d, c)
    w_abc = (1 - fu - fv) * inv(za, va) + fu * inv(zb, vb) + fv * inv(zc, vc)
    w_bdc = (1 - fv) * inv(zb, vb) + (1 - fu) * inv(zc, vc) + (fu + fv - 1) * inv(zd, vd)
    return 1.0 / np.where(upper, w_abc, w_bdc)


def test_lidar_agrees_with_exact_depth(nusc, ns_root):
    """Project every LIDAR_TOP point into every camera with the devkit's chain and compare its camera z with
    the exact depth at the pixel it falls in (nearest: pixel floor(u), floor(v)) and with the depth map's mesh
    at the sub-pixel position. Measured on the tiny preset (96x64 cameras, 18 sweeps, ~25k points each):
    best camera per point, mesh depth: median 2.7e-8, max 5.9e-5 relative (float32 storage) -> asserted < 1e-4;
    every projection, nearest pixel: median 1.07 % (0.072 m), p90 5.0 %, 90.0 % within 5 % (max 79.6 m);
    every projection, mesh depth: median 2.9e-8, 98.8 % within 1 % (the rest: parallax, a point one camera
    sees lies behind a nearer surface or across an edge in another). 320x192: docs/NUSCENES.md."""
    ns, _, _ = nusc
    root = Path(ns_root)
    rel_near, abs_near, rel_mesh_all, best = [], [], [], []
    for s in ns.sample:
        lsd = ns.get("sample_data", s["data"]["LIDAR_TOP"])
        raw = np.fromfile(root / lsd["filename"], dtype=np.float32)
        assert raw.size % 5 == 0 and raw.size > 0
        ring = raw.reshape(-1, 5)[:, 4]
        assert np.all(ring == np.round(ring)) and ring.min() >= 0 and ring.max() <= 31
        n_pts = raw.size // 5
        point_best = np.full(n_pts, np.inf)
        seen = np.zeros(n_pts, bool)
        for ch in NUSCENES_CAMERAS:
            cam = ns.get("sample_data", s["data"][ch])
            pc = LidarPointCloud.from_file(str(root / lsd["filename"]))
            cs = ns.get("calibrated_sensor", lsd["calibrated_sensor_token"])
            pc.rotate(Quaternion(cs["rotation"]).rotation_matrix)
            pc.translate(np.array(cs["translation"]))
            pose = ns.get("ego_pose", lsd["ego_pose_token"])
            pc.rotate(Quaternion(pose["rotation"]).rotation_matrix)
            pc.translate(np.array(pose["translation"]))
            pose = ns.get("ego_pose", cam["ego_pose_token"])
            pc.translate(-np.array(pose["translation"]))
            pc.rotate(Quaternion(pose["rotation"]).rotation_matrix.T)
            cs = ns.get("calibrated_sensor", cam["calibrated_sensor_token"])
            pc.translate(-np.array(cs["translation"]))
            pc.rotate(Quaternion(cs["rotation"]).rotation_matrix.T)
            z = pc.points[2].astype(np.float64)
            uv = view_points(pc.points[:3], np.array(cs["camera_intrinsic"]), normalize=True)
            W, H = cam["width"], cam["height"]
            inside = (z > 0.5) & (uv[0] >= 0) & (uv[0] < W) & (uv[1] >= 0) & (uv[1] < H)
            depth_file = cam["filename"].replace("samples/", "mcdp_synth/depth/").replace(".jpg", ".depth.exr")
            D = read_depth_exr(root / depth_file).astype(np.float64)
            valid = (D > 0) & (read_png(root / "mcdp_synth" / "masks" / f"{ch}.png", gray=True) > 127)
            idx = np.nonzero(inside)[0]
            u, v, zi = uv[0, idx], uv[1, idx], z[idx]
            c, r = np.floor(u).astype(int), np.floor(v).astype(int)
            ok = valid[r, c]
            d = D[r, c][ok]
            abs_near.append(np.abs(zi[ok] - d))
            rel_near.append(np.abs(zi[ok] - d) / d)
            dm = _mesh_depth(D, valid, u, v)
            okm = np.isfinite(dm)
            e = np.abs(zi[okm] - dm[okm]) / dm[okm]
            rel_mesh_all.append(e)
            point_best[idx[okm]] = np.minimum(point_best[idx[okm]], e)
            seen[idx] = True
        assert seen.mean() > 0.99  # every point is in front of some camera (the lidar samples what they see)
        best.append(point_best[np.isfinite(point_best)])
        assert np.isfinite(point_best).mean() > 0.99
    best, rel_near, abs_near = np.concatenate(best), np.concatenate(rel_near), np.concatenate(abs_near)
    rel_mesh_all = np.concatenate(rel_mesh_all)
    print(f"lidar vs depth: best-camera mesh rel max {best.max():.2e} median {np.median(best):.2e}; "
          f"nearest-pixel rel median {np.median(rel_near):.4f} p90 {np.percentile(rel_near, 90):.4f} "
          f"max {rel_near.max():.3f}, abs median {np.median(abs_near):.3f} m max {abs_near.max():.2f} m, "
          f"within 5% {(rel_near < 0.05).mean():.3f}; all-camera mesh rel median {np.median(rel_mesh_all):.2e} "
          f"within 1% {(rel_mesh_all < 0.01).mean():.4f} (n={len(rel_near)})")
    assert best.max() < 1e-4, best.max()
    assert np.median(rel_near) < 0.02 and np.median(abs_near) < 0.15
    assert (rel_near < 0.05).mean() > 0.85
    assert np.median(rel_mesh_all) < 1e-5 and (rel_mesh_all < 0.01).mean() > 0.95


def test_side_files(ns_root, tiny_dataset):
    root, src = Path(ns_root), Path(tiny_dataset)
    ds = open_dataset(src)
    exp = json.loads((root / "mcdp_synth" / "export.json").read_text())
    assert exp["complete"] and exp["source"]["config_hash"] == ds.manifest["config_hash"]
    assert json.loads((root / "mcdp_synth" / "splits.json").read_text()) == ds.manifest["splits"]
    for cam in ds.camera_names:
        assert np.array_equal(read_png(root / "mcdp_synth" / "masks" / f"{cam}.png", gray=True) > 127, ds.mask(cam))
    n_depth = 0
    for token, e in exp["sample_data"].items():
        if "depth" in e:
            assert sha256_file(root / e["depth"]) == sha256_file(ds.depth_path(e["sequence"], e["camera"], e["frame"]))
            n_depth += 1
    assert n_depth == 6 * sum(ds.n_frames(s) for s in ds.sequences)


def test_reexport_is_reproducible_and_cli(ns_root, tiny_dataset, tmp_path, capsys):
    """Same dataset, same tables and point clouds byte for byte; the CLI re-exports over a previous export of
    the same dataset (another version name, a coarser lidar) and the devkit loads that too."""
    from synth.cli import main

    copy = tmp_path / "copy"
    shutil.copytree(ns_root, copy)
    before = {p.relative_to(copy): sha256_file(p) for p in copy.rglob("*") if p.is_file()}
    export_nuscenes(open_dataset(tiny_dataset), copy, version=VERSION)
    after = {p.relative_to(copy): sha256_file(p) for p in copy.rglob("*") if p.is_file()}
    assert before == after
    rc = main(["export", str(tiny_dataset), "--format", "nuscenes", "--out", str(copy), "--version", "v1.0-ci",
               "lidar.azimuth_res_deg=1.0", "lidar.beams=16", "--no-progress"])
    assert rc == 0, capsys.readouterr().err
    assert not (copy / VERSION).exists() and sorted(p.name for p in copy.iterdir()) == \
        [".lock", "lidarseg", "maps", "mcdp_synth", "samples", "v1.0-ci"]
    assert [p.name for p in (copy / "lidarseg").iterdir()] == ["v1.0-ci"]  # the previous version's labels gone
    ns, out, caught = _load(copy, "v1.0-ci")
    assert caught == [] and "warn" not in out.lower()
    pts = LidarPointCloud.from_file(str(copy / ns.get("sample_data", ns.sample[0]["data"]["LIDAR_TOP"])["filename"]))
    assert 0 < pts.points.shape[1] <= 16 * 360


def test_refuses_foreign_or_other_folders(tiny_dataset, ns_root, tmp_path, capsys):
    from synth.cli import main

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(ExportError, match=re.escape(str(foreign))):
        export_nuscenes(open_dataset(tiny_dataset), foreign)
    assert [p.name for p in foreign.iterdir()] == ["notes.txt"]
    rc = main(["export", str(tiny_dataset), "--format", "nuscenes", "--out", str(foreign), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2 and str(foreign) in err and len(err.strip().splitlines()) == 1

    other = tmp_path / "other"
    (other / "mcdp_synth").mkdir(parents=True)
    (other / "mcdp_synth" / "export.json").write_text(json.dumps(
        {"format": "mcdp-synth-nuscenes-export", "source": {"config_hash": "f" * 64}, "version": VERSION}))
    with pytest.raises(ExportError, match="another dataset"):
        export_nuscenes(open_dataset(tiny_dataset), other)

    ours = tmp_path / "ours"
    export_nuscenes(open_dataset(tiny_dataset), ours, lidar=None)
    assert not (ours / "samples" / "LIDAR_TOP").exists()
    (ours / "mine.txt").write_text("x")
    with pytest.raises(ExportError, match=re.escape(str(ours / "mine.txt"))):
        export_nuscenes(open_dataset(tiny_dataset), ours, lidar=None)
    assert (ours / VERSION / "scene.json").is_file()  # nothing removed

    (ours / "mcdp_synth" / "export.json").write_text("{not json")
    with pytest.raises(ExportError, match="export.json"):
        export_nuscenes(open_dataset(tiny_dataset), ours, lidar=None)

    with pytest.raises(ExportError, match="not one mcdp-synth rendered"):
        export_nuscenes(open_dataset(ns_root), tmp_path / "new")
    assert not (tmp_path / "new").exists()
    with pytest.raises(ExportError, match="plain folder name"):
        export_nuscenes(open_dataset(tiny_dataset), tmp_path / "new", version="../up")
    with pytest.raises(ExportError, match="inside the source dataset"):
        export_nuscenes(open_dataset(tiny_dataset), Path(tiny_dataset) / "ns")


def test_tables_complete_and_json_last(ns_root):
    root = Path(ns_root)
    assert sorted(p.stem for p in (root / VERSION).iterdir()) == sorted([*TABLES, "lidarseg"])  # tiny has labels
    assert not list(root.rglob("*.tmp")) and not list(root.glob("*.partial"))
    newest_side = max(p.stat().st_mtime_ns for p in root.rglob("*") if p.is_file() and VERSION not in p.parts)
    assert min(p.stat().st_mtime_ns for p in (root / VERSION).iterdir()) >= newest_side


def test_lidar_config_rejects_bad_values():
    from corelib.configlib import ConfigError, build_config

    with pytest.raises(ConfigError, match="beams"):
        build_config(LidarConfig, {"beams": 0})
    with pytest.raises(ConfigError, match="max_range_m"):
        build_config(LidarConfig, {"min_range_m": 10.0, "max_range_m": 5.0})


def test_a_second_export_into_the_same_folder_is_refused_naming_the_pid(tiny_dataset, tmp_path, capsys):
    import os

    from corelib.rundir import lock_folder
    from synth.cli import main

    out = tmp_path / "ns"
    out.mkdir()
    held = lock_folder(out, ".lock")  # another export is writing
    try:
        assert main(["export", str(tiny_dataset), "--format", "nuscenes", "--out", str(out), "--no-lidar",
                     "--no-progress"]) == 2
        assert f"another process (pid {os.getpid()})" in capsys.readouterr().err
    finally:
        held.release()
    assert main(["export", str(tiny_dataset), "--format", "nuscenes", "--out", str(out), "--no-lidar",
                 "--no-progress"]) == 0


def test_a_second_export_over_a_running_one_deletes_nothing(ns_root, tiny_dataset, tmp_path, capsys):
    from corelib.rundir import lock_folder
    from synth.cli import main

    copy = tmp_path / "copy"
    shutil.copytree(ns_root, copy)
    before = {p.relative_to(copy): sha256_file(p) for p in copy.rglob("*") if p.is_file() and p.name != ".lock"}
    held = lock_folder(copy, ".lock")  # the first export is still writing
    try:
        assert main(["export", str(tiny_dataset), "--format", "nuscenes", "--out", str(copy), "--no-progress"]) == 2
    finally:
        held.release()
    after = {p.relative_to(copy): sha256_file(p) for p in copy.rglob("*") if p.is_file() and p.name != ".lock"}
    assert after == before
