"""Torch twins of the camera-model table (`synth.camera.MODELS`), keyed by the same row names: batched,
differentiable `project` and `unproject`, so a warp goes through whatever lens a camera has.

Conventions are the table's (docs/DESIGN.md, `synth.camera`): OpenCV camera axes; `K` in pixels of the image
it belongs to, pixel centres at +0.5; rays have z = 1 for a ``z_depth`` row (pinhole, radtan) and unit length
for a ``range`` row (kannala_brandt), so ``depth * ray`` is the point whichever the row's depth kind is.
``dist`` is (B, D) with the row's D parameters in `synth.camera.CameraModel.dist_names` order ((B, 0) for
pinhole). The distorted rows' inverses are Newton iterations (`synth.camera.NEWTON_TOL`, at most
`synth.camera.NEWTON_ITERS` steps) run without a graph, then one more step with it: at the solution that
step's gradient is the implicit function's, exact to first order, whatever the iteration count.

Why hand-written rather than kornia's (`distort_points_kannala_brandt`, `undistort_points`): these are ~100
lines, batch per-camera parameters in one (B, D) tensor, give the validity mask the table's rows give, and match
`synth.camera` to 1e-10 px (tests/mcdp/test_camera.py); kornia would add a dependency (and its Rust wheel)
to the core install for the same arithmetic.

Example::

    >>> import torch
    >>> from mcdp.camera import project, unproject
    >>> K = torch.tensor([[[100.0, 0, 64], [0, 100, 48], [0, 0, 1]]], dtype=torch.float64)
    >>> dist = torch.tensor([[0.01, -0.002, 0.0, 0.0]], dtype=torch.float64)
    >>> pts = unproject(torch.full((1, 1, 96, 128), 5.0, dtype=torch.float64), K, dist, "kannala_brandt")
    >>> uv, ok = project(pts.flatten(2), K, dist, "kannala_brandt")
    >>> bool(ok.all()), float((uv[0, 0, :128] - (torch.arange(128) + 0.5)).abs().max()) < 1e-9
    (True, True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch

from synth.camera import EPS_Z, MODELS, NEWTON_ITERS, NEWTON_TOL, RADTAN_R_CAP


@dataclass(frozen=True)
class TorchModel:
    """The twin of a `synth.camera.CameraModel` row: ``project(K, dist, p) -> (uv, valid)`` ((B, 3, N) ->
    (B, 2, N), (B, N) bool) and ``unproject(K, dist, uv) -> rays`` ((B, 2, N) -> (B, 3, N))."""

    name: str
    project: Callable
    unproject: Callable


TORCH_MODELS: dict[str, TorchModel] = {}


def _row(name: str) -> TorchModel:
    try:
        return TORCH_MODELS[name]
    except KeyError:
        raise ValueError(f"unknown camera model {name!r}; the table has {', '.join(TORCH_MODELS)}") from None


def _check(K, dist, name, B):
    if K.ndim != 3 or K.shape[1:] != (3, 3) or K.shape[0] not in (1, B):
        raise ValueError(f"K must have shape (B, 3, 3) with B = 1 or {B}, got {tuple(K.shape)}")
    D = len(MODELS[name].dist_names)
    if D and (dist is None or dist.ndim != 2 or dist.shape[1] != D or dist.shape[0] not in (1, B)):
        raise ValueError(f"camera model {name!r}: dist must have shape (B, {D}), got "
                         f"{None if dist is None else tuple(dist.shape)}")


def resized(K: torch.Tensor, sx: float, sy: float) -> torch.Tensor:
    """(B, 3, 3) K of images resized by (sx, sy): diag(sx, sy, 1) K, as `synth.camera.resized` (every row
    keeps its distortion parameters through a resize, so K is all that changes)."""
    return K * torch.tensor([sx, sy, 1.0], dtype=K.dtype, device=K.device).view(1, 3, 1)


def project(points: torch.Tensor, K: torch.Tensor, dist: torch.Tensor | None, model: str = "pinhole",
            eps: float = EPS_Z):
    """Camera-frame points (B, 3, N) -> pixel coordinates (B, 2, N) and valid (B, N) bool through row `model`.
    K: (B|1, 3, 3); dist: (B|1, D) (None for pinhole). ``eps``: the pinhole row's smallest z (its division
    uses max(z, eps), as `mcdp.geometry.points_to_pixels` always has)."""
    row = _row(model)
    if points.ndim != 3 or points.shape[1] != 3:
        raise ValueError(f"points must have shape (B, 3, N), got {tuple(points.shape)}")
    _check(K, dist, model, points.shape[0])
    return row.project(K.to(points.dtype), None if dist is None else dist.to(points.dtype), points, eps)


def unproject_pixels(uv: torch.Tensor, K: torch.Tensor, dist: torch.Tensor | None, model: str = "pinhole"):
    """Pixel coordinates (B|1, 2, N) -> rays (B, 3, N): z = 1 (``z_depth`` rows) or unit (``range``), NaN where
    the row has no ray."""
    _check(K, dist, model, max(uv.shape[0], K.shape[0]))
    return _row(model).unproject(K.to(uv.dtype), None if dist is None else dist.to(uv.dtype), uv)


def unproject(depth: torch.Tensor, K: torch.Tensor, dist: torch.Tensor | None, model: str = "pinhole"):
    """A depth map (B, 1, H, W) (z-depth or range: the row's depth kind) -> camera-frame points (B, 3, H, W)."""
    if depth.ndim != 4 or depth.shape[1] != 1:
        raise ValueError(f"depth must have shape (B, 1, H, W), got {tuple(depth.shape)}")
    B, _, H, W = depth.shape
    v, u = torch.meshgrid(torch.arange(H, device=depth.device, dtype=depth.dtype) + 0.5,
                          torch.arange(W, device=depth.device, dtype=depth.dtype) + 0.5, indexing="ij")
    rays = unproject_pixels(torch.stack([u, v]).view(1, 2, H * W), K, dist, model)
    return rays.nan_to_num(0.0).view(-1, 3, H, W) * depth  # no ray: the point (0, 0, 0), which no row sees


# --------------------------------------------------------------------------- a batch's lenses
@dataclass(frozen=True)
class Lens:
    """The lenses of a rig's cameras (issue 59): ``models`` (N,) row names in rig order and ``dist`` (N, D) or,
    in a batch, (B, N, D) float32, each camera's parameters in its row's order padded with zeros to the longest
    row's D. A rig whose cameras are all pinhole has no Lens (None): its warps are the pinhole path, unchanged."""

    models: tuple[str, ...]
    dist: torch.Tensor

    @staticmethod
    def of_cameras(cameras) -> "Lens | None":
        """The Lens of a reader's cameras (``.intrinsics``: `synth.protocol.Camera`), None when all are pinhole."""
        cams = [c.intrinsics for c in cameras]
        if all(c.model == "pinhole" for c in cams):
            return None
        D = max(len(c.dist) for c in cams)
        return Lens(tuple(c.model for c in cams),
                    torch.tensor([list(c.dist) + [0.0] * (D - len(c.dist)) for c in cams], dtype=torch.float32))

    def map(self, fn) -> "Lens":
        """The same Lens with ``fn`` applied to ``dist`` (``.to(device)``, ``pin_memory``)."""
        return Lens(self.models, fn(self.dist))

    def of(self, cams: torch.Tensor | None = None) -> tuple[tuple[str, ...], torch.Tensor]:
        """The per-item lens of a batch's cameras ``cams`` (P,) (None: all N in rig order), flattened in (b, p)
        order as the warps flatten images: (B * P row names, (B * P, D) dist); what `mcdp.geometry.warp_by_depth`
        and `splat_depth` take as ``lens_tgt`` / ``lens_src``."""
        if self.dist.ndim != 3:
            raise ValueError(f"Lens.of needs a batch's dist (B, N, D), got {tuple(self.dist.shape)}")
        B, N, D = self.dist.shape
        idx = list(range(N)) if cams is None else cams.tolist() if torch.is_tensor(cams) else [int(c) for c in cams]
        return tuple(self.models[c] for _ in range(B) for c in idx), self.dist[:, idx].reshape(-1, D)


def _row_dist(dist, name: str):
    D = len(MODELS[name].dist_names)
    return dist[:, :D] if D else None


def _by_row(fn, models, B: int, K: torch.Tensor, dist: torch.Tensor, x: torch.Tensor, *args):
    """``fn(x, K, dist, name, *args)`` of items whose rows are ``models`` (one name, or one per item of B),
    each row's items in one call, the outputs put back in item order (differentiable: index_copy)."""
    if isinstance(models, str) or len(set(models)) == 1:
        name = models if isinstance(models, str) else models[0]
        return fn(x, K, _row_dist(dist, name), name, *args)
    if len(models) != B:
        raise ValueError(f"a lens names {len(models)} camera models, the batch has {B} items")
    K, dist, x = K.expand(B, 3, 3), dist.expand(B, -1), x.expand(B, *x.shape[1:])
    outs = None
    for name in dict.fromkeys(models):
        idx = torch.tensor([i for i, m in enumerate(models) if m == name], device=x.device)
        part = fn(x[idx], K[idx], _row_dist(dist[idx], name), name, *args)
        part = part if isinstance(part, tuple) else (part,)
        if outs is None:
            outs = [torch.zeros((B, *p.shape[1:]), dtype=p.dtype, device=p.device) for p in part]
        outs = [o.index_copy(0, idx, p) for o, p in zip(outs, part)]
    return tuple(outs) if len(outs) > 1 else outs[0]


def project_lens(points: torch.Tensor, K: torch.Tensor, lens, eps: float = EPS_Z):
    """`project` through ``lens`` = (row name or (B,) row names, (B|1, D) dist): (B, 3, N) -> ((B, 2, N), (B, N))."""
    return _by_row(lambda x, k, d, n: project(x, k, d, n, eps), lens[0], points.shape[0], K, lens[1], points)


def unproject_lens(depth: torch.Tensor, K: torch.Tensor, lens):
    """`unproject` through ``lens`` (as `project_lens`): depth (B, 1, H, W) of each item's depth kind -> (B, 3, H, W)."""
    return _by_row(lambda x, k, d, n: unproject(x, k, d, n), lens[0], depth.shape[0], K, lens[1], depth)


def range_items(lens, B: int, device=None) -> torch.Tensor:
    """(B, 1) bool: which items' rows have depth kind ``range`` (their depth is a point's norm, not its z)."""
    models = (lens[0],) * B if isinstance(lens[0], str) else lens[0]
    return torch.tensor([MODELS[m].depth_kind == "range" for m in models], device=device).view(-1, 1)


# --------------------------------------------------------------------------- pinhole: mcdp.geometry's arithmetic
def _pinhole_project(K, dist, p, eps):
    Kp = K @ p  # (B, 3, N)
    return Kp[:, :2] / Kp[:, 2:3].clamp(min=eps), p[:, 2] > eps


def _pinhole_unproject(K, dist, uv):
    pix = torch.cat([uv, torch.ones_like(uv[:, :1])], 1)  # (1, 3, N)
    return torch.linalg.inv(K) @ pix  # z component = 1


# --------------------------------------------------------------------------- the distorted rows
def _tol(x: torch.Tensor) -> tuple[float, float]:
    """(Newton's stopping residual, the residual below which a pixel has a ray) in normalised units: the table's
    in float64; in float32 (training), where a residual stalls at a few ulps (~1e-7), 1e-6 and 1e-4 (1e-4 focal
    lengths: 0.04 px at f = 400 px; a pixel beyond a row's range misses by far more)."""
    return (NEWTON_TOL, 1e3 * NEWTON_TOL) if x.dtype == torch.float64 else (1e-6, 1e-4)


def _to_pixels(K, xd, yd):
    return torch.stack([K[:, 0, 0:1] * xd + K[:, 0, 1:2] * yd + K[:, 0, 2:3], K[:, 1, 1:2] * yd + K[:, 1, 2:3]], 1)


def _to_normalised(K, uv):
    yd = (uv[:, 1] - K[:, 1, 2:3]) / K[:, 1, 1:2]
    return (uv[:, 0] - K[:, 0, 2:3] - K[:, 0, 1:2] * yd) / K[:, 0, 0:1], yd


def _first_fall(deriv, hi: float, like: torch.Tensor) -> torch.Tensor:
    """(B, 1): per camera, the first point of synth.camera's grid on (0, hi] where `deriv` is not positive."""
    with torch.no_grad():
        t = torch.linspace(0.0, hi, 20001, dtype=like.dtype, device=like.device)
        bad = deriv(t[1:].view(1, -1)) <= 0  # (B, G)
        first = torch.where(bad.any(1), bad.float().argmax(1), torch.full_like(bad[:, 0], len(t) - 1, dtype=torch.long))
        return torch.where(bad.any(1), t[first], torch.full_like(t[first], hi)).view(-1, 1)


def _radtan(d, x, y):
    k1, k2, p1, p2, k3 = (d[:, i:i + 1] for i in range(5))
    r2 = x * x + y * y
    R = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return x * R + 2 * p1 * x * y + p2 * (r2 + 2 * x * x), y * R + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y, r2, R


def _radtan_rmax(d):
    k1, k2, k3 = d[:, 0:1], d[:, 1:2], d[:, 4:5]
    return _first_fall(lambda r: 1 + 3 * k1 * r**2 + 5 * k2 * r**4 + 7 * k3 * r**6, RADTAN_R_CAP, d)


def _radtan_project(K, d, p, eps):
    front = p[:, 2] > eps
    zs = torch.where(front, p[:, 2], torch.ones_like(p[:, 2]))
    xd, yd, r2, _ = _radtan(d, p[:, 0] / zs, p[:, 1] / zs)
    ok = front & (r2 < _radtan_rmax(d) ** 2)
    zero = torch.zeros_like(xd)
    return _to_pixels(K, torch.where(ok, xd, zero), torch.where(ok, yd, zero)), ok


def _radtan_step(d, x, y, xd, yd):
    k1, k2, p1, p2, k3 = (d[:, i:i + 1] for i in range(5))
    fx, fy, r2, R = _radtan(d, x, y)
    fx, fy = fx - xd, fy - yd
    dR = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    a = R + 2 * x * x * dR + 2 * p1 * y + 6 * p2 * x
    b = 2 * x * y * dR + 2 * p1 * x + 2 * p2 * y
    c = R + 2 * y * y * dR + 6 * p1 * y + 2 * p2 * x
    det = a * c - b * b
    return x - (c * fx - b * fy) / det, y - (a * fy - b * fx) / det, fx.abs() + fy.abs()


def _radtan_unproject(K, d, uv):
    xd, yd = _to_normalised(K, uv)
    with torch.no_grad():
        x, y = xd.detach(), yd.detach()
        for _ in range(NEWTON_ITERS):
            x, y, res = _radtan_step(d.detach(), x, y, xd.detach(), yd.detach())
            if bool((res < _tol(uv)[0]).all()):
                break
    x, y, _ = _radtan_step(d, x, y, xd, yd)  # with the graph: the implicit gradient
    with torch.no_grad():
        fx, fy, r2, _ = _radtan(d, x, y)
        ok = ((fx - xd).abs() + (fy - yd).abs() < _tol(uv)[1]) & (r2 < _radtan_rmax(d) ** 2)
    rays = torch.stack([x, y, torch.ones_like(x)], 1)
    return torch.where(ok[:, None], rays, torch.full_like(rays, math.nan))


def _kb_theta_d(d, t):
    k1, k2, k3, k4 = (d[:, i:i + 1] for i in range(4))
    t2 = t * t
    return t * (1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))


