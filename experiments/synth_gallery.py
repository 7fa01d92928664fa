"""``python -m experiments.synth_gallery``: one picture per family of the synthetic generator.

Each row is one frame: left image, GT disparity, SGBM disparity, instance labels (names, main
object starred). Writes ``docs/gallery/synth_<family>.png`` (at most 1600 px wide).

    python -m experiments.synth_gallery                       # every family, 4 frames, mixed cameras
    python -m experiments.synth_gallery 'families=[stairs]' 'seeds=[0,1,2]' out=/tmp/g
"""

from __future__ import annotations

if __name__ == "__main__":  # --help before the heavy imports (torch, Hydra)
    from .help import maybe_print_help

    maybe_print_help("synth_gallery")

import logging
import math
from pathlib import Path

import hydra
import numpy as np
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from . import CONF
from .schema import register
from .tool_configs import SynthGalleryConfig

ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = str(CONF)
log = logging.getLogger("somtorch.synth_gallery")
register()


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


def gallery(cfg: SynthGalleryConfig) -> list[Path]:
    """Write one picture per family of ``cfg``; returns their paths."""
    from somtorch.synth import CAMERAS, FAMILIES, generate_frame
    from somtorch.validation import check_choice

    for f in cfg.families:  # every name checked before the first frame is drawn
        check_choice("families", f, FAMILIES)
    for c in cfg.cameras:
        check_choice("cameras", c, CAMERAS)
    if not cfg.seeds or not cfg.cameras or not 0 < cfg.scale <= 1:
        raise ValueError(f"need seeds and cameras and 0 < scale <= 1; got seeds={cfg.seeds}, cameras={cfg.cameras}, "
                         f"scale={cfg.scale}")
    out = Path(to_absolute_path(cfg.out)) if cfg.out else ROOT / "docs" / "gallery"
    written = []
    for fam in cfg.families:
        cams = [cfg.cameras[i % len(cfg.cameras)] for i in range(len(cfg.seeds))]
        frames = [generate_frame(fam, s, cam, scale=cfg.scale) for s, cam in zip(cfg.seeds, cams)]
        written.append(plot_frames(frames, out / f"synth_{fam}.png"))
        log.info("%s", written[-1])
    return written


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="synth_gallery")
def main(dcfg: DictConfig) -> list[Path]:
    from .schema import one_line_errors

    with one_line_errors(log):
        cfg: SynthGalleryConfig = OmegaConf.to_object(dcfg)
        return gallery(cfg)


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, SynthGalleryConfig)


if __name__ == "__main__":
    cli()
