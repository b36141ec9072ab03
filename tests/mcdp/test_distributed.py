"""torchrun / DDP on CPU (gloo): 2 processes train, rank 0 writes a checkpoint that `mcdp eval`
reads, the run agrees with a 1-process run of the same global batch, and resume under torchrun is
exact (and works with another number of processes)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from study.method_commands import main
from mcdp.runs import load_checkpoint

ROOT = Path(__file__).resolve().parents[2]
PRESET = str(ROOT / "configs/train/tiny/mono2.yaml")
# lr_decay_at=1.0: the schedule does not depend on train.steps, so 2 + 2 steps == 4 steps
COMMON = ["--no-progress", "train.batch_size=2", "train.threads=1", "train.num_workers=0", "train.val_every=2",
          "train.ckpt_every=2", "train.lr_decay_at=1.0"]


def torchrun(nproc: int, data: Path, out: Path, *overrides: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={nproc}",
           "-m", "mcdp", "train", PRESET, "--data", str(data), "--out", str(out), *COMMON, *overrides]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def weights(path: Path) -> dict:
    return {k: v for k, v in load_checkpoint(path)["depth_model"].items() if v.is_floating_point()}


@pytest.fixture(scope="module")
def two_rank_run(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("ddp") / "r2"
    proc = torchrun(2, tiny_dataset, out, "train.steps=4")
    return out, proc


@pytest.mark.slow  # torchrun processes / training
def test_two_ranks_train_and_rank_0_writes_a_checkpoint_eval_reads(two_rank_run, tiny_dataset, capsys):
    out, proc = two_rank_run
    ckpt = load_checkpoint(out / "checkpoints" / "last.pt")
    assert ckpt["step"] == 4 and ckpt["world_size"] == 2
    assert proc.stderr.count("mcdp train: step 4") == 1  # rank 0 alone reports
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == ["best.pt", "last.pt", "written.json"]
    assert main(["eval", str(out), "--data", str(tiny_dataset), "--no-progress", "--checkpoint", "last"]) == 0
    assert (out / "metrics_test.json").is_file()


@pytest.mark.slow  # torchrun processes / training
def test_two_ranks_match_one_process_of_the_same_global_batch(two_rank_run, tiny_dataset, tmp_path, one_thread):
    """Same samples, same augmentation, gradients averaged by DDP; the one difference is that each rank's
    BatchNorm normalises its own half of the batch (there is no SyncBatchNorm on CPU). Measured on the
    tiny preset: val loss 0.05 % / 1.2 % apart at steps 2 / 4; asserted: 5 %."""
    out, _ = two_rank_run
    one = tmp_path / "r1"
    assert main(["train", PRESET, "--data", str(tiny_dataset), "--out", str(one), *COMMON, "train.steps=4"]) == 0
    v2 = dict(load_checkpoint(out / "checkpoints" / "last.pt")["val_history"])
    v1 = dict(load_checkpoint(one / "checkpoints" / "last.pt")["val_history"])
    assert sorted(v1) == sorted(v2) == [2, 4]
    for step in (2, 4):
        assert abs(v2[step] - v1[step]) <= 0.05 * v1[step], (step, v1[step], v2[step])


@pytest.mark.slow  # torchrun processes / training
def test_resume_under_torchrun_is_exact_and_another_world_size_resumes(two_rank_run, tiny_dataset, tmp_path, capsys,
                                                                      one_thread):
    out, _ = two_rank_run
    part = tmp_path / "part"
    torchrun(2, tiny_dataset, part, "train.steps=2")
    assert load_checkpoint(part / "checkpoints" / "last.pt")["step"] == 2
    # the same 2-rank run at step 2, to be continued by one process below: a copy of this one (a third
    # torchrun launch would train the same two steps again)
    other = tmp_path / "other"
    shutil.copytree(part, other)
    torchrun(2, tiny_dataset, part, "train.steps=4")  # resumes at step 2
    a, b = weights(out / "checkpoints" / "last.pt"), weights(part / "checkpoints" / "last.pt")
    assert all(torch.equal(a[k], b[k]) for k in a), "2 + 2 steps under torchrun differ from 4 steps"
    # the 2-rank run at step 2 continued by one process: allowed, said once, and it trains on
    assert load_checkpoint(other / "checkpoints" / "last.pt")["world_size"] == 2
    # in process (`mcdp train` as its console script runs it; the torchrun launches above are the CLI end to end)
    capsys.readouterr()
    assert main(["train", PRESET, "--data", str(tiny_dataset), "--out", str(other), *COMMON, "train.steps=4"]) == 0
    assert capsys.readouterr().err.count("resuming a run trained on 2 process(es) with 1") == 1
    ck = load_checkpoint(other / "checkpoints" / "last.pt")
    assert ck["step"] == 4 and ck["world_size"] == 1


def test_a_global_batch_that_does_not_split_over_the_ranks_is_refused():
    from mcdp.data import StepBatchSampler

    with pytest.raises(ValueError, match="train.batch_size=3 .* multiple of the 2 ranks"):
        StepBatchSampler(10, 3, 0, 0, 1, rank=0, world=2)
    shares = [list(StepBatchSampler(10, 4, 0, 0, 3, rank=r, world=2)) for r in (0, 1)]
    whole = list(StepBatchSampler(10, 4, 0, 0, 3))
    assert [a + b for a, b in zip(*shares)] == whole


def test_precision_is_resolved_per_device():
    from mcdp.runs import RunError, resolve_precision

    cpu = torch.device("cpu")
    assert resolve_precision("auto", cpu) == (False, torch.float32)
    assert resolve_precision("bf16", cpu) == (True, torch.bfloat16)
    with pytest.raises(RunError, match="fp16 needs a CUDA device"):
        resolve_precision("fp16", cpu)


@pytest.mark.slow  # torchrun processes / training
def test_bf16_autocast_trains_on_cpu(tiny_dataset, tmp_path, one_thread):
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.trainer import Trainer
    from synth.open import open_dataset

    # one validation sample (the preset's 2): bf16 on a CPU without native support is ~10x fp32, and the
    # validation at the last step runs under autocast either way
    cfg = load_config(RunConfig, PRESET, ["train.steps=2", "train.precision=bf16", "train.num_workers=0",
                                          "train.val_samples=1"])
    tr = Trainer(cfg, open_dataset(tiny_dataset), tmp_path / "run", progress=False, tensorboard=False)
    try:
        s = tr.train()
    finally:
        tr.close()
    assert tr.use_amp and tr.amp_dtype == torch.bfloat16
    assert s["steps"] == 2 and all(torch.isfinite(torch.tensor(s["losses"])))


def test_an_old_checkpoint_config_with_train_amp_still_loads():
    from mcdp.config import upgrade_config_dict

    assert upgrade_config_dict({"train": {"amp": True, "steps": 3}})["train"] == {"precision": "auto", "steps": 3}
    assert upgrade_config_dict({"train": {"amp": False}})["train"] == {"precision": "fp32"}
    from corelib.configlib import load_config
    from mcdp.config import RunConfig

    assert load_config(RunConfig, PRESET, ["train.amp=false"]).train.precision == "fp32"  # an old preset too
