"""Shared fixtures: one tiny dataset rendered once per test session (CPU, EGL/OSMesa llvmpipe)."""
from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

# Import torch (and the parts of it that load triton's LLVM) BEFORE any test renders in
# this process: loading that LLVM after Mesa llvmpipe's has segfaulted `import torch.fx`.
# The `synth` and `mcdp` CLIs never mix the two in one process order that triggers it
# (mcdp imports torch first; render workers are spawned processes).
import torch  # noqa: F401,E402
import torch.fx  # noqa: F401,E402
import torchvision  # noqa: F401,E402

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "data" / "tiny.yaml"


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

    out = tmp_path_factory.mktemp("ns") / "root"
    export_nuscenes(tiny_dataset, out, version="v1.0-synth")
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


def default_signals() -> None:
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
                         env=env, preexec_fn=default_signals)
    head, _, left = res.stdout.rpartition("\nLEFT:\n")
    res.stdout = head
    return res, sorted(left.split())


@pytest.fixture
def small_disk():
    """`run_on_small_disk(cmd, mount, size, full, timeout, env)`: `cmd` on a real tmpfs that fills."""
    return run_on_small_disk
