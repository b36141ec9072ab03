"""Contact sheet of one rig sample: 6 cameras x (RGB, coloured depth, mask, overlap with neighbours), and for a
dataset with labels (class map, flow) per camera and a last row, the class legend (`synth.preview_labels`).

Overlap column: the camera's RGB in grey, tinted blue where the previous camera in
ring order sees the pixel, red where the next one does (purple: both). Cameras that fire at their own times
(``rig.trigger``): each RGB tile's title gives the camera's offset from the frame time (``+7.1 ms``), and the
overlap warps through each camera's own pose (`camera_poses`).

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
from corelib.readfile import open_file
from corelib.rundir import FolderError, check_output_file
from synth.dataset import Dataset, dataset_containing
from synth.overlap import overlaps_by_neighbour
from synth.label_kinds import preview_tiles
from synth.preview_labels import legend

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
            with open_file(path, kind="hashed", link_ok=True) as fh, Image.open(fh, formats=["PNG"]) as im:
                return im.info.get("Software") == SOFTWARE  # (open_file: never a FIFO's blocking read)
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


#: a tile title's font: its largest and smallest scale (a title too wide at the smallest wraps at its spaces)
TITLE_FONT, TITLE_SCALE, TITLE_MIN_SCALE = cv2.FONT_HERSHEY_SIMPLEX, 0.4, 0.25


def fit_title(text: str, width: int) -> tuple[list[str], float]:
    """The lines and font scale that fit `text` into a tile `width` pixels wide (4 px margins): the largest scale
    down to `TITLE_MIN_SCALE` that fits on one line, else words wrapped at that scale."""
    room = max(width - 8, 1)
    wide = cv2.getTextSize(text, TITLE_FONT, TITLE_SCALE, 1)[0][0]
    scale = max(TITLE_MIN_SCALE, min(TITLE_SCALE, TITLE_SCALE * room / max(wide, 1)))
    lines: list[str] = []
    for word in text.split(" "):
        if lines and cv2.getTextSize(f"{lines[-1]} {word}", TITLE_FONT, scale, 1)[0][0] <= room:
            lines[-1] += f" {word}"
        else:
            lines.append(word)
    return lines, scale


def _label(img: np.ndarray, text: str) -> np.ndarray:
    img = img.copy()
    lines, scale = fit_title(text, img.shape[1])
    step = int(round(30 * scale)) + 2
    for k, line in enumerate(lines):
        y = 4 + step * (k + 1) - 2
        cv2.putText(img, line, (4, y), TITLE_FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(img, line, (4, y), TITLE_FONT, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return img


#: the depths named under the depth colour bar (metres)
BAR_TICKS_M = (1, 2, 5, 10, 20, 40, 80)


def depth_bar(width: int, max_depth: float = 80.0, height: int = 30) -> tuple[np.ndarray, dict[float, int]]:
    """The depth tiles' colour key: (height, `width`, 3) uint8, `colorize_depth`'s colours from far (left,
    `max_depth`) to 1 m (right) with the depths of `BAR_TICKS_M` written under their columns; and {depth: column}."""
    lo = 1.0 / max_depth
    t = np.linspace(0.0, 1.0, width)
    depth = 1.0 / (lo + t ** 2 * (1.0 - lo))  # colorize_depth's t = ((1/d - lo) / (1 - lo)) ** 0.5, inverted
    img = np.full((height, width, 3), 32, np.uint8)
    img[2:12] = colorize_depth(depth[None, :])[0]
    ticks = {}
    for d in BAR_TICKS_M:
        if d <= max_depth:
            x = int(np.argmin(np.abs(depth - d)))
            ticks[d] = x
            img[12:15, x] = 255
            tw = cv2.getTextSize(f"{d}", TITLE_FONT, 0.3, 1)[0][0]
            cv2.putText(img, f"{d}", (min(max(x - tw // 2, 0), width - tw), 24), TITLE_FONT, 0.3, (255, 255, 255), 1,
                        cv2.LINE_AA)
    return img, ticks


def flow_key(size: int = 48) -> np.ndarray:
    """The flow tiles' colour key: (`size`, `size`, 3) uint8, `colorize_flow` of a flow pointing away from the
    centre (hue = direction, e.g. red = to the right; brightness = length, full at the rim)."""
    from synth.preview_labels import colorize_flow

    c = (size - 1) / 2.0
    v, u = np.mgrid[0:size, 0:size].astype(np.float32) - c
    valid = np.hypot(u, v) <= c
    rgb, _ = colorize_flow(np.stack([u, v], axis=-1), valid)
    return rgb


def key_row(width: int, flow: bool) -> np.ndarray:
    """The sheet's last row: the depth colour bar (metres) and, with flow tiles, the flow colour key."""
    key = flow_key() if flow else None
    room = width - (key.shape[1] + 150 if flow else 0)
    bar, _ = depth_bar(max(room - 70, 64))
    row = np.full((max(bar.shape[0], key.shape[0] if flow else 0) + 14, width, 3), 32, np.uint8)
    cv2.putText(row, "depth (m)", (4, 12), TITLE_FONT, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
    bw = max(min(bar.shape[1], width - 66), 0)  # a sheet narrower than the bar: the bar cut at its edge
    row[14:14 + bar.shape[0], 66:66 + bw] = bar[:, :bw]
    if flow:
        x = width - key.shape[1] - 4
        row[14:14 + key.shape[0], x:x + key.shape[1]] = key
        for k, line in enumerate(("flow: hue = direction", "brightness = length", "(full: the tile's px)")):
            cv2.putText(row, line, (x - 146, 24 + 12 * k), TITLE_FONT, 0.3, (255, 255, 255), 1, cv2.LINE_AA)
    return row


def camera_titles(ds: Dataset, seq: str, frame: int) -> tuple[list[str], list[np.ndarray]]:
    """Each camera's RGB title and the pose its overlap warps through: its name and static ``T_ego_cam``; with
    trigger times (the manifest's ``trigger``) its name, its offset from the frame's time in ms and its own pose
    (`Dataset.camera_poses`)."""
    cams = list(ds.cameras)
    if "trigger" not in ds.manifest:
        return [c.name for c in cams], [c.T_ego_cam for c in cams]
    ts, T = ds.camera_poses(seq)
    t0 = float(ds.ego(seq)[frame]["timestamp_s"])
    return [f"{c.name} {(ts[frame, i] - t0) * 1000:+.1f} ms" for i, c in enumerate(cams)], list(T[frame])


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
    titles, Ts = camera_titles(ds, seq, frame)
    dl, Ks = [depths[c.name] for c in cams], [c.intrinsics for c in cams]  # any lens row (synth.overlap)
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
        tiles = [_label(rgb, titles[i]), _label(colorize_depth(depths[cam.name]), "depth"),
                 _label(m3, f"mask ({(~mask).mean():.0%} ego)"), _label(ov.astype(np.uint8), f"overlap {frac:.0%}")]
        tiles += [_label(img, text) for img, text in preview_tiles(ds, seq, cam.name, frame)]
        rows.append(np.concatenate(tiles, axis=1))
    if "semantic" in ds.label_kinds:
        rows.append(legend(ds.classes, max(r.shape[1] for r in rows)))
    rows.append(key_row(max(r.shape[1] for r in rows), "flow" in ds.label_kinds))
    w = max(r.shape[1] for r in rows)  # cameras of different sizes: a narrower row padded black on the right
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, w - r.shape[1]), (0, 0))) for r in rows], axis=0)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out, encode_preview(sheet))
    return out
