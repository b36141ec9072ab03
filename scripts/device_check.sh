#!/usr/bin/env bash
# The device check (issue 58 item 4): what the first GPU lent to this project should tell us, in one run of under
# 8 minutes on one GPU (16 CPU cores), written as a report that can be committed as docs/results/device.md.
#
#   scripts/device_check.sh                          # on a GPU machine: --device cuda, the full check
#   scripts/device_check.sh --device cpu --tiny      # its CPU path (tests/test_device_check.py runs it): seconds
#   scripts/device_check.sh --out /tmp/dc            # where the renders, the train table and device.md go
#   scripts/device_check.sh --reference DIR          # the CPU render made elsewhere (a device with no OSMesa):
#                                                    # DIR is `synth render` of the same preset and overrides
#
# It
#   1. renders a small world of the default preset (the tiny preset with --tiny) twice: through EGL on the device
#      (render.backend=egl; with --device cpu the auto back end) and through OSMesa on the CPU
#      (render.backend=osmesa); prints each render's throughput (camera images per second) and compares every
#      depth map: identical, or the largest difference and the share of valid pixels beyond DEPTH_TOL relative
#      (the check passes at most DEPTH_SHARE of them: a GPU rasteriser may put a silhouette's edge pixel on the
#      other side);
#   2. times training steps of Mono2 and MCDP (m = 2) at 96x64, 192x128 and 320x192 in fp32 and bf16
#      (benchmarks/train_step.py: steps per second, peak memory; --tiny: 96x64, fp32, 2 steps);
#   3. takes one training step on the CPU and one on the device from the same weights and batch (TF32 off) and
#      compares the loss, every gradient and the weights after one Adam step: within STEP_TOL relative (--device cpu:
#      the CPU against itself, which must be exact);
#   4. runs the smoke sweep (configs/sweep/ci.yaml: render, pretraining, 14 runs trained and evaluated) with
#      device=cuda (--device cpu: on the CPU; --tiny: one method at one overlap): the sweep's whole path on the
#      device, its data loader, checkpoints and evaluation included; passes when results.json has every run;
#   5. writes OUT/device.md (the device's name, torch's version, each figure) and exits 1 if a check failed.
#
# A part that fails (no EGL on the device, a training worker that dies) is reported as FAIL in device.md with its
# last line of error, and the other parts still run: one lent device run gives every answer it can.
#
# PYTHON (default .venv/bin/python) is the interpreter. Nothing is written outside OUT.
set -euo pipefail

DEVICE=cuda
TINY=0
OUT="${TMPDIR:-/tmp}/device_check"
REFERENCE=""
while [ $# -gt 0 ]; do
    case "$1" in
        --device) DEVICE="${2:?--device needs cpu or cuda}"; shift 2 ;;
        --tiny) TINY=1; shift ;;
        --out) OUT="${2:?--out needs a folder}"; shift 2 ;;
        --reference) REFERENCE="${2:?--reference needs a rendered dataset folder}"; shift 2 ;;
        -h|--help) sed -n '2,31p' "$0"; exit 0 ;;
        *) echo "device_check: unknown argument '$1' (--device cpu|cuda, --tiny, --out DIR, --reference DIR)" >&2
           exit 2 ;;
    esac
done
case "$DEVICE" in cpu|cuda) ;; *) echo "device_check: --device must be cpu or cuda, got '$DEVICE'" >&2; exit 2 ;; esac
if [ -n "$REFERENCE" ] && [ ! -f "$REFERENCE/manifest.json" ]; then
    echo "device_check: --reference $REFERENCE is not a rendered dataset (no manifest.json)" >&2; exit 2
fi

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${PYTHON:-$ROOT/.venv/bin/python}"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"
cd "$ROOT"

DEPTH_TOL=1e-3     # relative depth difference a pixel may have between the device and the CPU render
DEPTH_SHARE=0.001  # share of valid pixels allowed beyond DEPTH_TOL
STEP_TOL=1e-3      # relative difference allowed between a CPU and a device step (loss, gradients, weights)

if [ "$TINY" = 1 ]; then
    PRESET=configs/data/tiny.yaml; DATA_SET=(); SIZES=(64x96); MODES=(fp32); STEPS=2; THREADS=1
