"""Image formation of a non-pinhole camera (issue 59 item 3): its image made from pinhole renders ("faces") of the
rasteriser (`synth.gl_backend`, which stays pinhole) by a remap of every layer through the camera table's rays
(`synth.camera.rays`). A pinhole camera never comes here: `render_camera` renders it as ever, byte for byte.

Faces (`plan_for`). A camera whose rays all lie within `ONE_FACE_MAX_DEG` of its axis (a mild radtan lens) gets one
face looking along its axis; a wider one (a fisheye) gets the faces of a cube around its axis that its rays reach
(front, right, left, down, up: 5 for a 190 degree Kannala-Brandt lens; back too beyond 125 degrees from the axis),
each ray on the face of its major axis. Each face is a pinhole camera with square pixels, cropped to the rays it
holds plus `MARGIN_PX` face pixels, and sampled at least `SUPERSAMPLE` face pixels per target pixel in every
direction (the smallest singular value of d(face uv) / d(target uv) over its pixels).

Remap, per target pixel at face point (u, v) (pixel centres at +0.5):

* ``rgb``: bilinear of the four face pixels around (u, v), rounded to uint8;
* ``depth``: from the faces' exact ray geometry. A face's inverse z-depth is affine in its pixel coordinates over a
  plane, so where the four face pixels lie on one surface (all with depth, the same ego flag, layer and object id,
  and each with a second difference of inverse depth below `PLANAR_TOL` (relative) along both axes: no step
  between them) inverse face-z is interpolated bilinearly, which is exact on a plane; elsewhere (edges, creases) the
  nearest face pixel's surface is taken: its inverse depth extrapolated along its own plane (central differences)
  where its neighbours on both sides are of it, else its face-z as it is. Either way the point is the one at that face-z on the target pixel's own
  ray, and its depth is that point's, of the camera's depth kind: z-depth (pinhole, radtan) or range = ray length
  (kannala_brandt). Depth is never interpolated across an edge;
* ``ego``, ``layer``, ``instance``: the nearest face pixel's (the one whose face-z the nearest depth takes);
* a pixel without a ray (NaN: beyond the lens's valid range) has no surface: depth 0, rgb 0, ego False,
  layer -1, instance 0 (what the renderer writes for the sky);
* flow is not remapped: `synth.labels.forward_flow` recomputes it through the camera.

The error is stated and tested in tests/synth/test_lens_image.py (depth against a ray cast of the world mesh along
each pixel's ray; no seam where faces meet); the cost is in docs/results/render_throughput.md.

Example::

    plan = plan_for(cam.intrinsics, cam.width, cam.height)          # once per camera (cached)
    out = render_camera(renderer, cam, T_world_cam, frame, light, gain, labels=True)   # any lens
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from synth import camera

#: face pixels per target pixel, at least, in every direction (the face's sampling of the target's pixel grid)
SUPERSAMPLE = 2.0
#: face pixels kept around the rays a face holds, so that the four face pixels around every ray are rendered
MARGIN_PX = 2
#: a camera whose every ray lies within this angle of its axis is formed from one face (degrees)
ONE_FACE_MAX_DEG = 60.0
#: the four face pixels of a ray are one surface where |second difference of 1 / z| <= PLANAR_TOL / z at each
PLANAR_TOL = 1e-3
#: the largest side of a face (pixels): a camera whose faces would be larger is refused
MAX_FACE_PX = 8192
#: a face's focal length is at most this x `SUPERSAMPLE` x the camera's: near a fisheye's back pole (far beyond
#: any preset's 190 degrees) its pixels shrink tangentially without bound, and there it samples less densely
FOCAL_CAP = 4.0


@dataclass(frozen=True, eq=False)
class Face:
    """One pinhole face: `R_cam_face` (3, 3) rotates face-frame vectors into the camera frame; `K` (3, 3) its
    intrinsics at its image size `width` x `height`."""

    R_cam_face: np.ndarray
    K: np.ndarray
    width: int
    height: int

    @property
    def T_cam_face(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = self.R_cam_face
        return T


@dataclass(frozen=True, eq=False)
class LensPlan:
    """How a camera's (H, W) image is formed: its `faces`, and per target pixel (row-major) its face index
    `face` ((H*W,) int, -1 = no ray), its face point `uv` ((2, H*W) face pixels) and `scale` ((H*W,)): depth of
    the camera's kind = face z-depth x scale, for the point on the pixel's ray."""

    intrinsics: camera.Intrinsics
    width: int
    height: int
    faces: tuple[Face, ...]
    face: np.ndarray
    uv: np.ndarray
    scale: np.ndarray

    def face_pixels(self) -> int:
        """Pixels rendered per formed image (all faces together)."""
        return sum(f.width * f.height for f in self.faces)


def _frame(z_axis, down) -> np.ndarray:
    """R_cam_face of an OpenCV face looking along `z_axis` with image rows along `down` (camera frame)."""
    z, y = np.asarray(z_axis, np.float64), np.asarray(down, np.float64)
    return np.column_stack([np.cross(y, z), y, z])


#: cube faces around the camera's axis (camera frame): front, right, left, down, up, back
_CUBE = np.stack([_frame((0, 0, 1), (0, 1, 0)), _frame((1, 0, 0), (0, 1, 0)), _frame((-1, 0, 0), (0, 1, 0)),
                  _frame((0, 1, 0), (0, 0, -1)), _frame((0, -1, 0), (0, 0, 1)), _frame((0, 0, -1), (0, 1, 0))])


def plan_for(cam: camera.Intrinsics, width: int, height: int) -> LensPlan:
    """The faces and remap of camera `cam` at its image size (cached per camera); ValueError for a pinhole camera
    (it is rendered directly) or where a face would exceed `MAX_FACE_PX`."""
    cam = camera.as_intrinsics(cam)
    if cam.model == "pinhole":
        raise ValueError("a pinhole camera is rendered directly, not formed from faces")
    return _plan(cam.model, cam.K.tobytes(), cam.dist, int(width), int(height))


@lru_cache(maxsize=64)
def _plan(model: str, K_bytes: bytes, dist: tuple, W: int, H: int) -> LensPlan:
    cam = camera.Intrinsics(model, np.frombuffer(K_bytes, np.float64).reshape(3, 3), dist)
    d = camera.rays(cam, H, W)  # (3, P): z = 1 or unit; NaN where no ray
    P = H * W
    ok = np.isfinite(d).all(0)
    dn = np.where(ok, d, 0.0) / np.where(ok, np.linalg.norm(np.where(ok, d, 1.0), axis=0), 1.0)
    # the rays through the pixel's neighbours half a pixel either way: the local map target -> face (Jacobian)
    v, u = np.divmod(np.arange(P), W)
    centre = np.stack([u + 0.5, v + 0.5]).astype(np.float64)
    near = [camera.unproject(cam, centre + np.array(o)[:, None]) for o in ((0.5, 0), (-0.5, 0), (0, 0.5), (0, -0.5))]
    if ok.any() and math.degrees(math.acos(min(1.0, float(dn[2, ok].min())))) <= ONE_FACE_MAX_DEG:
        cube = _CUBE[:1]
        face = np.where(ok, 0, -1)
    else:
        cube = _CUBE
        face = np.where(ok, np.argmax(cube[:, :, 2] @ dn, axis=0), -1)  # the face of the ray's major axis
    faces, uv, scale = [], np.zeros((2, P)), np.zeros(P)
    kind = camera.depth_kind(cam)
    for k in range(len(cube)):
        sel = np.flatnonzero(face == k)
        if sel.size == 0:
            continue
        R = cube[k]
        q = R.T @ dn[:, sel]  # face-frame directions, z > 0 (the major axis)
        xy = q[:2] / q[2]  # face plane at unit focal length
        # smallest singular value of d(xy) / d(target pixel), from the half-pixel neighbours' rays
        cols = []
        for a, b in ((0, 1), (2, 3)):
            pa, pb = R.T @ near[a][:, sel], R.T @ near[b][:, sel]
            with np.errstate(divide="ignore", invalid="ignore"):
                cols.append(pa[:2] / pa[2] - pb[:2] / pb[2])
        J11, J21, J12, J22 = cols[0][0], cols[0][1], cols[1][0], cols[1][1]
        T = J11**2 + J21**2 + J12**2 + J22**2
        D = np.abs(J11 * J22 - J12 * J21)
        smin = np.sqrt(np.maximum((T - np.sqrt(np.maximum(T * T - 4 * D * D, 0.0))) / 2, 0.0))
        smin = smin[np.isfinite(smin) & (smin > 0)]
        f = SUPERSAMPLE / float(smin.min()) if smin.size else SUPERSAMPLE
        f = min(f, FOCAL_CAP * SUPERSAMPLE * float(max(cam.K[0, 0], cam.K[1, 1])))
        lo, hi = xy.min(1), xy.max(1)
        size = np.ceil(f * (hi - lo)).astype(int) + 2 * MARGIN_PX + 1
        if size.max() > MAX_FACE_PX:
            raise ValueError(f"camera model {model} at {W}x{H}: a face of {size[0]}x{size[1]} px exceeds "
                             f"{MAX_FACE_PX} px (field of view too wide for its image size)")
        cx, cy = MARGIN_PX - f * lo[0], MARGIN_PX - f * lo[1]
        Kf = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
        Kf.flags.writeable = False
        R = R.copy()
        R.flags.writeable = False
        face[sel] = len(faces)
        faces.append(Face(R, Kf, int(size[0]), int(size[1])))
        uv[:, sel] = camera.project(Kf, q)[0]  # the face's pinhole row (q: in front of the face)
        # the point at face-z z on this ray: z * (xy, 1) in the face frame; its depth in the camera's kind
        r_face = np.stack([xy[0], xy[1], np.ones(sel.size)])
        scale[sel] = (R @ r_face)[2] if kind == "z_depth" else np.linalg.norm(r_face, axis=0)
    for a in (face, uv, scale):
        a.flags.writeable = False
    return LensPlan(cam, W, H, tuple(faces), face, uv, scale)


def render_camera(renderer, cam, T_world_cam: np.ndarray, frame: float, light, gain=(1.0, 1.0, 1.0),
                  labels: bool = False) -> dict[str, np.ndarray]:
    """The renderer's layers for camera `cam` (a `synth.rig.CameraSpec`) at pose `T_world_cam`: a pinhole camera
    rendered directly (today's call, its bytes), another formed from its faces (`form`). Same keys, shapes and
    dtypes either way (`synth.gl_backend` module docstring; depth of the camera's depth kind)."""
    if cam.model == "pinhole":
        return renderer.render(cam.K, T_world_cam, frame, light, gain, size=(cam.width, cam.height), labels=labels)
    plan = plan_for(cam.intrinsics, cam.width, cam.height)
    return form(plan, lambda f: renderer.render(f.K, T_world_cam @ f.T_cam_face, frame, light, gain,
                                                size=(f.width, f.height), labels=True), labels)


def form(plan: LensPlan, render_face, labels: bool = False) -> dict[str, np.ndarray]:
    """The formed image of `plan`'s camera from ``render_face(face) -> layers`` (the renderer's read-back of that
    face with labels: rgb, depth, ego, instance, layer): rgb (H, W, 3) uint8, depth (H, W) float32 of the camera's
    depth kind, ego (H, W) bool, and with `labels` instance and layer (H, W) int32 (module docstring)."""
    H, W, P = plan.height, plan.width, plan.height * plan.width
    rgb = np.zeros((P, 3), np.uint8)
    depth = np.zeros(P, np.float32)
    ego = np.zeros(P, bool)
    inst = np.zeros(P, np.int32)
    layer = np.full(P, -1, np.int32)
    for k, f in enumerate(plan.faces):
        sel = np.flatnonzero(plan.face == k)
        out = render_face(f)
        rgb[sel], depth[sel], ego[sel], inst[sel], layer[sel] = _remap(out, plan.uv[:, sel], plan.scale[sel])
    res = {"rgb": rgb.reshape(H, W, 3), "depth": depth.reshape(H, W), "ego": ego.reshape(H, W)}
    if labels:
        res["instance"], res["layer"] = inst.reshape(H, W), layer.reshape(H, W)
    return res


def _one_surface_pixels(z: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(Hf, Wf) bool: face pixels with depth whose row and column neighbours (both sides) are of the same surface
    id and whose inverse depth has a second difference below `PLANAR_TOL` relative along both axes (no step)."""
    w = np.where(z > 0, 1.0 / np.where(z > 0, z, 1.0), 0.0)
    good = np.zeros(z.shape, bool)
    c = (slice(1, -1), slice(1, -1))
    ok = z[c] > 0
    for a, b in (((slice(1, -1), slice(0, -2)), (slice(1, -1), slice(2, None))),
                 ((slice(0, -2), slice(1, -1)), (slice(2, None), slice(1, -1)))):
        ok &= (z[a] > 0) & (z[b] > 0) & (ids[a] == ids[c]) & (ids[b] == ids[c])
        ok &= np.abs(w[a] - 2 * w[c] + w[b]) <= PLANAR_TOL * w[c]
    good[c] = ok
    return good


def _remap(out: dict, uv: np.ndarray, scale: np.ndarray):
    """One face's layers at face points `uv` (2, N): (rgb (N, 3) uint8, depth (N,) float32 of the camera's kind,
    ego (N,) bool, instance (N,) int32, layer (N,) int32)."""
    z = np.asarray(out["depth"], np.float64)
    Hf, Wf = z.shape
    # one surface id per face pixel: ego flag, layer and object id together
    ids = (out["layer"].astype(np.int64) * 2 + out["ego"]) * (1 << 32) + out["instance"].astype(np.int64)
    good = _one_surface_pixels(z, ids)
    x, y = uv[0] - 0.5, uv[1] - 0.5  # face pixel index coordinates
    i0 = np.clip(np.floor(x).astype(np.int64), 0, Wf - 2)
    j0 = np.clip(np.floor(y).astype(np.int64), 0, Hf - 2)
    fx, fy = np.clip(x - i0, 0.0, 1.0), np.clip(y - j0, 0.0, 1.0)
    wts = [((1 - fx) * (1 - fy)), (fx * (1 - fy)), ((1 - fx) * fy), (fx * fy)]
    idx = [(j0, i0), (j0, i0 + 1), (j0 + 1, i0), (j0 + 1, i0 + 1)]
    rgb_f = out["rgb"].astype(np.float64)
    rgb = sum(w[:, None] * rgb_f[j, i] for w, (j, i) in zip(wts, idx))
    one = good[j0, i0] & good[j0, i0 + 1] & good[j0 + 1, i0] & good[j0 + 1, i0 + 1]
    for j, i in idx[1:]:
        one &= ids[j, i] == ids[j0, i0]
    inv = sum(w / np.where(z[j, i] > 0, z[j, i], 1.0) for w, (j, i) in zip(wts, idx))
    jn = np.clip(np.floor(uv[1]).astype(np.int64), 0, Hf - 1)  # the nearest face pixel
    iN = np.clip(np.floor(uv[0]).astype(np.int64), 0, Wf - 1)
    # elsewhere: the nearest face pixel's surface, extrapolated along its own plane where its neighbours on both
    # sides are of it (``good``: central differences of 1 / z), else its face-z as it is
    zn = z[jn, iN]
    gn = good[jn, iN] & ~one
    w = np.where(z > 0, 1.0 / np.where(z > 0, z, 1.0), 0.0)
    jc, ic = np.clip(jn, 1, Hf - 2), np.clip(iN, 1, Wf - 2)
    gx = 0.5 * (w[jc, ic + 1] - w[jc, ic - 1])
    gy = 0.5 * (w[jc + 1, ic] - w[jc - 1, ic])
    wn = w[jn, iN] + gx * (uv[0] - iN - 0.5) + gy * (uv[1] - jn - 0.5)
    gn &= wn > 0
    zn = np.where(gn, 1.0 / np.where(gn, wn, 1.0), zn)
    zf = np.where(one, 1.0 / np.where(one, inv, 1.0), zn)
    depth = (zf * scale).astype(np.float32)
    return (np.clip(np.rint(rgb), 0, 255).astype(np.uint8), depth, out["ego"][jn, iN],
            out["instance"][jn, iN].astype(np.int32), out["layer"][jn, iN].astype(np.int32))
