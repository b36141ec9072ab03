"""`mcdp predict --rrd`: every stage's predicted depth, abs_rel image and coloured points beside the ground truth
(with the blueprint, the world mesh and the trajectory of `synth view`),
read back with Rerun's own chunk reader and `rerun rrd verify`. Skips without the viz extra."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun", reason="the viz extra is not here: it is in .venv-viz (tests/test_viz_env.py)")

import mcdp.trainer  # noqa: F401,E402  torch before the in-process GL renderer (tests/mcdp/test_cli.py)
from study.method_commands import main  # noqa: E402

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny"


def read_rrd(path) -> dict[str, list[tuple[int | None, dict]]]:
    """{entity: [(time ns or None, {component: value})]} through `rerun.chunk.RrdReader`."""
    from rerun.chunk import RrdReader

    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream():
        rb = chunk.to_record_batch()
        cols = {n: rb.column(n).to_pylist() for n in rb.schema.names if ":" in n}
        times = rb.column("time").cast("int64").to_pylist() if "time" in rb.schema.names else [None] * rb.num_rows
        for i in range(rb.num_rows):
            out.setdefault(chunk.entity_path, []).append((times[i], {k: v[i] for k, v in cols.items()}))
    return out


def image_of(row: dict, prefix: str) -> np.ndarray:
    fmt = row[f"{prefix}:format"][0]
    return np.asarray(row[f"{prefix}:buffer"][0], np.uint8).view(np.float32).reshape(fmt["height"], fmt["width"])


@pytest.fixture(scope="module")
def run(tiny_dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("rec") / "run"
    assert main(["train", str(TINY / "mcdp_m1.yaml"), "--data", str(tiny_dataset), "--out", str(run),
                 "--no-progress", "train.steps=2", "train.threads=1"]) == 0
    return run


def test_predict_rrd_holds_every_stage_beside_the_ground_truth(run, tiny_dataset, tmp_path, one_thread,
                                                              check_blueprint):
    from mcdp.predict import Predictor
    from mcdp.recording import abs_rel_image
    from synth.open import open_dataset

    out = tmp_path / "pred.rrd"
    assert main(["predict", str(run), "--data", str(tiny_dataset), "--rrd", str(out), "--max-samples", "2",
                 "--no-progress"]) == 0
    res = subprocess.run([sys.executable, "-m", "rerun", "rrd", "verify", str(out)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0 and "verified without error" in res.stdout + res.stderr
    ds = open_dataset(tiny_dataset)
    seq = ds.split("test")[0]
    pred = Predictor(run, ds)
    ents = read_rrd(out)
    times = [round(ds.ego(seq)[f]["timestamp_s"] * 1e9) for f in (0, 1)]
    for f, t in zip((0, 1), times):
        want = pred.predict(seq, f)
        assert list(want) == ["init", "refine1"]
        for stage, d in want.items():
            for c, cam in enumerate(ds.camera_names):
                rows = dict(ents[f"/world/ego/{cam}/pred/{stage}/depth"])
                np.testing.assert_allclose(image_of(rows[t], "DepthImage"), d[c], rtol=1e-6)
                gt = image_of(dict(ents[f"/world/ego/{cam}/depth"])[t], "DepthImage")
                np.testing.assert_array_equal(gt, ds.read_depth(seq, cam, f))
                err = image_of(dict(ents[f"/world/ego/{cam}/pred/{stage}/abs_rel"])[t], "Image")
                np.testing.assert_allclose(err, abs_rel_image(d[c], gt, ds.mask(cam)), rtol=1e-5, atol=1e-7)
            pts = dict(ents[f"/world/ego/pred/{stage}/points"])[t]
            colors = np.asarray(pts["Points3D:colors"], np.uint32)
            assert len(colors) == len(pts["Points3D:positions"]) and len(np.unique(colors)) > 10  # the RGB's
    check_blueprint(out, ds.cameras, ["RGB", "depth (ground truth)", "depth init", "depth refine1"])
    assert "/world/scene/static" in ents and "/world/ego/body" in ents
    assert [t for t, _ in ents["/world/trajectory"]] == [times[0]]  # one sequence: its trajectory, at its start


def test_predict_rrd_takes_the_world_mesh_from_the_dataset(run, flow_dataset, tmp_path, one_thread):
    """`record_predictions` on a dataset holding its world mesh (``labels.mesh=true``) shows that mesh, with no
    rebuild from the generator config given (mcdp never reads one)."""
    from mcdp.predict import Predictor
    from mcdp.recording import record_predictions
    from synth.open import open_dataset

    ds = open_dataset(flow_dataset)
    seq = ds.split("test")[0]
    record_predictions(Predictor(run, ds), [(seq, 0)], tmp_path / "pred.rrd")
    ents = read_rrd(tmp_path / "pred.rrd")
    (row,) = [r for t, r in ents["/world/scene/static"] if "Mesh3D:vertex_positions" in r]
    np.testing.assert_array_equal(np.asarray(row["Mesh3D:vertex_positions"], np.float32),
                                  ds.read_label("mesh", seq).static.positions)
    assert "/world/ego/body" in ents


def test_predict_needs_out_or_rrd_and_refuses_a_foreign_rrd(run, tiny_dataset, tmp_path, capsys):
    assert main(["predict", str(run), "--data", str(tiny_dataset)]) == 2
    assert "give --out PRED (files), --rrd FILE.rrd" in capsys.readouterr().err
    mine = tmp_path / "mine.rrd"
    mine.write_bytes(b"not a recording")
    assert main(["predict", str(run), "--data", str(tiny_dataset), "--rrd", str(mine)]) == 2
    assert "--rrd" in capsys.readouterr().err and mine.read_bytes() == b"not a recording"


def test_abs_rel_image_by_hand():
    from mcdp.recording import abs_rel_image

    gt = np.array([[10.0, 0.0], [100.0, 4.0]], np.float32)
    pred = np.array([[12.0, 5.0], [50.0, 3.0]], np.float32)
    mask = np.array([[True, True], [True, False]])
    np.testing.assert_allclose(abs_rel_image(pred, gt, mask), [[0.2, 0.0], [0.0, 0.0]], rtol=1e-6)


def test_predict_rrd_on_a_full_disk_exits_4_naming_the_file_and_leaves_no_temporary(run, tiny_dataset, tmp_path,
                                                                                    capsys, monkeypatch,
                                                                                    full_disk_after):
    """Issue 32, finding 7: was a traceback, exit 1 (Rerun's own file sink met the full disk)."""
    import corelib.atomic

    out = tmp_path / "p.rrd"
    args = ["predict", str(run), "--data", str(tiny_dataset), "--rrd", str(out), "--max-samples", "1", "--no-progress"]
    monkeypatch.setattr(corelib.atomic, "open", full_disk_after(0, ".rrd"), raising=False)
    capsys.readouterr()
    assert main(args) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("mcdp predict: error: ") and f"{out}: no space left on device" in err[-1], err
    assert not any("Traceback" in line for line in err) and list(tmp_path.iterdir()) == []
