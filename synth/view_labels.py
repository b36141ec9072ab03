"""The labels of a `synth view` recording (`synth.view.RigRecorder`, for a dataset with labels)::

    world/ego/<CAM>/semantic      SegmentationImage per frame: the class map; the classes' names and colours in
                                  the entity's AnnotationContext (static, from the dataset's class table)
    world/ego/<CAM>/flow          Arrows2D per frame 0 .. F-2: the forward flow t -> t+1 (pixels) at the pixel
                                  centres of a grid (`flow_stride`), valid flow only, each arrow the class of
                                  its pixel (colour and name from the same AnnotationContext); cleared at the
                                  last frame, which has no forward flow

Both sit under the camera's pinhole, so Rerun draws them over the image (the blueprint's "labels" tab).

Example::

    rec.log("world/ego/CAM_FRONT/semantic", class_context(rr, ds.classes), static=True)
"""
from __future__ import annotations

import numpy as np

ARROWS_ACROSS = 24  # about this many flow arrows across an image's width


def class_context(rr, classes: list[dict]):
    """The AnnotationContext of a class table (index, name, color)."""
    return rr.AnnotationContext([rr.AnnotationInfo(id=int(c["index"]), label=str(c["name"]),
                                                   color=tuple(int(k) for k in c["color"])) for c in classes])


def flow_stride(width: int) -> int:
    """Pixels between flow arrows: about `ARROWS_ACROSS` across the width, at least 4."""
    return max(4, int(round(width / ARROWS_ACROSS)))


def flow_arrows(rr, flow: np.ndarray, valid: np.ndarray, sem: np.ndarray | None = None):
    """Arrows2D of the valid forward flow ((H, W, 2) pixels, (H, W) bool) at the centres of every
    `flow_stride`-th pixel (rows and columns from stride // 2), class ids from `sem` ((H, W) classes) if given."""
    H, W = valid.shape
    s = flow_stride(W)
    v, u = np.mgrid[s // 2:H:s, s // 2:W:s]
    ok = valid[v, u]
    v, u = v[ok], u[ok]
    origins = np.stack([u + 0.5, v + 0.5], 1).astype(np.float32)
    return rr.Arrows2D(origins=origins, vectors=flow[v, u].astype(np.float32),
                       class_ids=None if sem is None else sem[v, u].astype(np.uint16))
