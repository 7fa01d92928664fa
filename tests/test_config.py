"""One home for every default: the library with no arguments is the CLI with no overrides."""

from __future__ import annotations

from dataclasses import asdict, fields
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from experiments.schema import register
from somtorch.config import (AreaConfig, FeatureConfig, GroundConfig, PipelineConfig, ReductionConfig, TrainConfig,
                             WarmStartConfig, with_overrides)

CONF = Path(__file__).resolve().parents[1] / "conf"
register()


def _composed(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return OmegaConf.to_object(compose(config_name="run", overrides=list(overrides)))


def _pipeline_part(cfg) -> dict:
    return {f.name: asdict(getattr(cfg, f.name)) if hasattr(getattr(cfg, f.name), "__dataclass_fields__")
            else getattr(cfg, f.name) for f in fields(PipelineConfig)}


def test_the_cli_without_overrides_is_the_library_default():
    assert _pipeline_part(_composed()) == _pipeline_part(PipelineConfig())
    assert _pipeline_part(_composed("+preset=robust")) == _pipeline_part(PipelineConfig())


def test_the_library_called_without_arguments_runs_what_the_cli_runs():
    from somtorch.disparity import load_scene
    from somtorch.pipeline import run_pipeline

    scene = load_scene("motorcycle")
    lib = run_pipeline(scene, metrics=False).members[0]
    cli = run_pipeline(scene, _composed(), metrics=False).members[0]
    assert [a.box for a in lib.kept] == [a.box for a in cli.kept]
    assert lib.reduction.reduction_union == cli.reduction.reduction_union


def test_the_som_fit_and_make_features_defaults_are_the_configs():
    import inspect

    from somtorch import SOM
    from somtorch.disparity.features import make_features

    fit = inspect.signature(SOM.fit).parameters
    for name in ("mode", "lr", "lr_decay", "sigma_decay", "neighborhood", "order", "batch_size"):
        assert fit[name].default == getattr(TrainConfig(), name), name
    mf = inspect.signature(make_features).parameters
    assert mf["d_weight"].default == FeatureConfig().d_weight and mf["normalize"].default == FeatureConfig().normalize


def test_the_paper_preset_pins_every_value_that_differs_from_the_default():
    paper = _composed("+preset=paper")
    assert (paper.som.rows, paper.som.cols) == (4, 7)
    assert (paper.train.mode, paper.features.normalize, paper.features.d_weight) == ("online", "minmax", 1.0)
    assert paper.ground.rule == "none"
    o = paper.objects
    assert (o.rule, o.similarity, o.merge, o.min_purity, o.min_solidity) == ("paper", 0.1, 0.0, 0.0, 0.0)
    assert (o.box_coverage, o.box_quantile, o.ground_clutter, o.map_stride) == (1.0, 0.0, 0.0, 1)
    r = paper.reduction
    assert (r.tolerance_px, r.tolerance_frac, r.tolerance_image) == (0, 0.05, 0.0)


@pytest.mark.parametrize("cls, kwargs, words", [
    (AreaConfig, {"min_purity": 2.0}, ["objects.min_purity", "[0, 1]", "2.0"]),
    (AreaConfig, {"rule": "largest"}, ["objects.rule", "largest", "paper, salient"]),
    (AreaConfig, {"keep_budget": 0.0}, ["objects.keep_budget", "(0, 1]"]),
    (TrainConfig, {"parallel": "data", "mode": "online"}, ["parallel='data'", "mode='online'"]),
    (GroundConfig, {"min_inlier_frac": -0.1}, ["ground.min_inlier_frac"]),
    (TrainConfig, {"epochs": 0}, ["train.epochs", "integer"]),
    (FeatureConfig, {"d_weight": float("inf")}, ["features.d_weight", "finite"]),
    (ReductionConfig, {"tolerance_image": -1}, ["reduction.tolerance_image"]),
    (PipelineConfig, {"method": "dbscan"}, ["method", "kmeans", "som"]),
])
def test_the_constraints_table_names_the_field_and_the_expectation(cls, kwargs, words):
    with pytest.raises(ValueError) as err:
        cls(**kwargs)
    for w in words:
        assert w in str(err.value), (w, str(err.value))


def test_wrong_types_are_type_errors_and_overrides_are_validated():
    with pytest.raises(TypeError, match="train.epochs"):
        TrainConfig(epochs=2.5)
    with pytest.raises(TypeError, match="sequence.warm"):
        WarmStartConfig(warm="yes")
    cfg = with_overrides(PipelineConfig(), {"objects.merge": 0.5, "ensemble": 3})
    assert (cfg.objects.merge, cfg.ensemble, PipelineConfig().objects.merge) == (0.5, 3, AreaConfig().merge)
    with pytest.raises(ValueError, match="not a field"):
        with_overrides(PipelineConfig(), {"objects.bogus": 1})
    with pytest.raises(ValueError, match="objects.merge"):
        with_overrides(PipelineConfig(), {"objects.merge": -1.0})


def test_a_segmenter_without_a_grid_refuses_the_paper_rule(shared_data):
    from somtorch.disparity import load_scene
    from somtorch.pipeline import run_pipeline

    scene = load_scene("motorcycle")
    cfg = with_overrides(PipelineConfig(method="kmeans"), {"objects.rule": "paper"})
    with pytest.raises(ValueError, match="no SOM grid"):
        run_pipeline(scene, cfg, metrics=False)


def test_option_tables_match_the_registries_that_implement_them():
    """``somtorch.config.options`` declares the names; the implementing registries serve exactly those."""
    from somtorch.config import options
    from somtorch.core.decay import DECAYS
    from somtorch.core.neighborhood import NEIGHBORHOODS
    from somtorch.segmenters import SEGMENTERS

    assert tuple(DECAYS) == options.DECAYS
    assert tuple(NEIGHBORHOODS) == options.NEIGHBORHOODS
    assert {n: s.deterministic for n, s in SEGMENTERS.items()} == options.METHODS


def test_a_registered_segmenter_is_a_valid_method():
    from somtorch.config import options
    from somtorch.segmenters import SEGMENTERS, register

    with pytest.raises(ValueError, match="method='custom_test' is not known"):
        PipelineConfig(method="custom_test")
    try:
        register("custom_test", deterministic=True)(lambda *a: None)
        assert PipelineConfig(method="custom_test", ensemble=3).runs == 1
        with pytest.raises(ValueError, match="declared deterministic"):
            register("slic", deterministic=False)(lambda *a: None)
    finally:
        SEGMENTERS.pop("custom_test", None)
        options.METHODS.pop("custom_test", None)
