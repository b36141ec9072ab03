"""The README's "Python API" block runs as it stands, from a folder that is not the project's.

The block is cut out of README.md (the first ```python fence under "### Python API") and run by this
interpreter in a fresh working directory holding only ``data/tiny`` (the tests' tiny render, linked),
so a preset path that only worked from the repository root, or a name the block uses that moved, fails
here. PYTHONPATH names this checkout so the block imports the code under test, not another install."""
from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def readme_python_block() -> str:
    text = (ROOT / "docs" / "GUIDE.md").read_text()  # moved from the README (issue 60)
    section = text.split("### Python API\n", 1)[1]
    m = re.search(r"```python\n(.*?)```", section, re.S)
    assert m, "no ```python block under '### Python API' in docs/GUIDE.md"
    return m.group(1)


def test_the_readme_python_block_runs_from_any_folder(tiny_dataset, tmp_path):
    code = readme_python_block()
    assert "configs/" in code and "data/tiny" in code  # what the block is meant to show: presets from anywhere
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "tiny").symlink_to(tiny_dataset, target_is_directory=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    res = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True,
                         timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    lines = res.stdout.splitlines()
    assert lines[0].startswith("['CAM_FRONT', ") and "seq_" in lines[0], res.stdout
    assert lines[1].startswith("mcdp ['init', 'refine1', 'refine2'] "), res.stdout
    abs_rel = float(lines[2].rsplit(" ", 1)[1])
    assert 0.05 < abs_rel < 0.84, res.stdout  # a working prior: well below a constant depth's ~0.84
