"""The [viz] tests (Rerun recordings, glTF export) in the environment that has the extra.

rerun-sdk 0.41 requires numpy >= 2 and nuscenes-devkit 1.2.0 numpy < 2, so `scripts/setup.sh --test`
installs [viz] into a second environment, ``.venv-viz``. When this interpreter lacks the extra and
``.venv-viz`` exists, this test runs the viz test modules there, so the README's test command
(``.venv/bin/python -m pytest -q -n 2 --dist loadfile``) covers them; where this interpreter has the extra they
run directly."""
from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VIZ_TESTS = ["tests/synth/test_view.py", "tests/synth/test_gltf_export.py", "tests/mcdp/test_recording.py"]


@pytest.mark.slow  # the viz tests in .venv-viz, a pytest of their own
def test_viz_tests_pass_in_the_viz_environment():
    if all(importlib.util.find_spec(m) is not None for m in ("rerun", "trimesh")):
        pytest.skip("this interpreter has the viz extra: the viz tests run directly in this session")
    py = ROOT / ".venv-viz" / "bin" / "python"
    if not py.exists():
        pytest.skip("no viz extra here and no .venv-viz: bash scripts/setup.sh --test (or pip install -e '.[viz]')")
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTEST_")}
    res = subprocess.run([str(py), "-m", "pytest", "-q", "-p", "no:cacheprovider", *VIZ_TESTS], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=1800)
    tail = (res.stdout + res.stderr)[-3000:]
    assert res.returncode == 0, tail
    m = re.search(r"(\d+) passed", tail)
    assert m and int(m.group(1)) > 0 and "skipped" not in tail.splitlines()[-1], tail


@pytest.mark.parametrize("module,argv", [
    ("rerun", ["synth", "view", "{tmp}/no_data", "--out", "{tmp}/rig.rrd"]),
    ("rerun", ["mcdp", "predict", "{tmp}/no_run", "--data", "{tmp}/no_data", "--rrd", "{tmp}/pred.rrd"]),
    ("trimesh", ["synth", "export", "{tmp}/no_data", "--format", "gltf", "--out", "{tmp}/gltf"]),
])
def test_a_missing_viz_extra_names_the_environment_that_has_it(module, argv, tmp_path, monkeypatch, capsys):
    """Without the extra, each viz command fails with one line (exit 2) that names .venv-viz and the setup
    command that makes it, before it reads anything: not `pip install -e '.[viz]'` into this environment."""
    from study.cli import main as mcdp_main
    from synth.cli import main as synth_main

    monkeypatch.setitem(sys.modules, module, None)  # `import rerun` / `import trimesh` raise ImportError
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    code = (synth_main if argv[0] == "synth" else mcdp_main)(argv[1:])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1, err
    assert f"optional extra 'viz' ({'rerun-sdk' if module == 'rerun' else 'trimesh'})" in err
    assert ".venv-viz" in err and "bash scripts/setup.sh --test" in err, err
    assert list(tmp_path.iterdir()) == []
