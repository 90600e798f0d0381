"""One training run: build the data and each method from the config, fit them through one Trainer setup, write results.

Sensorimotor data (primordial learning) goes to :func:`train_sensorimotor`, a row file for PCA to
:func:`train_streaming`; what follows is calibration, in memory or streamed from a row file.

Run directory layout::

    calibration.json        the main method's calibration (load = matrix @ (reading - offset))
    metrics.json            flat dict of final figures (baselines prefixed "<name>/")
    figures/*.png           recovered motion and singular-value spectrum
    tensorboard/<method>/   event files: losses per epoch, figures
    checkpoints/<method>/   last.ckpt
    baselines/<name>/calibration.json
    .hydra/config.yaml      the resolved config (written by Hydra)
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import lightning as L
import torch
from hydra.utils import instantiate
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.loggers import TensorBoardLogger
from lightning.pytorch.utilities import rank_zero_only
from matplotlib import pyplot as plt
from omegaconf import DictConfig

from sfmnet.calibration import Calibration
from sfmnet.data.calibration_datamodule import CalibrationDataModule
from sfmnet.data.recording import CalibrationData, CalibrationRecording
from sfmnet.data.row_file import RowFileDataModule
from sfmnet.data.sensorimotor import SensorimotorDataModule
from sfmnet.data.streamed_calibration import StreamedCalibrationDataModule
from sfmnet.errors import SfmnetError
from sfmnet.eval.diagnostics import calibration_diagnostics
from sfmnet.eval.figures import motion_figure, spectrum_figure
from sfmnet.eval.held_out import load_errors, magnitude_errors
from sfmnet.eval.rotation_protocol import evaluate_sweeps
from sfmnet.io import save_figure_atomic, write_json_atomic
from sfmnet.models.linear_calibrator import LinearCalibrator
from sfmnet.training.cross_validation import (
    folds_figure,
    leave_one_group_out,
    summarise_folds,
    write_folds,
)
from sfmnet.training.figure_output import publish_figure
from sfmnet.training.fitting import fit
from sfmnet.training.learner_module import matrix_error
from sfmnet.training.progress import ProgressBar
from sfmnet.training.sensorimotor_run import train_sensorimotor
from sfmnet.training.static_report import report_static_intervals
from sfmnet.training.streaming_run import train_streaming

RESULT_FILES = ("metrics.json", "calibration.json")


@dataclass
class MethodResult:
    """What one fitted method leaves behind."""

    name: str
    calibration: Calibration
    metrics: dict[str, float]
    warnings: list[str]


def quiet_lightning() -> None:
    """Keep the console to the progress bar and our summary; Lightning's notices go to the log file."""
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.pytorch.accelerators.cuda", "lightning.fabric"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=".*does not have many workers.*")
    warnings.filterwarnings("ignore", message=".*The number of training batches.*")
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")
    warnings.filterwarnings("ignore", message=".*this fit will run with no optimizer.*")


def refuse_existing_results(run_dir: Path) -> None:
    existing = [name for name in RESULT_FILES if (run_dir / name).exists()]
    if existing:
        raise SfmnetError(
            f"{run_dir} already holds a run ({', '.join(existing)}): give a new hydra.run.dir so nothing is overwritten"
        )


