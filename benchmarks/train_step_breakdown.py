"""Where a training step's wall time goes, timed with `time.perf_counter`, not `torch.profiler`.

Feeds: docs/results/train_step.md

    .venv/bin/python benchmarks/train_step_breakdown.py [--presets mono2 mcdp_m2 --steps 5 --threads 1]

The profiler misattributes time on some CPUs (docs/results/train_step.md shows a 10 ms convolution
backward as 80-108 ms), so this script times two ways, each in its own subprocess per preset:
- **convolutions**: every `nn.Conv2d` runs through an autograd function that times its forward
  (`aten::convolution`) and its backward (`aten::convolution_backward`); reflection padding runs outside
  the timer. The five costliest convolutions are listed.
- **phases**: the depth network's forward, the losses' forward, the whole backward and Adam.

Tiny presets (configs/train/tiny), 64x96, the synthetic rig of `benchmarks/train_step.py`,
`scale.source=odometry` (the sweep's scale). Prints a table per preset.
"""
from __future__ import annotations

import argparse
import collections
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _system(preset: str, threads: int):
    import torch

    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.system import SelfSupervisedSystem
    from train_step import synthetic_batch

    torch.set_num_threads(threads)
    cfg = load_config(RunConfig, ROOT / "configs" / "train" / "tiny" / f"{preset}.yaml",
                      ["train.height=64", "train.width=96", "train.batch_size=1", "scale.source=odometry"])
    torch.manual_seed(0)
    system = SelfSupervisedSystem(cfg, [(i, (i + 1) % 6) for i in range(6)], 6)
    opt = torch.optim.Adam(system.parameters(), lr=1e-4, fused=True)
    return system, opt, synthetic_batch(64, 96)


def time_convolutions(preset: str, steps: int, threads: int) -> dict:
    import torch
    import torch.nn.functional as F

    system, opt, batch = _system(preset, threads)
    acc: collections.Counter = collections.Counter()

    class TimedConv(torch.autograd.Function):
        @staticmethod
        def forward(ctx, x, w, b, stride, padding, dilation, groups, name):
            t = time.perf_counter()
            y = torch.ops.aten.convolution(x, w, b, stride, padding, dilation, False, [0, 0], groups)
            acc["fwd", name] += time.perf_counter() - t
            ctx.save_for_backward(x, w)
            ctx.args = (b is not None, stride, padding, dilation, groups, name)
            return y

        @staticmethod
        def backward(ctx, go):
            x, w = ctx.saved_tensors
            has_b, stride, padding, dilation, groups, name = ctx.args
            t = time.perf_counter()
            gx, gw, gb = torch.ops.aten.convolution_backward(
                go, x, w, [w.shape[0]] if has_b else None, stride, padding, dilation, False, [0, 0], groups,
                [ctx.needs_input_grad[0], True, has_b])
            acc["bwd", f"{name} {tuple(x.shape)}"] += time.perf_counter() - t
            return gx, gw, gb, None, None, None, None, None

    for name, m in system.named_modules():
        if not isinstance(m, torch.nn.Conv2d):
            continue
        if m.padding_mode == "zeros":
            m.forward = lambda x, m=m, n=name: TimedConv.apply(x, m.weight, m.bias, list(m.stride), list(m.padding),
                                                               list(m.dilation), m.groups, n)
        else:  # the decoder's reflection-padded convolutions: pad outside the timer
            m.forward = lambda x, m=m, n=name: TimedConv.apply(
                F.pad(x, m._reversed_padding_repeated_twice, mode=m.padding_mode), m.weight, m.bias,
                list(m.stride), [0, 0], list(m.dilation), m.groups, n)

    def step():
        _, losses = system.process_batch(batch, 0, train=True)
        opt.zero_grad(set_to_none=True)
        losses["loss"].backward()
        opt.step()

    for _ in range(3):
        step()
    acc.clear()
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    ms = {k: 1000 * v / steps for k, v in acc.items()}
    top = sorted(((k[1], v) for k, v in ms.items() if k[0] == "bwd"), key=lambda kv: -kv[1])[:5]
    return {"step_ms": 1000 * (time.perf_counter() - t0) / steps,
            "conv_fwd_ms": sum(v for k, v in ms.items() if k[0] == "fwd"),
            "conv_bwd_ms": sum(v for k, v in ms.items() if k[0] == "bwd"), "top_bwd": top}


def time_phases(preset: str, steps: int, threads: int) -> dict:
    system, opt, batch = _system(preset, threads)
    acc: collections.Counter = collections.Counter()

    def timed(obj, attr: str, label: str) -> None:
        f = getattr(obj, attr)

        def g(*a, **kw):
            t = time.perf_counter()
            try:
                return f(*a, **kw)
            finally:
                acc[label] += time.perf_counter() - t
        setattr(obj, attr, g)

    timed(system.depth, "forward", "depth network forward")
    timed(system, "compute_losses", "losses forward")

    def step():
        _, losses = system.process_batch(batch, 0, train=True)
        opt.zero_grad(set_to_none=True)
        t = time.perf_counter()
        losses["loss"].backward()
        acc["backward"] += time.perf_counter() - t
        t = time.perf_counter()
        opt.step()
        acc["Adam"] += time.perf_counter() - t

    for _ in range(3):
        step()
    acc.clear()
    t0 = time.perf_counter()
    for _ in range(steps):
        step()
    return {"step_ms": 1000 * (time.perf_counter() - t0) / steps, **{k: 1000 * v / steps for k, v in acc.items()}}


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--presets", nargs="+", default=["mono2", "mcdp_m2"])
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--_worker", nargs=2, metavar=("KIND", "PRESET"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args._worker:
        kind, preset = args._worker
        fn = time_convolutions if kind == "conv" else time_phases
        print(json.dumps(fn(preset, args.steps, args.threads)))
        return 0
    for preset in args.presets:
        res = {}
        for kind in ("conv", "phases"):  # each in a fresh process: no wrapper leaks into the other timing
            out = subprocess.run([sys.executable, __file__, "--_worker", kind, preset, "--steps", str(args.steps),
                                  "--threads", str(args.threads)], capture_output=True, text=True, check=True)
            res[kind] = json.loads(out.stdout.strip().splitlines()[-1])
        c, p = res["conv"], res["phases"]
        conv = c["conv_fwd_ms"] + c["conv_bwd_ms"]
        print(f"{preset}, 64x96, {args.threads} thread(s), {args.steps} steps")
        print(f"  convolutions: step {c['step_ms']:.0f} ms; forward {c['conv_fwd_ms']:.0f} ms, backward "
              f"{c['conv_bwd_ms']:.0f} ms ({100 * conv / c['step_ms']:.0f} % of the step)")
        for name, ms in c["top_bwd"]:
            print(f"    backward {name}: {ms:.1f} ms")
        print(f"  phases: step {p['step_ms']:.0f} ms; " + ", ".join(f"{k} {v:.0f} ms" for k, v in p.items()
                                                                 if k != "step_ms"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
