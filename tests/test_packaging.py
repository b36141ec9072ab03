"""Packaging odds and ends (issue 41, item 15): ``python -m synth`` runs the synth command line, and
pyproject.toml names its license as an SPDX string with its license file (the ``license = {text = ...}`` table
stops building after 2027-02-18), with a setuptools that reads it."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_python_m_synth_runs_the_synth_command_line():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    got = subprocess.run([sys.executable, "-m", "synth", "--help"], capture_output=True, text=True, env=env,
                         cwd=ROOT, timeout=120)
    assert got.returncode == 0, got.stderr
    assert "render" in got.stdout and "verify" in got.stdout


def test_the_license_is_an_spdx_string_with_its_file():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert meta["project"]["license"] == "MIT" and meta["project"]["license-files"] == ["LICENSE"]
    assert (ROOT / "LICENSE").is_file()
    req = next(r for r in meta["build-system"]["requires"] if r.startswith("setuptools"))
    assert int(re.search(r">=(\d+)", req).group(1)) >= 77  # the first setuptools that reads PEP 639's fields


def test_setuptools_reads_the_project_table():
    from setuptools.config.pyprojecttoml import read_configuration

    cfg = read_configuration(ROOT / "pyproject.toml")
    assert cfg["project"]["license"] == "MIT"
