"""Every config composes and instantiates (the lightning-hydra-template habit)."""

from __future__ import annotations

import pytest
from hydra.utils import instantiate

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


def test_default_experiment_is_fingertip():
    assert compose_config([]).experiment_name == "fingertip"


@pytest.mark.parametrize("group,option", [("optimizer", "adam"), ("optimizer", "lbfgs"), ("model", "least_squares")])
def test_group_options_compose(group: str, option: str):
    cfg = compose_config([f"{group}={option}"])
    assert cfg[group]._target_
