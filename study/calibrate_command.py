"""``mcdp calibrate``: train every arm of the anchors file at the calibration recipe, one sweep folder per arm.

Each arm is the sweep preset (``configs/sweep/cpu_calibration.yaml``) with ``methods: [arm.method]`` and the arm's
overrides appended to ``train_overrides``; every arm's folder shares the first arm's pretraining and rendered
worlds (hard links of its ``pretrain/``, ``data/`` and ``.mcdp/``, made before the arm's sweep starts), so the arms
differ by their switch only and every world is rendered once. The sweeps run one after the other, in the file's
``order``, each on the sweep's own engine (its ``jobs`` runs at a time): a session cut short has the first arms.
A rerun resumes every arm (each sweep skips what it has). The calibration page reads the folders
(`study.report.sections.calibration`).

Example::

    mcdp calibrate configs/calibration/anchors.yaml configs/sweep/cpu_calibration.yaml --out sweeps/calibration
    mcdp calibrate ... --arms mono2,mono2_nomask "train_overrides+=[train.steps=800]"   # the scale point
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

from corelib.configlib import ConfigError

#: what every arm's folder shares with the first arm's (the pretraining, the rendered worlds, the folder's marker
#: file, without which a sweep refuses a folder that is not empty)
SHARED = ("pretrain", "data", ".mcdp")


def arm_overrides(base_overrides: list[str], arm_overrides: list[str], method: str) -> list[str]:
    """The sweep overrides of one arm: its method, and the preset's train_overrides followed by the arm's."""
    train = ", ".join(list(base_overrides) + list(arm_overrides))
    return [f"methods=[{method}]", f"train_overrides=[{train}]"]


def link_shared(first: Path, target: Path) -> list[str]:
    """Hard-link ``first``'s shared folders into ``target`` where ``target`` has none yet; the folders linked."""
    done = []
    for name in SHARED:
        src, dst = first / name, target / name
        if src.is_symlink() or not src.exists():
            continue
        if os.path.lexists(dst):  # a folder shared before: the first arm's worlds (or pretrainings) it lacks
            if src.is_dir() and dst.is_dir() and not dst.is_symlink():
                for child in sorted(src.iterdir()):
                    if not child.is_symlink() and not os.path.lexists(dst / child.name):
                        subprocess.run(["cp", "-al", str(child), str(dst / child.name)], check=True)
                        done.append(f"{name}/{child.name}")
            continue
        target.mkdir(parents=True, exist_ok=True)
        if src.is_dir():
            subprocess.run(["cp", "-al", str(src), str(dst)], check=True)
        else:  # the sweep folder's marker file (`corelib.rundir`)
            os.link(src, dst)
        done.append(name)
    return done


def calibrate_args(p: argparse.ArgumentParser) -> None:
    """The arguments of ``mcdp calibrate``."""
    p.add_argument("anchors", help="anchors file, e.g. configs/calibration/anchors.yaml")
    p.add_argument("preset", help="sweep preset of the recipe, e.g. configs/sweep/cpu_calibration.yaml")
    p.add_argument("--out", required=True, help="calibration folder: one sweep folder per arm under it")
    p.add_argument("--arms", default="", help="comma-separated arms to run (default: every arm, in the file's order)")
    p.add_argument("--extra", default="", help="train overrides added to every arm (the scale point), comma-separated")
    p.add_argument("--dry-run", action="store_true", help="print each arm's sweep command and stop")
    p.add_argument("overrides", nargs="*", help="sweep overrides for every arm, e.g. 'seeds=[700,701]'")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="mcdp calibrate", description=__doc__.splitlines()[0])
    calibrate_args(p)
    return run_calibrate(p.parse_args(argv))


def run_calibrate(args: argparse.Namespace) -> int:
    """Run ``mcdp calibrate``: 0, or the worst exit status of the arms' sweeps; 2 for a bad file or argument."""
    from study.report.sections.anchors import load_anchors
    from study.sweep.config import load_sweep_config

    try:
        anchors = load_anchors(args.anchors)
        cfg = load_sweep_config(Path(args.preset), args.overrides)
    except ConfigError as exc:
        print(f"mcdp calibrate: {exc}", file=sys.stderr)
        return 2
    order = list(anchors.order)
    if args.arms:
        wanted = [a.strip() for a in args.arms.split(",") if a.strip()]
        unknown = [a for a in wanted if a not in anchors.arms]
        if unknown:
            print(f"mcdp calibrate: --arms: {unknown[0]!r} is not an arm of {args.anchors} ({', '.join(order)})",
                  file=sys.stderr)
            return 2
        order = [a for a in order if a in wanted]
    extra = [x.strip() for x in args.extra.split(",") if x.strip()]
    out = Path(args.out)
    first = out / anchors.order[0]
    worst = 0
    for name in order:
        arm = anchors.arms[name]
        over = list(args.overrides) + arm_overrides(list(cfg.train_overrides) + extra, arm.overrides, arm.method)
        cmd = [sys.executable, "-m", "study.cli", "sweep", args.preset, "--out", str(out / name), "--no-progress",
               *over]
        print(f"mcdp calibrate: arm {name}: {' '.join(cmd[2:])}", file=sys.stderr, flush=True)
        if args.dry_run:
            continue
        if name != anchors.order[0]:
            linked = link_shared(first, out / name)
            if linked:
                print(f"mcdp calibrate: arm {name}: shares {', '.join(linked)} with {first}", file=sys.stderr)
        rc = subprocess.run(cmd, env=dict(os.environ)).returncode
        if rc == 130:
            return rc
        worst = max(worst, rc)
    return worst


if __name__ == "__main__":
    sys.exit(main())
