"""The one definition of camera overlap, used by the manifest, the evaluator's overlap / non-overlap
split, the preview, the sweep report and `benchmarks/overlap_table.py`.

A valid pixel of camera i (ground-truth depth > 0, not ego body in i) *overlaps* neighbour j when
its ground-truth 3-D point

1. lies in front of j (z_j > `EPS_Z`; for a lens, where j's camera-table row images it: `synth.camera.project`),
2. projects inside j's image (0 <= u < W_j, 0 <= v < H_j; pixel centres at +0.5),
3. lands on a pixel that j's self-occlusion mask marks as scene, and
4. passes a z-test against j's ground-truth depth: z_j <= (1 + `Z_TOL`) * max(depth_j over the
   3x3 pixels around the landing pixel), z_j and depth_j of j's depth kind (z-depth; the point's
   range |p_j| against the range map of a ``range`` camera, e.g. kannala_brandt). The 3x3 maximum keeps slanted surfaces (the road far
   ahead changes depth by metres per pixel row at 96x64) and silhouette edges from failing by
   quantisation; a point hidden behind a nearer object in j fails. Sky (depth 0) never passes.

It is a property of the rig and the scene, never of a model.

Cameras: wherever a function takes a camera's ``K`` it takes a `synth.camera.Intrinsics` as well (a bare K is
the pinhole row), so every lens row is measured alike; a depth map is of its camera's depth kind.

The summaries every caller shares are here too, so each is written once: who is camera i's neighbour
(`neighbours_of`), the union over them (`overlap_union`, the evaluator's overlap region; per neighbour:
`overlaps_by_neighbour`), a pair's measured overlap from pixel counts (`pair_overlaps`: each direction and
their mean) and the mean over the pairs at a target (`target_pair_mean`).

Example::

    ov = overlap_mask(gt_i, K_i, T_i, gt_j, K_j, T_j, mask_i=m_i, mask_j=m_j)   # (H_i, W_i) bool
    nb = neighbours_of(ds.neighbours, len(ds.cameras))                       # [[1, 5], [0, 2], ...]
    ov = overlap_union(i, gts, Ks, Ts, masks, nb[i])                          # seen by any neighbour
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from synth import camera

EPS_Z = camera.EPS_Z  # 1e-6 m
Z_TOL = 0.05


def _arr(x, name: str, shape: tuple | None = None, dtype=np.float64) -> np.ndarray:
    a = np.asarray(x, dtype=dtype)
    if shape is not None and a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def overlap_mask(depth_i, K_i, T_ego_cam_i, depth_j, K_j, T_ego_cam_j, mask_i=None, mask_j=None,
                 z_tol: float = Z_TOL) -> np.ndarray:
    """Pixels of camera i that camera j sees (module docstring).

    Args:
        depth_i: (H_i, W_i) ground-truth depth of camera i (m, its depth kind), 0 = no surface.
        K_i: camera i at (H_i, W_i): a (3, 3) pinhole K or a `synth.camera.Intrinsics` (any lens row);
            T_ego_cam_i: (4, 4) camera i -> ego.
        depth_j: (H_j, W_j) ground-truth depth of camera j (m, its depth kind), 0 = no surface.
        K_j, T_ego_cam_j: the same for camera j at (H_j, W_j).
        mask_i, mask_j: optional (H, W) bool scene masks (True = scene, False = ego body).
        z_tol: relative z-test tolerance.

    Returns:
        (H_i, W_i) bool.
    """
    gi = _arr(depth_i, "depth_i")
    gj = _arr(depth_j, "depth_j")
    if gi.ndim != 2 or gj.ndim != 2:
        raise ValueError(f"depth_i and depth_j must have shape (H, W), got {gi.shape} and {gj.shape}")
    Ki, Kj = _cam(K_i, "K_i"), _cam(K_j, "K_j")
    Ti, Tj = _arr(T_ego_cam_i, "T_ego_cam_i", (4, 4)), _arr(T_ego_cam_j, "T_ego_cam_j", (4, 4))
    H, W = gi.shape
    valid = gi > 0
    if mask_i is not None:
        valid &= _arr(mask_i, "mask_i", (H, W), bool)
    mj = None if mask_j is None else _arr(mask_j, "mask_j", gj.shape, bool)
    v, u, pts = _points(gi, Ki, valid)
    seen = _seen_by_j(pts, np.linalg.inv(Tj) @ Ti, Kj, _near(gj), mj, z_tol)
    out = np.zeros((H, W), bool)
    out[v[seen], u[seen]] = True
    return out


def _cam(x, name: str):
    """A camera argument: a `synth.camera.Intrinsics` of another row as it is; a pinhole one or a bare K as the
    (3, 3) float64 K (the pinhole path, its arithmetic and cache keys as before lenses)."""
    if isinstance(x, camera.Intrinsics):
        return x if x.model != "pinhole" else np.array(x.K)
    return _arr(x, name, (3, 3))


def _lens_of(cam):
    """The camera of a `synth.rig.CameraSpec` / `synth.protocol.Camera` (its ``intrinsics``; a bare ``K``)."""
    return _cam(getattr(cam, "intrinsics", None) or cam.K, "K")


def _depth_of(cam, p: np.ndarray) -> np.ndarray:
    """(N,) depth of (3, N) camera-frame points in the camera's depth kind: z, or |p| for ``range``."""
    return p[2] if camera.depth_kind(cam) == "z_depth" else np.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])


