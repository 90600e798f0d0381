"""The calibration task: each method's calibration, error bars, goodness of fit and held-out errors.

Run directory::

    calibration.json        the main method's calibration (load = matrix @ (reading - offset))
    metrics.json            flat dict of final figures (baselines prefixed "<name>/")
    figures/*.png           recovered motion and singular-value spectrum (and static intervals, leave-one-out)
    tensorboard/<method>/   event files: losses per epoch, figures
    checkpoints/<method>/   last.ckpt
    baselines/<name>/calibration.json
    .hydra/config.yaml      the resolved config (written by Hydra)
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import torch

from sfmnet.data.recording import CalibrationData, CalibrationRecording
from sfmnet.errors import FitInterrupted
from sfmnet.eval.calibration_headline import trust_lines
from sfmnet.eval.diagnostics import calibration_diagnostics
from sfmnet.eval.figures import method_title, motion_figure, spectrum_figure
from sfmnet.eval.held_out import load_errors, magnitude_errors
from sfmnet.eval.goodness_of_fit import (
    OUTLIER_METRICS,
    correlated_noise_warning,
    repeated_rows_warning,
    revisited_pose_warning,
    stuck_channel_warnings,
)
from sfmnet.eval.rotation_protocol import evaluate_sweeps
from sfmnet.linalg.uncertainty import relative_matrix_std
from sfmnet.models.linear_calibrator import LinearCalibrator
from sfmnet.tasks.base import FittedMethod, MethodResult, Task
from sfmnet.training.components import build_logger, publish_figure
from sfmnet.training.cross_validation import (
    folds_figure,
    known_load_groups,
    leave_one_group_out,
    summarise_folds,
    write_folds,
)
from sfmnet.training.learner_module import matrix_error
from sfmnet.training.static_report import report_static_intervals

# Each experiment's main error figure, the first of these every method has: held-out first, then Table 1's.
MAIN_ERRORS = ("lopo/force_rms", "test/force_rms", "eval/max_error_pct")


class CalibrationTask(Task):
    """Calibrate a sensor with the main model, beside any baselines, on one calibration data set."""

    kind = "calibration"

    def true_matrix(self, data: CalibrationData) -> torch.Tensor | None:
        return None if data.truth is None else data.truth.matrix

    def evaluate(self, fitted: FittedMethod, data: CalibrationData) -> MethodResult:
        model: LinearCalibrator = fitted.model
        recording = model.report_recording(data.recordings[model.recording])
        unknown = model.unknown_directions(recording)
        loads = model.fitted_loads(recording, unknown)
        uncertainty = model.uncertainty(recording, loads, unknown)
        diagnostics, warnings, goodness = calibration_diagnostics(
            model, recording, data.channels, loads, uncertainty, data.load_unit
        )
        if model.robust and goodness.outlier_rows:
            # A robust fit down-weighted its outliers: its error bars describe the rows it kept, and it is judged on them,
            # its outliers still counted and listed.
            outlying = torch.zeros(len(loads), dtype=torch.bool)
            outlying[goodness.outlier_rows] = True
            kept, kept_loads = recording.without(outlying), loads[~outlying]
            uncertainty = model.uncertainty(kept, kept_loads)
            counted, listed = {key: goodness.metrics[key] for key in OUTLIER_METRICS}, goodness.outlier_rows
            diagnostics, warnings, goodness = calibration_diagnostics(
                model, kept, data.channels, kept_loads, uncertainty, data.load_unit
            )
            diagnostics.update(counted)
            goodness = replace(goodness, metrics={**goodness.metrics, **counted}, outlier_rows=listed)
        detection = data.static_intervals
        judged = "static rows" if detection is not None and not detection.independent else "rows"
        repeats = None if data.row_repeats is None else repeated_rows_warning(data.row_repeats, judged)
        # Repeated rows are correlated noise too: one warning says so, the one that names the cause.
        worst = None if detection is None or repeats else detection.most_correlated_channel
        correlated = None if worst is None else correlated_noise_warning(
            float(detection.noise_correlation[worst]), detection.correlation_dof, detection.correlation_words(),
            data.channels[worst],
        )
        revisits = data.revisited_poses
        drift = None if revisits is None else revisited_pose_warning(revisits, data.channels)
        stuck = stuck_channel_warnings(data.stuck_readings, data.channels)
        # The readings' own faults first: they name a cause whose effects the fit's checks report after them.
        readings_faults = [*stuck, *([repeats] if repeats else [])]
        rows_dependent = [warning for warning in (correlated, drift) if warning]
        warnings = [*data.warnings, *readings_faults, *model.fit_warnings, *warnings, *rows_dependent]
        # The error bars assume the model, independent rows and a fit that worked; a failed check or fit says they
        # cannot be believed.
        trustworthy = goodness.trustworthy and not model.fit_failed and not readings_faults and not rows_dependent
        calibration = model.to_calibration(
            data.channels,
            data.axes,
            recording,
            uncertainty,
            extra={
                "load_unit": data.load_unit,
                "noise_std": uncertainty.noise_std,
                "matrix_std_frame_share": uncertainty.frame_share,
                "warnings": warnings,
                "error_bars_trustworthy": trustworthy,
                "outlier_rows": goodness.outlier_rows[:100],
            },
            loads=loads,
        )
        metrics: dict[str, float] = {
            "residual_rms": calibration.residual_rms,
            "error_bars_trustworthy": float(trustworthy),
            "noise_std": uncertainty.noise_std,
            "matrix_std_relative": relative_matrix_std(uncertainty.matrix_std, calibration.matrix),
            "fit_seconds": fitted.seconds,
            "epochs": float(fitted.trainer.current_epoch),
            **diagnostics,
        }
        if revisits is not None:
            metrics.update(
                {"goodness/revisit_ratio": revisits.ratio, "goodness/revisit_z": revisits.z, "goodness/poses_revisited": float(revisits.poses)}
            )
        if uncertainty.frame_share is not None:
            metrics["matrix_std_frame_share"] = uncertainty.frame_share
            metrics["known_load_rows"] = float(recording.known.sum())
        for key, value in fitted.trainer.callback_metrics.items():
            if key.startswith("train/"):
                metrics[key] = float(value)
        if data.truth is not None:
            metrics["matrix_error_relative"] = float(matrix_error(calibration.matrix, data.truth.matrix))
            metrics["offset_error_rms"] = float((calibration.offset - data.truth.offset).pow(2).mean().sqrt())
        metrics.update(evaluate_sweeps(calibration, data.evaluations, self.cfg.eval.smoothing_window))
        if data.test is not None and data.test.true_loads is not None:
            errors = load_errors(calibration, data.test.readings, data.test.true_loads)
            metrics.update({f"test/{key}": value for key, value in errors.items()})
        elif data.test is not None:
            errors = magnitude_errors(calibration, data.test.readings, data.test.groups, data.test.magnitude)
            metrics.update({f"test/{key}": value for key, value in errors.items()})
        if fitted.trainer.is_global_zero:
            draw_figures(fitted, recording, data.load_unit, data.axes)
        return MethodResult(fitted.name, metrics, warnings, calibration, model)

    def after_fits(self, data: CalibrationData, results: dict[str, MethodResult], run_dir: Path) -> None:
        """With ``eval.leave_one_group_out``: every method refitted per held-out group (``lopo/...``), a CSV and a figure."""
        if not self.cfg.eval.get("leave_one_group_out"):
            return
        main = next(iter(results.values()))
        model_cfgs = {main.name: self.cfg.model, **self.cfg.get("baselines", {})}
        progress = bool(self.cfg.trainer.get("enable_progress_bar", True))
        # The groups held out are those of the main method's recording.
        try:
            folds = leave_one_group_out(self.cfg, data, model_cfgs, main.model.recording, progress)
        except FitInterrupted:
            # A fold's fit keeps no checkpoint; the methods' own fits, finished, do.
            checkpoints = sorted(run_dir.glob("checkpoints/*/last.ckpt"))
            resume = checkpoints[0] if len(checkpoints) == 1 else run_dir / "checkpoints" / "<method>" / "last.ckpt"
            raise FitInterrupted(
                "stopped while refitting without each group (eval.leave_one_group_out), after every method's own fit: "
                f"resume with ckpt_path={resume} (and a new hydra.run.dir); the groups are refitted from the start"
            ) from None
        for name, summary in summarise_folds(folds).items():
            results[name].metrics.update({f"lopo/{key}": value for key, value in summary.items()})
        for fold in folds:
            for key, value in fold.errors.items():
                results[fold.method].series.setdefault(f"leave_one_group_out/{key}", {})[fold.group] = value
        write_folds(folds, run_dir / "leave_one_group_out.csv")
        figure = folds_figure(folds, data.load_unit, known_load_groups(data, main.model.recording))
        publish_figure(figure, run_dir / "figures" / "leave_one_group_out.png", "leave_one_group_out",
                       build_logger(self.cfg, run_dir, "leave_one_group_out"))

    def write(self, results: dict[str, MethodResult], data: CalibrationData, run_dir: Path) -> dict[str, float]:
        main, *baselines = results.values()
        main.result.save(run_dir / "calibration.json")
        static_metrics, self.static_line = report_static_intervals(data, run_dir, build_logger(self.cfg, run_dir, "static_intervals"))
        metrics = {**main.metrics, **static_metrics}
        for result in baselines:
            result.result.save(run_dir / "baselines" / result.name / "calibration.json")
            metrics.update({f"{result.name}/{key}": value for key, value in result.metrics.items()})
        return metrics

    def summary(self, results: dict[str, MethodResult], data: CalibrationData) -> list[str]:
        """The static intervals, each method's headline (the main one's with the lines that say how far to
        trust it), the warnings and the main method against the best baseline: one screen."""
        lines = [self.static_line] if self.static_line else []
        main = next(iter(results))
        for result in results.values():
            lines.append(headline(result, data.load_unit))
            if result.name == main:
                recording = data.recordings[result.model.recording]
                lines.extend(
                    trust_lines(
                        result.metrics, data.channels, data.load_unit, recording.magnitude, recording.rank,
                        result.result.extra, len(result.warnings),
                    )
                )
            elif not result.metrics.get("error_bars_trustworthy", 1.0):
                lines.append(f"  {result.name}: NOT TRUSTWORTHY: the checks below say the model does not describe this data")
            lines.extend(f"  warning ({result.name}): {warning}" for warning in result.warnings)
        comparison = against_best_baseline(results, main)
        return [*lines, comparison] if comparison else lines


def draw_figures(fitted: FittedMethod, recording: CalibrationRecording, unit: str, axes: list[str]) -> None:
    """The spectrum and (constrained models) the calibrated readings: PNGs in the run directory and in TensorBoard."""
    name, model = fitted.name, fitted.model
    words = method_title(name)
    figures = {
        "spectrum": spectrum_figure(
            model.singular_values, recording.rank, f"{words}: singular values of the readings", "raw reading units"
        )
    }
    unknown = ~recording.known
    # Every row's load known: there is no recovered motion to draw.
    if model.constrained and bool(unknown.any()):
        # The calibrated readings, not the constraint-pulled motion: they show the noise.
        if recording.direction_maps is None:
            motion = model.motion_of(recording.readings[unknown])
            title = f"{words}: calibrated loads of the samples of unknown orientation"
            figure = motion_figure(motion, recording.magnitude, unit, title, axes)
        else:
            readings = recording.readings[unknown] / model.reading_scale
            directions = model.directions(readings, recording.row_configuration[unknown], 0.0)
            title = f"{words}: recovered gravity directions of the samples of unknown orientation"
            figure = motion_figure(directions, 1.0, "g", title, ["gravity x", "gravity y", "gravity z"])
        if figure is not None:
            figures["motion"] = figure
    for tag, figure in figures.items():
        png = fitted.run_dir / "figures" / f"{name}_{tag}.png"
        publish_figure(figure, png, f"{name}/{tag}", fitted.logger, fitted.trainer.global_step)


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
    force_unit, _, torque_unit = unit.partition(", ")
    parts = []
    if "eval/max_error_pct" in m:
        parts.append(f"worst |load| error {m['eval/max_error_pct']:.3f} %, worst smoothed std {m['eval/max_std_dev']:.3f} {unit}")
    if "lopo/force_rms" in m:
        torque = f", torque {m['lopo/torque_rms']:.4f} {torque_unit}" if "lopo/torque_rms" in m else ""
        parts.append(f"leave-one-out force error {m['lopo/force_rms']:.3f} {force_unit} RMS{torque}")
    if "test/force_rms" in m:
        torque = f", torque {m['test/torque_rms']:.4f} {torque_unit}" if "test/torque_rms" in m else ""
        parts.append(f"held-out force error {m['test/force_rms']:.3f} {force_unit} RMS{torque}")
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
