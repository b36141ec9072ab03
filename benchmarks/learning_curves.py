"""Learning curves: test-split depth accuracy of a training recipe against steps and CPU minutes.

Feeds: docs/results/learning.md
Record: ``--record PATH.csv`` also writes the table's rows to PATH (the CSV `scripts/publish_bench.py` reads).

Trains one preset (self-supervised, no ground truth) and, optionally, the same
depth network supervised with ground-truth depth (log-L1; the upper bound),
evaluating on the test split every ``--every`` steps. Every table carries its
yardsticks: a constant depth (train-split median GT) and the flat-road prior
(camera height and the ground plane, no training; `mcdp.priors`).

    python benchmarks/learning_curves.py --data data/lc --preset configs/train/tiny/mono2.yaml \
        --steps 600 --every 100 [--supervised] [key=value ...]

The dataset is rendered first if ``--data`` does not exist (``--render-sequences``).
CPU minutes are process CPU time (user + system) of the training only.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mcdp.config import RunConfig  # noqa: E402
from mcdp.evaluate import EvalConfig, evaluate  # noqa: E402
from mcdp.priors import constant_depth_predictor, median_gt_depth  # noqa: E402
from mcdp.predict import Predictor  # noqa: E402
from mcdp.priors import flat_road_predictor  # noqa: E402
from mcdp.trainer import Trainer  # noqa: E402
from corelib.configlib import load_config  # noqa: E402
from synth.open import open_dataset  # noqa: E402
from benchmarks._table import show  # noqa: E402
from corelib.text import bounded  # noqa: E402

EVAL = EvalConfig(min_depth=0.5, max_depth=80.0, frame_stride=2, skip_ends=True)


def cpu_s() -> float:
    t = os.times()
    return t.user + t.system


def summary(metrics: dict, stage: str = "final") -> dict:
    st = metrics["stages"][stage]
    return {
        "med_abs_rel": st["median"]["mean"]["abs_rel"],
        "med_a1": st["median"]["mean"]["a1"],
        "abs_rel": st["none"]["mean"]["abs_rel"],
        "a1": st["none"]["mean"]["a1"],
        "dep_con": st["dep_con"]["mean"],
    }


def ensure_data(path: Path, sequences: int, frames: int, overrides: list[str]) -> None:
    if (path / "manifest.json").exists():
        return
    cmd = [sys.executable, "-m", "synth.cli", "render", str(ROOT / "configs/data/tiny.yaml"), "--out", str(path),
           f"dataset.sequences={sequences}", f"dataset.frames={frames}", *overrides]
    print("rendering:", bounded(" ".join(cmd)), file=sys.stderr)
    subprocess.run(cmd, check=True)


def depth_stats(pred: Predictor, ds, n: int = 4) -> dict:
    """Spread of predicted depth on a few test rigs: p10, p50, p90 (metres)."""
    vals = []
    for seq in ds.split("test")[:n]:
        d = pred.predict(seq, 1)
        vals.append(np.stack(d[list(d)[-1]]).ravel())
    v = np.concatenate(vals)
    return {"p10": float(np.percentile(v, 10)), "p50": float(np.percentile(v, 50)), "p90": float(np.percentile(v, 90))}


class SupervisedRun:
    """The upper bound: the same depth network trained with ground-truth depth (log-L1), same data and schedule.

    Reads ground truth by design (benchmark only; never a method of the project).
    """

    def __init__(self, cfg, ds):
        from mcdp.data import RigDataset, neighbour_table
        from mcdp.methods import build_network

        self.cfg, self.ds = cfg, ds
        tc = cfg.train
        if tc.threads > 0:
            torch.set_num_threads(tc.threads)
        torch.manual_seed(tc.seed)
        self.network = build_network(cfg.model)
        if cfg.model.init_from:
            from mcdp.warmstart import warm_start

            warm_start(self.network, cfg.model.init_from)
        self.opt = torch.optim.Adam(self.network.parameters(), lr=tc.lr)
        self.train_set = RigDataset(ds, "train", tc.height, tc.width)
        self.nbr = neighbour_table(ds.neighbours, len(ds.camera_names))
        self.step = 0

    def gt(self, batch) -> torch.Tensor:
        import cv2

        H, W = self.cfg.train.height, self.cfg.train.width
        out = []
        for k, t in zip(batch.seq_index.tolist(), batch.frame.tolist()):
            seq = self.train_set.seqs[k]
            for n in self.ds.camera_names:
                g = np.asarray(self.ds.read_depth(seq, n, t), np.float32)
                if g.shape != (H, W):
                    g = cv2.resize(g, (W, H), interpolation=cv2.INTER_NEAREST)
                out.append(g)
        return torch.from_numpy(np.stack(out))[:, None]

    def train(self, until: int) -> None:
        from mcdp.data import StepBatchSampler, collate

        tc = self.cfg.train
        final = self.network.stages[-1]
        for idx in StepBatchSampler(len(self.train_set), tc.batch_size, tc.seed, self.step, until):
            batch = collate([self.train_set[i] for i in idx])
            lr = tc.lr * (tc.lr_decay_factor if self.step >= int(tc.lr_decay_at * tc.steps) else 1.0)
            for g in self.opt.param_groups:
                g["lr"] = lr
            out = self.network(batch.depth_input(self.nbr))
            gt = self.gt(batch)
            valid = (gt > EVAL.min_depth) & (gt < EVAL.max_depth) & (batch.mask.reshape(gt.shape) > 0)
            loss = 0.0
            for st in self.network.stages:
                d = out["depth", st, 0]
                loss = loss + (torch.log(d[valid]) - torch.log(gt[valid])).abs().mean()
            self.opt.zero_grad(set_to_none=True)
            loss.backward()
            self.opt.step()
            self.step += 1

    def save_checkpoint(self, path: Path) -> None:
        from mcdp.runs import CHECKPOINT_VERSION, atomic_torch_save
        from corelib.configlib import config_to_dict

        atomic_torch_save({"version": CHECKPOINT_VERSION, "step": self.step, "config": config_to_dict(self.cfg),
                           "depth_model": self.network.state_dict(), "cameras": list(self.ds.camera_names)}, path)

    def close(self) -> None:
        pass


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, type=Path)
    ap.add_argument("--preset", default=str(ROOT / "configs/train/tiny/mono2.yaml"))
    ap.add_argument("--steps", type=int, default=600)
    ap.add_argument("--every", type=int, default=100)
    ap.add_argument("--render-sequences", type=int, default=64)
    ap.add_argument("--render-frames", type=int, default=10)
    ap.add_argument("--render-override", action="append", default=[])
    ap.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    ap.add_argument("--record", type=Path, metavar="PATH", help="also write the printed table's rows to PATH (CSV)")
    ap.add_argument("--label", default=None)
    ap.add_argument("--supervised", action="store_true",
                    help="the upper bound: train the same network with ground-truth depth (log-L1) instead")
    ap.add_argument("--threshold", type=float, default=0.5,
                    help="report the CPU minutes until median abs_rel <= THRESHOLD x the constant (default 0.5)")
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args(argv)

    ensure_data(a.data, a.render_sequences, a.render_frames, a.render_override)
    ds = open_dataset(str(a.data))
    cfg = load_config(RunConfig, a.preset, [f"train.steps={a.steps}", "train.val_every=1000000", *a.overrides])
    const = median_gt_depth(ds, "train", EVAL)
    ref = summary(evaluate(ds, constant_depth_predictor(ds, const), "test", EVAL, progress=False), "constant")
    prior = summary(evaluate(ds, flat_road_predictor(ds, const), "test", EVAL, progress=False), "flat_road")
    print(f"yardsticks on test: constant {const:.2f} m: med_abs_rel {ref['med_abs_rel']:.3f} abs_rel {ref['abs_rel']:.3f}"
          f" a1 {ref['med_a1']:.3f}; flat-road prior: med_abs_rel {prior['med_abs_rel']:.3f} "
          f"abs_rel {prior['abs_rel']:.3f} a1 {prior['med_a1']:.3f}", flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        ckpt = Path(tmp) / "run/checkpoints/last.pt"
        if a.supervised:
            tr = SupervisedRun(cfg, ds)
        else:
            tr = Trainer(cfg, ds, Path(tmp) / "run", progress=False, tensorboard=False)
        w0 = time.perf_counter()
        train_cpu = 0.0
        for k in range(a.every, a.steps + 1, a.every):
            c0 = cpu_s()
            tr.train(until=k)
            train_cpu += cpu_s() - c0
            if a.supervised:
                tr.save_checkpoint(ckpt)
            else:
                tr.save_checkpoint("last.pt")
            pred = Predictor(None, ds, str(ckpt), device="cpu")
            m = summary(evaluate(ds, pred.predict, "test", EVAL, progress=False))
            m.update(depth_stats(pred, ds))
            m.update(step=k, cpu_min=train_cpu / 60, wall_min=(time.perf_counter() - w0) / 60)
            rows.append(m)
            print(
                f"{a.label or ''} step {k:5d} cpu {m['cpu_min']:5.1f} min  med_abs_rel {m['med_abs_rel']:.3f} "
                f"(const {ref['med_abs_rel']:.3f})  abs_rel {m['abs_rel']:.3f} (const {ref['abs_rel']:.3f})  "
                f"a1 {m['med_a1']:.3f}  depth p10/50/90 {m['p10']:.1f}/{m['p50']:.1f}/{m['p90']:.1f}",
                flush=True,
            )
        tr.close()
    target = a.threshold * ref["med_abs_rel"]
    hit = next((r for r in rows if r["med_abs_rel"] <= target), None)
    label = a.label or Path(a.preset).stem
    print(f"\n{label}{' (supervised upper bound)' if a.supervised else ''}: test split, {len(ds.split('test'))} sequences")
    header = ["steps", "CPU min", "median abs_rel", "metric abs_rel", "median a1", "metric a1", "Dep Con",
              "depth p10 / p90 m"]
    table = [[str(r["step"]), f"{r['cpu_min']:.1f}", f"{r['med_abs_rel']:.3f}", f"{r['abs_rel']:.3f}",
              f"{r['med_a1']:.3f}", f"{r['a1']:.3f}", f"{r['dep_con']:.2f}", f"{r['p10']:.1f} / {r['p90']:.1f}"]
             for r in rows]
    table += [[name, "0", f"{y['med_abs_rel']:.3f}", f"{y['abs_rel']:.3f}", f"{y['med_a1']:.3f}", f"{y['a1']:.3f}",
               f"{y['dep_con']:.2f}", ""] for name, y in (("constant depth", ref), ("flat-road prior", prior))]
    show(header, table, record=a.record)
    print(f"time to median abs_rel <= {a.threshold} x constant ({target:.3f}): "
          + (f"{hit['cpu_min']:.1f} CPU min (step {hit['step']})" if hit else f"not reached in {a.steps} steps"))
    if a.json:
        a.json.write_text(json.dumps({"label": label, "overrides": a.overrides, "preset": a.preset,
                                      "supervised": a.supervised, "constant": ref, "prior": prior, "rows": rows,
                                      "time_to_target_cpu_min": hit["cpu_min"] if hit else None}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
