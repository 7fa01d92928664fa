"""Fixtures of the synth tests: hand-made layouts rendered at a small size."""

from __future__ import annotations

import numpy as np
import pytest

from somtorch.synth.builder import Builder, Layout
from somtorch.synth.cameras import CAMERAS, Pose
from somtorch.synth.frame import render_layout
from somtorch.synth.geometry import Material

SIZE = (160, 120)  # (W, H) of the hand-made renders: OAK-D at 1/4


@pytest.fixture
def builder() -> Builder:
    """A builder for the OAK-D camera (texture sized for ~1.5 m)."""
    return Builder(np.random.default_rng(0), CAMERAS["oakd"], 1.5)


@pytest.fixture
def textured():
    """``textured(seed)``: a multi-scale noise material."""
    return lambda seed=0, scale_m=0.3: Material(rgb=(0.6, 0.55, 0.5), texture="noise", scale_m=scale_m, seed=seed)


@pytest.fixture
def render():
    """``render(builder, pose, scale=0.25) -> (RenderedPair, Camera, layout)`` with the OAK-D camera."""
    def go(b: Builder, pose: Pose, scale: float = 0.25):
        cam = CAMERAS["oakd"].camera(scale)
        w, h = CAMERAS["oakd"].size(scale)
        layout = Layout(list(b.prims), list(b.names), pose, (0.3, -0.5, 0.8))
        return render_layout(layout, cam, w, h), cam, layout
    return go


@pytest.fixture(autouse=True)
def one_thread():
    """Render on one thread, as the generator's workers do (two threads are slower on a busy machine)."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
