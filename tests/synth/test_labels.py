"""Ground-truth labels (issue 40): semantic classes, object ids, forward flow and the mover mask of a rendered
dataset, checked against its depth, its ego masks, the other cameras and the next frame's images."""
from __future__ import annotations

import json
import shutil

import cv2
import numpy as np
import pytest

from scenes.labels import CLASS, CLASSES, MATERIAL_CLASS, class_table, instance_table
from scenes.model import Mesh
from scenes.textures import LAYER, MATERIALS
from synth.verify import integrity_record, verify_dataset
from synth.files import DatasetError
from synth.labels import forward_flow, instance_map, semantic_map
from synth.open import open_dataset


@pytest.fixture(scope="module")
def ds(flow_dataset):
    return open_dataset(flow_dataset)


def test_the_defaults_write_semantic_and_instance_maps_but_no_flow(tiny_dataset):
    d = open_dataset(tiny_dataset)
    assert d.label_kinds == ("semantic", "instance")
    assert not list(tiny_dataset.rglob("*.flow.exr")) and len(list(tiny_dataset.rglob("*.instance.png"))) == 108
    with pytest.raises(DatasetError, match=r"has no flow labels .*labels\.flow=true"):
        d.read_movers(d.sequences[0], "CAM_FRONT", 0)


def test_every_material_has_a_class_and_the_table_is_in_the_manifest(ds):
    assert len(MATERIAL_CLASS) == len(MATERIALS)
    assert ds.label_kinds == ("semantic", "instance", "flow", "mesh")
    assert ds.classes == class_table()
    assert [c["name"] for c in ds.classes][:2] == ["sky", "road"]
    assert MATERIAL_CLASS[LAYER["asphalt"]] == CLASS["road"] and MATERIAL_CLASS[LAYER["foliage"]] == CLASS["vegetation"]


def test_semantic_map_rules():
    layer = np.array([[-1, LAYER["asphalt"], LAYER["car_paint"], LAYER["barrier_concrete"]]])
    inst = np.array([[0, 0, 7, 3]])
    ego = np.array([[False, False, False, False]])
    depth = np.array([[0.0, 5.0, 6.0, 7.0]], np.float32)
    classes = np.zeros(8, np.uint8)
    classes[7] = CLASS["moving_vehicle"]
    classes[3] = CLASS["building"]  # an object of barrier concrete that names itself a building
    sem = semantic_map(layer, inst, ego, depth, classes)
    assert sem.tolist() == [[CLASS["sky"], CLASS["road"], CLASS["moving_vehicle"], CLASS["building"]]]
    assert semantic_map(layer, inst, ~ego, depth, classes).tolist()[0][1:] == [CLASS["ego"]] * 3
    assert instance_map(inst, ego, depth).tolist() == [[0, 0, 7, 3]] and instance_map(inst, ego, depth).dtype == np.uint16


def test_instances_survive_the_static_merge():
    a = Mesh.merge([Mesh.empty(), _tri().tagged(3), _tri()])
    assert a.instances.tolist() == [3, 3, 3, 0, 0, 0]
    assert a.transformed(np.eye(4)).instances.tolist() == a.instances.tolist()
    with pytest.raises(ValueError, match="instance"):
        _tri().tagged(-1)


def _tri() -> Mesh:
    z = np.zeros((3, 3), np.float32)
    return Mesh(np.eye(3, dtype=np.float32), z + [0, 0, 1], np.zeros((3, 2), np.float32), np.zeros(3, np.int32),
                np.ones((3, 3), np.float32), np.array([[0, 1, 2]], np.uint32))


