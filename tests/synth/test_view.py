"""`synth view`: the Rerun recording of the tiny render, read back with Rerun's own tools (the `rerun rrd
verify` CLI and the SDK's chunk reader `rerun.chunk.RrdReader`). Skips without the viz extra."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun", reason="the viz extra is not here: it is in .venv-viz (tests/test_viz_env.py)")


def read_rrd(path) -> dict[str, list[tuple[int | None, dict]]]:
    """{entity path: [(time in ns or None for static, {component: value of that row})]} of the first
    recording in `path`, through the SDK's chunk reader."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch()
        cols = {n: rb.column(n).to_pylist() for n in rb.schema.names if ":" in n}
        times = rb.column("time").cast("int64").to_pylist() if "time" in rb.schema.names else [None] * rb.num_rows
        for i in range(rb.num_rows):
            out.setdefault(chunk.entity_path, []).append((times[i], {k: v[i] for k, v in cols.items()}))
    return out


def depth_of(row: dict, prefix: str = "DepthImage") -> np.ndarray:
    fmt = row[f"{prefix}:format"][0]
    buf = np.asarray(row[f"{prefix}:buffer"][0], np.uint8)
    return buf.view(np.float32).reshape(fmt["height"], fmt["width"])


def rrd_verify(path) -> str:
    res = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(path)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout + res.stderr


