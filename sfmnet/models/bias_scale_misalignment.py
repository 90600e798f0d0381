"""The triad calibration IMU tools use: bias, scale and misalignment fitted so every static reading has magnitude F.

IMU-TK (Tedaldi, Pretto, Menegatti, ICRA 2014) calibrates an accelerometer with
``a = T K (z - b)``: biases ``b`` (3), scales ``K`` (diagonal, 3) and a misalignment ``T``
(unit upper triangular, 3), nine numbers chosen so that ``|a_j| = g`` on every static sample.
``T K`` is any upper-triangular matrix with a positive diagonal, so the model is
``load = C (z - o)`` with ``C`` upper triangular: the magnitude of the load fixes ``C`` up to
an orthogonal transform, and the triangle is the choice of frame (x along the first sensing
axis, y in the plane of the first two). Shape from motion with ``p = n`` fits the same
family with a full ``C`` in an arbitrary frame, so the two differ only in how they weigh the
data: here the magnitude error itself, ``(|C (z_j - o)| - F)^2``, summed over every row.
"""

from __future__ import annotations

import math

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import closed_form_shape, gross_outlier_note
from sfmnet.models.linear_calibrator import Batch, LinearCalibrator, rms_norm


class BiasScaleMisalignment(LinearCalibrator):
    """``load = C (z - o)``, ``C`` (``n x n``) upper triangular, fitted on ``sum_j (|C (z_j - o)| - F)^2``.

    Kept as the shape ``S = C^-T``, lower triangular, so that it is a :class:`LinearCalibrator`
    like every other model (``C = pinv(S)^T``). Started from the closed-form ellipsoid fit
    (method §4: the same family), turned into the triangular frame by a QR decomposition, then
    refined by the trainer's optimiser. Needs as many channels as axes and one load magnitude.
    """

    name = "bias_scale_misalignment"
    recording = "rotation"
    constrained = True

    def __init__(self, estimate_offset: bool = True) -> None:
        super().__init__(estimate_offset=estimate_offset)
        self.magnitude = math.nan

    def initialise(self, recording: CalibrationRecording) -> None:
        n, p = recording.rank, recording.readings.shape[1]
        if p != n or recording.direction_maps is not None:
            raise SfmnetError(
                f"the bias/scale/misalignment model is for a triad (as many channels as axes, one magnitude), "
                f"not {p} channels for {n} axes: use model=shape_from_motion"
            )
        self.magnitude = recording.magnitude
        # Fixed by convention (the triangle), not by known loads.
        self.frame_fixed = False
        solution = closed_form_shape(recording.readings, n, self.magnitude, self.estimate_offset)
        left_out = int(solution.left_out.sum())
        if left_out:
            self.notes.append(gross_outlier_note(left_out, len(recording.readings)))
        # C = pinv(S)^T = Q R: |C x| = |R x|, and R^-T is the lower-triangular shape.
        q, r = torch.linalg.qr(torch.linalg.inv(solution.shape).T)
        r = r * torch.sign(torch.diagonal(r))[:, None]
        self.singular_values = solution.singular_values
        self.set_solution(torch.linalg.inv(r).T, solution.offset, rms_norm(recording.readings), load_scale=self.magnitude)

    def triangular_shape(self) -> torch.Tensor:
        """The dimensionless shape with only its lower triangle free."""
        return torch.tril(self.shape)

    def physical_shape(self) -> torch.Tensor:
        return self.triangular_shape().detach() * self.reading_scale / self.load_scale.reshape(-1, 1)

    def loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        """``mean_j (|m_j| - 1)^2`` with ``m_j = (z_j - o) S^-1`` (loads in units of ``F``)."""
        _, readings, _ = batch
        centred = readings / self.reading_scale - self.offset
        motion = torch.linalg.solve_triangular(self.triangular_shape().T, centred.T, upper=True).T
        magnitude_error = (motion.norm(dim=1) - 1).pow(2).mean()
        return {"magnitude_error": magnitude_error, "loss": magnitude_error}

    def unknown_directions(self, recording: CalibrationRecording) -> tuple[torch.Tensor, torch.Tensor]:
        """Each row's calibrated load direction, with the map ``F I``."""
        loads = self.motion_of(recording.readings[~recording.known])
        n = recording.rank
        eye = self.magnitude * torch.eye(n, dtype=loads.dtype)
        return loads / loads.norm(dim=1, keepdim=True), eye.expand(len(loads), n, n)
