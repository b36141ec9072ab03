"""Pictures of depth: colour-mapped disparity and six-camera grids (for `mcdp predict` and TensorBoard).

Example::

    img = colorize_disparity(1.0 / depth)            # (H, W, 3) uint8, 'magma'
"""
from __future__ import annotations

import numpy as np


def colorize_disparity(disp: np.ndarray, vmax_percentile: float = 95.0) -> np.ndarray:
    """(..., H, W) disparity -> (..., H, W, 3) uint8 'magma' image, normalised per map (Monodepth2 style)."""
    import matplotlib

    cmap = matplotlib.colormaps["magma"]
    d = np.asarray(disp, dtype=np.float64)
    flat = d.reshape(-1, *d.shape[-2:]) if d.ndim > 2 else d[None]
    out = np.empty(flat.shape + (3,), dtype=np.uint8)
    for i, m in enumerate(flat):
        lo, hi = float(m.min()), float(np.percentile(m, vmax_percentile))
        n = np.clip((m - lo) / max(hi - lo, 1e-12), 0, 1)
        out[i] = (cmap(n)[..., :3] * 255).astype(np.uint8)
    return out.reshape(d.shape + (3,))


def depth_grid(rgb: list[np.ndarray], depths: dict[str, list[np.ndarray]]) -> np.ndarray:
    """Rows: RGB, then one colour-mapped disparity row per stage; cameras side by side -> (H', W', 3) uint8.
    Cameras of different sizes: each row is as tall as the tallest, a shorter image padded black below."""
    h = max(a.shape[0] for a in rgb)

    def row(tiles) -> np.ndarray:
        return np.concatenate([np.pad(t, ((0, h - t.shape[0]), (0, 0), (0, 0))) for t in tiles], axis=1)

    rows = [row(rgb)]
    for _, ds in depths.items():
        rows.append(row([colorize_disparity(1.0 / np.maximum(d, 1e-6)) for d in ds]))
    return np.concatenate(rows, axis=0)
