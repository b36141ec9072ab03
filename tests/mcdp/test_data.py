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