def test_class_and_instance_maps_agree_with_depth_and_the_ego_mask(ds):
    n_obj = 0
    for seq in ds.sequences:
        for cam in ds.camera_names:
            ego = ~ds.mask(cam)
            for f in range(ds.n_frames(seq)):
                d, sem, inst = ds.read_depth(seq, cam, f), ds.read_semantic(seq, cam, f), ds.read_instance(seq, cam, f)
                assert np.array_equal(sem == CLASS["sky"], d == 0)  # sky is exactly where there is no depth
                assert np.array_equal(sem == CLASS["ego"], ego)  # the ego class is the ego mask
                assert not inst[(d == 0) | ego].any()
                n_obj += int((inst > 0).sum())
    assert n_obj > 1000


def test_instance_table_classes_match_the_maps_and_movers_carry_poses(ds):
    seq = ds.sequences[0]
    rows = {r["id"]: r for r in ds.instances(seq)}
    movers = [r for r in rows.values() if r["moving"]]
    assert movers and all(np.asarray(r["T_world_obj"]).shape == (ds.n_frames(seq), 4, 4) for r in movers)
    names = [c[0] for c in CLASSES]
    agree = total = 0
    for cam in ds.camera_names:
        sem, inst = ds.read_semantic(seq, cam, 0), ds.read_instance(seq, cam, 0)
        for i in np.unique(inst[inst > 0]):
            total += 1
            agree += names[int(np.bincount(sem[inst == i]).argmax())] == rows[int(i)]["class"]
    assert total > 5 and agree == total


def test_an_object_has_one_id_in_every_camera_that_sees_it(ds):
    """A pixel of camera i seen by neighbour j (its 3-D point projects into j and passes j's z-test) carries the
    same object id in both, away from object edges (where a 96x64 pixel holds two objects)."""
    from synth.overlap import overlap_mask

    same = seen = 0
    for seq in ds.sequences:
        for a, b in ds.neighbours:
            ca, cb = ds.cameras[a], ds.cameras[b]
            f = 1
            da, db = ds.read_depth(seq, ca.name, f), ds.read_depth(seq, cb.name, f)
            ia, ib = ds.read_instance(seq, ca.name, f), ds.read_instance(seq, cb.name, f)
            k3 = np.ones((3, 3), np.uint8)
            inner = cv2.dilate(ib, k3) == cv2.erode(ib, k3)  # j's pixels whose 3x3 neighbourhood is one object
            ov = overlap_mask(da, ca.K, ca.T_ego_cam, db, cb.K, cb.T_ego_cam, ds.mask(ca.name), ds.mask(cb.name))
            v, u = np.nonzero(ov & (ia > 0))
            if not len(u):
                continue
            p = np.linalg.inv(ca.K) @ np.stack([u + 0.5, v + 0.5, np.ones(len(u))]) * da[v, u]
            T = np.linalg.inv(cb.T_ego_cam) @ ca.T_ego_cam
            q = cb.K @ (T[:3, :3] @ p + T[:3, 3:])
            ub, vb = np.floor(q[0] / q[2]).astype(int), np.floor(q[1] / q[2]).astype(int)
            ok = (ub >= 0) & (ub < cb.width) & (vb >= 0) & (vb < cb.height)
            ok[ok] &= inner[vb[ok], ub[ok]] & (np.abs(db[vb[ok], ub[ok]] - q[2][ok]) < 0.03 * q[2][ok])  # that surface
            seen += int(ok.sum())
            same += int((ia[v[ok], u[ok]] == ib[vb[ok], ub[ok]]).sum())
    assert seen > 200
    assert same == seen


