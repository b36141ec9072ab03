"""Fixtures shared by the mcdp tests."""
from __future__ import annotations

import pytest
import torch


@pytest.fixture
def one_thread():
    """Run a test on one torch thread (deterministic, no oversubscription on shared CPUs)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def ds(tiny_dataset):
    """The tiny dataset (tests/conftest.py), opened."""
    from synth.open import open_dataset

    return open_dataset(tiny_dataset)
