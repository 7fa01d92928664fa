"""The dataset registry: every development frame, grouped by dataset, declared once in
``conf/datasets.yaml`` and expanded here.

A *frame* is one disparity map with its labelled objects (a :class:`FrameSpec`); a *dataset* is a
named group of frames from one source (a camera, a benchmark, a generator family × camera). The
validation protocol leaves one dataset out at a time, the studies and the quality tests select
frames by dataset or name, and nothing else lists scenes.

    from experiments.datasets import frames, load_frame
    specs = frames(datasets=["oakd", "middlebury_2005_2006"])       # or names=[...], real=True
    scene = load_frame(specs[0], data_dir="../shared/data")
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Optional

from . import CONF  # the clone's conf/, or the one shipped in the wheel

REGISTRY = CONF / "datasets.yaml"
LABELS = CONF / "labels"

__all__ = ["DatasetSpec", "FrameSpec", "corpus_dir", "datasets", "frames", "load_frame", "missing_corpus"]


@dataclass(frozen=True)
class FrameSpec:
    """One development frame.

    ``folder`` is relative to the data root (``paths.data_dir``), or, for a synthetic frame, to the
    corpus cache (:func:`corpus_dir`). ``disparity``: ``"gt"`` (the folder's own map), a file of the
    folder (e.g. KITTI's ``disp_est.png``), or ``"sgbm"`` (computed from ``left`` / ``right`` with
    our default SGBM and ``ndisp`` disparities). ``labels``: a polygon label file under
    ``conf/labels`` giving the objects where the folder has no mask. ``junk``: a synthetic failure
    class (:func:`experiments.scenes.add_junk`). ``group``: the underlying scene (the versions of
    one scene share it; the protocol's bootstrap resamples groups, not frames). ``camera``: the
    generator camera (:data:`somtorch.synth.CAMERAS`) that stands for the rig the frame was taken
    with (the dataset's ``camera:`` key; a synthetic frame's own), or None: a trained baseline's
    leave-one-dataset-out fold leaves that camera's generated frames out of its training.
    """

    name: str
    dataset: str
    real: bool
    folder: str
    disparity: str = "gt"
    left: Optional[str] = None
    right: Optional[str] = None
    ndisp: int = 128
    junk: Optional[str] = None
    labels: Optional[str] = None
    group: str = ""
    synthetic: bool = False
    camera: Optional[str] = None

    @property
    def computed(self) -> bool:
        """True unless the map is the folder's own (ground truth or the device's)."""
        return self.disparity != "gt" or self.junk is not None


@dataclass(frozen=True)
class DatasetSpec:
    """A named group of frames; ``real`` datasets decide the protocol, the others are evidence."""

    name: str
    real: bool
    frames: tuple[FrameSpec, ...]


def corpus_dir() -> Path:
    """The generated corpus: ``$SOMTORCH_CORPUS``, else ``$SOMTORCH_CACHE/corpus``, else
    ``~/.cache/somtorch/corpus`` (rebuilt by ``python -m experiments.synth``; never committed)."""
    if os.environ.get("SOMTORCH_CORPUS"):
        return Path(os.environ["SOMTORCH_CORPUS"]).expanduser()
    base = os.environ.get("SOMTORCH_CACHE") or Path.home() / ".cache" / "somtorch"
    return Path(base).expanduser() / "corpus"


_FRAME_KEYS = {"name", "folder", "disparity", "left", "right", "ndisp", "junk", "labels", "group"}


def _check_keys(where: str, d: Any, allowed: set[str]) -> None:
    if not isinstance(d, dict):
        raise ValueError(f"{REGISTRY}: {where} must be a mapping; got {type(d).__name__}")
    extra = sorted(set(d) - allowed)
    if extra:
        raise ValueError(f"{REGISTRY}: {where}: unknown key(s) {extra}; known: {sorted(allowed)}")


def _labelled_frames(name: str, real: bool, body: dict[str, Any]) -> list[FrameSpec]:
    """A GT and an SGBM frame per label file of ``conf/labels/<labelled>/`` (``no_object`` files out)."""
    out = []
    for path in sorted((LABELS / body["labelled"]).glob("*.json")):
        doc = json.loads(path.read_text())
        if doc.get("no_object"):
            continue
        scene_folder = Path(doc["scene"]).name
        folder = f"{body['folder']}/{scene_folder}"
        left = doc.get("image", "view1.png")
        right = {"view1.png": "view5.png", "im2.png": "im6.png"}.get(left)
        if right is None:
            raise ValueError(f"{path}: no right view known for image {left!r}")
        base = scene_folder.lower()
        labels = f"{body['labelled']}/{path.name}"
        common = {"dataset": name, "real": real, "folder": folder, "labels": labels, "group": base,
                  "camera": body.get("camera")}
        out.append(FrameSpec(name=f"mb_{base}", disparity="gt", **common))
        out.append(FrameSpec(name=f"mb_{base}_sgbm", disparity="sgbm", left=left, right=right,
                             ndisp=int(body.get("ndisp", 128)), **common))
    return out


def _synthetic_datasets(body: dict[str, Any]) -> list[DatasetSpec]:
    """One dataset per family x camera, seeds 0..seeds-1, each in a GT and an SGBM version; the
    families of ``noisy`` also as their GT with ``noisy.junk`` added (a dense sensor's noise)."""
    _check_keys("synthetic", body, {"families", "cameras", "seeds", "noisy"})
    noisy = body.get("noisy") or {}
    if noisy:
        from .scenes import check_junk_kind

        _check_keys("synthetic.noisy", noisy, {"families", "junk"})
        check_junk_kind(noisy["junk"])
    out = []
    for fam in body["families"]:
        for cam in body["cameras"]:
            name = f"synth_{fam}_{cam}"
            specs = []
            for seed in range(int(body["seeds"])):
                folder = f"{fam}_{cam}/{seed:05d}"
                for version in ("gt", "sgbm"):
                    specs.append(FrameSpec(
                        name=f"{name}_{seed:02d}" + ("_sgbm" if version == "sgbm" else ""), dataset=name,
                        real=False, folder=folder, disparity="gt" if version == "gt" else "disp_sgbm.pfm",
                        group=f"{name}_{seed:02d}", synthetic=True, camera=cam))
                if fam in noisy.get("families", ()):
                    specs.append(FrameSpec(name=f"{name}_{seed:02d}_noisy", dataset=name, real=False,
                                           folder=folder, junk=noisy["junk"], group=f"{name}_{seed:02d}",
                                           synthetic=True, camera=cam))
            out.append(DatasetSpec(name, False, tuple(specs)))
    return out


@lru_cache(maxsize=1)
def _registry() -> tuple[DatasetSpec, ...]:
    import yaml

    doc = yaml.safe_load(REGISTRY.read_text())
    out: list[DatasetSpec] = []
    for name, body in doc.items():
        _check_keys(name, body, {"real", "frames", "labelled", "folder", "ndisp", "synthetic", "camera"})
        if not isinstance(body.get("real"), bool):
            raise ValueError(f"{REGISTRY}: dataset {name!r} needs real: true|false")
        real = body["real"]
        if "synthetic" in body:
            out.extend(_synthetic_datasets(body["synthetic"]))
            continue
        specs = []
        for i, d in enumerate(body.get("frames") or []):
            _check_keys(f"{name}.frames[{i}]", d, _FRAME_KEYS)
            d = dict(d)
            d.setdefault("group", d["folder"])
            specs.append(FrameSpec(dataset=name, real=real, camera=body.get("camera"), **d))
        if "labelled" in body:
            specs.extend(_labelled_frames(name, real, body))
        out.append(DatasetSpec(name, real, tuple(specs)))
    seen: dict[str, str] = {}
    for ds in out:
        for f in ds.frames:
            if f.name in seen:
                raise ValueError(f"{REGISTRY}: frame {f.name!r} in both {seen[f.name]!r} and {ds.name!r}")
            seen[f.name] = ds.name
            if f.junk is not None:
                from .scenes import check_junk_kind

                try:
                    check_junk_kind(f.junk)
                except ValueError as e:
                    raise ValueError(f"{REGISTRY}: frame {f.name!r}: {e}") from None
    return tuple(out)


def datasets(real: bool | None = None) -> list[DatasetSpec]:
    """Every dataset of the registry (``real`` filters), in the file's order."""
    return [d for d in _registry() if real is None or d.real == real]


def frames(datasets: list[str] | None = None, names: list[str] | None = None, *,
           real: bool | None = None, synthetic: bool | None = None) -> list[FrameSpec]:
    """Frames of the registry: of the named ``datasets`` (None = all), then of the named frames
    (None = all, else in the given order); ``real`` / ``synthetic`` filter.

    Raises:
        ValueError: an unknown dataset or frame name (the message lists the known ones).
    """
    reg = _registry()
    known = [d.name for d in reg]
    if datasets is not None:
        unknown = [n for n in datasets if n not in known]
        if unknown:
            raise ValueError(f"unknown dataset(s) {unknown}; {REGISTRY.name} declares {known}")
    pool = [f for d in reg if datasets is None or d.name in datasets for f in d.frames]
    if names is not None:
        by_name = {f.name: f for f in pool}
        unknown = [n for n in names if n not in by_name]
        if unknown:
            import difflib

            hints = [f"{n!r} (did you mean {m[0]!r}?)" if (m := difflib.get_close_matches(n, by_name, 1))
                     else repr(n) for n in unknown]
            raise ValueError(f"unknown frame(s) {', '.join(hints)}; {len(by_name)} frames in "
                             f"{'the registry' if datasets is None else datasets}")
        pool = [by_name[n] for n in names]
    return [f for f in pool if (real is None or f.real == real)
            and (synthetic is None or f.synthetic == synthetic)]


def missing_corpus(specs: list[FrameSpec], corpus: str | Path | None = None) -> str | None:
    """One line naming the synthetic frames of ``specs`` not generated yet and the command that
    generates them (``somtorch-synth``), or None when every one is there."""
    root = Path(corpus or corpus_dir())
    missing = [s for s in specs if s.synthetic and not (root / s.folder).is_dir()]
    if not missing:
        return None
    from .synth_config import SynthConfig

    fams, cams = {}, {}  # ordered sets
    seeds = 0
    for s in missing:
        fam_cam, seed = s.folder.split("/")
        fam, cam = fam_cam.rsplit("_", 1)
        fams[fam], cams[cam], seeds = None, None, max(seeds, int(seed) + 1)
    args = [] if sorted(fams) == sorted(SynthConfig().families) else [f"'families=[{','.join(fams)}]'"]
    args += [f"'cameras=[{','.join(cams)}]'", f"n={seeds}"]
    if root != corpus_dir():
        args.append(f"cache={root}")
    frames_ = len({s.folder for s in missing})
    return (f"{frames_} synthetic frame(s) are not generated yet (in {root}); generate them first with "
            f"`somtorch-synth {' '.join(args)}` (`python -m experiments.synth ...` in a clone), or leave the "
            "synthetic datasets out (datasets=[...])")


def load_frame(spec: FrameSpec, data_dir: str | Path, corpus: str | Path | None = None) -> Any:
    """The :class:`~somtorch.disparity.scene.Scene` of ``spec``, named ``spec.name``, with its objects.

    Raises:
        FileNotFoundError: the folder is missing (for a synthetic frame: the message names the
            command that builds the corpus).
    """
    from .scenes import load_dev_scene

    if not spec.synthetic:
        return load_dev_scene(spec, data_dir)
    import dataclasses

    from somtorch.disparity import load_scene

    folder = Path(corpus or corpus_dir()) / spec.folder
    if not folder.is_dir():
        raise FileNotFoundError(f"synthetic frame {spec.name!r}: {missing_corpus([spec], corpus)}")
    scene = load_scene(folder) if spec.disparity == "gt" else load_scene(folder, disparity_file=spec.disparity)
    if spec.junk:
        from .scenes import add_junk

        scene = add_junk(scene, spec.junk, seed=sum(map(ord, spec.name)))
    return dataclasses.replace(scene, name=spec.name)
