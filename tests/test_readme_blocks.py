"""The README's ```bash blocks, then the user guide's (docs/GUIDE.md, where the README's other blocks moved in issue
60), run top to bottom, in order, from a new shell in an empty folder (issue 41, item 11:
the viz block came before the commands that make data/tiny and runs/m2, a block wrote data/d five times with
different configs, later blocks used bare `synth` / `mcdp` without a word on activating .venv).

How: every ```bash block of README.md and then of docs/GUIDE.md (`DOCS`), in order, becomes one bash script (`set -e`) run in a temporary folder that
holds only links to configs/ and benchmarks/ and `.venv`, a link to the environment running this test (with
PYTHONPATH naming this checkout, so the code under test runs). Each command line is looked up in `PLAN` (the
longest matching prefix): run as written, run with the overrides that scale it down, or skipped with the reason
said here. Lines that need what a test machine may lack (`.venv-viz`, Ray) are skipped when it lacks it.

Heavy lines must say how long and how much in their README comment (checked below), and the smoke sweep's stated
sizes (68 MB of disk, the pretraining's 57 MB `pretrained.pt`, no checkpoint kept) are checked on its run here,
scaled to the runs it made.
"""
from __future__ import annotations

import importlib.util
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VENV = Path(sys.executable).parent.parent
#: the viz environment: this checkout's, else the one beside the environment running the test (a worktree's)
VIZ = next((v for v in (ROOT / ".venv-viz", VENV.parent / ".venv-viz") if v.is_dir()), None)
TRAIN_TINY = "train.steps=2 train.val_every=2 train.val_samples=1 train.ckpt_every=2"
DEFAULT_TINY = "dataset.sequences=2 dataset.frames=3 camera.width=96 camera.height=64"
NO_VIZ = "needs .venv-viz (`bash scripts/setup.sh --test`), absent here"
NO_RAY = "needs Ray (the cluster extra), absent here"

#: command-line prefix -> ("run", "") | ("scale", overrides appended) | ("skip", why)
PLAN = {
    "bash scripts/setup.sh": ("skip", "installs system packages as root and builds .venv: this test runs in the "
                                      "environment it was started from (the main job behind it is the 85-min sweep; "
                                      "its smoke version runs below)"),
    "source .venv/bin/activate": ("run", ""),
    "mcdp sweep configs/sweep/ci.yaml": ("scale", "overlaps=[0.5] methods=[mono2,mcdp_m2] --no-progress"),
    "synth render configs/data/tiny.yaml --out data/tiny": ("run", ""),
    "synth render configs/data/default.yaml": ("scale", DEFAULT_TINY),
    # the lens presets (issue 59), written small in the guide: run as written
    "synth render configs/data/fisheye.yaml": ("run", ""),
    "synth render configs/data/distorted.yaml": ("run", ""),
    "synth merge": ("run", ""), "synth verify": ("run", ""), "synth preview": ("run", ""), "synth export": ("run", ""),
    ".venv/bin/synth render configs/data/tiny.yaml --out data/w64": ("scale", "dataset.sequences=3 dataset.frames=4"),
    ".venv/bin/mcdp pretrain": ("scale", "'data_overrides=[seed=1000,dataset.frames=4]' "
                                         "'train_overrides=[train.steps=2,train.val_every=2,train.val_samples=1,"
                                         "train.ckpt_every=2]'"),
    ".venv/bin/mcdp train": ("scale", TRAIN_TINY),
    ".venv/bin/mcdp eval": ("run", ""),
    ".venv-viz/bin/rerun": ("skip", "opens the viewer's window"),
    ".venv-viz/": ("run", ""),
    "torchrun": ("scale", "train.steps=2 train.val_every=2 train.val_samples=1"),
}


#: the files whose ```bash blocks run, in this order: the README's quickstart, then the user guide
DOCS = (ROOT / "README.md", ROOT / "docs" / "GUIDE.md")


def bash_blocks() -> list[str]:
    return [b for doc in DOCS for b in re.findall(r"^```bash\n(.*?)^```", doc.read_text(), re.S | re.M)]


def command_lines(block: str) -> list[tuple[str, str]]:
    """(command, its README comment) per command line, continuation lines joined."""
    out, cur = [], ""
    for raw in block.splitlines():
        code, _, comment = raw.partition("  #") if not raw.lstrip().startswith("#") else ("", "", raw)
        code = code.rstrip()
        if cur:
            cur += " " + code.strip()
        elif code.strip():
            cur = code.strip()
        else:
            continue
        if cur.endswith("\\"):
            cur = cur[:-1].rstrip()
            continue
        out.append((cur, comment.strip()))
        cur = ""
    return out


