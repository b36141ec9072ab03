"""Training steps/s with 1 process vs 2 torchrun processes (gloo, CPU) at the same global batch.

Feeds: docs/SCALING.md

    .venv/bin/python benchmarks/train_scaling.py [--preset configs/train/tiny/mono2.yaml] [--batch 2]

Renders the tiny dataset into a temporary folder, then times `mcdp train` for a short and a long
run per setting; the difference of the two wall times over the difference of steps is the time
of one step without start-up (imports, process group, model build). Prints a table.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run(nproc: int, threads: int, steps: int, data: Path, out: Path, preset: str, batch: int) -> float:
    launch = ([sys.executable, "-m", "torch.distributed.run", "--standalone", f"--nproc_per_node={nproc}", "-m", "mcdp"]
              if nproc > 1 else [sys.executable, "-m", "mcdp"])
    cmd = launch + ["train", preset, "--data", str(data), "--out", str(out), "--no-progress", f"train.steps={steps}",
                    f"train.batch_size={batch}", f"train.threads={threads}", "train.num_workers=0",
                    "train.val_every=100000", "train.ckpt_every=100000", "train.log_every=100000"]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env={**os.environ, "OMP_NUM_THREADS": str(threads)}, cwd=ROOT)
    return time.perf_counter() - t0


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--preset", default=str(ROOT / "configs/train/tiny/mono2.yaml"))
    ap.add_argument("--batch", type=int, default=2, help="global batch (rig samples)")
    ap.add_argument("--short", type=int, default=4)
    ap.add_argument("--long", type=int, default=24)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data"
        subprocess.run([sys.executable, "-m", "synth.cli", "render", str(ROOT / "configs/data/tiny.yaml"), "--out",
                        str(data), "--no-progress"], check=True, capture_output=True, cwd=ROOT)
        rows = []
        for nproc, threads in ((1, 1), (1, 2), (2, 1)):
            t = [run(nproc, threads, s, data, Path(tmp) / f"r{nproc}{threads}{s}", args.preset, args.batch)
                 for s in (args.short, args.long)]
            step_s = (t[1] - t[0]) / (args.long - args.short)
            rows.append((nproc, threads, step_s, t[0]))
    base = rows[0][2]
    print(f"\n{Path(args.preset).name}, global batch {args.batch}, CPU ({os.cpu_count()} cores), gloo")
    print("| processes | threads each | s / step | steps / s | speed-up vs 1x1 | start-up s |")
    print("|---|---|---|---|---|---|")
    for nproc, threads, step_s, t0 in rows:
        print(f"| {nproc} | {threads} | {step_s:.3f} | {1 / step_s:.2f} | {base / step_s:.2f}x | {t0:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
