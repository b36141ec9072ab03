"""Motion blur and rolling shutter (issue 48, item 4): a camera image made of renders at several times.

Both act around a camera's trigger time ``t_c`` (`synth.trigger`; the frame time for a synchronous rig), as a
continuous frame index (`scenes.timeline`: the ego and every mover posed at that time):

* **Motion blur** (``sensor.exposure_ms`` E > 0, ``sensor.subframes`` K >= 2): the shutter is open for E ms
  centred on the row's read time; K sub-frames sample it by the midpoint rule, at offsets
  ``E * ((k + 0.5) / K - 0.5)``, k = 0 .. K-1, and their sRGB images are decoded to linear light, averaged and
  encoded (`average_linear`), before fog and the sensor model (`synth.photometry`). Depth, masks and labels
  are those of the **mid-exposure instant**, rendered once: with odd K the middle sub-frame is that instant
  (its image is one of the K); with even K no sub-frame is, and the mid instant is rendered once more for the
  ground truth alone (K + 1 renders).
* **Rolling shutter** (``sensor.rolling_shutter_ms`` R > 0, in ``sensor.rolling_bands`` B bands): the rows are
  read top to bottom over R ms, centred on ``t_c`` (the middle of the image is read at the trigger time, the
  time ego.json's per-camera pose is for). The image is cut into B bands of rows (band b: rows
  ``b * H // B`` to ``(b + 1) * H // B``), and band b is read at ``t_c + R * ((b + 0.5) / B - 0.5)``: its
  rows of the image, depth and labels all come from a render at that time (blurred around it when E > 0:
  K sub-frames per band, B * K renders). The bands are a separate knob from the sub-frames, so blur and
  rolling shutter combine; the time is per band, not per row, so that each row's ground truth is exactly
  the scene at its band's time (a per-row time would need H renders). The manifest's ``shutter`` records
  this convention and each band's rows and offset.

What "exact" means here: the depth (and labels) of every pixel is exact for the scene at the pixel's own
time, mid-exposure of its band; its colour is the mean over the exposure. Where nothing moves across a pixel
during the exposure, colour and depth describe the same surface. Where the ego or a mover moves an edge
across it, the colour mixes the surfaces seen during the exposure, and the depth describes only the one
seen at mid-exposure. No mask of such mixed pixels is written: it would be another file kind for every
reader and export to carry, and it is derived from what is written: a pixel's blur extent is its image
motion over the exposure, about ``|flow| * E * fps / 1000`` pixels from the forward flow (``labels.flow``);
drop pixels where that exceeds what the use tolerates, or near a depth edge by that many pixels.

Forward flow is refused with rolling shutter (`synth.config.DataConfig`): one image would need one camera
pose per band, which `synth.labels.forward_flow` does not take. The overlap counts of the manifest use each
camera's pose at its trigger time for every row (a rolling-shutter image's bands are offset by at most R/2).

Off (E = 0 and R = 0, the defaults) `Shutter.for_config` is None and `synth.render` renders once, as before.

Example::

    shutter = Shutter.for_config(cfg)                       # None: one render per image
    res = shutter.render(lambda x: r.render(K, pose_at(x), x, light), x, height)
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from synth.sensor import linear_to_srgb8, srgb_to_linear


def subframe_offsets_s(exposure_ms: float, k: int) -> np.ndarray:
    """(k,) seconds of each sub-frame from mid-exposure: the midpoints of k equal slices of the exposure."""
    return exposure_ms / 1000.0 * ((np.arange(k) + 0.5) / k - 0.5)


def band_offsets_s(rolling_ms: float, bands: int) -> np.ndarray:
    """(bands,) seconds of each band's read time from the trigger time, top band first (0 for no rolling)."""
    return rolling_ms / 1000.0 * ((np.arange(bands) + 0.5) / bands - 0.5)


