"""safetensors checkpoints: round trips, the JSON sidecar, and files that are not checkpoints."""

from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import save_file

from somtorch import SOM, DataFileError


@pytest.fixture
def trained(x3) -> SOM:
    return SOM(3, 4, 3, ensemble=2, toroidal=True, dtype=torch.float64, seed=7).fit(
        x3.double(), mode="batch", epochs=3, progress=False)


def test_round_trip_keeps_weights_config_seeds_and_dtype(trained, tmp_path):
    path = trained.save(tmp_path / "som.safetensors")
    assert path == tmp_path / "som.safetensors"
    back = SOM.load(path, device="cpu")
    assert back.weight.dtype == torch.float64
    assert torch.equal(back.weight, trained.weight)
    assert back.config() == trained.config()
    assert back.seeds == [7, 8] and back.toroidal and back.initialized
    assert torch.equal(back.adjacency, trained.adjacency)


def test_suffix_is_added_and_json_sidecar_describes_the_map(trained, tmp_path):
    path = trained.save(tmp_path / "run1")
    assert path.name == "run1.safetensors"
    meta = json.loads((tmp_path / "run1.json").read_text())
    assert meta["format"] == "somtorch.som/1"
    assert {k: meta[k] for k in trained.config()} == trained.config()
    # loading by the name without the suffix finds the same file
    assert torch.equal(SOM.load(tmp_path / "run1").weight, trained.weight)


def test_uninitialised_flag_survives(tmp_path):
    som = SOM(2, 2, 2, seed=0)
    back = SOM.load(som.save(tmp_path / "blank"))
    assert not back.initialized and torch.equal(back.weight, som.weight)


def test_loaded_map_trains_on_from_the_saved_weights(trained, tmp_path, x3):
    back = SOM.load(trained.save(tmp_path / "m"))
    # the loaded map is not re-initialised by fit: training starts from the saved weights
    a = back.fit(x3.double(), mode="batch", epochs=1, progress=False)
    b = trained.fit(x3.double(), mode="batch", epochs=1, progress=False)
    assert torch.equal(a.weight, b.weight)


def test_missing_file_is_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere"):
        SOM.load(tmp_path / "nothere.safetensors")


@pytest.mark.parametrize("content", [b"", b"hello, this is not a safetensors file", b"\xff" * 64])
def test_garbage_is_data_file_error_naming_the_file(tmp_path, content):
    path = tmp_path / "junk.safetensors"
    path.write_bytes(content)
    with pytest.raises(DataFileError, match="junk.safetensors") as info:
        SOM.load(path)
    assert info.value.path == path


def test_foreign_safetensors_file_is_rejected(tmp_path):
    path = tmp_path / "other.safetensors"
    save_file({"weight": torch.zeros(1, 4, 2)}, str(path))  # right tensor name, no somtorch metadata
    with pytest.raises(DataFileError, match="other.safetensors.*not a somtorch SOM checkpoint"):
        SOM.load(path)
    save_file({"w": torch.zeros(1, 4, 2)}, str(path), metadata={"format": "somtorch.som/1", "config": "{}"})
    with pytest.raises(DataFileError, match="weight"):
        SOM.load(path)


def test_broken_config_is_data_file_error(tmp_path):
    path = tmp_path / "broken.safetensors"
    save_file({"weight": torch.zeros(1, 4, 2)}, str(path),
              metadata={"format": "somtorch.som/1", "config": json.dumps({"rows": 2})})
    with pytest.raises(DataFileError, match="broken.safetensors"):
        SOM.load(path)


def test_existing_file_with_another_suffix_is_data_file_error(tmp_path):
    path = tmp_path / "model.pt"
    path.write_bytes(b"PK\x03\x04 a torch zip pickle, not safetensors")
    with pytest.raises(DataFileError, match="model.pt"):
        SOM.load(path)


def test_from_config_builds_what_the_config_describes_and_survives_a_checkpoint(tmp_path):
    from somtorch.config import SOMConfig

    cfg = SOMConfig(rows=4, cols=5, topology="hexagonal", toroidal=True)
    som = SOM.from_config(cfg, 3, ensemble=2, seed=4)
    assert (som.rows, som.cols, som.dim, som.ensemble, som.topology, som.toroidal) == (4, 5, 3, 2, "hexagonal", True)
    som.fit(torch.rand(50, 3), epochs=2, progress=False)
    som.save(tmp_path / "m.safetensors")
    back = SOM.load(tmp_path / "m.safetensors")
    assert (back.rows, back.cols, back.topology, back.toroidal) == (cfg.rows, cfg.cols, cfg.topology, cfg.toroidal)
    assert torch.equal(back.weight, som.weight)


@pytest.mark.parametrize("how", ["copy_", "load_state_dict", "assign", "parameter"])
def test_user_set_weights_count_as_initialised_and_fit_keeps_them(how):
    x = torch.rand(60, 3, generator=torch.Generator().manual_seed(0))
    w0 = torch.rand(1, 12, 3, generator=torch.Generator().manual_seed(1))
    som = SOM(3, 4, 3, seed=0)
    assert not som.initialized
    if how == "copy_":
        with torch.no_grad():
            som.weight.copy_(w0)
    elif how == "load_state_dict":
        som.load_state_dict({"weight": w0})
    elif how == "assign":
        som.weight = w0
    else:
        som.weight = torch.nn.Parameter(w0.clone())
    assert som.initialized
    ref = SOM(3, 4, 3, seed=0)
    ref.weight = w0
    som.fit(x, mode="batch", epochs=2, progress=False)
    ref.fit(x, mode="batch", epochs=2, progress=False)
    assert torch.equal(som.weight, ref.weight)  # trained from w0, not re-initialised
