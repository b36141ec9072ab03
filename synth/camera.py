"""The camera-model table: how a camera maps camera-frame points to pixels and pixels to rays, one
`CameraModel` row a lens model. Every projection and unprojection of `synth` goes through it (and `mcdp`'s
torch twins, `mcdp.camera`, are keyed by the same row names); a new lens is a row here and its twin there.

Rows (in this order):

- ``pinhole``: K only. Depth kind ``z_depth``: a ray has z = 1, a point at z-depth d of a pixel is
  ``d * ray``. The arithmetic is today's, element by element (``((K0 x + K1 y) + K2 z)``), so a point's
  result never depends on which other points share the batch.
- ``radtan``: OpenCV's Brown-Conrady model (``cv2.projectPoints``), distortion ``k1 k2 p1 p2 k3`` on the
  normalised plane (x / z, y / z); depth kind ``z_depth``. Valid where z > `EPS_Z` and the radial map
  r -> r (1 + k1 r^2 + k2 r^4 + k3 r^6) still increases (`radtan_max_r`), so a pixel has one ray.
- ``kannala_brandt``: OpenCV's fisheye model (``cv2.fisheye.projectPoints``), ``k1 k2 k3 k4``:
  theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8) with theta the angle from the optical
  axis, written with atan2 so that it holds beyond 90 degrees (a 195 degree lens sees behind its own plane,
  where z-depth is not a distance); depth kind ``range``: rays are unit vectors, a point at range (ray
  length) r is ``r * ray``. Valid where theta_d still increases with theta (`kb_max_theta`).

Conventions (docs/DESIGN.md): OpenCV camera axes; `K` in pixels of the stored image, pixel centres at +0.5
(pixel (col c, row r) covers [c, c + 1) x [r, r + 1)); points are (3, N) float64 camera-frame columns.
The inverses of the distorted rows are Newton iterations to `NEWTON_TOL` (in normalised units: below 1e-9
px at any focal length below 1e3 px), at most `NEWTON_ITERS` steps; a pixel without a ray (beyond the
model's valid range) gets NaN.

Resizing an image by (sx, sy) maps K to diag(sx, sy, 1) K and keeps every distortion parameter: the
distortion acts on the normalised plane (or on angles), which a resize does not change.

Example::

    >>> import numpy as np
    >>> from synth.camera import Intrinsics, project, rays, model
    >>> K = np.array([[100.0, 0, 64], [0, 100, 48], [0, 0, 1]])
    >>> cam = Intrinsics("kannala_brandt", K, (0.01, -0.002, 0.0, 0.0))
    >>> model(cam).depth_kind, rays(K, 2, 2).shape
    ('range', (3, 4))
    >>> uv, ok = project(cam, rays(cam, 96, 128))      # unproject every pixel, project it back
    >>> bool(ok.all()), float(np.abs(uv[0] - (np.arange(96 * 128) % 128 + 0.5)).max()) < 1e-9
    (True, True)
    >>> Intrinsics.from_json(cam.to_json()) == cam
    True
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache
from typing import Callable, Literal

import numpy as np

#: a point is in front of a z-depth camera when its z exceeds this (metres); the overlap and flow tests' value
EPS_Z = 1e-6
#: Newton iterations of the distorted rows' inverses stop when the residual is below this (normalised units)
NEWTON_TOL = 1e-13
NEWTON_ITERS = 30

DepthKind = Literal["z_depth", "range"]


@dataclass(frozen=True)
class CameraModel:
    """One lens model: its name, the names of its distortion parameters (in order), its depth kind, and its
    `project(K, dist, points) -> (uv, valid)` ((3, N) -> (2, N) pixels, (N,) bool) and
    `unproject(K, dist, uv) -> rays` ((2, N) pixels -> (3, N) rays: z = 1 for ``z_depth``, unit for ``range``,
    NaN where the pixel has no ray). uv is finite wherever valid; elsewhere any finite value."""

    name: str
    dist_names: tuple[str, ...]
    depth_kind: DepthKind
    project: Callable[[np.ndarray, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
    unproject: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    about: str = ""


@dataclass(frozen=True, eq=False)
class Intrinsics:
    """A camera's intrinsics: its model's row name, `K` (3x3, pixels) and the model's distortion parameters
    (``len(dist) == len(row.dist_names)``). JSON: ``{"model", "K", "dist": {name: value}}`` (`to_json`)."""

    model: str
    K: np.ndarray
    dist: tuple[float, ...] = field(default=())

    def __post_init__(self) -> None:
        row = model(self.model)
        K = np.array(self.K, np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all():
            raise ValueError(f"camera model {self.model!r}: K must be a finite 3x3 matrix, got shape {K.shape}")
        dist = tuple(float(d) for d in self.dist)
        if len(dist) != len(row.dist_names) or not np.isfinite(dist).all():
            raise ValueError(f"camera model {self.model!r}: dist must be {len(row.dist_names)} finite numbers "
                             f"({', '.join(row.dist_names) or 'none'}), got {self.dist!r}")
        K.flags.writeable = False
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)

    def __eq__(self, other) -> bool:
        return (isinstance(other, Intrinsics) and self.model == other.model and self.dist == other.dist
                and np.array_equal(self.K, other.K))

    def to_json(self) -> dict:
        names = model(self.model).dist_names
        return {"model": self.model, "K": self.K.tolist(), "dist": dict(zip(names, self.dist))}

    @staticmethod
    def from_json(d: dict) -> "Intrinsics":
        """The inverse of `to_json`; ValueError naming the key that is missing or unknown."""
        if not isinstance(d, dict) or set(d) != {"model", "K", "dist"}:
            raise ValueError(f"camera intrinsics must have the keys model, K, dist; got {sorted(d) if isinstance(d, dict) else d!r}")
        names = model(d["model"]).dist_names
        if not isinstance(d["dist"], dict) or set(d["dist"]) != set(names):
            raise ValueError(f"camera model {d['model']!r}: dist must have the keys {list(names)}, got {d['dist']!r}")
        return Intrinsics(d["model"], np.asarray(d["K"], np.float64), tuple(d["dist"][n] for n in names))


MODELS: dict[str, CameraModel] = {}


def register(row: CameraModel) -> CameraModel:
    """Add a row to `MODELS` (a name given twice is an error)."""
    if row.name in MODELS:
        raise ValueError(f"camera model {row.name!r} is registered twice")
    MODELS[row.name] = row
    return row


def model(x) -> CameraModel:
    """The row of a model name, of an `Intrinsics`, or ``pinhole`` for a bare (3, 3) K."""
    name = x.model if isinstance(x, Intrinsics) else x if isinstance(x, str) else "pinhole"
    try:
        return MODELS[name]
    except KeyError:
        raise ValueError(f"unknown camera model {name!r}; the table has {', '.join(MODELS)}") from None


def as_intrinsics(cam) -> Intrinsics:
    """An `Intrinsics` as it is; a bare K (3x3 array or nested list) as a pinhole camera."""
    return cam if isinstance(cam, Intrinsics) else Intrinsics("pinhole", np.asarray(cam, np.float64))


def _parts(cam) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    if isinstance(cam, Intrinsics):
        return model(cam.model), cam.K, np.asarray(cam.dist, np.float64)
    K = np.asarray(cam, np.float64)
    if K.shape != (3, 3):
        raise ValueError(f"K must have shape (3, 3), got {K.shape}")
    return MODELS["pinhole"], K, np.zeros(0)


# --------------------------------------------------------------------------- the table's entry points
def project(cam, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(2, N) float64 pixel coordinates (pixel centres at +0.5) and (N,) bool valid of (3, N) camera-frame
    points; `cam` an `Intrinsics` or a pinhole K. Where not valid, uv is finite but meaningless."""
    row, K, dist = _parts(cam)
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[0] != 3:
        raise ValueError(f"points must have shape (3, N), got {p.shape}")
    return row.project(K, dist, p)


