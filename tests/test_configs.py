"""Configs that no run can use are one clear line before any work, in every system; unset fields take the profile's."""

import pytest

from assets.applearn.models import PROTOCOL, AppLearnConfig
from assets.dcb.cases import CasesConfig, case_scales
from assets.dcb.training import TrainingConfig as DCBTrainingConfig
from assets.dcb.training import training_plan as dcb_plan
from assets.profiles import resolve
from assets.trajectory.models import TrajectoryModelsConfig
from assets.trajectory.models import training_plan as trajectory_plan
from assets.urban.training import TrainingConfig as UrbanTrainingConfig
from assets.urban.training import training_plan as urban_plan
from models.trajectory.training import PROFILE_DEFAULTS

TRAINED = ["sc1", "real_cr"]


def test_unset_fields_take_the_profile_and_set_ones_win():
    assert dcb_plan(DCBTrainingConfig(profile="demo")) == {"episodes": 200, "seeds": [0, 1, 2]}
    assert dcb_plan(DCBTrainingConfig(profile="paper", seeds=[3])) == {"episodes": 15000, "seeds": [3]}
    assert dcb_plan(DCBTrainingConfig(profile="demo", hold="depart", c_plus=1e4))["episodes"] == 200  # every method departs
    assert case_scales(CasesConfig(profile="paper")) == [0.95, 0.9, 0.85, 0.8]
    assert case_scales(CasesConfig(capacity_scales=[1.0, 0.9], max_delay_min=30)) == [1.0, 0.9]
    assert urban_plan(UrbanTrainingConfig(profile="demo"), TRAINED) == {
        "episodes": 50, "seeds": [0], "method_scenarios": {"ch3_dqn_cnn": ["sc1"], "i_marl": ["sc1"]}}
    assert urban_plan(UrbanTrainingConfig(episodes=2, methods=["col_marl"], method_scenarios={"col_marl": ["real_cr"]}), TRAINED)[
        "method_scenarios"] == {"col_marl": ["real_cr"]}
    # a field left at None takes the profile's value, also when it is falsy in the config's own type
    assert resolve(TrajectoryModelsConfig(profile="demo", gail_iterations=0), PROFILE_DEFAULTS)["gail_iterations"] == 0
    assert resolve(TrajectoryModelsConfig(profile="paper"), PROFILE_DEFAULTS)["bc_epochs"] == 200


@pytest.mark.parametrize("check, message", [
    (lambda: dcb_plan(DCBTrainingConfig(profile="fast")), "profile 'fast': expected one of demo, paper"),
    (lambda: dcb_plan(DCBTrainingConfig(episodes=0)), "episodes 0: expected at least 1"),
    (lambda: dcb_plan(DCBTrainingConfig(seeds=[])), "seeds is empty"),
    (lambda: dcb_plan(DCBTrainingConfig(methods=["HCMARL2", "MIRL"])), r"DCB methods \['HCMARL2'\]: expected one or more of MIRL"),
    (lambda: dcb_plan(DCBTrainingConfig(methods=[])), "DCB methods none"),
    (lambda: dcb_plan(DCBTrainingConfig(reward="global")), "unknown DCB reward 'global'"),
    (lambda: dcb_plan(DCBTrainingConfig(hold="depart", reward="overload")), "DCB hold 'depart' is implemented with the thesis state and reward only"),
    (lambda: dcb_plan(DCBTrainingConfig(c_plus=-1)), r"DCB C\+ -1.0 is not positive"),
    (lambda: case_scales(CasesConfig(capacity_scales=[0.951, 0.949])), r"give the cases \['cap95', 'cap95'\]"),
    (lambda: case_scales(CasesConfig(capacity_scales=[])), "expected one or more scales > 0"),
    (lambda: case_scales(CasesConfig(capacity_scales=[0.9, -0.5])), "expected one or more scales > 0"),
    (lambda: case_scales(CasesConfig(max_delay_min=0)), "max_delay_min 0"),
    (lambda: urban_plan(UrbanTrainingConfig(methods=["col_marl", "colmarl"]), TRAINED), r"urban methods \['colmarl'\]"),
    (lambda: urban_plan(UrbanTrainingConfig(method_scenarios={"col_marl": ["Sc1"]}), TRAINED), r"names \['Sc1'\], not trained scenarios"),
    (lambda: urban_plan(UrbanTrainingConfig(episodes=-3), TRAINED), "episodes -3"),
    (lambda: urban_plan(UrbanTrainingConfig(methods=[]), TRAINED), "urban methods none"),
    (lambda: urban_plan(UrbanTrainingConfig(method_scenarios={"colmarl": ["sc1"]}), TRAINED), r"urban methods \['colmarl'\]"),
    (lambda: case_scales(CasesConfig(capacity_scales=[0.0])), "expected one or more scales > 0"),
    (lambda: resolve(TrajectoryModelsConfig(bc_epochs=-1), PROFILE_DEFAULTS), "bc_epochs -1: expected counts >= 0"),
    (lambda: resolve(TrajectoryModelsConfig(profile="thesis"), PROFILE_DEFAULTS), "profile 'thesis'"),
    (lambda: resolve(TrajectoryModelsConfig(seeds=[]), PROFILE_DEFAULTS), "seeds is empty"),
    (lambda: trajectory_plan(TrajectoryModelsConfig(algorithms=["gail"])), r"algorithms \['gail'\]: expected one or more of triple_gail"),
    (lambda: trajectory_plan(TrajectoryModelsConfig(discriminators=[])), "discriminators none: expected one or more of wgan_gp"),
    (lambda: resolve(AppLearnConfig(seeds=[]), PROTOCOL), "seeds is empty"),
])
def test_unusable_config_is_one_line(check, message):
    with pytest.raises(ValueError, match=message) as e:
        check()
    assert "\n" not in str(e.value)


def test_every_profile_default_is_read_when_a_run_builds_its_config(monkeypatch):
    # TRAFFICLEARN_PROFILE set after the assets were imported (as in a run's process, or a launchpad run of `make dev`)
    # reaches every config: each reads it when built, none at import (a misspelt profile was a traceback then)
    import dagster as dg

    import pipelines.definitions  # noqa: F401  (imports every asset's config)

    def subclasses(cls):
        return {s for c in cls.__subclasses__() for s in {c} | subclasses(c)}

    configs = sorted(f"{c.__module__}.{c.__name__}" for c in subclasses(dg.Config) if c.__module__.startswith("assets.") and "profile" in c.model_fields)
    assert len(configs) == 7, configs  # DCB cases and training, urban routes, scenarios and training, trajectory, AppLearn
    monkeypatch.setenv("TRAFFICLEARN_PROFILE", "paper")
    built = {f"{c.__module__}.{c.__name__}": c().profile for c in subclasses(dg.Config) if f"{c.__module__}.{c.__name__}" in configs}
    assert built == dict.fromkeys(configs, "paper")
