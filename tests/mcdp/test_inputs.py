"""mcdp.inputs: the typed input of every network (DepthInput), a training step's batch (RigBatch) and the
optional fields a network declares."""
import numpy as np
import pytest
import torch

from mcdp.data import RigDataset, collate
from mcdp.inputs import DepthInput, InputField, RigBatch


def _sample(n: int = 3, h: int = 4, w: int = 6, k: float = 0.0) -> dict:
    return {"rgb": torch.full((n, 3, 3, h, w), k), "K": torch.eye(3).expand(n, 3, 3), "T_ego_cam": torch.eye(4).expand(n, 4, 4),
            "mask": torch.ones(n, 1, h, w), "T_world_ego": torch.eye(4).expand(3, 4, 4),
            "seq_index": torch.tensor(0), "frame": torch.tensor(1),
            "fields": {"a": torch.full((n,), k), "b": torch.full((n, 1, h, w), k + 1)}}


def test_collate_stacks_samples_and_their_fields_and_frame_t_is_the_network_input():
    batch = collate([_sample(k=0.0), _sample(k=1.0)])
    assert isinstance(batch, RigBatch) and batch.rgb.shape == (2, 3, 3, 3, 4, 6)
    assert batch.fields["a"].tolist() == [[0.0] * 3, [1.0] * 3] and batch.fields["b"].shape == (2, 3, 1, 4, 6)
    nbr = torch.tensor([[2, 1], [0, 2], [1, 0]])
    declared = (InputField("a", lambda r, s, f: None), InputField("b", lambda r, s, f: None), InputField("c", None))
    inp = batch.depth_input(nbr, declared)
    assert inp.rgb.shape == (2, 3, 3, 4, 6) and torch.equal(inp.rgb, batch.rgb[:, :, 1]) and inp.nbr is nbr
    assert set(inp.fields) == {"a", "b"} and inp.get("a") is batch.fields["a"] and inp.get("c") is None
    other = torch.zeros_like(batch.rgb)
    assert torch.equal(batch.depth_input(nbr, declared, rgb=other).rgb, other[:, :, 1])  # e.g. colour-augmented
    # the one constructor (`DepthInput.filled`) takes the declared fields only: a batch's value no field declares
    with pytest.raises(ValueError, match="input field 'b' is not declared \\(declared: a, c\\)"):
        batch.depth_input(nbr, (declared[0], declared[2]))
    moved = batch.to("cpu")
    assert isinstance(moved, RigBatch) and torch.equal(moved.fields["b"], batch.fields["b"])


def test_the_cut_empties_only_the_fields_that_carry_other_cameras():
    own = InputField("a", lambda r, s, f: np.zeros(3))
    theirs = InputField("b", lambda r, s, f: np.zeros(3), neighbours=True, truth=True)
    inp = DepthInput(torch.rand(1, 3, 3, 4, 6), torch.eye(3).expand(1, 3, 3, 3), torch.eye(4).expand(1, 3, 4, 4),
                     torch.ones(1, 3, 1, 4, 6), torch.tensor([[2, 1], [0, 2], [1, 0]]),
                     {"a": torch.ones(1, 3), "b": torch.ones(1, 3)}, (own, theirs))
    cut = inp.cut()
    assert (cut.nbr == -1).all() and (inp.nbr >= 0).all()  # a new input: the original is unchanged
    assert set(cut.fields) == {"a"} and set(inp.fields) == {"a", "b"}


def test_a_sample_holds_the_fields_its_network_declares_and_no_other(ds):
    calls = []

    def read(reader, seq, frame):
        calls.append((seq, frame))
        return np.arange(len(reader.cam_names), dtype=np.float64) + frame

    f = InputField("frame_plus", read, "(N,)")
    plain, filled = RigDataset(ds, "train", 16, 24), RigDataset(ds, "train", 16, 24, (f,))
    assert plain[0]["fields"] == {} and not calls
    item = filled[0]
    seq, t = filled.seqs[filled.samples[0][0]], filled.samples[0][1]
    assert calls == [(seq, t)] and item["fields"]["frame_plus"].dtype == torch.float32
    assert item["fields"]["frame_plus"].tolist() == [float(c + t) for c in range(len(ds.camera_names))]