def plan_of(cmd: str) -> tuple[str, str]:
    keys = [k for k in PLAN if cmd.startswith(k)]
    assert keys, f"README line not in tests/test_readme_blocks.py's PLAN (run, scale or skip it): {cmd}"
    kind, arg = PLAN[max(keys, key=len)]
    if kind != "skip" and cmd.startswith(".venv-viz/") and VIZ is None:
        return "skip", NO_VIZ
    if "--engine ray" in cmd and importlib.util.find_spec("ray") is None:
        return "skip", NO_RAY
    return kind, arg


def test_every_heavy_readme_line_says_how_long_and_how_much():
    """A line the test must scale down (it takes over a minute or 100 MB as written) says both in its comment."""
    for block in bash_blocks():
        for cmd, comment in command_lines(block):
            if plan_of(cmd)[0] == "scale" and not cmd.startswith("torchrun"):
                assert re.search(r"\d\s*(s|min|h)\b", comment) and re.search(r"\d\s*[MG]B\b", comment), (cmd, comment)


@pytest.mark.slow  # every README command as a subprocess, a smoke sweep among them (~100 s)
def test_the_readme_blocks_run_in_order_from_an_empty_folder(tmp_path):
    for name in ("configs", "benchmarks", "scripts"):
        (tmp_path / name).symlink_to(ROOT / name, target_is_directory=True)
    (tmp_path / ".venv").symlink_to(VENV, target_is_directory=True)
    if VIZ is not None:
        (tmp_path / ".venv-viz").symlink_to(VIZ, target_is_directory=True)
    script, skipped = ["set -eo pipefail"], []
    for block in bash_blocks():
        for cmd, _ in command_lines(block):
            kind, arg = plan_of(cmd)
            if kind == "skip":
                skipped.append(f"{cmd[:60]}: {arg}")
                continue
            line = f"{cmd} {arg}" if kind == "scale" else cmd
            script += [f"echo {shlex.quote('>>> ' + line)} >&2", line]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    res = subprocess.run(["bash", "-c", "\n".join(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=900)
    assert res.returncode == 0, res.stderr[-4000:]
    print("skipped:\n" + "\n".join(skipped))
    print({p: _du(tmp_path / p) for p in ("data/tiny", "data/w64", "pretrain/tiny", "runs/m2", "sweeps/ci")})
    # what the blocks made, in the order they made it
    for made in ("data/tiny/manifest.json", "tiny_sheet.png", "data/d/manifest.json", "data/full/manifest.json",
                 "data/d_ns", "sheet.png", "pretrain/tiny/pretrained.pt", "runs/m2/metrics_test.json", "sweeps/ci/report.md"):
        assert (tmp_path / made).exists(), made
    # the smoke sweep's stated sizes: 68 MB from an empty folder for 14 runs (the pretraining's 57 MB
    # pretrained.pt, 2 MB of worlds, 4.4 MB of runs), no checkpoint but pretrained.pt; here 2 runs of them
    text = (ROOT / "docs" / "GUIDE.md").read_text()
    total, pre, runs = (float(x) for x in re.search(r"configs/sweep/ci.yaml --out sweeps/ci`, (\d+) MB of disk from an "
                                                    r"empty folder\s+\(`du -sb`, [\d-]+: the pretraining's (\d+) MB "
                                                    r"`pretrained.pt`, \d+ MB of worlds, ([\d.]+) MB of runs\)", text,
                                                    re.S).groups())
    sweep = tmp_path / "sweeps" / "ci"
    du = _du
    pts = [f for f in sweep.rglob("*.pt")]
    assert [f.name for f in pts] == ["pretrained.pt"], pts
    assert abs(pts[0].stat().st_size / 1e6 - pre) < 1.0, pts[0].stat().st_size
    n = len(list((sweep / "runs").glob("*/*_s*/")))
    assert n == 2 and du(sweep / "runs") <= 2 * n * runs / 14 * 1e6, du(sweep / "runs")
    assert du(sweep) <= total * 1e6, du(sweep)


def _du(path: Path) -> int:
    """Bytes of the regular files under `path`."""
    return sum(f.stat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())
