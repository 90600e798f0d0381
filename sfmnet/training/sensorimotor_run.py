"""One primordial-learning run: fit each learner through the Trainer, read commands on held-out runs, write results.

Run directory layout::

    metrics.json                 flat dict (baselines prefixed "<name>/")
    learner.npz                  the main learner (see :func:`save_learner`); baselines/<name>/learner.npz
    predictions.csv              the main learner's commands and confidence on every held-out sample
    figures/<name>_commands.png  the paper's Fig. 6 on the first held-out run
    figures/<name>_spectrum.png  singular values of the training vectors, the chosen rank marked
    tensorboard/<name>/          losses per epoch (and the autoencoder's subspace angle), the same figures
    checkpoints/<name>/last.ckpt
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from matplotlib import pyplot as plt
from omegaconf import DictConfig

from sfmnet.data.sensorimotor import SensorimotorData, SensorimotorDataModule
from sfmnet.eval.command_metrics import command_metrics
from sfmnet.eval.figures import commands_figure, spectrum_figure
from sfmnet.io import (
    save_figure_atomic,
    save_npz_atomic,
    write_csv_atomic,
    write_json_atomic,
)
from sfmnet.linalg.factorisation import truncated_svd_factors
from sfmnet.linalg.subspace import principal_angles_deg
from sfmnet.models.sensorimotor_learner import CommandReading, SensorimotorLearner
from sfmnet.training.fitting import fit
from sfmnet.training.progress import ProgressBar


def train_sensorimotor(cfg: DictConfig, datamodule: SensorimotorDataModule, run_dir: Path) -> dict[str, float]:
    """Fit ``cfg.model`` and ``cfg.baselines`` on the training runs; evaluate on the held-out ones."""
    data = datamodule.data
    models: dict[str, SensorimotorLearner] = {}
    main = instantiate(cfg.model)
    models[main.name] = main
    models.update({name: instantiate(model_cfg) for name, model_cfg in cfg.get("baselines", {}).items()})
    results = {name: fit_and_evaluate(name, model, cfg, datamodule, run_dir) for name, model in models.items()}

    save_learner(main, data, run_dir / "learner.npz")
    write_predictions(data, results[main.name].readings, run_dir / "predictions.csv")
    metrics = dict(results[main.name].metrics)
    for name, model in models.items():
        if name != main.name:
            save_learner(model, data, run_dir / "baselines" / name / "learner.npz")
            metrics.update({f"{name}/{key}": value for key, value in results[name].metrics.items()})
    write_json_atomic(run_dir / "metrics.json", metrics)

    print(f"\nrun directory: {run_dir}")
    for name, result in results.items():
        print(headline(name, result.metrics, data))
    print(f"inspect: tensorboard --logdir {run_dir}")
    return metrics


@dataclass(frozen=True)
class Evaluation:
    """A fitted learner's figures, and what it read on each held-out run (for the figure and predictions.csv)."""

    metrics: dict[str, float]
    readings: list[CommandReading]


def fit_and_evaluate(
    name: str, model: SensorimotorLearner, cfg: DictConfig, datamodule: SensorimotorDataModule, run_dir: Path
) -> Evaluation:
    data = datamodule.data
    logger = TensorBoardLogger(save_dir=str(run_dir), name="tensorboard", version=name, default_hp_metric=False)
    checkpoint = ModelCheckpoint(dirpath=run_dir / "checkpoints" / name, save_last=True, save_top_k=0)
    callbacks = [checkpoint, ProgressBar()] if cfg.trainer.get("enable_progress_bar", True) else [checkpoint]
    started = time.perf_counter()
    trainer = fit(model, cfg, datamodule, logger=logger, callbacks=callbacks, default_root_dir=str(run_dir))
    seconds = time.perf_counter() - started

    readings = [model.read_commands(torch.from_numpy(episode.sensors)) for episode in data.test]
    metrics = command_metrics(
        data.commands,
        np.concatenate([e.commands for e in data.test]),
        np.concatenate([r.commands for r in readings]),
        np.concatenate([r.confidence for r in readings]),
    )
    metrics.update(
        {
            "rank": float(model.rank),
            "heldout_reconstruction_error": model.reconstruction_error(data.vectors(data.test)),
            "train_reconstruction_error": model.reconstruction_error(data.vectors(data.train)),
            "fit_seconds": seconds,
            "epochs": float(trainer.current_epoch),
        }
    )
    if hasattr(model, "monitor"):
        metrics.update(model.monitor())
    else:
        # Against the principal subspace of the same standardised data, for the comparison table.
        reference = truncated_svd_factors(model.standardise(data.vectors(data.train)), model.rank, centre=True).shape
        metrics["subspace_angle_deg"] = float(principal_angles_deg(model.basis(), reference).max())
    log_figures(name, model, data, readings[0], run_dir, logger, trainer.global_step)
    return Evaluation(metrics, readings)


