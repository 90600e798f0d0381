"""Shape from motion: the factorisation ``Z = M S (+ 1 o^T)`` with the metric constraint as a loss term."""

from __future__ import annotations

import math
from typing import Literal

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import (
    fit_ellipsoid,
    metric_gram,
    metric_upgrade,
    truncated_svd_factors,
)
from sfmnet.linalg.frame import frame_rotation
from sfmnet.models.linear_calibrator import Batch, LinearCalibrator, dense_parameter
from sfmnet.models.losses import known_load_loss, metric_constraint_loss, reconstruction_loss


class ShapeFromMotion(LinearCalibrator):
    """Rank-n factorisation of raw readings into motion ``M`` (a per-sample table) and shape ``S``.

    Loss (NOTES 5)::

        L = |Z - M S - 1 o^T|^2 / (f scale2)
            + metric_weight * mean_j ((|m_j|^2 - F^2) / 2F^2)^2      over unknown-load rows
            + known_load_weight * mean_k |m_k - f_k|^2 / F^2          over known-load rows

    ``metric_weight = 0`` is the unconstrained affine factorisation (truncated SVD, or PCA
    when centred). The closed form (paper eqs. 7-11, NOTES 2-4) is the first step of fitting;
    gradient steps through the trainer then refine it towards maximum likelihood.

    Args:
        rank: ``n``, the number of load axes (2, 3, 6, ...).
        metric_weight: weight of the metric-constraint loss (0: unconstrained).
        known_load_weight: weight of the known-load loss.
        estimate_offset: learn channel offsets (ellipsoid closed form, NOTES 4); else tared readings.
        init: ``"closed_form"``: the paper's solution; ``"svd"``: only the affine factors
            (eq. 8), leaving the metric upgrade to the loss.
    """

    name = "shape_from_motion"
    recording = "rotation"

    def __init__(
        self,
        rank: int,
        metric_weight: float = 100.0,
        known_load_weight: float = 100.0,
        estimate_offset: bool = False,
        init: Literal["closed_form", "svd"] = "closed_form",
    ) -> None:
        super().__init__(estimate_offset=estimate_offset)
        if init not in ("closed_form", "svd"):
            raise SfmnetError(f"model.init must be closed_form or svd, got {init!r}")
        self.rank = rank
        self.metric_weight = metric_weight
        self.known_load_weight = known_load_weight
        self.init = init
        self.register_parameter("motion", None)
        self.magnitude = float("nan")

    def initialise(self, recording: CalibrationRecording) -> None:
        if recording.rank != self.rank:
            raise SfmnetError(
                f"model.rank is {self.rank} but the data has {recording.rank} load axes: set model.rank={recording.rank}"
            )
        constrained = self.metric_weight > 0
        if constrained and not math.isfinite(recording.magnitude):
            raise SfmnetError("the metric constraint needs the load magnitude: set data.magnitude (load units)")
        self.magnitude = recording.magnitude
        unknown = recording.readings[~recording.known]
        factors = truncated_svd_factors(unknown, self.rank, centre=self.estimate_offset)
        self.singular_values = factors.singular_values
        shape, offset = factors.shape, factors.mean
        if constrained and self.init == "closed_form":
            if self.estimate_offset:
                ellipsoid = fit_ellipsoid(factors.motion, self.magnitude)
                offset = factors.mean + ellipsoid.centre @ factors.shape
                shape = torch.linalg.solve_triangular(
                    torch.linalg.cholesky(ellipsoid.gram), factors.shape, upper=False
                )
            else:
                _, shape = metric_upgrade(factors, metric_gram(factors.motion, self.magnitude))
        self.set_solution(shape, offset, recording.readings)
        self.motion = dense_parameter(self.motion_of(recording.readings))
        if self.init == "closed_form":
            self.finalise(recording)

    def loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        index, readings, loads = batch
        motion = self.motion[index]
        known = ~torch.isnan(loads).any(dim=1)
        scale = self.magnitude if math.isfinite(self.magnitude) else 1.0
        terms = {
            "reconstruction": reconstruction_loss(readings, motion, self.shape, self.offset, self.scale2),
            "metric_constraint": metric_constraint_loss(motion[~known], scale),
            "known_load": known_load_loss(motion[known], loads[known], scale),
        }
        terms["loss"] = (
            terms["reconstruction"]
            + self.metric_weight * terms["metric_constraint"]
            + self.known_load_weight * terms["known_load"]
        )
        return terms

    @torch.no_grad()
    def finalise(self, recording: CalibrationRecording) -> None:
        """Turn the solution into the known loads' frame by Procrustes (NOTES 3).

        Reconstruction and metric losses do not change under an orthogonal transform of the
        frame, so this is the exact minimiser of the known-load term over that freedom.
        Without known loads the frame stays arbitrary (``frame_fixed`` is False).
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
            hint_motion = self.motion[unknown_rows[hint.sample]][None]
        rotation = frame_rotation(self.motion[known], recording.loads[known], hint_motion, hint)
        self.motion.copy_(self.motion @ rotation)
        self.shape.copy_(rotation.T @ self.shape)