def fit_method(
    name: str,
    model: LinearCalibrator,
    cfg: DictConfig,
    datamodule: CalibrationDataModule,
    run_dir: Path,
    ckpt_path: str | None = None,
) -> MethodResult:
    """Fit one model through a Trainer built from ``cfg.trainer`` (resuming from ``ckpt_path``), then evaluate and plot it."""
    logger = TensorBoardLogger(save_dir=str(run_dir), name="tensorboard", version=name, default_hp_metric=False)
    checkpoint = ModelCheckpoint(dirpath=run_dir / "checkpoints" / name, save_last=True, save_top_k=0)
    callbacks = [checkpoint, ProgressBar()] if cfg.trainer.get("enable_progress_bar", True) else [checkpoint]
    started = time.perf_counter()
    trainer = fit(
        model, cfg, datamodule, ckpt_path=ckpt_path, logger=logger, callbacks=callbacks, default_root_dir=str(run_dir)
    )
    seconds = time.perf_counter() - started

    data = datamodule.data
    recording = model.report_recording(data.recordings[model.recording])
    loads = model.fitted_loads(recording)
    uncertainty = model.uncertainty(recording, loads)
    diagnostics, warnings, goodness = calibration_diagnostics(
        model, recording, data.channels, loads, uncertainty, data.load_unit
    )
    if getattr(model, "robust", None) and goodness.outlier_rows:
        # A robust fit down-weighted its outliers: its error bars describe the rows it kept.
        outlying = torch.zeros(len(loads), dtype=torch.bool)
        outlying[goodness.outlier_rows] = True
        uncertainty = model.uncertainty(recording.without(outlying), loads[~outlying])
    warnings = [*model.fit_warnings, *warnings]
    calibration = Calibration(
        matrix=model.calibration_matrix(),
        offset=model.physical_offset(),
        channels=data.channels,
        axes=data.axes,
        singular_values=model.singular_values.tolist(),
        residual_rms=model.residual_rms(recording),
        matrix_std=uncertainty.matrix_std,
        offset_std=uncertainty.offset_std,
        extra={
            "method": name,
            "load_unit": data.load_unit,
            "frame": frame_description(model),
            "noise_std": uncertainty.noise_std,
            "warnings": warnings,
            # The error bars assume the model; a failed goodness-of-fit check says they cannot be believed.
            "error_bars_trustworthy": goodness.trustworthy,
            "outlier_rows": goodness.outlier_rows[:100],
        },
    )
    metrics: dict[str, float] = {
        "residual_rms": calibration.residual_rms,
        "error_bars_trustworthy": float(goodness.trustworthy),
        "noise_std": uncertainty.noise_std,
        "matrix_std_relative": float(uncertainty.matrix_std.norm() / calibration.matrix.norm()),
        "fit_seconds": seconds,
        "epochs": float(trainer.current_epoch),
        **diagnostics,
    }
    for key, value in trainer.callback_metrics.items():
        if key.startswith("train/"):
            metrics[key] = float(value)
    if data.truth is not None:
        metrics["matrix_error_relative"] = float(matrix_error(calibration.matrix, data.truth.matrix))
        metrics["offset_error_rms"] = float((calibration.offset - data.truth.offset).pow(2).mean().sqrt())
    metrics.update(evaluate_sweeps(calibration, data.evaluations, cfg.eval.smoothing_window))
    if data.test is not None and data.test.true_loads is not None:
        errors = load_errors(calibration, data.test.readings, data.test.true_loads)
        metrics.update({f"test/{key}": value for key, value in errors.items()})
    elif data.test is not None:
        errors = magnitude_errors(calibration, data.test.readings, data.test.groups, data.test.magnitude)
        metrics.update({f"test/{key}": value for key, value in errors.items()})
    if trainer.is_global_zero:
        log_figures(name, model, recording, data.load_unit, model.singular_values, run_dir, logger, trainer.global_step)
    return MethodResult(name=name, calibration=calibration, metrics=metrics, warnings=warnings)


def frame_description(model: LinearCalibrator) -> str:
    return "known_loads" if model.frame_fixed else "arbitrary (no known loads: correct up to an orthogonal transform)"


def log_figures(
    name: str,
    model: LinearCalibrator,
    recording: CalibrationRecording,
    unit: str,
    singular: torch.Tensor,
    run_dir: Path,
    logger: TensorBoardLogger,
    step: int,
) -> None:
    """Save each figure as a PNG in the run directory and in TensorBoard."""
    figures = {"spectrum": spectrum_figure(singular, recording.rank, f"{name}: singular values of the readings")}
    if model.constrained:
        # The calibrated readings, not the constraint-pulled motion: they show the noise.
        unknown = ~recording.known
        if recording.direction_maps is None:
            motion = model.motion_of(recording.readings[unknown])
            figure = motion_figure(motion, recording.magnitude, unit, f"{name}: recovered motion")
        else:
            readings = recording.readings[unknown] / model.reading_scale
            directions = model.directions(readings, recording.row_configuration[unknown], 0.0)
            figure = motion_figure(directions, 1.0, "g", f"{name}: recovered gravity directions")
        if figure is not None:
            figures["motion"] = figure
    for tag, figure in figures.items():
        save_figure_atomic(figure, run_dir / "figures" / f"{name}_{tag}.png")
        if logger.experiment is not None:
            logger.experiment.add_figure(f"{name}/{tag}", figure, global_step=step, close=False)
        plt.close(figure)
    if logger.experiment is not None:
        # The trainer has finalised its writer; this one is ours to flush.
        logger.experiment.flush()


