"""scripts/device_check.sh's CPU path (``--device cpu --tiny``): it renders the tiny world through both back ends,
times the two presets' training steps, takes one step twice from the same weights and batch, and writes a report
whose checks pass (the CPU against itself: identical depth, an exact step)."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # two tiny renders, two training-step workers, a one-run smoke sweep and four steps: ~40 s
def test_the_cpu_path_writes_a_passing_report(tmp_path):
    out = tmp_path / "dc"
    env = {**os.environ, "PYTHON": sys.executable, "TMPDIR": str(tmp_path)}
    res = subprocess.run(["bash", str(ROOT / "scripts" / "device_check.sh"), "--device", "cpu", "--tiny",
                          "--out", str(out)], capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    report = (out / "device.md").read_text()
    assert report.startswith("# Device check\n")
    m = re.search(r"depth: (\d+) of (\d+) maps identical", report)
    assert m and m.group(1) == m.group(2) and int(m.group(2)) == 3 * 6 * 6  # 3 sequences x 6 frames x 6 cameras
    assert "0.0000% of valid pixels beyond" in report
    assert re.search(r"mono2 .*64x96|64x96.*mono2", report) and "mcdp_m2" in report
    assert "agreement: pass (allowed 0)" in report
    # the smoke sweep's whole path (one method at one overlap on the CPU path): every run of its plan
    assert re.search(r"- 1 of 1 runs trained and evaluated, results\.json written, in \d+ s .*: pass", report)
    assert re.search(r"loss (\S+) \(CPU\) against \1: relative 0\.00e\+00", report)
    # the yardstick: the CPU against itself at 1 and 2 threads (its sums in another order), a finite figure
    m = re.search(r"yardstick, the CPU at 1 thread against 2 threads: loss \S+, gradients (\S+), "
                  r"weights ([\d.e+-]+)$", report, re.M)
    assert m and all(0 <= float(x) < 0.1 for x in m.groups())


def test_a_wrong_argument_is_one_line_and_exit_2(tmp_path):
    res = subprocess.run(["bash", str(ROOT / "scripts" / "device_check.sh"), "--device", "tpu"],
                         capture_output=True, text=True, timeout=30)
    assert res.returncode == 2
    assert res.stderr == "device_check: --device must be cpu or cuda, got 'tpu'\n"
    res = subprocess.run(["bash", str(ROOT / "scripts" / "device_check.sh"), "--fast"],
                         capture_output=True, text=True, timeout=30)
    assert res.returncode == 2 and "unknown argument '--fast'" in res.stderr


@pytest.mark.slow  # the report's CPU steps: about 15 s
def test_failing_parts_are_reported_and_no_stale_table_passes(tmp_path):
    """A render, the training steps and the sweep that all fail (a PYTHON that refuses them) still give a report:
    each part says FAIL with its last line of error, the exit status is 1, and a training table left in OUT by an
    earlier run is not reported as this run's."""
    fake = tmp_path / "python"
    fake.write_text(f"#!/bin/sh\ncase \"$1\" in -) exec {sys.executable} \"$@\" ;; esac\n"
                    "echo \"planted failure: $*\" >&2\nexit 3\n")
    fake.chmod(0o755)
    out = tmp_path / "dc"
    out.mkdir()
    (out / "train_step.txt").write_text("STALE TABLE FROM AN EARLIER RUN\n")
    env = {**os.environ, "PYTHON": str(fake), "TMPDIR": str(tmp_path)}
    res = subprocess.run(["bash", str(ROOT / "scripts" / "device_check.sh"), "--device", "cpu", "--tiny",
                          "--out", str(out)], capture_output=True, text=True, env=env, timeout=600)
    assert res.returncode == 1, res.stderr[-2000:]
    report = (out / "device.md").read_text()
    assert "STALE" not in report
    assert re.search(r"- FAIL: the render did not run \(render_cpu: planted failure: -m synth render", report)
    assert "FAIL: planted failure:" in report.split("## Training steps")[1].split("##")[0]
    assert re.search(r"## The smoke sweep .*\n\n- FAIL: planted failure: -m mcdp sweep", report)
    assert "agreement: pass (allowed 0)" in report  # the part that could run did