@pytest.fixture(scope="module")
def recording(tiny_dataset, tmp_path_factory):
    from synth.cli import main

    out = tmp_path_factory.mktemp("view") / "rig.rrd"
    assert main(["view", str(tiny_dataset), "--seq", "seq_00001", "--frames", "1:4", "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def flow_recording(flow_dataset, tmp_path_factory):
    """A recording of the tiny preset rendered with every label (forward flow is off by default)."""
    from synth.cli import main

    out = tmp_path_factory.mktemp("view_flow") / "rig.rrd"
    assert main(["view", str(flow_dataset), "--seq", "seq_00001", "--frames", "1:4", "--out", str(out)]) == 0
    return out


def test_recording_verifies_and_holds_the_rig_of_rig_json(recording, tiny_dataset):
    assert "verified without error" in rrd_verify(recording)
    ents = read_rrd(recording)
    rig = json.loads((tiny_dataset / "rig.json").read_text())
    for cam in rig["cameras"]:
        rows = [r for t, r in ents[f"/world/ego/{cam['name']}"] if t is None]
        pin = [r for r in rows if "Pinhole:image_from_camera" in r]
        assert len(pin) == 1
        K = np.asarray(pin[0]["Pinhole:image_from_camera"][0]).reshape(3, 3).T  # stored column-major
        np.testing.assert_allclose(K, cam["K"], rtol=1e-6)
        assert pin[0]["Pinhole:resolution"][0] == [cam["width"], cam["height"]]
        tr = [r for r in rows if "Transform3D:translation" in r][0]
        T = np.asarray(cam["T_ego_cam"])
        np.testing.assert_allclose(tr["Transform3D:translation"][0], T[:3, 3], atol=1e-6)
        np.testing.assert_allclose(np.asarray(tr["Transform3D:mat3x3"][0]).reshape(3, 3).T, T[:3, :3], atol=1e-6)


def test_recording_carries_the_blueprint(recording, tiny_dataset, check_blueprint):
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    check_blueprint(recording, ds.cameras, ["RGB", "depth (ground truth)", "labels"])


def test_labels_are_a_segmentation_image_with_the_class_colours_and_flow_arrows(flow_recording, flow_dataset):
    """Frames 1..3 of seq_00001: per camera and frame the class map as a SegmentationImage (equal to the PNG), the
    class table as its AnnotationContext, the valid forward flow as arrows on the grid of `flow_stride`."""
    from synth.open import open_dataset
    from synth.view_labels import flow_stride

    ds = open_dataset(flow_dataset)
    ego = ds.ego("seq_00001")
    ents = read_rrd(flow_recording)
    for cam in ds.cameras:
        for kind in ("semantic", "flow"):
            (ctx,) = [r["AnnotationContext:context"][0] for t, r in ents[f"/world/ego/{cam.name}/{kind}"] if t is None]
            assert [(c["class_id"], c["class_description"]["info"]["label"]) for c in ctx] == \
                [(c["index"], c["name"]) for c in ds.classes]
            r, g, b = ds.classes[1]["color"]
            assert ctx[1]["class_description"]["info"]["color"] == (r << 24) | (g << 16) | (b << 8) | 255
        sems = {t: r for t, r in ents[f"/world/ego/{cam.name}/semantic"] if t is not None}
        flows = {t: r for t, r in ents[f"/world/ego/{cam.name}/flow"] if t is not None}
        assert sorted(sems) == sorted(flows) == [round(ego[f]["timestamp_s"] * 1e9) for f in (1, 2, 3)]
        for f in (1, 3):
            t = round(ego[f]["timestamp_s"] * 1e9)
            sem = ds.read_semantic("seq_00001", cam.name, f)
            row = sems[t]
            assert row["SegmentationImage:format"][0]["width"] == cam.width
            got = np.asarray(row["SegmentationImage:buffer"][0], np.uint8).reshape(cam.height, cam.width)
            assert np.array_equal(got, sem)
            flow, valid = ds.read_flow("seq_00001", cam.name, f)
            org = np.asarray(flows[t]["Arrows2D:origins"], np.float32)
            u, v = (org[:, 0] - 0.5).astype(int), (org[:, 1] - 0.5).astype(int)
            s = flow_stride(cam.width)
            assert (u % s == s // 2).all() and (v % s == s // 2).all() and valid[v, u].all()
            assert len(org) == valid[s // 2::s, s // 2::s].sum() > 0
            np.testing.assert_allclose(np.asarray(flows[t]["Arrows2D:vectors"]), flow[v, u], rtol=1e-6)
            assert flows[t]["Arrows2D:class_ids"] == sem[v, u].tolist()


def test_without_labels_the_recording_is_as_before(flow_dataset, tiny_dataset_without_labels, tmp_path,
                                                   check_blueprint):
    """The last frame has no forward flow: its arrows are cleared. A dataset without labels records no label
    entities and no labels tab."""
    from synth.cli import main
    from synth.open import open_dataset

    ds = open_dataset(flow_dataset)  # the tiny preset with flow: its images and depth are the dataset's without labels
    outs = {}
    for name, data in (("new", flow_dataset), ("old", tiny_dataset_without_labels)):
        outs[name] = tmp_path / f"{name}.rrd"
        assert main(["view", str(data), "--seq", "seq_00000", "--frames", "5:6", "--out", str(outs[name])]) == 0
    new, old = read_rrd(outs["new"]), read_rrd(outs["old"])
    assert [r for t, r in new["/world/ego/CAM_FRONT/flow"] if t is not None] == [{"Clear:is_recursive": [False]}]
    assert {e for e in new if not e.endswith(("/semantic", "/flow"))} == set(old)
    assert not any(e.endswith(("/semantic", "/flow")) for e in old)
    check_blueprint(outs["old"], ds.cameras, ["RGB", "depth (ground truth)"])


def test_ring_order_is_front_row_then_back_row():
    from types import SimpleNamespace

    from synth.view_blueprint import ring_order

    def cam(name, yaw_deg):  # optical axis (camera z) at `yaw_deg` in the ego frame (x forward, y left)
        a = np.radians(yaw_deg)
        T = np.eye(4)
        T[:3, 2] = [np.cos(a), np.sin(a), 0.0]
        return SimpleNamespace(name=name, T_ego_cam=T)

    cams = [cam("F", 0), cam("FR", -55), cam("BR", -110), cam("B", 180), cam("BL", 110), cam("FL", 55)]
    assert ring_order(cams) == (["FL", "F", "FR", "BL", "B", "BR"], 3)


def test_recording_holds_the_world_mesh_trajectory_and_ego_body(recording, tiny_dataset):
    from synth.open import open_dataset
    from synth.gltf_export import rebuild_scene

    ds = open_dataset(tiny_dataset)
    cfg, model = rebuild_scene(ds, "seq_00001")
    ego = ds.ego("seq_00001")
    t0 = round(ego[0]["timestamp_s"] * 1e9)
    ents = read_rrd(recording)
    (row,) = [r for t, r in ents["/world/scene/static"] if "Mesh3D:vertex_positions" in r]
    np.testing.assert_allclose(np.asarray(row["Mesh3D:vertex_positions"]), model.static.positions, rtol=1e-6)
    assert len(row["Mesh3D:triangle_indices"]) == model.static.n_triangles
    assert [t for t, r in ents["/world/scene/static"]] == [t0]  # at the sequence's start
    (strip,) = [r["LineStrips3D:strips"] for t, r in ents["/world/trajectory"]]
    np.testing.assert_allclose(np.asarray(strip[0]), [np.asarray(e["T_world_ego"])[:3, 3] for e in ego], rtol=1e-6)
    (body,) = [r for t, r in ents["/world/ego/body"] if t is None]  # static: the same car in every sequence
    assert len(body["Mesh3D:vertex_positions"]) > 100
    mover = model.movers[0]
    poses = {t: r for t, r in ents[f"/world/scene/{mover.name}"] if "Transform3D:translation" in r}
    t2 = round(ego[2]["timestamp_s"] * 1e9)
    np.testing.assert_allclose(poses[t2]["Transform3D:translation"][0], mover.T_world_obj[2][:3, 3], rtol=1e-6)
    assert sorted(poses) == [t0] + [round(ego[f]["timestamp_s"] * 1e9) for f in (1, 2, 3)]


def test_one_depth_image_per_camera_and_frame_equal_to_the_exr(recording, tiny_dataset):
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    ego = ds.ego("seq_00001")
    ents = read_rrd(recording)
    for cam in ds.camera_names:
        rows = ents[f"/world/ego/{cam}/depth"]
        assert sorted(t for t, _ in rows) == [round(ego[f]["timestamp_s"] * 1e9) for f in (1, 2, 3)]
        for t, row in rows:
            f = [f for f in (1, 2, 3) if round(ego[f]["timestamp_s"] * 1e9) == t][0]
            assert row["DepthImage:meter"] == [1.0]
            np.testing.assert_array_equal(depth_of(row), ds.read_depth("seq_00001", cam, f))
        for what in ("rgb", "overlap"):
            assert len([t for t, _ in ents[f"/world/ego/{cam}/{what}"] if t is not None]) == 3
        assert [t for t, _ in ents[f"/world/ego/{cam}/ego_mask"] if t is None]
    poses = {t: r for t, r in ents["/world/ego"]}
    T = np.asarray(ego[2]["T_world_ego"])
    np.testing.assert_allclose(poses[round(ego[2]["timestamp_s"] * 1e9)]["Transform3D:translation"][0], T[:3, 3],
                               rtol=1e-6)
    assert len(ents["/world/ego/points_gt"]) == 3


def test_a_nuscenes_dataroot_records_its_lidar_sweep_in_the_world_frame(tiny_dataset, tmp_path):
    """The LiDAR branch: our nuScenes export of the tiny render, opened by `synth.open.open_dataset`
    (the plain-JSON reader here: this environment cannot have nuscenes-devkit, which pins numpy < 2),
    recorded by `synth view`: world/lidar holds `lidar_points_world` of each frame at that frame's time."""
    from synth.cli import main
    from synth.open import open_dataset
    from synth.nuscenes.export import export_nuscenes
    from synth.nuscenes.dataset import NuScenesDataset

    root = tmp_path / "ns"
    export_nuscenes(open_dataset(tiny_dataset), root, version="v1.0-synth")
    ds = open_dataset(root)
    assert isinstance(ds, NuScenesDataset)
    seq = ds.sequences[0]
    out = tmp_path / "ns.rrd"
    assert main(["view", str(root), "--seq", seq, "--frames", "1:3", "--out", str(out)]) == 0
    assert "verified without error" in rrd_verify(out)
    ents = read_rrd(out)
    ego = ds.ego(seq)
    rows = {t: r for t, r in ents["/world/lidar"] if t is not None}
    assert sorted(rows) == [round(ego[f]["timestamp_s"] * 1e9) for f in (1, 2)]
    for f in (1, 2):
        want = ds.lidar_points_world(seq, f)
        assert len(want) > 1000  # a real sweep, not an empty branch
        got = np.asarray(rows[round(ego[f]["timestamp_s"] * 1e9)]["Points3D:positions"], np.float64)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-6 * max(1.0, np.abs(want).max()))
    assert not [t for t, _ in ents["/world/lidar"] if t is None]
    assert "/world/trajectory" in ents and not [e for e in ents if e.startswith("/world/scene")]  # no scene model
    assert len([t for t, _ in ents[f"/world/ego/{ds.camera_names[0]}/depth"] if t is not None]) == 2


@pytest.mark.parametrize("args, message", [
    (["--seq", "seq_9"], "--seq 'seq_9' is not a sequence of"),
    (["--frames", "4:9"], "--frames 4:9 is outside seq_00000's frames: A:B with 0 <= A < B <= 6"),
    (["--frames", "x"], "--frames 'x' is not A:B"),
])
def test_bad_seq_and_frames_name_the_valid_range(tiny_dataset, tmp_path, capsys, args, message):
    from synth.cli import main

    assert main(["view", str(tiny_dataset), "--out", str(tmp_path / "r.rrd"), *args]) == 2
    assert message in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_foreign_files_and_dataset_folders_are_refused(tiny_dataset, tmp_path, capsys):
    from synth.cli import main

    mine = tmp_path / "notes.rrd"
    mine.write_text("my own file")
    assert main(["view", str(tiny_dataset), "--out", str(mine)]) == 2
    assert "exists and is not a Rerun recording" in capsys.readouterr().err
    assert mine.read_text() == "my own file"
    assert main(["view", str(tiny_dataset), "--out", str(tiny_dataset / "r.rrd")]) == 2
    assert "inside the dataset" in capsys.readouterr().err
    assert main(["view", str(tiny_dataset), "--out", str(tmp_path / "r.txt")]) == 2
    assert "is named *.rrd" in capsys.readouterr().err


def test_missing_extra_names_the_install_command(monkeypatch):
    import synth.view as view

    monkeypatch.setitem(sys.modules, "rerun", None)  # `import rerun` raises ImportError
    with pytest.raises(view.ViewError, match=r"pip install -e '\.\[viz\]'"):
        view.import_rerun()


# --------------------------------------------------------------------------- a full disk (issue 32, finding 7)
def test_a_full_disk_while_recording_exits_4_naming_the_file_and_leaves_no_temporary(tiny_dataset, tmp_path, capsys,
                                                                                      monkeypatch, full_disk_after):
    """Rerun writes into a pipe; our writer (`corelib.atomic.atomic_pipe`) meets the full disk: one line naming
    --out, exit 4, nothing under its name or a temporary one; the same command then writes it."""
    import corelib.atomic
    from synth.cli import main

    out = tmp_path / "v.rrd"
    args = ["view", str(tiny_dataset), "--frames", "0:2", "--out", str(out)]
    monkeypatch.setattr(corelib.atomic, "open", full_disk_after(0, ".rrd"), raising=False)
    capsys.readouterr()
    assert main(args) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("synth view: error: ") and f"{out}: no space left on device" in err[0]
    assert list(tmp_path.iterdir()) == []
    monkeypatch.undo()
    assert main(args) == 0 and "verified without error" in rrd_verify(out)


@pytest.mark.parametrize("full", [False, True], ids=["fills-while-writing", "full-from-the-start"])
def test_synth_view_on_a_real_disk_that_fills_ends_in_exit_4_not_a_hang(tiny_dataset, tmp_path, small_disk, full):
    """A real 64 KiB tmpfs (the recording is ~0.3 MB): Rerun's own file sink hung here forever."""
    import os
    from pathlib import Path

    mnt = tmp_path / "mnt"
    mnt.mkdir()
    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    res, left = small_disk([sys.executable, "-m", "synth.cli", "view", str(tiny_dataset), "--frames", "0:2",
                            "--out", str(mnt / "v.rrd")], mnt, full=full, timeout=120, env=env)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 4, res.stderr[-2000:]
    assert len(err) == 1 and f"{mnt / 'v.rrd'}: no space left on device" in err[0], err
    assert left == (["fill"] if full else [])


def test_a_jpeg_dataset_logs_its_jpeg_files_as_they_are(tmp_path):
    """``sensor.jpeg_quality``: each camera's image is logged as the stored JPEG bytes (media type image/jpeg)."""
    from synth.cli import main
    from synth.config import load_data_config
    from synth.render import render_dataset

    data, out = tmp_path / "data", tmp_path / "rig.rrd"
    tiny = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
    cfg = load_data_config(tiny, ["sensor.jpeg_quality=90", "dataset.sequences=1", "dataset.frames=3"])
    render_dataset(cfg, data, workers=1, progress=False, log=lambda *a: None)
    assert main(["view", str(data), "--seq", "seq_00000", "--frames", "0:2", "--out", str(out)]) == 0
    rows = read_rrd(out)["/world/ego/CAM_BACK/rgb"]
    assert len(rows) == 2 and all(r["EncodedImage:media_type"] == ["image/jpeg"] for _, r in rows)
    blob = bytes(np.asarray(rows[0][1]["EncodedImage:blob"][0], np.uint8))
    assert blob in {(data / "seq_00000" / "CAM_BACK" / f"00000{f}.jpg").read_bytes() for f in (0, 1)}


def test_cameras_that_fire_apart_are_played_at_their_own_times(tmp_path):
    """rig.trigger=lidar_sweep: each camera's image, depth and overlap at its own time, with its Transform3D then
    (its pose in the frame's ego frame: `camera_poses`, per frame, none static); the ego and the points at the
    frame's time."""
    from pathlib import Path

    from corelib.configlib import load_config
    from synth.cli import main
    from synth.config import DataConfig
    from synth.open import open_dataset
    from synth.render import render_dataset

    tiny = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
    data = tmp_path / "data"
    render_dataset(load_config(DataConfig, tiny, ["rig.trigger=lidar_sweep", "dataset.frames=3", "camera.width=48",
                                                  "camera.height=32"]), data, workers=1, progress=False,
                   log=lambda *a: None)
    ds = open_dataset(data)
    seq = ds.sequences[0]
    out = tmp_path / "trig.rrd"
    assert main(["view", str(data), "--seq", seq, "--out", str(out)]) == 0
    assert "verified without error" in rrd_verify(out)
    ents = read_rrd(out)
    ts, T = ds.camera_poses(seq)
    frame_ns = [round(e["timestamp_s"] * 1e9) for e in ds.ego(seq)]
    for c, cam in enumerate(ds.camera_names):
        own = [round(t * 1e9) for t in ts[:, c]]
        for what in ("rgb", "depth", "overlap"):
            assert sorted(t for t, _ in ents[f"/world/ego/{cam}/{what}"] if t is not None) == own, (cam, what)
        rows = [(t, r) for t, r in ents[f"/world/ego/{cam}"] if "Transform3D:translation" in r]
        assert all(t is not None for t, _ in rows) and sorted(t for t, _ in rows) == own
        for t, r in rows:
            np.testing.assert_allclose(r["Transform3D:translation"][0], T[own.index(t), c, :3, 3], atol=1e-5)
    assert own != frame_ns and sorted(t for t, _ in ents["/world/ego"] if t is not None) == frame_ns
    assert sorted(t for t, _ in ents["/world/ego/points_gt"]) == frame_ns
