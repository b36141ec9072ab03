"""Lighting changes: per sequence (time of day: sun direction and colour, ambient, sky),
per camera (exposure gain and white balance drawn once per sequence) and per frame
(small flicker of every camera's gain). One surface therefore looks different in
adjacent cameras, which is the paper's reason to avoid a cross-camera photometric loss.

All colours are linear RGB. Everything drawn here is written to ``ego.json``.

Example::

    seq = draw_sequence_lighting(cfg.lighting, camera_names, rng)
    light, gains = frame_lighting(seq, frame_rng)
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from synth.gl_backend import LightState

# elevation range (deg), sun colour, ambient colour, zenith, horizon, base exposure
_PRESETS = {
    "morning": ((15.0, 35.0), (2.3, 1.95, 1.5), (0.36, 0.40, 0.50), (0.22, 0.40, 0.80), (0.80, 0.78, 0.75), 0.95),
    "noon": ((55.0, 75.0), (2.6, 2.5, 2.3), (0.42, 0.47, 0.58), (0.20, 0.40, 0.85), (0.72, 0.80, 0.90), 0.85),
    "afternoon": ((25.0, 45.0), (2.4, 2.15, 1.75), (0.38, 0.42, 0.52), (0.22, 0.42, 0.82), (0.78, 0.80, 0.82), 0.9),
    "dusk": ((3.0, 10.0), (1.5, 0.85, 0.45), (0.22, 0.20, 0.27), (0.12, 0.16, 0.38), (0.85, 0.52, 0.35), 1.6),
    "overcast": ((40.0, 60.0), (0.35, 0.35, 0.37), (0.95, 0.97, 1.0), (0.62, 0.64, 0.68), (0.78, 0.79, 0.80), 0.95),
}


@dataclass(frozen=True)
class SequenceLighting:
    time_of_day: str
    light: LightState
    base_gain: dict[str, tuple[float, float, float]]   # camera -> exposure x white balance
    flicker_sigma: float
    camera_names: tuple[str, ...]

    def to_json(self) -> dict:
        L = self.light
        return {"time_of_day": self.time_of_day, "sun_dir": list(L.sun_dir), "sun_rgb": list(L.sun_rgb),
                "ambient_rgb": list(L.ambient_rgb), "zenith_rgb": list(L.zenith_rgb),
                "horizon_rgb": list(L.horizon_rgb), "shadows": L.shadows,
                "camera_base_gain": {k: list(v) for k, v in self.base_gain.items()}}


def draw_sequence_lighting(cfg, camera_names, rng: np.random.Generator) -> SequenceLighting:
    """Draw the lighting of one sequence from `cfg` (a `LightingConfig`)."""
    tod = str(cfg.times_of_day[int(rng.integers(len(cfg.times_of_day)))])
    (e0, e1), sun, amb, zen, hor, exposure = _PRESETS[tod]
    elev = math.radians(rng.uniform(e0, e1))
    azim = rng.uniform(0.0, 2 * math.pi)
    sun_dir = (math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev))
    k = rng.uniform(0.85, 1.15)
    a = rng.uniform(0.85, 1.15)
    light = LightState(sun_dir=tuple(float(x) for x in sun_dir), sun_rgb=tuple(float(k * c) for c in sun),
                       ambient_rgb=tuple(float(a * c) for c in amb), zenith_rgb=zen, horizon_rgb=hor,
                       shadows=bool(cfg.shadows and tod != "overcast"))
    gains = {}
    for name in camera_names:
        g = exposure * math.exp(rng.normal(0.0, cfg.exposure_sigma))
        wb = np.exp(rng.normal(0.0, cfg.white_balance_sigma, 3))
        wb = wb / wb[1]
        gains[name] = tuple(float(g * w) for w in wb)
    return SequenceLighting(tod, light, gains, float(cfg.flicker_sigma), tuple(camera_names))


def frame_gains(seq: SequenceLighting, rng: np.random.Generator) -> dict[str, tuple[float, float, float]]:
    """Per-camera gain of one frame: the sequence's gain times a small flicker."""
    out = {}
    for name in seq.camera_names:
        f = math.exp(rng.normal(0.0, seq.flicker_sigma)) if seq.flicker_sigma > 0 else 1.0
        out[name] = tuple(float(f * c) for c in seq.base_gain[name])
    return out
