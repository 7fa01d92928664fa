"""Inputs and training data of the learned baseline.

* :func:`prepare_input` turns any disparity map into the network's input: disparity divided by its
  95th percentile over the valid pixels (so a camera's focal length and baseline, which scale all
  disparities by ``f·B``, do not matter), zero at invalid pixels, the valid mask, and (optionally) the
  left image, all area-resized to the network's ``height x width``.
* :func:`synthetic_frames` lists the training frames of a :class:`~somtorch.config.learned.LearnedDataConfig`
  and :func:`build_tensors` renders (or reuses, via :func:`somtorch.synth.ensure_frame`) and prepares
  them. **Only frames of the procedural generator are accepted**: :func:`check_synthetic` refuses a
  folder that lies under a forbidden root (the real data, named by the caller) or that the current
  generator did not write.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F

from somtorch.config.learned import LearnedDataConfig, LearnedModelConfig
from somtorch.validation import SomtorchError, check_tensor

__all__ = ["FrameRef", "RealDataError", "TrainingData", "build_tensors", "check_synthetic", "prepare_input",
           "prepare_target", "synthetic_frames", "tensor_hash"]

PREP_VERSION = 1  # bump when prepare_input / prepare_target change: cached tensors are rebuilt


class RealDataError(SomtorchError, ValueError):
    """A training frame is not a generated frame (it lies in the real data, or no generator wrote it)."""


def _robust_scale(d: torch.Tensor) -> float:
    k = max(1, int(round(0.95 * d.numel())))
    s = float(d.kthvalue(k).values) if d.numel() else 1.0
    return s if s > 0 else 1.0


def prepare_input(disparity: torch.Tensor, valid: torch.Tensor, cfg: LearnedModelConfig,
                  image: torch.Tensor | None = None) -> torch.Tensor:
    """The network's input of one map: normalised disparity, valid mask (, RGB), at ``cfg``'s size.

    Disparity is divided by its 95th percentile over the valid pixels and clipped to [0, 2]; area
    resizing averages valid pixels only, and an output pixel is valid when most of its area is.

    Args:
        disparity: disparity, pixels (values at invalid pixels are ignored).
        valid: True where ``disparity`` holds a value.
        cfg: the network's hyper-parameters (size, whether the image is an input).
        image: the left image, uint8 RGB; required when ``cfg.image``.

    Shape:
        - disparity, valid: :math:`(H, W)`; image: :math:`(3, H, W)`.
        - output: :math:`(C, h, w)`, ``C = cfg.in_channels``, ``(h, w) = (cfg.height, cfg.width)``.
    """
    check_tensor("disparity", disparity, ndim=2)
    check_tensor("valid", valid, ndim=2, dtype=torch.bool)
    if disparity.shape != valid.shape:
        raise ValueError(f"disparity {tuple(disparity.shape)} and valid {tuple(valid.shape)} differ in shape")
    d = disparity.detach().float().cpu()
    v = valid.detach().cpu() & torch.isfinite(d)
    d = torch.where(v, d, torch.zeros_like(d))
    dn = (d / _robust_scale(d[v])).clamp_(0.0, 2.0)
    size = (cfg.height, cfg.width)
    den = F.interpolate(v.float()[None, None], size=size, mode="area")[0, 0]  # (h, w)
    num = F.interpolate((dn * v)[None, None], size=size, mode="area")[0, 0]
    vr = den > 0.5
    dr = torch.where(vr, num / den.clamp_min(1e-6), torch.zeros_like(num))
    chans = [dr, vr.float()]
    if cfg.image:
        if image is None:
            raise ValueError("model.image=true needs the scene's left image; this scene has none")
        check_tensor("image", image, ndim=3, dtype=torch.uint8)
        chans += list(F.interpolate(image.float()[None] / 255.0, size=size, mode="area")[0])
    return torch.stack(chans)


def prepare_target(mask: torch.Tensor, cfg: LearnedModelConfig) -> torch.Tensor:
    """The main object's share of each network pixel (area-resized mask, in [0, 1]).

    Shape:
        mask :math:`(H, W)` bool → :math:`(1, h, w)` float.
    """
    return F.interpolate(mask.float()[None, None], size=(cfg.height, cfg.width), mode="area")[0]


@dataclass(frozen=True)
class FrameRef:
    """One training or held-out frame: generator family, camera, seed and disparity version."""

    family: str
    camera: str
    seed: int
    version: str  # "gt" or "sgbm"
    held_out: bool


def synthetic_frames(cfg: LearnedDataConfig) -> list[FrameRef]:
    """Every frame of ``cfg``: per family x camera, ``frames`` training seeds then ``held_out`` seeds."""
    from somtorch.synth import CAMERAS, FAMILIES
    from somtorch.validation import check_choice

    for f in cfg.families:
        check_choice("data.families", f, FAMILIES)
    for c in cfg.cameras:
        check_choice("data.cameras", c, CAMERAS)
    versions = ("gt", "sgbm") if cfg.sgbm else ("gt",)
    out = []
    for fam in cfg.families:
        for cam in cfg.cameras:
            for i in range(cfg.frames + cfg.held_out):
                out += [FrameRef(fam, cam, cfg.first_seed + i, v, i >= cfg.frames) for v in versions]
    return out


def check_synthetic(folder: str | Path, forbidden: tuple[str | Path, ...] = ()) -> Path:
    """``folder`` if it is a frame the current generator wrote and lies under none of ``forbidden``.

    Raises:
        RealDataError: the folder lies under a forbidden root (the real datasets), or it has no
            ``objects.json`` of this generator version (it was not rendered by :mod:`somtorch.synth`).
    """
    from somtorch.synth.store import generator_version

    p = Path(folder).resolve()
    for root in forbidden:
        r = Path(root).expanduser().resolve()
        if p == r or r in p.parents:
            raise RealDataError(f"{p}: lies under the real data {r}; the learned baseline trains on generated "
                                f"frames only (somtorch.synth)")
    try:
        doc = json.loads((p / "objects.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        doc = {}
    if doc.get("generator") != generator_version() or "family" not in doc:
        raise RealDataError(f"{p}: not a frame of this generator (objects.json with generator "
                            f"{generator_version()}); the learned baseline trains on generated frames only")
    return p


@dataclass
class TrainingData:
    """Prepared frames: inputs, targets, which are held out, and what they are.

    Shape:
        - inputs: :math:`(N, C, h, w)` float32; targets: :math:`(N, 1, h, w)` float32 in [0, 1];
          held_out: :math:`(N,)` bool.
    """

    inputs: torch.Tensor
    targets: torch.Tensor
    held_out: torch.Tensor
    frames: list[FrameRef]

    @property
    def data_hash(self) -> str:
        """16 hex digits of SHA-256 over the tensors: the identity of the data a model saw."""
        return tensor_hash(self.inputs, self.targets, self.held_out)


def tensor_hash(*tensors: torch.Tensor) -> str:
    """16 hex digits of SHA-256 over the tensors' shapes, dtypes and bytes."""
    h = hashlib.sha256()
    for t in tensors:
        t = t.detach().contiguous().cpu()
        h.update(f"{tuple(t.shape)}{t.dtype}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.dtype != torch.bool
                 else t.to(torch.uint8).numpy().tobytes())
    return h.hexdigest()[:16]


