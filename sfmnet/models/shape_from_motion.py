"""Shape from motion: the factorisation ``Z = M S (+ 1 o^T)`` with the metric constraint as a loss term."""

from __future__ import annotations

import math

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import (
    fit_ellipsoid,
    metric_gram,
    metric_shape,
    metric_unknowns,
    require_coverage,
    truncated_svd_factors,
)
from sfmnet.linalg.frame import frame_rotation
from sfmnet.linalg.motion import constrained_motion
from sfmnet.models.linear_calibrator import Batch, LinearCalibrator
from sfmnet.models.losses import metric_constraint_loss, reconstruction_loss


class ShapeFromMotion(LinearCalibrator):
    """Rank-n factorisation of raw readings into motion ``M`` and shape ``S``, the metric constraint a loss term.

    Loss (NOTES 5), readings in units of their RMS norm and loads in units of ``F``::

        L = (1/f) [ sum_j |z_j - m_j S - o|^2                            unknown-load rows
                    + metric_weight * sum_j ((|m_j|^2 - 1) / 2)^2     unknown-load rows
                    + sum_k |z_k - f_k S - o|^2 ]                      known-load rows

    Each unknown row's ``m_j`` is the minimiser of its own terms given ``S`` and ``o``
    (:func:`constrained_motion`, variable projection), so the trainer's optimiser works on
    ``S`` and ``o`` alone: a small, well-conditioned problem. Known loads are used as their
    rows' motion, their maximum-likelihood use, which also holds the frame during training.
    ``metric_weight = 0`` is the unconstrained affine factorisation (truncated SVD, or PCA
    when centred); large weights approach the hard constraint of maximum likelihood.

    The closed form (paper eqs. 7-11, NOTES 2-4) is the first step of fitting.

    Args:
        rank: ``n``, the number of load axes (2, 3, 6, ...); None takes it from the data.
        metric_weight: weight of the metric-constraint loss (0: unconstrained).
        estimate_offset: learn channel offsets (ellipsoid closed form, NOTES 4); else tared readings.
    """

    name = "shape_from_motion"
    recording = "rotation"

    def __init__(self, rank: int | None = None, metric_weight: float = 1000.0, estimate_offset: bool = True) -> None:
        super().__init__(estimate_offset=estimate_offset)
        self.rank = rank
        self.metric_weight = metric_weight

    def initialise(self, recording: CalibrationRecording) -> None:
        self.rank = self.rank or recording.rank
        if recording.rank != self.rank:
            raise SfmnetError(
                f"model.rank is {self.rank} but the data has {recording.rank} load axes: set model.rank={recording.rank}"
            )
        magnitude = recording.magnitude
        constrained = self.metric_weight > 0
        if constrained and not math.isfinite(magnitude):
            raise SfmnetError("the metric constraint needs the load magnitude: set data.magnitude (load units)")
        # Every row of a rotation recording is the same mass, known loads included.
        readings = recording.readings
        needed = metric_unknowns(self.rank, self.estimate_offset) if constrained else self.rank + self.estimate_offset
        if len(readings) < needed:
            raise SfmnetError(
                f"only {len(readings)} samples for {needed} unknowns of the metric constraint"
                f"{' with offsets' if self.estimate_offset else ''}: record at least {needed} orientations "
                "(dozens give a good calibration)"
            )
        factors = truncated_svd_factors(readings, self.rank, centre=self.estimate_offset)
        self.singular_values = factors.singular_values
        shape, offset = factors.shape, factors.mean
        if constrained and self.estimate_offset:
            ellipsoid = fit_ellipsoid(factors.motion, magnitude)
            offset = factors.mean + ellipsoid.centre @ factors.shape
            shape = metric_shape(factors.shape, ellipsoid.gram)
        elif constrained:
            shape = metric_shape(factors.shape, metric_gram(factors.motion, magnitude))
        self.set_solution(shape, offset, recording.readings, load_scale=magnitude if constrained else 1.0)
        if constrained:
            self.coverage = require_coverage(self.motion_of(readings), magnitude)
        self.orient(recording)

    def motion(self, readings: torch.Tensor, loads: torch.Tensor) -> torch.Tensor:
        """Rows' motion in the model's units: the known load where given, else :func:`constrained_motion`.

        Args:
            readings: ``b x p`` divided by ``reading_scale``; loads: ``b x n`` divided by ``load_scale``, NaN if unknown.
        """
        unknown = torch.isnan(loads).any(dim=1)
        motion = loads.clone()
        motion[unknown] = constrained_motion(
            readings[unknown] - self.offset.detach(), self.shape.detach(), self.metric_weight
        )
        return motion

    def loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        _, readings, loads = batch
        readings = readings / self.reading_scale
        loads = loads / self.load_scale
        unknown = torch.isnan(loads).any(dim=1)
        motion = self.motion(readings, loads)
        terms = {
            "reconstruction": reconstruction_loss(readings, motion, self.shape, self.offset, unknown),
            "metric_constraint": metric_constraint_loss(motion, unknown),
            "known_load": reconstruction_loss(readings, motion, self.shape, self.offset, ~unknown),
        }
        terms["loss"] = terms["reconstruction"] + self.metric_weight * terms["metric_constraint"] + terms["known_load"]
        return terms

    def unknown_loads(self, recording: CalibrationRecording) -> torch.Tensor:
        """The fitted loads of the constant-magnitude rows, put exactly on the sphere of radius ``F``."""
        unknown = ~recording.known
        motion = constrained_motion(
            recording.readings[unknown] / self.reading_scale - self.offset.detach(), self.shape.detach(), self.metric_weight
        )
        return recording.magnitude * motion / motion.norm(dim=1, keepdim=True)

    @torch.no_grad()
    def orient(self, recording: CalibrationRecording) -> None:
        """Turn the closed-form solution into the known loads' frame by Procrustes (NOTES 3).

        Training then keeps that frame: the known-load term holds it, and with ``n - 1``
        known loads the mirror image is a discrete jump no gradient step makes. Without
        known loads the frame stays arbitrary (``frame_fixed`` is False).
        """
        known = recording.known
        self.frame_fixed = bool(known.any())
        if not self.frame_fixed:
            return
        hint = recording.mirror_hint
        hint_motion = None
        if hint is not None:
            unknown_rows = torch.nonzero(~known)[:, 0]
            if not 0 <= hint.sample < len(unknown_rows):
                raise SfmnetError(
                    f"mirror_hint.sample is {hint.sample} but there are {len(unknown_rows)} unknown-orientation rows"
                )
            hint_motion = self.motion_of(recording.readings[unknown_rows[hint.sample]][None])
        rotation = frame_rotation(self.motion_of(recording.readings[known]), recording.loads[known], hint_motion, hint)
        self.shape.copy_(rotation.T @ self.shape)
