"""What the camera's sensor and weather knobs cost a render: time and disk per rig-frame, each knob alone and all.

Feeds: docs/results/render_throughput.md
Record: ``--record PATH.txt`` also writes the table it prints to PATH (`scripts/publish_bench.py`).

    .venv/bin/python benchmarks/sensor_costs.py [--size 320x192 --sequences 1 --frames 10 --rounds 3]

Renders the same small dataset (``configs/data/default.yaml`` at ``--size``, one worker) with the ideal camera
and with each built knob of issue 48 alone at ``configs/data/realistic.yaml``'s values (`KNOBS`: its keys), then
with all of them, in bracketed pairs: ideal, knob 1, ideal, knob 2, ..., ideal, each round (A B A C A ...). A
knob's ratio in a round is its time over the mean of the two ideal renders around it, and the table gives the
median over rounds, of wall time and of the process's CPU time (all threads: llvmpipe's, the writers'), so a
machine whose speed drifts, or that other jobs share, still gives a fair ratio; the seconds themselves are
that machine's. Disk: every file of the dataset per rig-frame (exact sizes on disk), and the RGB images alone.
"""
from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._table import tee  # noqa: E402
from benchmarks.label_costs import ROOT, render_once  # noqa: E402

#: each knob's keys (section.key), set as configs/data/realistic.yaml sets them
KNOBS = {
    "exposure": ("sensor.exposure_spread_ev", "sensor.auto_exposure_target", "sensor.auto_exposure_tau_s"),
    "white balance": ("sensor.white_balance_spread",),
    "vignetting": ("sensor.vignetting",),
    "noise": ("sensor.noise", "sensor.read_noise_e"),
    "fog": ("weather.fog_density",),
    "JPEG": ("sensor.jpeg_quality",),
}


def settings() -> dict[str, list[str]]:
    """{name: overrides}: ``ideal`` (no knob), each knob alone and ``all``, with realistic.yaml's values."""
    from synth.config import load_data_config

    cfg = load_data_config(ROOT / "configs" / "data" / "realistic.yaml")

    def value(key: str) -> str:
        section, field = key.split(".")
        return json.dumps(getattr(getattr(cfg, section), field), separators=(",", ":"))  # YAML reads JSON

    out = {"ideal": []}
    out.update({name: [f"{k}={value(k)}" for k in keys] for name, keys in KNOBS.items()})
    out["all"] = [ov for name in KNOBS for ov in out[name]]
    return out


def disk_bytes(out: Path) -> tuple[int, int]:
    """(every file of the dataset's sequences, the RGB images alone), bytes on disk."""
    seqs = [p for p in out.glob("seq_*/**/*") if p.is_file()]
    rgb = [p for p in seqs if p.name.count(".") == 1 and p.suffix in (".png", ".jpg")]
    return sum(p.stat().st_size for p in seqs), sum(p.stat().st_size for p in rgb)


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="320x192")
    ap.add_argument("--sequences", type=int, default=1)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--note", default="", help="a line printed above the table (where it was measured)")
    ap.add_argument("--record", type=Path, default=None)
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    base = [f"camera.width={w}", f"camera.height={h}", f"dataset.sequences={a.sequences}",
            f"dataset.frames={a.frames}", "dataset.val_fraction=0", "dataset.test_fraction=0"]
    sets, n = settings(), a.sequences * a.frames
    knobs = [k for k in sets if k != "ideal"]
    wall: dict[str, list[float]] = {k: [] for k in sets}
    cpu: dict[str, list[float]] = {k: [] for k in sets}
    ratio: dict[str, list[tuple[float, float]]] = {k: [] for k in knobs}
    disk: dict[str, tuple[int, int]] = {}

    def run(name: str, tag: str) -> None:
        out = Path(tmp) / tag
        c0 = time.process_time()
        wall[name].append(render_once(base + sets[name], out) / n)
        cpu[name].append((time.process_time() - c0) / n)
        disk.setdefault(name, disk_bytes(out))

    with tempfile.TemporaryDirectory() as tmp:
        render_once(base, Path(tmp) / "warmup")  # GL, shaders, caches
        for r in range(a.rounds):
            run("ideal", f"{r}_ideal_0")
            for k, name in enumerate(knobs):
                run(name, f"{r}_{k}")
                run("ideal", f"{r}_ideal_{k + 1}")
                ratio[name].append((wall[name][-1] / statistics.mean(wall["ideal"][-2:]),  # the ideal runs
                                    cpu[name][-1] / statistics.mean(cpu["ideal"][-2:])))  # before and after
    with tee(a.record):
        if a.note:
            print(a.note)
        print(f"{a.size}, {a.sequences} sequence(s) x {a.frames} frames, one worker, {a.rounds} rounds of bracketed "
              "pairs (ideal, knob, ideal, ...); s = median per rig-frame; x ideal = median over rounds of the knob's "
              "time over the two ideal renders around it")
        print(f"{'camera':>13} | {'wall s':>7} | {'x ideal':>7} | {'CPU s':>6} | {'x ideal':>7} | "
              f"{'disk KB / rig-frame':>19} | {'x ideal':>7} | {'RGB KB / rig-frame':>18}")
        print("-" * 104)
        ideal_disk = disk["ideal"][0]
        for name in sets:
            rw, rc = (1.0, 1.0) if name == "ideal" else (statistics.median(x[i] for x in ratio[name]) for i in (0, 1))
            total, rgb = disk[name]
            print(f"{name:>13} | {statistics.median(wall[name]):7.3f} | {rw:7.2f} | "
                  f"{statistics.median(cpu[name]):6.3f} | {rc:7.2f} | {total / n / 1024:19.1f} | "
                  f"{total / ideal_disk:7.2f} | {rgb / n / 1024:18.1f}")
        each = "; ".join(f"{k}: " + " ".join(v) for k, v in sets.items() if k not in ("ideal", "all"))
        print(f"(the settings: {each}; all: every one of them)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
