"""The engine switch without Ray installed: `--engine ray` says in one line how to install it, and writes nothing."""
from __future__ import annotations

import sys
from pathlib import Path

from study import cli as study_cli
from study import config as sweep
from synth.cli import main as synth_main

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
HINT = "install the extra: pip install -e '.[cluster]'"


def test_engine_key_and_flag():
    assert sweep.load_sweep_config(CI).engine == "local"
    assert sweep.load_sweep_config(CI, ["engine=ray", "ray_cpus=2"]).ray_cpus == 2
    assert sweep.load_sweep_config(CI, ["engine=ray"], {"engine": "local"}).engine == "local"  # the flag wins


def test_engine_ray_without_ray_is_one_clear_line(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    out = tmp_path / "sweep"
    assert study_cli.main(["sweep", str(CI), "--out", str(out), "--engine", "ray", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and HINT in err[0] and not out.exists()
    data = tmp_path / "data"
    assert synth_main(["render", str(ROOT / "configs" / "data" / "tiny.yaml"), "--out", str(data), "--engine", "ray",
                       "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and HINT in err[0] and not data.exists()
