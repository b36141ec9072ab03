"""The one way any command opens a dataset it is handed: `open_dataset`, a factory above both formats.

A folder with a ``manifest.json`` is one this package rendered (`synth.dataset.open_synth`); a nuScenes
dataroot (``v1.0-*`` tables, `synth.nuscenes.tables.is_nuscenes_root`) is read through the devkit
(`synth.nuscenes.read.open_nuscenes`, imported only then). Both return a `synth.protocol.DatasetReader`,
so nothing above this module knows which format it reads. A new format is a reader module plus one
branch here.

Example::

    ds = open_dataset("data/tiny")          # or a nuScenes dataroot
    ds.camera_names, ds.read_depth(ds.sequences[0], ds.camera_names[0], 0)
"""
from __future__ import annotations

from pathlib import Path

from synth.dataset import MANIFEST, open_synth
from synth.files import DatasetError


def open_dataset(path: str | Path, verify: bool = False):
    """The dataset at ``path`` (`synth.dataset.Dataset` or `synth.nuscenes.dataset.NuScenesDataset`), or a
    `DatasetError` naming the folder; ``verify=True`` also checks every file's sha256 (rendered datasets only:
    a nuScenes dataroot has no checksums)."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    if not (root / MANIFEST).is_file():
        from synth.nuscenes.tables import is_nuscenes_root

        if is_nuscenes_root(root):
            if verify:
                raise DatasetError(f"{root}: a nuScenes dataroot has no checksums to verify")
            from synth.nuscenes.read import open_nuscenes  # the devkit loads only when needed

            return open_nuscenes(root)
    ds = open_synth(root)
    if verify:
        from synth.verify import verify_dataset

        problems = verify_dataset(root)
        if problems:
            raise DatasetError("; ".join(problems[:5]) + (f" (+{len(problems) - 5} more)" if len(problems) > 5 else ""))
    return ds