def band_rows(height: int, bands: int) -> list[tuple[int, int]]:
    """Each band's rows [lo, hi) of an image `height` rows tall (bands of equal size to within one row)."""
    return [(b * height // bands, (b + 1) * height // bands) for b in range(bands)]


def average_linear(images: list[np.ndarray]) -> np.ndarray:
    """The mean of uint8 sRGB images in linear light, encoded back to uint8 sRGB (the sensor's own encode)."""
    acc = srgb_to_linear(images[0])
    for img in images[1:]:
        acc += srgb_to_linear(img)
    return linear_to_srgb8(acc / len(images))


class Shutter:
    """A camera's shutter: the render times of one image and how their renders combine (module docstring)."""

    def __init__(self, exposure_ms: float, subframes: int, rolling_ms: float, bands: int, fps: float) -> None:
        self.exposure_ms, self.rolling_ms, self.fps = float(exposure_ms), float(rolling_ms), float(fps)
        self.subframes = int(subframes) if exposure_ms > 0 else 1
        self.bands = int(bands) if rolling_ms > 0 else 1
        self.sub_dx = subframe_offsets_s(self.exposure_ms, self.subframes) * self.fps  # in frame indices
        self.band_dx = band_offsets_s(self.rolling_ms, self.bands) * self.fps

    @staticmethod
    def for_config(cfg) -> "Shutter | None":
        """The shutter of `cfg` (a `synth.config.DataConfig`); None when there is neither blur nor rolling."""
        s = cfg.sensor
        if s.exposure_ms <= 0 and s.rolling_shutter_ms <= 0:
            return None
        return Shutter(s.exposure_ms, s.subframes, s.rolling_shutter_ms, s.rolling_bands, cfg.dataset.fps)

    def renders_per_image(self) -> int:
        """How many renders one image costs: K (+1 for even K) per band."""
        k = self.subframes
        return self.bands * (k + (1 if k > 1 and k % 2 == 0 else 0))

    def render(self, render_at: Callable[[float], dict], x: float, height: int) -> dict:
        """One camera image at trigger index `x`: `render_at(x')` renders the camera with the ego and the
        movers at continuous index x' (a dict of (H, W, ...) arrays, ``rgb`` among them). Returns such a dict:
        ``rgb`` averaged over each band's exposure, every other array that of each band's mid-exposure."""
        out: dict | None = None
        mid_k = (self.subframes - 1) // 2 if self.subframes % 2 else None
        for (lo, hi), db in zip(band_rows(height, self.bands), self.band_dx):
            xb = x + float(db) if db != 0 else x  # the band's mid-exposure time (x itself without rolling)
            mid = render_at(xb)
            if self.subframes > 1:
                rgbs = [mid["rgb"] if k == mid_k else render_at(xb + float(d))["rgb"] for k, d in enumerate(self.sub_dx)]
                mid = dict(mid, rgb=average_linear(rgbs))
            if self.bands == 1:
                return mid
            if out is None:
                out = {k: np.empty_like(v) for k, v in mid.items()}
            for k, v in mid.items():
                out[k][lo:hi] = v[lo:hi]
        return out

    def record(self) -> dict:
        """The manifest's ``shutter``: the exposure and its sub-frames, the read-out and each band's rows (of a
        camera `height` rows tall, as fractions of it) and time offset from the camera's trigger time."""
        return {"exposure_ms": self.exposure_ms, "subframes": self.subframes,
                "subframe_offsets_ms": [float(d / self.fps * 1000.0) for d in self.sub_dx],
                "rolling_shutter_ms": self.rolling_ms, "bands": self.bands,
                "band_offsets_ms": [float(d / self.fps * 1000.0) for d in self.band_dx],
                "convention": "band b of B holds rows floor(b*H/B) .. floor((b+1)*H/B)-1, top first, read at the "
                              "camera's trigger time + band_offsets_ms[b]; its exposure is centred there, sampled "
                              "at + subframe_offsets_ms, averaged in linear light; depth and labels of band b are "
                              "those of its read time"}


def check_shutter_record(rec, mpath) -> None:
    """The manifest's ``shutter``: bounded numbers and lists of the stated lengths; DatasetError naming the key."""
    from synth.files import DatasetError

    def num(v, hi: float) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and abs(v) <= hi

    if not isinstance(rec, dict):
        raise DatasetError(f"{mpath}: shutter must be an object")
    for key, n_key in (("subframe_offsets_ms", "subframes"), ("band_offsets_ms", "bands")):
        n, offs = rec.get(n_key), rec.get(key)
        if not (isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 64):
            raise DatasetError(f"{mpath}: shutter.{n_key} must be an integer in [1, 64], got {str(n)[:40]}")
        if not (isinstance(offs, list) and len(offs) == n and all(num(v, 1000.0) for v in offs)):
            raise DatasetError(f"{mpath}: shutter.{key} must be {n} finite offsets in ms within +-1000")
    for key in ("exposure_ms", "rolling_shutter_ms"):
        if not num(rec.get(key), 1000.0):
            raise DatasetError(f"{mpath}: shutter.{key} must be a finite number of ms within +-1000")
