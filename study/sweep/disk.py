"""What a sweep will write to disk, said before it starts and refused when the disk cannot hold it.

A sweep writes its renders and, per run, its checkpoints: ``last.pt`` (the networks' weights and Adam's two
moments, about three times the weights) while ``keep_last``, ``best.pt`` (the weights) while ``keep_best``, and
both for a while during training whatever they say. A propagation sweep of 90 runs kept 16 GB of checkpoints and
once filled the disk after 67 minutes: the sweep stopped cleanly (nothing half-written was kept), but the time
was lost. So the command line says the estimate beside the renders' size, and refuses a sweep that would write
more than the space free where it writes, unless ``--yes``::

    mcdp sweep: its checkpoints: 14 run(s), each writing last.pt about 328 MB and best.pt 109 MB; no run keeps
    its checkpoints, and 2 at a time hold both while they train (keep_last: false, keep_best: false), with the
    pretraining: 0.983 GB of checkpoints on disk at most; with the renders about 1.98 GB; 1.98 GB still to write
    (14 of 14 run(s) and 2 of 2 world(s) left), 76.8 GB free

The checkpoint sizes come from the networks themselves, built on PyTorch's ``meta`` device (no memory, no
weights read): the bytes of their state and of the trainable parameters' two Adam moments. A method whose
network cannot be built that way is left out of the estimate, and the line says so.

What is still to write (`still_to_write`) counts only what a resumed sweep has not done: the worlds without a
manifest (a render's last file), the runs without their ``metrics_test.json``, the pretraining without its
``pretrain.json``; a complete sweep writes nothing more and is never refused. Bytes on disk are counted as the
blocks a file holds (a sparse file holds few), never its apparent size. The space free is measured where the
bytes land (``data/`` for the renders, ``runs/`` and ``pretrain/`` for the checkpoints: a folder mounted there
is its own file system); a symbolic link among the sweep's own folders (``data/``, ``pretrain/``, ``plots/``,
and the folders in the first two) is refused before anything is written (`refuse_own_links`), so no writer
writes outside ``--out``. (A run folder under ``runs/`` may be a link: another sweep's run reused read only,
`study.sweep.stages`.)
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from corelib.configlib import ConfigError
from study.sweep.config import SweepConfig, run_config_for

#: the fraction of a render's uncompressed bound (`synth.config.render_size`) that lands on disk, as the
#: render's own size line says ("about a third")
RENDER_ON_DISK = 1 / 3


def checkpoint_bytes(rcfg, n_cameras: int = 6) -> tuple[int, int]:
    """(last.pt, best.pt) bytes of one run of ``rcfg``, estimated from its networks built on the meta device:
    best.pt holds the state's tensors, last.pt those and the trainable parameters' two Adam moments."""
    import torch

    from mcdp.system import SelfSupervisedSystem

    ring = [(i, (i + 1) % n_cameras) for i in range(n_cameras)]
    with torch.device("meta"):
        system = SelfSupervisedSystem(rcfg, ring, n_cameras)
    state = sum(t.numel() * t.element_size() for t in system.state_dict().values())
    moments = sum(2 * p.numel() * p.element_size() for p in system.parameters() if p.requires_grad)
    return state + moments, state


def bytes_under(folder: Path) -> int:
    """The bytes on disk of the files under ``folder``: the blocks each holds (a sparse file of 1 TB holds few),
    links not followed (0 when it does not exist)."""
    total = 0
    for root, _dirs, files in os.walk(folder):
        for f in files:
            try:
                st = os.lstat(os.path.join(root, f))
            except OSError:
                continue
            total += st.st_blocks * 512
    return total


#: the sweep's own folders that no link may stand in for (``runs/``' run folders may: a reused run, read only)
OWN_FOLDERS = ("data", "pretrain", "plots")


def refuse_own_links(out: Path) -> None:
    """`corelib.atomic.LinkRefused` (one line naming it) for a symbolic link at one of the sweep's own folders
    (`OWN_FOLDERS`), at an entry of ``data/`` or ``pretrain/`` (a world, a pretraining) or at a folder of a
    pretraining (``pretrain/<hash>/data``, ``run``): a writer would write through it, outside ``--out``, where
    the disk check did not look."""
    from corelib.atomic import LinkRefused

    def entries(folder: Path):
        try:
            with os.scandir(folder) as it:
                return sorted(e.name for e in it)
        except (NotADirectoryError, FileNotFoundError):
            return []

    for name in OWN_FOLDERS:
        top = Path(out) / name
        if os.path.islink(top):
            raise LinkRefused(top)
        if name == "plots":
            continue
        for sub in entries(top):
            if os.path.islink(top / sub):
                raise LinkRefused(top / sub)
            if name == "pretrain":
                for inner in entries(top / sub):
                    if os.path.islink(top / sub / inner) and inner in ("data", "run"):
                        raise LinkRefused(top / sub / inner)


def free_bytes(out: Path) -> int:
    """The bytes free on the file system of ``out`` (of its nearest existing parent when it does not exist)."""
    p = Path(os.path.abspath(out))
    while not p.exists() and p != p.parent:
        p = p.parent
    return shutil.disk_usage(p).free


def estimate(cfg: SweepConfig, render_bytes: int) -> dict:
    """What the whole sweep writes: ``renders`` (on disk), ``last`` / ``best`` (bytes of one run's checkpoint,
    the largest over its methods), ``runs``, ``checkpoints`` (the most on disk at once: those kept, the
    ``jobs`` runs that hold both while they train, and the pretraining's, sized as the runs' networks),
    ``total``, and ``unsized`` (methods whose network could not be built on the meta device)."""
    runs = len(cfg.overlaps) * len(cfg.methods) * len(cfg.seeds)
    last = best = 0
    unsized = []
    init_from = "pretrained.pt" if cfg.pretrain is not None else None
    for method in cfg.methods:
        try:
            lb = checkpoint_bytes(run_config_for(cfg, method, cfg.seeds[0], init_from)[0])
        except Exception:  # an estimate only: a network that cannot be built on meta is said, not fatal
            unsized.append(method)
            continue
        last, best = max(last, lb[0]), max(best, lb[1])
    kept = runs * ((last if cfg.keep_last else 0) + (best if cfg.keep_best else 0))
    transient = min(runs, cfg.jobs) * ((0 if cfg.keep_last else last) + (0 if cfg.keep_best else best))
    pre = 0 if cfg.pretrain is None else (best + (last if cfg.keep_last else 0) + (best if cfg.keep_best else 0))
    renders = int(render_bytes * RENDER_ON_DISK)
    checkpoints = kept + transient + pre
    return {"renders": renders, "last": last, "best": best, "runs": runs, "checkpoints": checkpoints,
            "total": renders + checkpoints, "unsized": unsized}


def _gb(n: int) -> str:
    return f"{n / 1e9:.3g} GB"


def _is_file(path: Path) -> bool:
    try:
        return os.path.isfile(path) and not os.path.islink(path)
    except OSError:
        return False


def still_to_write(cfg: SweepConfig, out: Path, est: dict) -> dict:
    """What a (resumed) sweep has still to write: ``renders`` (the worlds without their manifest, each its share of
    the renders), ``checkpoints`` (the runs without their metrics_test.json: those they keep and, ``jobs`` at a
    time, those they delete; the pretraining's unless its pretrain.json is written), their sum ``total``, and the
    counts ``runs_left``, ``worlds_left`` and ``worlds``."""
    from study.sweep.config import overlap_key, world_key, worlds_of

    out = Path(out)
    worlds = [(o, w) for o in cfg.overlaps for w in worlds_of(cfg)]
    worlds_left = sum(not _is_file(out / "data" / world_key(o, w) / "manifest.json") for o, w in worlds)
    runs_left = sum(not _is_file(out / "runs" / overlap_key(o) / f"{m}_s{s}" / "metrics_test.json")
                    for o in cfg.overlaps for m in cfg.methods for s in cfg.seeds)
    last, best = est["last"], est["best"]
    kept = runs_left * ((last if cfg.keep_last else 0) + (best if cfg.keep_best else 0))
    transient = min(runs_left, cfg.jobs) * ((0 if cfg.keep_last else last) + (0 if cfg.keep_best else best))
    pre_done = cfg.pretrain is None or any(_is_file(p) for p in (out / "pretrain").glob("*/pretrain.json"))
    pre = 0 if pre_done else best + (last if cfg.keep_last else 0) + (best if cfg.keep_best else 0)
    renders = est["renders"] * worlds_left // max(1, len(worlds))
    checkpoints = kept + transient + pre
    return {"renders": renders, "checkpoints": checkpoints, "total": renders + checkpoints, "runs_left": runs_left,
            "worlds_left": worlds_left, "worlds": len(worlds)}


def statement(est: dict, cfg: SweepConfig) -> str:
    """One line: what the checkpoints' figure sums (the most on disk at once, not runs x sizes) and the total with
    the renders."""
    kept = [n for n, on in (("last.pt", cfg.keep_last), ("best.pt", cfg.keep_best)) if on]
    held = (f"every run keeps {' and '.join(kept)}" if kept else "no run keeps its checkpoints") + \
        (f", and {min(est['runs'], cfg.jobs)} at a time hold both while they train" if len(kept) < 2 else "")
    line = (f"{est['runs']} run(s), each writing last.pt about {est['last'] / 1e6:.0f} MB and best.pt "
            f"{est['best'] / 1e6:.0f} MB; {held} (keep_last: {str(cfg.keep_last).lower()}, keep_best: "
            f"{str(cfg.keep_best).lower()}){', with the pretraining' if cfg.pretrain is not None else ''}: "
            f"{_gb(est['checkpoints'])} of checkpoints on disk at most; with the renders about {_gb(est['total'])}")
    if est["unsized"]:
        line += f" (not counted: {', '.join(est['unsized'])}, whose network was not built on the meta device)"
    return line


def _where(out: Path, sub: str) -> Path:
    """The nearest existing folder of ``out/sub`` (where its bytes land: a file system mounted there is its own)."""
    p = Path(os.path.abspath(out / sub))
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _device(path: Path) -> int:
    """The file system ``path`` lies on."""
    return os.stat(path).st_dev


def check_disk(cfg: SweepConfig, out: str | Path, render_bytes: int, yes: bool) -> str:
    """The checkpoints' line (`statement`) and what is still to write (`still_to_write`) against the space free
    where it lands; ConfigError when it is more than that and the user did not say ``--yes``. A link among the
    sweep's own folders is refused first (`refuse_own_links`), before anything is written."""
    out = Path(out)
    refuse_own_links(out)
    est = estimate(cfg, render_bytes)
    todo = still_to_write(cfg, out, est)
    # the bytes by the file system they land on: renders in data/, checkpoints in runs/ and pretrain/
    by_dev: dict[int, list] = {}
    for sub, n in (("data", todo["renders"]), ("runs", todo["checkpoints"])):
        where = _where(out, sub)
        entry = by_dev.setdefault(_device(where), [where, 0])
        entry[1] += n
    short = [(where, n, free_bytes(where)) for where, n in by_dev.values()]
    worst = max(short, key=lambda t: t[1] - t[2])
    left = (f"{_gb(todo['total'])} still to write ({todo['runs_left']} of {est['runs']} run(s) and "
            f"{todo['worlds_left']} of {todo['worlds']} world(s) left)")
    free = ", ".join(f"{_gb(f)} free" + (f" on {w}" if len(short) > 1 else "") for w, _n, f in short)
    if worst[1] > worst[2] and not yes:
        keys = [f"{k}: false" for k, on in (("keep_last", cfg.keep_last), ("keep_best", cfg.keep_best)) if on]
        where = f" on {worst[0]}" if len(short) > 1 else ""
        raise ConfigError(f"sweep --out {out}: it will write about {_gb(worst[1])} more{where} ({statement(est, cfg)}; "
                          f"{left}) and {_gb(worst[2])} are free there; "
                          + (f"set {' and '.join(keys)}, " if keys else "")
                          + "run fewer seeds / overlaps / methods, free some space, or pass --yes")
    return statement(est, cfg) + f"; {left}, {free}"
