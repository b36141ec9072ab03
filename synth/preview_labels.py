"""The labels of the preview sheet (`synth.preview`): class maps in the class table's colours, forward flow as a
colour image, the class legend (each label kind's tiles: its row's ``show`` in `synth.label_kinds`).

Flow colours: hue = the flow's direction (the HSV wheel, 0 deg = red = to the right, image v down), brightness =
its length relative to the longest valid flow of the tile (the 99th percentile, named in the tile's caption);
black where the flow is invalid (leaves the image or is occluded at t + 1). The sequence's last frame has no
forward flow: its tile shows the mover mask instead (white = a moving object).

Example::

    rgb, scale = colorize_flow(*ds.read_flow(seq, "CAM_FRONT", 0))   # hue = direction, full brightness = scale
"""
from __future__ import annotations

import cv2
import numpy as np


def colorize_classes(sem: np.ndarray, classes: list[dict]) -> np.ndarray:
    """(H, W) class index -> (H, W, 3) uint8 in the class table's colours."""
    palette = np.array([c["color"] for c in classes], np.uint8).reshape(-1, 3)
    return palette[np.minimum(sem, len(palette) - 1)]


def colorize_flow(flow: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, float]:
    """((H, W, 2) flow in pixels, (H, W) valid) -> ((H, W, 3) uint8 RGB, the length shown at full brightness)."""
    u, v = flow[..., 0].astype(np.float32), flow[..., 1].astype(np.float32)
    mag, ang = cv2.cartToPolar(u, v, angleInDegrees=True)
    scale = float(np.percentile(mag[valid], 99)) if valid.any() else 0.0
    scale = max(scale, 1e-3)
    hsv = np.zeros(flow.shape[:2] + (3,), np.uint8)
    hsv[..., 0] = (ang / 2).astype(np.uint8)  # OpenCV hue is 0..179
    hsv[..., 1] = 255
    hsv[..., 2] = (np.clip(mag / scale, 0, 1) * 255).astype(np.uint8)
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    rgb[~valid] = 0
    return rgb, scale


def legend(classes: list[dict], width: int, line_h: int = 18) -> np.ndarray:
    """(h, `width`, 3) uint8: each class's colour swatch and name, wrapped to `width`."""
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, 0.4
    items, x, y = [], 4, 0
    for c in classes:
        w = 14 + cv2.getTextSize(c["name"], font, fs, 1)[0][0] + 12
        if x + w > width and x > 4:
            x, y = 4, y + line_h
        items.append((x, y, c))
        x += w
    img = np.full((y + line_h, width, 3), 32, np.uint8)
    for x, y, c in items:
        cv2.rectangle(img, (x, y + 4), (x + 10, y + 14), tuple(int(k) for k in c["color"]), -1)
        cv2.rectangle(img, (x, y + 4), (x + 10, y + 14), (160, 160, 160), 1)
        cv2.putText(img, c["name"], (x + 14, y + 13), font, fs, (255, 255, 255), 1, cv2.LINE_AA)
    return img
