"""`synth export --format gltf`: the GLB loaded back with trimesh holds the scene model (vertex count,
bounds, mover poses) and scene.json's cameras project like rig.json + ego.json. Skips without the viz extra."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh", reason="the viz extra is not here: it is in .venv-viz (tests/test_viz_env.py)")

SEQ = "seq_00001"


@pytest.fixture(scope="module")
def export(tiny_dataset, tmp_path_factory):
    from synth.cli import main

    out = tmp_path_factory.mktemp("gltf") / "out"
    assert main(["export", str(tiny_dataset), "--format", "gltf", "--out", str(out), "--no-progress"]) == 0
    return out


@pytest.fixture(scope="module")
def model(tiny_dataset):
    from synth.open import open_dataset
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


def read_glb(path) -> tuple[dict, bytes]:
    """(the JSON chunk, the BIN chunk) of a GLB (glTF 2.0, section 4.4: 12-byte header, then chunks)."""
    import struct

    data = path.read_bytes()
    magic, version, _ = struct.unpack_from("<4sII", data, 0)
    assert (magic, version) == (b"glTF", 2)
    n, kind = struct.unpack_from("<I4s", data, 12)
    assert kind == b"JSON"
    tree = json.loads(data[20:20 + n])
    m, kind = struct.unpack_from("<I4s", data, 20 + n)
    assert kind == b"BIN\x00"
    return tree, data[28 + n:28 + n + m]


def accessor(tree: dict, blob: bytes, i: int) -> np.ndarray:
    acc = tree["accessors"][i]
    view = tree["bufferViews"][acc["bufferView"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
    assert acc["componentType"] == 5126  # float32
    a = np.frombuffer(blob, np.float32, acc["count"] * width, view["byteOffset"] + acc.get("byteOffset", 0))
    return a.reshape(acc["count"], width)


def node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # column-major
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    T = np.eye(4)
    T[:3, :3] = trimesh.transformations.quaternion_matrix([w, x, y, z])[:3, :3]
    T[:3, 3] = node.get("translation", [0, 0, 0])
    return T


def test_glb_holds_the_rig_cameras_and_the_poses_as_an_animation(export, model, tiny_dataset):
    """Six glTF perspective cameras under the 'ego' node, whose pose in the world frame (ego @ camera under the z-up root, glTF's
    -z looking axis flipped back) is T_world_ego[0] @ T_ego_cam; the animation 'sequence' holds every frame's
    ego and mover pose at the frames' timestamps."""
    from synth.gltf_cameras import GL_FROM_CV

    tree, blob = read_glb(export / SEQ / "scene.glb")
    rig = json.loads((tiny_dataset / "rig.json").read_text())
    ego = json.loads((tiny_dataset / SEQ / "ego.json").read_text())["frames"]
    names = {n.get("name"): i for i, n in enumerate(tree["nodes"])}
    cams = {c["name"]: c for c in tree["cameras"]}
    assert sorted(cams) == sorted(c["name"] for c in rig["cameras"])
    ego_node = tree["nodes"][names["ego"]]
    for cam in rig["cameras"]:
        i = names[f"camera/{cam['name']}"]
        assert i in ego_node["children"]
        node = tree["nodes"][i]
        assert tree["cameras"][node["camera"]]["name"] == cam["name"]
        p = cams[cam["name"]]["perspective"]
        assert p["yfov"] == pytest.approx(2 * np.arctan(cam["height"] / (2 * cam["K"][1][1])))
        assert p["aspectRatio"] == pytest.approx(cam["width"] / cam["height"])
        T = node_matrix(ego_node) @ node_matrix(node) @ np.linalg.inv(GL_FROM_CV)
        want = np.asarray(ego[0]["T_world_ego"]) @ np.asarray(cam["T_ego_cam"])
        np.testing.assert_allclose(T, want, atol=1e-5)
    (anim,) = tree["animations"]
    assert anim["name"] == "sequence"
    track = {}
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        track[(tree["nodes"][ch["target"]["node"]]["name"], ch["target"]["path"])] = (
            accessor(tree, blob, s["input"])[:, 0], accessor(tree, blob, s["output"]))
    mover = model.movers[0]
    for name, poses in (("ego", model.T_world_ego), (mover.name, mover.T_world_obj)):
        t, xyz = track[(name, "translation")]
        np.testing.assert_allclose(t, [f["timestamp_s"] for f in ego], atol=1e-6)
        np.testing.assert_allclose(xyz, poses[:, :3, 3], atol=1e-4)
        _, q = track[(name, "rotation")]
        for f in range(len(poses)):
            x, y, z, w = q[f]
            R = trimesh.transformations.quaternion_matrix([w, x, y, z])[:3, :3]
            np.testing.assert_allclose(R, poses[f][:3, :3], atol=1e-5)
    sc = trimesh.load_scene(export / SEQ / "scene.glb", process=False)  # still a scene trimesh reads
    assert sc.has_camera