def _photometric(ds, flow_of) -> dict[str, list[float]]:
    """Mean |I_t - I_{t+1} warped by a flow| over valid static and mover pixels, for `flow_of(seq, cam, f)`."""
    out = {"static": [0.0, 0.0, 0], "mover": [0.0, 0.0, 0]}
    for seq in ds.sequences:
        for cam in ds.camera_names:
            scene = ds.mask(cam)
            for f in range(ds.n_frames(seq) - 1):
                flow, valid = ds.read_flow(seq, cam, f)
                mov = ds.read_movers(seq, cam, f)
                i0 = ds.read_rgb(seq, cam, f).astype(np.float32)
                i1 = ds.read_rgb(seq, cam, f + 1).astype(np.float32)
                fl = flow_of(seq, cam, f, flow)
                v, u = np.mgrid[0:i0.shape[0], 0:i0.shape[1]].astype(np.float32)
                warped = cv2.remap(i1, u + fl[..., 0], v + fl[..., 1], cv2.INTER_LINEAR)
                e_flow, e_id = np.abs(warped - i0).mean(-1), np.abs(i1 - i0).mean(-1)
                for k, sel in (("static", valid & ~mov & scene), ("mover", valid & mov)):
                    out[k][0] += float(e_flow[sel].sum())
                    out[k][1] += float(e_id[sel].sum())
                    out[k][2] += int(sel.sum())
    return out


def test_warping_the_next_frame_by_the_flow_reproduces_this_one(ds):
    """On valid static pixels and on mover pixels, frame t+1 warped back by the flow matches frame t much better
    than the identity; on movers, a flow from ego motion alone does not."""
    r = _photometric(ds, lambda seq, cam, f, flow: flow)
    for k in ("static", "mover"):
        err_flow, err_id, n = r[k]
        assert n > (100 if k == "mover" else 10000), (k, n)
        assert err_flow / n < 0.5 * err_id / n, (k, err_flow / n, err_id / n)

    def ego_only(seq, cam, f, flow):  # the same points moved as if every object stood still
        c = ds.camera_names.index(cam)
        K, T = ds.cameras[c].K, ds.cameras[c].T_ego_cam
        Tw = ds.T_world_ego(seq)
        d0, d1 = ds.read_depth(seq, cam, f), ds.read_depth(seq, cam, f + 1)
        i0, i1 = ds.read_instance(seq, cam, f), ds.read_instance(seq, cam, f + 1)
        fl, _ = forward_flow(d0, i0, ~ds.mask(cam), K, Tw[f] @ T, Tw[f + 1] @ T, {}, d1, i1)
        return np.where(ds.read_movers(seq, cam, f)[..., None], fl, flow)

    e = _photometric(ds, ego_only)
    assert e["mover"][0] > 1.5 * r["mover"][0]  # ego motion alone fails on movers


