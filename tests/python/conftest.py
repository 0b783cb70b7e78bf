"""Shared pytest set-up for the Python suite."""

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """2 shared cores (CI and dev machines): one intra-op thread per test keeps the suite from oversubscribing them
    while Rust builds or training run beside it; restored afterwards for tests that measure thread counts."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
