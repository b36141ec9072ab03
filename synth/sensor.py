"""The camera as a sensor: what happens to an image after the scene has formed it (issue 48, item 2).

The renderer writes sRGB (`synth.shaders.to_srgb`); the sensor model decodes it to linear light, applies
an exposure (a per-camera EV offset, a per-camera spread, optional auto-exposure), white-balance gains,
radial vignetting and Poisson-Gaussian noise, clips to [0, 1] and encodes it back to uint8 sRGB. Depth,
masks and labels never pass through here, so they stay byte-identical to the ideal render.

This is not `synth.lighting`: there the exposure and white balance are part of the *scene's* lighting
(`lighting.exposure_sigma`, `white_balance_sigma`, applied in the shader before the sRGB encode, at full
float precision, and always on); here they are the *sensor's* response to the image once formed: EV steps
on the quantised image, a lens falloff, noise, and an exposure controller, every knob off by default.

Randomness: a camera's drawn values come from ``SeedSequence([seed, sequence index, SENSOR_DRAWS, camera
index])``, its noise at frame f from ``SeedSequence([seed, index, SENSOR_NOISE, camera index, f])``, so a
sequence's pixels are the same whoever renders it and in whatever order.

Example::

    cfg = load_data_config("configs/data/tiny.yaml", ["sensor.exposure_ev=0.5", "sensor.noise=0.01"])
    cams = draw_camera_sensors(cfg.sensor, cfg.seed, 0, rig.names)
    linear = expose(srgb_to_linear(rgb), cams["CAM_FRONT"], ev=cams["CAM_FRONT"].exposure_ev)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import Field, field_validator, model_validator

from corelib.configlib import StrictModel, added_key

SENSOR_DRAWS, SENSOR_NOISE = 0x5E75, 0x5E76  # seed streams of their own (no other draw of a sequence moves)
_LUMA = np.array([0.2126, 0.7152, 0.0722])  # Rec. 709 luminance of linear RGB
MAX_EV = 8.0  # auto-exposure's correction is clamped to +-MAX_EV (a black or a white frame)
MIN_NOISE = 1e-6  # the smallest sensor.noise above 0: the linear signal of one photo-electron
MAX_SHUTTER_MS = 100.0  # an exposure or a rolling read-out longer than this is not a driving camera's
#: the keys of the shutter (`synth.shutter`): they decide which times are rendered, not what the sensor does
#: to a formed image, so `is_identity` does not look at them
SHUTTER_KEYS = ("exposure_ms", "subframes", "rolling_shutter_ms", "rolling_bands")


class SensorConfig(StrictModel):
    """The photometric sensor model (`synth.sensor`), applied to each rendered RGB image before it is written.
    Every knob is off by default: the image is then the renderer's, byte for byte, and the section is not hashed.

    exposure_ev: an exposure offset in EV (a gain of 2**ev in linear light): one number for every camera, or
        one per camera in rig order (``synth.rig.CAMERA_NAMES``).
    exposure_spread_ev: the standard deviation of a per-camera EV offset drawn once per sequence, added.
    auto_exposure_target: null = off; else each camera meters the mean linear luminance of its image and
        steers its exposure so that mean reaches this value (0.18 = mid-grey), on top of the offsets above.
    auto_exposure_tau_s: the controller's time constant (first-order, in seconds of sequence time); frame 0
        starts converged.
    white_balance: linear per-channel gains (R, G, B): one triple for every camera, or one per camera in rig
        order.
    white_balance_spread: the log-normal sigma of per-camera, per-channel gains drawn once per sequence
        (green held at 1, as `synth.lighting` does).
    vignetting: the darkening of the image corner: gain 1 - vignetting * (r / r_corner)**2, r the distance
        from the principal point; 0 = none.
    noise: Poisson-Gaussian noise as a simple gain: the linear signal of one photo-electron (white = 1 / noise
        electrons); shot noise has variance noise * I. 0 = none.
    read_noise_e: read noise in electrons (Gaussian, sigma = read_noise_e * noise in linear units); only with
        ``noise`` > 0.
    jpeg_quality: null = the image is written as PNG (lossless); 1..100 = as JPEG at that quality
        (``<frame>.jpg``, as nuScenes ships its camera images; the manifest's ``rgb`` records it). The last step,
        after the knobs above; it changes the file, not the image the sensor formed. An added key: unset, it is
        not hashed (a sensor section hashed before it existed keeps its hash).
    exposure_ms: motion blur (`synth.shutter`): the shutter is open this long, centred on the camera's time;
        0 = an instant (no blur). Needs ``subframes`` >= 2.
    subframes: K renders spread evenly over the exposure, averaged in linear light (1..16; 1 with no exposure).
    rolling_shutter_ms: rows read out top to bottom over this time, centred on the camera's time; 0 = global.
    rolling_bands: the rolling read-out's bands of rows, each rendered at its own time (2..32; with
        ``subframes`` K, K renders a band).
    """

    exposure_ev: float | list[float] = Field(0.0, description="EV offset, one or one per camera")
    exposure_spread_ev: float = Field(0.0, ge=0.0, le=3.0)
    auto_exposure_target: float | None = Field(None, gt=0.0, lt=1.0)
    auto_exposure_tau_s: float = Field(0.5, ge=0.0, le=60.0)
    white_balance: list[float] | list[list[float]] = Field(default_factory=lambda: [1.0, 1.0, 1.0])
    white_balance_spread: float = Field(0.0, ge=0.0, le=0.5)
    vignetting: float = Field(0.0, ge=0.0, lt=1.0)
    noise: float = Field(0.0, ge=0.0, le=0.5)
    read_noise_e: float = Field(2.0, ge=0.0, le=100.0)
    jpeg_quality: int | None = added_key(None, ge=1, le=100, description="null = PNG; 1..100 = JPEG at that quality")
    # added keys: at their defaults (an instant, a global shutter) every hash and byte is as before
    exposure_ms: float = added_key(0.0, ge=0.0, le=MAX_SHUTTER_MS)
    subframes: int = added_key(1, ge=1, le=16)
    rolling_shutter_ms: float = added_key(0.0, ge=0.0, le=MAX_SHUTTER_MS)
    rolling_bands: int = added_key(8, ge=2, le=32)

    @model_validator(mode="after")
    def _blur(self) -> "SensorConfig":
        if (self.exposure_ms > 0) != (self.subframes > 1):
            raise ValueError(f"motion blur takes both sensor.exposure_ms > 0 and sensor.subframes >= 2 (got "
                             f"exposure_ms={self.exposure_ms:g}, subframes={self.subframes}); set both, or neither")
        return self

    @field_validator("exposure_ev")
    @classmethod
    def _ev(cls, v):
        from synth.rig import CAMERA_NAMES

        vals = v if isinstance(v, list) else [v]
        if isinstance(v, list) and len(v) != len(CAMERA_NAMES):
            raise ValueError(f"a list gives one EV offset per camera, {len(CAMERA_NAMES)} in rig order "
                             f"({', '.join(CAMERA_NAMES)}), got {len(v)}")
        if not all(math.isfinite(x) and abs(x) <= MAX_EV for x in vals):
            raise ValueError(f"EV offsets must be finite and within +-{MAX_EV:g}, got {v}")
        return v

    @field_validator("noise")
    @classmethod
    def _noise(cls, v):
        if 0 < v < MIN_NOISE:  # 1 / noise electrons at white: numpy's Poisson refuses a mean above ~1e18
            raise ValueError(f"0 (no noise) or at least {MIN_NOISE:g} (a million electrons at white; a real sensor "
                             f"holds about 1e4), got {v:g}")
        return v

    @field_validator("white_balance")
    @classmethod
    def _wb(cls, v):
        from synth.rig import CAMERA_NAMES

        triples = v if v and isinstance(v[0], list) else [v]
        if isinstance(v[0] if v else None, list) and len(v) != len(CAMERA_NAMES):
            raise ValueError(f"a list of triples gives one (R, G, B) per camera, {len(CAMERA_NAMES)} in rig order, "
                             f"got {len(v)}")
        if not all(len(t) == 3 and all(math.isfinite(g) and 0.1 <= g <= 10.0 for g in t) for t in triples):
            raise ValueError(f"white balance gains are (R, G, B) triples in [0.1, 10], got {v}")
        return v

    def is_identity(self) -> bool:
        """True when every photometric knob is off: the sensor leaves the formed image's bytes as they are (the
        file format, ``jpeg_quality``, is `synth.pipeline.FrameSink.rgb`'s; the shutter's keys, `SHUTTER_KEYS`,
        choose the times that form it)."""
        default = SensorConfig()
        return self.model_copy(update={"jpeg_quality": None, **{k: getattr(default, k) for k in SHUTTER_KEYS}}) == default


@dataclass(frozen=True)
class CameraSensor:
    """One camera's drawn sensor values for a sequence: its EV offset and linear white-balance gains."""

    exposure_ev: float
    white_balance: tuple[float, float, float]

    def to_json(self) -> dict:
        return {"exposure_ev": self.exposure_ev, "white_balance": list(self.white_balance)}


