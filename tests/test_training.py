"""Fitting through the one Lightning trainer: convergence, the default experiment's accuracy, Table 1."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from sfmnet.calibration import Calibration
from sfmnet.training.learner_module import LearnerModule, matrix_error
from sfmnet.training.run import train
from tests.conftest import EXPERIMENTS, compose_config, experiment_overrides

NOISE_FREE = ["data.noise_fraction=0.0", "data.errors.angle_error_deg=0.0"]


@pytest.mark.parametrize(
    "overrides",
    [
        ["experiment=fingertip", "data.known_loads=2"],
        ["experiment=fingertip", "data.known_loads=1"],
        ["experiment=lord3dof", "data.known_loads=3"],
        ["experiment=lord3dof", "data.offset_scale=0.5", "model.estimate_offset=true"],
        ["experiment=lord3dof", "data.offset_scale=0.5", "model.refinement=penalty"],
        ["experiment=fingertip", "data.known_loads=1", "model.refinement=penalty"],
    ],
    ids=[
        "2d-two-loads", "2d-one-load-and-hint", "3d-three-loads", "3d-offsets-two-loads-and-hint",
        "3d-offsets-penalty", "2d-hint-penalty",
    ],
)
def test_training_through_trainer_converges_to_closed_form(overrides):
    """Knock the closed-form solution 10 % off, then let the trainer's refinement steps bring it back."""
    # Noise-free, the loss falls to zero: the default tolerances (set for noisy data, where the
    # loss levels off at the noise) would stop at a 1e-6 error, so tighten them.
    tight = ["optimizer.tolerance_grad=1e-14", "optimizer.tolerance_change=1e-20"]
    cfg = compose_config([*overrides, *NOISE_FREE, *tight, "trainer.max_epochs=20"])
    datamodule = instantiate(cfg.data)
    datamodule.setup()
    model = instantiate(cfg.model)
    model.initialise(datamodule.data.recordings["rotation"])
    truth = datamodule.data.truth.matrix
    assert matrix_error(model.calibration_matrix(), truth) < 1e-9
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        model.shape.mul_(1 + 0.1 * torch.randn(model.shape.shape, generator=generator, dtype=model.shape.dtype))
        model.offset.add_(0.1 * torch.randn(model.offset.shape, generator=generator, dtype=model.offset.dtype))
    assert matrix_error(model.calibration_matrix(), truth) > 0.05
    trainer = instantiate(cfg.trainer, logger=False, enable_checkpointing=False)
    trainer.fit(LearnerModule(model, instantiate(cfg.optimizer)), datamodule=datamodule)
    assert matrix_error(model.calibration_matrix(), truth) < 1e-6


def test_gradient_refinement_keeps_exact_closed_form(run_dir: Path):
    metrics = train(compose_config(["experiment=lord3dof", *NOISE_FREE]), run_dir)
    assert metrics["matrix_error_relative"] < 1e-6


def test_default_fingertip_accuracy_within_paper_figure(run_dir: Path):
    """Paper-like noise (1 % of the load): shape from motion within 0.3 % for every test mass."""
    metrics = train(compose_config([]), run_dir)
    errors = {k: v for k, v in metrics.items() if k.startswith("eval/") and k.endswith("/error_pct") and "max" not in k}
    assert len(errors) == 5
    assert max(errors.values()) <= 0.3, errors


def test_run_directory_contents(run_dir: Path):
    train(compose_config(["experiment=lord3dof"]), run_dir)
    calibration = json.loads((run_dir / "calibration.json").read_text())
    assert set(calibration) >= {"matrix", "offset", "channels", "axes", "singular_values", "residual_rms"}
    assert len(calibration["matrix"]) == 3 and len(calibration["matrix"][0]) == 6
    assert len(calibration["offset"]) == 6
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert all(isinstance(v, float) for v in metrics.values())
    assert (run_dir / "checkpoints" / "shape_from_motion" / "last.ckpt").is_file()
    events = EventAccumulator(str(run_dir / "tensorboard" / "shape_from_motion"))
    events.Reload()
    assert set(events.Tags()["images"]) == {"shape_from_motion/motion", "shape_from_motion/spectrum"}
    assert {"train/loss", "train/metric_constraint", "error/matrix_relative"} <= set(events.Tags()["scalars"])
    assert len(events.Scalars("train/loss")) == compose_config([]).trainer.max_epochs
    for name in ("shape_from_motion_motion.png", "shape_from_motion_spectrum.png"):
        assert (run_dir / "figures" / name).stat().st_size > 10_000
    # The saved file applies to readings the same way the model does.
    loaded = Calibration.load(run_dir / "calibration.json")
    readings = torch.randn(5, 6, dtype=torch.float64)
    assert loaded.apply(readings).shape == (5, 3)


def test_table1_reproduces_paper_ordering(run_dir: Path):
    """At the rig's default load-application errors, shape from motion is at least as accurate and precise."""
    metrics = train(compose_config(["experiment=table1"]), run_dir)
    for load in ("60.4", "111.4"):
        assert metrics[f"eval/{load}/error_pct"] <= metrics[f"least_squares/eval/{load}/error_pct"]
        assert metrics[f"eval/{load}/std_dev"] <= metrics[f"least_squares/eval/{load}/std_dev"]
    rows = (run_dir / "table1.csv").read_text().splitlines()
    assert rows[0].startswith("load,least_squares_mean,least_squares_error_pct,least_squares_std_dev")
    assert len(rows) == 6


def test_least_squares_beats_shape_from_motion_with_perfect_loads(run_dir: Path):
    """The other side of the crossover (method §7): with only the stage's 0.2 degree error, least squares wins precision."""
    cfg = compose_config(
        ["experiment=table1", "data.errors.string_misalignment_deg=0", "data.errors.friction=0",
         "data.errors.out_of_plane_deg=0", "data.errors.mass_error=0"]
    )
    metrics = train(cfg, run_dir)
    assert metrics["least_squares/eval/max_std_dev"] < metrics["eval/max_std_dev"]


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_fast_dev_run(experiment: str, run_dir: Path, tmp_path: Path):
    overrides = [f"experiment={experiment}", "trainer.fast_dev_run=true", *experiment_overrides(experiment, tmp_path)]
    metrics = train(compose_config(overrides), run_dir)
    if (run_dir / "learner.npz").is_file():
        assert metrics["rank"] >= 1
    elif (run_dir / "pca.npz").is_file():
        assert metrics["rows"] >= 1
    else:
        calibration = json.loads((run_dir / "calibration.json").read_text())
        if len(calibration["channels"]) > len(calibration["axes"]):
            assert metrics["rank_gap"] > 1
        else:
            # As many channels as axes: no singular value beyond the load space, the bars from the constraint.
            assert "rank_gap" not in metrics and 0 < metrics["matrix_std_relative"] < 1


def test_existing_results_are_never_overwritten(run_dir: Path):
    (run_dir / "metrics.json").write_text("{}")
    from sfmnet.errors import SfmnetError

    with pytest.raises(SfmnetError, match="already holds a run"):
        train(compose_config(["trainer.fast_dev_run=true"]), run_dir)
    assert (run_dir / "metrics.json").read_text() == "{}"
