"""Wall and CPU time of one world of the L_con recipe (configs/sweep/cpu_lcon.yaml), part by part: its render, its
yardsticks, each arm's training and each arm's evaluation (the sweep's own stages: `study.sweep.worlds.render_stage`,
`study.sweep.worlds.reference_stage`, `mcdp.trainer.Trainer`, `study.sweep.stages.evaluate_run`), with this checkout's code and,
with ``--before DIR``, with another checkout's (e.g. ``git archive <commit> | tar -x -C DIR``) on the same world.

Feeds: docs/results/world_cost.md
Record: ``--record PATH.txt`` also writes the table it prints to PATH, as printed (`scripts/publish_bench.py`).

Each part runs in a process of its own (``--part``, the code's folder first on ``sys.path``) and times itself from
after its imports: wall (``time.perf_counter``) and CPU (user + system of the process and of the workers it waited
for, ``resource.getrusage``). The runs train from scratch (the recipe warm-starts from a shared pretraining, made once
per sweep, not per world: a step costs the same). Each code's runs are evaluated on the runs this checkout trained,
so both evaluate the same checkpoints. Rounds are interleaved (after, before, after, before, ...) and each part's
median is printed, so a load that comes and goes hits both codes alike. ``eval/train``: an arm's evaluation over its
training, as the committed runs' ``eval_s / train_s``.

    python benchmarks/world_cost.py --quick --before /tmp/before            # 8 test sequences, 20 steps: minutes
    python benchmarks/world_cost.py --before /tmp/before --rounds 1         # the recipe's world (32 test sequences)
    python benchmarks/world_cost.py --tests 32 --steps 200 --only eval      # evaluation only, on an existing --work
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RECIPE = ROOT / "configs" / "sweep" / "cpu_lcon.yaml"
OVERLAP, WORLD = 0.10, 0  # the recipe's one overlap; world 0's render (data seed + 0)
#: the recipe's split: 88 sequences, 8 val, 32 test (val_fraction 0.0909, test_fraction 0.3636)
TEST_FRACTION, VAL_FRACTION = 0.3636, 0.0909


def _study(name: str):
    """The sweep's module ``name`` (config, records, worlds, stages) of the checkout on the path: ``study.sweep.<name>``
    since study was laid out by role, ``study.<name>`` in a checkout from before (a ``--before`` copy)."""
    import importlib

    try:
        return importlib.import_module(f"study.sweep.{name}")
    except ModuleNotFoundError as e:
        if e.name not in (f"study.sweep.{name}", "study.sweep"):  # a missing import inside it: say that one
            raise
        return importlib.import_module(f"study.{name}")


def sweep_config(tests: int, steps: int, code: Path = ROOT):
    """The recipe's sweep config (as the checkout ``code`` has it) with ``tests`` test sequences (the train split
    scaled with them, as in the recipe) and ``steps`` training steps."""
    cfg = _study("config").load_sweep_config(code / RECIPE.relative_to(ROOT))
    sequences = max(3, round(tests / TEST_FRACTION))
    data = list(cfg.data_overrides) + [f"dataset.sequences={sequences}"]
    train = list(cfg.train_overrides) + [f"train.steps={steps}", f"train.ckpt_every={steps}",
                                          f"train.val_every={max(1, min(25, steps))}"]
    return cfg.model_copy(update={"data_overrides": data, "train_overrides": train, "workers": 2})


def _cpu_s() -> float:
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_part(part: str, work: Path, tests: int, steps: int, code: Path = ROOT) -> dict:
    """Do one part of the world in this process with the checkout ``code`` (its code and its presets);
    {"wall_s", "cpu_s"} of its work (imports excluded)."""
    import torch  # noqa: F401 (imported before the clock starts, as a sweep's worker has it)

    Counters = _study("records").Counters
    cfg = sweep_config(tests, steps, code)
    log = (lambda line: None)
    what, _, method = part.partition(":")
    if what == "render":
        render_stage = _study("worlds").render_stage
        t0, c0 = time.perf_counter(), _cpu_s()
        d = render_stage(cfg, OVERLAP, work / "sweep", Counters(), log, False, WORLD)
        out = {"splits": d["splits"]}
    else:
        sc = _study("config")
        data_config_for, eval_config_for, run_config_for, world_key = (
            sc.data_config_for, sc.eval_config_for, sc.run_config_for, sc.world_key)
        from synth.open import open_dataset
        from corelib.configlib import config_hash

        data = work / "sweep_main" / "data" / world_key(OVERLAP, WORLD)
        d = {"overlap": OVERLAP, "world": WORLD, "path": str(data),
             "config_hash": config_hash(data_config_for(cfg, OVERLAP, WORLD))}
        ds = open_dataset(data)
        if what == "yardsticks":
            reference_stage = _study("worlds").reference_stage
            side = work / f"yardsticks_{os.getpid()}"
            (side / "data").mkdir(parents=True)
            t0, c0 = time.perf_counter(), _cpu_s()
            reference_stage(cfg, d, side, Counters(), log)
        elif what == "train":
            from mcdp.trainer import Trainer

            rcfg, _ = run_config_for(cfg, method, WORLD)
            run_dir = work / f"runs_{os.getpid()}" / method
            t0, c0 = time.perf_counter(), _cpu_s()
            tr = Trainer(rcfg, ds, run_dir, progress=False)
            try:
                tr.train()
            finally:
                tr.close()
        elif what == "eval":
            evaluate_run = _study("stages").evaluate_run
            run_dir = work / "runs" / method
            t0, c0 = time.perf_counter(), _cpu_s()
            evaluate_run(cfg, run_dir, ds, eval_config_for(cfg), False, log, method)
        else:
            raise SystemExit(f"world_cost: unknown part {part!r}")
        out = {}
    return {**out, "wall_s": time.perf_counter() - t0, "cpu_s": _cpu_s() - c0}


def _spawn(code: Path, part: str, work: Path, tests: int, steps: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(code)}
    cmd = [sys.executable, str(Path(__file__).resolve()), "--part", part, "--code", str(code), "--work", str(work),
           "--tests", str(tests), "--steps", str(steps)]
    res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=code)  # its presets, relative paths
    if res.returncode != 0:
        raise SystemExit(f"world_cost: part {part} with {code} failed:\n{res.stderr[-3000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _prepare(work: Path, tests: int, steps: int, methods: list[str], trainer: Path = ROOT) -> dict:
    """The world the evaluations read: rendered once by this checkout, its runs trained once by ``trainer`` (the
    older code when there are two: a checkpoint of newer code may hold keys that older code refuses; newer code
    reads an older checkpoint); not timed here."""
    import shutil

    data = work / "sweep_main" / "data"
    if not data.exists():
        rec = _spawn(ROOT, "render", work, tests, steps)
        (work / "sweep_main").mkdir(parents=True, exist_ok=True)
        shutil.move(str(work / "sweep" / "data"), str(data))
        shutil.rmtree(work / "sweep", ignore_errors=True)
        print(f"world: splits {rec['splits']}", file=sys.stderr)
    for m in methods:
        if not (work / "runs" / m / "checkpoints" / "last.pt").exists():
            _spawn(trainer, f"train:{m}", work, tests, steps)
            pid_runs = sorted(work.glob("runs_*"), key=lambda p: p.stat().st_mtime)[-1]
            (work / "runs").mkdir(exist_ok=True)
            shutil.move(str(pid_runs / m), str(work / "runs" / m))
            shutil.rmtree(pid_runs, ignore_errors=True)
    return {}


def _clean(work: Path) -> None:
    import shutil

    for p in list(work.glob("runs_*")) + list(work.glob("yardsticks_*")) + [work / "sweep"]:
        shutil.rmtree(p, ignore_errors=True)


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 test sequences (12 train, 2 val) and 20 training steps")
    ap.add_argument("--tests", type=int, default=None, help="test sequences of the world (default 32, the recipe's)")
    ap.add_argument("--steps", type=int, default=None, help="training steps per arm (default 200, the recipe's)")
    ap.add_argument("--before", metavar="DIR", help="another checkout's root: its code timed on the same world")
    ap.add_argument("--rounds", type=int, default=2, help="interleaved rounds per part (median printed)")
    ap.add_argument("--only", choices=["all", "eval"], default="all", help="eval: time only the evaluations")
    ap.add_argument("--parts", nargs="+", metavar="PART", help="time only these parts (render, train:ARM, "
                    "yardsticks, eval:ARM), e.g. eval:mcdp_m2")
    ap.add_argument("--work", metavar="DIR", help="working folder (default a fresh one under /tmp); reused if given")
    ap.add_argument("--record", metavar="PATH", help="also write what it prints to PATH (text)")
    ap.add_argument("--part", help=argparse.SUPPRESS)
    ap.add_argument("--code", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    tests = args.tests or (8 if args.quick else 32)
    steps = args.steps or (20 if args.quick else 200)
    if args.part:  # a child: this part with the code of --code first on sys.path
        sys.path.insert(0, args.code)
        print(json.dumps(run_part(args.part, Path(args.work), tests, steps, Path(args.code))))
        return 0
    import tempfile

    sys.path.insert(0, str(ROOT))
    from benchmarks._table import tee

    cfg_methods = ["mcdp_m2_nocon", "mcdp_m2"]
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="world_cost_"))
    work.mkdir(parents=True, exist_ok=True)
    codes = [("after", ROOT)] + ([("before", Path(args.before).resolve())] if args.before else [])
    _prepare(work, tests, steps, [m for m in cfg_methods if args.parts is None or f"eval:{m}" in args.parts
                                  or f"train:{m}" in args.parts], codes[-1][1])
    parts = (["render"] + [f"train:{m}" for m in cfg_methods] if args.only == "all" else [])
    parts += ["yardsticks"] + [f"eval:{m}" for m in cfg_methods]
    if args.parts:
        parts = [p for p in parts if p in args.parts]
    times: dict = {}
    for r in range(args.rounds):
        for part in parts:
            if r > 0 and part.split(":")[0] in ("render", "train"):
                continue  # the long parts once: what the evaluation changed is measured in rounds
            for name, code in codes if r % 2 == 0 else codes[::-1]:
                rec = _spawn(code, part, work, tests, steps)
                times.setdefault((part, name), []).append(rec)
                _clean(work)
                print(f"  round {r + 1}/{args.rounds} {part} {name}: {rec['wall_s']:.1f} s wall, "
                      f"{rec['cpu_s']:.1f} s CPU", file=sys.stderr, flush=True)
    with tee(args.record):
        print(f"One world of the L_con recipe ({RECIPE.relative_to(ROOT)}, overlap {OVERLAP}, world {WORLD}): "
              f"{tests} test sequences, {steps} training steps per arm; parts one at a time, "
              f"{args.rounds} interleaved round(s) of the evaluations (median), render and training once")
        head = f"{'part':<22} {'code':<7} {'wall s':>8} {'cpu s':>8} {'after/before wall':>18} {'cpu':>6}"
        print(head)
        print("-" * len(head))
        med = {k: (statistics.median(x["wall_s"] for x in v), statistics.median(x["cpu_s"] for x in v))
               for k, v in times.items()}
        for part in parts:
            for name, _ in codes:
                w, c = med[part, name]
                ratio = ""
                if name == "after" and (part, "before") in med:
                    bw, bc = med[part, "before"]
                    ratio = f"{w / bw:>18.2f} {c / bc:>6.2f}"
                print(f"{part:<22} {name:<7} {w:>8.1f} {c:>8.1f} {ratio}")
        for name, _ in codes:
            total = sum(med[p, name][0] for p in parts)
            cpu = sum(med[p, name][1] for p in parts)
            line = f"world ({name}): {total:.1f} s wall, {cpu:.1f} s CPU (parts one after another)"
            if all(f"{k}:{m}" in parts for k in ("train", "eval") for m in cfg_methods):
                ev = sum(med[f"eval:{m}", name][0] for m in cfg_methods)
                tr = sum(med[f"train:{m}", name][0] for m in cfg_methods)
                line += f"; eval/train: {ev / tr:.2f}"
            print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
