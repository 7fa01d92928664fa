"""Quality gates on the development scenes: the defaults must keep finding the main object.

The thresholds live in ``baseline.json`` beside this file, with the command that measured the
figures they are drawn from; a regression of the object rule, the box refinement or the tolerance
fails here, while the figures themselves stay the validation's job (``docs/validation.md``). The
paper preset on the same seeds is the contrast: its hits are trivial (no useful reduction).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from experiments.datasets import frames, load_frame
from somtorch.disparity import load_scene
from somtorch.pipeline import PipelineConfig, run_pipeline

CONF = Path(__file__).resolve().parents[2] / "conf"
BASELINE = json.loads((Path(__file__).with_name("baseline.json")).read_text())


@pytest.mark.parametrize("name", list(BASELINE["gates"]))
def test_defaults_give_useful_hits_on_the_development_scenes(shared_data, name):
    scene = load_frame(frames(names=[name])[0], shared_data)
    n = BASELINE["runs"]
    result = run_pipeline(scene, PipelineConfig(ensemble=n), metrics=False)
    scores = [m.score for m in result.members]
    useful = sum(s.useful_hit for s in scores)
    assert useful >= BASELINE["gates"][name], f"{name}: {useful}/{n} useful hits"
    # useful = found AND reduced: the mean reduction of the hits is within 10 points of x_opt
    # (a wider margin where baseline.json records why)
    margin = BASELINE["reduction_margin"].get(name, BASELINE["reduction_margin"]["default"])
    hits = [s.reduction_union for s in scores if s.useful_hit]
    assert sum(hits) / len(hits) >= scores[0].x_opt - margin
    assert not any(m.no_object for m in result.members if m.score.useful_hit)


def test_paper_preset_hits_on_real_scenes_are_trivial(shared_data):
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from experiments.schema import register

    register()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        paper = OmegaConf.to_object(compose(config_name="run", overrides=["+preset=paper", "ensemble=5"]))
    assert paper.reduction.tolerance_frac == 0.05 and paper.objects.merge == 0.0
    scene = load_scene(shared_data / "kitti2015/devkit_demo")
    scores = [m.score for m in run_pipeline(scene, paper, metrics=False).members]
    assert sum(s.identified_95 for s in scores) >= 4  # "identified" ...
    assert sum(s.useful_hit for s in scores) == 0  # ... by keeping (nearly) the whole map


def test_purity_and_solidity_tests_reject_sgbm_junk_on_a_computed_disparity_map(shared_data):
    """ETH3D terrace with the disparity computed by our SGBM instead of the ground truth: the most
    contrasty area is junk at the left border (no match within the search range) and speckles, which
    the purity test skips, and the solidity test alone mostly too. Until session 10 the junk cost
    the useful hit (20 seeds: 20 / 19 / 14 useful with both checks / solidity only / neither); since
    session 11 further areas need no score relative to the best (``keep_ratio`` deleted), the terrace
    is kept beside the junk and every run is useful either way, so the checks are measured by what
    they keep out (junk: a first kept area under the default purity or solidity): with the session-12
    defaults (``min_purity`` 0.15) junk first in 0 / 1 / 17 of 20 runs, mean reduction 81.1 / 80.2 /
    74.3 %."""
    from somtorch.tasks.objects import AreaConfig

    scene = load_frame(frames(names=["eth3d_terrace_sgbm"])[0], shared_data)
    p, s = AreaConfig().min_purity, AreaConfig().min_solidity
    useful, junk_first, reduction = {}, {}, {}
    for purity, solid in ((p, s), (0.0, s), (0.0, 0.0)):
        cfg = PipelineConfig(ensemble=20, objects=AreaConfig(min_purity=purity, min_solidity=solid))
        members = run_pipeline(scene, cfg, metrics=False).members
        useful[purity, solid] = sum(m.score.useful_hit for m in members)
        junk_first[purity, solid] = sum(
            not m.no_object and (m.kept[0].purity < p or m.kept[0].solidity_rel < s) for m in members)
        reduction[purity, solid] = sum(m.score.reduction_union for m in members) / len(members)
    assert useful[p, s] >= 15, useful
    assert junk_first[p, s] <= 1 and junk_first[0.0, s] <= 8, junk_first
    assert junk_first[0.0, 0.0] >= 10, junk_first  # the checks still keep the junk out ...
    assert reduction[p, s] >= reduction[0.0, 0.0] + 3, reduction  # ... and the data small


def test_solidity_test_rejects_ceiling_streaks_on_an_unlabelled_sgbm_scene(shared_data):
    """OAK-D desk (SGBM, no mask): without the solidity test the kept area is a set of 1-2 px high
    mismatch streaks on the ceiling in about half of the runs (52/100 measured); with it, in at most
    a few (3/100: every candidate failed and the best-ranked was kept anyway)."""
    from somtorch.tasks.objects import AreaConfig

    scene = load_scene(shared_data / "oakd_stereodemo" / "desk")
    low = {}
    for v in (0.25, 0.0):
        members = run_pipeline(scene, PipelineConfig(ensemble=20, objects=AreaConfig(min_solidity=v)),
                               metrics=False).members
        # fail-safe runs keep the whole map (flagged no_object): not junk
        low[v] = sum(not m.no_object and m.kept[0].solidity_rel < 0.25 for m in members)
    assert low[0.25] <= 2, low
    assert low[0.0] >= 6, low


def test_the_ground_mask_takes_almost_no_object_pixels_on_the_real_development_scenes(shared_data):
    """The issue's ground target (≈ 0 object pixels in the ground mask), over every real masked
    development scene, with the RANSAC seed varied: the constrained search accepts only planes that
    span the disparity range like a floor (min_slope_frac), so the seat, table-top and wall planes
    of the OAK-D rooms (which took 7-36 % of the objects' pixels when the tests were first made
    constraints at min_slope_frac 0.25) are refused, whatever the seed."""
    from somtorch.evaluation import ground_object_share
    from somtorch.tasks.ground import fit_ground_plane

    shares = {}
    for spec in frames(synthetic=False):
        if spec.junk is not None:
            continue
        scene = load_frame(spec, shared_data)
        for seed in (0, 1):
            g = fit_ground_plane(scene.disparity, scene.valid, seed=seed)
            shares[spec.name, seed] = ground_object_share(g, scene)
    assert max(shares.values()) <= 0.15, shares  # the bike's wheels on the floor: 12 %
    assert sum(shares.values()) / len(shares) <= 0.03, shares
