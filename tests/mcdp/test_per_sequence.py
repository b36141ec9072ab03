"""mcdp.per_sequence: the per-sequence sums a bootstrap resamples give back the evaluation's own figures."""
import math

import numpy as np
import pytest

from mcdp import evaluate as E
from mcdp.per_sequence import REGIONS, per_sequence, resampled

H, W, Z = 12, 16, 10.0


def _pred(seq, frame):
    """A prediction whose error differs by sequence, frame and camera (so a wrong pooling shows)."""
    k = {"s0": 1.0, "s1": 3.0}[seq]
    d = np.full((2, H, W), Z, np.float32)
    d[0] *= 1.0 + 0.05 * k * frame
    d[1, :, : W // 2] *= 1.0 + 0.02 * k
    return {"init": d}


@pytest.mark.parametrize("sc", E.SCALINGS)
def test_all_sequences_give_the_split_figure(fake_dataset, sc):
    m = E.evaluate(fake_dataset(), _pred, "test", E.EvalConfig(), progress=False)["stages"]["final"][sc]
    ps = m["per_sequence"]
    assert set(ps) == set(REGIONS) and set(ps["all"]) == {"s0", "s1"}
    for region, key in (("all", "mean"), ("overlap", "overlap"), ("non_overlap", "non_overlap")):
        want = m[key]["abs_rel"]
        got = resampled(ps[region], ["s0", "s1"])
        assert (math.isnan(want) and math.isnan(got)) or got == pytest.approx(want, rel=1e-12, abs=1e-15)
    # every image counted once per camera: 2 frames per sequence (ends skipped)
    assert ps["all"]["s0"]["n"] == [2, 2]


def test_one_sequence_twice_is_that_sequence_alone(fake_dataset):
    ds = fake_dataset()
    full = E.evaluate(ds, _pred, "test", E.EvalConfig(), progress=False)["stages"]["final"]["none"]
    ps = full["per_sequence"]["all"]

    class OnlyS1(type(ds)):
        def split(self, name):
            return {"test": ["s1"]}.get(name, [])

    alone = E.evaluate(OnlyS1(), _pred, "test", E.EvalConfig(), progress=False)["stages"]["final"]["none"]
    assert resampled(ps, ["s1", "s1"]) == pytest.approx(alone["mean"]["abs_rel"], rel=1e-12)
    assert resampled(ps, ["s1"]) != pytest.approx(resampled(ps, ["s0"]), rel=1e-3)  # the sequences do differ


def test_nan_images_are_left_out_and_counts_checked():
    per_image = {"all": [[{"abs_rel": 0.1}, {"abs_rel": math.nan}, {"abs_rel": 0.3}]]}
    rec = per_sequence(per_image, ["a", "a", "b"])["all"]
    assert rec == {"a": {"sum": [0.1], "n": [1]}, "b": {"sum": [0.3], "n": [1]}}
    assert resampled(rec, ["a", "b"]) == pytest.approx(0.2)
    assert math.isnan(resampled(rec, []))
    with pytest.raises(ValueError, match="camera 0 of region 'all' has 3 images, expected 2"):
        per_sequence(per_image, ["a", "b"])
