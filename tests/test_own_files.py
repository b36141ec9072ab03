"""Hardening round six (issue 61): the files the project writes for itself (a sweep's records, results, pages,
checkpoints, its own folders) are read and written by the same rule as the files a user hands in. One test per
finding, each the reproduction that failed before the fix, holding the one-line outcome now."""
from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


# --- finding 1: a multi-part EXR is refused before any part is decoded ---------------------------------------

def _multipart_exr(path: Path, names=("Z",)) -> None:
    import OpenEXR

    h = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    part0 = OpenEXR.Part(dict(h), {c: np.ones((64, 96), np.float32) for c in names}, name="depth")
    part1 = OpenEXR.Part(dict(h), {f"C{i}": np.ones((64, 96), np.float32) for i in range(4)}, name="extra")
    buf = io.BytesIO()
    with OpenEXR.File([part0, part1]) as f:
        f.write(buf)
    path.write_bytes(buf.getvalue())


@pytest.mark.parametrize("reader,names", [("read_depth_exr", ("Z",)), ("read_flow_exr", ("U", "V"))])
def test_multipart_exr_refused_before_decoding(tmp_path, monkeypatch, reader, names):
    import OpenEXR

    import synth.files as files

    path = tmp_path / "000000.depth.exr"
    _multipart_exr(path, names)
    opened = []
    real = OpenEXR.File
    monkeypatch.setattr(OpenEXR, "File", lambda *a, **k: opened.append(k) or real(*a, **k))
    with pytest.raises(files.DatasetError) as e:
        getattr(files, reader)(path)
    assert str(e.value) == (f"{path}: an OpenEXR file of several parts (multi-part); a dataset's maps are "
                            "single-part scanline files; refused before decoding")
    assert opened == []  # OpenEXR never saw it, not even its header


# --- finding 9: no read asks for a buffer of the 2 GiB bound ------------------------------------------------

