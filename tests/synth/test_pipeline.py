"""Rendered datasets: contract, cross-camera consistency, masks, texture, determinism, shards, resume, bad input."""

import json
import shutil

import cv2
import numpy as np
import pytest

from synth.cli import main as synth_main
from synth.config import load_data_config
from synth.verify import verify_dataset
from synth.open import open_dataset
from synth.files import DatasetError, read_depth_exr, write_depth_exr
from synth.merge import merge_datasets
from synth.preview import key_row
from synth.render import OutputFolderError, render_dataset

QUIET = dict(progress=False, log=lambda *a: None)


def _consistency(ds, seq, i, j):
    """Relative |z_i->j - depth_j| / z for camera i's pixels that land inside camera j."""
    ci, cj = ds.cameras[i], ds.cameras[j]
    out = []
    for f in range(ds.n_frames(seq)):
        di, dj = ds.read_depth(seq, ci.name, f), ds.read_depth(seq, cj.name, f)
        v, u = np.nonzero((di > 0) & ds.mask(ci.name))
        z = di[v, u].astype(np.float64)
        P = np.linalg.inv(ci.K) @ np.stack([u + 0.5, v + 0.5, np.ones_like(z)]) * z
        T = np.linalg.inv(cj.T_ego_cam) @ ci.T_ego_cam
        Q = T[:3, :3] @ P + T[:3, 3:]
        Q_keep = Q[2] > 0.1
        Q = Q[:, Q_keep]
        uv = cj.K @ Q
        uj, vj = uv[0] / uv[2], uv[1] / uv[2]
        ins = (uj >= 1) & (uj < cj.width - 1) & (vj >= 1) & (vj < cj.height - 1)
        if not ins.any():
            continue
        mx = (uj[ins] - 0.5).astype(np.float32)[None]
        my = (vj[ins] - 0.5).astype(np.float32)[None]
        # inverse depth is affine in the pixel coordinates on a plane: interpolate it, not depth
        inv_j = np.where(dj > 0, 1.0 / np.maximum(dj, 1e-6), 0).astype(np.float32)
        inv_s = cv2.remap(inv_j, mx, my, cv2.INTER_LINEAR)[0].astype(np.float64)
        d_s = np.where(inv_s > 0, 1.0 / np.maximum(inv_s, 1e-12), 0)
        m_s = cv2.remap(ds.mask(cj.name).astype(np.float32), mx, my, cv2.INTER_NEAREST)[0] > 0.5
        zq = Q[2, ins]
        # mutual visibility: j's nearest pixel, back-projected with j's depth, returns to i's pixel (< 1 px)
        qu, qv = np.floor(uj[ins]).astype(int), np.floor(vj[ins]).astype(int)
        dq = dj[qv, qu].astype(np.float64)
        Xj = np.linalg.inv(cj.K) @ np.stack([qu + 0.5, qv + 0.5, np.ones_like(dq)]) * dq
        Ti = np.linalg.inv(T)
        Xi = Ti[:3, :3] @ Xj + Ti[:3, 3:]
        pi = ci.K @ Xi
        back_u, back_v = pi[0] / np.maximum(pi[2], 1e-9), pi[1] / np.maximum(pi[2], 1e-9)
        src = np.stack([u + 0.5, v + 0.5])[:, Q_keep][:, ins]
        mutual = (np.hypot(back_u - src[0], back_v - src[1]) < 1.0) & (dq > 0)
        keep = (d_s > 0) & m_s & mutual
        out.append(np.abs(d_s[keep] - zq[keep]) / zq[keep])
    return np.concatenate(out) if out else np.zeros(0)


def test_contract_and_verify(tiny_dataset, tiny_config):
    ds = open_dataset(tiny_dataset, verify=True)
    m = ds.manifest
    assert m["schema_version"] == 1 and m["seed"] == tiny_config.seed
    assert ds.camera_names == ["CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT",
                               "CAM_FRONT_LEFT"]
    splits = [ds.split(s) for s in ("train", "val", "test")]
    assert sorted(sum(splits, [])) == ds.sequences and all(splits)
    seq = ds.sequences[0]
    rgb, depth = ds.read_rgb(seq, "CAM_FRONT", 0), ds.read_depth(seq, "CAM_FRONT", 0)
    assert rgb.shape == (64, 96, 3) and rgb.dtype == np.uint8
    assert depth.shape == (64, 96) and depth.dtype == np.float32
    assert (depth == 0).any() and (depth > 0).mean() > 0.5       # sky is 0, ground everywhere below
    ego = ds.ego(seq)
    assert len(ego) == ds.n_frames(seq)
    T = ds.T_world_ego(seq)
    speed = np.linalg.norm(np.diff(T[:, :3, 3], axis=0), axis=1) * ds.fps
    assert np.all(speed > 2.0) and np.all(speed < 40.0)          # plausible driving speeds in m/s
    assert set(ego[0]["lighting"]["camera_gain"]) == set(ds.camera_names)
    assert verify_dataset(tiny_dataset) == []
    assert synth_main(["verify", str(tiny_dataset)]) == 0