def build_tensors(data: LearnedDataConfig, model: LearnedModelConfig, *, root: str | Path | None = None,
                  forbidden: tuple[str | Path, ...] = (), progress: bool = False) -> TrainingData:
    """Render (or reuse from the cache) and prepare every frame of ``data`` for ``model``.

    Args:
        root: the generator's cache (None: :func:`somtorch.synth.cache_root`).
        forbidden: roots no training frame may lie under (the real data); see :func:`check_synthetic`.
        progress: a tqdm bar over the frames.
    """
    from tqdm.auto import tqdm

    from somtorch.disparity import load_scene
    from somtorch.synth.store import VERSIONS, ensure_frame

    refs = synthetic_frames(data)
    inputs, targets = [], []
    for ref in tqdm(refs, desc="frames", unit="frame", disable=not progress):
        folder = check_synthetic(ensure_frame(ref.family, ref.seed, ref.camera, scale=data.scale, root=root), forbidden)
        scene = load_scene(folder, disparity_file=VERSIONS[ref.version])
        main = scene.main_object_mask
        if main is None:  # every generated frame has a main object (id 1)
            raise RealDataError(f"{folder}: no main object in objects.json")
        inputs.append(prepare_input(scene.disparity, scene.valid, model, scene.image))
        targets.append(prepare_target(main, model))
    held = torch.tensor([r.held_out for r in refs], dtype=torch.bool)
    return TrainingData(torch.stack(inputs), torch.stack(targets), held, refs)
