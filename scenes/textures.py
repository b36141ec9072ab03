"""Procedural, seamlessly tiling material textures (pure numpy).

`make_textures(rng, size)` returns one (S, S, 3) uint8 sRGB layer per material in
`MATERIALS`; the layer index of a material is `LAYER[name]` (stable: the order
of `MATERIALS` never changes within a schema version). Every texture is periodic
(built from FFT-filtered noise and patterns with an integer number of periods
per tile), so repeat wrapping shows no seams, and carries real local contrast
(grain, mortar, frames, clumps): self-supervised depth learns from gradients.

Physical scale: `TILE_M[name]` is the (width, height) in metres one tile should
cover; meshes use `uv_scale=uv_scale_for(name)` (tiles per metre). Both, with each material's semantic
class, come from the one table of materials, `scenes.materials.TABLE`. Orientation
(see `scenes.primitives`): column = u * S, row = v * S, rows top-down, and on
vertical surfaces v grows downward, so facades appear upright.

`car_paint`, `sign` and `house_siding` are light and neutral: meshes colour them with per-vertex tints. The
noise, grain and pattern operations every maker uses are `scenes.patterns`.

Example::

    from scenes.textures import make_textures, LAYER
    tex, names = make_textures(np.random.default_rng(0), size=256)   # (L, 256, 256, 3) uint8
    tex[LAYER["brick"]]
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from scenes.materials import LAYER, MATERIALS, TILE_M, uv_scale_for  # noqa: F401 (the materials' table)
from scenes.patterns import Ctx as _Ctx, box_mask as _box_mask, lines as _lines, mix as _mix, shade as _shade

TEXTURE_SIZES = (64, 128, 256, 512)

# ---------------------------------------------------------------------------- materials
def _asphalt(c: _Ctx) -> np.ndarray:
    g = c.grain()
    blot = c.noise(1, 6)
    mid = c.noise(6, 24)
    speck = (c.noise(c.S / 4, c.S / 2) > 2.2).astype(float)
    crack = np.clip(1 - np.abs(c.noise(2, 8, (1.0, 1.0))) / 0.04, 0, 1) * (c.noise(1, 3) > 0.8)
    lum = 0.32 + 0.05 * g + 0.03 * blot + 0.02 * mid + 0.12 * speck - 0.10 * crack
    return _shade((1.0, 1.0, 1.03), lum)


def _lane_marking(c: _Ctx) -> np.ndarray:
    wear = c.noise(2, 16)
    lum = 0.86 + 0.04 * c.grain() - 0.08 * np.clip(wear - 1.0, 0, 2)
    return _shade((1.0, 1.0, 0.97), lum)


def _slabs(c: _Ctx, nx: int, ny: int, base, joint_w: float, stagger: bool) -> np.ndarray:
    U = c.U + (np.floor(c.V * ny) % 2) * (0.5 / nx) if stagger else c.U
    cell = c.cells(nx, ny) if not stagger else _stagger_cells(c, nx, ny)
    joints = np.maximum(_lines(U, nx, joint_w), _lines(c.V, ny, joint_w))
    lum = (0.85 + 0.15 * cell) * (1 + 0.06 * c.grain() + 0.05 * c.noise(2, 10)) * (1 - 0.45 * joints)
    return _shade(base, lum)


def _stagger_cells(c: _Ctx, nx: int, ny: int) -> np.ndarray:
    table = c.rng.random((ny, nx), dtype=np.float32)
    iy = np.floor(c.V * ny).astype(int) % ny
    U = (c.U + (iy % 2) * (0.5 / nx)) % 1.0
    ix = np.floor(U * nx).astype(int) % nx
    return table[iy, ix]


def _sidewalk(c: _Ctx) -> np.ndarray:
    return _slabs(c, 4, 4, (0.66, 0.64, 0.61), 0.03, False)


def _plaza(c: _Ctx) -> np.ndarray:
    return _slabs(c, 2, 2, (0.58, 0.57, 0.55), 0.012, False)


def _kerb(c: _Ctx) -> np.ndarray:
    joints = _lines(c.U, 2, 0.01)
    edge = _box_mask(c.V, 0.03, 0.14, 0.02)  # rounded top edge highlight
    lum = (0.7 + 0.08 * c.grain() + 0.05 * c.noise(2, 12)) * (1 - 0.5 * joints) * (1 + 0.15 * edge)
    return _shade((0.9, 0.9, 0.88), lum)


def _grass(c: _Ctx) -> np.ndarray:
    blades = c.noise(c.S / 6, c.S / 2, (0.6, 1.8))
    patches = c.noise(1, 5)
    dry = np.clip(c.noise(2, 8), 0, None)
    g = _shade((0.22, 0.42, 0.12), 1 + 0.25 * blades + 0.15 * patches)
    d = _shade((0.45, 0.42, 0.22), 1 + 0.2 * blades)
    return _mix(g, d, np.clip(0.35 * dry, 0, 0.7))


def _gravel(c: _Ctx) -> np.ndarray:
    stones = c.noise(c.S / 16, c.S / 4)
    lum = 0.5 + 0.09 * stones + 0.06 * c.grain() + 0.04 * c.noise(1, 6)
    return _shade((0.95, 0.9, 0.82), lum)


def _brick_pattern(c: _Ctx, nx: int, ny: int, base, mortar) -> np.ndarray:
    cell = _stagger_cells(c, nx, ny)
    iy = np.floor(c.V * ny) % 2
    U = c.U + iy * (0.5 / nx)
    mort = np.maximum(_lines(U, nx, 0.045), _lines(c.V, ny, 0.09))
    brick = _shade(base, (0.75 + 0.4 * cell) * (1 + 0.08 * c.grain() + 0.05 * c.noise(4, 24)))
    mor = _shade(mortar, 1 + 0.05 * c.grain())
    return _mix(brick, mor, mort)


def _brick(c: _Ctx) -> np.ndarray:
    return _brick_pattern(c, 8, 16, (0.55, 0.26, 0.17), (0.72, 0.70, 0.66))


def _window(c: _Ctx, x0, x1, y0, y1, frame, wall: np.ndarray, mullion: bool = True) -> np.ndarray:
    """Paint one framed window (fractions of the tile) onto `wall` (S, S, 3)."""
    outer = _box_mask(c.U, x0, x1, 0.004) * _box_mask(c.V, y0, y1, 0.004)
    fw = 0.025
    inner = _box_mask(c.U, x0 + fw, x1 - fw, 0.004) * _box_mask(c.V, y0 + fw, y1 - fw, 0.004)
    # glass: sky reflection gradient + blurred reflections of the street, varying per window
    refl = c.noise(2, 10, (1.0, 0.4))
    vy = np.clip((c.V - y0) / max(y1 - y0, 1e-3), 0, 1)
    glass = _shade((0.35, 0.45, 0.55), 0.55 + 0.5 * (1 - vy) * 0.6 + 0.15 * refl)
    if mullion:
        xm = 0.5 * (x0 + x1)
        ym = y0 + 0.35 * (y1 - y0)
        bars = np.maximum(_box_mask(c.U, xm - 0.008, xm + 0.008, 0.004),
                          _box_mask(c.V, ym - 0.008, ym + 0.008, 0.004)) * inner
    else:
        bars = np.zeros_like(inner)
    fr = _shade(frame, 1 + 0.05 * c.grain())
    out = _mix(wall, fr, outer)
    out = _mix(out, glass, inner * (1 - bars))
    # sill shadow below, lintel shadow above: depth cues
    sill = _box_mask(c.U, x0 - 0.02, x1 + 0.02, 0.004) * _box_mask(c.V, y1, y1 + 0.025, 0.004)
    shadow = _box_mask(c.U, x0, x1, 0.004) * _box_mask(c.V, y0 + fw, y0 + fw + 0.05, 0.01) * inner
    out = _mix(out, _shade((0.85, 0.85, 0.83), 1 + 0.04 * c.grain()), sill)
    return out * (1 - 0.35 * shadow[..., None])


def _plaster(c: _Ctx, base) -> np.ndarray:
    return _shade(base, 1 + 0.06 * c.grain() + 0.06 * c.noise(1, 8) + 0.04 * c.noise(8, 40))


def _facade_a(c: _Ctx) -> np.ndarray:
    wall = _plaster(c, (0.78, 0.72, 0.62))
    band = _box_mask(c.V, 0.90, 0.96, 0.005)  # floor cornice
    wall = _mix(wall, _shade((0.88, 0.85, 0.8), 1 + 0.05 * c.grain()), band)
    return _window(c, 0.25, 0.75, 0.22, 0.78, (0.92, 0.92, 0.9), wall)


def _facade_b(c: _Ctx) -> np.ndarray:
    blocks = _slabs(c, 4, 6, (0.70, 0.68, 0.64), 0.02, True)
    out = _window(c, 0.12, 0.40, 0.15, 0.80, (0.25, 0.25, 0.27), blocks)
    return _window(c, 0.60, 0.88, 0.15, 0.80, (0.25, 0.25, 0.27), out)


def _facade_c(c: _Ctx) -> np.ndarray:
    wall = _brick_pattern(c, 6, 24, (0.45, 0.30, 0.22), (0.6, 0.58, 0.55))
    lintel = _box_mask(c.U, 0.26, 0.74, 0.004) * _box_mask(c.V, 0.17, 0.23, 0.004)
    wall = _mix(wall, _shade((0.75, 0.73, 0.7), 1 + 0.05 * c.grain()), lintel)
    return _window(c, 0.3, 0.7, 0.23, 0.75, (0.95, 0.95, 0.95), wall)


def _facade_glass(c: _Ctx) -> np.ndarray:
    pane = c.cells(2, 1)
    refl = c.noise(1, 6, (1.0, 0.5))
    glass = _shade((0.30, 0.40, 0.48), 0.8 + 0.35 * pane + 0.25 * refl + 0.04 * c.grain())
    mull = np.maximum(_lines(c.U, 2, 0.025), _lines(c.V, 1, 0.03))
    spandrel = _box_mask(c.V, 0.82, 1.0, 0.004)
    sp = _shade((0.32, 0.33, 0.35), 1 + 0.06 * c.grain())
    out = _mix(glass, sp, spandrel)
    return _mix(out, _shade((0.6, 0.62, 0.65), 1 + 0.05 * c.grain()), mull)


def _shopfront(c: _Ctx) -> np.ndarray:
    wall = _plaster(c, (0.5, 0.47, 0.45))
    sign_band = _box_mask(c.V, 0.05, 0.22, 0.004)
    letters = (c.noise(12, 40, (0.4, 1.0)) > 0.6) * _box_mask(c.U, 0.1, 0.9, 0.01) * _box_mask(c.V, 0.09, 0.18, 0.004)
    out = _mix(wall, _shade((0.2, 0.25, 0.45), 1 + 0.05 * c.grain()), sign_band)
    out = _mix(out, _shade((0.95, 0.9, 0.7), np.ones_like(c.U)), letters)
    out = _window(c, 0.06, 0.55, 0.3, 0.95, (0.2, 0.2, 0.22), out, mullion=False)
    return _window(c, 0.65, 0.92, 0.3, 0.95, (0.2, 0.2, 0.22), out)  # door


def _house_siding(c: _Ctx) -> np.ndarray:
    boards = 12
    f = (c.V * boards) % 1.0
    shade = 0.82 + 0.2 * f  # each board darker at its top (shadow of the one above)
    board_id = c.cells(1, boards)
    lum = shade * (0.95 + 0.08 * board_id) * (1 + 0.05 * c.grain() + 0.05 * c.noise(2, 10, (0.3, 1.0)))
    return _shade((0.9, 0.9, 0.88), lum)


def _house_windows(c: _Ctx) -> np.ndarray:
    wall = _house_siding(c)
    return _window(c, 0.3, 0.7, 0.25, 0.7, (0.95, 0.95, 0.95), wall)


def _roof_tiles(c: _Ctx) -> np.ndarray:
    nx, ny = 8, 8
    cell = _stagger_cells(c, nx, ny)
    f = (c.V * ny) % 1.0
    iy = np.floor(c.V * ny) % 2
    U = c.U + iy * (0.5 / nx)
    side = _lines(U, nx, 0.05)
    lum = (0.6 + 0.5 * f) * (0.85 + 0.3 * cell) * (1 - 0.4 * side) * (1 + 0.06 * c.grain())
    return _shade((0.55, 0.25, 0.18), lum)


def _roof_flat(c: _Ctx) -> np.ndarray:
    seams = _lines(c.U, 4, 0.01)
    lum = (0.45 + 0.06 * c.grain() + 0.05 * c.noise(1, 6)) * (1 - 0.3 * seams)
    return _shade((0.9, 0.9, 0.92), lum)


def _leaves(c: _Ctx, base, scale: float) -> np.ndarray:
    clumps = c.noise(2 * scale, 10 * scale)
    leaves = c.noise(c.S / 10, c.S / 2.5)
    holes = np.clip(-clumps - 1.0, 0, 1)
    lum = 1 + 0.3 * clumps + 0.3 * leaves - 0.5 * holes
    col = _shade(base, np.clip(lum, 0.2, 2.0))
    hue = c.noise(1, 4)
    col[..., 0] *= 1 + 0.12 * hue
    return col


def _foliage(c: _Ctx) -> np.ndarray:
    return _leaves(c, (0.16, 0.32, 0.10), 1.0)


def _hedge(c: _Ctx) -> np.ndarray:
    return _leaves(c, (0.12, 0.26, 0.09), 2.0)


def _bark(c: _Ctx) -> np.ndarray:
    streak = c.noise(4, 30, (0.5, 4.0))  # elongated along v (vertical on trunks)
    lum = 0.8 + 0.3 * streak + 0.1 * c.grain()
    return _shade((0.36, 0.28, 0.21), lum)


def _metal_pole(c: _Ctx) -> np.ndarray:
    brushed = c.noise(8, c.S / 2, (1.0, 20.0))
    lum = 0.55 + 0.06 * brushed + 0.04 * c.grain() + 0.05 * c.noise(1, 4)
    return _shade((0.92, 0.93, 0.95), lum)


def _car_paint(c: _Ctx) -> np.ndarray:
    lum = 0.82 + 0.03 * c.grain() + 0.04 * c.noise(1, 5)
    return _shade((1.0, 1.0, 1.0), lum)


def _car_glass(c: _Ctx) -> np.ndarray:
    refl = c.noise(1, 5, (1.0, 0.5))
    return _shade((0.16, 0.2, 0.25), 1 + 0.35 * refl + 0.1 * (1 + np.cos(2 * np.pi * c.V)) + 0.04 * c.grain())


def _tyre(c: _Ctx) -> np.ndarray:
    tread = _lines(c.U, 16, 0.2) * _box_mask(c.V, 0.1, 0.9, 0.02)
    return _shade((0.11, 0.11, 0.12), (1 + 0.15 * c.grain()) * (1 - 0.5 * tread) + 0.3 * _box_mask(c.V, 0.45, 0.55, 0.02))


def _barrier(c: _Ctx) -> np.ndarray:
    joints = _lines(c.U, 1, 0.006)
    stain = np.clip(c.noise(1, 6, (1.0, 0.3)), 0, None) * (c.V ** 2)
    lum = (0.72 + 0.06 * c.grain() + 0.04 * c.noise(4, 20)) * (1 - 0.45 * joints) * (1 - 0.2 * stain)
    return _shade((0.95, 0.94, 0.9), lum)


def _guardrail(c: _Ctx) -> np.ndarray:
    corr = np.cos(2 * np.pi * c.V * 2)  # two corrugations across the rail
    bolts = (_box_mask(c.U * 4 % 1.0, 0.48, 0.52, 0.01) * _box_mask(c.V, 0.45, 0.55, 0.01))
    lum = (0.6 + 0.18 * corr + 0.05 * c.grain() + 0.04 * c.noise(1, 6)) * (1 - 0.4 * bolts)
    return _shade((0.92, 0.94, 0.96), lum)


def _sign(c: _Ctx) -> np.ndarray:
    border = 1 - _box_mask(c.U, 0.07, 0.93, 0.01) * _box_mask(c.V, 0.07, 0.93, 0.01)
    glyph = (c.noise(3, 10) > 0.7) * _box_mask(c.U, 0.18, 0.82, 0.01) * _box_mask(c.V, 0.2, 0.8, 0.01)
    lum = (0.7 + 0.04 * c.grain()) * (1 + 0.35 * border) * (1 + 0.4 * glyph)
    return _shade((1.0, 1.0, 1.0), lum)


_MAKERS: dict[str, Callable[[_Ctx], np.ndarray]] = {
    "asphalt": _asphalt, "lane_marking": _lane_marking, "sidewalk": _sidewalk, "kerb": _kerb,
    "grass": _grass, "gravel": _gravel, "plaza": _plaza, "brick": _brick,
    "facade_windows_a": _facade_a, "facade_windows_b": _facade_b, "facade_windows_c": _facade_c,
    "facade_glass": _facade_glass, "shopfront": _shopfront, "house_siding": _house_siding,
    "roof_tiles": _roof_tiles, "roof_flat": _roof_flat, "foliage": _foliage, "bark": _bark,
    "hedge": _hedge, "metal_pole": _metal_pole, "car_paint": _car_paint, "car_glass": _car_glass,
    "tyre": _tyre, "barrier_concrete": _barrier, "guardrail": _guardrail, "sign": _sign,
    "house_windows": _house_windows,
}
assert set(_MAKERS) == set(MATERIALS), "every material of scenes.materials.TABLE needs its texture maker"


def make_textures(rng: np.random.Generator, size: int = 256) -> tuple[np.ndarray, list[str]]:
    """Generate every material texture.

    rng:  explicit generator (the only source of randomness; same state -> same bytes).
    size: S, texture edge in pixels, one of TEXTURE_SIZES.
    Returns (textures (L, S, S, 3) uint8 sRGB, materials list of L names == list(MATERIALS)).
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if isinstance(size, bool) or size not in TEXTURE_SIZES:
        raise ValueError(f"size must be one of {TEXTURE_SIZES}, got {size!r}")
    ctx = _Ctx(rng, int(size))
    out = np.empty((len(MATERIALS), size, size, 3), np.uint8)
    for i, name in enumerate(MATERIALS):
        img = _MAKERS[name](ctx)
        out[i] = np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)
    return out, list(MATERIALS)
