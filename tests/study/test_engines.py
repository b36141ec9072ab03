"""The engines: the switch without Ray installed (`--engine ray` says in one line how to install it, and writes
nothing), and Ctrl-C on a parallel sweep (issue 49, item 7)."""
from __future__ import annotations

import sys
from pathlib import Path

import pytest

from study import cli as study_cli
from study.sweep import config as sweep
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


# a sweep of two runs, jobs=2, whose runs sleep (study.sweep.engines._stage_job replaced); its workers import this file as
# they import the `mcdp` script, and are told to take 30 s over it (as a loaded machine takes over torch's import)
_CTRL_C_SWEEP = '''
import os, signal, sys, time
from pathlib import Path

import pytest

HERE = Path(sys.argv[1])
if __name__ == "__mp_main__":  # a spawned worker, still starting
    (HERE / "worker.pid").write_text(str(os.getpid()))
    time.sleep(30)


def slow_job(*args):
    time.sleep(600)


if __name__ == "__main__":
    from concurrent.futures import ProcessPoolExecutor

    from study import sweep_command as sweep
    from study.sweep import engines
    from study.cli import main
    from study.sweep.stages import Counters

    engines._stage_job = slow_job
    submit = ProcessPoolExecutor.submit

    def submit_then_interrupt(self, *args, **kw):
        fut = submit(self, *args, **kw)
        ProcessPoolExecutor.submit = submit  # the first submission only
        t0 = time.monotonic()
        while not (HERE / "worker.pid").exists() and time.monotonic() - t0 < 200:
            time.sleep(0.05)
        # Ctrl-C on a terminal reaches the process group, the starting worker included; `kill -INT` the sweep only
        os.killpg(0, signal.SIGINT) if sys.argv[2] == "group" else os.kill(os.getpid(), signal.SIGINT)
        return fut

    ProcessPoolExecutor.submit = submit_then_interrupt
    todo = [({"overlap": 0.2}, "mono2", 0), ({"overlap": 0.2}, "mono2", 1)]
    sweep._run_sweep = lambda cfg, out, progress, log, source: engines.run_all(cfg, todo, out, Counters(), log, False)
    sys.exit(main(["sweep", "configs/sweep/ci.yaml", "--out", str(HERE / "sweep"), "--no-progress", "jobs=2",
                   "pretrain=null", "methods=[mono2]", "overlaps=[0.2]", "seeds=[0,1]"]))
'''


@pytest.mark.slow  # a subprocess that imports torch, and its spawned worker
@pytest.mark.parametrize("to", ["group", "parent"])
def test_ctrl_c_right_after_a_run_is_submitted_is_one_line_and_ends_the_workers(tmp_path, to, default_signals):
    """Issue 49, item 7: SIGINT while the first of two runs is being submitted (its worker still starting):
    exit 130 with the one line "mcdp sweep: interrupted", no traceback (the pool's management thread raised
    InvalidStateError: CANCELLED for futures cancelled by hand; a starting worker printed its KeyboardInterrupt),
    and the worker ended at once (the sweep waited for the running run when interrupted during submission)."""
    import os
    import subprocess

    (tmp_path / "driver.py").write_text(_CTRL_C_SWEEP)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"), str(tmp_path), to], cwd=ROOT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, preexec_fn=default_signals,
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=240)  # the worker's run would take 600 s
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, 9)
            proc.wait()
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "Error" not in err, err[-3000:]
    lines = err.strip().splitlines()
    assert lines[-1] == "mcdp sweep: interrupted" and err.count("interrupted") == 1, err[-3000:]
    worker = int((tmp_path / "worker.pid").read_text())
    state = Path(f"/proc/{worker}/stat").read_text().rsplit(")", 1)[1].split()[0] \
        if Path(f"/proc/{worker}").exists() else "gone"
    assert state in ("gone", "Z"), f"the worker {worker} outlived the interrupted sweep ({state})"
