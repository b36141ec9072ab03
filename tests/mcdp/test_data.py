"""Tests for mcdp.data's frame cache: the same pixels as a read from disk, and bounded."""
import numpy as np

from mcdp.data import RigReader


def test_frame_cache_returns_the_disk_pixels_and_respects_its_bound(ds):
    seq = list(ds.split("train"))[0]
    nocache = RigReader(ds, 32, 48, cache_bytes=0)
    one = RigReader(ds, 32, 48, cache_bytes=len(ds.camera_names) * 3 * 32 * 48)  # room for one frame
    big = RigReader(ds, 32, 48)
    for frame in (0, 1, 0, 2, 1):
        ref = nocache.rgb(seq, frame)
        for r in (one, big):
            got = r.rgb(seq, frame)
            assert got.dtype == np.float32 and np.array_equal(got, ref)
    assert len(nocache._cache) == 0
    assert list(one._cache) == [(seq, 0)] and one._cached_bytes <= one.cache_bytes
    assert len(big._cache) == 3
    got = big.rgb(seq, 0)
    got[:] = 0  # a caller writing into the returned array does not change the cache
    assert np.array_equal(big.rgb(seq, 0), nocache.rgb(seq, 0))


def test_each_camera_is_resized_from_its_own_size_and_its_K_scaled_by_its_own_factors(fake_dataset):
    """Cameras of different sizes (rig.cameras.<CAM>.width): every camera reaches the training size, and
    each K is diag(sx, sy, 1) K with that camera's own factors (here the aspect changes too)."""
    from mcdp.data import RigDataset, scaled_K

    fake = fake_dataset(scale=(1, 2))  # CAM_FRONT 16x12, CAM_FRONT_RIGHT 32x24
    h, w = 6, 16
    r = RigReader(fake, h, w)
    assert r.rgb("s_train", 0).shape == (2, 3, h, w) and r.mask.shape == (2, 1, h, w)
    for c, cam in enumerate(fake.cameras):
        sx, sy = w / cam.width, h / cam.height  # CAM_FRONT (1, 1/2), CAM_FRONT_RIGHT (1/2, 1/4)
        want = np.diag([sx, sy, 1.0]) @ cam.K
        assert np.allclose(r.K[c], want) and np.allclose(r.K[c], scaled_K(cam.K, (cam.height, cam.width), (h, w)))
    # the same field of view at both sizes: the same K at the training size
    assert np.allclose(r.K[0], r.K[1]) and np.allclose(r.K[0], [[20, 0, 8], [0, 10, 3], [0, 0, 1]])
    item = RigDataset(fake, "train", h, w)[0]
    assert item["rgb"].shape == (2, 3, 3, h, w) and item["K"].shape == (2, 3, 3) and item["mask"].shape == (2, 1, h, w)
