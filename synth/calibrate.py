"""An overlap knob in measured pixels: ``rig.overlap_target: pixels`` (docs/results/overlap.md).

``rig.overlap`` is the shared fraction of the horizontal angle by default (``angle``). The measured
pixel overlap (`synth.overlap`, the one definition) is lower: a pinhole image's corners fall outside the
neighbour's vertical field of view, close points are shifted by the baseline between mounts, and the
ego body and occluders hide the rest. With ``pixels``, the geometric overlap of the layout (the yaw
spacing in ``spacing`` mode, the hfov in ``fov`` mode) is solved so that the mean measured pixel overlap
over the pairs at the target, on a calibration sample of the world's own scenes (frame 0 of its first
`SAMPLES` sequences, each camera at its image size, ego body included), equals ``rig.overlap`` within
`TOL` (bisection: the measured overlap grows with the geometric one).

The solution is a function of the config alone (scenes from the seed), kept per process by config
hash, and recorded in the manifest (``overlap.knob``, ``overlap.geometric``, ``overlap.calibration``).

Example::

    cfg = load_data_config("configs/data/tiny.yaml", ["rig.overlap=0.3", "rig.overlap_target=pixels"])
    geometric_rig(cfg).overlap      # e.g. 0.39: the angle overlap that measures 0.30 in pixels
"""
from __future__ import annotations

import numpy as np

SAMPLES = 2  # sequences of the world in the calibration sample (frame 0 of each)
TOL = 0.005  # the bisection stops when the calibration sample measures within this of the target
_SOLVED: dict[str, dict] = {}


def geometric_rig(cfg):
    """The `synth.rig.RigConfig` the cameras are built from: ``cfg.rig`` itself (``angle``), or a copy with
    the solved geometric overlap (``pixels``; not re-validated: it may exceed the knob's 0.60). Every lens row is
    calibrated alike: its images are formed as the render forms them (`synth.lens_image`) and measured in pixels."""
    if cfg.rig.overlap_target == "angle":
        return cfg.rig
    return cfg.rig.model_copy(update={"overlap": calibration(cfg)["geometric"], "overlap_target": "angle"})


def calibration(cfg) -> dict:
    """{"target", "geometric", "measured", "iterations", "samples"} of ``rig.overlap_target: pixels``."""
    from corelib.configlib import config_hash

    key = config_hash(cfg)
    if key not in _SOLVED:
        _SOLVED[key] = _solve(cfg)
    return dict(_SOLVED[key])


def _solve(cfg) -> dict:
    from synth.gl_backend import Renderer

    lo, hi = 0.02, (0.66 if cfg.rig.overlap_mode == "fov" else 0.95)  # fov: hfov = 60 / (1 - o) < 179 deg
    target = float(cfg.rig.overlap)
    with Renderer(cfg.camera.width, cfg.camera.height, backend=cfg.render.backend, znear=cfg.rig.znear_m,
                  zfar=cfg.rig.zfar_m) as r:
        scenes = _sample(cfg)
        best, it = None, 0
        for it in range(1, 25):
            mid = 0.5 * (lo + hi)
            m = measure(cfg, mid, r, scenes)
            if best is None or abs(m - target) < abs(best[1] - target):
                best = (mid, m)
            if abs(m - target) <= TOL:
                break
            lo, hi = (mid, hi) if m < target else (lo, mid)
    if abs(best[1] - target) > 0.02:
        raise ValueError(f"rig.overlap_target=pixels: no layout measures {target:.2f} (closest: geometric "
                         f"{best[0]:.3f} measures {best[1]:.3f}); lower rig.overlap or use overlap_target=angle")
    return {"target": target, "geometric": round(best[0], 6), "measured": best[1], "iterations": it,
            "samples": len(scenes)}


def _sample(cfg) -> list:
    from synth.pipeline import build_sequence_scene

    return [build_sequence_scene(cfg, i) for i in range(min(SAMPLES, cfg.dataset.sequences))]


def measure(cfg, geometric: float, renderer, scenes) -> float:
    """Mean measured pixel overlap over the pairs at the geometric target (both directions, every sample),
    for the layout of geometric overlap `geometric`."""
    from scenes.textures import LAYER
    from synth.gl_backend import LightState
    from synth.lens_image import render_camera
    from synth.overlap import overlap_fraction_counts, pair_overlaps
    from synth.ego_body import ego_body_mesh
    from synth.rig import build_rig

    rig = build_rig(cfg.rig.model_copy(update={"overlap": geometric, "overlap_target": "angle"}), cfg.camera)
    ego = ego_body_mesh(LAYER["car_paint"], LAYER["car_glass"], LAYER["tyre"], cfg.rig.camera_height_m)
    light = LightState((0.3, 0.2, 0.9), (1.0, 1.0, 1.0), (0.5, 0.5, 0.5), (0.3, 0.5, 0.9), (0.8, 0.8, 0.9),
                       shadows=False)
    targets = rig.pair_target_overlap()
    pairs = [(i, j) for i, j in rig.neighbours
             if abs(targets[f"{rig.names[i]}-{rig.names[j]}"] - geometric) < 1e-6]
    tot = {}
    for scene in scenes:
        renderer.load_scene(scene, ego)
        T_we = scene.T_world_ego[0]
        depths, masks = {}, {}
        for c in rig.cameras:
            out = render_camera(renderer, c, T_we @ c.T_ego_cam, 0, light)  # any lens (synth.lens_image)
            depths[c.name] = out["depth"]
            masks[c.name] = np.where(out["ego"], 0, 255).astype(np.uint8)
        for k, v in overlap_fraction_counts(depths, masks, list(rig.cameras), pairs).items():
            t = tot.setdefault(k, [0, 0])
            t[0], t[1] = t[0] + v[0], t[1] + v[1]
    fr = [x for p in pair_overlaps(tot, rig.names, pairs).values() for k, x in p.items()
          if k != "measured" and np.isfinite(x)]  # every direction of every pair at the target
    return float(np.mean(fr)) if fr else 0.0


def overlap_record(cfg, rig, totals: dict) -> dict:
    """The manifest's ``overlap``: the knob (target, mode, ``angle`` | ``pixels``, the geometric overlap the
    layout was built with, its calibration) and, per adjacent pair, its geometric target and measured pixel
    overlap (mean of both directions) from ``totals`` ({"A->B": [valid pixels of A, of those seen by B]},
    summed over every frame of the dataset)."""
    from synth.overlap import pair_overlaps

    targets = rig.pair_target_overlap()
    per_pair = {k: {"target": targets[k], **v} for k, v in pair_overlaps(totals, rig.names, rig.neighbours).items()}
    rec = {"target": cfg.rig.overlap, "mode": cfg.rig.overlap_mode, "knob": cfg.rig.overlap_target,
           "geometric": rig.overlap_target, "yaw_spacing_deg": rig.yaw_spacing_deg,
           "hfov_deg": rig.cameras[0].hfov_deg, "per_pair_measured": per_pair}
    if cfg.rig.overlap_target == "pixels":
        rec["calibration"] = calibration(cfg)
    return rec
