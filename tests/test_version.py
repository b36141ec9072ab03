"""One version: pyproject.toml's, in both packages and behind --version on both commands."""
import subprocess
import sys
import tomllib
from pathlib import Path

import mcdp
import synth

ROOT = Path(__file__).resolve().parents[1]


def test_version_matches_pyproject_everywhere():
    v = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert mcdp.__version__ == synth.__version__ == v
    for cmd in (["-m", "synth.cli"], ["-m", "study.cli"]):
        out = subprocess.run([sys.executable, *cmd, "--version"], capture_output=True, text=True, timeout=120)
        assert out.returncode == 0, out.stderr
        assert out.stdout.strip().endswith(v)
