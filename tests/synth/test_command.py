"""The command (experiments.synth) and the Hydra data option (data=synthetic)."""

from __future__ import annotations

import json
from pathlib import Path

from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from experiments.schema import RunConfig, SynthConfig, register

CONF = Path(__file__).resolve().parents[2] / "conf"
register()


def test_data_synthetic_loads_the_named_frame(tmp_path, monkeypatch):
    from experiments.run import load_input

    monkeypatch.setenv("SOMTORCH_CACHE", str(tmp_path))
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="run", overrides=["data=synthetic", "data.family=hands", "data.seed=3",
                                                    "data.camera=oakd", "data.version=sgbm"])
    run_cfg: RunConfig = OmegaConf.to_object(cfg)
    scene = load_input(run_cfg)
    assert scene.name == "hands_oakd_3_sgbm"
    assert scene.source["disparity"] == str(tmp_path / "corpus" / "hands_oakd" / "00003" / "disp_sgbm.pfm")
    assert scene.objects is not None and scene.camera is not None and scene.width == 640


def test_the_command_writes_frames_once_and_lists_them_in_the_manifest(tmp_path):
    from experiments.synth import generate

    cfg = SynthConfig(families=["stairs", "room"], cameras=["oakd"], n=2, scale=0.25, workers=1, cache=str(tmp_path))
    first = generate(cfg, progress=False)
    assert first["generated"] == 4 and first["present"] == 0
    manifest = json.loads((tmp_path / "stairs_oakd_x0.25" / "manifest.json").read_text())
    assert sorted(manifest["frames"]) == ["00000", "00001"]
    import cv2
    import numpy as np
    import torch

    made_by = manifest["frames"]["00001"]["rendered_with"]  # what made the bytes, for a digest that differs
    assert f"numpy {np.__version__}" in made_by and f"opencv {cv2.__version__}" in made_by
    assert torch.backends.cpu.get_cpu_capability() in made_by
    assert (tmp_path / "room_oakd_x0.25" / "00001" / "disp0GT.pfm").is_file()
    again = generate(cfg, progress=False)
    assert again["generated"] == 0 and again["present"] == 4
    # the bytes of the four frames, one digest: the same when nothing was rendered again
    assert again["digest"] == first["digest"] and len(first["digest"]) == 16


def test_the_corpus_digest_covers_every_frame_and_is_filled_in_for_old_manifests(tmp_path):
    from experiments.synth import corpus_digest, frame_digest, generate

    cfg = SynthConfig(families=["fence"], cameras=["oakd"], n=2, scale=0.25, workers=1, cache=str(tmp_path))
    first = generate(cfg, progress=False)
    ds = tmp_path / "fence_oakd_x0.25"
    manifest = json.loads((ds / "manifest.json").read_text())
    digests = {f"fence_oakd_x0.25/{s}": e["digest"] for s, e in manifest["frames"].items()}
    assert first["digest"] == corpus_digest(digests)
    assert digests["fence_oakd_x0.25/00001"] == frame_digest(ds / "00001")
    # a manifest written before digests were recorded: the digest is read from the files and saved
    for e in manifest["frames"].values():
        del e["digest"]
    (ds / "manifest.json").write_text(json.dumps(manifest))
    assert generate(cfg, progress=False)["digest"] == first["digest"]
    assert "digest" in json.loads((ds / "manifest.json").read_text())["frames"]["00000"]
    # one changed byte in one frame changes the corpus digest
    pfm = ds / "00000" / "disp0GT.pfm"
    raw = bytearray(pfm.read_bytes())
    raw[-1] ^= 1
    pfm.write_bytes(bytes(raw))
    assert corpus_digest({**digests, "fence_oakd_x0.25/00000": frame_digest(ds / "00000")}) != first["digest"]


def test_help_lists_the_command_keys(capsys):
    import pytest

    from experiments.help import maybe_print_help

    with pytest.raises(SystemExit):
        maybe_print_help("synth", ["--help"])
    out = capsys.readouterr().out
    assert "families=" in out and "cameras=" in out and "workers=" in out and "SOMConfig" not in out


def test_help_does_not_import_torch():
    import subprocess
    import sys

    code = "import sys; from experiments.help import help_text; help_text('synth'); print('torch' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], cwd=CONF.parent, capture_output=True, text=True, timeout=60)
    assert proc.stdout.strip() == "False", proc.stderr

