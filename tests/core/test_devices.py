"""The core SOM on every available device: CUDA rows skip cleanly on a machine without a GPU."""

from __future__ import annotations

import pytest
import torch

from somtorch.core.som import SOM
from somtorch.core.streaming import fit_batch_chunked

DEVICES = ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(),
                                                                reason="no CUDA device on this machine"))]


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("mode", ["batch", "online", "minibatch"])
def test_fit_on_the_device_matches_the_cpu(device, mode):
    x = torch.rand(2000, 3, generator=torch.Generator().manual_seed(0))
    ref = SOM(4, 4, 3, seed=1, ensemble=2)
    ref.initialize(x)
    w0 = ref.weight.detach().clone()
    ref.fit(x, mode=mode, epochs=2, order="sequential", progress=False)
    som = SOM(4, 4, 3, seed=1, ensemble=2, device=device)
    som.weight = w0.to(device)
    som.fit(x.to(device), mode=mode, epochs=2, order="sequential", progress=False)
    assert som.weight.device.type == device
    assert (som.weight.detach().cpu() - ref.weight.detach()).abs().max() < 1e-4
    if device == "cpu":  # the same kernels: the same bits
        assert torch.equal(som.weight, ref.weight)


@pytest.mark.parametrize("device", DEVICES)
def test_chunked_batch_map_on_the_device(device):
    x = torch.rand(3000, 3, generator=torch.Generator().manual_seed(2))
    som = SOM(3, 5, 3, seed=0, device=device)
    som.initialize(x.to(device))
    fit_batch_chunked(som, x, epochs=3, chunk_size=700)  # chunks come from the CPU, moved per chunk
    assert som.weight.device.type == device and torch.isfinite(som.weight).all()
