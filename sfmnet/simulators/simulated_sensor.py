"""Simulated calibration sessions: the 2-axis fingertip (paper eq. 1) and a 3-axis force sensor (paper section 4)."""

from __future__ import annotations

import math
from abc import abstractmethod

import torch

from sfmnet.data.calibration_datamodule import CalibrationDataModule
from sfmnet.data.recording import CalibrationData
from sfmnet.errors import SfmnetError
from sfmnet.simulators.simulation import (
    DTYPE,
    ORIENTATION_LAWS,
    LinearSensor,
    LoadApplicationErrors,
    channel_noise_std,
    evaluation_sweeps,
    least_squares_recording,
    random_directions,
    rotation_recording,
    true_masses,
)


class SimulatedSensorDataModule(CalibrationDataModule):
    """A simulated sensor and one calibration session on it, all fixed by ``seed``.

    Recordings: ``rotation`` (one mass of ``magnitude`` through ``samples`` unknown
    orientations, then ``known_loads`` loads along the first axes) and, when
    ``least_squares_masses`` is not empty, ``least_squares`` (the paper's protocol).
    Evaluation: each of ``evaluation_masses`` turned once round in ``samples_per_turn`` steps.

    Args:
        magnitude: the calibration mass's load (load units, e.g. gf).
        samples: number of unknown orientations.
        known_loads: number of known loads (``n - 1`` needs ``mirror_hint``).
        mirror_hint: name one unknown sample's rough direction (see :class:`MirrorHint`).
        motion_span: how many load axes the unknown orientations cover (default all; fewer
            simulates a session that cannot calibrate: collinear or coplanar loads).
        orientation_bias: crowd the orientations towards the last axis (0: none).
        orientation_law: how the unknown orientations are spread: ``"uniform"``, ``"hemisphere"``,
            ``"band"`` (near the equator), ``"cone"`` (within 60 degrees of the last axis) or
            ``"poses"`` (a few poses, many samples each); see :func:`sfmnet.simulators.simulation.oriented_directions`.
        poses: the number of poses of the ``"poses"`` law.
        noise_fraction: electrical noise std as a fraction of a channel's full-load signal.
        offset_scale: std of the channel offsets (raw units); 0 gives tared readings.
        errors: the load-application error model (a :class:`LoadApplicationErrors` or its fields).
        least_squares_masses: masses for the least-squares data set (empty: none).
        angle_step_deg: stage step of the least-squares protocol.
        repeats: readings averaged per least-squares load.
        evaluation_masses: test masses for the accuracy/precision protocol.
        samples_per_turn: readings per evaluation turn.
        seed: fixes the sensor and every recording.
    """

    axes: list[str]
    load_unit: str

    def __init__(
        self,
        magnitude: float,
        samples: int = 96,
        known_loads: int = 1,
        mirror_hint: bool = True,
        motion_span: int | None = None,
        orientation_bias: float = 0.0,
        orientation_law: str = "uniform",
        poses: int = 12,
        noise_fraction: float = 0.01,
        offset_scale: float = 0.0,
        errors: LoadApplicationErrors | dict | None = None,
        least_squares_masses: list[float] | None = None,
        angle_step_deg: float = 40.0,
        repeats: int = 10,
        evaluation_masses: list[float] | None = None,
        samples_per_turn: int = 360,
        seed: int = 0,
        batch_size: int | None = None,
    ) -> None:
        super().__init__(batch_size=batch_size)
        n = len(self.axes)
        if known_loads > n:
            raise SfmnetError(f"data.known_loads is {known_loads} but this sensor has {n} load axes: give 0 to {n}")
        if motion_span is not None and motion_span > n:
            raise SfmnetError(f"data.motion_span is {motion_span} but this sensor has {n} load axes: give 1 to {n} (null: all)")
        if orientation_law not in ORIENTATION_LAWS:
            raise SfmnetError(f"data.orientation_law is '{orientation_law}': use one of {', '.join(ORIENTATION_LAWS)}")
        if orientation_law == "poses" and samples < poses:
            raise SfmnetError(f"data.samples is {samples}, too few to visit data.poses={poses} poses: give at least {poses}")
        self.magnitude = magnitude
        self.samples = samples
        self.known_loads = known_loads
        self.mirror_hint = mirror_hint
        self.motion_span = motion_span
        self.orientation_bias = orientation_bias
        self.orientation_law = orientation_law
        self.poses = poses
        self.noise_fraction = noise_fraction
        self.offset_scale = offset_scale
        self.errors = errors if isinstance(errors, LoadApplicationErrors) else LoadApplicationErrors(**(errors or {}))
        self.least_squares_masses = list(least_squares_masses or [])
        self.angle_step_deg = angle_step_deg
        self.repeats = repeats
        self.evaluation_masses = list(evaluation_masses or [magnitude])
        self.samples_per_turn = samples_per_turn
        self.seed = seed

    def require_channels(self, channels: int) -> None:
        """A sensor with fewer channels than load axes cannot be calibrated."""
        if channels < len(self.axes):
            raise SfmnetError(
                f"data.channels is {channels}: a sensor with {len(self.axes)} load axes needs at least {len(self.axes)} channels"
            )

    @abstractmethod
    def true_shape(self, generator: torch.Generator) -> torch.Tensor:
        """The sensor's shape ``S``, ``n x p``."""

    def build(self) -> CalibrationData:
        generator = torch.Generator().manual_seed(self.seed)
        shape = self.true_shape(generator)
        offset = torch.randn(shape.shape[1], generator=generator, dtype=DTYPE) * self.offset_scale
        sensor = LinearSensor(shape=shape, offset=offset, noise_std=channel_noise_std(shape, self.magnitude, self.noise_fraction))
        masses = true_masses(sorted({self.magnitude, *self.least_squares_masses}), self.errors, generator)
        recordings = {
            "rotation": rotation_recording(
                sensor,
                magnitude=self.magnitude,
                true_magnitude=masses[self.magnitude],
                samples=self.samples,
                known_loads=self.known_loads,
                mirror_hint=self.mirror_hint,
                errors=self.errors,
                generator=generator,
                motion_span=self.motion_span,
                orientation_bias=self.orientation_bias,
                orientation_law=self.orientation_law,
                poses=self.poses,
            )
        }
        if self.least_squares_masses:
            recordings["least_squares"] = least_squares_recording(
                sensor,
                masses={m: masses[m] for m in self.least_squares_masses},
                angle_step_deg=self.angle_step_deg,
                repeats=self.repeats,
                errors=self.errors,
                generator=generator,
            )
        return CalibrationData(
            recordings=recordings,
            channels=[f"ch{i}" for i in range(shape.shape[1])],
            axes=list(self.axes),
            load_unit=self.load_unit,
            evaluations=evaluation_sweeps(sensor, self.evaluation_masses, self.samples_per_turn, generator),
            truth=sensor.truth(),
        )


