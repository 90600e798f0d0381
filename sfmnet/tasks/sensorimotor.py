"""The primordial-learning task: each learner reads commands from held-out runs' sensors alone (paper section 6).

Run directory::

    metrics.json                 flat dict (baselines prefixed "<name>/")
    learner.npz                  the main learner (see :func:`save_learner`); baselines/<name>/learner.npz
    predictions.csv              the main learner's commands and confidence on every held-out sample
    figures/<name>_commands.png  the paper's Fig. 6 on the first held-out run
    figures/<name>_spectrum.png  singular values of the training vectors, the chosen rank marked
    figures/closed_loop_room<i>.png  simulated data: where each policy drove in test room i (closed loop)
    tensorboard/<name>/          losses per epoch (and the autoencoder's subspace angle), the same figures
    checkpoints/<name>/last.ckpt
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from lightning.pytorch.utilities import rank_zero_only
from lightning.pytorch.loggers import Logger
from omegaconf import DictConfig, OmegaConf

from sfmnet.data.sensorimotor import SensorimotorData
from sfmnet.eval.closed_loop import ClosedLoopResult, ClosedLoopSettings, closed_loop
from sfmnet.eval.command_metrics import command_metrics
from sfmnet.eval.figures import commands_figure, method_title, spectrum_figure
from sfmnet.io import save_npz_atomic, write_csv_atomic
from sfmnet.linalg.factorisation import truncated_svd_factors
from sfmnet.linalg.subspace import principal_angles_deg
from sfmnet.models.sensorimotor_learner import CommandReading, SensorimotorLearner
from sfmnet.tasks.base import FittedMethod, MethodResult, Task
from sfmnet.eval.trajectory_figure import trajectory_figure
from sfmnet.training.components import build_logger, publish_figure


class SensorimotorTask(Task):
    """Fit the main learner and the baselines on the training runs; read commands on the held-out ones."""

    kind = "sensorimotor"
    ignores = {"eval.leave_one_group_out": "holds out whole runs already (data.test_runs or the data's split)"}

    def __init__(self, cfg: DictConfig) -> None:
        super().__init__(cfg)
        self.closed_loop: ClosedLoopResult | None = None

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

    def after_fits(self, data: SensorimotorData, results: dict[str, MethodResult], run_dir: Path) -> None:
        """Simulated data with ``eval.closed_loop``: each learner's mapping, the teleoperator and a random policy
        drive the robot in the test rooms (sfmnet.eval.closed_loop); a figure per room."""
        settings = OmegaConf.select(self.cfg, "eval.closed_loop")
        if data.world is None or settings is None:
            return
        learners = {name: result.model for name, result in results.items()}
        self.closed_loop = closed_loop(data.world, learners, data.commands, instantiate(settings))
        if rank_zero_only.rank == 0:
            draw_closed_loop(self.closed_loop, data, run_dir, build_logger(self.cfg, run_dir, "closed_loop"))

    def write(self, results: dict[str, MethodResult], data: SensorimotorData, run_dir: Path) -> dict[str, float]:
        main, *baselines = results.values()
        save_learner(main.model, data, run_dir / "learner.npz")
        write_predictions(data, main.result, run_dir / "predictions.csv")
        metrics = dict(main.metrics)
        for result in baselines:
            save_learner(result.model, data, run_dir / "baselines" / result.name / "learner.npz")
            metrics.update({f"{result.name}/{key}": value for key, value in result.metrics.items()})
        if self.closed_loop is not None:
            metrics.update(self.closed_loop.flat_metrics())
        return metrics

    def summary(self, results: dict[str, MethodResult], data: SensorimotorData) -> list[str]:
        lines = [headline(name, result.metrics, data) for name, result in results.items()]
        if self.closed_loop is not None:
            lines += closed_loop_lines(self.closed_loop, data)
        return lines


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


def closed_loop_caption(figures: dict[str, float], settings: ClosedLoopSettings) -> str:
    """E.g. ``wheel turning 97.6 % of the time, 76 of 76 bumps/stalls escaped within 10 s, 7.8 bumps/min``."""
    escaped = round(figures["escape_rate"] * figures["incidents"]) if figures["incidents"] else 0
    return (
        f"wheel turning {100 * figures['moving_fraction']:.1f} % of the time, {escaped} of {int(figures['incidents'])} "
        f"bumps/stalls escaped within {settings.escape_seconds:g} s, {figures['bumps_per_minute']:.1f} bumps/min"
    )


def closed_loop_lines(result: ClosedLoopResult, data: SensorimotorData) -> list[str]:
    settings = result.settings
    lines = [
        f"  closed loop, commands read from the robot's own sensors every {data.period:g} s "
        f"({len(data.world.test_rooms)} test rooms x {settings.runs_per_room} runs of {settings.seconds:g} s):"
    ]
    lines += [f"    {policy}: {closed_loop_caption(figures, settings)}" for policy, figures in result.metrics.items()]
    return lines


def draw_closed_loop(result: ClosedLoopResult, data: SensorimotorData, run_dir: Path, logger: Logger | None) -> None:
    """``figures/closed_loop_room<i>.png``: every policy's paths in test room ``i`` (1-based)."""
    settings = result.settings
    captions = {policy: closed_loop_caption(figures, settings).replace(", ", "\n", 1) for policy, figures in result.metrics.items()}
    for number, (room, runs) in enumerate(result.rooms(data.world), start=1):
        title = (
            f"Closed loop in test room {number} of {len(data.world.test_rooms)}: each policy drives the robot from its "
            f"own sensors, {settings.runs_per_room} runs of {settings.seconds:g} s\n(the figures under each name are over "
            "every test room)"
        )
        figure = trajectory_figure(room, runs, captions, title)
        publish_figure(figure, run_dir / "figures" / f"closed_loop_room{number}.png", f"closed_loop/room{number}", logger)


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
    auroc = metrics["confidence_auroc"]
    # Undefined where every held-out command was right (or every one wrong), or every row has one confidence (a method
    # with no confidence measure, such as least squares): nothing to rank.
    parts.append(
        f"confidence AUROC {auroc:.2f}" if math.isfinite(auroc) else "confidence AUROC undefined (no wrong and right "
        "commands to rank, or one confidence on every row, as a method without a confidence measure gives)"
    )
    parts.append(f"subspace angle to PCA {metrics['subspace_angle_deg']:.2f} deg")
    return f"  {name}: " + "; ".join(parts)
