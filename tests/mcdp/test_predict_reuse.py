"""Inference does each thing once per sample (`mcdp.predict`): the passes of one sample (as trained, then with the
neighbours cut) read its images once (`Predictor.inputs`) and run the encoder and decoder once (`SameInputs`); every
output is the same bits as a predictor that runs them again, on 1 and 2 torch threads."""
from __future__ import annotations

import pytest
import torch

from mcdp.predict import SameInputs


def _plain(pred):
    """The predictor without the reuse: encoder and decoder run at every call, inputs read at every call."""
    for name in ("encoder", "decoder"):
        del getattr(pred.network, name).forward  # the instance's wrapper; the class's forward again
    pred.inputs = lambda seq, frame, _f=type(pred).inputs: (setattr(pred, "_last_inputs", None), _f(pred, seq, frame))[1]
    return pred


def _depths(out) -> dict:
    return {k: v for k, v in out.items() if isinstance(k, tuple) and k[0] in ("depth", "weights") and v is not None}


@pytest.mark.parametrize("threads", [1, 2])
def test_the_cut_pass_reuses_the_trained_pass_and_gives_the_same_bits(ds, untrained, tmp_path, one_thread, threads):
    torch.set_num_threads(threads)  # one_thread restores the count
    pred = untrained(ds, tmp_path / "m.pt", "mcdp_m2")
    plain = _plain(untrained(ds, tmp_path / "p.pt", "mcdp_m2"))
    enc = pred.network.encoder.forward
    assert isinstance(enc, SameInputs)
    seq = ds.split("test")[0]
    for frame in (1, 2):
        inp = pred.inputs(seq, frame)
        assert pred.inputs(seq, frame) is inp  # the second pass reads nothing again
        trained, cut = pred.forward(inp), pred.forward(inp.cut())
        ref_trained = plain.forward(plain.inputs(seq, frame))
        ref_cut = plain.forward(plain.inputs(seq, frame).cut())
        for mine, ref in ((trained, ref_trained), (cut, ref_cut)):
            assert _depths(mine).keys() == _depths(ref).keys()
            for k, v in _depths(ref).items():
                assert torch.equal(_depths(mine)[k], v), k
        assert not torch.equal(cut["depth", "refine2", 0], trained["depth", "refine2", 0])  # the cut acts
    assert (enc.calls, enc.hits) == (4, 2)  # once per sample, reused by its cut pass
    dec = pred.network.decoder.forward
    assert (dec.calls, dec.hits) == (4, 2)


def test_reuse_only_without_gradients_and_unchanged_outputs():
    lin = torch.nn.Linear(3, 2)
    calls = []

    def fwd(x):
        calls.append(1)
        return [lin(x), 2 * x]

    memo = SameInputs(fwd)
    x = torch.randn(4, 3)
    with torch.no_grad():
        a = memo(x)
        b = memo(x.clone())  # equal values: reused
        assert len(calls) == 1 and b is not a and all(u is v for u, v in zip(a, b))
        memo(x + 1)  # other values: run
        assert len(calls) == 2
        out = memo(x + 1)
        assert len(calls) == 2
        out[1].mul_(3)  # an output changed in place: never handed out again
        memo(x + 1)
        assert len(calls) == 3
        y = x + 1
        memo(y)  # equal to the last inputs: reused
        assert len(calls) == 3
        y.add_(1)  # the input changed in place after the call: the kept copy does not follow it
        memo(y)
        assert len(calls) == 4
    memo(y)
    memo(y)  # with gradients: always run
    assert len(calls) == 6


def test_no_reuse_after_the_weights_change_or_under_inference_mode():
    """The kept outputs are stale once the module's weights change in place (a load, a step under no_grad), and
    inference mode (whose tensors keep no version counter) always runs."""
    lin = torch.nn.Linear(3, 2).eval()  # a module in training mode always runs
    memo = SameInputs(lin.forward)
    x = torch.randn(4, 3)
    with torch.no_grad():
        a = memo(x)
        assert memo(x) is a and memo.hits == 1
        lin.weight.add_(1.0)  # the weights moved: the same input gives another output
        b = memo(x)
        assert memo.hits == 1 and not torch.equal(a, b) and torch.equal(b, lin(x))
        lin.load_state_dict({k: v.clone() for k, v in lin.state_dict().items()})  # a load bumps them too
        memo(x)
        assert memo.hits == 1
    with torch.inference_mode():
        c = memo(x)
        d = memo(x)
    assert memo.hits == 1 and torch.equal(c, d)
