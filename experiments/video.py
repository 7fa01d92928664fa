"""``python -m experiments.video``: a disparity sequence, each frame's SOM warm-started.

The frames are ``sequence.frames`` (a glob of disparity files, sorted by name; any format
``read_disparity`` reads) or, when that is empty, a synthetic camera pan over the scene of
``data`` (``sequence.width × height`` windows moving ``step_px`` per frame; a masked scene is
scored frame by frame). Runs :class:`somtorch.video.SequenceRunner` and writes ``kept.mp4`` (what
was kept in each frame, at most 640 px wide), ``contact_sheet.png`` (up to 16 frames) and ``metrics.json``
(schema ``somtorch.video/1``: per frame the kept boxes, the reduction, warm / ground re-used, the
stage timings; the frames per second; useful hits where scored) into the Hydra run folder.

    python -m experiments.video                                     # 60-frame pan over the Motorcycle
    python -m experiments.video data=middlebury_motorcycle_q sequence.frames=120 sequence.warm=false
    python -m experiments.video 'sequence.glob=/data/seq/disp_*.png'
"""

from __future__ import annotations

if __name__ == "__main__":  # signals and --help answered before the heavy imports (torch, Hydra)
    from .entry import start

    start("video")

import dataclasses
import glob
import logging
import shutil
import statistics
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import hydra
from hydra.core.config_store import ConfigStore
from hydra.core.hydra_config import HydraConfig
from hydra.utils import to_absolute_path
from omegaconf import DictConfig, OmegaConf

from .cli import CONF
from .schema import RunConfig, register
from somtorch.config import WarmStartConfig

CONF_DIR = str(CONF)
SCHEMA = "somtorch.video/1"
log = logging.getLogger("somtorch.video")


@dataclass
class SequenceConfig(WarmStartConfig):
    """Which frames (``glob`` of disparity files, or a pan over ``data``) plus the warm start of
    :class:`somtorch.config.WarmStartConfig`.

    Attributes:
        glob: disparity files read as frames, in name order (None = a pan over ``data``).
        frames: at most this many frames.
        width: width in px of the pan's window.
        height: height in px of the pan's window.
        step_px: the pan's shift per frame in px.
    """

    glob: Optional[str] = None
    frames: int = 60
    width: int = 1264
    height: int = 720
    step_px: int = 4


@dataclass
class VideoConfig(RunConfig):
    sequence: SequenceConfig = field(default_factory=SequenceConfig)


register()
ConfigStore.instance().store(name="video_schema", node=VideoConfig)


def frames_of(cfg: VideoConfig):
    """The frames, lazily (a file is read when its frame is due; every path checked first)."""
    from .run import load_input
    from somtorch.disparity.io import read_disparity
    from somtorch.disparity.resize import resize_scene
    from somtorch.disparity.scene import scene_from_arrays
    from somtorch.video import pan_sequence

    s = cfg.sequence
    if s.glob:
        files = sorted(glob.glob(to_absolute_path(s.glob)))
        if not files:
            raise FileNotFoundError(f"sequence.glob={s.glob!r} matches no file")
        files = files[: s.frames]
        return (scene_from_arrays(*read_disparity(f), name=Path(f).stem) for f in files), len(files)
    scene = load_input(cfg)
    if scene.width < s.width or scene.height < s.height:  # the pan needs room: enlarge the scene
        f = max(s.width / scene.width, s.height / scene.height) * 1.25
        scene = resize_scene(scene, round(scene.width * f), round(scene.height * f))
    return pan_sequence(scene, s.width, s.height, s.frames, s.step_px), s.frames


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="video")
def main(dcfg: DictConfig) -> dict:
    from .cli import configure_threads

    configure_threads()
    from .cli import interruptible, marked_if_failed
    from .schema import one_line_errors, to_config
    from somtorch.atomic import commit_staged, write_json
    from somtorch.outputs import SequenceWriter
    from somtorch.video import SequenceRunner

    out = Path(HydraConfig.get().runtime.output_dir)
    with marked_if_failed(out), interruptible(out), one_line_errors(log):  # Ctrl-C / kill: one line, FAILED, 130 / 143
        cfg: VideoConfig = to_config(dcfg)
        s = cfg.sequence
        runner = SequenceRunner(cfg, warm=s.warm, warm_epochs=s.warm_epochs, warm_sigma=s.warm_sigma,
                                ground_keep=s.ground_keep, ground_every=s.ground_every)
        frames, n = frames_of(cfg)
        rows, t0 = [], time.perf_counter()
        out.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=out))  # moved in only when complete
        try:
            pictures = SequenceWriter(stage, n)
            summary = _run_frames(cfg, runner, frames, n, rows, pictures)
            pictures_info = pictures.close()
            summary["wall_s"] = time.perf_counter() - t0
            write_json(stage / "metrics.json", {"schema": SCHEMA, "summary": summary, "frames": rows,
                                                "pictures": pictures_info,
                                                "config": OmegaConf.to_container(dcfg, resolve=True)})
            commit_staged(stage, out)
        finally:
            shutil.rmtree(stage, ignore_errors=True)
    scored = [r["useful_hit"] for r in rows if r["useful_hit"] is not None]
    log.info("%d frames, %.1f ms / frame (%.1f fps, first frame excluded)%s; metrics in %s", len(rows),
             summary["median_ms_per_frame"], summary["fps"],
             f", useful hits {summary['useful_hits']}/{len(scored)}" if scored else "", out / "metrics.json")
    print(f"outputs in {out}", flush=True)  # always, --quiet too: where the results are
    return summary


def _run_frames(cfg: VideoConfig, runner, frames, n: int, rows: list, pictures) -> dict:
    """Every frame through ``runner`` (a row of ``rows`` each, its picture into ``pictures``); the summary."""
    from .cli import announce, progress_bar
    from .run import check_resources
    from somtorch import interrupt

    s = cfg.sequence
    bar = progress_bar(n, "frames", "frame")
    for i, scene in enumerate(frames):
        if i == 0:  # every frame has the size of the first: a cold frame, then warm ones
            warm = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, epochs=s.warm_epochs))
            what = f"{n} frames of {scene.width}x{scene.height}"
            est = check_resources([(scene, cfg, 1), (scene, warm if s.warm else cfg, n - 1)], cfg.resources,
                                  f"sequence of {what}")
            announce("video", what, est.seconds)
        interrupt.checkpoint(f"after frame {i}/{n}")
        r = runner.step(scene)
        pictures.add(r.index, scene, r.members[0])
        m = r.members[0]
        rows.append({"frame": r.index, "warm": r.warm, "ground_reused": r.ground_reused,
                     "kept_boxes": [list(a.box) for a in m.kept], "reduction_union": m.reduction.reduction_union,
                     "no_object": m.no_object, "useful_hit": None if m.score is None else m.score.useful_hit,
                     "timings_ms": {k: 1e3 * v for k, v in r.timings.items()}})
        bar.update()
    bar.close()
    per = [sum(r["timings_ms"].values()) for r in rows[1:]] or [sum(rows[0]["timings_ms"].values())]
    scored = [r["useful_hit"] for r in rows if r["useful_hit"] is not None]
    return {"frames": len(rows), "median_ms_per_frame": statistics.median(per),
            "fps": 1e3 / statistics.median(per), "useful_hits": sum(scored) if scored else None,
            "scored_frames": len(scored)}


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, VideoConfig)


if __name__ == "__main__":
    cli()