else
    PRESET=configs/data/default.yaml; DATA_SET=(dataset.sequences=4 dataset.frames=10)
    SIZES=(64x96 128x192 192x320); MODES=(fp32 bf16); STEPS=100; THREADS=0  # 200 ran 497 s on an H100, over the 8 minutes
fi
if [ "$DEVICE" = cuda ]; then DEVICE_BACKEND=egl; else DEVICE_BACKEND=auto; fi

echo "device_check: 1/4 render ($PRESET) on the device (render.backend=$DEVICE_BACKEND) and on the CPU (osmesa)" >&2
rm -rf "$OUT/render_device" "$OUT/render_cpu" "$OUT"/*.err "$OUT/train_step.txt" "$OUT/sweep.log" "$OUT/device.md"
render() {  # render(FOLDER, BACKEND): seconds on stdout, or "nan" with the error in FOLDER.err
    local t0 t1
    t0=$(date +%s.%N)
    if ! "$PY" -m synth render "$PRESET" --out "$1" "render.backend=$2" "${DATA_SET[@]}" --no-progress -q \
            2>"$1.err" >&2; then
        echo "device_check: the $2 render failed: $(tail -n 1 "$1.err")" >&2; echo nan; return
    fi
    rm -f "$1.err"
    t1=$(date +%s.%N)
    awk -v a="$t0" -v b="$t1" 'BEGIN { printf "%.3f\n", b - a }'
}
RENDER_DEVICE_S=$(render "$OUT/render_device" "$DEVICE_BACKEND")
if [ -n "$REFERENCE" ]; then
    ln -s "$(cd "$REFERENCE" && pwd)" "$OUT/render_cpu"; RENDER_CPU_S=nan
else
    RENDER_CPU_S=$(render "$OUT/render_cpu" osmesa)
fi

echo "device_check: 2/4 training steps (benchmarks/train_step.py)" >&2
"$PY" benchmarks/train_step.py --device "$DEVICE" --tiny --sizes "${SIZES[@]}" --presets mono2 mcdp_m2 \
    --modes "${MODES[@]}" --rounds 1 --steps "$STEPS" --threads "$THREADS" --set scale.source=odometry \
    --record "$OUT/train_step.txt" >/dev/null 2>"$OUT/train_step.err" \
    || echo "device_check: the training steps failed: $(tail -n 1 "$OUT/train_step.err")" >&2

echo "device_check: 3/4 the smoke sweep (configs/sweep/ci.yaml, device=$DEVICE)" >&2
rm -rf "$OUT/sweep"
SWEEP_SET=("device=$DEVICE")
if [ "$TINY" = 1 ]; then SWEEP_SET+=("methods=[mono2]" "overlaps=[0.2]"); fi
t0=$(date +%s.%N)
if "$PY" -m mcdp sweep configs/sweep/ci.yaml --out "$OUT/sweep" "${SWEEP_SET[@]}" --no-progress -q \
        >"$OUT/sweep.log" 2>&1; then
    SWEEP_S=$(awk -v a="$t0" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f\n", b - a }')
else
    SWEEP_S=nan; echo "device_check: the smoke sweep failed: $(tail -n 1 "$OUT/sweep.log")" >&2
fi

echo "device_check: 4/4 one CPU step against one $DEVICE step, and the report" >&2
"$PY" - "$OUT" "$DEVICE" "$TINY" "$RENDER_DEVICE_S" "$RENDER_CPU_S" "$DEPTH_TOL" "$DEPTH_SHARE" "$STEP_TOL" \
    "$SWEEP_S" <<'EOF'
import datetime, platform, sys
from pathlib import Path

import numpy as np
import torch

if sys.argv[3] == "1":
    torch.set_num_threads(1)
out, device, tiny = Path(sys.argv[1]), sys.argv[2], sys.argv[3] == "1"
render_dev_s, render_cpu_s, depth_tol, depth_share, step_tol, sweep_s = map(float, sys.argv[4:10])
sys.path.insert(0, ".")
from synth.open import open_dataset

# --- 1. the two renders' depth
images = identical = 0
worst, beyond, valid = 0.0, 0, 0
errors = [f"{e.stem}: {(e.read_text().strip().splitlines() or ['failed'])[-1]}"
          for e in sorted(out.glob("render_*.err"))]
render_error = "; ".join(errors) or None
if render_error is None:
    try:
        a, b = open_dataset(out / "render_device"), open_dataset(out / "render_cpu")
        shape = lambda d: (d.sequences, d.camera_names, [d.n_frames(q) for q in d.sequences])  # noqa: E731
        if shape(a) != shape(b):
            raise ValueError("the CPU render is not of the same world (sequences, cameras or frames differ): "
                             "render it with the same preset and overrides")
        for seq in a.sequences:
            for f in range(a.n_frames(seq)):
                for cam in a.camera_names:
                    da, db = a.read_depth(seq, cam, f), b.read_depth(seq, cam, f)
                    if da.shape != db.shape:
                        raise ValueError(f"{seq}/{cam}/{f}: depth {da.shape} on the device, {db.shape} on the CPU")
                    images += 1
                    identical += int(np.array_equal(da, db))
                    v = (da > 0) | (db > 0)
                    rel = np.abs(da.astype(np.float64) - db) / np.maximum(np.maximum(da, db), 1e-6)
                    worst = max(worst, float(rel[v].max()) if v.any() else 0.0)
                    beyond += int((rel[v] > depth_tol).sum())
                    valid += int(v.sum())
    except Exception as e:  # noqa: BLE001 - reported in device.md; the other parts' results are kept
        render_error = f"comparing the renders: {type(e).__name__}: {str(e)[:300]}"
share = beyond / max(valid, 1)
render_ok = render_error is None and images > 0 and share <= depth_share

# --- 4. one CPU step against one device step, same weights and batch
from benchmarks.train_step import synthetic_batch
from corelib.configlib import load_config
from mcdp.config import RunConfig
from mcdp.system import SelfSupervisedSystem

torch.backends.cuda.matmul.allow_tf32 = False
torch.backends.cudnn.allow_tf32 = False
H, W = 64, 96
cfg = load_config(RunConfig, Path("configs/train/tiny/mcdp_m2.yaml"),
                  [f"train.height={H}", f"train.width={W}", "train.batch_size=1", "scale.source=odometry"])
pairs = [(i, (i + 1) % 6) for i in range(6)]


def one_step(dev, threads=0):
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(0)
    system = SelfSupervisedSystem(cfg, pairs, 6).to(dev)
    opt = torch.optim.Adam(system.parameters(), lr=1e-4)
    batch = synthetic_batch(H, W).to(dev)
    batch.fields = {k: v for k, v in batch.fields.items() if k in {f.name for f in system.fields}}
    _, losses = system.process_batch(batch, 0, train=True)
    opt.zero_grad(set_to_none=True)
    losses["loss"].backward()
    grads = {n: p.grad.detach().double().cpu() for n, p in system.named_parameters() if p.grad is not None}
    opt.step()
    weights = {n: p.detach().double().cpu() for n, p in system.named_parameters()}
    return float(losses["loss"].detach()), grads, weights


def rel(x, y):
    return float((x - y).norm() / max(float(y.norm()), 1e-12))


step_error = None
try:
    loss_c, grads_c, w_c = one_step(torch.device("cpu"))
    loss_d, grads_d, w_d = one_step(torch.device(device))
    loss_rel = abs(loss_d - loss_c) / max(abs(loss_c), 1e-12)
    grad_rel = max(rel(grads_d[n], grads_c[n]) for n in grads_c)
    weight_rel = max(rel(w_d[n], w_c[n]) for n in w_c)
    step_ok = max(loss_rel, grad_rel, weight_rel) <= (0.0 if device == "cpu" else step_tol)
    # the yardstick: the CPU against itself at another thread count (its sums in another order)
    n_threads = torch.get_num_threads()  # 1 thread against 2 on every machine, so that runs compare
    loss_1, grads_1, w_1 = one_step(torch.device("cpu"), 1)
    loss_n, grads_n, w_n = one_step(torch.device("cpu"), 2)
    torch.set_num_threads(n_threads)
    yard = (2, abs(loss_n - loss_1) / max(abs(loss_1), 1e-12),
            max(rel(grads_n[n], grads_1[n]) for n in grads_1), max(rel(w_n[n], w_1[n]) for n in w_1))
except Exception as e:  # noqa: BLE001 - reported in device.md, the exit status says FAIL
    step_error, step_ok = f"{type(e).__name__}: {str(e)[:300]}", False
train_table = out / "train_step.txt"
train_ok = train_table.is_file() and train_table.stat().st_size > 0
train_text = train_table.read_text().strip("\n") if train_ok else (
    "FAIL: " + ((out / "train_step.err").read_text().strip().splitlines() or ["no output"])[-1][:300])

# --- 3. the smoke sweep: every run of its plan in results.json
sweep_runs, sweep_expected, sweep_error = 0, 0, None
if sweep_s != sweep_s:
    lines_ = (out / "sweep.log").read_text(errors="replace").strip().splitlines() if (out / "sweep.log").is_file() \
        else []
    sweep_error = (lines_ or ["no output"])[-1][:300]
else:
    import json

    try:
        res = json.loads((out / "sweep" / "results.json").read_text())
        sweep_runs = len(res.get("rows", []))
        sweep_expected = len(res.get("methods", [])) * len(res.get("overlaps", [])) * len(res.get("seeds") or [0])
    except (OSError, ValueError, TypeError, AttributeError) as e:
        sweep_error = f"reading the sweep's results.json: {type(e).__name__}: {str(e)[:300]}"
sweep_ok = sweep_error is None and sweep_runs > 0 and sweep_runs == sweep_expected

# --- 5. the report
if device == "cuda":
    name = torch.cuda.get_device_name(0)
else:
    name = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")),
                platform.processor() or "CPU")
n_img = images
render_cpu = "a reference render made elsewhere" if render_cpu_s != render_cpu_s else (
    f"CPU render (OSMesa): {render_cpu_s:.1f} s, {n_img / render_cpu_s:.1f} camera images/s")
lines = [
    "# Device check",
    "",
    f"{datetime.date.today().isoformat()}: `scripts/device_check.sh --device {device}{' --tiny' if tiny else ''}` on "
    f"**{name}** (torch {torch.__version__}).",
    "",
    "## Render: device against CPU",
    "",
]
if render_error is not None:
    lines += [f"- FAIL: the render did not run ({render_error[:300]})"]
else:
    lines += [
        f"- device render ({'EGL' if device == 'cuda' else 'auto back end'}): {render_dev_s:.1f} s, "
        f"{n_img / render_dev_s:.1f} camera images/s; {render_cpu} ({n_img} camera images)",
        f"- depth: {identical} of {n_img} maps identical; largest relative difference {worst:.3g}; "
        f"{share:.4%} of valid pixels beyond {depth_tol:g} (allowed {depth_share:.2%}): "
        f"{'pass' if render_ok else 'FAIL'}",
    ]
lines += ["", "## Training steps", "", "```", train_text, "```", "",
          f"## The smoke sweep on the {device} (configs/sweep/ci.yaml{', one method, one overlap' if tiny else ''})",
          "",
          (f"- FAIL: {sweep_error}" if sweep_error is not None else
           f"- {sweep_runs} of {sweep_expected} runs trained and evaluated, results.json written, in {sweep_s:.0f} s "
           f"(render, pretraining, runs and report): {'pass' if sweep_ok else 'FAIL'}"),
          "",
          f"## One CPU step against one {device} step (MCDP (m = 2), 96x64, same weights and batch, TF32 off)", ""]
if step_error is not None:
    lines += [f"- FAIL: {step_error}"]
else:
    lines += [
        f"- loss {loss_c:.6g} (CPU) against {loss_d:.6g}: relative {loss_rel:.2e}",
        f"- gradients: largest relative difference (L2, per parameter) {grad_rel:.2e}",
        f"- weights after one Adam step: largest relative difference {weight_rel:.2e}",
        f"- agreement: {'pass' if step_ok else 'FAIL'} (allowed {0.0 if device == 'cpu' else step_tol:g})",
        f"- yardstick, the CPU at 1 thread against {yard[0]} threads: loss {yard[1]:.2e}, gradients {yard[2]:.2e}, "
        f"weights {yard[3]:.2e}" + ("" if device == "cpu" else
                                    f" (the {device} step's figures are {grad_rel / max(yard[2], 1e-30):.3g}x and "
                                    f"{weight_rel / max(yard[3], 1e-30):.3g}x these)"),
    ]
lines.append("")
(out / "device.md").write_text("\n".join(lines))
print("\n".join(lines))
sys.exit(0 if render_ok and step_ok and train_ok and sweep_ok else 1)
EOF
