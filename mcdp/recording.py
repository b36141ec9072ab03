"""`mcdp predict RUN --data DATA --rrd pred.rrd`: a run's predictions beside the ground truth in a Rerun
recording (the layout of `synth.view`: world mesh (the dataset's; `record_predictions`), trajectory, blueprint
with one tab of depth per stage; plus per stage)::

    world/ego/<CAM>/pred/<stage>/depth     DepthImage, predicted z-depth (m), dataset resolution
    world/ego/<CAM>/pred/<stage>/abs_rel   Image (float32, one channel): |pred - gt| / gt on pixels with
                                           ground truth in [0.5, 80] m outside the ego mask, 0 elsewhere
    world/ego/pred/<stage>/points          Points3D, predicted depth back-projected (ego frame, ego body left
                                           out), coloured by the camera's RGB at that pixel
    sample                                 TextLog: which sequence and frame the time shows

Sequences follow one another on the ``time`` timeline: a sequence starts one frame period after the last
frame of the one before (`sequence_offsets`), so one recording holds every sample of the split. The
metric depth is what the network predicts (no scaling), as in ``mcdp eval``'s ``none`` rows.

Example::

    mcdp predict runs/m2 --data data/tiny --rrd pred.rrd --max-samples 6 && rerun pred.rrd
"""
from __future__ import annotations

import numpy as np

from mcdp.config import EVAL_MAX_DEPTH, EVAL_MIN_DEPTH
from synth.view import RigRecorder, backproject, blueprint_of, import_rerun, recording

GT_RANGE = (EVAL_MIN_DEPTH, EVAL_MAX_DEPTH)  # the evaluator's default ground-truth range (mcdp.config)


def abs_rel_image(pred: np.ndarray, gt: np.ndarray, mask: np.ndarray, lo: float = GT_RANGE[0],
                  hi: float = GT_RANGE[1]) -> np.ndarray:
    """(H, W) float32 |pred - gt| / gt where lo <= gt <= hi and `mask` (scene), 0 elsewhere."""
    valid = (gt >= lo) & (gt <= hi) & np.asarray(mask, bool)
    out = np.zeros(gt.shape, np.float32)
    out[valid] = np.abs(pred[valid] - gt[valid]) / gt[valid]
    return out


def sequence_offsets(ds, samples: list[tuple[str, int]]) -> dict[str, float]:
    """Seconds added to each sequence's timestamps so that the sequences of `samples` follow one another."""
    offsets, t = {}, 0.0
    for seq in dict.fromkeys(s for s, _ in samples):
        offsets[seq] = t
        ego = ds.ego(seq)
        t += float(ego[-1].get("timestamp_s", (len(ego) - 1) / ds.fps)) + 1.0 / ds.fps
    return offsets


def record_predictions(pred, samples: list[tuple[str, int]], out, point_stride: int = 2,
                       progress: bool = False, rebuild=None) -> dict:
    """Write the recording of `samples` ((sequence, frame) pairs) with `pred`'s (`mcdp.predict.Predictor`)
    depth of every stage to `out` (checked by the caller with `synth.view.check_rrd_target`). The world mesh is
    the dataset's (label kind ``mesh``); for a dataset without one, ``rebuild(ds, seq)`` when given (the
    caller's: `synth.gltf_export.rebuilt_world_mesh` rebuilds it from the generator config, which this library
    never reads), else none."""
    from pathlib import Path

    rr = import_rerun()
    ds = pred.ds
    out = Path(out)
    offsets = sequence_offsets(ds, samples)
    items = samples
    if progress:
        from corelib.progress import progress_bar
        items = progress_bar(samples, desc="rrd", unit="sample")
    with recording(out, f"predict_{out.stem}", blueprint_of(ds, samples[0][0], pred.stages)) as rec:
        rec.log("run", rr.TextDocument(f"checkpoint {pred.ckpt_path} (step {pred.step}); stages "
                                       f"{', '.join(pred.stages)}; dataset {ds.root}"), static=True)
        recorders: dict[str, RigRecorder] = {}
        for seq, frame in items:
            if seq not in recorders:
                recorders[seq] = RigRecorder(rr, rec, ds, seq, point_stride, offsets[seq], rebuild=rebuild)
                if len(recorders) == 1:
                    recorders[seq].log_static()
                recorders[seq].log_sequence(ego_body=len(recorders) == 1)
            gt = recorders[seq].log_frame(frame)
            rec.log("sample", rr.TextLog(f"{seq} frame {frame}"))
            depths = pred.predict(seq, frame)
            rgb = recorders[seq].rgb
            Ts = recorders[seq].poses_at(frame)  # each camera's own pose when they fire apart, as the truth's
            for stage, d in depths.items():
                pts, cols = [], []
                for c, cam in enumerate(ds.cameras):
                    base = f"{RigRecorder.cam_path(cam.name)}/pred/{stage}"
                    dc = np.asarray(d[c], np.float32)
                    rec.log(f"{base}/depth", rr.DepthImage(dc, meter=1.0))
                    mask = np.asarray(ds.mask(cam.name), bool)
                    if cam.name in gt:
                        rec.log(f"{base}/abs_rel", rr.Image(abs_rel_image(dc, gt[cam.name], mask), color_model="L"))
                    p, v, u = backproject(dc, cam.intrinsics, Ts[c], mask, point_stride)
                    pts.append(p)
                    cols.append(rgb[cam.name][v, u])
                rec.log(f"world/ego/pred/{stage}/points", rr.Points3D(np.concatenate(pts), colors=np.concatenate(cols),
                                                                      radii=0.05))
    size = out.stat().st_size
    return {"out": str(out), "samples": len(samples), "bytes": size,
            "bytes_per_rig_frame": size / max(len(samples), 1), "sequences": list(offsets)}