class FingertipDataModule(SimulatedSensorDataModule):
    """The 2-axis fingertip: a cylindrical cantilever with ``channels`` axial strain gauges (paper eq. 1).

    Gauge ``i`` reads ``z_i = g_i beta_i F cos(theta - alpha_i)``, so column ``i`` of ``S`` is
    ``g_i beta_i [cos alpha_i, sin alpha_i]`` (eqs. 2-4). Loads in gram-force.

    Args:
        channels: number of gauges, spaced evenly round the beam.
        gain: nominal ``g beta``, volts per gram-force.
        gain_spread: relative std of each gauge's gain.
        misplacement_deg: std of each gauge's angular misplacement, degrees.
        **kwargs: see :class:`SimulatedSensorDataModule`.
    """

    axes = ["fx", "fy"]
    load_unit = "gf"

    def __init__(
        self,
        channels: int = 4,
        gain: float = 0.01,
        gain_spread: float = 0.1,
        misplacement_deg: float = 3.0,
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        self.require_channels(channels)
        self.channels = channels
        self.gain = gain
        self.gain_spread = gain_spread
        self.misplacement_deg = misplacement_deg

    def true_shape(self, generator: torch.Generator) -> torch.Tensor:
        nominal = torch.arange(self.channels, dtype=DTYPE) * (2 * math.pi / self.channels)
        alpha = nominal + torch.randn(self.channels, generator=generator, dtype=DTYPE) * math.radians(self.misplacement_deg)
        gains = self.gain * (1 + self.gain_spread * torch.randn(self.channels, generator=generator, dtype=DTYPE))
        return gains * torch.stack([alpha.cos(), alpha.sin()])


class ForceSensor3DataModule(SimulatedSensorDataModule):
    """A 3-axis force sensor with ``channels`` gauges, each sensitive along its own direction (paper section 4, eq. 12).

    Column ``i`` of ``S`` is ``g_i u_i`` with ``u_i`` a random unit vector (fixed by the seed)
    and ``g_i`` the gain with its spread. Loads in newtons.
    """

    axes = ["fx", "fy", "fz"]
    load_unit = "N"

    def __init__(self, channels: int = 6, gain: float = 0.1, gain_spread: float = 0.1, **kwargs) -> None:
        super().__init__(**kwargs)
        self.require_channels(channels)
        self.channels = channels
        self.gain = gain
        self.gain_spread = gain_spread

    def true_shape(self, generator: torch.Generator) -> torch.Tensor:
        directions = random_directions(self.channels, 3, generator)
        gains = self.gain * (1 + self.gain_spread * torch.randn(self.channels, generator=generator, dtype=DTYPE))
        return (directions * gains[:, None]).T