def test_verify_checks_the_label_files(flow_dataset, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(flow_dataset, data)
    assert verify_dataset(data) == []
    seq = sorted(p.name for p in data.glob("seq_*"))[0]
    (data / seq / "CAM_FRONT" / "000001.flow.exr").write_bytes(b"not an exr")
    (data / seq / "CAM_BACK" / "000002.instance.png").unlink()
    problems = "\n".join(verify_dataset(data))
    assert "000001.flow.exr: checksum mismatch" in problems and "000002.instance.png: missing" in problems
    m = json.loads((data / "manifest.json").read_text())
    del m["files"][f"{seq}/CAM_FRONT/000000.semantic.png"]
    m["integrity"] = integrity_record({k: v for k, v in m.items() if k != "integrity"},
                                      json.loads((data / "rig.json").read_text()))
    (data / "manifest.json").write_text(json.dumps(m))
    assert "000000.semantic.png: not listed in the manifest" in "\n".join(verify_dataset(data))


def _strip_labels(src, dst) -> None:
    """`src` as it would have been rendered before labels existed: no label file, no `labels` record."""
    shutil.copytree(src, dst, ignore=shutil.ignore_patterns("*.semantic.png", "*.instance.png", "*.flow.exr",
                                                            "*.flow_valid.png", "*.movers.png", "instances.json",
                                                            "world_mesh.npz"))
    m = json.loads((dst / "manifest.json").read_text())
    del m["labels"]
    m["files"] = {k: v for k, v in m["files"].items() if (dst / k).is_file()}
    m["integrity"] = integrity_record({k: v for k, v in m.items() if k != "integrity"},
                                      json.loads((dst / "rig.json").read_text()))
    (dst / "manifest.json").write_text(json.dumps(m))


def test_a_dataset_rendered_before_labels_reads_trains_and_evaluates(flow_dataset, tmp_path, capsys):
    import mcdp.trainer  # noqa: F401  torch before any in-process GL (tests/mcdp/test_cli.py)
    from mcdp.evaluate import evaluate
    from mcdp.priors import constant_depth_predictor
    from study.method_commands import main

    old = tmp_path / "old"
    _strip_labels(flow_dataset, old)
    assert verify_dataset(old) == []
    ds = open_dataset(old)
    assert ds.label_kinds == () and ds.classes == []
    with pytest.raises(DatasetError, match=r"has no semantic labels .*labels\.semantic=true"):
        ds.read_semantic(ds.sequences[0], "CAM_FRONT", 0)
    with pytest.raises(DatasetError, match="has no flow labels"):
        ds.read_flow(ds.sequences[0], "CAM_FRONT", 0)
    m = evaluate(ds, constant_depth_predictor(ds, 10.0), "test", progress=False)
    assert "classes" not in m["stages"]["final"]["median"] and "abs_rel" in m["stages"]["final"]["median"]["mean"]
    run = tmp_path / "run"
    assert main(["train", "configs/train/tiny/mono2.yaml", "--data", str(old), "--out", str(run), "--no-progress",
                 "train.steps=1"]) == 0
    assert main(["eval", str(run), "--data", str(old), "--out", str(tmp_path / "ev.json"), "--no-progress"]) == 0
    metrics = json.loads((tmp_path / "ev.json").read_text())
    assert "classes" not in metrics["stages"]["final"]["median"]


def test_eval_by_class_and_motion_and_the_hole_on_movers(ds):
    """Ground truth as the prediction scores 0 everywhere; push every mover pixel to 10x its depth and only the
    moving rows move, and the hole holds most moving vehicles against no parked one."""
    from mcdp.evaluate import evaluate

    def predict(seq, f, movers_far=False):
        out = []
        for cam in ds.camera_names:
            d = ds.read_depth(seq, cam, f).astype(np.float64)
            d = np.where(d > 0, d, 50.0)
            if movers_far:
                d = np.where(ds.read_semantic(seq, cam, f) == CLASS["moving_vehicle"], 10 * d, d)
            out.append(d)
        return {"init": np.stack(out)}

    full = evaluate(ds, predict, "test", progress=False)
    m = full["stages"]["final"]["none"]
    from mcdp.tables import format_tables

    text = format_tables(full)
    assert "\nroad " in text and "\nmoving " in text and "movers beyond 2x their depth:" in text
    assert set(m["classes"]) == {"road", "building", "vehicle", "vehicle_parked", "vehicle_moving", "vegetation",
                                 "other"}
    assert m["motion"]["static"]["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert m["classes"]["road"]["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert m["holes"]["moving"] == 0.0
    far = evaluate(ds, lambda s, f: predict(s, f, True), "test", progress=False)["stages"]["final"]["none"]
    assert far["motion"]["static"]["abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert far["motion"]["moving"]["abs_rel"] > 1.0 and far["classes"]["road"]["abs_rel"] == pytest.approx(0, abs=1e-6)
    assert far["holes"]["moving"] > 0.5 and far["holes"]["moving_pixels"] > 0  # below 1: the clamp at max_depth
    assert far["holes"]["parked"] in (0.0,) or np.isnan(far["holes"]["parked"])
    assert set(far["road_bands"]) == set(m["bands"])


def test_instance_table_of_a_built_scene(tiny_config):
    from synth.pipeline import build_sequence_scene

    scene = build_sequence_scene(tiny_config, 0)
    rows = instance_table(scene)
    assert [r["id"] for r in rows] == list(range(1, len(rows) + 1))
    assert sum(r["moving"] for r in rows) == len(scene.movers)
    assert {r["class"] for r in rows if r["moving"]} <= {"moving_vehicle"}
