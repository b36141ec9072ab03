"""Pinhole camera geometry for MCDP: unprojection, projection, backward warping, z-buffered splatting.

Conventions (docs/INTERFACES.md, tested in tests/mcdp/test_geometry.py):

- Camera frame OpenCV: x right, y down, z forward. ``depth`` is z-depth in metres.
- ``K`` is in pixels of the image it belongs to; pixel (col c, row r) has its
  centre at (c + 0.5, r + 0.5). Resizing by (sx, sy) maps K to diag(sx, sy, 1) @ K.
- ``grid_sample`` is always called with ``align_corners=False``; the matching
  normalisation is x_norm = 2 u / W - 1, y_norm = 2 v / H - 1.
- ``T_a_b`` (4x4) maps points in frame b into frame a.
- Batch dimensions first; K and T may have batch size 1 and are then broadcast
  over the batch of the image tensors. float32 and float64 both work.

Example (temporal view synthesis of frame t from frame t+1)::

    warped, valid = warp_by_depth(img_tp1, depth_t, K, K, T_tp1_t)
    # neighbour camera depth forward-projected into the target camera
    depth_hat, hit = splat_depth(depth_j, K_j, K_i, T_ci_cj, H_i, W_i)
"""
from __future__ import annotations

from typing import Optional, Sequence

import torch
import torch.nn.functional as F

from mcdp.camera import project, project_lens, range_items, resized, unproject, unproject_lens

__all__ = [
    "scale_intrinsics",
    "pixel_grid",
    "depth_to_points",
    "transform_points",
    "points_to_pixels",
    "pixels_to_grid",
    "warp_by_depth",
    "splat_depth",
]


# --------------------------------------------------------------------------- shape checks
def _check_tensor(x, name: str) -> None:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")


def _check_shape(x: torch.Tensor, name: str, expected: Sequence[Optional[int]], doc: str) -> None:
    """Raise ValueError naming `name` unless x.shape matches `expected` (None = any size)."""
    _check_tensor(x, name)
    ok = x.ndim == len(expected) and all(e is None or s == e for s, e in zip(x.shape, expected))
    if not ok:
        raise ValueError(f"{name} must have shape {doc}, got {tuple(x.shape)}")


def _check_batch(x: torch.Tensor, name: str, batch: int) -> None:
    if x.shape[0] not in (1, batch):
        raise ValueError(f"{name} has batch size {x.shape[0]}, expected 1 or {batch}")


# --------------------------------------------------------------------------- basics
def scale_intrinsics(K: torch.Tensor, sx: float, sy: float) -> torch.Tensor:
    """Intrinsics of an image resized by (sx, sy): diag(sx, sy, 1) @ K (`synth.camera.resized`'s K, batched;
    every row's distortion parameters are kept by a resize).

    Exact under the pixel-centre-at-+0.5 convention: resizing an H x W image to
    (sy H) x (sx W) maps every continuous pixel coordinate (u, v) to (sx u, sy v).

    Args:
        K: (B, 3, 3) intrinsics in pixels.
        sx: horizontal factor (new width / old width).
        sy: vertical factor (new height / old height).

    Returns:
        (B, 3, 3) scaled intrinsics.
    """
    _check_shape(K, "K", (None, 3, 3), "(B, 3, 3)")
    return resized(K, sx, sy)


def pixel_grid(H: int, W: int, device=None, dtype=None) -> torch.Tensor:
    """Homogeneous pixel-centre coordinates (u, v, 1) of an H x W image.

    Returns:
        (1, 3, H, W) tensor; [0, :, r, c] = (c + 0.5, r + 0.5, 1).
    """
    if int(H) <= 0 or int(W) <= 0:
        raise ValueError(f"H and W must be positive, got H={H}, W={W}")
    dtype = dtype if dtype is not None else torch.get_default_dtype()
    v, u = torch.meshgrid(
        torch.arange(H, device=device, dtype=dtype) + 0.5,
        torch.arange(W, device=device, dtype=dtype) + 0.5,
        indexing="ij",
    )
    return torch.stack([u, v, torch.ones_like(u)], dim=0).unsqueeze(0)


