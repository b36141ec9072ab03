"""What the ``mcdp`` commands share: where an output may go, opening a dataset, an empty split refused, and
``--print-config`` (`study.method_commands`, `study.train_command`, `study.cli`)."""
from __future__ import annotations

import argparse
from pathlib import Path


def outside_datasets(out: str | Path, flag: str = "--out") -> None:
    """An output inside a dataset would change it behind its manifest (and `synth verify` would not see it)."""
    from corelib.rundir import FolderError
    from synth.dataset import dataset_containing

    inside = dataset_containing(out)
    if inside is not None:
        raise FolderError(f"{flag} {out} is inside the dataset {inside}; nothing was written: write outside it")


def open_dataset(path: str):
    """The dataset at ``path`` (rendered or a nuScenes dataroot), imported when a command needs it."""
    from synth.open import open_dataset as open_any

    return open_any(path)


def require_split(ds, data: str, split: str) -> list[str]:
    """The sequences of `split`; an empty split is refused in one line (before a model is loaded)."""
    from mcdp.runs import RunError
    from synth.files import DatasetError

    def filled(k: str) -> bool:
        try:
            return bool(ds.split(k))
        except DatasetError:  # a nuScenes dataroot's empty official split
            return False

    seqs = ds.split(split)
    if not seqs:
        has = [k for k in ("train", "val", "test") if k != split and filled(k)]
        raise RunError(f"dataset {data}: split {split!r} has no sequence, nothing to do (render more "
                       f"dataset.sequences, or use --split {' / '.join(has) or '...'})")
    return seqs


def add_print_config(p: argparse.ArgumentParser) -> None:
    p.add_argument("--print-config", action="store_true", help="print the resolved config (YAML, overrides "
                   "applied) on stdout and exit 0; nothing is run or written")


def print_config(cfg) -> int:
    """The resolved config as YAML on stdout (``--print-config``); 0."""
    import yaml

    from corelib.configlib import config_to_dict

    print(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), end="")
    return 0


def require(args: argparse.Namespace, *flags: str) -> None:
    """The flags a command needs unless ``--print-config`` (argparse's own wording, exit 2)."""
    from corelib.configlib import ConfigError

    missing = [f for f in flags if getattr(args, f.lstrip("-").replace("-", "_")) is None]
    if missing:
        raise ConfigError(f"the following arguments are required: {', '.join(missing)}")
