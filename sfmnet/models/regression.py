"""Least squares as practitioners calibrate: the loads regressed on the readings, every load known."""

from __future__ import annotations

import torch

from sfmnet.calibration import calibration_matrix
from sfmnet.data.recording import CalibrationRecording
from sfmnet.linalg.least_squares import (
    regress_loads,
    regression_offset,
    regression_standard_errors,
    ridge_strength_by_cross_validation,
    standardisation,
)
from sfmnet.linalg.uncertainty import CalibrationUncertainty
from sfmnet.models.least_squares import require_every_load
from sfmnet.models.linear_calibrator import Batch, LinearCalibrator, UnknownRows, rms_norm

# Seeds the random K-fold split of rows without groups (the same split every run).
FOLD_SEED = 0


class LoadRegression(LinearCalibrator):
    """``C, b = argmin sum_j |f_j - C z_j - b|^2 [+ k strength |C diag(s)|^2]``: the load error itself.

    The paper's least squares (:class:`~sfmnet.models.least_squares.LeastSquaresCalibration`)
    fits the readings from the loads and inverts; this regresses the loads on the readings
    (force/torque vendors' practice), :func:`~sfmnet.linalg.least_squares.regress_loads`, the
    offsets the intercept's (``o = -pinv(C) b``,
    :func:`~sfmnet.linalg.least_squares.regression_offset`). With ``ridge`` the slopes on the
    standardised readings (per-channel std ``s``) are shrunk, the strength chosen from a log grid
    by cross-validation on the rows this model is given (leave-one-group-out where they have
    groups, e.g. poses; else ``folds``-fold, rows dealt at random with a fixed seed): under an outer leave-one-group-out the held-out
    group is never among them.

    Stored as the base class's shape ``S = pinv(C)^T`` (so ``pinv(S)^T = C``) and ``o``; the
    reading-space figures (``residual_rms``, per-channel residuals) describe that
    minimum-norm shape, not a fitted model of the readings. The trainer's steps minimise the same
    objective in the scaled units, from its minimum, so they only confirm it. Error bars:
    :func:`~sfmnet.linalg.least_squares.regression_standard_errors` (the coefficients' standard
    errors, the known loads exact; ``noise_std`` the reading noise that would give the load residuals).

    Args:
        estimate_offset: fit the intercept (untared readings); else ``b = o = 0``.
        ridge: shrink the slopes, the strength chosen by cross-validation; else ordinary least squares.
        ridge_min, ridge_max, ridge_count: the log grid of strengths (dimensionless, see
            :func:`~sfmnet.linalg.least_squares.regress_loads`).
        folds: K of the K-fold split when the rows have no groups.
    """

    name = "regression"
    recording = "least_squares"

    def __init__(
        self,
        estimate_offset: bool = True,
        ridge: bool = False,
        ridge_min: float = 1e-8,
        ridge_max: float = 1e2,
        ridge_count: int = 41,
        folds: int = 5,
    ) -> None:
        super().__init__(estimate_offset=estimate_offset)
        self.ridge = ridge
        self.strengths = torch.logspace(
            torch.log10(torch.tensor(ridge_min)), torch.log10(torch.tensor(ridge_max)), ridge_count, dtype=torch.float64
        )
        self.folds = folds
        self.strength = 0.0
        # s / reading_scale, ``p``: the penalty's weights on the scaled calibration matrix.
        self.register_buffer("penalty_scale", None)

    def initialise(self, recording: CalibrationRecording) -> None:
        require_every_load(recording, "the load regression")
        readings, loads = recording.readings, recording.loads
        if self.ridge:
            self.strength, _ = ridge_strength_by_cross_validation(
                readings, loads, self.strengths, self.fold_labels(recording), self.estimate_offset
            )
        matrix, intercept = regress_loads(readings, loads, self.strength, self.estimate_offset)
        offset = regression_offset(matrix, intercept)
        # Of the centred readings: o is only fixed along C's rows, so readings - o may hold a constant part.
        self.singular_values = torch.linalg.svdvals(readings - readings.mean(dim=0))
        reading_scale = rms_norm(readings)
        self.penalty_scale = standardisation(readings, self.estimate_offset)[1] / reading_scale
        self.set_solution(
            torch.linalg.pinv(matrix).T, offset, reading_scale, load_scale=loads.pow(2).mean(dim=0).sqrt()
        )

    def fold_labels(self, recording: CalibrationRecording) -> torch.Tensor:
        """``f`` (long): each row's cross-validation fold, its group (two groups or more), or a seeded K-fold split."""
        if recording.groups is not None and len(recording.groups.unique()) > 1:
            return recording.groups
        rows = len(recording.readings)
        order = torch.randperm(rows, generator=torch.Generator().manual_seed(FOLD_SEED))
        labels = torch.empty(rows, dtype=torch.long)
        labels[order] = torch.arange(rows) % min(self.folds, rows)
        return labels

    def monitor(self) -> dict[str, float]:
        """The chosen ridge strength (logged with the training figures, so it reaches ``metrics.json``)."""
        return {"train/ridge_strength": self.strength} if self.ridge else {}

    def uncertainty(
        self, recording: CalibrationRecording, loads: torch.Tensor, unknown: UnknownRows | None = None
    ) -> CalibrationUncertainty:
        """The regression's standard errors (every row's load is known: ``unknown`` is unused)."""
        matrix_std, offset_std, noise_std = regression_standard_errors(
            recording.readings,
            recording.loads,
            self.calibration_matrix(),
            self.physical_offset(),
            self.strength,
            self.estimate_offset,
        )
        return CalibrationUncertainty(matrix_std=matrix_std, offset_std=offset_std, noise_std=noise_std)

    def loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        """``(1/b) sum_j |f'_j - C' (z'_j - o')|^2 + strength |C' diag(s / reading_scale)|^2`` in the scaled units.

        ``z' = z / reading_scale``, ``f' = f / load_scale`` (per axis) and ``C' = pinv(S')^T`` of the
        scaled shape; per axis it is :func:`regress_loads`'s objective divided by the axis' scale squared.
        """
        _, readings, loads = batch
        matrix = calibration_matrix(self.shape)
        error = loads / self.load_scale - (readings / self.reading_scale - self.offset) @ matrix.T
        terms = {"load_error": error.pow(2).sum() / len(readings)}
        terms["loss"] = terms["load_error"]
        if self.ridge:
            terms["ridge"] = self.strength * (matrix * self.penalty_scale).pow(2).sum()
            terms["loss"] = terms["loss"] + terms["ridge"]
        return terms