def depth_to_points(depth: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Unproject a z-depth map to camera-frame 3D points: X = depth * K^-1 (u, v, 1).

    Args:
        depth: (B, 1, H, W) z-depth in metres.
        K: (B, 3, 3) (or (1, 3, 3)) intrinsics of the depth map's resolution.

    Returns:
        (B, 3, H, W) points in metres, camera frame (OpenCV).
    """
    _check_shape(depth, "depth", (None, 1, None, None), "(B, 1, H, W)")
    _check_shape(K, "K", (None, 3, 3), "(B, 3, 3)")
    _check_batch(K, "K", depth.shape[0])
    return unproject(depth, K, None, "pinhole")  # the camera table's pinhole row (mcdp.camera)


def transform_points(T: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """Apply a rigid transform T_a_b to frame-b points: p_a = R p_b + t.

    Args:
        T: (B, 4, 4) (or (1, 4, 4)) homogeneous transform T_a_b.
        points: (B, 3, H, W) points in frame b.

    Returns:
        (B, 3, H, W) points in frame a.
    """
    _check_shape(T, "T", (None, 4, 4), "(B, 4, 4)")
    _check_shape(points, "points", (None, 3, None, None), "(B, 3, H, W)")
    B, _, H, W = points.shape
    _check_batch(T, "T", B)
    T = T.to(points.dtype)
    p = points.reshape(B, 3, H * W)  # (B, 3, N)
    out = T[:, :3, :3] @ p + T[:, :3, 3:4]
    return out.view(B, 3, H, W)


def points_to_pixels(points: torch.Tensor, K: torch.Tensor, eps: float = 1e-6):
    """Project camera-frame points to continuous pixel coordinates.

    The division uses max(z, eps), so points behind the camera get finite but
    meaningless (u, v); callers must mask them with ``z > eps``.

    Args:
        points: (B, 3, H, W) camera-frame points (metres).
        K: (B, 3, 3) (or (1, 3, 3)) intrinsics of the target image.
        eps: smallest z used in the division.

    Returns:
        uv: (B, 2, H, W) pixel coordinates (centre of pixel (c, r) is (c+0.5, r+0.5)).
        z: (B, 1, H, W) z-depth of each point in this camera (not clamped).
    """
    _check_shape(points, "points", (None, 3, None, None), "(B, 3, H, W)")
    _check_shape(K, "K", (None, 3, 3), "(B, 3, 3)")
    B, _, H, W = points.shape
    _check_batch(K, "K", B)
    uv, _ = project(points.reshape(B, 3, H * W), K, None, "pinhole", eps=eps)  # the camera table's pinhole row
    return uv.view(B, 2, H, W), points[:, 2:3]


def pixels_to_grid(uv: torch.Tensor, H_src: int, W_src: int) -> torch.Tensor:
    """Pixel coordinates -> normalised sampling grid for ``grid_sample(align_corners=False)``.

    x_norm = 2 u / W_src - 1, y_norm = 2 v / H_src - 1, so the image rectangle
    [0, W_src] x [0, H_src] maps to [-1, 1]^2.

    Args:
        uv: (B, 2, H, W) pixel coordinates in the source image.
        H_src, W_src: size of the image that will be sampled.

    Returns:
        (B, H, W, 2) grid (x, y) for ``F.grid_sample``.
    """
    _check_shape(uv, "uv", (None, 2, None, None), "(B, 2, H, W)")
    x = 2.0 * uv[:, 0] / W_src - 1.0
    y = 2.0 * uv[:, 1] / H_src - 1.0
    return torch.stack([x, y], dim=-1)


# --------------------------------------------------------------------------- warping
def warp_by_depth(
    src: torch.Tensor,
    depth_tgt: torch.Tensor,
    K_tgt: torch.Tensor,
    K_src: torch.Tensor,
    T_src_tgt: torch.Tensor,
    padding_mode: str = "zeros",
    eps: float = 1e-6,
    lens_tgt: Optional[tuple[str, torch.Tensor]] = None,
    lens_src: Optional[tuple[str, torch.Tensor]] = None,
):
    """Backward-warp a source image/feature map into the target view using target depth.

    target pixel -> 3D with ``depth_tgt`` -> source frame via ``T_src_tgt`` ->
    source pixel -> bilinear sample (``align_corners=False``). Source and target
    may have different resolutions; each K belongs to its own resolution.

    Args:
        src: (B, C, Hs, Ws) image or features of the source view.
        depth_tgt: (B, 1, H, W) z-depth of the target view in metres.
        K_tgt: (B, 3, 3) intrinsics of the target at (H, W).
        K_src: (B, 3, 3) intrinsics of the source at (Hs, Ws).
        T_src_tgt: (B, 4, 4) maps target-camera points into the source camera.
        padding_mode: ``grid_sample`` padding ("zeros", "border", "reflection").
        eps: a point is in front of the source camera when z > eps.
        lens_tgt, lens_src: None (pinhole) or a camera-model row name (or one per item, B names) and the
            (B, D) distortion parameters (`mcdp.camera`; `mcdp.camera.Lens.of` of a batch); then ``depth_tgt``
            is of the row's depth kind (range for kannala_brandt) and valid also needs the source row's validity.

    Returns:
        warped: (B, C, H, W) source sampled at each target pixel's correspondence.
        valid: (B, 1, H, W) float 0/1: 1 where the point is in front of the source
            camera (z > eps) and its projection lies inside the source image
            rectangle [0, Ws] x [0, Hs]. Multiply by it to zero the outside
            (e.g. a neighbour camera's features outside the overlap).
    """
    _check_shape(src, "src", (None, None, None, None), "(B, C, Hs, Ws)")
    _check_shape(depth_tgt, "depth_tgt", (src.shape[0], 1, None, None), f"({src.shape[0]}, 1, H, W)")
    B = src.shape[0]
    for t, n in ((K_tgt, "K_tgt"), (K_src, "K_src")):
        _check_shape(t, n, (None, 3, 3), "(B, 3, 3)")
        _check_batch(t, n, B)
    _check_shape(T_src_tgt, "T_src_tgt", (None, 4, 4), "(B, 4, 4)")
    _check_batch(T_src_tgt, "T_src_tgt", B)
    Hs, Ws = src.shape[-2:]

    pts_tgt = depth_to_points(depth_tgt, K_tgt) if lens_tgt is None else unproject_lens(depth_tgt, K_tgt, lens_tgt)
    pts_src = transform_points(T_src_tgt, pts_tgt)
    if lens_src is None:
        uv, z = points_to_pixels(pts_src, K_src, eps=eps)
        front = z > eps
    else:  # a pixel without a ray (NaN) samples outside the image
        uv, front = project_lens(pts_src.flatten(2), K_src, lens_src, eps=eps)
        uv, front = uv.nan_to_num(nan=-1e4).view(B, 2, *pts_src.shape[-2:]), front.view(B, 1, *pts_src.shape[-2:])
    grid = pixels_to_grid(uv, Hs, Ws).to(src.dtype)  # (B, H, W, 2)
    warped = F.grid_sample(src, grid, mode="bilinear", padding_mode=padding_mode, align_corners=False)
    with torch.no_grad():
        inside = (grid.abs() <= 1.0).all(dim=-1, keepdim=True).permute(0, 3, 1, 2)  # (B, 1, H, W)
        valid = (inside & front).to(src.dtype)
    return warped, valid


def splat_depth(
    depth_src: torch.Tensor,
    K_src: torch.Tensor,
    K_tgt: torch.Tensor,
    T_tgt_src: torch.Tensor,
    H_tgt: int,
    W_tgt: int,
    valid_src: Optional[torch.Tensor] = None,
    eps: float = 1e-6,
    lens_src: Optional[tuple] = None,
    lens_tgt: Optional[tuple] = None,
):
    """Forward-project source depth into the target camera with a z-buffer.

    Each source pixel with depth > 0 (and ``valid_src`` > 0) is unprojected,
    moved into the target frame and assigned to the target pixel that contains
    its projection: (floor(u), floor(v)). When several points land on one pixel
    the nearest one (smallest target z) wins; exact ties go to the lowest source
    pixel index, so the result is deterministic. The returned depth is the
    target-frame z of the winner and is differentiable w.r.t. ``depth_src``
    (the pixel assignment and the z-buffer choice are not: they are piecewise
    constant). Fully vectorised and free of host syncs: two ``scatter_reduce('amin')``
    and two scatters over all source pixels.

    Args:
        depth_src: (B, 1, Hs, Ws) source z-depth in metres (0 = no surface).
        K_src: (B, 3, 3) source intrinsics at (Hs, Ws).
        K_tgt: (B, 3, 3) target intrinsics at (H_tgt, W_tgt).
        T_tgt_src: (B, 4, 4) maps source-camera points into the target camera.
        H_tgt, W_tgt: target image size.
        valid_src: optional (B, 1, Hs, Ws) mask; source pixels with valid_src <= 0
            are not splatted (e.g. the ego-body self-occlusion mask).
        eps: points with target z <= eps are dropped.
        lens_src, lens_tgt: None (pinhole) or a lens as `warp_by_depth` takes it; then ``depth_src`` is of the
            source row's depth kind, a point is kept where the target row images it, and the z-buffer and the
            returned depth are of the target row's depth kind (range: the point's norm).

    Returns:
        depth_in_tgt: (B, 1, H_tgt, W_tgt) target z-depth of the nearest splatted
            point, 0 where nothing landed.
        hit: (B, 1, H_tgt, W_tgt) float 0/1, 1 where a point landed.
    """
    _check_shape(depth_src, "depth_src", (None, 1, None, None), "(B, 1, Hs, Ws)")
    B, _, Hs, Ws = depth_src.shape
    for t, n in ((K_src, "K_src"), (K_tgt, "K_tgt")):
        _check_shape(t, n, (None, 3, 3), "(B, 3, 3)")
        _check_batch(t, n, B)
    _check_shape(T_tgt_src, "T_tgt_src", (None, 4, 4), "(B, 4, 4)")
    _check_batch(T_tgt_src, "T_tgt_src", B)
    if valid_src is not None:
        _check_shape(valid_src, "valid_src", (B, 1, Hs, Ws), f"({B}, 1, {Hs}, {Ws})")
    H_tgt, W_tgt = int(H_tgt), int(W_tgt)
    if H_tgt <= 0 or W_tgt <= 0:
        raise ValueError(f"H_tgt and W_tgt must be positive, got {H_tgt}, {W_tgt}")

    if lens_src is None and lens_tgt is None:
        pts = transform_points(T_tgt_src, depth_to_points(depth_src, K_src))
        uv, z = points_to_pixels(pts, K_tgt, eps=eps)
        seen = None
    else:  # through the lenses: z is the target's depth of its kind, seen where its row images the point
        pts = depth_to_points(depth_src, K_src) if lens_src is None else unproject_lens(depth_src, K_src, lens_src)
        pts = transform_points(T_tgt_src, pts).flatten(2)  # (B, 3, Ns)
        lens_t = lens_tgt if lens_tgt is not None else ("pinhole", pts.new_zeros(1, 0))
        uv, seen = project_lens(pts, K_tgt, lens_t, eps=eps)
        z = torch.where(range_items(lens_t, B, pts.device), pts.norm(dim=1), pts[:, 2])
        uv = uv.nan_to_num(nan=-1.0)
    u = uv[:, 0].reshape(B, -1).detach()  # (B, N)
    v = uv[:, 1].reshape(B, -1).detach()
    z = z.reshape(B, -1)  # differentiable
    zd = z.detach()

    ok = (zd > eps) & (depth_src.detach().reshape(B, -1) > 0)
    if seen is not None:
        ok &= seen
    ok &= (u >= 0) & (u < W_tgt) & (v >= 0) & (v < H_tgt)  # False for NaN too
    if valid_src is not None:
        ok &= valid_src.reshape(B, -1) > 0

    # Everything below keeps full (B*N,) tensors and routes dropped points to a dummy bin at
    # index B*n_tgt, so there is no boolean indexing and hence no host sync on GPU.
    n_tgt = H_tgt * W_tgt
    dummy = B * n_tgt
    col = torch.where(ok, u, torch.zeros_like(u)).floor().long().clamp_(0, W_tgt - 1)
    row = torch.where(ok, v, torch.zeros_like(v)).floor().long().clamp_(0, H_tgt - 1)
    b_off = torch.arange(B, device=depth_src.device).view(B, 1) * n_tgt
    lin = torch.where(ok, b_off + row * W_tgt + col, torch.full_like(col, dummy)).reshape(-1)  # (B*N,)
    ok = ok.reshape(-1)
    z = z.reshape(-1)
    zd = torch.where(ok, zd.reshape(-1), torch.full_like(z, float("inf")))

    # z-buffer: per target pixel minimum of the (detached) z
    zmin = torch.full((dummy + 1,), float("inf"), dtype=zd.dtype, device=zd.device)
    zmin = zmin.scatter_reduce(0, lin, zd, reduce="amin", include_self=True)
    win = ok & (zd == zmin[lin])
    # exact ties: keep the lowest source index so exactly one point writes each pixel
    ids = torch.arange(lin.numel(), device=lin.device)
    big = torch.full_like(ids, lin.numel())
    first = torch.full((dummy + 1,), lin.numel(), dtype=ids.dtype, device=ids.device)
    first = first.scatter_reduce(0, lin, torch.where(win, ids, big), reduce="amin", include_self=True)
    keep = win & (ids == first[lin])
    lin_k = torch.where(keep, lin, torch.full_like(lin, dummy))  # unique indices except the dummy bin

    zero = torch.zeros((), dtype=z.dtype, device=z.device)
    # scatter's gradient w.r.t. src is a gather: each kept point receives its pixel's gradient,
    # dropped points read the (discarded) dummy bin, whose gradient is 0
    out = torch.zeros(dummy + 1, dtype=z.dtype, device=z.device).scatter(0, lin_k, torch.where(keep, z, zero))
    hit = torch.zeros(dummy + 1, dtype=z.dtype, device=z.device).scatter(0, lin_k, keep.to(z.dtype))
    out, hit = out[:dummy], hit[:dummy]
    return out.view(B, 1, H_tgt, W_tgt), hit.view(B, 1, H_tgt, W_tgt)
