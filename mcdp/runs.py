"""A run on disk: its checkpoints (written whole, read without pickle), resuming, the device.

Run folder::

    RUN/config.yaml            resolved RunConfig
    RUN/run.json               dataset path (every dataset trained on), cameras, rig, neighbours, warm start
    RUN/checkpoints/last.pt    model, optimiser, step, config, RNG (written whole: corelib.atomic)
    RUN/checkpoints/best.pt    lowest val loss: networks, step, config (no optimiser state: a third of the
                               size; resuming always starts from last.pt)
    RUN/checkpoints/written.json  the checkpoints the trainer wrote, each with its sha256 (`mcdp.checkpoint_files`)
    RUN/checkpoints/removed.json  the checkpoints deleted after use, each with its step, size and why
                               (a sweep's keep_last / keep_best: false); `find_checkpoint` then says so
    RUN/tensorboard/           scalars (val/depth_*: `mcdp.validation`), six-camera image grids, the config
                               (mcdp.logger)
    RUN/train.log              every line of the run (`corelib.logs`: the stderr lines, and DEBUG the
                               logged steps' losses), appended on resume

Example::

    ckpt = load_checkpoint(find_checkpoint("runs/m1"))   # best.pt, else last.pt
    cfg = config_from_checkpoint(ckpt)
    run_hash(cfg)   # its cache key: the config with the warm start named by content, not path
"""
from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import torch

from corelib.atomic import atomic_write_json
from corelib.configlib import build_config, config_hash, config_to_dict, hashed_dict
from corelib.readfile import read_json_file
from corelib.version import code_version
from mcdp.checkpoint_files import REMOVED, atomic_torch_save, removed_checkpoints  # noqa: F401 (names callers use)
from mcdp.config import RunConfig, resume_conflicts, upgrade_config_dict

CHECKPOINT_VERSION = 1


class RunError(ValueError):
    """A run folder or checkpoint cannot be used as asked; the message says why and what to do."""


# --------------------------------------------------------------------------- the cache key of a run
def run_hash(cfg: RunConfig) -> str:
    """The cache key of a run (a sweep's ``run_config_hash``): `config_hash` of its resolved config with
    ``model.init_from`` named by the sha256 of the weights it starts from instead of by their path, so a
    sweep folder (its runs and the pretraining they start from) copied or moved elsewhere keeps every
    run's key. The content, not the pretraining's config hash: a pretraining made again to other bits
    (a GPU's nondeterminism) is another start, and its runs are trained again. A missing file keeps its
    path (the training then refuses it, naming ``model.init_from``). Without a warm start it is
    `config_hash` itself."""
    d = hashed_dict(cfg)
    src = cfg.model.init_from
    if src is not None and Path(src).is_file():
        d["model"]["init_from"] = {"sha256": _file_digest(Path(src))}
    return config_hash(d)


def _file_digest(path: Path) -> str:
    """sha256 of a file, computed once per process for the same file, size and modification time."""
    st = path.stat()
    return _digest(str(path.resolve()), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=16)
def _digest(path: str, size: int, mtime_ns: int) -> str:
    from corelib.hashing import sha256_file

    return sha256_file(path)