def _points(depth: np.ndarray, K, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel rows, columns and camera-frame 3-D points (3, N) of the `valid` pixels of a float64 depth map."""
    H, W = depth.shape
    if isinstance(K, camera.Intrinsics):  # a pixel without a ray (NaN) has no point
        valid = valid & np.isfinite(_rays(K, H, W)).all(0).reshape(H, W)
    v, u = np.nonzero(valid)
    return v, u, _points_at(K, H, W, v * W + u, depth.ravel())


def _points_at(K, H: int, W: int, flat: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(3, N) camera-frame points of the pixels at row-major indices `flat` of an (H, W) camera with
    intrinsics K, at the depths z[flat] (z: the flattened depth map)."""
    return _rays(K, H, W)[:, flat] * z[flat]


def _apply3(M: np.ndarray, p: np.ndarray, t: np.ndarray | None = None) -> np.ndarray:
    """M @ p (+ t) for (3, N) points, element by element: ((M0 x + M1 y) + M2 z) + t. Each point's result
    is then the same whichever other points share the batch (a BLAS product can round a column differently
    with the number of columns), so counting on a subset gives the counts of the whole."""
    out = M[:, 0:1] * p[0] + M[:, 1:2] * p[1]
    out += M[:, 2:3] * p[2]
    if t is not None:
        out += t[:, None]
    return out


def _near(depth: np.ndarray) -> np.ndarray:
    """Maximum of `depth` over each pixel's 3x3 neighbourhood, 0 outside the image (no surface): the
    maximum over 3 rows of the maximum over 3 columns (the same values as 8 shifted maxima, in half the
    passes)."""
    H, W = depth.shape
    pad = np.pad(depth, 1, mode="constant")
    rows = np.maximum(pad[:, :W], pad[:, 1:W + 1])
    np.maximum(rows, pad[:, 2:W + 2], out=rows)                    # (H + 2, W): max over 3 columns
    near = np.maximum(rows[:H], rows[1:H + 1])
    np.maximum(near, rows[2:H + 2], out=near)
    return near


def _seen_by_j(pts: np.ndarray, T_j_i: np.ndarray, K_j: np.ndarray, near_j: np.ndarray, mask_j, z_tol: float):
    """Indices into `pts` (camera i's points) that camera j sees: in front, inside, on scene, z-test."""
    Hj, Wj = near_j.shape
    pj = _apply3(T_j_i[:3, :3], pts, T_j_i[:3, 3])
    zj = _depth_of(K_j, pj)  # j's depth kind: z (pinhole, radtan) or range
    (uj, vj), front = camera.project(K_j, pj)  # the camera table: front = z_j > EPS_Z, or where the lens images
    idx = np.flatnonzero(front & (uj >= 0) & (uj < Wj) & (vj >= 0) & (vj < Hj))
    col = np.clip(np.floor(uj[idx]).astype(np.int64), 0, Wj - 1)
    row = np.clip(np.floor(vj[idx]).astype(np.int64), 0, Hj - 1)
    keep = np.ones(idx.size, bool) if mask_j is None else mask_j[row, col]
    near = near_j[row, col]
    keep &= (near > 0) & (zj[idx] <= (1.0 + z_tol) * near)
    return idx[keep]


#: pixels of margin around camera j's image within which `_candidates` keeps a ray (only for safety: the
#: exact tests run afterwards on every kept point, so a wider margin costs time, never a count)
CANDIDATE_MARGIN_PX = 4.0
_CACHE: dict[tuple, np.ndarray] = {}  # per-rig constants (rays, candidate indices), keyed by the cameras' bytes
_CACHE_MAX = 256
_CACHE_RAYS_MAX_PX = 2 ** 21  # 48 MB of rays a camera at most


def _cached(key: tuple, make) -> np.ndarray:
    out = _CACHE.get(key)
    if out is None:
        if len(_CACHE) >= _CACHE_MAX:
            _CACHE.clear()
        out = make()
        out.flags.writeable = False  # shared by the writer threads
        _CACHE[key] = out
    return out


def _lens_key(cam) -> tuple:
    """() for a pinhole camera (its keys as before lenses), else (row name, distortion parameters)."""
    return () if not isinstance(cam, camera.Intrinsics) else (cam.model, cam.dist)


def _cam_key(cam) -> tuple:
    lens = _lens_of(cam)
    return (int(cam.width), int(cam.height), _arr(cam.K, "K", (3, 3)).tobytes(),
            _arr(cam.T_ego_cam, "T_ego_cam", (4, 4)).tobytes()) + _lens_key(lens)


def _rays(K, H: int, W: int) -> np.ndarray:
    """(3, H*W) camera-frame rays through the pixel centres, for every pixel (row-major), cached per (camera,
    H, W): K^-1 [u+.5, v+.5, 1] at z = 1 for a pinhole K; the camera table's rays of an `Intrinsics` (z = 1 or
    unit by its depth kind, NaN where a pixel has no ray)."""
    K = _cam(K, "K")
    Kb = (K.K if isinstance(K, camera.Intrinsics) else K).tobytes()

    def make():
        return camera.rays(K, H, W)  # the camera table
    if H * W > _CACHE_RAYS_MAX_PX:  # 24 bytes a pixel: kept for small images only, remade for large ones
        return make()
    return _cached(("rays", int(H), int(W), Kb) + _lens_key(K), make)


def _candidates(cam_i, cam_j) -> np.ndarray:
    """Sorted flat (row-major) indices of the pixels of camera i whose ray, at some depth > 0, enters
    camera j's view cone widened by `CANDIDATE_MARGIN_PX`. A point of any other pixel fails `_seen_by_j`'s
    in-front or inside-the-image test at every depth, so leaving those pixels out changes no count.

    The ray p(t) = a + t b (t = depth in camera i, in camera j's frame) meets each of the cone's five
    half-spaces n . p >= 0 (z_j = p_2 >= 0; -m <= u_j <= W_j + m; -m <= v_j <= H_j + m, as u_j z_j = (K_j p)_0)
    on an interval of t; the pixel is a candidate when the intervals meet for some t > 0. The cone is pinhole
    maths: where either camera has another lens, every pixel is a candidate (the exact tests decide)."""
    if isinstance(_lens_of(cam_i), camera.Intrinsics) or isinstance(_lens_of(cam_j), camera.Intrinsics):
        return _cached(("all", int(cam_i.height) * int(cam_i.width)),
                       lambda: np.arange(int(cam_i.height) * int(cam_i.width)))

    def make():
        Ti, Tj = _arr(cam_i.T_ego_cam, "T", (4, 4)), _arr(cam_j.T_ego_cam, "T", (4, 4))
        T_j_i = np.linalg.inv(Tj) @ Ti
        a = T_j_i[:3, 3]
        b = T_j_i[:3, :3] @ _rays(cam_i.K, int(cam_i.height), int(cam_i.width))  # (3, P)
        K, m, e3 = _arr(cam_j.K, "K", (3, 3)), CANDIDATE_MARGIN_PX, np.array([0.0, 0.0, 1.0])
        Wj, Hj = float(cam_j.width), float(cam_j.height)
        # z_j = p_2 and u_j z_j = (K_j p)_0 (as in `_seen_by_j`): the faces z_j >= 0, u_j >= -m, u_j <= W_j + m, ...
        normals = np.stack([e3, K[0] + m * e3, (Wj + m) * e3 - K[0], K[1] + m * e3, (Hj + m) * e3 - K[1]])
        na, nb = normals @ a, normals @ b                               # (5,), (5, P)
        lo = np.zeros(nb.shape[1])
        hi = np.full(nb.shape[1], np.inf)
        ok = np.ones(nb.shape[1], bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -na[:, None] / nb
        for k in range(5):
            pos, neg = nb[k] > 0, nb[k] < 0
            lo = np.where(pos, np.maximum(lo, t[k]), lo)
            hi = np.where(neg, np.minimum(hi, t[k]), hi)
            ok &= (nb[k] != 0) | (na[k] >= 0)
        return np.flatnonzero(ok & (lo <= hi * (1 + 1e-9) + 1e-9))
    return _cached(("cand", CANDIDATE_MARGIN_PX, _cam_key(cam_i), _cam_key(cam_j)), make)


def overlap_fraction_counts(depths: dict, masks: dict, cameras: list, neighbours,
                            z_tol: float = Z_TOL) -> dict[str, list[int]]:
    """For each ordered adjacent pair i->j: [valid pixels of i, of those overlapping j] (one rig frame).

    `depths` and `masks` are keyed by camera name; `cameras` are `synth.rig.CameraSpec`s. The same
    numbers as `overlap_mask` pair by pair, computed with less work: each camera's points (from rays
    cached per rig) and 3x3 depth maximum once per frame, not once per pair and direction, and for each
    pair only the points whose ray can reach the other camera's image at all (`_candidates`)."""
    prep = {}
    for c in {k for pair in neighbours for k in pair}:
        cam = cameras[c]
        m = np.asarray(masks[cam.name]) > 127
        g32 = np.asarray(depths[cam.name])
        g = _arr(g32, "depth")
        if g.shape != (int(cam.height), int(cam.width)) or m.shape != g.shape:
            raise ValueError(f"camera {cam.name}: depth {g.shape} and mask {m.shape} must be "
                             f"({cam.height}, {cam.width})")
        valid = ((g > 0) & m).ravel()
        near = _near(g32).astype(np.float64) if g32.dtype == np.float32 else _near(g)  # max commutes with the cast
        prep[c] = (valid, int(np.count_nonzero(valid)), g.ravel(), near, m, _arr(cam.T_ego_cam, "T_ego_cam", (4, 4)))
    out = {}
    for a, b in neighbours:
        for i, j in ((a, b), (b, a)):
            (valid, n_valid, z, _, _, Ti), (_, _, _, near_j, mj, Tj) = prep[i], prep[j]
            ci, cj = cameras[i], cameras[j]
            cand = _candidates(ci, cj)
            li, lj = _lens_of(ci), _lens_of(cj)
            keep = cand[valid[cand]]
            if isinstance(li, camera.Intrinsics):  # a pixel without a ray has no point
                keep = keep[np.isfinite(_rays(li, int(ci.height), int(ci.width))[0, keep])]
            pts = _points_at(li, int(ci.height), int(ci.width), keep, z)
            seen = _seen_by_j(pts, np.linalg.inv(Tj) @ Ti, lj, near_j, mj, z_tol)
            out[f"{ci.name}->{cj.name}"] = [n_valid, int(seen.size)]
    return out


def neighbours_of(neighbours, n_cameras: int) -> list[list[int]]:
    """For each camera, the cameras it forms an adjacent pair with (either order), in the pairs' order."""
    out: list[list[int]] = [[] for _ in range(int(n_cameras))]
    for a, b in neighbours:
        a, b = int(a), int(b)
        if b not in out[a]:
            out[a].append(b)
        if a not in out[b]:
            out[b].append(a)
    return out


def overlaps_by_neighbour(i: int, depths, Ks, Ts, masks, nbrs) -> list[np.ndarray]:
    """Camera ``i``'s overlap with each camera of ``nbrs`` (`overlap_mask`), in that order: (H_i, W_i) bool
    each. ``depths`` (each of its camera's depth kind), ``Ks`` ((3, 3) pinhole K or `synth.camera.Intrinsics`, any
    lens row), ``Ts`` (T_ego_cam) and ``masks`` (self-occlusion, True / > 127 = scene; or None) are indexed by
    camera."""
    def m(k):
        return None if masks is None else masks[k]

    return [overlap_mask(depths[i], Ks[i], Ts[i], depths[j], Ks[j], Ts[j], mask_i=m(i), mask_j=m(j)) for j in nbrs]


def overlap_union(i: int, depths, Ks, Ts, masks, nbrs) -> np.ndarray:
    """(H_i, W_i) bool: the pixels of camera ``i`` seen by at least one camera of ``nbrs`` (its overlap region;
    all False without neighbours). Arguments as `overlaps_by_neighbour`: ``Ks`` may be a list of
    `synth.camera.Intrinsics` (every lens row; depths of each camera's depth kind)."""
    ov = np.zeros(np.shape(depths[i]), bool)
    for o in overlaps_by_neighbour(i, depths, Ks, Ts, masks, nbrs):
        ov |= o
    return ov


def pair_overlaps(totals: dict, names, neighbours) -> dict[str, dict[str, float]]:
    """Per adjacent pair "A-B": the measured pixel overlap of each direction ("A->B": the fraction of A's
    valid pixels that B sees) and their mean ("measured"), from ``totals`` ({"A->B": [valid pixels of A, of
    those seen by B]}, e.g. summed `overlap_fraction_counts`); NaN for a direction without valid pixels."""
    out = {}
    for i, j in neighbours:
        a, b = names[i], names[j]
        fwd, bwd = totals.get(f"{a}->{b}", [0, 0]), totals.get(f"{b}->{a}", [0, 0])
        m_ab = fwd[1] / fwd[0] if fwd[0] else float("nan")
        m_ba = bwd[1] / bwd[0] if bwd[0] else float("nan")
        out[f"{a}-{b}"] = {"measured": (m_ab + m_ba) / 2, f"{a}->{b}": m_ab, f"{b}->{a}": m_ba}
    return out


def target_pair_mean(per_pair: dict, target: float, tol: float = 1e-3) -> tuple[float, int]:
    """(mean measured overlap, number of pairs) over the pairs of ``per_pair`` ({"A-B": {"target", "measured"}})
    whose geometric target is ``target`` within ``tol``; (NaN, 0) when none is. In ``spacing`` mode the ring
    does not close, so the pairs that take up the remaining angle have another target and are left out."""
    def fin(x) -> bool:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)

    same = [float(v["measured"]) for v in per_pair.values()
            if fin(target) and fin(v.get("target")) and abs(v["target"] - target) < tol and fin(v.get("measured"))]
    return (float(np.mean(same)) if same else float("nan")), len(same)


@dataclass(frozen=True)
class OverlapKnob:
    """What a dataset's overlap knob meant (its manifest's ``overlap`` record, `synth.calibrate.overlap_record`):
    ``knob`` ``angle`` (``target`` is the shared fraction of the hfov, the pairs' geometric target) or ``pixels``
    (``target`` is a pixel overlap, met by a calibrated layout whose geometric overlap is ``geometric``). A record
    written before the knob existed reads as ``angle``."""
    target: float | None
    knob: str = "angle"
    geometric: float | None = None

    @classmethod
    def of(cls, record: dict) -> "OverlapKnob":
        knob = record.get("knob") or "angle"
        if knob not in ("angle", "pixels"):
            raise ValueError(f"overlap record: knob must be angle or pixels, got {str(knob)[:40]!r}")
        return cls(record.get("target"), knob, record.get("geometric", record.get("target")))

    @property
    def pair_target(self) -> float | None:
        """The geometric target the adjacent pairs were laid out at (`target_pair_mean` selects by it)."""
        return self.geometric if self.knob == "pixels" else self.target


#: upper edges of the distance bands, as fractions of the image width (`distance_bands`)
BAND_EDGES = (0.10, 0.20, 0.35)
#: the bands' names: inside the overlap, then out to the far edge
BAND_NAMES = ("overlap", "0-0.10", "0.10-0.20", "0.20-0.35", ">0.35")


def distance_to_overlap(overlap: np.ndarray) -> np.ndarray:
    """(H, W) float32 Euclidean distance in pixels from each pixel centre to the nearest overlap pixel
    of the same image (0 inside the overlap; inf everywhere when the image has no overlap pixel)."""
    import cv2

    ov = _arr(overlap, "overlap", dtype=bool)
    if not ov.any():
        return np.full(ov.shape, np.inf, np.float32)
    return cv2.distanceTransform((~ov).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def distance_bands(overlap: np.ndarray) -> np.ndarray:
    """(H, W) int8 band index of every pixel: 0 inside the overlap, then k for a distance to the nearest
    overlap pixel in (edge_{k-1}, edge_k] x image width (`BAND_EDGES`, edge_0 = 0), the last band beyond
    the last edge (and every pixel of an image without overlap). Fractions of the width make resolutions
    compare. The bands partition the image."""
    d = distance_to_overlap(overlap) / float(np.asarray(overlap).shape[1])
    out = np.full(d.shape, len(BAND_EDGES) + 1, np.int8)
    for k in range(len(BAND_EDGES), 0, -1):
        out[d <= BAND_EDGES[k - 1]] = k
    out[d == 0] = 0
    return out
