"""Fixtures shared by the sweep tests: the smallest sweep with a pretraining, run once per session."""
from __future__ import annotations

import contextlib
import io
import json
import shutil
from pathlib import Path
from typing import NamedTuple

import pytest

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
#: the smallest sweep with a pretraining: configs/sweep/ci.yaml at one overlap, one method, in process
MINI = ["--no-progress", "overlaps=[0.5]", "methods=[mono2]", "jobs=1", "workers=1", "preview=false",
        "pretrain.workers=1"]


class MiniSweep(NamedTuple):
    out: Path        # the sweep folder: copy it (copy_to), never write into it
    err: str         # what the sweep wrote to stderr
    results: dict    # its results.json
    args: list[str]  # the overrides it ran with (MINI)

    def copy_to(self, dst: Path, *parts: str) -> Path:
        """A copy of the whole sweep folder (or of only its ``parts``, e.g. ``data``, ``pretrain``, and the marker
        that makes it a sweep folder) at ``dst``."""
        from corelib.rundir import MARKER

        if not parts:
            shutil.copytree(self.out, dst)
        for p in parts:
            shutil.copytree(self.out / p, dst / p)
        if parts:
            shutil.copy2(self.out / MARKER, dst / MARKER)
        return dst


@pytest.fixture(scope="session")
def mini_sweep(tmp_path_factory) -> MiniSweep:
    """``mcdp sweep configs/sweep/ci.yaml MINI`` from an empty folder (render, pretraining, one run trained and
    evaluated, the report), once: the tests that start from such a sweep (a rerun, a copied folder) copy it."""
    from study import cli as study_cli

    out = tmp_path_factory.mktemp("mini") / "sweep"
    err = io.StringIO()
    with contextlib.redirect_stderr(err):  # the sweep logs to the current sys.stderr (corelib.logs)
        rc = study_cli.main(["sweep", str(CI), "--out", str(out), *MINI])
    assert rc == 0, err.getvalue()[-3000:]
    return MiniSweep(out, err.getvalue(), json.loads((out / "results.json").read_text()), list(MINI))


def _write_dataset(out: Path, h: str, target: float, **extra) -> None:
    """A finished dataset's rig.json and manifest.json at `out` (two 8x6 cameras, 3 sequences of 3 frames, no
    image): its config hash `h`, its overlap `target`, and `extra` manifest keys (None: left out)."""
    cams = ["CAM_A", "CAM_B"]
    out.mkdir(parents=True)
    eye = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    rig = {"cameras": [{"name": n, "width": 8, "height": 6, "K": [[4, 0, 4], [0, 4, 3], [0, 0, 1]], "T_ego_cam": eye,
                        "hfov_deg": 90.0, "yaw_deg": 0.0} for n in cams], "neighbours": [[0, 1]]}
    overlap = {"target": target, "mode": "spacing", "per_pair_measured": {
        "CAM_A-CAM_B": {"target": target, "measured": 0.2}, "CAM_B-CAM_A": {"target": -0.1, "measured": 0.0}}}
    manifest = {"schema_version": 1, "generator": "mcdp-synth", "cameras": cams,
                "image_size": {"width": 8, "height": 6}, "fps": 10,
                "splits": {"train": ["seq_0000", "seq_0001"], "val": [], "test": ["seq_0002"]},
                "sequences": {f"seq_000{i}": {"frames": 3} for i in range(3)}, "files": {}, "config_hash": h,
                "overlap": overlap, **{k: v for k, v in extra.items() if v is not None}}
    (out / "rig.json").write_text(json.dumps(rig))
    (out / "manifest.json").write_text(json.dumps(manifest))


@pytest.fixture
def write_dataset():
    """`write_dataset(out, config_hash, overlap, **manifest_keys)`: a rendered dataset's records, no images."""
    return _write_dataset
