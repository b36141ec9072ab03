"""The engines side by side: render rig-frames/s and the CI sweep's wall time, local vs Ray.

Feeds: docs/results/scaling.md
Record: ``--record PATH.csv`` also writes its tables' rows to PATH_render.csv and PATH_sweep.csv (the CSV
`scripts/publish_bench.py` reads).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/engines.py [--sequences 6 --frames 6] [--no-sweep]

Render: configs/data/tiny.yaml (96x64) with ``--sequences`` x ``--frames``, end to end
(`synth.render.render_dataset`: masks, scene generation, six renders, PNG + EXR + sha256,
manifest) with the local engine at workers=1 and 2, and with Ray on a local instance of
``--ray-cpus`` CPUs: "cold" includes starting Ray (what ``synth render --engine ray`` pays),
"warm" renders into a Ray already running. Sweep: ``mcdp sweep configs/sweep/ci.yaml`` as the
console script (a fresh folder each, so pretraining, renders, 10 runs and the report), local
jobs=1, local jobs=2, and ``--engine ray ray_cpus=N``. Prints Markdown tables and the load
average before and after (other processes on the machine slow every column).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._table import record_path, show  # noqa: E402

QUIET = dict(progress=False, log=lambda *a: None)


def _load() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def render_rows(sequences: int, frames: int, ray_cpus: int, tmp: Path) -> list[tuple[str, float, float]]:
    from synth.config import load_data_config
    from synth.render import render_dataset

    cfg = load_data_config(ROOT / "configs" / "data" / "tiny.yaml",
                           [f"dataset.sequences={sequences}", f"dataset.frames={frames}"])
    rows = []
    for label, kw in (("local, workers=1", dict(workers=1)), ("local, workers=2", dict(workers=2))):
        t0 = time.perf_counter()
        s = render_dataset(cfg, tmp / label.replace(" ", "").replace(",", "_"), **kw, **QUIET)
        rows.append((label, s["rig_frames"] / (time.perf_counter() - t0), time.perf_counter() - t0))
    import ray

    t0 = time.perf_counter()
    ray.init(address="local", num_cpus=ray_cpus, include_dashboard=False)
    t_start = time.perf_counter() - t0
    t1 = time.perf_counter()
    s = render_dataset(cfg, tmp / "ray", engine="ray", **QUIET)
    warm = time.perf_counter() - t1
    ray.shutdown()
    rows.append((f"Ray ({ray_cpus} CPUs), cold (incl. {t_start:.1f} s Ray start)", s["rig_frames"] / (warm + t_start),
                 warm + t_start))
    rows.append((f"Ray ({ray_cpus} CPUs), warm", s["rig_frames"] / warm, warm))
    return rows


def sweep_rows(ray_cpus: int, tmp: Path) -> list[tuple[str, float]]:
    mcdp = str(Path(sys.executable).parent / "mcdp")
    rows = []
    for label, extra in (("local, jobs=1", ["jobs=1"]), ("local, jobs=2", ["jobs=2"]),
                         (f"Ray ({ray_cpus} CPUs)", ["--engine", "ray", f"ray_cpus={ray_cpus}"])):
        out = tmp / f"sweep_{len(rows)}"
        t0 = time.perf_counter()
        subprocess.run([mcdp, "sweep", str(ROOT / "configs" / "sweep" / "ci.yaml"), "--out", str(out),
                        "--no-progress", *extra], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        rows.append((label, time.perf_counter() - t0))
        shutil.rmtree(out, ignore_errors=True)
    return rows


def show_render(rows: list[tuple[str, float, float]], record: Path | None = None) -> str:
    """Print the render table of `rows` ((engine, rig-frames/s, wall s) each); recorded as PATH_render.csv."""
    return show(["engine", "rig-frames/s", "wall s"], [[e, f"{rate:.2f}", f"{wall:.1f}"] for e, rate, wall in rows],
                "lrr", record_path(record, "render"))


def show_sweep(rows: list[tuple[str, float]], record: Path | None = None) -> str:
    """Print the CI sweep table of `rows` ((engine, wall s) each); recorded as PATH_sweep.csv."""
    return show(["engine", "wall s"], [[e, f"{wall:.1f}"] for e, wall in rows], "lr", record_path(record, "sweep"))


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--sequences", type=int, default=6)
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--ray-cpus", type=int, default=2)
    ap.add_argument("--no-sweep", action="store_true")
    ap.add_argument("--record", type=Path, metavar="PATH", help="also write the tables' rows (CSV): PATH_render.csv, "
                    "PATH_sweep.csv")
    args = ap.parse_args(argv)
    print(f"cores: {os.cpu_count()}, load average (1/5/15 min) before: {_load()}")
    with tempfile.TemporaryDirectory(prefix="bench_engines_") as d:
        tmp = Path(d)
        rows = render_rows(args.sequences, args.frames, args.ray_cpus, tmp)
        print(f"\nRender, configs/data/tiny.yaml 96x64, {args.sequences} sequences x {args.frames} frames "
              f"= {args.sequences * args.frames} rig-frames\n")
        show_render(rows, args.record)
        if not args.no_sweep:
            srows = sweep_rows(args.ray_cpus, tmp)
            print("\nCI sweep (configs/sweep/ci.yaml: pretraining, 2 overlaps x 5 methods x 1 seed, "
                  "2 training steps each), `mcdp sweep` wall time\n")
            show_sweep(srows, args.record)
    print(f"\nload average after: {_load()}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
