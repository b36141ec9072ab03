"""Contact sheet of one rig sample: 6 cameras x (RGB, coloured depth, mask, overlap with neighbours), and for a
dataset with labels (class map, flow) per camera and a last row, the class legend (`synth.preview_labels`).

Overlap column: the camera's RGB in grey, tinted blue where the previous camera in
ring order sees the pixel, red where the next one does (purple: both).

The sheet carries a PNG text chunk (``Software: mcdp-synth preview``, written and read by Pillow's
`PngImagePlugin`; sheets of earlier versions carry the same chunk): `--out` may name a new file or an
earlier sheet, never a file of anyone else (`check_preview_target`).

Example::

    synth preview data/tiny --out sheet.png
"""
from __future__ import annotations

import io
import warnings
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, PngImagePlugin

from corelib.atomic import atomic_write_bytes
from corelib.rundir import FolderError, check_output_file
from synth.dataset import Dataset, dataset_containing
from synth.overlap import overlaps_by_neighbour
from synth.preview_labels import label_tiles, legend

SOFTWARE = "mcdp-synth preview"  # the value of the sheet's ``Software`` text chunk


def encode_preview(sheet: np.ndarray) -> bytes:
    """uint8 RGB (H, W, 3) -> PNG bytes carrying the ``Software`` text chunk (before the image data)."""
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", SOFTWARE)
    buf = io.BytesIO()
    Image.fromarray(sheet).save(buf, format="PNG", pnginfo=info, compress_level=3)
    return buf.getvalue()


def is_preview(path: Path) -> bool:
    """True for a PNG file that `make_preview` wrote. Pillow reads only the chunks before the image data
    (the pixels are never decoded), so any file, however large or malformed, is answered cheaply."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path, formats=["PNG"]) as im:
                return im.info.get("Software") == SOFTWARE
    except (OSError, SyntaxError, ValueError, Image.DecompressionBombError):  # not a PNG, or a broken one
        return False


def check_preview_target(out: str | Path) -> Path:
    """--out: a new file or an earlier preview sheet, outside any dataset; FolderError naming it otherwise."""
    out = check_output_file(out, is_preview, "preview sheet written by synth preview")
    inside = dataset_containing(out)
    if inside is not None:
        raise FolderError(f"--out {out} is inside the dataset {inside}; nothing was written: write the sheet "
                          "outside it")
    return out


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
    out = check_preview_target(out)  # before the overlap is computed
    seq = seq or ds.sequences[0]
    if seq not in ds.manifest["sequences"]:
        raise ValueError(f"--sequence {seq!r} is not in the dataset (has {', '.join(ds.sequences[:5])}...)")
    if not 0 <= frame < ds.n_frames(seq):
        raise ValueError(f"--frame must be in [0, {ds.n_frames(seq) - 1}], got {frame}")
    names = ds.camera_names
    depths = {n: ds.read_depth(seq, n, frame) for n in names}
    rows = []
    cams = list(ds.cameras)
    dl, Ks, Ts = [depths[c.name] for c in cams], [c.K for c in cams], [c.T_ego_cam for c in cams]
    masks = [ds.mask(c.name) for c in cams]
    for i, cam in enumerate(cams):
        rgb = ds.read_rgb(seq, cam.name, frame)
        mask = masks[i]
        # the ring's previous and next camera (blue / red), whatever order the rig lists its pairs in
        by_prev, by_next = overlaps_by_neighbour(i, dl, Ks, Ts, masks, [(i - 1) % len(names), (i + 1) % len(names)])
        gray = rgb.mean(axis=2, keepdims=True).repeat(3, axis=2)
        ov = gray.copy()
        ov[by_prev] = 0.5 * ov[by_prev] + 0.5 * np.array([40, 90, 255])
        ov[by_next] = 0.5 * ov[by_next] + 0.5 * np.array([255, 60, 40])
        frac = (by_prev | by_next)[mask].mean() if mask.any() else 0.0
        m3 = np.repeat(mask[..., None].astype(np.uint8) * 255, 3, axis=2)
        tiles = [_label(rgb, cam.name), _label(colorize_depth(depths[cam.name]), "depth"),
                 _label(m3, f"mask ({(~mask).mean():.0%} ego)"), _label(ov.astype(np.uint8), f"overlap {frac:.0%}")]
        tiles += [_label(img, text) for img, text in label_tiles(ds, seq, cam.name, frame)]
        rows.append(np.concatenate(tiles, axis=1))
    if "semantic" in ds.label_kinds:
        rows.append(legend(ds.classes, max(r.shape[1] for r in rows)))
    w = max(r.shape[1] for r in rows)  # cameras of different sizes: a narrower row padded black on the right
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, w - r.shape[1]), (0, 0))) for r in rows], axis=0)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, encode_preview(sheet))
    return out