def test_dataset_read_asks_no_2gib_buffer(tmp_path):
    """Under an address-space limit of 512 MiB above what the process maps, a tiny depth map reads (before:
    MemoryError, `f.read(MAX_READ_BYTES + 1)` asked for 2 GiB whatever the file's size)."""
    code = f"""
import resource
import numpy as np
from synth.files import write_depth_exr, read_depth_exr, read_json
from corelib.readfile import read_text_inside
write_depth_exr({str(tmp_path / 'd.exr')!r}, np.ones((64, 96), np.float32))
open({str(tmp_path / 'r.json')!r}, 'w').write('{{"a": 1}}')
vm = int([l for l in open('/proc/self/status') if l.startswith('VmSize')][0].split()[1]) * 1024
resource.setrlimit(resource.RLIMIT_AS, (vm + 512 * 2**20, resource.getrlimit(resource.RLIMIT_AS)[1]))
print(read_depth_exr({str(tmp_path / 'd.exr')!r}).shape, read_json({str(tmp_path / 'r.json')!r}),
      read_text_inside({str(tmp_path / 'r.json')!r}, {str(tmp_path)!r}, limit=2**31))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "(64, 96) {'a': 1} {\"a\": 1}"


def test_read_bounded_sees_one_byte_past_the_bound(tmp_path):
    from corelib.readfile import read_bounded

    (tmp_path / "f").write_bytes(b"x" * 100)
    with open(tmp_path / "f", "rb") as f:
        assert len(read_bounded(f, 10)) == 11
    with open(tmp_path / "f", "rb") as f:
        assert read_bounded(f, 1000) == b"x" * 100


# --- finding 6: a tiny sensor.noise is refused by the config check, naming the key ---------------------------

def test_tiny_sensor_noise_refused_naming_key():
    from corelib.configlib import ConfigError
    from synth.config import load_data_config

    with pytest.raises(ConfigError) as e:
        load_data_config(ROOT / "configs/data/tiny.yaml", ["sensor.noise=1e-20"])
    assert str(e.value).splitlines()[-1] == ("  sensor.noise: 0 (no noise) or at least 1e-06 (a million electrons at "
                                             "white; a real sensor holds about 1e4), got 1e-20")
    load_data_config(ROOT / "configs/data/tiny.yaml", ["sensor.noise=1e-6"])  # the smallest allowed renders


def test_tiny_sensor_noise_refused_before_a_sweep_starts():
    from corelib.configlib import ConfigError
    from study.sweep.config import check_nested_configs, load_sweep_config

    cfg = load_sweep_config(ROOT / "configs/sweep/ci.yaml", ["data_overrides=[sensor.noise=1e-20]"], None)
    with pytest.raises(ConfigError) as e:  # before: a traceback 45 s in, when the first world rendered
        check_nested_configs(cfg, yes=True)  # what `mcdp sweep` does before anything is written
    assert str(e.value).splitlines()[-1].startswith("  sensor.noise: 0 (no noise) or at least 1e-06")


# --- finding 12 (last part): a validator's value is echoed once ----------------------------------------------

def test_validator_value_echoed_once():
    from corelib.configlib import ConfigError
    from synth.config import load_data_config

    with pytest.raises(ConfigError) as e:
        load_data_config(ROOT / "configs/data/tiny.yaml", ["weather.fog_density=[0.5,0.1]"])
    assert str(e.value).splitlines()[-1] == ("  weather.fog_density: a fog density range is [lo, hi] with lo <= hi, "
                                             "got [0.5, 0.1]")


# --- finding 8: checkpoints: a tensor of another shape, no optimizer, NaN weights, the divergence message ------

TINY_TRAIN = ROOT / "configs/train/tiny"


@pytest.fixture(scope="module")
def mono2_state():
    import torch

    from corelib.configlib import config_to_dict, load_config
    from mcdp.config import RunConfig
    from mcdp.methods import build_network, method_params
    from mcdp.runs import CHECKPOINT_VERSION

    cfg = load_config(RunConfig, TINY_TRAIN / "mono2.yaml", [])
    with torch.random.fork_rng():
        torch.manual_seed(0)
        net = build_network(cfg.model, method_params(cfg))
    return {"version": CHECKPOINT_VERSION, "step": 3, "config": config_to_dict(cfg),
            "depth_model": net.state_dict()}, cfg


def _save(ckpt: dict, path: Path) -> Path:
    from mcdp.runs import atomic_torch_save

    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_torch_save(ckpt, path)
    return path


def test_checkpoint_tensor_of_another_shape_is_one_line(tmp_path, mono2_state):
    import torch

    from mcdp.runs import RunError, load_checkpoint

    ckpt, _ = mono2_state
    name = next(k for k, v in ckpt["depth_model"].items() if v.ndim == 4)
    bad = {**ckpt, "depth_model": {**ckpt["depth_model"], name: torch.zeros(3, 3, 3, 3)}}
    path = _save(bad, tmp_path / "best.pt")
    with pytest.raises(RunError) as e:
        load_checkpoint(path)
    msg = str(e.value)
    assert "\n" not in msg
    assert msg.startswith(f"checkpoint {path}: depth_model does not fit the mono2 network its config builds: "
                          f"size mismatch for {name}: copying a param with shape torch.Size([3, 3, 3, 3])")


def test_checkpoint_with_nan_weights_refused(tmp_path, mono2_state):
    import torch

    from mcdp.runs import RunError, load_checkpoint

    ckpt, _ = mono2_state
    name = next(k for k, v in ckpt["depth_model"].items() if v.is_floating_point())
    t = ckpt["depth_model"][name].clone()
    t.view(-1)[:2] = float("nan")
    path = _save({**ckpt, "depth_model": {**ckpt["depth_model"], name: t}}, tmp_path / "last.pt")
    with pytest.raises(RunError) as e:
        load_checkpoint(path)
    assert str(e.value) == (f"checkpoint {path}: depth_model.{name} holds 2 non-finite value(s) (NaN or inf): the run "
                            "diverged before it was written; refused (use an earlier checkpoint or retrain)")
    assert load_checkpoint(_save(ckpt, tmp_path / "ok.pt"))["step"] == 3  # a finite one reads as before


def test_resume_from_checkpoint_without_optimizer_is_one_line(mono2_state):
    import torch

    from mcdp.methods import build_network, method_params
    from mcdp.runs import RunError, restore_checkpoint

    ckpt, cfg = mono2_state
    net = build_network(cfg.model, method_params(cfg))
    opt = torch.optim.Adam(net.parameters())
    with pytest.raises(RunError) as e:
        restore_checkpoint({**ckpt, "torch_rng": torch.get_rng_state()}, net, None, opt, None, source="RUN/last.pt")
    assert str(e.value) == ("RUN/last.pt: no optimizer in the checkpoint (a weights-only checkpoint, or not written by "
                            "mcdp train), so training cannot resume from it; move it away to start afresh")


def test_nan_weights_never_written_and_divergence_says_what_it_checked(tmp_path, mono2_state):
    from types import SimpleNamespace

    import torch

    from mcdp.methods import build_network, method_params
    from mcdp.trainer import Trainer, TrainingDiverged

    _, cfg = mono2_state
    net = build_network(cfg.model, method_params(cfg))
    name, p = next(iter(net.named_parameters()))
    with torch.no_grad():
        p.view(-1)[0] = float("nan")
    (tmp_path / "checkpoints").mkdir()
    (tmp_path / "checkpoints" / "last.pt").write_bytes(b"written at step 2")
    fake = SimpleNamespace(dist=SimpleNamespace(is_main=True), depth=net, pose=None, run_dir=tmp_path, step=5)
    fake._last_good = lambda: Trainer._last_good(fake)
    with pytest.raises(TrainingDiverged) as e:
        Trainer.save_checkpoint(fake, "last.pt")
    assert str(e.value) == (f"depth_model.{name} holds 1 non-finite value(s) at step 5; last.pt not written; the last "
                            f"checkpoint written (its weights finite when written) is {tmp_path}/checkpoints/last.pt; "
                            "try a lower train.lr or train.grad_clip=1.0")
    assert (tmp_path / "checkpoints" / "last.pt").read_bytes() == b"written at step 2"


# --- finding 3: a sweep's own records are read by the one rule (a FIFO, a huge file, a link out) -------------

def _fifo(path: Path) -> Path:
    import os

    os.mkfifo(path)
    return path


def _huge(path: Path, size: int = 3 * 2**30) -> Path:
    with open(path, "wb") as f:  # sparse: no block written
        f.truncate(size)
    return path


@pytest.mark.parametrize("name", ["sweep_status.json", "metrics_test.json", "overlap_0.50.status.json"])
def test_sweep_record_fifo_huge_or_link_refused_in_one_line(tmp_path, name):
    from corelib.readfile import ReadRefused
    from study.sweep.records import read_json

    run = tmp_path / "sweep" / "runs" / "overlap_0.50" / "mono2_s0"
    run.mkdir(parents=True)
    path = run / name
    _fifo(path)
    with pytest.raises(ReadRefused) as e:  # before: blocked for good
        read_json(path)
    assert str(e.value) == f"{path}: is a FIFO (named pipe), not a regular file; refused without reading it"
    path.unlink()
    _huge(path)
    with pytest.raises(ReadRefused) as e:  # before: read whole, past 6 GB
        read_json(path)
    assert str(e.value) == (f"{path}: 3221225472 bytes, more than a record may hold ({16 * 2**20}); refused unread")
    path.unlink()
    forged = tmp_path / "elsewhere.json"
    forged.write_text('{"stages": {"final": {"none": {"mean": {"abs_rel": 1e308}}}}}')
    path.symlink_to(forged)
    with pytest.raises(ReadRefused) as e:  # before: trusted ("evaluated already, skipped")
        read_json(path)
    assert str(e.value) == (f"{path}: is a symbolic link; a file the project wrote is read only as itself, never "
                            "through a link")
    path.unlink()
    assert read_json(path) is None  # absent: written again
    path.write_text("{not json")
    assert read_json(path) is None  # not JSON (never half-written: a crashed writer's temp): written again
    path.write_text('{"a": NaN}')
    assert read_json(path)["a"] != read_json(path)["a"]  # NaN, as the sweep writes it


def test_sweep_record_under_a_linked_folder_refused_with_root(tmp_path):
    from corelib.readfile import ReadRefused
    from study.sweep.records import read_json

    sweep, outside = tmp_path / "sweep", tmp_path / "outside"
    (outside / "mono2_s0").mkdir(parents=True)
    (outside / "mono2_s0" / "metrics_test.json").write_text("{}")
    (sweep / "runs").mkdir(parents=True)
    (sweep / "runs" / "overlap_0.50").symlink_to(outside)
    path = sweep / "runs" / "overlap_0.50" / "mono2_s0" / "metrics_test.json"
    with pytest.raises(ReadRefused) as e:
        read_json(path, root=sweep)
    assert str(e.value) == (f"{path}: {sweep}/runs/overlap_0.50 is a symbolic link; a folder's own files are read "
                            "only without following one")


def test_read_refused_is_one_line_exit_2():
    from study.method_commands import USER_ERRORS

    assert ("corelib.readfile", "ReadRefused") in USER_ERRORS


# --- finding 10: ego.json frames: a bad timestamp_s and a triggered frame without camera times, one line ------

def _cams(n: int = 2):
    from types import SimpleNamespace

    return [SimpleNamespace(name=f"CAM_{i}", T_ego_cam=np.eye(4)) for i in range(n)]


@pytest.mark.parametrize("frame,shown", [({"T_world_ego": np.eye(4).tolist()}, "none"),
                                         ({"timestamp_s": "soon", "T_world_ego": np.eye(4).tolist()}, "soon"),
                                         ({"timestamp_s": float("nan")}, "nan")])
def test_ego_frame_without_a_numeric_timestamp_is_one_line(frame, shown):
    from synth.files import DatasetError
    from synth.trigger import camera_poses

    frames = [{"timestamp_s": 0.0, "T_world_ego": np.eye(4).tolist()}, frame]
    with pytest.raises(DatasetError) as e:  # before: KeyError / ValueError traceback in mcdp eval
        camera_poses(frames, _cams(), "SEQ/ego.json")
    assert str(e.value) == f"SEQ/ego.json: frame 1: timestamp_s must be a finite number of seconds, got {shown}"


def test_triggered_frame_without_camera_times_refused():
    from types import SimpleNamespace

    from synth.dataset import Dataset
    from synth.files import DatasetError

    frames = [{"timestamp_s": 0.0, "T_world_ego": np.eye(4).tolist()}]
    fake = SimpleNamespace(manifest={"trigger": {"mode": "lidar_sweep", "offsets_ms": {}}}, cameras=_cams(),
                           root=Path("DS"), ego=lambda seq: frames)
    with pytest.raises(DatasetError) as e:  # before: silently read as synchronous
        Dataset.camera_poses(fake, "seq_000")
    assert str(e.value) == ("DS/seq_000/ego.json: frame 0 has no 'cameras' (each camera's timestamp_s and "
                            "T_world_cam); the manifest's trigger is lidar_sweep, so every frame gives them")
    fake = SimpleNamespace(manifest={}, cameras=_cams(), root=Path("DS"), ego=lambda seq: frames)
    ts, T = Dataset.camera_poses(fake, "seq_000")  # a synchronous rig: the frame's time, the static pose
    assert ts.tolist() == [[0.0, 0.0]] and np.array_equal(T[0, 1], np.eye(4))


# --- finding 4: republish --list reads every page by the one rule -------------------------------------------

@pytest.mark.parametrize("kind", ["fifo", "huge", "latin1", "link"])
def test_republish_list_refuses_a_hostile_page_in_one_line(tmp_path, kind):
    import importlib

    rp = importlib.import_module("scripts.republish")
    results = tmp_path / "results"
    results.mkdir()
    (results / "good.md").write_text("> Generated by `python scripts/publish_sweep.py --name good`\n")
    page = results / "page.md"
    if kind == "fifo":
        _fifo(page)
    elif kind == "huge":
        _huge(page)
    elif kind == "latin1":
        page.write_bytes("> Generated by `python scripts/publish_sweep.py --name page` \xe9t\xe9\n".encode("latin-1"))
    else:
        (tmp_path / "outside.md").write_text("> Generated by `python scripts/publish_sweep.py --name page`\n")
        page.symlink_to(tmp_path / "outside.md")
    with pytest.raises(rp.RepublishError) as e:
        rp.pages(results)
    assert str(e.value) == {
        "fifo": f"{page}: is a FIFO (named pipe), not a regular file; refused without reading it",
        "huge": f"{page}: 3221225472 bytes, more than a page may hold ({8 * 2**20}); refused unread",
        "latin1": f"{page}: not UTF-8 (invalid continuation byte at byte 61)",
        "link": f"{page}: is a symbolic link; a file the project wrote is read only as itself, never through a link",
    }[kind]
    page.unlink()
    assert rp.pages(results) == {"good": "publish_sweep"}


# --- finding 5: publish_sweep's csv-only path by the rule; results validated before the builders use them ------

@pytest.fixture()
def ps(monkeypatch, tmp_path):
    import importlib

    mod = importlib.import_module("scripts.publish_sweep")
    monkeypatch.setattr(mod, "RESULTS", tmp_path / "results")
    (tmp_path / "results" / "old").mkdir(parents=True)
    return mod


@pytest.mark.parametrize("kind", ["link", "huge", "malformed"])
def test_publish_csv_only_report_read_by_the_rule(ps, tmp_path, kind):
    from corelib.readfile import ReadRefused

    csv = tmp_path / "results" / "old" / "results.csv"
    if kind == "link":
        (tmp_path / "users").write_text("root:x:0:0:root:/root:/bin/bash\n")
        csv.symlink_to(tmp_path / "users")
    elif kind == "huge":
        _huge(csv)
    else:
        csv.write_text("overlap,method,variant\n0.1,mono2,trained\n")
    with pytest.raises(ReadRefused if kind != "malformed" else ps.PublishError) as e:  # before: tracebacks, 6 GB
        ps.publish("old", None)
    assert str(e.value) == {
        "link": f"{csv}: is a symbolic link; a file the project wrote is read only as itself, never through a link",
        "huge": f"{csv}: 3221225472 bytes, more than a results may hold ({64 * 2**20}); refused unread",
        "malformed": f"{csv}: not a sweep's results.csv (no column 'seed')",
    }[kind]
    assert not (tmp_path / "results" / "old" / "plots").exists()  # nothing written


@pytest.fixture(scope="module")
def committed_results():
    from study.results.files import read_results

    return read_results(ROOT / "docs/results/propagation_budget/results.json")


def _every_float(obj, value):
    if isinstance(obj, dict):
        return {k: _every_float(v, value) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_every_float(v, value) for v in obj]
    return value if isinstance(obj, float) else obj


@pytest.mark.parametrize("case", ["nan", "big", "big_rows", "escape", "overlaps", "plan"])
def test_results_checked_before_the_report_builders_use_them(ps, committed_results, case):
    import copy
    import json

    from mcdp.methods import METHODS

    r = copy.deepcopy(committed_results)
    if case == "nan":
        r = _every_float(r, float("nan"))
    elif case == "big":
        r = _every_float(r, 1e308)
    elif case == "big_rows":
        r["flat"] = _every_float(r["flat"], 1e308)
    elif case == "escape":
        m = r["methods"][0]
        r = json.loads(json.dumps(r).replace(json.dumps(m), json.dumps(m + "\x1b[31m")))
    elif case == "overlaps":
        r["overlaps"] = [i / 100000 for i in range(100000)]
    else:
        r["sweep_config"]["plan"] = {"worlds": 5, "first_look": "soon"}
    path = Path("SWEEP/results.json")
    with pytest.raises(ps.PublishError) as e:  # before: pydantic / arange / KeyError tracebacks, 300 s and 3.2 GB
        ps.check_results(json.dumps(r, allow_nan=True).encode(), path)
    flat0 = next(k for k, v in r["flat"][0].items() if isinstance(v, float))
    assert str(e.value) == {
        "nan": "SWEEP/results.json: field 'overlaps[0]' is nan, not an overlap in [0, 1]",
        "big": "SWEEP/results.json: field 'overlaps[0]' is 1e+308, not an overlap in [0, 1]",
        "big_rows": f"SWEEP/results.json: field 'flat[0].{flat0}' is beyond +-1e+12 (NaN is a missing value; a number "
                    "this large is no measurement)",
        "escape": "SWEEP/results.json: field 'methods[0]' is 'mono2\\x1b[31m', not a method of "
                  f"mcdp/methods/__init__.py ({', '.join(METHODS)})",
        "overlaps": "SWEEP/results.json: field 'overlaps' has 100000 entries, more than a report is built from (64)",
        "plan": "SWEEP/results.json: field 'sweep_config.plan.first_look': Input should be a valid integer",
    }[case]


@pytest.mark.parametrize("name", ["lcon_main", "sweep_cpu"])  # a recorded plan; three overlaps, three seeds
def test_committed_results_pass_the_check(ps, name):
    from corelib.readfile import read_inside

    p = ROOT / "docs/results" / name / "results.json"
    ps.check_results(read_inside(p, ROOT / "docs/results"), p)


# --- findings 2, 7, 12: the sweep's writers stay inside --out; the disk check counts blocks and what is left ---

SWEEP_CI = ROOT / "configs/sweep/ci.yaml"


def _ci(*overrides):
    from study.sweep.config import load_sweep_config

    return load_sweep_config(SWEEP_CI, list(overrides), None)


@pytest.fixture()
def disk(monkeypatch):
    from study.sweep import disk as mod
    monkeypatch.setattr(mod, "checkpoint_bytes", lambda rcfg, n_cameras=6: (300_000_000, 100_000_000))
    return mod


@pytest.mark.parametrize("where", ["data", "pretrain", "plots", "data/overlap_0.20", "pretrain/abc123/run"])
def test_a_link_among_the_sweeps_own_folders_is_refused_before_writing(disk, tmp_path, where):
    from corelib.atomic import LinkRefused

    out, elsewhere = tmp_path / "sweep", tmp_path / "small_fs"
    elsewhere.mkdir()
    (out / where).parent.mkdir(parents=True, exist_ok=True)
    (out / where).symlink_to(elsewhere)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    with pytest.raises(LinkRefused) as e:  # before: rendered / pretrained through the link, outside --out
        disk.check_disk(_ci(), out, 0, yes=True)
    assert str(e.value) == (f"{out / where} is a symbolic link; nothing is written through a link: remove the link "
                            "(or use another output folder) and run the command again")
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_the_disk_check_measures_where_the_bytes_land(disk, tmp_path, monkeypatch):
    out = tmp_path / "sweep"
    (out / "data").mkdir(parents=True)  # a small file system mounted at data/
    monkeypatch.setattr(disk, "_device", lambda p: 2 if p.name == "data" else 1)
    monkeypatch.setattr(disk, "free_bytes", lambda p: 20_000_000 if p.name == "data" else 66_000_000_000)
    with pytest.raises(Exception) as e:  # before: --out's 66 GB measured, the world rendered on 20 MB
        disk.check_disk(_ci(), out, 3_000_000_000, yes=False)
    assert f"it will write about 1 GB more on {out / 'data'} (" in str(e.value)
    assert "and 0.02 GB are free there;" in str(e.value)


def test_a_sparse_file_is_not_counted_as_written(disk, tmp_path, monkeypatch):
    out = tmp_path / "sweep"
    out.mkdir()
    _huge(out / "sparse.bin", 2**40)  # 1 TB apparent, no block
    monkeypatch.setattr(disk, "free_bytes", lambda p: 10**15)
    line = disk.check_disk(_ci(), out, 3_000_000_000, yes=False)
    assert "; 1.9 GB still to write (14 of 14 run(s) and 2 of 2 world(s) left), 1e+06 GB free" in line, line
    assert disk.bytes_under(out) < 2**20  # before: 1 TB, "0 GB still to write"


def _complete(out: Path, cfg) -> None:
    from study.sweep.config import overlap_key, world_key, worlds_of

    for o in cfg.overlaps:
        for w in worlds_of(cfg):
            (out / "data" / world_key(o, w)).mkdir(parents=True)
            (out / "data" / world_key(o, w) / "manifest.json").write_text("{}")
        for m in cfg.methods:
            for s in cfg.seeds:
                (out / "runs" / overlap_key(o) / f"{m}_s{s}").mkdir(parents=True)
                (out / "runs" / overlap_key(o) / f"{m}_s{s}" / "metrics_test.json").write_text("{}")
    (out / "pretrain" / "abc").mkdir(parents=True)
    (out / "pretrain" / "abc" / "pretrain.json").write_text("{}")


def test_a_complete_sweep_is_never_refused(disk, tmp_path, monkeypatch):
    out = tmp_path / "sweep"
    cfg = _ci()
    _complete(out, cfg)
    monkeypatch.setattr(disk, "free_bytes", lambda p: 0)  # a disk filled while the report was written
    line = disk.check_disk(cfg, out, 3_000_000_000, yes=False)  # before: refused without --yes
    assert line.endswith("; 0 GB still to write (0 of 14 run(s) and 0 of 2 world(s) left), 0 GB free"), line
    (out / "runs" / "overlap_0.50" / "fsm_s0" / "metrics_test.json").unlink()  # one run left: its peak only
    line = disk.check_disk(cfg, out, 3_000_000_000, yes=True)
    assert "; 0.4 GB still to write (1 of 14 run(s) and 0 of 2 world(s) left)" in line, line


def test_the_disk_line_says_what_it_sums(disk, tmp_path, monkeypatch):
    monkeypatch.setattr(disk, "free_bytes", lambda p: 10**12)
    line = disk.check_disk(_ci(), tmp_path / "sweep", 3_000_000_000, yes=False)
    assert line.startswith(  # before: "14 run(s) x (last.pt about 328 MB + best.pt 109 MB): 0.983 GB", read as 6.1
        "14 run(s), each writing last.pt about 300 MB and best.pt 100 MB; no run keeps its checkpoints, and 2 at a "
        "time hold both while they train (keep_last: false, keep_best: false), with the pretraining: 0.9 GB of "
        "checkpoints on disk at most; with the renders about 1.9 GB; 1.9 GB still to write"), line


# --- finding 11: every data preset's header true of what it renders (the claims a config can show) ------------

def _header(path: Path) -> str:
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line.lstrip("# "))
    return " ".join(lines)


def _times(cfg) -> tuple:
    from synth.sensor import SHUTTER_KEYS

    return (cfg.rig.trigger, *(getattr(cfg.sensor, k) for k in SHUTTER_KEYS))


@pytest.mark.parametrize("path", sorted((ROOT / "configs/data").glob("*.yaml")), ids=lambda p: p.stem)
def test_a_data_presets_header_says_what_it_renders(path):
    """Before: realistic.yaml said its ground truth was byte-identical to default.yaml's while its trigger and
    rolling shutter moved every camera's time; nuscenes_like_sensor.yaml's trigger was said nowhere."""
    import re

    from synth.config import load_data_config
    from synth.shutter import Shutter

    cfg = load_data_config(path)
    head = _header(path)
    for negated, other in re.findall(r"(NOT to |not )?(?:byte-)?identical to (\w+)\.yaml", head):
        same = _times(load_data_config(path.parent / f"{other}.yaml")) == _times(cfg)
        assert same != bool(negated), f"{path.name}: says its ground truth is {negated}identical to {other}.yaml's"
    if cfg.rig.trigger != "synchronous":
        assert f"rig.trigger: {cfg.rig.trigger}" in head, path.name
        assert f"{path.name}` (" in (ROOT / "docs/DATASET.md").read_text() and "lidar_sweep" in \
            (ROOT / "docs/DATASET.md").read_text()
    shutter = Shutter.for_config(cfg)
    if shutter is not None and shutter.renders_per_image() > 1:
        assert f"{shutter.renders_per_image()} renders an image" in head, path.name
        assert re.search(r"[\d.]+ s a rig-frame", head) and re.search(r"[\d.]+ MB a rig-frame on disk", head), path.name


# --- finding 13: the render's time cost stated beside its bytes when the shutter multiplies renders ------------

def test_the_size_line_states_the_shutters_renders():
    from synth.config import load_data_config, render_size, size_statement

    cfg = load_data_config(ROOT / "configs/data/tiny.yaml", ["sensor.exposure_ms=100", "sensor.subframes=16",
                                                             "sensor.rolling_shutter_ms=100", "sensor.rolling_bands=32"])
    assert size_statement(render_size(cfg)) == (  # before: the bytes only
        "18 rig-frames, 108 images (RGB, depth and labels): 0.00664 GB before compression, about a third of that on "
        "disk; the shutter (sensor.subframes x sensor.rolling_bands) takes 544 renders an image, 58752 in all, so its "
        "rendering takes up to 544 times as long as with still images")
    still = load_data_config(ROOT / "configs/data/tiny.yaml")
    assert "renders an image" not in size_statement(render_size(still))


# --- the one rule: no plain read of a project file outside corelib.readfile (and synth.files, its twin) ---------

#: the library's packages and scripts the scan reads
SCANNED = ("corelib", "synth", "scenes", "mcdp", "study", "scripts")
#: the rule itself, written once, and its twin for a dataset's files (the same rule, `DatasetError`)
RULE_MODULES = {"corelib/readfile.py", "synth/files.py"}
#: justified exceptions: (file, a part of the call's source line) -> why it is not a plain read of a project file
ALLOWED = {
    ("corelib/version.py", "pyproject.read_text()"): "the package's own pyproject.toml, to say its version",
    ("corelib/version.py", "p.read_bytes()"): "the package's own source files, hashed into the code version",
    ("synth/nuscenes/export.py", "ds.read_bytes(dsrc)"): "the dataset reader's own method (read_regular)",
    ("synth/nuscenes/export.py", "ds.read_bytes(ds.rgb_path("): "the dataset reader's own method (read_regular)",
    ("synth/nuscenes/lidarseg.py", "self.ds.read_bytes(src)"): "the dataset reader's own method (read_regular)",
    ("synth/view.py", "ds.read_bytes(src)"): "the dataset reader's own method (read_regular)",
    ("synth/preview.py", "Image.open(fh,"): "fh is corelib.readfile.open_file's (regular, never blocking)",
    ("mcdp/networks.py", "torch.load(f,"): "f is corelib.readfile.open_file's (regular, bounded, non-blocking)",
    ("mcdp/runs.py", "torch.load(f,"): "f is corelib.readfile.open_file's (regular, bounded, non-blocking)",
    ("scripts/publish_sweep.py", '(stage / "results.csv").read_bytes()'): "the temporary folder this process "
                                                                           "made a moment before",
    ("scripts/publish_sweep.py", "p.read_bytes()"): "a plot in the temporary folder this process made",
}


def _plain_reads(path: Path):
    """(line, source) of every call in ``path`` that reads a file plainly: ``open()`` for reading,
    ``.read_text()``, ``.read_bytes()``, ``x.open()`` (but ``os.open``, the rule's primitive, and archives'
    members), ``json.load`` / ``torch.load`` / ``np.load`` / ``pickle.load``."""
    import ast

    text = path.read_text()
    lines = text.splitlines()
    for node in ast.walk(ast.parse(text, str(path))):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id == "open":
            mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            m = mode.value if isinstance(mode, ast.Constant) else "r"
            hit = isinstance(m, str) and not any(c in m for c in "wax")
        elif isinstance(f, ast.Attribute):
            recv = f.value.id if isinstance(f.value, ast.Name) else None
            hit = f.attr in ("read_text", "read_bytes") \
                or (f.attr == "open" and recv not in ("os", "gzip", "zipfile", "tarfile", "zf")) \
                or (f.attr == "load" and recv in ("json", "torch", "np", "pickle"))
        else:
            hit = False
        if hit:
            yield node.lineno, lines[node.lineno - 1].strip()


def test_no_plain_read_of_a_project_file_outside_the_rule():
    found, used = [], set()
    for pkg in SCANNED:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).as_posix()
            if rel in RULE_MODULES:
                continue
            for line, src in _plain_reads(path):
                key = next((k for k in ALLOWED if k[0] == rel and k[1] in src), None)
                if key is None:
                    found.append(f"{rel}:{line}: {src}")
                else:
                    used.add(key)
    assert found == [], ("a plain read of a file: read it by corelib.readfile (read_file, read_json_file, "
                         "read_text_file, open_file), or add it to ALLOWED with its reason:\n" + "\n".join(found))
    assert set(ALLOWED) - used == set(), "ALLOWED entries that match nothing any more"


def test_the_scan_finds_a_plain_read(tmp_path):
    (tmp_path / "m.py").write_text("import json\nfrom pathlib import Path\n"
                                   "a = json.loads(Path('x').read_text())\nb = open('y')\nc = open('z', 'wb')\n"
                                   "import os\nd = os.open('w', os.O_RDONLY)\n")
    assert sorted(ln for ln, _ in _plain_reads(tmp_path / "m.py")) == [3, 4]  # not the write, not os.open
