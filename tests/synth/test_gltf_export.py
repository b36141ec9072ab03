"""`synth export --format gltf`: the GLB loaded back with trimesh holds the scene model (vertex count,
bounds, mover poses) and scene.json's cameras project like rig.json + ego.json. Skips without the viz extra."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh", reason="the viz extra is not installed: pip install -e '.[viz]'")

SEQ = "seq_00001"


@pytest.fixture(scope="module")
def export(tiny_dataset, tmp_path_factory):
    from synth.cli import main

    out = tmp_path_factory.mktemp("gltf") / "out"
    assert main(["export", str(tiny_dataset), "--format", "gltf", "--out", str(out), "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def model(tiny_dataset):
    from synth.dataset import open_dataset
    from synth.gltf_export import rebuild_scene

    return rebuild_scene(open_dataset(tiny_dataset), SEQ)[1]


def world_points(sc, meta, prefix: str) -> np.ndarray:
    """Vertices of the nodes under `prefix` in the dataset's world frame (undoing the y-up root)."""
    W = np.linalg.inv(np.asarray(meta["T_gltf_world"]))
    out = []
    for node in sc.graph.nodes_geometry:
        if node.startswith(prefix + "/"):
            T, geom = sc.graph.get(node)
            out.append(trimesh.transform_points(sc.geometry[geom].vertices, W @ T))
    return np.concatenate(out)


def test_glb_holds_the_scene_model(export, model, tiny_dataset):
    from synth.config import DataConfig
    from corelib.configlib import build_config
    from synth.render import make_ego_mesh

    sc = trimesh.load_scene(export / SEQ / "scene.glb", process=False)
    meta = json.loads((export / SEQ / "scene.json").read_text())
    cfg = build_config(DataConfig, json.loads((tiny_dataset / "manifest.json").read_text())["config"], "manifest")
    n = model.static.n_vertices + sum(m.mesh.n_vertices for m in model.movers) + make_ego_mesh(cfg).n_vertices
    assert sum(len(g.vertices) for g in sc.geometry.values()) == n == meta["vertices"]
    static = world_points(sc, meta, "static")
    assert len(static) == model.static.n_vertices
    eps = 1e-5 * np.abs(model.static.positions).max()  # float32 rounding of a world-sized coordinate
    np.testing.assert_allclose(static.min(0), model.static.positions.min(0), atol=eps)
    np.testing.assert_allclose(static.max(0), model.static.positions.max(0), atol=eps)
    mover = model.movers[0]
    pts = world_points(sc, meta, mover.name)
    want = mover.mesh.positions @ mover.T_world_obj[0][:3, :3].T + mover.T_world_obj[0][:3, 3]
    np.testing.assert_allclose(np.sort(pts, 0), np.sort(want, 0), atol=eps)
    for f, fr in enumerate(meta["frames"]):
        np.testing.assert_allclose(fr["movers"][mover.name], mover.T_world_obj[f], atol=1e-12)
    part = sc.geometry[sc.graph.get([n for n in sc.graph.nodes_geometry if n.startswith("static/")][0])[1]]
    assert part.visual.material.baseColorTexture.size == (128, 128)  # the procedural texture, as an image


def test_json_cameras_project_a_world_point_like_rig_json_and_the_ego_pose(export, model, tiny_dataset):
    meta = json.loads((export / SEQ / "scene.json").read_text())
    rig = json.loads((tiny_dataset / "rig.json").read_text())
    ego = json.loads((tiny_dataset / SEQ / "ego.json").read_text())["frames"]
    f = 3
    for cam in rig["cameras"]:
        T_cw = np.linalg.inv(np.asarray(ego[f]["T_world_ego"]) @ np.asarray(cam["T_ego_cam"]))
        j = meta["frames"][f]["cameras"][cam["name"]]
        T_cw_json = np.linalg.inv(np.asarray(j["T_world_cam"]))
        X = model.static.positions.astype(np.float64)
        Xc = X @ T_cw[:3, :3].T + T_cw[:3, 3]
        i = int(np.argmax((Xc[:, 2] > 1.0) * -np.abs(Xc[:, 0] / np.maximum(Xc[:, 2], 1e-9))))  # near the axis
        uv = np.asarray(cam["K"]) @ Xc[i]
        p = X[i] @ T_cw_json[:3, :3].T + T_cw_json[:3, 3]
        uv_json = np.asarray(j["K"]) @ p
        np.testing.assert_allclose(uv_json[:2] / uv_json[2], uv[:2] / uv[2], atol=1e-6)
        assert (j["width"], j["height"]) == (cam["width"], cam["height"])


def test_re_export_and_foreign_folders(export, tiny_dataset, tmp_path, capsys):
    from synth.cli import main

    assert main(["export", str(tiny_dataset), "--format", "gltf", "--out", str(export), "--no-progress"]) == 0
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    assert main(["export", str(tiny_dataset), "--format", "gltf", "--out", str(mine), "--no-progress"]) == 2
    assert "is not empty and is not an mcdp gltf_export folder" in capsys.readouterr().err
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    assert main(["export", str(tiny_dataset), "--format", "gltf", "--out", str(tiny_dataset / "g")]) == 2
    assert "inside the dataset" in capsys.readouterr().err


def test_missing_extra_names_the_install_command(monkeypatch):
    from synth.files import DatasetError
    from synth.gltf_export import import_trimesh

    monkeypatch.setitem(sys.modules, "trimesh", None)
    with pytest.raises(DatasetError, match=r"pip install -e '\.\[viz\]'"):
        import_trimesh()
