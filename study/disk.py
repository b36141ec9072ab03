"""What a sweep will write to disk, said before it starts and refused when the disk cannot hold it.

A sweep writes its renders and, per run, its checkpoints: ``last.pt`` (the networks' weights and Adam's two
moments, about three times the weights) while ``keep_last``, ``best.pt`` (the weights) while ``keep_best``, and
both for a while during training whatever they say. A propagation sweep of 90 runs kept 16 GB of checkpoints and
once filled the disk after 67 minutes: the sweep stopped cleanly (nothing half-written was kept), but the time
was lost. So the command line says the estimate beside the renders' size, and refuses a sweep that would write
more than the space free where it writes, unless ``--yes``::

    mcdp sweep: its checkpoints: 42 run(s) x (last.pt about 173 MB + best.pt 58 MB): 9.99 GB of checkpoints at
    most (keep_last: true, keep_best: true); with the renders about 11.2 GB; 11.2 GB still to write, 35.8 GB free

The checkpoint sizes come from the networks themselves, built on PyTorch's ``meta`` device (no memory, no
weights read): the bytes of their state and of the trainable parameters' two Adam moments. A method whose
network cannot be built that way is left out of the estimate, and the line says so. What is already under the
sweep's folder (a resumed sweep) counts as written.
"""
from __future__ import annotations

import os
import shutil
from pathlib import Path

from corelib.configlib import ConfigError
from study.config import SweepConfig, run_config_for

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
    """The bytes of the files under ``folder`` (links not followed; 0 when it does not exist)."""
    total = 0
    for root, _dirs, files in os.walk(folder):
        for f in files:
            try:
                st = os.lstat(os.path.join(root, f))
            except OSError:
                continue
            total += st.st_size
    return total


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


def statement(est: dict, cfg: SweepConfig) -> str:
    """One line: the checkpoints' estimate and the total with the renders."""
    line = (f"{est['runs']} run(s) x (last.pt about {est['last'] / 1e6:.0f} MB + best.pt {est['best'] / 1e6:.0f} MB):"
            f" {_gb(est['checkpoints'])} of checkpoints at most (keep_last: {str(cfg.keep_last).lower()}, keep_best: "
            f"{str(cfg.keep_best).lower()}); with the renders about {_gb(est['total'])}")
    if est["unsized"]:
        line += f" (not counted: {', '.join(est['unsized'])}, whose network was not built on the meta device)"
    return line


def check_disk(cfg: SweepConfig, out: str | Path, render_bytes: int, yes: bool) -> str:
    """The checkpoints' line (`statement`); ConfigError when what is still to write (the estimate less what
    is already under ``out``) is more than the space free there and the user did not say ``--yes``."""
    out = Path(out)
    est = estimate(cfg, render_bytes)
    todo = max(0, est["total"] - bytes_under(out))
    free = free_bytes(out)
    if todo > free and not yes:
        keys = [f"{k}: false" for k, on in (("keep_last", cfg.keep_last), ("keep_best", cfg.keep_best)) if on]
        raise ConfigError(f"sweep --out {out}: it will write about {_gb(todo)} more ({statement(est, cfg)}) and "
                          f"{_gb(free)} are free there; " + (f"set {' and '.join(keys)}, " if keys else "")
                          + "run fewer seeds / overlaps / methods, free some space, or pass --yes")
    return statement(est, cfg) + f"; {_gb(todo)} still to write, {_gb(free)} free"
