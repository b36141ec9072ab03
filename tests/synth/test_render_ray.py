"""`synth render --engine ray` on a local Ray (2 CPUs): the same files, byte for byte (the manifest's
sha256 map), as the local engine; a rerun skips the complete sequences."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("ray")
pytestmark = pytest.mark.slow  # a local Ray started, the tiny preset rendered twice: `pytest -m "not slow"` skips it

from synth.cli import main as synth_main  # noqa: E402

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
FRAMES = "dataset.frames=3"


def _manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def test_ray_render_writes_the_local_engines_files(local_ray, tmp_path, capsys):
    local, ray_out = tmp_path / "local", tmp_path / "ray"
    assert synth_main(["render", str(TINY), "--out", str(local), FRAMES, "--no-progress"]) == 0
    assert synth_main(["render", str(TINY), "--out", str(ray_out), FRAMES, "--engine", "ray", "--no-progress"]) == 0
    a, b = _manifest(local), _manifest(ray_out)
    # 3 seqs x (6 cams x 3 frames x (png, exr, semantic, instance), ego.json, instances.json), rig, masks
    assert len(a["files"]) == 3 * (6 * 3 * 4 + 2) + 1 + 6
    assert a["files"] == b["files"]
    assert a["overlap"] == b["overlap"] and a["splits"] == b["splits"]
    assert synth_main(["verify", str(ray_out)]) == 0

    capsys.readouterr()
    assert synth_main(["render", str(TINY), "--out", str(ray_out), FRAMES, "--engine", "ray", "--no-progress"]) == 0
    assert "rendered 0 sequence(s)" in capsys.readouterr().out  # resumed: nothing left to do
    assert _manifest(ray_out)["files"] == a["files"]
