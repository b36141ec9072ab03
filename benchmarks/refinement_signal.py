"""Does the training loss know which basis weights are better? The gradient that reaches MCDP's

Feeds: docs/results/refinement.md
Record: ``--record PATH.csv`` also writes the table's rows to PATH (the CSV `scripts/publish_bench.py` reads).
refined weights, compared with the direction to the ORACLE weights of the same bases.

For a trained MCDP run and rig samples of a split, per image (camera) i:

- g_p: gradient of the photometric + smoothness loss (lambda = 0) w.r.t. the last refined stage's
  softmax weights w (n values), and g_c: the gradient that L_con adds (lambda as trained), both
  projected onto the simplex's tangent (sum zero: a softmax cannot move along 1);
- d = w_oracle - w: where the per-image weights fitted to ground truth (`mcdp.oracle`) lie.

It prints the mean cosine between -g and d (> 0: descending the loss moves towards the weights that
explain the ground truth best; 0: the loss does not know), the share of images where it is > 0, the
gradient norms, and how consistent the gradient is across images of the same camera (the norm of
the mean unit gradient: 1 = one direction for all, ~1/sqrt(k) = noise).

    python benchmarks/refinement_signal.py RUN --data DATASET [--split train] [--samples 24]
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mcdp.data import RigDataset, collate  # noqa: E402
from mcdp.oracle import fit_oracle_weights  # noqa: E402
from mcdp.truth import ground_truth_at  # noqa: E402
from mcdp.runs import config_from_checkpoint, find_checkpoint, load_checkpoint  # noqa: E402
from mcdp.system import SelfSupervisedSystem  # noqa: E402
from synth.open import open_dataset  # noqa: E402
from benchmarks._table import show  # noqa: E402


def tangent(g: torch.Tensor) -> torch.Tensor:
    return g - g.mean(-1, keepdim=True)


def weight_grads(system: SelfSupervisedSystem, batch: dict, stage: str) -> tuple[torch.Tensor, dict]:
    system.zero_grad(set_to_none=True)
    outputs, losses = system.process_batch(batch, step=0, train=False)
    w = outputs["weights", stage]
    w.retain_grad()
    losses["loss"].backward()
    return w.grad.detach().clone(), outputs


def main(argv=None) -> None:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", type=Path)
    ap.add_argument("--data", required=True, type=Path)
    ap.add_argument("--split", default="train")
    ap.add_argument("--samples", type=int, default=24)
    ap.add_argument("--checkpoint", default="auto")
    ap.add_argument("--record", type=Path, metavar="PATH", help="also write the table's rows to PATH (CSV)")
    ap.add_argument("--lambda", dest="lam", type=float, default=None,
                    help="L_con weight for g_c (default: as trained, or the paper's 1e-3 for a run trained without)")
    args = ap.parse_args(argv)
    torch.manual_seed(0)
    ckpt = load_checkpoint(find_checkpoint(args.run, args.checkpoint))
    cfg = config_from_checkpoint(ckpt, source=str(args.run))
    if cfg.model.method != "mcdp" or cfg.model.refine_steps < 1:
        from corelib.text import bounded

        raise SystemExit(bounded(f"{args.run}: needs an MCDP run with refinement"))
    ds = open_dataset(args.data)
    n_cam = len(ds.camera_names)
    lam = args.lam if args.lam is not None else (cfg.loss.consistency_weight or 1e-3)
    cfg_p = cfg.model_copy(update={"loss": cfg.loss.model_copy(update={"consistency_weight": 0.0})})
    sys_p = SelfSupervisedSystem(cfg_p, ds.neighbours, n_cam)
    cfg_t = cfg.model_copy(update={"loss": cfg.loss.model_copy(update={"consistency_weight": lam})})
    sys_t = SelfSupervisedSystem(cfg_t, ds.neighbours, n_cam)
    for s in (sys_p, sys_t):
        s.depth.load_state_dict(ckpt["depth_model"])
        s.eval()
    stage = f"refine{cfg.model.refine_steps}"
    data = RigDataset(ds, args.split, cfg.train.height, cfg.train.width)
    idx = np.linspace(0, len(data) - 1, min(args.samples, len(data))).round().astype(int)
    rows = {"p": [], "c": []}
    grads = {"p": [], "c": []}
    for i in idx:
        item = data[int(i)]
        batch = collate([item])
        g_p, out = weight_grads(sys_p, batch, stage)
        g_t, _ = weight_grads(sys_t, batch, stage)
        g_c = g_t - g_p
        w = out["weights", stage].detach()
        k, frame = data.samples[int(i)]
        seq = data.seqs[k]
        bases = out["bases"][0].detach()
        masks = [np.asarray(ds.mask(n), bool) for n in ds.camera_names]
        gt, valid = ground_truth_at(ds, masks, seq, frame, tuple(bases.shape[-2:]), (0.5, 80.0))
        w_o = fit_oracle_weights(bases, gt, valid, sys_t.depth.to_depth)
        d = tangent(w_o - w)
        for key, g in (("p", g_p), ("c", g_c)):
            gt_ = tangent(g)
            cos = F.cosine_similarity(-gt_, d, dim=1)
            rows[key] += [(float(x), float(n)) for x, n in zip(cos, gt_.norm(dim=1))]
            grads[key].append(gt_)
    print(f"run {args.run} ({stage}, trained with lambda {cfg.loss.consistency_weight:g}), {len(idx)} {args.split} "
          f"rig samples x {n_cam} cameras")
    header = ["gradient", "mean cos(-g, w_oracle - w)", "share cos > 0", "mean norm", "consistency across images"]
    table = []
    for key, name in (("p", "photometric + smoothness"), ("c", f"L_con (lambda {lam:g})")):
        cos = np.array([r[0] for r in rows[key]])
        nrm = np.array([r[1] for r in rows[key]])
        G = torch.cat(grads[key])  # (samples * cams, n)
        unit = G / G.norm(dim=1, keepdim=True).clamp(min=1e-20)
        cons = [float(unit[c::n_cam].mean(0).norm()) for c in range(n_cam)]
        hw = 1.96 * cos.std(ddof=1) / math.sqrt(len(cos)) if len(cos) > 1 else float("nan")
        table.append([name, f"{np.nanmean(cos):+.3f} ± {hw:.3f}", f"{np.mean(cos > 0):.2f}", f"{np.mean(nrm):.2e}",
                      f"{np.mean(cons):.2f} (noise ~ {1 / math.sqrt(len(idx)):.2f})"])
    show(header, table, record=args.record)


if __name__ == "__main__":
    main()
