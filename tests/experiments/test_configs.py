"""Every Hydra config composes against the typed schema; typos and wrong types fail before any work."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf, open_dict
from omegaconf.errors import ConfigAttributeError, MissingMandatoryValue, ValidationError

from experiments.schema import RunConfig, register
from somtorch.outputs import OutputConfig
from somtorch.pipeline import FeatureConfig, ReductionConfig, SOMConfig, TrainConfig
from somtorch.tasks.objects import AreaConfig

CONF = Path(__file__).resolve().parents[2] / "conf"
SCHEMAS = {"features": FeatureConfig, "som": SOMConfig, "train": TrainConfig, "objects": AreaConfig,
           "reduction": ReductionConfig, "output": OutputConfig}
# data configs whose mandatory ??? values must come from the command line, and values that fill them
MANDATORY = {"file": ["data.source=/tmp/disp.pfm"], "stereo_pair": ["data.left=l.png", "data.right=r.png"],
             "kitti2015_official": ["data.source=/tmp/training", "data.frame=46"]}

register()


def _options() -> list[tuple[str, str]]:
    return sorted((p.parent.name, p.stem) for p in CONF.glob("*/*.yaml") if p.parent.name != "experiment")


def _experiments() -> list[str]:
    return sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))


def _compose(overrides: list[str]):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="run", overrides=overrides)


def test_every_group_has_options():
    groups = {g for g, _ in _options()}
    assert {"data", "features", "som", "train", "objects", "reduction", "output", "paths"} <= groups


@pytest.mark.parametrize("group, option", _options(), ids=[f"{g}={o}" for g, o in _options()])
def test_every_group_option_composes_and_validates(group, option):
    extra = MANDATORY.get(option, []) if group == "data" else []
    if group == "preset":  # presets are not in the defaults list: appended with +preset=NAME
        cfg = _compose([f"+preset={option}"])
        assert isinstance(OmegaConf.to_object(cfg), RunConfig)
        return
    cfg = _compose([f"{group}={option}", *extra])
    obj = OmegaConf.to_object(cfg)
    assert isinstance(obj, RunConfig)
    if group in SCHEMAS:
        assert isinstance(getattr(obj, group), SCHEMAS[group])
    # every literal value of the option's file arrives in the composed config
    raw = OmegaConf.to_container(OmegaConf.load(CONF / group / f"{option}.yaml"), resolve=False)
    for key, value in raw.items():
        if value == "???" or (isinstance(value, str) and "${" in value):
            continue
        assert OmegaConf.to_container(cfg[group], resolve=True)[key] == value, f"{group}.{key}"
    for override in extra:
        key, value = override.split("=", 1)
        assert OmegaConf.select(cfg, key) == value


def test_the_issue_s_studies_exist():
    assert {"table1", "table2", "runtime", "stability", "grid", "baselines", "optuna"} <= set(_experiments())


@pytest.mark.parametrize("name", _experiments())
def test_every_experiment_composes_and_validates(name):
    from experiments.study import StudyConfig

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="study", overrides=[f"+experiment={name}"], return_hydra_config=True)
    hydra_cfg = cfg.hydra
    with open_dict(cfg):
        del cfg["hydra"]
    study = OmegaConf.to_object(cfg)
    assert isinstance(study, StudyConfig)
    assert str(hydra_cfg.mode) == "RunMode.MULTIRUN"
    # table2 = table1's jobs; minisom joins baselines; <study>_baselines add task-baseline rows to <study>
    assert study.study in (name, "table1", "baselines", name.removesuffix("_baselines"))
    assert hydra_cfg.sweeper.params, f"{name}: no sweep parameters"


def test_shared_scene_paths_resolve_under_paths_data_dir(tmp_path):
    cfg = _compose(["data=eth3d_terrace", f"paths.data_dir={tmp_path}"])
    assert OmegaConf.to_object(cfg).data.source == f"{tmp_path}/eth3d/terrace"


def test_data_file_without_a_source_is_missing():
    cfg = _compose(["data=file"])
    with pytest.raises(MissingMandatoryValue, match="source"):
        OmegaConf.to_object(cfg)


def test_a_stereo_pair_is_named_after_its_files():
    named = OmegaConf.to_object(_compose(["data=stereo_pair", "data.left=/d/toy/left.png", "data.right=/d/toy/right.png"]))
    assert named.data.name == "toy"  # left.png says nothing: the folder's name
    named = OmegaConf.to_object(_compose(["data=stereo_pair", "data.left=/d/kitchen_l.png", "data.right=/d/kitchen_r.png"]))
    assert named.data.name == "kitchen_l"


def test_stereo_pair_without_a_left_image_is_missing():
    cfg = _compose(["data=stereo_pair", "data.right=r.png"])
    with pytest.raises(MissingMandatoryValue, match="left"):
        OmegaConf.to_object(cfg)


# ----------------------------------------------------------------- typos and wrong types fail early


@pytest.mark.parametrize("override, names", [
    ("train.epochs=abc", "epochs"),
    ("objects.selectt=1", "selectt"),
    ("som.rowz=3", "rowz"),
    ("ensemble=two", "ensemble"),
    ("objects.rule=bogus", "bogus"),
    ("objects.link=grid", "link"),  # a field that was folded into objects.rule
    ("objects.keep_budget=2.0", "keep_budget"),
])
def test_typos_wrong_types_and_bad_values_fail_at_composition(override, names):
    errors = (ConfigCompositionException, ValidationError, ConfigAttributeError, ValueError)
    with pytest.raises(errors) as info:
        OmegaConf.to_object(_compose([override]))
    chain = f"{info.value} {info.value.__cause__}"
    assert names in chain


@pytest.mark.parametrize("override", ["som.rows=0"])
def test_bad_som_values_fail_at_composition(override):
    with pytest.raises(ValueError, match="rows"):
        OmegaConf.to_object(_compose([override]))
