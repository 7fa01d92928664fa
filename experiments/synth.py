"""``python -m experiments.synth`` / ``somtorch-synth``: generated stereo frames into the cache.

Writes ``n`` frames (seeds ``start .. start + n - 1``) per family x camera into
``<cache>/<family>_<camera>/<seed:05d>/`` (the Middlebury layout ``load_scene`` reads; see
``docs/synth.md``), skipping frames that are present and made by this generator version (the
``manifest.json`` of each data set lists the frames and the generator's hash). One frame per task on
``workers`` processes, each on one thread. Last, it prints the corpus digest: one hash over the bytes of
every requested frame (each frame's own digest is its manifest entry's ``digest``), so that two
machines can check that they render the same corpus without copying it.

    python -m experiments.synth 'families=[stairs,garden]' 'cameras=[oakd]' n=50
    python -m experiments.synth 'cameras=[oakd,kitti,middlebury]' n=40 workers=2
    python -m experiments.synth n=4 scale=0.5 cache=/tmp/synth      # small previews elsewhere
"""

from __future__ import annotations

if __name__ == "__main__":  # signals and --help answered before the heavy imports (torch, Hydra)
    from .entry import start

    start("synth")

import logging
import time
from pathlib import Path

import hydra
from omegaconf import DictConfig

from . import CONF
from .schema import register
from .synth_config import SynthConfig

CONF_DIR = str(CONF)
log = logging.getLogger("somtorch.synth")
register()


def _init_worker() -> None:
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)


def frame_digest(folder: str | Path) -> str:
    """16 hex digits of SHA-256 over a written frame's files (name and bytes, sorted by name;
    ``objects.json`` without its ``generator`` hash, which names the code, not the frame): two
    machines that render a seed into the same bytes give the same digest, so corpora can be compared
    without copying them.

    Raises:
        FileNotFoundError: ``folder`` holds no generated frame (no ``disp0GT.pfm``).
    """
    import json

    from .metrics_schema import files_digest

    def read(f: Path) -> bytes:
        if f.name != "objects.json":
            return f.read_bytes()
        doc = json.loads(f.read_bytes())
        doc.pop("generator", None)
        return json.dumps(doc, sort_keys=True).encode()

    folder = Path(folder)
    if not (folder / "disp0GT.pfm").is_file():
        raise FileNotFoundError(f"{folder}: no generated frame (disp0GT.pfm missing)")
    return files_digest(folder, (p for p in folder.iterdir() if p.is_file()), read)


def corpus_digest(digests: dict[str, str]) -> str:
    """16 hex digits of SHA-256 over ``{"<dataset>/<seed:05d>": frame digest}``, in sorted order."""
    import hashlib

    h = hashlib.sha256()
    for key in sorted(digests):
        h.update(f"{key} {digests[key]}\n".encode())
    return h.hexdigest()[:16]


def rendered_with() -> str:
    """The libraries whose code makes a frame's bytes, as one line (each manifest entry's
    ``rendered_with``): where two machines' digests differ, the entries say whether their numpy,
    OpenCV, torch or torch's CPU kernels (``torch.backends.cpu.get_cpu_capability``) did."""
    import cv2
    import numpy as np
    import torch

    return (f"numpy {np.__version__}, opencv {cv2.__version__}, torch {torch.__version__} "
            f"({torch.backends.cpu.get_cpu_capability()})")


def _make(family: str, camera: str, seed: int, scale: float, root: str) -> dict:
    """Generate and write one frame; its manifest entry (with its digest and the seconds it took)."""
    from somtorch.synth.frame import generate_frame
    from somtorch.synth.store import frame_dir, manifest_entry, write_frame

    t0, c0 = time.perf_counter(), time.process_time()
    frame = generate_frame(family, seed, camera, scale=scale)
    folder = write_frame(frame, frame_dir(family, camera, seed, scale, root))
    return {**manifest_entry(frame), "digest": frame_digest(folder), "rendered_with": rendered_with(),
            "wall_s": round(time.perf_counter() - t0, 3),
            "cpu_s": round(time.process_time() - c0, 3)}


