"""``python -m experiments.synth_gallery``: one picture per family of the synthetic generator.

Each row is one frame: left image, GT disparity, SGBM disparity, instance labels (names, main
object starred). Writes ``docs/gallery/synth_<family>.png`` (at most 1600 px wide).

    python -m experiments.synth_gallery                       # every family, 4 frames, mixed cameras
    python -m experiments.synth_gallery --families stairs --seeds 0 1 2 --out /tmp/g
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _disp_image(ax, d: np.ndarray, vmax: float, title: str) -> None:
    shown = np.where(np.isfinite(d), d, np.nan)
    ax.imshow(shown, cmap="turbo", vmin=0, vmax=vmax, interpolation="nearest")
    ax.set_title(title, fontsize=8)


def plot_frames(frames: list, path: Path) -> Path:
    """Write one figure with a row per :class:`~somtorch.synth.Frame`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ratios = [fr.left.shape[1] / fr.left.shape[2] for fr in frames]  # H / W of each row
    fig_w = 16.0
    fig, axes = plt.subplots(len(frames), 4, figsize=(fig_w, sum(fig_w / 4 * r + 0.3 for r in ratios)),
                             squeeze=False, gridspec_kw={"height_ratios": ratios})
    for row, fr in zip(axes, frames):
        m = fr.meta
        gt = fr.disparity.numpy()
        vmax = float(np.nanmax(np.where(np.isfinite(gt), gt, np.nan)))
        row[0].imshow(fr.left.permute(1, 2, 0).numpy())
        row[0].set_title(f"{m['family']} {m['camera']} seed {m['seed']}: pitch {m['pitch_deg']:.0f}°, "
                         f"h {m['height_m']:.2f} m", fontsize=8)
        _disp_image(row[1], gt, vmax, f"GT disparity (max {vmax:.0f} px)")
        sg = fr.sgbm.numpy()
        valid = np.isfinite(sg) & np.isfinite(gt)
        err = np.median(np.abs(sg[valid] - gt[valid])) if valid.any() else math.nan
        _disp_image(row[2], sg, vmax, f"SGBM (ndisp {fr.ndisp}): {np.isfinite(sg).mean():.0%} valid, "
                                     f"median |err| {err:.2f} px")
        obj = fr.objects.numpy()
        cmap = plt.get_cmap("tab20")
        colours = np.zeros((obj.max() + 1, 3))
        for i in range(1, obj.max() + 1):
            colours[i] = cmap((i - 1) % 20)[:3]
        row[3].imshow(colours[obj], interpolation="nearest")
        row[3].set_title(f"labels: {len(fr.object_info)} object(s)", fontsize=8)
        for o in fr.object_info[:12]:
            ys, xs = np.nonzero(obj == o["id"])
            if xs.size:
                row[3].text(np.median(xs), np.median(ys), ("*" if o["main"] else "") + f"{o['id']} {o['name']}",
                            fontsize=6, color="white", ha="center", va="center",
                            bbox={"facecolor": "black", "alpha": 0.5, "pad": 1, "linewidth": 0})
        for ax in row:
            ax.set_axis_off()
    fig.tight_layout(pad=0.3)
    import io

    from PIL import Image

    buf = io.BytesIO()
    fig.savefig(buf, dpi=100)
    plt.close(fig)
    path.parent.mkdir(parents=True, exist_ok=True)
    # 256 colours: the noisy renders would otherwise make megabyte PNGs
    Image.open(buf).convert("RGB").quantize(256, dither=Image.Dither.NONE).save(path, optimize=True)
    return path


def main(argv: list[str] | None = None) -> None:
    from somtorch.synth import FAMILIES, generate_frame

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--families", nargs="*", default=list(FAMILIES))
    p.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2, 3])
    p.add_argument("--cameras", nargs="*", default=["oakd", "kitti", "middlebury", "oakd"],
                   help="camera of each seed, in turn")
    p.add_argument("--scale", type=float, default=1.0)
    p.add_argument("--out", default=str(ROOT / "docs" / "gallery"))
    a = p.parse_args(argv)
    for fam in a.families:
        cams = [a.cameras[i % len(a.cameras)] for i in range(len(a.seeds))]
        frames = [generate_frame(fam, s, cam, scale=a.scale) for s, cam in zip(a.seeds, cams)]
        print(plot_frames(frames, Path(a.out) / f"synth_{fam}.png"))


if __name__ == "__main__":
    main()
