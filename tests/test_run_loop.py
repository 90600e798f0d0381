"""The one run loop: every kind of run through train(), config keys honoured or refused, logger and callbacks from config."""

from __future__ import annotations

from pathlib import Path

import pytest

from sfmnet.errors import SfmnetError
from sfmnet.training.run import train
from tests.conftest import compose_config, experiment_overrides, lightning_checkpoint


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["task=pca"], r"task=pca does not fit data for a calibration run"),
        (["task=mapping"], r"task=mapping is not a task: use one of calibration, sensorimotor, pca"),
        (["experiment=mkv_pca", "eval.leave_one_group_out=true"], r"eval.leave_one_group_out is set but a sensorimotor run"),
        (["experiment=pca", "eval.leave_one_group_out=true"], r"eval.leave_one_group_out is set but a pca run"),
        (["experiment=pca", "ckpt_path={tmp}/last.ckpt"], r"ckpt_path is set but a pca run"),
    ],
)
def test_keys_a_task_cannot_honour_are_refused(tmp_path: Path, overrides: list[str], message: str):
    extra = experiment_overrides("pca", tmp_path) if "experiment=pca" in overrides else []
    lightning_checkpoint(tmp_path / "last.ckpt")
    with pytest.raises(SfmnetError, match=message):
        train(compose_config([*(item.format(tmp=tmp_path) for item in overrides), *extra]), tmp_path / "run")


def test_baselines_are_refused_for_pca(tmp_path: Path):
    cfg = compose_config(["experiment=pca", *experiment_overrides("pca", tmp_path)])
    cfg.baselines = {"other": cfg.model}
    with pytest.raises(SfmnetError, match="baselines is set but a pca run fits one model"):
        train(cfg, tmp_path / "run")


def test_a_run_without_logger_or_checkpoints_still_writes_its_results(tmp_path: Path):
    run_dir = tmp_path / "run"
    metrics = train(compose_config(["~logger", "~callbacks.model_checkpoint"]), run_dir)
    assert metrics["eval/max_error_pct"] < 0.3
    assert (run_dir / "calibration.json").is_file() and (run_dir / "figures" / "shape_from_motion_motion.png").is_file()
    assert not (run_dir / "tensorboard").exists() and not (run_dir / "checkpoints").exists()


def test_the_default_run_logs_to_tensorboard_and_checkpoints(tmp_path: Path):
    run_dir = tmp_path / "run"
    train(compose_config([]), run_dir)
    assert list((run_dir / "tensorboard" / "shape_from_motion").glob("events.out.tfevents.*"))
    assert (run_dir / "checkpoints" / "shape_from_motion" / "last.ckpt").is_file()
