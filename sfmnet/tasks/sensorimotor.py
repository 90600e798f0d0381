"""The primordial-learning task: each learner reads commands from held-out runs' sensors alone (paper section 6).

Run directory::

    metrics.json                 flat dict (baselines prefixed "<name>/")
    learner.npz                  the main learner (see :func:`save_learner`); baselines/<name>/learner.npz
    predictions.csv              the main learner's commands and confidence on every held-out sample
    figures/<name>_commands.png  the paper's Fig. 6 on the first held-out run
    figures/<name>_spectrum.png  singular values of the training vectors, the chosen rank marked
    tensorboard/<name>/          losses per epoch (and the autoencoder's subspace angle), the same figures
    checkpoints/<name>/last.ckpt
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from sfmnet.data.sensorimotor import SensorimotorData
from sfmnet.eval.command_metrics import command_metrics
from sfmnet.eval.figures import commands_figure, method_title, spectrum_figure
from sfmnet.io import save_npz_atomic, write_csv_atomic
from sfmnet.linalg.factorisation import truncated_svd_factors
from sfmnet.linalg.subspace import principal_angles_deg
from sfmnet.models.sensorimotor_learner import CommandReading, SensorimotorLearner
from sfmnet.tasks.base import FittedMethod, MethodResult, Task
from sfmnet.training.components import publish_figure


class SensorimotorTask(Task):
    """Fit the main learner and the baselines on the training runs; read commands on the held-out ones."""

    kind = "sensorimotor"
    ignores = {"eval.leave_one_group_out": "holds out whole runs already (data.test_runs or the data's split)"}

    def evaluate(self, fitted: FittedMethod, data: SensorimotorData) -> MethodResult:
        model: SensorimotorLearner = fitted.model
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
                "fit_seconds": fitted.seconds,
                "epochs": float(fitted.trainer.current_epoch),
            }
        )
        monitored = model.monitor()
        if "subspace_angle_deg" not in monitored:
            # Against the principal subspace of the same standardised data, for the comparison table.
            reference = truncated_svd_factors(model.standardise(data.vectors(data.train)), model.rank, centre=True).shape
            monitored["subspace_angle_deg"] = float(principal_angles_deg(model.basis(), reference).max())
        metrics.update(monitored)
        if fitted.trainer.is_global_zero:
            draw_figures(fitted, data, readings[0])
        return MethodResult(fitted.name, metrics, result=readings, model=model)

    def write(self, results: dict[str, MethodResult], data: SensorimotorData, run_dir: Path) -> dict[str, float]:
        main, *baselines = results.values()
        save_learner(main.model, data, run_dir / "learner.npz")
        write_predictions(data, main.result, run_dir / "predictions.csv")
        metrics = dict(main.metrics)
        for result in baselines:
            save_learner(result.model, data, run_dir / "baselines" / result.name / "learner.npz")
            metrics.update({f"{result.name}/{key}": value for key, value in result.metrics.items()})
        return metrics

    def summary(self, results: dict[str, MethodResult], data: SensorimotorData) -> list[str]:
        return [headline(name, result.metrics, data) for name, result in results.items()]


def draw_figures(fitted: FittedMethod, data: SensorimotorData, reading: CommandReading) -> None:
    """Fig. 6 on the first held-out run (``reading`` is the learner's reading of it) and the spectrum."""
    name, model = fitted.name, fitted.model
    episode = data.test[0]
    labels = [np.array(c.labels, dtype=object) for c in data.commands]
    human = np.stack([labels[i][episode.commands[:, i]] for i in range(len(labels))], axis=1)
    learned = np.stack([labels[i][reading.commands[:, i]] for i in range(len(labels))], axis=1)
    words = method_title(name)
    figures = {
        "commands": commands_figure(
            data.period, [c.name for c in data.commands], [list(c.labels) for c in data.commands], human, learned,
            reading.confidence, f"{words}: human and learnt commands on a held-out run (paper Fig. 6)",
        ),
        "spectrum": spectrum_figure(
            model.singular_values, model.rank, f"{words}: singular values of the training vectors",
            "standardised units",
        ),
    }
    for tag, figure in figures.items():
        png = fitted.run_dir / "figures" / f"{name}_{tag}.png"
        publish_figure(figure, png, f"{name}/{tag}", fitted.logger, fitted.trainer.global_step)


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
