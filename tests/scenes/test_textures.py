"""Textures: shape/dtype, determinism, seamless tiling, local contrast."""
import numpy as np
import pytest

from scenes.textures import LAYER, MATERIALS, TILE_M, make_textures, uv_scale_for

FLAT_OK = {"car_glass", "tyre"}  # dark, smooth on purpose


@pytest.fixture(scope="module")
def tex():
    return make_textures(np.random.default_rng(0), size=128)


def test_shape_names_determinism(tex):
    t, names = tex
    assert t.shape == (len(MATERIALS), 128, 128, 3) and t.dtype == np.uint8
    assert names == list(MATERIALS)
    assert all(LAYER[n] == i for i, n in enumerate(names))
    t2, _ = make_textures(np.random.default_rng(0), size=128)
    assert np.array_equal(t, t2)
    t3, _ = make_textures(np.random.default_rng(1), size=128)
    assert not np.array_equal(t, t3)


def test_seamless_tiling(tex):
    t, names = tex
    for i, name in enumerate(names):
        g = t[i].astype(np.float64).mean(-1)
        # mean jump across each interior column/row boundary vs across the wrap-around boundary:
        # a seam is a jump stronger than any the pattern itself contains (board edges, mortar)
        col_jumps = np.abs(np.diff(g, axis=1)).mean(axis=0)
        row_jumps = np.abs(np.diff(g, axis=0)).mean(axis=1)
        seam_dx = np.abs(g[:, 0] - g[:, -1]).mean()
        seam_dy = np.abs(g[0] - g[-1]).mean()
        assert seam_dx <= 1.1 * col_jumps.max() + 1.0, name
        assert seam_dy <= 1.1 * row_jumps.max() + 1.0, name
        # and for noise-like materials the seam is as smooth as a typical interior boundary
        if name in ("asphalt", "grass", "gravel", "foliage", "hedge", "bark", "car_paint", "roof_flat"):
            assert seam_dx < 1.5 * np.median(col_jumps) + 1.0, name
            assert seam_dy < 1.5 * np.median(row_jumps) + 1.0, name


def test_local_contrast(tex):
    t, names = tex
    from numpy.lib.stride_tricks import sliding_window_view
    for i, name in enumerate(names):
        if name in FLAT_OK:
            continue
        g = t[i].astype(np.float64).mean(-1)
        std3 = sliding_window_view(np.pad(g, 1, mode="wrap"), (3, 3)).std(axis=(-1, -2))
        assert np.mean(std3 > 2.0) > 0.7, f"{name}: too little local contrast"


def test_uv_scale_and_errors():
    assert set(TILE_M) == set(MATERIALS)
    su, sv = uv_scale_for("brick")
    assert su > 0 and sv > 0
    with pytest.raises(ValueError, match="unknown material"):
        uv_scale_for("nope")
    with pytest.raises(ValueError, match="size"):
        make_textures(np.random.default_rng(0), size=100)
    with pytest.raises(ValueError, match="rng"):
        make_textures(0, size=128)


@pytest.mark.parametrize("dt", [np.float32, np.float64])
def test_shade_and_mix_are_their_broadcast_definitions_bit_for_bit(dt):
    """`_shade` and `_mix` compute channel by channel for speed; every texture byte depends on them
    giving exactly the values (and dtype) of the broadcast expressions they replace."""
    from scenes.patterns import mix as _mix, shade as _shade

    rng = np.random.default_rng(3)
    amount = (1 + 0.2 * rng.standard_normal((32, 48))).astype(dt)
    base = (0.45, 0.42, 0.22)
    ref = np.asarray(base, np.float32)[None, None, :] * amount[..., None]
    got = _shade(base, amount)
    assert got.dtype == ref.dtype and np.array_equal(got, ref)
    a = _shade(base, amount.astype(np.float32))
    b = _shade((0.2, 0.3, 0.1), amount)
    t = np.clip(amount - 1, 0, 1)
    ref = a * (1.0 - t[..., None]) + b * t[..., None]
    got = _mix(a, b, t)
    assert got.dtype == ref.dtype and np.array_equal(got, ref)
