"""The sweep's checkpoint clean-up (``keep_last`` / ``keep_best`` false, the pretraining's trim): it deletes only
the files the run recorded writing (`mcdp.checkpoint_files`), records each removal, and says so in one line.
Every file it deletes or writes (the removal record, the run's status) is reached from ``root``, the sweep's
folder, without following a link (`corelib.nolinks`): a run folder that is, or lies under, a link to a folder
outside the sweep (another sweep's run, linked in to reuse it) is left as it is, and the kept line names the link.
"""
from __future__ import annotations

from pathlib import Path

from study.sweep.config import SweepConfig
from study.sweep.records import write_json

LAST_REASON = ("by the sweep's keep_last: false once the run's best.pt was evaluated (so the run cannot be "
               "resumed; its numbers are in metrics_test.json)")
BEST_REASON = ("by the sweep's keep_best: false once the run's evaluation of checkpoints/{evaluated} was recorded "
               "(metrics_test.json); rerun the sweep with keep_best: true into a new --out to keep it")
PRETRAIN_REASON = ("by the sweep's {key}: false once the pretraining was finished (the runs start from its "
                   "pretrained.pt, kept)")


def removed_line(removed: list[tuple[str, int, str]]) -> str:
    """The one log line of what a run's (or the pretraining's) clean-up removed."""
    return "removed " + ", ".join(f"checkpoints/{name} ({n / 1e6:.0f} MB, {key}: false)" for name, n, key in removed)


def _unlink_recorded(run_dir: Path, files: dict[str, dict], key: str | dict,
                     sizes: dict[str, int], root: Path | None) -> list[tuple[str, int, str]]:
    """Record ``files`` ({name: {"step", "reason"}}, each checked by `mcdp.checkpoint_files.removable`: ``sizes``)
    in RUN/checkpoints/removed.json (appended), then delete them; [(name, bytes, the keep_* key that removed it)]."""
    from mcdp.checkpoint_files import record_removed, unlink_checkpoints

    record_removed(run_dir, files, sizes, root=root)  # first: then the files go
    unlink_checkpoints(run_dir, files, root=root)
    return [(n, sizes[n], key if isinstance(key, str) else key[n]) for n in files]


def _removable(run_dir: Path, names, log, tag: str, root: Path | None) -> dict[str, int]:
    """{name: bytes} of the checkpoints ``names`` the run wrote itself (`mcdp.checkpoint_files.removable`);
    one log line names each file that is kept (a user's file under that name, a link, an unreadable record)."""
    from mcdp.checkpoint_files import kept_line, removable

    ok, kept = removable(run_dir, names, root=root)
    if kept:
        log(f"{tag}: {kept_line(kept)}")
    return ok


def remove_last(run_dir: Path, status: dict, status_path: Path, log, tag: str, root: Path | None = None
                 ) -> tuple[dict, list[tuple[str, int, str]]]:
    """keep_last=false: delete last.pt of a trained run whose evaluated checkpoint is best.pt; (status, removed).
    ``root``: the sweep's folder, from which nothing is followed through a link (module docstring)."""
    # by name: the recorded path is where the run was evaluated, which a moved sweep folder no longer is
    # (the sweep evaluates only checkpoints/best.pt or last.pt of the run's own folder)
    evaluated = Path(status.get("checkpoint") or "")
    if not (status.get("trained") and evaluated.name == "best.pt"):
        return status, []
    ok = _removable(run_dir, ["last.pt", "best.pt"], log, tag, root)  # best.pt: the run's own, evaluated
    if "last.pt" in ok and "best.pt" in ok:
        status = {**status, "last_removed": True}
        write_json(status_path, status, root=root)  # first: an interruption between the two leaves a last.pt
        return status, _unlink_recorded(run_dir, {"last.pt": {"step": status.get("steps"), "reason": LAST_REASON}},
                                        "keep_last", ok, root)
    return status, []


def remove_best(run_dir: Path, status: dict, status_path: Path, key: str, log, tag: str, root: Path | None = None
                 ) -> tuple[dict, list[tuple[str, int, str]]]:
    """keep_best=false: delete every checkpoint the run wrote and still has once its evaluation of this key is
    recorded (the evaluated one is recorded in its status as ``checkpoint`` / ``checkpoint_step``); (status, removed)."""
    if not (status.get("trained") and status.get("eval_key") == key):
        return status, []
    ok = _removable(run_dir, ["best.pt", "last.pt"], log, tag, root)
    if not ok:
        return status, []
    evaluated = Path(status.get("checkpoint") or "").name
    reason = BEST_REASON.format(evaluated=evaluated)
    files = {n: {"step": status.get("checkpoint_step") if n == evaluated else
                 (status.get("steps") if n == "last.pt" else None), "reason": reason} for n in ok}
    status = {**status, "best_removed": True, **({"last_removed": True} if "last.pt" in ok else {})}
    write_json(status_path, status, root=root)  # first, as in remove_last
    return status, _unlink_recorded(run_dir, files, "keep_best", ok, root)


def trim_pretraining(cfg: SweepConfig, run_dir: Path, step: int, log, root: Path | None = None) -> None:
    """keep_last / keep_best: false: delete the finished pretraining's last.pt / best.pt (never read again:
    the runs start from its pretrained.pt) that it wrote itself, recorded in its run/checkpoints/removed.json."""
    keys = {n: k for n, k, keep in (("last.pt", "keep_last", cfg.keep_last), ("best.pt", "keep_best", cfg.keep_best))
            if not keep}
    ok = _removable(run_dir, list(keys), log, "[sweep] pretraining", root) if keys else {}
    if ok:
        removed = _unlink_recorded(run_dir, {n: {"step": step if n == "last.pt" else None,
                                                 "reason": PRETRAIN_REASON.format(key=keys[n])} for n in ok},
                                   keys, ok, root)
        log(f"[sweep] pretraining: {removed_line(removed)}; the runs start from {run_dir.parent / 'pretrained.pt'}, "
            "kept")
