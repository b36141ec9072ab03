"""A sequence's image formation after the render: fog (`synth.weather`), then the sensor (`synth.sensor`).

The renderer's sRGB image is decoded to linear light once, fogged from the exact depth, exposed, white
balanced, vignetted, made noisy, and encoded back to uint8 sRGB. A lens other than pinhole (`synth.lens_image`)
fogs by the distance along each pixel's own ray (`synth.weather.ray_distance` of its depth kind); vignetting is
a falloff with the radius on the sensor, whatever the lens. When `sensor` and `weather` are at their
defaults `for_sequence` returns None and `synth.render` writes the renderer's bytes untouched.

Example::

    photo = SequencePhotometry.for_sequence(cfg, index, rig, seq_light)   # None: every knob off
    rgb = photo.apply(c, cam, frame, res["rgb"], res["depth"], gains[cam.name]) if photo else res["rgb"]
"""
from __future__ import annotations

import math

import numpy as np

from synth.sensor import (SENSOR_NOISE, draw_camera_sensors, linear_to_srgb8, metered_ev, sense, srgb_to_linear,
                          vignetting_gain)
from synth.weather import apply_fog, draw_fog_density, ray_distance


class SequencePhotometry:
    """The fog and sensor state of one sequence: drawn values per camera and the auto-exposure of each."""

    def __init__(self, cfg, index: int, rig, horizon_rgb) -> None:
        self.cfg, self.index = cfg, index
        self.sensor_on, self.fog_on = not cfg.sensor.is_identity(), not cfg.weather.is_identity()
        self.cams = draw_camera_sensors(cfg.sensor, cfg.seed, index, rig.names)
        self.density = draw_fog_density(cfg.weather, cfg.seed, index)
        self.airlight = tuple(float(c) for c in (cfg.weather.airlight_rgb or horizon_rgb))
        s = cfg.sensor
        self._vignette = {c.name: vignetting_gain(c.K, c.width, c.height, s.vignetting)
                          for c in rig.cameras} if s.vignetting > 0 else {}
        self._ray = {}
        self._ae: dict[str, float] = {}  # camera -> auto-exposure EV now
        self._alpha = 1.0 - math.exp(-1.0 / (cfg.dataset.fps * s.auto_exposure_tau_s)) if s.auto_exposure_tau_s > 0 \
            else 1.0
        self.frame_ev: dict[str, float] = {}  # the last frame's total EV per camera (ego.json)

    @classmethod
    def for_sequence(cls, cfg, index: int, rig, seq_light) -> "SequencePhotometry | None":
        if cfg.sensor.is_identity() and cfg.weather.is_identity():
            return None
        return cls(cfg, index, rig, seq_light.light.horizon_rgb)

    def apply(self, c: int, cam, frame: int, rgb: np.ndarray, depth: np.ndarray, light_gain) -> np.ndarray:
        """Camera `cam` (rig index `c`) at `frame`: (H, W, 3) uint8 sRGB -> (H, W, 3) uint8 sRGB."""
        linear = srgb_to_linear(rgb)
        if self.fog_on:
            ray = self._ray.get(cam.name)
            if ray is None or ray.shape != depth.shape:
                lens = cam.K if cam.model == "pinhole" else cam.intrinsics  # range per unit depth of its kind
                ray = self._ray[cam.name] = ray_distance(np.ones_like(depth), lens)  # |K^-1 p| per pixel (pinhole)
            airlight = np.asarray(self.airlight) * np.asarray(light_gain)
            linear = apply_fog(linear, ray * depth, self.density, airlight)
        if not self.sensor_on:
            return linear_to_srgb8(linear)
        s, sc = self.cfg.sensor, self.cams[cam.name]
        ev = sc.exposure_ev
        if s.auto_exposure_target is not None:
            want = metered_ev(linear, s.auto_exposure_target)
            prev = self._ae.get(cam.name)
            self._ae[cam.name] = want if prev is None else prev + self._alpha * (want - prev)
            ev += self._ae[cam.name]
        self.frame_ev[cam.name] = float(ev)
        rng = np.random.default_rng(np.random.SeedSequence([self.cfg.seed, self.index, SENSOR_NOISE, c, frame]))
        return linear_to_srgb8(sense(linear, ev, sc, self._vignette.get(cam.name), s, rng))

    def frame_record(self) -> dict:
        """What ego.json's frame records (auto-exposure only: the EV each camera used)."""
        if self.sensor_on and self.cfg.sensor.auto_exposure_target is not None:
            return {"sensor": {"exposure_ev": dict(self.frame_ev)}}
        return {}

    def record(self) -> dict:
        """The sequence's drawn values, for its record and the manifest's ``sequences.<seq>``."""
        out = {}
        if self.sensor_on:
            out["sensor"] = {k: v.to_json() for k, v in self.cams.items()}
        if self.fog_on:
            out["weather"] = {"fog_density": self.density, "airlight_rgb": list(self.airlight)}
        return out
