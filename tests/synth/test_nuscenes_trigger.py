"""The nuScenes export of a rig whose cameras fire at their own times (rig.trigger, issue 48, item 1): each camera
sample_data has its own timestamp and ego_pose, as nuScenes has; the devkit loads them, they match the dataset's
per-camera records, and the nuScenes reader gives back the synth reader's camera poses (model.sync=compensate)."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("nuscenes", reason="nuscenes-devkit not installed (pip install -e '.[nuscenes]')")

from nuscenes.nuscenes import NuScenes  # noqa: E402
from pyquaternion import Quaternion  # noqa: E402

from corelib.configlib import load_config  # noqa: E402
from synth.lidar import LidarConfig  # noqa: E402
from synth.nuscenes.records import timestamp_us  # noqa: E402
from synth.open import open_dataset  # noqa: E402

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
SMALL = ["dataset.frames=3", "camera.width=64", "camera.height=48"]


@pytest.fixture(scope="module")
def trigger_dataset(tmp_path_factory):
    """The tiny preset at 64x48, 3 frames, its cameras fired by a LiDAR sweep (nuScenes' trigger)."""
    from synth.config import DataConfig
    from synth.render import render_dataset

    out = tmp_path_factory.mktemp("trig") / "data"
    render_dataset(load_config(DataConfig, TINY, ["rig.trigger=lidar_sweep", *SMALL]), out, workers=1,
                   progress=False, log=lambda *a: None)
    return out


@pytest.fixture(scope="module")
def trigger_root(trigger_dataset, tmp_path_factory):
    from synth.nuscenes.export import export_nuscenes

    out = tmp_path_factory.mktemp("ns_trig") / "root"
    export_nuscenes(open_dataset(trigger_dataset), out, lidar=LidarConfig(azimuth_res_deg=1.0))
    return out


def _matrix(rec: dict) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Quaternion(rec["rotation"]).rotation_matrix
    T[:3, 3] = rec["translation"]
    return T


def test_devkit_gives_each_camera_its_own_time_and_ego_pose(trigger_dataset, trigger_root):
    nusc = NuScenes(version="v1.0-synth", dataroot=str(trigger_root), verbose=False)
    ds = open_dataset(trigger_dataset)
    offsets = ds.manifest["trigger"]["offsets_ms"]
    assert json.loads((trigger_root / "mcdp_synth" / "export.json").read_text())["trigger"] == ds.manifest["trigger"]
    checked = 0
    for si, seq in enumerate(ds.sequences):
        scene = next(s for s in nusc.scene if s["name"] == seq)
        sample = nusc.get("sample", scene["first_sample_token"])
        for f, fr in enumerate(ds.ego(seq)):
            ts = timestamp_us(si, f, ds.fps)
            assert sample["timestamp"] == ts
            lidar = nusc.get("sample_data", sample["data"]["LIDAR_TOP"])  # the LiDAR keeps the frame's time and pose
            assert lidar["timestamp"] == ts
            assert np.allclose(_matrix(nusc.get("ego_pose", lidar["ego_pose_token"])), fr["T_world_ego"], atol=1e-9)
            poses = {}
            for cam in ds.camera_names:
                sd = nusc.get("sample_data", sample["data"][cam])
                assert sd["timestamp"] == ts + round(offsets[cam] * 1000)  # us: the camera's own trigger time
                assert sd["filename"].endswith(f"__{cam}__{sd['timestamp']}.jpg")
                ep = nusc.get("ego_pose", sd["ego_pose_token"])
                assert ep["timestamp"] == sd["timestamp"]
                poses[cam] = _matrix(ep)
                assert np.allclose(poses[cam], fr["cameras"][cam]["T_world_ego"], atol=1e-9)  # ego.json's record
                checked += 1
            assert np.allclose(poses["CAM_FRONT"], fr["T_world_ego"], atol=1e-9)  # it fires at the frame time
            moved = [np.linalg.norm(poses[c][:3, 3] - poses["CAM_FRONT"][:3, 3]) for c in ds.camera_names[1:]]
            assert min(moved) > 0.05 and np.all(np.diff(moved) > 0), moved  # later around the sweep, further on
            sample = nusc.get("sample", sample["next"]) if sample["next"] else None
    assert checked == 6 * sum(ds.n_frames(s) for s in ds.sequences)


def test_the_nuscenes_reader_gives_back_each_cameras_pose(trigger_dataset, trigger_root):
    from mcdp.data import RigReader
    from synth.nuscenes.read import open_nuscenes

    ds, ns = open_dataset(trigger_dataset), open_nuscenes(trigger_root)
    for seq in ds.sequences:
        ts, T = ds.camera_poses(seq)
        ts_ns, T_ns = ns.camera_poses(seq)
        assert np.abs(ts_ns - ts).max() < 1e-6  # whole microseconds
        assert np.allclose(T_ns, T, atol=1e-9) and np.allclose(ns.T_world_ego(seq), ds.T_world_ego(seq), atol=1e-9)
        assert not np.allclose(T_ns[1], np.stack([c.T_ego_cam for c in ns.cameras]), atol=1e-3)
    seq = ds.sequences[0]  # the trainer's cross-camera warps read them under model.sync=compensate
    reader = RigReader(ns, 32, 48, sync="compensate")
    assert np.allclose(reader.T_ego_cam_at(seq, 1), ns.camera_poses(seq)[1][1], atol=1e-6)
    assert np.array_equal(RigReader(ns, 32, 48, sync="assume").T_ego_cam_at(seq, 1), reader.T_ego_cam)


def test_a_synchronous_export_reads_the_static_rig(ns_root):
    from synth.nuscenes.read import open_nuscenes

    ns = open_nuscenes(ns_root)
    seq = ns.sequences[0]
    ts, T = ns.camera_poses(seq)
    assert np.array_equal(T, np.broadcast_to(np.stack([c.T_ego_cam for c in ns.cameras]), T.shape))
    assert np.array_equal(ts, np.repeat(np.array([f["timestamp_s"] for f in ns.ego(seq)])[:, None], 6, 1))
    assert "trigger" not in json.loads((ns_root / "mcdp_synth" / "export.json").read_text())