# --------------------------------------------------------------------------- checkpoints
def checkpoint_record(step: int, cfg: RunConfig, depth, pose, optimizer, scaler, ds, *, best_val: float,
                      val_history: list, spread: dict, init_from, world_size: int) -> dict:
    """What a training checkpoint holds (`load_checkpoint` reads it): the networks', optimiser's and scaler's
    states, the step, the config, the val history, the rig trained on, the RNG state and the code version."""
    return {
        "version": CHECKPOINT_VERSION,
        "step": step,
        "config": config_to_dict(cfg),
        "depth_model": depth.state_dict(),
        "pose_model": pose.state_dict() if pose is not None else None,
        "optimizer": optimizer.state_dict(),
        "scaler": scaler.state_dict(),
        "best_val": best_val,
        "val_history": val_history,
        "cameras": list(ds.camera_names),
        "neighbours": [list(p) for p in ds.neighbours],
        "torch_rng": torch.get_rng_state(),
        "depth_spread": dict(spread),
        "init_from": init_from,
        "world_size": world_size,
        "code_version": code_version(),
    }


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint written by `Trainer.save_checkpoint`; RunError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"checkpoint {path} does not exist")
    try:
        # weights_only: tensors and plain containers only; a pickle that would run code is refused
        from corelib.readfile import open_file

        with open_file(path, kind="checkpoint", link_ok=True) as f:  # regular, bounded, never a FIFO's read
            ckpt = torch.load(f, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001
        from mcdp.networks import load_error_line  # torch's advice to load it unsafely is left out

        raise RunError(f"checkpoint {path} is unreadable or not a plain weights file: {load_error_line(exc)}") from None
    if not isinstance(ckpt, dict) or ckpt.get("version") != CHECKPOINT_VERSION or "config" not in ckpt:
        raise RunError(f"checkpoint {path} is not an mcdp checkpoint of version {CHECKPOINT_VERSION}")
    check_weights(ckpt, path)
    return ckpt


def non_finite(state) -> tuple[str, int] | None:
    """(name, count) of the first floating-point tensor of the state dict ``state`` that holds a NaN or an
    infinity, None when every one is finite."""
    for name, t in state.items():
        if torch.is_tensor(t) and t.is_floating_point():
            bad = int((~torch.isfinite(t)).sum())
            if bad:
                return str(name), bad
    return None


def load_error_first(exc: Exception) -> str:
    """The first problem of torch's many-line ``load_state_dict`` error, and how many more it lists."""
    lines = [ln.strip() for ln in str(exc).splitlines()[1:] if ln.strip()] or [str(exc).strip()]
    first = lines[0].rstrip(".")
    return first[:300] + (f" (+{len(lines) - 1} more)" if len(lines) > 1 else "")


def check_weights(ckpt: dict, path: Path) -> None:
    """RunError, one line naming the file and the tensor, for a checkpoint whose weights are not finite (a
    diverged run's: evaluated, it scores nothing without a word) or whose ``depth_model`` does not fit the network
    its own config builds (a tensor of another shape; before: a many-line ``size mismatch`` traceback). The fit is
    tried on PyTorch's ``meta`` device: no memory, no copy."""
    for key in ("depth_model", "pose_model"):
        state = ckpt.get(key)
        if state is None and key == "pose_model":
            continue
        if not isinstance(state, dict):
            raise RunError(f"checkpoint {path}: no {key} state (got {type(state).__name__}); not a training checkpoint")
        bad = non_finite(state)
        if bad is not None:
            raise RunError(f"checkpoint {path}: {key}.{bad[0]} holds {bad[1]} non-finite value(s) (NaN or inf): "
                           "the run diverged before it was written; refused (use an earlier checkpoint or retrain)")
    try:
        cfg = config_from_checkpoint(ckpt, source=str(path))
    except Exception:  # noqa: BLE001 - the caller reads the config next and says what is wrong with it
        return
    import warnings

    from mcdp.methods import build_network, method_params

    try:
        with torch.device("meta"):
            net = build_network(cfg.model, method_params(cfg))
    except Exception:  # noqa: BLE001 - a network that cannot be built on meta is checked when it is built
        return
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # "copying ... to a meta parameter is a no-op": the point here
            net.load_state_dict(ckpt["depth_model"])
    except RuntimeError as exc:
        raise RunError(f"checkpoint {path}: depth_model does not fit the {cfg.model.method} network its config "
                       f"builds: {load_error_first(exc)}") from None


def restore_checkpoint(ckpt: dict, depth, pose, optimizer, scaler, source: str = "checkpoint") -> dict:
    """Load a training checkpoint (`checkpoint_record`'s, read by `load_checkpoint`) into the networks, the
    optimiser, the scaler and torch's RNG; the rest of the trainer's state it holds: {"step", "best_val",
    "val_history", "spread", "init_from", "world_size"}. RunError, one line naming ``source`` (the file) and the
    key, for a checkpoint without the state a resume needs (a weights-only one: no ``optimizer``) or with a tensor
    that does not fit."""
    wanted = ["depth_model", "optimizer", "torch_rng", "step"] + (["pose_model"] if pose is not None else [])
    missing = [k for k in wanted if k not in ckpt]
    if missing:
        raise RunError(f"{source}: no {', '.join(missing)} in the checkpoint (a weights-only checkpoint, or not "
                       "written by mcdp train), so training cannot resume from it; move it away to start afresh")
    for key, net in (("depth_model", depth), ("pose_model", pose), ("optimizer", optimizer)):
        if net is None:
            continue
        try:
            net.load_state_dict(ckpt[key])
        except (RuntimeError, ValueError, KeyError, TypeError) as exc:
            raise RunError(f"{source}: its {key} does not fit this run's: {load_error_first(exc)}") from None
    if ckpt.get("scaler"):
        scaler.load_state_dict(ckpt["scaler"])
    torch.set_rng_state(ckpt["torch_rng"])
    return {"step": int(ckpt["step"]), "best_val": float(ckpt.get("best_val", math.inf)),
            "val_history": [tuple(x) for x in ckpt.get("val_history", [])],
            "spread": dict(ckpt.get("depth_spread") or {}), "init_from": ckpt.get("init_from"),
            "world_size": int(ckpt.get("world_size", 1))}


def config_from_checkpoint(ckpt: dict, source: str = "checkpoint") -> RunConfig:
    return build_config(RunConfig, upgrade_config_dict(ckpt["config"]), source=source)


def check_resume(run_dir: Path, cfg: RunConfig) -> dict | None:
    """The checkpoint to resume from (or None for a fresh run); RunError naming conflicting keys."""
    last = Path(run_dir) / "checkpoints" / "last.pt"
    if not last.exists():
        return None
    ckpt = load_checkpoint(last)
    saved = upgrade_config_dict(ckpt["config"])
    requested = config_to_dict(cfg)
    bad = resume_conflicts(saved, requested)
    if bad:

        def get(d, k):
            for p in k.split("."):
                d = d.get(p) if isinstance(d, dict) else None
            return d

        lines = [f"  {k}: checkpoint has {get(saved, k)!r}, requested {get(requested, k)!r}" for k in bad]
        raise RunError(
            f"{last} was trained with a different config; these keys conflict:\n"
            + "\n".join(lines)
            + f"\nuse the run's own settings (see {Path(run_dir) / 'config.yaml'}) or a new --out folder"
        )
    return ckpt


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RunError("train.device=cuda but no CUDA device is available (use train.device=cpu or auto)")
    return torch.device(name)


def resolve_precision(name: str, device: torch.device) -> tuple[bool, torch.dtype]:
    """(autocast on?, its dtype) for ``train.precision`` on `device`; RunError for fp16 on CPU."""
    if name == "auto":
        if device.type != "cuda":
            return False, torch.float32
        return True, torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16
    if name == "fp32":
        return False, torch.float32
    if name == "fp16" and device.type != "cuda":
        raise RunError("train.precision=fp16 needs a CUDA device (a GradScaler); on CPU use bf16 or fp32")
    return True, torch.bfloat16 if name == "bf16" else torch.float16


def find_checkpoint(run_dir: str | Path, which: str = "auto") -> Path:
    """``auto``: best.pt if present else last.pt; ``best`` | ``last``; or a path to a .pt file."""
    run_dir = Path(run_dir)
    if which not in ("auto", "best", "last"):
        p = Path(which)
        if not p.is_file():
            raise RunError(f"checkpoint {p} does not exist")
        return p
    if not run_dir.is_dir():
        raise RunError(f"run folder {run_dir} does not exist (train first: mcdp train PRESET --data DATA --out {run_dir})")
    ck = run_dir / "checkpoints"
    names = {"auto": ["best.pt", "last.pt"], "best": ["best.pt"], "last": ["last.pt"]}[which]
    for n in names:
        if (ck / n).is_file():
            return ck / n
    gone = removed_checkpoints(run_dir)
    for n in names:
        if n in gone:
            r = gone[n]
            raise RunError(f"run folder {run_dir}: its checkpoint checkpoints/{n}"
                           + (f" (step {r['step']})" if isinstance(r.get("step"), int) else "")
                           + f" was removed {str(r.get('reason') or '')[:300]}")
    raise RunError(f"run folder {run_dir} has no checkpoint {' or '.join(names)} in {ck}")


# --------------------------------------------------------------------------- the rig a run was trained on
def rig_differences(run: Path, ds) -> list[str] | None:
    """How the dataset's rig (per camera: size, K, T_ego_cam, lens model and distortion) differs from the one the
    run was trained on (``run.json``'s ``rig``; None for a run written before it was recorded): [] when it is the
    same."""
    try:
        trained = read_json_file(run / "run.json", kind="record").get("rig")
    except (OSError, ValueError, AttributeError):
        return None
    if not isinstance(trained, list):
        return None
    now = {c.name: c for c in ds.cameras}
    diffs = [] if [c.get("name") for c in trained] == list(now) else \
        [f"cameras {[c.get('name') for c in trained]} -> {list(now)}"]
    for c in trained:
        cam = now.get(c.get("name"))
        if cam is None:
            continue
        if (c.get("width"), c.get("height")) != (cam.width, cam.height):
            diffs.append(f"{cam.name} size {c.get('width')}x{c.get('height')} -> {cam.width}x{cam.height}")
        for key, new in (("K", cam.K), ("T_ego_cam", cam.T_ego_cam)):
            old = np.asarray(c.get(key), np.float64)
            if old.shape != new.shape or not np.allclose(old, new, rtol=1e-6, atol=1e-6):
                diffs.append(f"{cam.name} {key}")
        lens = cam.intrinsics  # the lens too (issue 59; a record without one is pinhole): a K alone can agree
        model, dist = c.get("model", "pinhole"), list((c.get("dist") or {}).values())
        if model != lens.model:
            diffs.append(f"{cam.name} lens {model} -> {lens.model}")
        elif len(dist) != len(lens.dist) or not np.allclose(np.asarray(dist, np.float64), lens.dist, rtol=1e-6,
                                                             atol=1e-9):
            diffs.append(f"{cam.name} lens {model} dist")
    return diffs


def write_run_record(run: Path, ds, step: int, oracle: bool, init_from, warn) -> dict:
    """Write ``run.json`` (what `mcdp eval` compares a dataset against: its data, cameras, rig) for a run that
    trains on `ds` from `step`. A run resumed on another dataset than the one it was trained on (or on another
    rig) is said with `warn` in one line, and ``datasets`` keeps every dataset it trained on, in order, with
    the step it started at (``data`` and ``rig`` are the latest's). Returns the record."""
    data = str(Path(ds.root).resolve())
    old = {}
    if step > 0:
        try:
            old = read_json_file(run / "run.json", kind="record")
        except (OSError, ValueError, UnicodeDecodeError):
            old = {}
        old = old if isinstance(old, dict) else {}
    history = old.get("datasets") if isinstance(old.get("datasets"), list) else (
        [{"data": old["data"], "from_step": 0}] if isinstance(old.get("data"), str) else [])
    rig_diff = rig_differences(run, ds) if old else None
    if history and (history[-1].get("data") != data or rig_diff):
        rig = f"; its rig differs: {', '.join(rig_diff[:4])}" if rig_diff else ""
        warn(f"mcdp train: warning: resuming {run} at step {step} on {data}, not on {history[-1].get('data')} "
             f"where it trained before{rig}; run.json records both (datasets)")
    if not history or history[-1].get("data") != data:
        history.append({"data": data, "from_step": step})
    rec = {"data": data, "datasets": history,
           "cameras": list(ds.camera_names), "rig": [c.to_json() for c in ds.cameras],  # mcdp eval compares it
           "neighbours": [list(p) for p in ds.neighbours], "oracle": oracle, "init_from": init_from}
    atomic_write_json(run / "run.json", rec)
    return rec