def log_figures(
    name: str,
    model: SensorimotorLearner,
    data: SensorimotorData,
    reading: CommandReading,
    run_dir: Path,
    logger: TensorBoardLogger,
    step: int,
) -> None:
    """Fig. 6 on the first held-out run (``reading`` is the learner's reading of it) and the spectrum."""
    episode = data.test[0]
    labels = [np.array(c.labels, dtype=object) for c in data.commands]
    human = np.stack([labels[i][episode.commands[:, i]] for i in range(len(labels))], axis=1)
    learned = np.stack([labels[i][reading.commands[:, i]] for i in range(len(labels))], axis=1)
    figures = {
        "commands": commands_figure(
            data.period, [c.name for c in data.commands], human, learned, reading.confidence,
            f"{name}: human and learnt commands on a held-out run (paper Fig. 6)",
        ),
        "spectrum": spectrum_figure(model.singular_values, model.rank, f"{name}: singular values, chosen rank {model.rank}"),
    }
    for tag, figure in figures.items():
        save_figure_atomic(figure, run_dir / "figures" / f"{name}_{tag}.png")
        logger.experiment.add_figure(f"{name}/{tag}", figure, global_step=step, close=False)
        plt.close(figure)
    logger.experiment.flush()


def save_learner(model: SensorimotorLearner, data: SensorimotorData, path: Path) -> None:
    """``columns``, ``mean`` and ``scale`` (standardisation), ``basis`` (``k x m``, standardised units),
    ``centre`` (``m``), ``sensor_count`` and the singular values of the standardised training vectors."""
    save_npz_atomic(
        path,
        columns=np.array(data.columns),
        mean=model.column_mean.numpy(),
        scale=model.column_scale.numpy(),
        basis=model.basis().detach().numpy(),
        centre=model.centre().detach().numpy(),
        sensor_count=np.array(model.sensor_count),
        singular_values=model.singular_values.numpy(),
    )


def write_predictions(data: SensorimotorData, readings: list[CommandReading], path: Path) -> None:
    """Every held-out sample: run, step, each command's human and learnt label, and the confidence."""
    rows = []
    for number, (episode, reading) in enumerate(zip(data.test, readings)):
        for step in range(len(episode.sensors)):
            cells = [number, step]
            for i, command in enumerate(data.commands):
                cells += [command.labels[episode.commands[step, i]], command.labels[reading.commands[step, i]]]
            rows.append([*cells, f"{reading.confidence[step]:.6f}"])
    header = ["run", "step", *(f"{c.name}_{who}" for c in data.commands for who in ("human", "learnt")), "confidence"]
    write_csv_atomic(path, header, rows)


def headline(name: str, metrics: dict[str, float], data: SensorimotorData) -> str:
    parts = [f"rank {int(metrics['rank'])}"]
    for command in data.commands:
        part = f"{command.name} accuracy {metrics[f'{command.name}_accuracy']:.3f} (kappa {metrics[f'{command.name}_kappa']:.2f})"
        if command.signed:
            part += (
                f", when-F1 {metrics[f'{command.name}_when_f1']:.3f}"
                f", direction {metrics[f'{command.name}_direction_accuracy']:.3f}"
            )
        parts.append(part)
    parts.append(f"confidence AUROC {metrics['confidence_auroc']:.2f}")
    parts.append(f"subspace angle to PCA {metrics['subspace_angle_deg']:.2f} deg")
    return f"  {name}: " + "; ".join(parts)
