"""What every calibration model shares: a shape ``S`` and offsets ``o`` learnt from one recording."""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

import torch
from torch import nn

from sfmnet.calibration import Calibration, calibration_matrix
from sfmnet.data.recording import CalibrationRecording
from sfmnet.data.rows import IntervalSums
from sfmnet.linalg.frame import channel_frame_rotation
from sfmnet.linalg.uncertainty import CalibrationUncertainty, calibration_uncertainty
from sfmnet.models.contracts import FitMode

# The unknown-load rows' unit directions ``u`` (``f' x d``) and maps ``D`` (``f' x d x n``): their loads are ``u D``.
UnknownRows = tuple[torch.Tensor, torch.Tensor]

Batch = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


class LinearCalibrator(nn.Module, ABC):
    """``Z = M S + 1 o^T``; the calibration is ``load = pinv(S)^T (z - o)``.

    Parameters live in dimensionless units, readings divided by ``reading_scale`` (RMS norm
    of the centred readings) and loads by ``load_scale`` (the load magnitude, or one scale
    per load axis where forces and torques mix), so every
    parameter is of order one: a gradient optimiser then sees a well-conditioned problem
    whatever the sensor's units. They are created by :meth:`initialise`, once the data's
    size is known.

    Attributes:
        name: the method's name in results and file names.
        recording: the name of the recording this model learns from.
        estimate_offset: learn ``o`` (else the readings are taken as tared, ``o = 0``).
        frame_fixed: False while the load frame is arbitrary (no known loads).
        coverage: see :func:`sfmnet.linalg.factorisation.motion_coverage`; NaN where it does not apply.

    Each is a :class:`sfmnet.models.contracts.Learner`: fitted by the trainer's steps on
    ``loss(batch)`` (``FitMode.STEPS``, the default here; a batch is ``(index, readings, loads)``,
    :data:`Batch`), by its own ``alternate`` rounds, or from streamed sums (``FitMode.PASSES``).
    """

    name: str
    recording: str
    # Whether the metric constraint shapes the motion (the motion figure is drawn then).
    constrained = False
    # A robust loss that down-weights outlying rows (ShapeFromMotion's "huber"), or None.
    robust: str | None = None
    # Whether the fit maximises the likelihood with each row's direction a parameter (not one integrated out).
    joint_likelihood = True

    def __init__(self, estimate_offset: bool) -> None:
        super().__init__()
        self.estimate_offset = estimate_offset
        self.register_parameter("shape", None)
        self.register_parameter("offset", None)
        self.register_buffer("reading_scale", None)
        self.register_buffer("load_scale", None)
        self.singular_values: torch.Tensor | None = None
        self.frame_fixed = True
        # Without known loads, whether the frame was turned to the channels' own (:meth:`turn_to_channels`).
        self.frame_of_channels = False
        self.coverage = float("nan")
        # What the fit noticed on the way (e.g. a glitch left out of its start), reported beside its warnings.
        self.notes: list[str] = []

    @property
    def is_initialised(self) -> bool:
        return self.shape is not None

    @abstractmethod
    def initialise(self, recording: CalibrationRecording) -> None:
        """Create the parameters from the closed-form solution: the first step of fitting."""

    @property
    def fit_warnings(self) -> list[str]:
        """What the fit itself has to say (its notes; e.g. not converged), beside the diagnostics' warnings."""
        return list(self.notes)

    @property
    def fit_failed(self) -> bool:
        """Whether the fit itself failed or is biased beyond its error bars (one of :attr:`fit_warnings` says how)."""
        return False

    def fit_mode(self) -> FitMode:
        return FitMode.STEPS

    @property
    def learnt_orientation_law(self) -> bool:
        """Whether the error bars rest on a law of directions learnt from the rows (not assumed uniform); False here."""
        return False

    def alternation_bias(self) -> float | None:
        """The fit's own bias to first order, a fraction of the calibration matrix, where it is known to have one
        (:func:`~sfmnet.linalg.uncertainty.alternation_bias`); None here."""
        return None

    def alternation_beside(self, recording: CalibrationRecording) -> LinearCalibrator | None:
        """A second estimator fitted to the same rows, for the diagnostics to compare with this fit; None here."""
        return None

    def prepare_step(self, batch: Batch) -> None:
        """Nothing to do before a step (the marginal refinement overrides this)."""

    def end_fit(self, recording: CalibrationRecording | None) -> None:
        """After the last step: the channels' frame again where the fit started in it (:meth:`turn_to_channels`), since
        nothing holds a frame no known load fixes and the refinement turns it (a hostile tester's magnetometer, soft
        iron, 300 rows on a hemisphere: 7.4 degrees from the channels' frame, ``C`` 18 % from symmetric, the run
        trusted)."""
        if self.frame_of_channels:
            self.turn_to_channels()

    def monitor(self) -> dict[str, float]:
        return {}

    def to_calibration(
        self,
        channels: list[str],
        axes: list[str],
        recording: CalibrationRecording | None = None,
        uncertainty: CalibrationUncertainty | None = None,
        extra: dict[str, Any] | None = None,
        loads: torch.Tensor | None = None,
    ) -> Calibration:
        """The fitted calibration: matrix, offsets and spectrum, with the residual on ``recording`` (its
        :meth:`fitted_loads`, or ``loads`` already computed) and the error bars of ``uncertainty`` where
        given; ``extra`` goes into the file beside the method and frame."""
        residual_rms = float("nan") if recording is None else self.residual_rms(recording, loads)
        return Calibration(
            matrix=self.calibration_matrix().detach(),
            offset=self.physical_offset().detach(),
            channels=list(channels),
            axes=list(axes),
            singular_values=[] if self.singular_values is None else self.singular_values.tolist(),
            residual_rms=residual_rms,
            matrix_std=None if uncertainty is None else uncertainty.matrix_std,
            offset_std=None if uncertainty is None else uncertainty.offset_std,
            extra={"method": self.name, "frame": self.frame_description(), **self.estimator_description(), **(extra or {})},
        )

    def estimator_description(self) -> dict[str, Any]:
        """What the calibration file says of how the model was fitted beyond its method (none here)."""
        return {}

    def frame_description(self) -> str:
        if self.frame_fixed:
            return "known_loads"
        if self.frame_of_channels:
            return "channels (no known loads: each axis nearest its own channel, C symmetric; right-handed where the channels are)"
        return "arbitrary (no known loads: correct up to an orthogonal transform)"

    @torch.no_grad()
    def turn_to_channels(self) -> None:
        """Without known loads and with as many channels as axes, turn the arbitrary frame into the channels' own
        (:func:`~sfmnet.linalg.frame.channel_frame_rotation`); else leave it."""
        self.frame_of_channels = False
        matrix = self.calibration_matrix()
        if self.frame_fixed or matrix.shape[0] != matrix.shape[1]:
            return
        rotation = channel_frame_rotation(matrix)
        self.shape.copy_(rotation.T @ self.shape)
        self.frame_of_channels = True

    def report_recording(self, recording: CalibrationRecording) -> CalibrationRecording:
        """The rows the results (error bars, residuals, figures) are computed on: the training recording."""
        return recording

    def set_solution(
        self, shape: torch.Tensor, offset: torch.Tensor, reading_scale: torch.Tensor, load_scale: float | torch.Tensor
    ) -> None:
        """Store a solution given in physical units (``S``: ``n x p``, ``o``: ``p``; ``load_scale`` scalar or ``n``;
        ``reading_scale`` from :func:`rms_norm` of the readings)."""
        self.reading_scale = reading_scale
        self.load_scale = torch.as_tensor(load_scale, dtype=shape.dtype)
        self.shape = dense_parameter(shape * self.load_scale.reshape(-1, 1) / self.reading_scale)
        self.offset = dense_parameter(offset / self.reading_scale, requires_grad=self.estimate_offset)

    def physical_shape(self) -> torch.Tensor:
        """``S`` in raw units per load unit, ``n x p``."""
        return self.shape.detach() * self.reading_scale / self.load_scale.reshape(-1, 1)

    def signal_to_noise_at(self, magnitude: float | torch.Tensor, noise: float) -> float:
        """``F |s| / noise``: a load of ``magnitude`` over a channel's ``noise`` (raw units), ``|s|`` the mean norm of the
        shape's columns (one channel's signal per unit load): the SNR ``auto`` and the checks go by. Infinite at no noise."""
        return float(self.physical_shape().norm(dim=0).mean() * magnitude / noise)

    def physical_offset(self) -> torch.Tensor:
        """``o`` in raw units, ``p``."""
        return self.offset.detach() * self.reading_scale

    def calibration_matrix(self) -> torch.Tensor:
        """``n x p``: ``load = C (z - o)``."""
        return calibration_matrix(self.physical_shape())

    def motion_of(self, readings: torch.Tensor) -> torch.Tensor:
        """The least-squares loads of readings under the current shape, ``f x n`` load units."""
        return (readings - self.physical_offset()) @ self.calibration_matrix().T

    def unknown_directions(self, recording: CalibrationRecording) -> UnknownRows:
        """Fitted unit directions ``u`` (``f' x d``) of the unknown-load rows and their maps ``D`` (``f' x d x n``).

        An unknown row's load is ``u D``; rows whose load is free (an unconstrained model) have
        ``u`` the load itself and ``D = I``. None here.
        """
        n = recording.rank
        return recording.loads[:0], recording.loads.new_zeros(0, n, n)

    def information_directions(self, recording: CalibrationRecording, directions: torch.Tensor) -> torch.Tensor:
        """The unknown rows' directions (``f' x d``) at which the error bars' information is evaluated: the fitted
        ``directions`` (:meth:`unknown_directions`) here."""
        return directions

    def unknown_poses(self, recording: CalibrationRecording) -> torch.Tensor | None:
        """``f'`` (long): the pose of each unknown-load row where the fit gives a pose's rows one direction; None:
        each row its own."""
        return None

    def unknown_row_weight(self, recording: CalibrationRecording) -> float:
        """How many of the fitted recording's unknown-load rows each of ``recording``'s stands for (1: all are here)."""
        return 1.0

    def interval_sums(self) -> IntervalSums | None:
        """Sums over every row of each static interval the fit saw, where its report's rows are only a sample of them
        (a streamed fit); None: the report's rows are all there is."""
        return None

    def unknown_loads(self, recording: CalibrationRecording, unknown: UnknownRows | None = None) -> torch.Tensor:
        """The fitted loads of the rows whose load is unknown, ``f' x n``; ``unknown``: :meth:`unknown_directions`
        already computed."""
        directions, maps = self.unknown_directions(recording) if unknown is None else unknown
        return torch.einsum("bd,bdn->bn", directions, maps)

    def fitted_loads(self, recording: CalibrationRecording, unknown: UnknownRows | None = None) -> torch.Tensor:
        """Each row's load, ``f x n``: the known one, else :meth:`unknown_loads`."""
        loads = recording.loads.clone()
        loads[~recording.known] = self.unknown_loads(recording, unknown)
        return loads

    def fitted_residuals(self, recording: CalibrationRecording, loads: torch.Tensor) -> torch.Tensor:
        """``z - m S - o`` per row (``f x p``) for the rows' ``loads`` (from :meth:`fitted_loads`)."""
        return recording.readings - loads @ self.physical_shape() - self.physical_offset()

    def uncertainty(
        self, recording: CalibrationRecording, loads: torch.Tensor, unknown: UnknownRows | None = None
    ) -> CalibrationUncertainty:
        """Cramer-Rao standard errors at the fitted solution (reading noise only); ``loads`` from :meth:`fitted_loads`,
        ``unknown``: :meth:`unknown_directions` already computed (each solves every row's direction again)."""
        residual = self.fitted_residuals(recording, loads)
        directions, maps = self.unknown_directions(recording) if unknown is None else unknown
        poses = self.unknown_poses(recording)
        return calibration_uncertainty(
            self.physical_shape(),
            loads[recording.known],
            self.information_directions(recording, directions),
            maps,
            self.estimate_offset,
            residual_sum_of_squares=float(torch.linalg.vector_norm(residual)) ** 2,
            observations=residual.numel(),
            free_directions=None if poses is None else len(poses.unique()),
        )

    def residual_rms(self, recording: CalibrationRecording, loads: torch.Tensor | None = None) -> float:
        """RMS of ``Z - M S - o`` per entry (raw units) with ``M`` the fitted loads: what the model leaves unexplained.

        The fitted loads obey the metric constraint, so the residual holds both what lies off the
        rank-n subspace and each row's departure from ``|m_j| = F``; with as many channels as
        axes (``p = n``) only the latter is left, and it is what the error bars rest on.
        """
        return float(self.fitted_residuals(recording, self.fitted_loads(recording) if loads is None else loads).pow(2).mean().sqrt())


def rms_norm(readings: torch.Tensor) -> torch.Tensor:
    """RMS norm of the centred readings (``f x p``): the unit the parameters are kept in."""
    return (readings - readings.mean(dim=0)).pow(2).sum(dim=1).mean().sqrt()


def dense_parameter(value: torch.Tensor, requires_grad: bool = True) -> nn.Parameter:
    """A parameter with its own contiguous storage (L-BFGS flattens gradients with ``view``)."""
    return nn.Parameter(value.detach().clone(memory_format=torch.contiguous_format), requires_grad=requires_grad)
