"""Trainer on the tiny render: exact resume, determinism, config conflicts, NaN guard, checkpoints.

Learning itself is tested without a long trajectory in test_learning.py (the signal, one overfit)."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdp.config import RunConfig
from mcdp.runs import RunError, load_checkpoint
from mcdp.system import SelfSupervisedSystem
from mcdp.trainer import Trainer, TrainingDiverged
from corelib.configlib import load_config

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "train" / "tiny"


def cfg_of(preset: str, *overrides: str) -> RunConfig:
    return load_config(RunConfig, TINY / f"{preset}.yaml", list(overrides))


def train(ds, run: Path, preset: str, *overrides: str, until: int | None = None) -> dict:
    tr = Trainer(cfg_of(preset, *overrides), ds, run, progress=False, tensorboard=False)
    try:
        return tr.train(until=until)
    finally:
        tr.close()


def state_of(run: Path) -> dict:
    return load_checkpoint(run / "checkpoints" / "last.pt")


def assert_same_state(a: dict, b: dict) -> None:
    for key in ("depth_model", "pose_model"):
        sa, sb = a[key], b[key]
        if sa is None:
            assert sb is None
            continue
        assert sa.keys() == sb.keys()
        for k in sa:
            assert torch.equal(sa[k], sb[k]), f"{key}.{k} differs"
    oa, ob = a["optimizer"]["state"], b["optimizer"]["state"]
    assert oa.keys() == ob.keys()
    for k in oa:
        for kk in ("exp_avg", "exp_avg_sq"):
            assert torch.equal(oa[k][kk], ob[k][kk]), f"optimizer state {k}.{kk} differs"


# --------------------------------------------------------------------------- resume and determinism
@pytest.mark.slow
def test_resume_is_exact_and_runs_are_seeded(ds, tmp_path):
    ov = ("train.steps=4", "train.ckpt_every=2", "train.val_every=2", "train.color_aug=true")
    train(ds, tmp_path / "straight", "mcdp_m1", *ov)
    train(ds, tmp_path / "again", "mcdp_m1", *ov)
    train(ds, tmp_path / "split", "mcdp_m1", *ov, until=3)  # as if killed after step 3
    assert state_of(tmp_path / "split")["step"] == 3
    summary = train(ds, tmp_path / "split", "mcdp_m1", *ov)  # same command again: resumes at step 3
    assert summary["trained"] == 1 and summary["steps"] == 4
    a, b, c = state_of(tmp_path / "straight"), state_of(tmp_path / "again"), state_of(tmp_path / "split")
    assert a["step"] == b["step"] == c["step"] == 4
    assert_same_state(a, b)  # same seed, same bytes
    assert_same_state(a, c)  # 3 + 1 steps == 4 steps
    assert a["val_history"] == c["val_history"]
    assert not list((tmp_path / "straight" / "checkpoints").glob("*.tmp"))  # atomic writes leave no temp files
    best = torch.load(tmp_path / "straight" / "checkpoints" / "best.pt", map_location="cpu", weights_only=False)
    assert "optimizer" not in best and "depth_model" in best  # best.pt: weights for inference only
    assert best["step"] in [s for s, _ in a["val_history"]]


def test_different_seed_gives_different_weights(ds, tmp_path):
    train(ds, tmp_path / "a", "mono2", "train.steps=1")
    train(ds, tmp_path / "b", "mono2", "train.steps=1", "train.seed=1")
    sa, sb = state_of(tmp_path / "a")["depth_model"], state_of(tmp_path / "b")["depth_model"]
    assert any(not torch.equal(sa[k], sb[k]) for k in sa)


def test_resuming_a_run_made_by_other_code_warns_once_and_resumes(ds, tmp_path, capsys):
    from corelib.version import code_version

    run = tmp_path / "run"
    train(ds, run, "mono2", "train.steps=1")
    assert state_of(run)["code_version"] == code_version()  # every checkpoint records the code that wrote it
    capsys.readouterr()
    train(ds, run, "mono2", "train.steps=2")  # the same code resumes without a word
    assert "made by code" not in capsys.readouterr().err
    ckpt = state_of(run)
    ckpt["code_version"] = "0.0.1+src.000000000000"
    torch.save(ckpt, run / "checkpoints" / "last.pt")
    summary = train(ds, run, "mono2", "train.steps=3")
    err = capsys.readouterr().err
    assert summary["trained"] == 1 and state_of(run)["step"] == 3  # a warning, not a refusal
    lines = [ln for ln in err.splitlines() if "made by code 0.0.1+src.000000000000" in ln]
    assert len(lines) == 1 and "last.pt" in lines[0] and code_version() in lines[0], err


def test_resume_with_a_conflicting_config_names_the_keys(ds, tmp_path):
    run = tmp_path / "run"
    train(ds, run, "mcdp_m1", "train.steps=1")
    with pytest.raises(RunError) as exc:
        Trainer(cfg_of("mcdp_m1", "train.steps=2", "model.bases=4", "loss.consistency_weight=0.5"), ds, run,
                progress=False, tensorboard=False)
    msg = str(exc.value)
    assert "model.bases" in msg and "loss.consistency_weight" in msg
    assert "checkpoint has 8, requested 4" in msg
    assert "train.steps" not in msg  # extending a run is allowed


# --------------------------------------------------------------------------- guards and logs
def test_nan_loss_stops_with_a_clear_message(ds, tmp_path, monkeypatch):
    orig = SelfSupervisedSystem.compute_losses

    def poisoned(self, *a, **kw):
        losses = orig(self, *a, **kw)
        losses["loss"] = losses["loss"] * float("nan")
        return losses

    monkeypatch.setattr(SelfSupervisedSystem, "compute_losses", poisoned)
    with pytest.raises(TrainingDiverged, match=r"loss is nan at step 0; terms: .*photometric/init="):
        train(ds, tmp_path / "run", "mono2", "train.steps=2")


def test_tensorboard_scalars_and_images_are_written(ds, tmp_path):
    run = tmp_path / "run"
    tr = Trainer(cfg_of("mcdp_m1", "train.steps=2"), ds, run, progress=False, tensorboard=True)
    tr.train()
    tr.close()
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(run / "tensorboard"))
    acc.Reload()
    tags = acc.Tags()
    assert "train/loss" in tags["scalars"] and "train/photometric/refine1" in tags["scalars"]
    assert "train/consistency/init" in tags["scalars"] and "val/loss" in tags["scalars"]
    assert "rig/rgb_depth_per_stage_masks" in tags["images"]
    assert (run / "config.yaml").is_file() and (run / "run.json").is_file()


def test_velocity_scale_supervises_the_pose_translation(ds, tmp_path):
    cfg = cfg_of("mono2", "train.steps=1")
    tr = Trainer(cfg, ds, tmp_path / "run", progress=False, tensorboard=False)
    from mcdp.data import collate

    batch = tr.to_device(collate([tr.train_set[0]]))
    _, losses = tr.system.process_batch(batch, 0, train=False)
    tr.close()
    # the tiny render drives ~2 m per frame; a fresh pose net predicts ~0 m
    assert float(losses["pose/t_norm_odom"]) > 0.5
    assert float(losses["pose/velocity"].detach()) == pytest.approx(
        abs(float(losses["pose/t_norm_odom"]) - float(losses["pose/t_norm_pred"])), rel=0.2)


class _RunsCode:
    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        import os

        return (os.system, (f"touch {self.marker}",))


def test_a_checkpoint_whose_pickle_runs_code_is_refused_and_the_code_does_not_run(tmp_path):
    bad = tmp_path / "last.pt"
    torch.save({"version": 1, "config": {}, "payload": _RunsCode(tmp_path / "pwned")}, bad)
    with pytest.raises(RunError, match="not a plain weights file") as err:
        load_checkpoint(bad)
    assert str(bad) in str(err.value) and len(str(err.value)) < 400
    assert not (tmp_path / "pwned").exists()


def test_the_val_loss_is_the_steps_own_final_stage_loss(ds, tmp_path, one_thread):
    """Validation reads the step's ``stage/<final>`` loss (nothing re-weighted in mcdp.validation), and that
    value is what picks best.pt: L_p + lambda L_con of the final stage, the same batch in eval mode."""
    from mcdp.data import collate
    from mcdp.validation import validation_loss

    tr = Trainer(cfg_of("mcdp_m1", "train.steps=1"), ds, tmp_path / "run", progress=False, tensorboard=False)
    try:
        i = tr.val_indices()[0]
        val, _ = validation_loss(tr.system, tr.val_set, [i], tr.step, tr.dist, tr.device)
        tr.depth.eval()
        tr.pose.eval()
        with torch.no_grad():
            _, losses = tr.system.process_batch(tr.to_device(collate([tr.val_set[i]])), tr.step, train=False)
        tr.depth.train()
        tr.pose.train()
    finally:
        tr.close()
    final, lam = tr.depth.stages[-1], tr.cfg.loss.consistency_weight
    assert final == "refine1" and lam > 0 and float(losses[f"consistency/{final}"]) > 0
    assert val == float(losses[f"stage/{final}"])
    assert val == pytest.approx(float(losses[f"photometric/{final}"] + lam * losses[f"consistency/{final}"]),
                                rel=1e-6)
