"""Label kind ``mesh`` (`synth.world_mesh`): ``<seq>/world_mesh.npz`` is written by a render with
``labels.mesh=true`` (off by default: every config hash and every rendered file as before), checked by
`synth verify`, and read back equal to the scene model the render drew; its bytes are a function of the scene."""
from __future__ import annotations

import io
import json
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from synth.files import DatasetError
from synth.world_mesh import ColoredMesh, WorldMesh, read_world_mesh, world_mesh_bytes

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"


def _tri(shift: float = 0.0) -> ColoredMesh:
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32) + shift
    return ColoredMesh(pos, np.array([[0, 1, 2]], np.uint32), np.tile(np.float32([0, 0, 1]), (3, 1)),
                       np.full((3, 3), 200, np.uint8))


def _toy(frames: int = 2) -> WorldMesh:
    T = np.repeat(np.eye(4)[None], frames, axis=0)
    T[:, 0, 3] = np.arange(frames)
    return WorldMesh(_tri(), (("car_00", _tri(5.0), T),), _tri(-1.0))


def test_the_mesh_key_is_off_and_leaves_every_hash_as_it_was():
    from corelib.configlib import config_hash
    from synth.config import load_data_config

    for extra in ([], ["labels.flow=true"]):
        base = load_data_config(TINY, extra)
        assert base.labels.mesh is False
        assert config_hash(load_data_config(TINY, extra + ["labels.mesh=false"])) == config_hash(base)
        assert config_hash(load_data_config(TINY, extra + ["labels.mesh=true"])) != config_hash(base)


def test_a_default_render_writes_no_mesh(tiny_dataset):
    from synth.open import open_dataset

    assert "mesh" not in open_dataset(tiny_dataset).label_kinds
    assert not list(tiny_dataset.rglob("world_mesh.npz"))


def test_the_mesh_is_written_verified_and_read_back_equal_to_the_scene(flow_dataset):
    from synth.cli import main
    from synth.gltf_export import rebuild_scene
    from synth.label_kinds import label_kind
    from synth.open import open_dataset
    from synth.render import make_ego_mesh
    from synth.world_mesh import vertex_colors, world_mesh

    m = json.loads((flow_dataset / "manifest.json").read_text())
    assert m["labels"]["mesh"] == label_kind("mesh").about
    assert all(f"{seq}/world_mesh.npz" in m["files"] for seq in m["sequences"])
    assert main(["verify", str(flow_dataset)]) == 0
    ds = open_dataset(flow_dataset)
    cfg, scene = rebuild_scene(ds, "seq_00001")
    wm = ds.read_label("mesh", "seq_00001")
    for got, want in ((wm.static, scene.static), (wm.ego, make_ego_mesh(cfg))):
        np.testing.assert_array_equal(got.positions, want.positions)
        np.testing.assert_array_equal(got.indices, want.indices)
        np.testing.assert_array_equal(got.normals, want.normals)
        np.testing.assert_array_equal(got.colors, vertex_colors(want, scene.textures))
    assert len(wm.static.positions) > 1000 and len(np.unique(wm.static.colors, axis=0)) > 5
    assert [n for n, _, _ in wm.movers] == [mv.name for mv in scene.movers] and wm.movers
    for (_, mesh, T), mv in zip(wm.movers, scene.movers):
        np.testing.assert_array_equal(T, mv.T_world_obj)
        np.testing.assert_array_equal(mesh.positions, mv.mesh.positions)
    # the file is a function of the scene: rebuilt now, the same bytes as written at render time
    assert (flow_dataset / "seq_00001" / "world_mesh.npz").read_bytes() == \
        world_mesh_bytes(world_mesh(scene, make_ego_mesh(cfg)))


def test_verify_reads_the_mesh_file_back(flow_dataset, tmp_path):
    from synth.verify import verify_dataset

    data = tmp_path / "data"
    shutil.copytree(flow_dataset, data)
    bad = _toy(frames=6)
    bad = WorldMesh(ColoredMesh(bad.static.positions, np.array([[0, 1, 7]], np.uint32), bad.static.normals,
                                bad.static.colors), bad.movers, bad.ego)
    (data / "seq_00000" / "world_mesh.npz").write_bytes(world_mesh_bytes(bad))
    (data / "seq_00002" / "world_mesh.npz").unlink()
    problems = "\n".join(verify_dataset(data))
    assert "seq_00000/world_mesh.npz: checksum mismatch" in problems
    assert "seq_00000/world_mesh.npz: static.indices refers to vertex 7; the mesh has 3" in problems
    assert "seq_00002/world_mesh.npz: missing" in problems


def test_the_file_is_deterministic_and_read_back_whole(tmp_path):
    wm = _toy()
    data = world_mesh_bytes(wm)
    assert data == world_mesh_bytes(_toy())
    assert {i.date_time for i in zipfile.ZipFile(io.BytesIO(data)).infolist()} == {(1980, 1, 1, 0, 0, 0)}
    p = tmp_path / "world_mesh.npz"
    p.write_bytes(data)
    back = read_world_mesh(p, n_frames=2)
    np.testing.assert_array_equal(back.movers[0][2], wm.movers[0][2])
    assert back.movers[0][0] == "car_00" and back.ego.positions.tolist() == wm.ego.positions.tolist()
    with np.load(p, allow_pickle=False) as npz:  # an ordinary npz
        assert npz["static.indices"].tolist() == [[0, 1, 2]]


@pytest.mark.parametrize("what, message", [
    ("frames", r"mover0.T_world_obj must be \(3, 4, 4\)"),
    ("name", r"movers\[0\] 'a/b' must be a distinct name"),
    ("pickle", r"movers.npy is not readable \(Object arrays cannot be loaded when allow_pickle=False"),
    ("zip", r"not a world mesh file"),
    ("colors", r"static.colors must be an \(N, 3\) uint8 array"),
])
def test_a_bad_file_is_refused_naming_it(tmp_path, what, message):
    p = tmp_path / "world_mesh.npz"
    wm = _toy()
    if what == "name":
        wm = WorldMesh(wm.static, (("a/b",) + wm.movers[0][1:],), wm.ego)
    if what == "colors":
        wm = WorldMesh(ColoredMesh(*(wm.static.positions, wm.static.indices, wm.static.normals,
                                     wm.static.colors.astype(np.float32))), wm.movers, wm.ego)
    data = world_mesh_bytes(wm)
    if what == "pickle":  # an object array in place of the names: never unpickled
        buf = io.BytesIO()
        with zipfile.ZipFile(io.BytesIO(data)) as src, zipfile.ZipFile(buf, "w") as dst:
            for i in src.infolist():
                if i.filename == "movers.npy":
                    one = io.BytesIO()
                    np.lib.format.write_array(one, np.array([{"x": 1}], dtype=object), allow_pickle=True)
                    dst.writestr(i.filename, one.getvalue())
                else:
                    dst.writestr(i, src.read(i))
        data = buf.getvalue()
    p.write_bytes(b"not a zip" if what == "zip" else data)
    with pytest.raises(DatasetError, match=message) as e:
        read_world_mesh(p, n_frames=3 if what == "frames" else 2)
    assert str(p) in str(e.value)