def unproject(cam, uv: np.ndarray) -> np.ndarray:
    """(3, N) rays of (2, N) continuous pixel coordinates: z = 1 (depth kind ``z_depth``) or unit (``range``)."""
    row, K, dist = _parts(cam)
    uv = np.asarray(uv, np.float64)
    if uv.ndim != 2 or uv.shape[0] != 2:
        raise ValueError(f"uv must have shape (2, N), got {uv.shape}")
    return row.unproject(K, dist, uv)


def rays_at(cam, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(3, M) rays through the centres of the pixels of integer columns `u` and rows `v` (1-D)."""
    return unproject(cam, np.stack([np.asarray(u) + 0.5, np.asarray(v) + 0.5]).astype(np.float64))


def rays(cam, H: int, W: int) -> np.ndarray:
    """(3, H*W) rays through every pixel centre in row-major order (``.T.reshape(H, W, 3)`` for an image)."""
    v, u = np.divmod(np.arange(int(H) * int(W)), int(W))
    return rays_at(cam, u, v)


def resized(cam, sx: float, sy: float):
    """The camera of its image resized by (sx, sy) (new / old width, height): K -> diag(sx, sy, 1) K, the
    distortion kept; a bare K gives a bare K. Exact under the pixel-centre-at-+0.5 convention."""
    row, K, dist = _parts(cam)
    K2 = K * np.array([sx, sy, 1.0])[:, None]
    return Intrinsics(row.name, K2, tuple(dist)) if isinstance(cam, Intrinsics) else K2


def depth_kind(cam) -> DepthKind:
    return model(cam).depth_kind


def pinhole_K(cam) -> np.ndarray:
    """K of a pinhole camera (what a rasteriser and a pinhole-only format need); ValueError for another model,
    naming it."""
    row, K, _ = _parts(cam)
    if row.name != "pinhole":
        raise ValueError(f"a pinhole camera is needed here, got camera model {row.name!r}")
    return K


def gl_projection(cam, width: int, height: int, znear: float, zfar: float) -> np.ndarray:
    """(4, 4) OpenGL clip matrix of a pinhole camera (OpenCV axes: x right, y down, z forward); the rasteriser
    draws pinhole images only (another model is refused). Maps pixel u (centres at +0.5) to window x = u and v
    to window y = H - v."""
    K = pinhole_K(cam)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    P = np.zeros((4, 4))
    P[0, 0] = 2 * fx / width
    P[0, 1] = 2 * K[0, 1] / width
    P[0, 2] = 2 * cx / width - 1
    P[1, 1] = -2 * fy / height
    P[1, 2] = 1 - 2 * cy / height
    P[2, 2] = (zfar + znear) / (zfar - znear)
    P[2, 3] = -2 * zfar * znear / (zfar - znear)
    P[3, 2] = 1.0
    return P


def pinhole_inverse(cam) -> np.ndarray:
    """K^-1 of a pinhole camera: the ray matrix a shader applies to (u, v, 1) (`synth.shaders` FS_SKY)."""
    return np.linalg.inv(pinhole_K(cam))


def unit_focal_radius(name: str, dist, angle_rad: float) -> float:
    """How far from the principal point (in focal lengths) row `name` images a ray at `angle_rad` from its axis:
    tan for pinhole, the distorted radius for radtan, theta_d for kannala_brandt (a K's focal length from a
    field of view, `synth.rig.intrinsics_for`). ValueError where the row has no image of that angle."""
    cam = Intrinsics(name, np.eye(3), tuple(dist))
    uv, ok = project(cam, np.array([[math.sin(angle_rad)], [0.0], [math.cos(angle_rad)]]))
    if not ok[0] or not uv[0, 0] > 0:
        raise ValueError(f"camera model {name!r} with dist {tuple(dist)} does not image {math.degrees(angle_rad):g} "
                         "degrees from its axis (half the field of view)")
    return float(uv[0, 0])


def pinhole_only(cameras, what: str, error: type[Exception] = ValueError) -> None:
    """`error` in one line unless every camera (``.name``, ``.model``) is pinhole: for what is pinhole by its
    format (nuScenes' calibrated_sensor has a camera_intrinsic only, glTF's cameras are perspective)."""
    other = [f"{c.name} ({c.model})" for c in cameras if c.model != "pinhole"]
    if other:
        raise error(f"{what} is pinhole only; camera(s) {', '.join(other)[:200]} have another lens model "
                         "(rig.cameras.<CAM>.model)")


# --------------------------------------------------------------------------- pinhole
def _apply3(M: np.ndarray, p: np.ndarray) -> np.ndarray:
    """M @ p for (3, N) columns, element by element: (M0 x + M1 y) + M2 z (batch-independent rounding)."""
    out = M[:, 0:1] * p[0] + M[:, 1:2] * p[1]
    out += M[:, 2:3] * p[2]
    return out


def _pinhole_project(K, dist, p):
    uvw = _apply3(K, p)
    z = p[2]
    front = z > EPS_Z
    zs = np.where(front, z, 1.0)
    return np.stack([uvw[0] / zs, uvw[1] / zs]), front


def _pinhole_unproject(K, dist, uv):
    return _apply3(np.linalg.inv(K), np.stack([uv[0], uv[1], np.ones(uv.shape[1])]))


# --------------------------------------------------------------------------- shared by the distorted rows
def _to_pixels(K, xd, yd):
    return np.stack([K[0, 0] * xd + K[0, 1] * yd + K[0, 2], K[1, 1] * yd + K[1, 2]])


def _to_normalised(K, uv):
    yd = (uv[1] - K[1, 2]) / K[1, 1]
    return (uv[0] - K[0, 2] - K[0, 1] * yd) / K[0, 0], yd


def _first_fall(f, lo: float, hi: float, n: int = 20001) -> float:
    """The first grid point of (lo, hi] where f (a derivative, f(lo) > 0) is no longer positive, else hi."""
    t = np.linspace(lo, hi, n)
    bad = np.flatnonzero(f(t[1:]) <= 0)
    return float(t[bad[0]]) if bad.size else hi


# --------------------------------------------------------------------------- radtan (OpenCV Brown-Conrady)
#: the largest normalised radius `radtan_max_r` searches (tan 84 deg: beyond any rectilinear lens)
RADTAN_R_CAP = 10.0


def radtan_max_r(dist) -> float:
    """The normalised radius up to which r (1 + k1 r^2 + k2 r^4 + k3 r^6) increases (at most `RADTAN_R_CAP`)."""
    return _radtan_max_r(tuple(float(d) for d in dist))


@lru_cache(maxsize=256)
def _radtan_max_r(dist: tuple) -> float:
    k1, k2, _, _, k3 = dist
    return _first_fall(lambda r: 1 + 3 * k1 * r**2 + 5 * k2 * r**4 + 7 * k3 * r**6, 0.0, RADTAN_R_CAP)


def _radtan(dist, x, y):
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    R = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * R + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * R + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return xd, yd, r2, R


def _radtan_project(K, dist, p):
    z = p[2]
    front = z > EPS_Z
    zs = np.where(front, z, 1.0)
    x, y = p[0] / zs, p[1] / zs
    xd, yd, r2, _ = _radtan(dist, x, y)
    ok = front & (r2 < radtan_max_r(dist) ** 2)
    xd, yd = np.where(ok, xd, 0.0), np.where(ok, yd, 0.0)
    return _to_pixels(K, xd, yd), ok


def _radtan_unproject(K, dist, uv):
    """Newton on the 2x2 system distort(x, y) = (xd, yd), from (xd, yd)."""
    k1, k2, p1, p2, k3 = dist
    xd, yd = _to_normalised(K, uv)
    x, y = xd.copy(), yd.copy()
    for _ in range(NEWTON_ITERS):
        fx, fy, r2, R = _radtan(dist, x, y)
        fx, fy = fx - xd, fy - yd
        if np.all(np.abs(fx) + np.abs(fy) < NEWTON_TOL):
            break
        dR = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # dR / d(r^2)
        a = R + 2 * x * x * dR + 2 * p1 * y + 6 * p2 * x
        b = 2 * x * y * dR + 2 * p1 * x + 2 * p2 * y
        d = R + 2 * y * y * dR + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * b
        with np.errstate(divide="ignore", invalid="ignore"):
            x, y = x - (d * fx - b * fy) / det, y - (a * fy - b * fx) / det
    fx, fy, r2, _ = _radtan(dist, x, y)
    ok = (np.abs(fx - xd) + np.abs(fy - yd) < 1e3 * NEWTON_TOL) & (r2 < radtan_max_r(dist) ** 2)
    return np.where(ok, np.stack([x, y, np.ones_like(x)]), np.nan)


# --------------------------------------------------------------------------- kannala_brandt (OpenCV fisheye)
def kb_max_theta(dist) -> float:
    """The angle from the axis (radians, at most pi) up to which theta_d(theta) increases."""
    return _kb_max_theta(tuple(float(d) for d in dist))


@lru_cache(maxsize=256)
def _kb_max_theta(dist: tuple) -> float:
    k1, k2, k3, k4 = dist
    return _first_fall(lambda t: 1 + 3 * k1 * t**2 + 5 * k2 * t**4 + 7 * k3 * t**6 + 9 * k4 * t**8, 0.0, np.pi)


def _kb_theta_d(dist, t):
    k1, k2, k3, k4 = dist
    t2 = t * t
    return t * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def _kb_project(K, dist, p):
    rho = np.hypot(p[0], p[1])
    theta = np.arctan2(rho, p[2])
    ok = (np.hypot(rho, p[2]) > EPS_Z) & (theta < kb_max_theta(dist))
    rs = np.where(rho > 0, rho, 1.0)
    s = np.where(ok, _kb_theta_d(dist, theta) / rs, 0.0)  # rho = 0: on the axis, (0, 0)
    return _to_pixels(K, s * p[0], s * p[1]), ok


def _kb_unproject(K, dist, uv):
    """Newton on theta_d(theta) = |(xd, yd)| from theta = theta_d; unit rays."""
    k1, k2, k3, k4 = dist
    xd, yd = _to_normalised(K, uv)
    td = np.hypot(xd, yd)
    tmax = kb_max_theta(dist)
    t = np.minimum(td, tmax)
    for _ in range(NEWTON_ITERS):
        f = _kb_theta_d(dist, t) - td
        if np.all(np.abs(f) < NEWTON_TOL):
            break
        t2 = t * t
        df = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
        t = np.clip(t - f / df, 0.0, tmax)
    ok = (np.abs(_kb_theta_d(dist, t) - td) < 1e3 * NEWTON_TOL) & (t < tmax)
    tds = np.where(td > 0, td, 1.0)
    s = np.sin(t) / tds
    return np.where(ok, np.stack([s * xd, s * yd, np.cos(t)]), np.nan)


register(CameraModel("pinhole", (), "z_depth", _pinhole_project, _pinhole_unproject,
                     "K only: today's arithmetic, element by element"))
register(CameraModel("radtan", ("k1", "k2", "p1", "p2", "k3"), "z_depth", _radtan_project, _radtan_unproject,
                     "OpenCV / Brown-Conrady radial-tangential distortion (cv2.projectPoints)"))
register(CameraModel("kannala_brandt", ("k1", "k2", "k3", "k4"), "range", _kb_project, _kb_unproject,
                     "OpenCV fisheye / Kannala-Brandt (cv2.fisheye.projectPoints), beyond 180 degrees"))