def draw_camera_sensors(cfg: SensorConfig, seed: int, index: int, names) -> dict[str, CameraSensor]:
    """Each camera's values for sequence `index`: the configured offset / gains times the drawn spread."""
    from synth.rig import CAMERA_NAMES

    out = {}
    for c, name in enumerate(names):
        rng = np.random.default_rng(np.random.SeedSequence([seed, index, SENSOR_DRAWS, c]))
        k = CAMERA_NAMES.index(name) if name in CAMERA_NAMES else c  # a list holds one entry per name
        ev = cfg.exposure_ev[k] if isinstance(cfg.exposure_ev, list) else cfg.exposure_ev
        ev += float(rng.normal(0.0, cfg.exposure_spread_ev)) if cfg.exposure_spread_ev > 0 else 0.0
        wb = np.asarray(cfg.white_balance[k] if isinstance(cfg.white_balance[0], list) else cfg.white_balance)
        if cfg.white_balance_spread > 0:
            d = np.exp(rng.normal(0.0, cfg.white_balance_spread, 3))
            wb = wb * d / d[1]
        out[name] = CameraSensor(float(ev), tuple(float(g) for g in wb))
    return out


def srgb_to_linear(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 sRGB -> float64 linear light in [0, 1] (the inverse of the shader's `to_srgb`)."""
    c = rgb.astype(np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb8(linear: np.ndarray) -> np.ndarray:
    """(H, W, 3) linear light -> uint8 sRGB (clipped to [0, 1], rounded), as the shader encodes."""
    c = np.clip(linear, 0.0, 1.0)
    s = np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1.0 / 2.4) - 0.055)
    return np.rint(s * 255.0).astype(np.uint8)


def metered_ev(linear: np.ndarray, target: float) -> float:
    """The EV that brings the mean linear luminance of `linear` (H, W, 3) to `target`, within +-MAX_EV."""
    mean = float((linear @ _LUMA).mean())
    return float(np.clip(math.log2(target / max(mean, 1e-6)), -MAX_EV, MAX_EV))


def vignetting_gain(K: np.ndarray, width: int, height: int, strength: float) -> np.ndarray:
    """(H, W) gain 1 - strength * (r / r_corner)**2, r the distance of each pixel centre from the principal
    point of `K` (pixels), r_corner that of the farthest image corner: 1 at the centre, 1 - strength there."""
    cx, cy = float(K[0, 2]), float(K[1, 2])
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    r2 = (u - cx) ** 2 + (v - cy) ** 2
    r2_corner = max((x - cx) ** 2 + (y - cy) ** 2 for x in (0.0, width) for y in (0.0, height))
    return 1.0 - strength * r2 / r2_corner


def add_noise(linear: np.ndarray, gain: float, read_noise_e: float, rng: np.random.Generator) -> np.ndarray:
    """Poisson-Gaussian noise on linear light: ``gain * Poisson(I / gain) + Normal(0, gain * read_noise_e)``,
    so mean I and variance ``gain * I + (gain * read_noise_e)**2``; `gain` 0 returns `linear` itself."""
    if gain <= 0:
        return linear
    electrons = rng.poisson(np.maximum(linear, 0.0) / gain).astype(np.float64)
    return gain * (electrons + rng.normal(0.0, read_noise_e, linear.shape))


def sense(linear: np.ndarray, ev: float, cam: CameraSensor, vignette: np.ndarray | None, cfg: SensorConfig,
          noise_rng: np.random.Generator) -> np.ndarray:
    """One image through the sensor, in linear light: exposure 2**ev, white balance, vignetting, noise."""
    out = linear * (2.0 ** ev) * np.asarray(cam.white_balance)
    if vignette is not None:
        out = out * vignette[..., None]
    return add_noise(out, cfg.noise, cfg.read_noise_e, noise_rng)
