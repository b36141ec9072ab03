"""Contact sheet of one rig sample: 6 cameras x (RGB, coloured depth, mask, overlap with neighbours).

Overlap column: the camera's RGB in grey, tinted blue where the previous camera in
ring order sees the pixel, red where the next one does (purple: both).

Example::

    synth preview data/tiny --out sheet.png
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from synth.dataset import Dataset
from synth.files import write_png
from synth.overlap import overlap_mask


def colorize_depth(depth: np.ndarray, max_depth: float = 80.0) -> np.ndarray:
    """(H, W) metres -> (H, W, 3) uint8 (inverse-depth turbo map; black = no surface)."""
    from matplotlib import colormaps

    inv = np.where(depth > 0, 1.0 / np.maximum(depth, 1e-3), 0.0)
    lo = 1.0 / max_depth
    t = np.clip((inv - lo) / (1.0 / 1.0 - lo), 0, 1) ** 0.5
    rgb = (colormaps["turbo"](t)[..., :3] * 255).astype(np.uint8)
    rgb[depth <= 0] = 0
    return rgb


def _label(img: np.ndarray, text: str) -> np.ndarray:
    img = img.copy()
    cv2.putText(img, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return img


def make_preview(ds: Dataset, out: str | Path, seq: str | None = None, frame: int = 0) -> Path:
    seq = seq or ds.sequences[0]
    if seq not in ds.manifest["sequences"]:
        raise ValueError(f"--sequence {seq!r} is not in the dataset (has {', '.join(ds.sequences[:5])}...)")
    if not 0 <= frame < ds.n_frames(seq):
        raise ValueError(f"--frame must be in [0, {ds.n_frames(seq) - 1}], got {frame}")
    names = ds.camera_names
    depths = {n: ds.read_depth(seq, n, frame) for n in names}
    rows = []
    for i, cam in enumerate(ds.cameras):
        rgb = ds.read_rgb(seq, cam.name, frame)
        mask = ds.mask(cam.name)
        prev_c, next_c = ds.cameras[(i - 1) % len(names)], ds.cameras[(i + 1) % len(names)]
        by_prev, by_next = (overlap_mask(depths[cam.name], cam.K, cam.T_ego_cam, depths[o.name], o.K, o.T_ego_cam,
                                         mask_i=mask, mask_j=ds.mask(o.name)) for o in (prev_c, next_c))
        gray = rgb.mean(axis=2, keepdims=True).repeat(3, axis=2)
        ov = gray.copy()
        ov[by_prev] = 0.5 * ov[by_prev] + 0.5 * np.array([40, 90, 255])
        ov[by_next] = 0.5 * ov[by_next] + 0.5 * np.array([255, 60, 40])
        frac = (by_prev | by_next)[mask].mean() if mask.any() else 0.0
        m3 = np.repeat(mask[..., None].astype(np.uint8) * 255, 3, axis=2)
        tiles = [_label(rgb, cam.name), _label(colorize_depth(depths[cam.name]), "depth"),
                 _label(m3, f"mask ({(~mask).mean():.0%} ego)"), _label(ov.astype(np.uint8), f"overlap {frac:.0%}")]
        rows.append(np.concatenate(tiles, axis=1))
    sheet = np.concatenate(rows, axis=0)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_png(out, sheet)
    return out