def train(cfg: DictConfig, run_dir: Path) -> dict[str, float]:
    """Run the configured experiment into ``run_dir``; return the flat metrics also written to ``metrics.json``."""
    run_dir = Path(run_dir)
    refuse_existing_results(run_dir)
    quiet_lightning()
    torch.set_num_threads(cfg.threads)
    L.seed_everything(cfg.seed, workers=True, verbose=False)
    datamodule: CalibrationDataModule | SensorimotorDataModule | RowFileDataModule = instantiate(cfg.data)
    datamodule.setup("fit")
    if isinstance(datamodule, SensorimotorDataModule):
        return train_sensorimotor(cfg, datamodule, run_dir)
    if isinstance(datamodule, RowFileDataModule) and not isinstance(datamodule, StreamedCalibrationDataModule):
        return train_streaming(cfg, datamodule, run_dir)

    main_model: LinearCalibrator = instantiate(cfg.model)
    models = {main_model.name: main_model}
    models.update({name: instantiate(model_cfg) for name, model_cfg in cfg.get("baselines", {}).items()})
    # Resuming (ckpt_path) applies to the main method; baselines refit, as deterministically.
    results = {
        name: fit_method(name, model, cfg, datamodule, run_dir, cfg.get("ckpt_path") if model is main_model else None)
        for name, model in models.items()
    }

    if cfg.eval.get("leave_one_group_out"):
        model_cfgs = {main_model.name: cfg.model, **cfg.get("baselines", {})}
        cross_validate(cfg, datamodule.data, model_cfgs, main_model.recording, results, run_dir)

    main = results[main_model.name]
    if rank_zero_only.rank != 0:
        # Other processes of a distributed fit (same numbers): the first one writes and reports.
        return main.metrics
    main.calibration.save(run_dir / "calibration.json")
    metrics = {**main.metrics, **report_static_intervals(datamodule.data, run_dir)}
    for name, result in results.items():
        if result is not main:
            result.calibration.save(run_dir / "baselines" / name / "calibration.json")
            metrics.update({f"{name}/{key}": value for key, value in result.metrics.items()})
    write_json_atomic(run_dir / "metrics.json", metrics)

    print(f"\nrun directory: {run_dir}")
    for result in results.values():
        print(headline(result, datamodule.data.load_unit))
        if not result.metrics.get("error_bars_trustworthy", 1.0):
            print(f"  {result.name}: NOT TRUSTWORTHY: the checks below say the model does not describe this data")
        for warning in result.warnings:
            print(f"  warning ({result.name}): {warning}")
    comparison = against_best_baseline(results, main_model.name)
    if comparison:
        print(comparison)
    if cfg.get("report"):
        print(instantiate(cfg.report)({n: r.metrics for n, r in results.items()}, datamodule.data, run_dir))
    print(f"inspect: tensorboard --logdir {run_dir}")
    return metrics


def cross_validate(
    cfg: DictConfig,
    data: CalibrationData,
    model_cfgs: dict[str, DictConfig],
    recording: str,
    results: dict[str, MethodResult],
    run_dir: Path,
) -> None:
    """Leave-one-group-out errors into each method's metrics (``lopo/...``), a CSV and a figure."""
    progress = bool(cfg.trainer.get("enable_progress_bar", True))
    folds = leave_one_group_out(cfg, data, model_cfgs, recording, progress)
    for name, summary in summarise_folds(folds).items():
        results[name].metrics.update({f"lopo/{key}": value for key, value in summary.items()})
    write_folds(folds, run_dir / "leave_one_group_out.csv")
    publish_figure(folds_figure(folds, data.load_unit), run_dir, "leave_one_group_out")


# Each experiment's main error figure, the first of these every method has: held-out first, then Table 1's.
MAIN_ERRORS = ("lopo/force_rms", "test/force_rms", "eval/max_error_pct")


def against_best_baseline(results: dict[str, MethodResult], main: str) -> str | None:
    """One line: the main method against the best baseline (e.g. the better least-squares form) by the main error figure.

    None without baselines or a figure every method has.
    """
    baselines = [result for name, result in results.items() if name != main]
    key = next((k for k in MAIN_ERRORS if all(k in r.metrics for r in results.values())), None)
    if not baselines or key is None:
        return None
    best = min(baselines, key=lambda result: result.metrics[key])
    others = ", ".join(f"{r.name} {r.metrics[key]:.4g}" for r in baselines if r is not best)
    return (
        f"  {main} against the best baseline by {key}: {results[main].metrics[key]:.4g} against "
        f"{best.name} {best.metrics[key]:.4g}" + (f" (beside {others})" if others else "")
    )


def headline(result: MethodResult, unit: str) -> str:
    m = result.metrics
    parts = []
    if "eval/max_error_pct" in m:
        parts.append(f"worst |load| error {m['eval/max_error_pct']:.3f} %, worst smoothed std {m['eval/max_std_dev']:.3f} {unit}")
    if "lopo/force_rms" in m:
        torque = f", torque {m['lopo/torque_rms']:.4f} N m" if "lopo/torque_rms" in m else ""
        parts.append(f"leave-one-out force error {m['lopo/force_rms']:.3f} {unit.split(', ')[0]} RMS{torque}")
    if "test/force_rms" in m:
        torque = f", torque {m['test/torque_rms']:.4f} N m" if "test/torque_rms" in m else ""
        parts.append(f"held-out force error {m['test/force_rms']:.3f} {unit.split(', ')[0]} RMS{torque}")
    if "test/magnitude_rms" in m:
        parts.append(
            f"held-out |load| - magnitude {m['test/magnitude_rms']:.4g} {unit} RMS over {m['test/groups']:.0f} intervals"
        )
    parts.append(f"matrix standard error {100 * m['matrix_std_relative']:.3f} % (Cramer-Rao)")
    if "goodness/outliers" in m and m["goodness/outliers"]:
        parts.append(f"{m['goodness/outliers']:.0f} outlying rows")
    if "matrix_error_relative" in m:
        parts.append(f"matrix error {100 * m['matrix_error_relative']:.3f} % (vs simulated truth)")
    if "rank_gap" in m:
        parts.append(f"rank gap {m['rank_gap']:.1f}")
    return f"  {result.name}: " + ", ".join(parts)
