"""Small shared data sets for the core tests (all seeded; a few hundred rows at most)."""

from __future__ import annotations

import numpy as np
import pytest
import torch


def two_blobs(n_per_blob: int = 150, seed: int = 0) -> np.ndarray:
    """Two 2-D Gaussian blobs ``(2·n_per_blob, 2)`` float64."""
    rng = np.random.RandomState(seed)
    a = rng.randn(n_per_blob, 2) * 0.3
    b = rng.randn(n_per_blob, 2) * 0.3 + np.array([2.0, 1.0])
    return np.vstack([a, b])


@pytest.fixture(autouse=True)
def _one_intra_op_thread():
    """Run each core test with one intra-op thread, then restore the previous setting.

    The tensors here are tiny, so threads only add OpenMP barriers; with ``-n 2`` on two cores each
    xdist worker's threads oversubscribe the machine and a barrier can wait a whole scheduler slice:
    measured 2.4 s vs 0.06 s for 60 Adam steps on ``som.loss``. Multi-threaded determinism is still
    checked where it matters (``test_som_contract.py`` sets 2 threads explicitly there).
    """
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def blobs() -> np.ndarray:
    """300 points from two Gaussian blobs, float64 ``(300, 2)``."""
    return two_blobs()


@pytest.fixture
def x3() -> torch.Tensor:
    """240 points in three tight 3-D clusters, float32 ``(240, 3)``.

    Clustered on purpose: a random initialisation in the bounding box is then clearly worse than a
    trained map, so "training lowers the quantization error" is a real test.
    """
    g = torch.Generator().manual_seed(3)
    centres = torch.tensor([[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 1.0]])
    return centres[torch.arange(240) % 3] + 0.08 * torch.randn(240, 3, generator=g)