def _kb_tmax(d):
    k1, k2, k3, k4 = (d[:, i:i + 1] for i in range(4))
    return _first_fall(lambda t: 1 + 3 * k1 * t**2 + 5 * k2 * t**4 + 7 * k3 * t**6 + 9 * k4 * t**8, math.pi, d)


def _kb_project(K, d, p, eps):
    rho = torch.sqrt(p[:, 0] ** 2 + p[:, 1] ** 2 + torch.finfo(p.dtype).tiny)  # tiny: a finite gradient on the axis
    theta = torch.atan2(rho, p[:, 2])
    ok = (torch.sqrt(rho**2 + p[:, 2] ** 2) > eps) & (theta < _kb_tmax(d))
    rs = torch.where(rho > 0, rho, torch.ones_like(rho))
    s = torch.where(ok, _kb_theta_d(d, theta) / rs, torch.zeros_like(rho))
    return _to_pixels(K, s * p[:, 0], s * p[:, 1]), ok


def _kb_step(d, t, td):
    k1, k2, k3, k4 = (d[:, i:i + 1] for i in range(4))
    t2 = t * t
    f = _kb_theta_d(d, t) - td
    return t - f / (1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))), f.abs()


def _kb_unproject(K, d, uv):
    xd, yd = _to_normalised(K, uv)
    td = torch.sqrt(xd**2 + yd**2 + torch.finfo(xd.dtype).tiny)
    tmax = _kb_tmax(d)
    with torch.no_grad():
        t = torch.minimum(td, tmax)
        for _ in range(NEWTON_ITERS):
            t_new, res = _kb_step(d, t, td)
            if bool((res < _tol(uv)[0]).all()):
                break
            t = torch.minimum(torch.clamp(t_new, min=0.0), tmax)
    t, _ = _kb_step(d, t, td)  # with the graph
    with torch.no_grad():
        ok = ((_kb_theta_d(d, t) - td).abs() < _tol(uv)[1]) & (t < tmax)
    s = torch.sin(t) / torch.where(td > 0, td, torch.ones_like(td))
    rays = torch.stack([s * xd, s * yd, torch.cos(t)], 1)
    return torch.where(ok[:, None], rays, torch.full_like(rays, math.nan))


for _r in (TorchModel("pinhole", _pinhole_project, _pinhole_unproject),
           TorchModel("radtan", _radtan_project, _radtan_unproject),
           TorchModel("kannala_brandt", _kb_project, _kb_unproject)):
    TORCH_MODELS[_r.name] = _r
