"""Every config composes and instantiates (the lightning-hydra-template habit)."""

from __future__ import annotations

import inspect
from pathlib import Path

import pytest
from hydra.utils import get_class, instantiate
from omegaconf import OmegaConf

from tests.conftest import EXPERIMENTS, compose_config, experiment_overrides


def test_experiments_found():
    assert {"fingertip", "lord3dof", "table1"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_experiment_composes_and_instantiates(experiment: str, tmp_path):
    cfg = compose_config([f"experiment={experiment}", *experiment_overrides(experiment, tmp_path)])
    datamodule = instantiate(cfg.data)
    datamodule.setup()
    model = instantiate(cfg.model)
    assert model.recording in datamodule.data.recordings
    for baseline in cfg.baselines.values():
        assert instantiate(baseline).recording in datamodule.data.recordings
    instantiate(cfg.trainer, logger=False, enable_checkpointing=False)


@pytest.mark.parametrize("experiment", ["wall_following", "mkv_compare"])
def test_a_comparison_s_autoencoder_takes_the_main_learner_s_rank(experiment: str):
    """A hostile tester's: model.rank=3 left the autoencoder at its own rank 9, and its angle to PCA was to PCA at 9."""
    cfg = compose_config([f"experiment={experiment}", "model.rank=3", "model.rank_rule=largest_ratio"])
    assert (cfg.baselines.linear_autoencoder.rank, cfg.baselines.linear_autoencoder.rank_rule) == (3, "largest_ratio")


def test_default_experiment_is_fingertip():
    assert compose_config([]).experiment_name == "fingertip"


@pytest.mark.parametrize("group,option", [("optimizer", "adam"), ("optimizer", "lbfgs"), ("model", "least_squares")])
def test_group_options_compose(group: str, option: str):
    cfg = compose_config([f"{group}={option}"])
    assert cfg[group]._target_


@pytest.mark.parametrize("path", sorted((Path(__file__).parents[1] / "conf" / "model").glob("*.yaml")), ids=lambda p: p.stem)
def test_model_configs_state_the_constructors_defaults(path: Path):
    """A model config's literal values are its class's defaults, so the CLI, the Python API and the benchmarks that
    build models directly fit the same model (``learnt_law`` once differed between them)."""
    cfg = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    parameters = inspect.signature(get_class(cfg.pop("_target_"))).parameters
    for key, value in cfg.items():
        if isinstance(value, str) and (value.startswith("${") or value == "???"):
            continue
        assert value == parameters[key].default, (key, value, parameters[key].default)
