"""Shared fixtures: one tiny dataset rendered once per test session (CPU, EGL/OSMesa llvmpipe)."""
from __future__ import annotations

import errno
import math
import os
from pathlib import Path

import numpy as np
import pytest

# Import torch (and the parts of it that load triton's LLVM) BEFORE any test renders in
# this process: loading that LLVM after Mesa llvmpipe's has segfaulted `import torch.fx`.
# The `synth` and `mcdp` CLIs never mix the two in one process order that triggers it
# (mcdp imports torch first; render workers are spawned processes).
import torch  # noqa: F401,E402
import torch.fx  # noqa: F401,E402
import torchvision  # noqa: F401,E402

from synth.label_reader import NoLabels  # noqa: E402
from synth.rig import CameraSpec  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "data" / "tiny.yaml"

# Under pytest-xdist (`pytest -n 2 --dist loadfile`, the README's command: a module's tests on one worker, so its
# module-scoped fixtures are made once) the workers share the cores: one torch thread each (the tiny presets train
# on one thread already; this holds the rest, e.g. a predictor, to it too).
if os.environ.get("PYTEST_XDIST_WORKER"):
    torch.set_num_threads(1)


@pytest.fixture(scope="session")
def tiny_config():
    from synth.config import load_data_config

    return load_data_config(TINY)


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory, tiny_config):
    """Path of a finished tiny dataset (configs/data/tiny.yaml), rendered once."""
    from synth.render import render_dataset

    out = tmp_path_factory.mktemp("tiny") / "data"
    render_dataset(tiny_config, out, workers=1, progress=False, log=lambda *a: None)
    return out


@pytest.fixture(scope="session")
def flow_dataset(tmp_path_factory):
    """The tiny preset with every label, forward flow included (off by default: its cost), rendered once."""
    from synth.config import load_data_config
    from synth.render import render_dataset

    out = tmp_path_factory.mktemp("labels") / "data"
    render_dataset(load_data_config(TINY, ["labels.flow=true"]), out, workers=1, progress=False, log=lambda *a: None)
    return out


@pytest.fixture(scope="session")
def _mono2_run_once(tiny_dataset, tmp_path_factory):
    from study.method_commands import main

    run = tmp_path_factory.mktemp("mono2") / "run"
    assert main(["train", str(ROOT / "configs" / "train" / "tiny" / "mono2.yaml"), "--data", str(tiny_dataset),
                 "--out", str(run), "--no-progress", "train.steps=1"]) == 0
    return run


@pytest.fixture
def mono2_run(_mono2_run_once, tmp_path):
    """``tmp_path / "run"``: the run folder of `mcdp train configs/train/tiny/mono2.yaml --data TINY_DATASET
    train.steps=1`, trained once per session (per xdist worker) and copied for each test (a run to evaluate,
    predict from or refuse; never one whose training is under test)."""
    import shutil

    return Path(shutil.copytree(_mono2_run_once, tmp_path / "run", symlinks=True))


@pytest.fixture(scope="session")
def tiny_dataset_without_labels(tiny_dataset, tmp_path_factory):
    """A copy of the tiny dataset as rendered before labels existed: its manifest has no labels record (the
    label files stay, unread)."""
    import json
    import shutil

    out = tmp_path_factory.mktemp("tiny_old") / "data"
    shutil.copytree(tiny_dataset, out)
    m = json.loads((out / "manifest.json").read_text())
    m.pop("labels")
    (out / "manifest.json").write_text(json.dumps(m, indent=1))
    return out


@pytest.fixture(scope="module")
def ns_root(tiny_dataset, tmp_path_factory):
    """The tiny dataset exported as a nuScenes dataroot (version v1.0-synth), once per test module: tests
    read it, or change a copy of it."""
    from synth.nuscenes.export import export_nuscenes
    from synth.open import open_dataset

    out = tmp_path_factory.mktemp("ns") / "root"
    export_nuscenes(open_dataset(tiny_dataset), out, version="v1.0-synth")
    return out


