"""Seconds per training step and peak memory of every training preset, with the ratio to mono2.

Feeds: docs/results/train_step.md, docs/results/device.md
Record: ``--record PATH.txt`` also writes the table it prints to PATH, as printed (the text a
docs/results/<doc>/*.txt holds; `scripts/publish_bench.py` puts it in the doc).

One rig sample per step (6 cameras x 3 frames), random images on a synthetic
six-camera ring (no dataset needed), the presets' own settings otherwise.
Each (preset, size) runs in a fresh subprocess so that peak memory (CPU: max
RSS; CUDA: max allocated) belongs to it alone; rounds are interleaved over
presets and the median is reported, so load from other processes hits all
presets alike. Also reports the share of a step spent in L_con (forward +
backward of every stage's consistency loss, timed on its own).

    python benchmarks/train_step.py                       # 96x160 and 192x320, 3 rounds
    python benchmarks/train_step.py --sizes 96x160 --rounds 5 --steps 5 --device cpu
    python benchmarks/train_step.py --tiny --sizes 64x96 --threads 1 --modes before fp32 bf16 \
        --presets mono2 mcdp_m2 --set scale.source=odometry   # roofline (the sweep's scale)

Modes: ``before`` is the step as it was before the speed work (SSIM's 3x3 mean by
``F.avg_pool2d``, Adam's per-tensor loop, fp32): the same run's baseline for the ``x before``
column. ``fp32`` and ``bf16`` are today's step (separable 3x3 sums, fused Adam) without and with
bf16 autocast (AMX on a CPU that has it); ``cl`` is fp32 with the networks in channels-last memory.

Roofline columns: GFLOP of one step (forward + backward, convolutions and matrix products,
`torch.utils.flop_counter`), the GFLOP/s it achieves, and the machine's own ceiling measured in the
same worker (a 1024^3 `torch.mm` in the step's dtype and thread count), so every preset shows its
fraction of the limit.

Floors (2-core CPU): mcdp_m2 <= 1.5x mono2 per step (aim 1.3x); L_con <= 5 % of a step.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._table import tee  # noqa: E402

PRESETS = ["mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2"]
MODES = ["before", "fp32", "bf16", "cl"]


def synthetic_batch(H: int, W: int, n_cams: int = 6, seed: int = 0):
    """A `mcdp.inputs.RigBatch` on a ring of cameras (60 deg spacing, 70 deg hfov)."""
    import numpy as np
    import torch

    g = torch.Generator().manual_seed(seed)
    f = W / 2 / math.tan(math.radians(70) / 2)
    K = torch.tensor([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    R0 = np.array([[0, 0, 1.0], [-1, 0, 0], [0, -1, 0]])  # OpenCV camera looking along ego +x
    T = torch.zeros(n_cams, 4, 4)
    for i in range(n_cams):
        yaw = -2 * math.pi * i / n_cams
        Rz = np.array([[math.cos(yaw), -math.sin(yaw), 0], [math.sin(yaw), math.cos(yaw), 0], [0, 0, 1]])
        T[i, :3, :3] = torch.from_numpy(Rz @ R0).float()
        T[i, :3, 3] = torch.tensor([1.5 + math.cos(yaw), math.sin(yaw), 1.6])
        T[i, 3, 3] = 1
    # smooth random images (low-frequency noise, upsampled)
    rgb = torch.nn.functional.interpolate(torch.rand(n_cams * 3, 3, H // 8, W // 8, generator=g), size=(H, W),
                                          mode="bilinear", align_corners=False).view(1, n_cams, 3, 3, H, W)
    Tw = torch.eye(4).repeat(1, 3, 1, 1)
    Tw[0, :, 0, 3] = torch.tensor([-0.5, 0.0, 0.5])
    mask = torch.ones(1, n_cams, 1, H, W)
    mask[..., -H // 10:, :] = 0
    from mcdp.inputs import RigBatch

    return RigBatch(rgb, K.expand(1, n_cams, 3, 3).clone(), T[None], mask, Tw, torch.zeros(1, dtype=torch.long),
                    torch.ones(1, dtype=torch.long), {"gt_median": torch.full((1, n_cams), 10.0)})


def mm_ceiling(dtype, dev, n: int = 1024, reps: int = 5) -> float:
    """GFLOP/s of an n^3 matrix product in `dtype` on this worker's threads (the best of `reps`); on a GPU at
    n = 4096 (1024 leaves one far from its ceiling)."""
    import torch

    if dev.type == "cuda":
        n = max(n, 4096)

    a = torch.randn(n, n, device=dev).to(dtype)
    b = torch.randn(n, n, device=dev).to(dtype)
    torch.mm(a, b)
    best = float("inf")
    for _ in range(reps):
        t0 = time.perf_counter()
        torch.mm(a, b)
        if dev.type == "cuda":
            torch.cuda.synchronize()
        best = min(best, time.perf_counter() - t0)
    return 2 * n**3 / best / 1e9


def worker(preset: str, H: int, W: int, steps: int, device: str, threads: int = 0, precision: str = "fp32",
           tiny: bool = False, overrides: tuple = ()) -> dict:  # precision: one of MODES
    """Time `steps` optimiser steps (after 3 warm-up steps) of one preset; returns a result dict."""
    import resource

    import torch

    if threads > 0:
        torch.set_num_threads(threads)

    sys.path.insert(0, str(ROOT))
    from mcdp.config import RunConfig
    from mcdp.system import SelfSupervisedSystem
    from corelib.configlib import load_config

    preset_dir = ROOT / "configs" / "train" / ("tiny" if tiny else "")
    cfg = load_config(RunConfig, preset_dir / f"{preset}.yaml",
                      [f"train.height={H}", f"train.width={W}", "train.batch_size=1", *overrides])
    dev = torch.device(device)
    torch.manual_seed(0)
    pairs = [(i, (i + 1) % 6) for i in range(6)]
    system = SelfSupervisedSystem(cfg, pairs, 6).to(dev)
    if precision == "bf16":  # autocast (AMX on a CPU that has it); geometry stays float32
        system.use_amp = True
        system.amp_dtype = torch.bfloat16
    if precision == "cl":
        system = system.to(memory_format=torch.channels_last)
    if precision == "before":  # the step before the speed work: avg_pool2d SSIM, per-tensor Adam
        import torch.nn.functional as F
        from mcdp import losses

        losses._box3 = lambda t: F.avg_pool2d(t, 3, 1)
    opt = torch.optim.Adam(system.parameters(), lr=1e-4, fused=precision != "before")
    batch = synthetic_batch(H, W).to(dev)
    batch.fields = {k: v for k, v in batch.fields.items() if k in {f.name for f in system.fields}}  # the declared only

    def sync():
        if dev.type == "cuda":
            torch.cuda.synchronize()

    def one_step():
        _, losses = system.process_batch(batch, 0, train=True)
        opt.zero_grad(set_to_none=True)
        losses["loss"].backward()
        opt.step()

    for _ in range(3):  # warm-up: allocator, oneDNN primitive caches
        one_step()
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as fc:
        one_step()
    gflop = fc.get_total_flops() / 1e9
    if dev.type == "cuda":
        torch.cuda.reset_peak_memory_stats()
    sync()
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        one_step()
        sync()
        times.append(time.perf_counter() - t0)

    # L_con alone: forward + backward for every stage, on depth maps of the real shapes
    con_s = 0.0
    if cfg.loss.consistency_weight > 0:
        n_stages = cfg.model.refine_steps + 1
        depth = (torch.rand(6, 1, H, W, device=dev) * 20 + 2).requires_grad_(True)
        ct = []
        for _ in range(steps + 1):
            sync()
            t0 = time.perf_counter()
            for _ in range(n_stages):
                system.consistency(depth, batch).backward()
            sync()
            ct.append(time.perf_counter() - t0)
        con_s = statistics.median(ct[1:])
    if dev.type == "cuda":
        peak_mb = torch.cuda.max_memory_allocated() / 2**20
    else:
        peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    ceiling = mm_ceiling(torch.bfloat16 if precision == "bf16" else torch.float32, dev)
    return {"preset": preset, "H": H, "W": W, "step_s": statistics.median(times), "con_s": con_s,
            "peak_mb": peak_mb, "threads": torch.get_num_threads(), "device": device, "precision": precision,
            "gflop": gflop, "ceiling_gflops": ceiling}


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", nargs="+", default=["96x160", "192x320"], help="HxW training sizes")
    ap.add_argument("--presets", nargs="+", default=PRESETS)
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds (median over rounds)")
    ap.add_argument("--steps", type=int, default=5, help="timed steps per round (median within a round)")
    ap.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = torch default)")
    ap.add_argument("--json", default=None, help="also write the results here")
    ap.add_argument("--record", metavar="PATH", help="also write what it prints to PATH (text)")
    ap.add_argument("--modes", "--precision", dest="precision", nargs="+", default=["fp32"], choices=MODES,
                    help="one or more: each is a row set of the table (see the module docstring)")
    ap.add_argument("--tiny", action="store_true", help="the tiny presets (configs/train/tiny)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="config overrides for every preset (e.g. scale.source=odometry, the sweep's)")
    ap.add_argument("--_worker", nargs=4, metavar=("PRESET", "H", "W", "STEPS"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._worker:
        p, H, W, s = args._worker
        print(json.dumps(worker(p, int(H), int(W), int(s), args.device, args.threads, args.precision[0], args.tiny,
                                tuple(args.set))))
        return 0

    results: dict = {}
    for size in args.sizes:
        H, W = (int(x) for x in size.lower().split("x"))
        for r in range(args.rounds):
            for prec in args.precision:
                for p in args.presets:
                    cmd = [sys.executable, __file__, "--device", args.device, "--threads", str(args.threads),
                           "--precision", prec, *(["--tiny"] if args.tiny else []), "--set", *args.set,
                           "--_worker", p, str(H), str(W), str(args.steps)]
                    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=dict(os.environ))
                    if out.returncode != 0:
                        print(out.stderr, file=sys.stderr)
                        return 1
                    res = json.loads(out.stdout.strip().splitlines()[-1])
                    results.setdefault((p, H, W, prec), []).append(res)
                    print(f"  round {r + 1}/{args.rounds} {prec} {p:14s} {H}x{W}: {res['step_s']:.3f} s/step",
                          file=sys.stderr)

    with tee(args.record):
        rows = []
        print(f"\ntrain step, 1 rig sample (6 cameras x 3 frames), device {args.device}, "
              f"torch threads {next(iter(results.values()))[0]['threads']}, median of {args.rounds} rounds")
        per_min = "steps/CPU-min" if args.device == "cpu" else "steps/dev-min"
        hdr = (f"{'preset':14s} {'mode':>6s} {'size':>8s} {'s/step':>8s} {'x mono2':>8s} {'L_con %':>8s} "
               f"{'peak MiB':>9s} {'GFLOP':>7s} {'GFLOP/s':>8s} {'ceiling':>8s} {'% ceil':>7s} {per_min:>13s} "
               f"{'x before':>8s}")
        print(hdr + "\n" + "-" * len(hdr))
        for size in args.sizes:
            H, W = (int(x) for x in size.lower().split("x"))
            for prec in args.precision:
                base = statistics.median(r["step_s"] for r in results.get(("mono2", H, W, prec),
                                                                          [{"step_s": float("nan")}]))
                for p in args.presets:
                    rs = results[(p, H, W, prec)]
                    t = statistics.median(r["step_s"] for r in rs)
                    con = statistics.median(r["con_s"] for r in rs)
                    peak = max(r["peak_mb"] for r in rs)
                    gflop = statistics.median(r["gflop"] for r in rs)
                    ceil = statistics.median(r["ceiling_gflops"] for r in rs)
                    thr = rs[0]["threads"] if args.device == "cpu" else 1  # on a GPU: steps per device-minute
                    before = results.get((p, H, W, "before"))
                    speedup = statistics.median(r["step_s"] for r in before) / t if before else float("nan")
                    rows.append({"preset": p, "precision": prec, "H": H, "W": W, "step_s": t, "ratio_mono2": t / base,
                                 "lcon_share": con / t, "peak_mb": peak, "gflop": gflop, "gflops": gflop / t,
                                 "ceiling_gflops": ceil, "steps_per_cpu_min": 60 / (t * thr),
                                 "x_before": speedup})
                    print(f"{p:14s} {prec:>6s} {size:>8s} {t:8.3f} {t / base:8.2f} {100 * con / t:8.1f} "
                          f"{peak:9.0f} {gflop:7.1f} {gflop / t:8.1f} {ceil:8.1f} {100 * gflop / t / ceil:7.1f} "
                          f"{60 / (t * thr):13.1f} {speedup:8.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
