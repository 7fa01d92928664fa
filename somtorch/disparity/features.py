"""Paper step 1a: the input data set — every valid pixel becomes a vector (y, x, d).

How y, x and d are scaled decides what a SOM segment is, so it is explicit here:

* ``normalize="image"`` (default): y and x are divided by ``max(H, W)`` (the image plane keeps its
  aspect ratio, both axes in [0, 1]); d is min-max scaled to [0, 1] over the valid pixels and then
  multiplied by ``d_weight``. With ``d_weight = 1`` a full disparity range weighs as much as the
  longer image side.
* ``normalize="minmax"``: each of y, x, d min-max scaled to [0, 1] independently (the literal reading
  of the paper; ``d_weight`` still multiplies d).
* ``normalize="none"``: raw pixel units (y, x in px, d in px · d_weight).

Negative, non-finite and invalid disparities are removed (their count is reported). The
runtime-optimised mode (OR) trains on a strided subsample (stride 10 on 1264×720 → 127·72 = 9,144 px
here; the paper reports 9,072) while
the full map is still segmented: :func:`make_features` returns both.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from ..config import FeatureConfig
from ..config.options import D_MODES, NORMALIZATIONS  # noqa: F401 (D_MODES: FeatureConfig.d_mode)
from ..validation import check_choice, check_positive, check_positive_int, check_tensor

_F = FeatureConfig  # the defaults of make_features, declared once in somtorch.config


@dataclass
class Features:
    """Pixel vectors of a disparity map and the affine map between pixel and feature units.

    Attributes:
        x: feature vectors ``(N, 3)``: scaled (y, x, d).
        pixels: their pixel coordinates ``(N, 2)`` long (y, x).
        offset, scale: ``features = (pixel_units − offset) · scale`` per column ``(3,)``.
        shape: ``(H, W)`` of the map.
        n_invalid: pixels of the map that were removed (invalid, negative or non-finite).
        stride: subsampling stride used (1 = all valid pixels).
    """

    x: torch.Tensor
    pixels: torch.Tensor
    offset: torch.Tensor
    scale: torch.Tensor
    shape: tuple[int, int]
    n_invalid: int
    stride: int = 1
    mask: torch.Tensor | None = None  # (H, W) bool: which pixels are rows of x (row-major)

    def __len__(self) -> int:
        return int(self.x.shape[0])

    def to_pixel_units(self, v: torch.Tensor) -> torch.Tensor:
        """Feature-space vectors (e.g. SOM weights ``(..., 3)``) back to (y px, x px, d px)."""
        return v / self.scale.to(v) + self.offset.to(v)

    def to_features(self, v: torch.Tensor) -> torch.Tensor:
        """(y px, x px, d px) vectors ``(..., 3)`` to feature space."""
        return (v - self.offset.to(v)) * self.scale.to(v)

    def subsample(self, stride: int) -> Features:
        """The pixels on a ``stride``-grid (y % stride == 0 and x % stride == 0), same scaling."""
        stride = check_positive_int("stride", stride)
        if stride == 1:
            return self
        if self.mask is not None and self.stride == 1:
            # rank of every pixel among the feature rows, read at the strided grid
            rank = torch.cumsum(self.mask.view(-1), 0).view(self.shape) - 1
            on_grid = self.mask[::stride, ::stride]
            keep = torch.masked_select(rank[::stride, ::stride], on_grid)  # = [on_grid], faster
            sub = torch.zeros_like(self.mask)
            sub[::stride, ::stride] = on_grid
        else:
            keep = ((self.pixels[:, 0] % stride == 0) & (self.pixels[:, 1] % stride == 0)).nonzero().view(-1)
            sub = None
        return Features(self.x[keep], self.pixels[keep], self.offset, self.scale, self.shape,
                        self.n_invalid, self.stride * stride, sub)


def make_features(disparity: torch.Tensor, valid: torch.Tensor, *, normalize: str = _F.normalize,
                  d_weight: float = _F.d_weight, image: torch.Tensor | None = None,
                  color_weight: float = _F.color_weight, dtype: torch.dtype = torch.float32) -> Features:
    """Turn the valid pixels of a disparity map into scaled (y, x, d) vectors, row-major order.

    Args:
        disparity: disparity map ``(H, W)`` in px (values at invalid pixels are ignored).
        valid: validity mask ``(H, W)`` bool; negative and non-finite disparities are dropped too.
        normalize: ``"image"``, ``"minmax"`` or ``"none"`` (module docstring).
        d_weight: weight of the disparity axis relative to the image axes.
        image: the left image ``(3, H, W)`` RGB uint8; with ``color_weight > 0`` its Y, Cb, Cr
            (ITU-R BT.601, each in [0, 1]) times ``color_weight`` are appended (the paper's "YIQ
            or YCbCr colour models" future work).
        color_weight: weight of the colour features (0 = off: (y, x, d) only).
        dtype: floating dtype of the vectors.

    Shape:
        returns :class:`Features` with ``x`` ``(N, 3)`` — or ``(N, 6)`` with colour —, N = number
        of usable pixels.

    Raises:
        ValueError: no usable pixel, shapes disagree, unknown ``normalize``.
    """
    check_tensor("disparity", disparity, ndim=2, floating=True)
    check_tensor("valid", valid, ndim=2, dtype=torch.bool)
    if valid.shape != disparity.shape:
        raise ValueError(f"valid has shape {tuple(valid.shape)} but disparity has {tuple(disparity.shape)}")
    check_choice("normalize", normalize, NORMALIZATIONS)
    check_positive("d_weight", d_weight)
    check_positive("color_weight", color_weight, allow_zero=True)
    h, w = disparity.shape
    usable = valid & torch.isfinite(disparity) & (disparity >= 0)
    n = int(usable.sum())
    if n == 0:
        raise ValueError("the disparity map has no valid, finite, non-negative pixel: nothing to train on")
    yx = usable.nonzero()  # (N, 2), row-major
    d = torch.masked_select(disparity, usable)  # = disparity[usable] (row-major), 2-3x faster
    y_range = x_range = d_range = None
    if normalize != "none":
        d_range = (float(d.min()), float(d.max()))
        y_range = (int(yx[0, 0]), int(yx[-1, 0]))  # row-major: first and last rows
        cols = usable.any(0).nonzero()
        x_range = (int(cols[0, 0]), int(cols[-1, 0]))
    offset, scale = feature_scaling((h, w), normalize=normalize, d_weight=d_weight, d_range=d_range,
                                    y_range=y_range, x_range=x_range)
    columns = [yx[:, 0], yx[:, 1], d]
    if color_weight > 0:
        if image is None:
            raise ValueError("color_weight > 0 needs the left image (the scene has none): set color_weight=0")
        check_tensor("image", image, ndim=3, dtype=torch.uint8)
        if tuple(image.shape) != (3, h, w):
            raise ValueError(f"image has shape {tuple(image.shape)}; (3, {h}, {w}) expected")
        columns += list(ycbcr(image[:, usable]))
        offset = torch.cat([offset, torch.zeros(3, dtype=torch.float64)])
        scale = torch.cat([scale, torch.full((3,), float(color_weight), dtype=torch.float64)])
    feats = pixel_features(columns, offset, scale, dtype)
    return Features(feats, yx, offset.to(dtype), scale.to(dtype), (h, w), h * w - n, 1, usable)


def relative_disparity(disparity: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
    """``disparity − reference`` clipped at 0: the height of what stands on a support surface whose
    disparity is ``reference`` (``features.d_mode="plane_residual"``), in disparity px. Pixels behind
    the surface (matching noise, or what it does not hide) get 0, the surface's own level.

    Shape:
        ``disparity``, ``reference`` ``(H, W)`` → ``(H, W)``, the dtype of ``disparity``.

    >>> relative_disparity(torch.tensor([[3.0, 5.0]]), torch.tensor([[4.0, 4.0]]))
    tensor([[0., 1.]])
    """
    return (disparity - reference.to(disparity)).clamp_min_(0)


def feature_scaling(shape: tuple[int, int], *, normalize: str = _F.normalize, d_weight: float = _F.d_weight,
                    d_range: tuple[float, float] | None = None, y_range: tuple[int, int] | None = None,
                    x_range: tuple[int, int] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """The affine map ``features = (pixel units − offset) · scale`` of (y, x, d) for ``normalize``.

    Args:
        shape: ``(H, W)`` of the map.
        d_range: smallest and largest usable disparity (px); needed unless ``normalize="none"``.
        y_range, x_range: first and last row / column holding a usable pixel; needed for ``"minmax"``.

    Shape:
        returns ``offset``, ``scale`` ``(3,)`` float64.

    Every path that turns pixels into features (:func:`make_features` on a whole map,
    :mod:`somtorch.large` on blocks of a memory map) takes its scaling from here.
    """
    if normalize == "none":
        return torch.zeros(3, dtype=torch.float64), torch.tensor([1.0, 1.0, d_weight], dtype=torch.float64)
    d_lo, d_hi = d_range
    d_span = max(d_hi - d_lo, 1e-6)
    if normalize == "image":
        side = float(max(shape) - 1 or 1)
        return (torch.tensor([0.0, 0.0, d_lo], dtype=torch.float64),
                torch.tensor([1.0 / side, 1.0 / side, d_weight / d_span], dtype=torch.float64))
    (y_lo, y_hi), (x_lo, x_hi) = y_range, x_range
    offset = torch.tensor([float(y_lo), float(x_lo), d_lo], dtype=torch.float64)
    span = torch.tensor([float(y_hi - y_lo), float(x_hi - x_lo), d_span], dtype=torch.float64).clamp_min(1e-6)
    return offset, torch.tensor([1.0, 1.0, d_weight], dtype=torch.float64) / span


def pixel_features(columns: list[torch.Tensor], offset: torch.Tensor, scale: torch.Tensor,
                   dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Feature vectors ``(N, D)`` from D pixel-unit columns ``(N,)`` each (y px, x px, d px, …):
    column j is ``(c_j − offset_j) · scale_j`` in ``dtype``, computed column by column (no
    ``(N, D)`` float64 temporary); ``offset``, ``scale`` ``(D,)``."""
    feats = torch.empty(int(columns[0].shape[0]), len(columns), dtype=dtype)
    for j, col in enumerate(columns):
        torch.mul(col.to(dtype) - float(offset[j]), float(scale[j]), out=feats[:, j])
    return feats


def ycbcr(rgb: torch.Tensor) -> torch.Tensor:
    """ITU-R BT.601 Y, Cb, Cr of uint8 RGB values, each in [0, 1].

    Shape:
        ``rgb`` ``(3, ...)`` → ``(3, ...)`` float64.
    """
    r, g, b = (c.double() / 255.0 for c in rgb)
    y = 0.299 * r + 0.587 * g + 0.114 * b
    return torch.stack([y, 0.5 + (b - y) / 1.772, 0.5 + (r - y) / 1.402])