@pytest.fixture(scope="module")
def local_ray():
    """A private local Ray (2 CPUs, no dashboard) for one test module, shut down and removed after it.

    The engines find Ray initialised and use it as it is (`corelib.cluster.ray_session`).
    Skips (visibly) without the ``cluster`` extra.
    """
    ray = pytest.importorskip("ray")
    import shutil
    import tempfile

    if ray.is_initialized():
        ray.shutdown()
    tmp = tempfile.mkdtemp(prefix="ray_")
    ray.init(address="local", num_cpus=2, include_dashboard=False, _temp_dir=tmp)
    yield ray
    ray.shutdown()
    shutil.rmtree(tmp, ignore_errors=True)


def _tree_hash(path: Path) -> str:
    """sha256 of every path name and file's bytes under `path` (to prove nothing there changed)."""
    import hashlib

    h = hashlib.sha256()
    for p in sorted(path.rglob("*")):
        h.update(str(p.relative_to(path)).encode())
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()


@pytest.fixture
def tree_hash():
    return _tree_hash


class _FullFile:
    """A file whose next write stores half its bytes and then fails as a full disk does."""

    def __init__(self, f):
        self.f = f

    def write(self, data):
        self.f.write(bytes(data)[: len(data) // 2])
        self.f.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()

    def __getattr__(self, name):
        return getattr(self.f, name)


class FullDiskAfter:
    """`open` for corelib.atomic: the disk fills once `n` files (whose path contains `part`) were written."""

    def __init__(self, n: int, part: str = ""):
        self.n, self.part, self.calls = n, part, 0

    def __call__(self, file, mode="r", *args, **kw):
        f = open(file, mode, *args, **kw)
        if "w" in mode and self.part in str(file):
            self.calls += 1
            if self.calls > self.n:
                return _FullFile(f)
        return f


@pytest.fixture
def full_disk_after():
    """`FullDiskAfter(n, part)`: an `open` to patch into corelib.atomic that fills the disk after n files."""
    return FullDiskAfter


def _default_signals() -> None:
    """A child's SIGINT and SIGHUP at their defaults (``preexec_fn``), as under a terminal: a test run
    started in the background (``cmd &``, nohup, some CI runners) passes them on ignored, and a child
    that inherits SIGINT ignored never sees a KeyboardInterrupt (Python keeps an inherited SIG_IGN)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_DFL)


def run_on_small_disk(cmd: list[str], mount: Path, size: str = "64k", full: bool = False, timeout: float = 300,
                      env: dict | None = None):
    """Run `cmd` with a tmpfs of `size` at `mount` (an empty folder), in a user and mount namespace of its
    own (``unshare -rm``: no root needed, nothing mounted outside it): a real disk that fills while `cmd`
    writes, or is `full` from the start. Returns (CompletedProcess, the names left in `mount` as `cmd`
    saw them). Skips where the kernel allows no such namespace. A `cmd` that hangs fails the test
    (subprocess.TimeoutExpired after `timeout` s)."""
    import shlex
    import shutil
    import subprocess

    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1): a small tmpfs needs a user and mount namespace")
    probe = subprocess.run(["unshare", "-rm", "mount", "-t", "tmpfs", "-o", "size=4k", "none", str(mount)],
                           capture_output=True, text=True, timeout=30)
    if probe.returncode != 0:
        pytest.skip(f"no user and mount namespace here (unshare -rm mount: {probe.stderr.strip()[:200]})")
    fill = f"dd if=/dev/zero of={shlex.quote(str(mount))}/fill bs=1k count=100000 2>/dev/null; " if full else ""
    script = (f"mount -t tmpfs -o size={size} none {shlex.quote(str(mount))} || exit 99; {fill}"
              f"{shlex.join(cmd)}; rc=$?; echo; echo LEFT:; ls -A {shlex.quote(str(mount))}; exit $rc")
    res = subprocess.run(["unshare", "-rm", "sh", "-c", script], capture_output=True, text=True, timeout=timeout,
                         env=env, preexec_fn=_default_signals)
    head, _, left = res.stdout.rpartition("\nLEFT:\n")
    res.stdout = head
    return res, sorted(left.split())


@pytest.fixture
def default_signals():
    """The ``preexec_fn`` that puts a child's SIGINT and SIGHUP back to their defaults (`_default_signals`)."""
    return _default_signals


@pytest.fixture
def small_disk():
    """`run_on_small_disk(cmd, mount, size, full, timeout, env)`: `cmd` on a real tmpfs that fills."""
    return run_on_small_disk


# --------------------------------------------------------------------------- a fake dataset (no rendering)
class FakeDataset(NoLabels):
    """A `synth.protocol.DatasetReader` (tests/synth/test_protocol.py checks it): two forward cameras,
    j = i shifted right (no rendering: tests/mcdp/test_evaluate.py scores it by hand; the `fake_dataset` fixture).

    The wall is fronto-parallel at z = 10 m for both cameras and the baseline gives an
    exact 3-pixel disparity, so the z-buffered splat of the true depth is exact.
    The bottom row of both cameras is ego body (mask False).
    ``scale``: the cameras' image sizes, as multiples of W x H (the same field of view: K scaled with
    them; a camera of twice the size sees the wall at a disparity of 6 of its pixels, as exact).
    """
    format = "fake"
    H, W, F_PX, Z_WALL, SHIFT_PX = 12, 16, 20.0, 10.0, 3  # image size, focal (px), wall depth (m), disparity (px)

    def __init__(self, n_frames=4, scale=(1, 1)):
        R = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # OpenCV camera axes in the ego frame
        T0 = np.eye(4)
        T0[:3, :3] = R
        T0[:3, 3] = [1.0, 0.0, 1.5]
        T1 = T0.copy()
        T1[1, 3] = -self.SHIFT_PX * self.Z_WALL / self.F_PX  # to the right
        H, W, F = self.H, self.W, self.F_PX
        hfov = math.degrees(2 * math.atan(W / 2 / F))
        self.cameras = [CameraSpec(n, W * s, H * s, np.array([[F * s, 0, W * s / 2], [0, F * s, H * s / 2],
                                                              [0, 0, 1.0]]), T, hfov, 0.0, 0.0)
                        for n, T, s in zip(("CAM_FRONT", "CAM_FRONT_RIGHT"), (T0, T1), scale)]
        self.camera_names = [c.name for c in self.cameras]
        self._hw = {c.name: (c.height, c.width) for c in self.cameras}  # each camera's images at its own size
        self.neighbours = [(0, 1)]
        self._n = n_frames
        self.depth_reads = []
        self.root = Path("fake")
        self.fps = 10.0
        self.has_depth = True
        self.ground_truth = {"kind": "unknown"}

    @property
    def sequences(self):
        return ["s0", "s1", "s_train"]

    def split(self, name):
        return {"train": ["s_train"], "val": [], "test": ["s0", "s1"]}[name]

    def n_frames(self, seq):
        return self._n

    def ego(self, seq):
        return [{"timestamp_s": f / self.fps, "T_world_ego": np.eye(4).tolist()} for f in range(self._n)]

    def T_world_ego(self, seq):
        return np.stack([np.eye(4)] * self._n)

    def rgb_path(self, seq, cam_name, frame):
        return self.root / seq / cam_name / f"{frame:06d}.png"

    def depth_path(self, seq, cam_name, frame):
        return self.root / seq / cam_name / f"{frame:06d}.depth.exr"

    def read_rgb(self, seq, cam_name, frame):
        return np.full((*self._hw[cam_name], 3), 128, np.uint8)

    def read_depth(self, seq, cam_name, frame):
        self.depth_reads.append((seq, cam_name, frame))
        return np.full(self._hw[cam_name], self.Z_WALL, dtype=np.float32)

    def mask(self, cam_name):
        m = np.ones(self._hw[cam_name], bool)
        m[-1, :] = False
        return m


@pytest.fixture(scope="session")
def fake_dataset():
    """The class `FakeDataset`: two cameras facing an analytic wall, as a dataset reader (call it for one)."""
    return FakeDataset


# --------------------------------------------------------------------------- Rerun blueprints (the viz extra)
def read_blueprint(path) -> dict[str, dict]:
    """{entity path: {component: value}} of the blueprint store of `path` (`RrdReader.blueprints`)."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    (store,) = reader.blueprints()
    out: dict[str, dict] = {}
    for chunk in reader.stream(store=store):
        rb = chunk.to_record_batch()
        for n in rb.schema.names:
            if ":" in n:
                out.setdefault(chunk.entity_path, {})[n] = rb.column(n).to_pylist()[-1]
    return out


def blueprint_views(bp: dict) -> dict[str, dict]:
    """{view id: {"class", "origin", "name", "hidden": entity paths with EntityBehavior visible=False}}."""
    views = {}
    for path, comp in bp.items():
        if "ViewBlueprint:class_identifier" in comp:
            hidden = [p.split("/ViewContents/overrides/", 1)[1].rsplit("/visualizers", 1)[0] for p, c in bp.items()
                      if p.startswith(path + "/ViewContents/overrides/") and c.get("EntityBehavior:visible") == [False]]
            views[path.strip("/")] = {"class": comp["ViewBlueprint:class_identifier"][0],
                                      "origin": comp["ViewBlueprint:space_origin"][0],
                                      "name": (comp.get("ViewBlueprint:display_name") or [None])[0], "hidden": hidden}
    return views


def _check_blueprint(path, cameras, tabs: list[str]) -> dict:
    """The blueprint of `synth.view_blueprint`: one 3-D view of world hiding the cameras' depth and masks;
    per tab a grid of one 2-D view per camera in ring order, the masks hidden; returns the views."""
    from synth.view_blueprint import ring_order

    bp = read_blueprint(path)
    views = blueprint_views(bp)
    (world,) = [v for v in views.values() if v["class"] == "3D"]
    assert world["origin"] == "world"
    names, cols = ring_order(cameras)
    assert set(f"world/ego/{n}/{p}" for n in names for p in ("depth", "ego_mask", "overlap")) <= set(world["hidden"])
    grids = {c["ContainerBlueprint:display_name"][0]: c for c in bp.values() if "ContainerBlueprint:grid_columns" in c}
    assert sorted(grids) == sorted(tabs)
    for tab, grid in grids.items():
        assert grid["ContainerBlueprint:grid_columns"] == [cols]
        order = [views[v]["origin"] for v in grid["ContainerBlueprint:contents"]]
        assert order == [f"world/ego/{n}" for n in names], tab
        for v in grid["ContainerBlueprint:contents"]:
            o = views[v]["origin"]
            assert {f"{o}/ego_mask", f"{o}/overlap"} <= set(views[v]["hidden"]), tab  # masks: toggles, off
            if tab == "RGB":
                assert f"{o}/rgb" not in views[v]["hidden"] and f"{o}/depth" in views[v]["hidden"]
            if "labels" in tabs:  # the labels show in their own tab only (and not in the 3-D view)
                labels = {f"{o}/semantic", f"{o}/flow"}
                assert labels.isdisjoint(views[v]["hidden"]) if tab == "labels" else labels <= set(views[v]["hidden"])
                assert labels <= set(world["hidden"])
    return views


@pytest.fixture(scope="session")
def check_blueprint():
    """`check_blueprint(path, cameras, tabs)`: the blueprint `synth.view_blueprint` writes into a recording,
    checked tab by tab (`synth view`, `mcdp predict --rrd`); needs the viz extra (rerun)."""
    return _check_blueprint