def test_cross_camera_consistency(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    seq = ds.sequences[0]
    checked = 0
    for a, b in ds.neighbours:
        for i, j in ((a, b), (b, a)):
            rel = _consistency(ds, seq, i, j)
            if rel.size > 50:
                assert np.median(rel) <= 0.005, (ds.camera_names[i], ds.camera_names[j], np.median(rel))
                checked += 1
    assert checked >= 4


def test_measured_overlap_follows_target(tiny_dataset):
    m = open_dataset(tiny_dataset).manifest["overlap"]
    front = m["per_pair_measured"]["CAM_FRONT-CAM_FRONT_RIGHT"]
    assert front["target"] == pytest.approx(0.25)
    assert 0.12 < front["measured"] < 0.35
    side = m["per_pair_measured"]["CAM_FRONT_RIGHT-CAM_BACK_RIGHT"]
    assert side["target"] < 0 and side["measured"] < 0.02      # a gap in spacing mode


def test_masks_exact_and_placed(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    ego_frac = {n: 1 - ds.mask(n).mean() for n in ds.camera_names}
    assert ego_frac["CAM_FRONT"] == 0.0
    assert sum(v > 0.02 for v in ego_frac.values()) >= 2
    # the ego body is rigid with the rig: its pixels hold the same depth in every frame
    seq = ds.sequences[0]
    cam = max(ego_frac, key=ego_frac.get)
    body = ~ds.mask(cam)
    d0, d1 = ds.read_depth(seq, cam, 0), ds.read_depth(seq, cam, ds.n_frames(seq) - 1)
    assert np.all(d0[body] > 0) and np.allclose(d0[body], d1[body], rtol=1e-5)


def test_texture_has_local_contrast(tiny_dataset):
    ds = open_dataset(tiny_dataset)
    fracs = []
    for seq in ds.sequences:
        for cam in ds.camera_names:
            g = cv2.cvtColor(ds.read_rgb(seq, cam, 0), cv2.COLOR_RGB2GRAY).astype(np.float32)
            mean = cv2.blur(g, (3, 3))
            std = np.sqrt(np.maximum(cv2.blur(g * g, (3, 3)) - mean * mean, 0))
            sel = (ds.read_depth(seq, cam, 0) > 0) & ds.mask(cam)
            fracs.append((std[sel] > 2.0).mean())
    assert np.mean(fracs) > 0.5        # most non-sky pixels have local contrast


def test_lighting_differs_between_cameras(tiny_dataset):
    ego = open_dataset(tiny_dataset).ego(open_dataset(tiny_dataset).sequences[0])
    g0 = np.array(list(ego[0]["lighting"]["camera_gain"].values()))
    g1 = np.array(list(ego[1]["lighting"]["camera_gain"].values()))
    assert np.ptp(g0[:, 1]) > 0.01          # exposure differs between cameras
    assert not np.allclose(g0, g1)          # flicker over time


def test_exr_roundtrip(tmp_path):
    d = np.random.default_rng(0).uniform(0.5, 300.0, (7, 11)).astype(np.float32)
    d[0, 0] = 0.0
    write_depth_exr(tmp_path / "d.exr", d)
    assert np.array_equal(read_depth_exr(tmp_path / "d.exr"), d)
    with pytest.raises(ValueError, match="float32"):
        write_depth_exr(tmp_path / "e.exr", d.astype(np.float64))
    with pytest.raises(DatasetError, match="x.exr"):
        read_depth_exr(tmp_path / "x.exr")


def test_determinism_and_seed(tiny_dataset, tiny_config, tmp_path):
    render_dataset(tiny_config, tmp_path / "again", **QUIET)
    a = json.loads((tiny_dataset / "manifest.json").read_text())["files"]
    b = json.loads((tmp_path / "again" / "manifest.json").read_text())["files"]
    assert a == b                                              # byte-identical files
    other = tiny_config.model_copy(update={"seed": 1})
    render_dataset(other, tmp_path / "seed1", **QUIET)
    c = json.loads((tmp_path / "seed1" / "manifest.json").read_text())["files"]
    differ = [k for k in a if k.endswith(".png") and a[k] != c.get(k)]
    assert len(differ) > 0.9 * sum(k.endswith(".png") for k in a)


def test_shards_merge_and_resume(tiny_dataset, tiny_config, tmp_path):
    full = json.loads((tiny_dataset / "manifest.json").read_text())
    s0, s1 = tmp_path / "s0", tmp_path / "s1"
    r0 = render_dataset(tiny_config, s0, shard=(0, 2), **QUIET)
    assert r0["rendered_sequences"] == 2 and not r0["complete"]
    assert not (s0 / "manifest.json").exists()                 # incomplete: no manifest
    with pytest.raises(DatasetError, match="manifest.json"):
        open_dataset(s0)
    render_dataset(tiny_config, s1, shard=(1, 2), **QUIET)
    res = merge_datasets([s0, s1], tmp_path / "merged")
    assert res["complete"]
    merged = json.loads((tmp_path / "merged" / "manifest.json").read_text())
    assert merged["files"] == full["files"] and merged["splits"] == full["splits"]
    # resume: shard 0's folder plus an interrupted sequence -> the full render skips what is complete
    (s0 / "seq_00001.partial").mkdir()
    (s0 / "seq_00001.partial" / "junk").write_text("x")
    r = render_dataset(tiny_config, s0, **QUIET)
    assert r["skipped_sequences"] == 2 and r["rendered_sequences"] == 1 and r["complete"]
    assert not (s0 / "seq_00001.partial").exists()
    assert json.loads((s0 / "manifest.json").read_text())["files"] == full["files"]


def test_verify_catches_damage(tiny_dataset, tmp_path):
    d = tmp_path / "copy"
    shutil.copytree(tiny_dataset, d)
    ds = open_dataset(d)
    seq = ds.sequences[0]
    png = ds.rgb_path(seq, "CAM_BACK", 1)
    exr = ds.depth_path(seq, "CAM_FRONT", 2)
    png.write_bytes(png.read_bytes()[:100])                    # truncated
    b = bytearray(exr.read_bytes())
    b[-10] ^= 0xFF                                             # altered
    exr.write_bytes(bytes(b))
    (d / "masks" / "CAM_BACK_LEFT.png").unlink()               # missing
    problems = verify_dataset(d)
    assert any(str(png) in p for p in problems) and any(str(exr) in p for p in problems)
    assert any("CAM_BACK_LEFT.png" in p and "missing" in p for p in problems)
    assert synth_main(["verify", str(d)]) == 1
    with pytest.raises(DatasetError, match="checksum"):
        open_dataset(d, verify=True)
    m = json.loads((d / "manifest.json").read_text())
    m["schema_version"] = 99
    (d / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(DatasetError, match="schema_version 99"):
        open_dataset(d)


def test_bad_output_folders_write_nothing(tiny_dataset, tiny_config, tmp_path, capsys):
    other = tiny_config.model_copy(update={"seed": 5})
    before = sorted(p.name for p in tiny_dataset.iterdir())
    with pytest.raises(OutputFolderError, match="another dataset.*seed"):
        render_dataset(other, tiny_dataset, **QUIET)
    assert sorted(p.name for p in tiny_dataset.iterdir()) == before
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "notes.txt").write_text("mine")
    assert synth_main(["render", "configs/data/tiny.yaml", "--out", str(junk), "--no-progress"]) == 2
    assert "holds no synth dataset" in capsys.readouterr().err
    assert sorted(p.name for p in junk.iterdir()) == ["notes.txt"]


@pytest.mark.parametrize("args, needle", [
    (["rig.overlap=0.9"], "rig.overlap"),
    (["camera.width=abc"], "camera.width"),
    (["rig.nope=1"], "rig.nope"),
    (["--shard", "3/2"], "--shard"),
    (["--workers", "0"], "--workers"),
])
def test_cli_bad_input(tmp_path, capsys, args, needle):
    out = tmp_path / "o"
    assert synth_main(["render", "configs/data/tiny.yaml", "--out", str(out), "--no-progress"] + args) == 2
    assert needle in capsys.readouterr().err
    assert not out.exists()


def test_preview_sheet(tiny_dataset, tmp_path):
    assert synth_main(["preview", str(tiny_dataset), "--out", str(tmp_path / "s.png")]) == 0
    img = cv2.imread(str(tmp_path / "s.png"))
    # tiny has the default labels (semantic, instance; no flow): the class tile more per camera, a legend (3 lines)
    assert img.shape == (6 * 64 + 54 + key_row(5 * 96, flow=False).shape[0], 5 * 96, 3)  # + the depth colour bar
    assert synth_main(["preview", str(tiny_dataset), "--out", str(tmp_path / "t.png"), "--frame", "99"]) == 2