def generate(cfg: SynthConfig, progress: bool = True) -> dict:
    """Generate the missing or stale frames of ``cfg``; a summary (counts, seconds, per-camera rates)."""
    from concurrent.futures import as_completed

    from tqdm.auto import tqdm

    from somtorch.interrupt import worker_pool
    from somtorch.synth import CAMERAS, FAMILIES
    from somtorch.synth.store import cache_root, dataset_dir, is_current, read_manifest, write_manifest
    from somtorch.validation import check_choice

    for f in cfg.families:
        check_choice("families", f, FAMILIES)
    for c in cfg.cameras:
        check_choice("cameras", c, CAMERAS)
    if cfg.n < 0 or cfg.start < 0 or cfg.workers < 1 or not 0 < cfg.scale <= 1:
        raise ValueError(f"need n >= 0, start >= 0, workers >= 1 and 0 < scale <= 1; got n={cfg.n}, "
                         f"start={cfg.start}, workers={cfg.workers}, scale={cfg.scale}")
    root = str(Path(cfg.cache).expanduser() if cfg.cache else cache_root())
    manifests, todo = {}, []
    for fam in cfg.families:
        for cam in cfg.cameras:
            ds = dataset_dir(fam, cam, cfg.scale, root)
            manifests[(fam, cam)] = read_manifest(ds)["frames"]
            todo += [(fam, cam, s) for s in range(cfg.start, cfg.start + cfg.n)
                     if not is_current(ds, s, {"frames": manifests[(fam, cam)]})]
    total = len(cfg.families) * len(cfg.cameras) * cfg.n
    log.info("%d of %d frames to generate into %s (%d present)", len(todo), total, root, total - len(todo))
    t0, seconds = time.perf_counter(), {}
    if todo:
        with worker_pool(cfg.workers, initializer=_init_worker) as ex:  # Ctrl-C / kill: the workers end at once
            jobs = {ex.submit(_make, fam, cam, s, cfg.scale, root): (fam, cam, s) for fam, cam, s in todo}
            for fut in tqdm(as_completed(jobs), total=len(jobs), unit="frame", disable=not progress):
                fam, cam, s = jobs[fut]
                entry = fut.result()
                seconds.setdefault(cam, []).append((entry.pop("wall_s"), entry.pop("cpu_s")))
                manifests[(fam, cam)][f"{s:05d}"] = entry
                write_manifest(dataset_dir(fam, cam, cfg.scale, root), manifests[(fam, cam)])
    wall = time.perf_counter() - t0
    # the bytes of every requested frame, one digest (a frame cached before digests were recorded
    # gets its digest from its files now)
    digests = {}
    for (fam, cam), frames in manifests.items():
        ds, dirty = dataset_dir(fam, cam, cfg.scale, root), False
        for s in range(cfg.start, cfg.start + cfg.n):
            entry = frames[f"{s:05d}"]
            if "digest" not in entry:
                entry["digest"], dirty = frame_digest(ds / f"{s:05d}"), True
            digests[f"{ds.name}/{s:05d}"] = entry["digest"]
        if dirty:
            write_manifest(ds, frames)
    summary = {"root": root, "generated": len(todo), "present": total - len(todo), "wall_s": round(wall, 1),
               "digest": corpus_digest(digests),
               "frames_per_min": round(60 * len(todo) / wall, 1) if todo else None,
               # per camera: mean seconds of one frame in a worker, wall clock and CPU (one thread)
               "wall_s_per_frame": {c: round(sum(w for w, _ in v) / len(v), 3) for c, v in seconds.items()},
               "cpu_s_per_frame": {c: round(sum(u for _, u in v) / len(v), 3) for c, v in seconds.items()}}
    log.info("%s", summary)
    log.info("corpus digest %s over %d frames (the same on another machine: the same bytes; per frame: each "
             "manifest.json's \"digest\", and what rendered it: \"rendered_with\"; here %s)", summary["digest"],
             len(digests), rendered_with())
    return summary


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="synth")
def main(dcfg: DictConfig) -> dict:
    from .cli import show_progress
    from .schema import one_line_errors, to_config

    with one_line_errors(log):
        cfg: SynthConfig = to_config(dcfg)
        return generate(cfg, progress=show_progress())


def cli() -> None:
    """Console entry: the overrides are checked against the schema first ("did you mean")."""
    from .cli import run_checked

    run_checked(main, SynthConfig)


if __name__ == "__main__":
    cli()
