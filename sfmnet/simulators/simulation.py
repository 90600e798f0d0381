"""Simulated linear sensors and the ways loads are applied to them (paper sections 4-5, method §7).

Every draw uses a ``torch.Generator`` so a seed fixes the sensor and all its recordings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from sfmnet.calibration import calibration_matrix
from sfmnet.data.recording import CalibrationRecording, EvaluationSweep, SensorTruth
from sfmnet.linalg.directions import direction_grid
from sfmnet.linalg.frame import MirrorHint

DTYPE = torch.float64


@dataclass(frozen=True)
class LinearSensor:
    """``z = m S + o + e``, ``e ~ N(0, noise_std^2 I)``.

    Attributes:
        shape: ``S``, ``n x p`` (raw units per load unit).
        offset: ``o``, ``p`` raw units.
        noise_std: electrical noise per channel, raw units.
    """

    shape: torch.Tensor
    offset: torch.Tensor
    noise_std: float

    def read(self, loads: torch.Tensor, generator: torch.Generator, repeats: int = 1) -> torch.Tensor:
        """Readings of ``loads`` (``k x n``), each the mean of ``repeats`` noisy samples: ``k x p``."""
        clean = loads @ self.shape + self.offset
        noise = torch.randn(clean.shape, generator=generator, dtype=DTYPE) * self.noise_std / math.sqrt(repeats)
        return clean + noise

    def truth(self) -> SensorTruth:
        return SensorTruth(matrix=calibration_matrix(self.shape), offset=self.offset.clone())


@dataclass(frozen=True)
class LoadApplicationErrors:
    """How a physically applied load differs from the one the operator believes was applied.

    Attributes:
        angle_error_deg: std of the error in setting a known direction (rotary stage), degrees.
        string_misalignment_deg: std of the pull direction's error per application, degrees.
        out_of_plane_deg: std of the pull's tilt out of the sensing plane (scales the load by cos).
        friction: relative std of the transmitted tension per application (pulley friction).
        mass_error: relative std of each mass's true value against its label (fixed per mass).
    """

    angle_error_deg: float = 0.0
    string_misalignment_deg: float = 0.0
    out_of_plane_deg: float = 0.0
    friction: float = 0.0
    mass_error: float = 0.0


def random_directions(count: int, dims: int, generator: torch.Generator) -> torch.Tensor:
    """``count x dims`` unit vectors, uniform on the circle or sphere."""
    vectors = torch.randn(count, dims, generator=generator, dtype=DTYPE)
    return vectors / vectors.norm(dim=1, keepdim=True)


ORIENTATION_LAWS = ("uniform", "hemisphere", "band", "cone", "poses")
# Half-width of the "band" law (latitude, degrees) and half-angle of the "cone" law (degrees).
BAND_HALF_WIDTH_DEG = 30.0
CONE_HALF_ANGLE_DEG = 60.0


def oriented_directions(law: str, count: int, dims: int, generator: torch.Generator, poses: int = 12) -> torch.Tensor:
    """``count x dims`` unit load directions drawn from an orientation law, the last axis "up".

    On the sphere (``dims = 3``), with ``z`` the last component:

    - ``"uniform"``: the whole sphere;
    - ``"hemisphere"``: uniform with ``z >= 0`` (a robot that keeps the mass below the sensor);
    - ``"band"``: uniform within ``BAND_HALF_WIDTH_DEG`` of the equator, ``|z| <= sin 30deg``;
    - ``"cone"``: uniform within ``CONE_HALF_ANGLE_DEG`` of the last axis, ``z >= cos 60deg``;
    - ``"poses"``: ``poses`` uniform directions drawn once, each held for ``count / poses``
      samples in turn (a robot or hand visiting a few poses, many samples each).

    Uniform over a zone of the sphere means ``z`` uniform on its interval (Archimedes) and the
    azimuth uniform. On the circle (``dims = 2``) the same laws are arcs of the angle from the
    first axis: the half circle ``y >= 0``, the two arcs within 30 degrees of the ``x`` axis, the
    arc within 60 degrees of ``+y``, and ``poses`` angles.
    """
    if law not in ORIENTATION_LAWS:
        raise ValueError(f"orientation law '{law}': use one of {', '.join(ORIENTATION_LAWS)}")
    if law == "uniform" or dims not in (2, 3):
        return random_directions(count, dims, generator)
    if law == "poses":
        if count < poses:
            raise ValueError(f"{count} samples cannot visit {poses} poses")
        return random_directions(poses, dims, generator).repeat_interleave(math.ceil(count / poses), dim=0)[:count]
    uniform = torch.rand(count, generator=generator, dtype=DTYPE)
    if dims == 3:
        low, high = sphere_zone(law)
        z = low + (high - low) * uniform
        azimuth = 2 * math.pi * torch.rand(count, generator=generator, dtype=DTYPE)
        radius = (1 - z**2).sqrt()
        return torch.stack([radius * azimuth.cos(), radius * azimuth.sin(), z], dim=1)
    centre, half_width = circle_arc(law)
    angle = centre + half_width * (2 * uniform - 1)
    if law == "band":
        # Either end of the x axis.
        angle = angle + math.pi * (torch.rand(count, generator=generator, dtype=DTYPE) < 0.5)
    return torch.stack([angle.cos(), angle.sin()], dim=1)


def sphere_zone(law: str) -> tuple[float, float]:
    """The interval of the last component ``z`` that an orientation law covers on the sphere (uniformly)."""
    band = math.sin(math.radians(BAND_HALF_WIDTH_DEG))
    cone = math.cos(math.radians(CONE_HALF_ANGLE_DEG))
    return {"uniform": (-1.0, 1.0), "hemisphere": (0.0, 1.0), "band": (-band, band), "cone": (cone, 1.0)}[law]


def circle_arc(law: str) -> tuple[float, float]:
    """Centre and half-width (radians) of the arc of angles an orientation law covers on the circle; the
    ``"band"`` law covers it and the arc opposite."""
    return {
        "uniform": (0.0, math.pi),
        "hemisphere": (math.pi / 2, math.pi / 2),
        "band": (0.0, math.radians(BAND_HALF_WIDTH_DEG)),
        "cone": (math.pi / 2, math.radians(CONE_HALF_ANGLE_DEG)),
    }[law]


def circle_directions(angles: np.ndarray, axis: np.ndarray, height: float = 0.0) -> np.ndarray:
    """``k x 3`` unit directions on the circle ``a^T u = height`` about the unit ``axis`` ``a`` (0: a great circle, as
    on a turntable), at ``angles`` (``k``, radians) from its point toward ``a x e_x``: a load turned about one axis only.
    ``axis`` must not be along ``e_x``."""
    first = np.cross(axis, [1.0, 0.0, 0.0])
    first /= np.linalg.norm(first)
    circle = np.cos(angles)[:, None] * first + np.sin(angles)[:, None] * np.cross(axis, first)
    return math.sqrt(1 - height**2) * circle + height * axis


def perturb_directions(directions: torch.Tensor, std_rad: float, generator: torch.Generator) -> torch.Tensor:
    """Tilt each unit vector by a random tangent step of std ``std_rad`` (radians)."""
    if std_rad == 0:
        return directions
    step = torch.randn(directions.shape, generator=generator, dtype=DTYPE) * std_rad
    tangent = step - (step * directions).sum(dim=1, keepdim=True) * directions
    tilted = directions + tangent
    return tilted / tilted.norm(dim=1, keepdim=True)


def applied_loads(
    directions: torch.Tensor,
    masses: torch.Tensor,
    errors: LoadApplicationErrors,
    generator: torch.Generator,
    set_directions: bool,
) -> torch.Tensor:
    """The loads really applied when the operator means ``masses[:, None] * directions``.

    Args:
        directions: ``k x n`` intended unit directions.
        masses: ``k`` the true masses (load units) on each application.
        errors: the load-application error model.
        set_directions: the operator set these directions on a stage (adds ``angle_error_deg``).

    Returns:
        ``k x n`` true loads.
    """
    std_deg = math.hypot(errors.string_misalignment_deg, errors.angle_error_deg if set_directions else 0.0)
    directions = perturb_directions(directions, math.radians(std_deg), generator)
    k = len(masses)
    tension = 1 + errors.friction * torch.randn(k, generator=generator, dtype=DTYPE)
    tilt = torch.randn(k, generator=generator, dtype=DTYPE) * math.radians(errors.out_of_plane_deg)
    return directions * (masses * tension * tilt.cos())[:, None]


def true_masses(labels: list[float], errors: LoadApplicationErrors, generator: torch.Generator) -> dict[float, float]:
    """Each labelled mass's true value, drawn once (the same weight is used throughout)."""
    draws = torch.randn(len(labels), generator=generator, dtype=DTYPE) * errors.mass_error
    return {label: label * (1 + float(d)) for label, d in zip(labels, draws)}


def rotation_recording(
    sensor: LinearSensor,
    magnitude: float,
    true_magnitude: float,
    samples: int,
    known_loads: int,
    mirror_hint: bool,
    errors: LoadApplicationErrors,
    generator: torch.Generator,
    motion_span: int | None = None,
    orientation_bias: float = 0.0,
    orientation_law: str = "uniform",
    poses: int = 12,
) -> CalibrationRecording:
    """One mass turned through ``samples`` unknown orientations, then ``known_loads`` loads along the first axes.

    The orientations follow ``orientation_law`` (:func:`oriented_directions`, ``poses`` for the
    ``"poses"`` law). ``motion_span`` (default ``n``) limits the unknown orientations to the first that many
    axes: 1 gives collinear loads, 2 coplanar ones (a session that cannot calibrate).
    ``orientation_bias`` > 0 crowds the orientations towards the last axis (1: most loads
    within 60 degrees of it, from the uniform law), as when an arm cannot turn the sensor upside down.

    The unknown rows come first; the known ones (axis-aligned, set on a stage) follow. Under the
    ``"poses"`` law each row's pose is its group (as an operator logs it), each known row its own.
    With ``mirror_hint``, the unknown sample whose load leans furthest along the last axis
    is named with the sign of that component, as an operator would remember it.
    """
    n = sensor.shape.shape[0]
    masses = torch.full((samples,), true_magnitude, dtype=DTYPE)
    directions = oriented_directions(orientation_law, samples, n, generator, poses)
    directions[:, -1] += orientation_bias
    directions[:, (motion_span or n) :] = 0
    directions = directions / directions.norm(dim=1, keepdim=True)
    unknown = applied_loads(directions, masses, errors, generator, set_directions=False)
    axes = torch.eye(n, dtype=DTYPE)[:known_loads]
    known_true = applied_loads(axes, masses[:known_loads], errors, generator, set_directions=True)
    loads = torch.cat([unknown, known_true])
    readings = sensor.read(loads, generator)
    believed = torch.cat([torch.full_like(unknown, float("nan")), axes * magnitude])
    hint = None
    if mirror_hint:
        row = int(unknown[:, -1].abs().argmax())
        hint = MirrorHint(sample=row, axis=n - 1, sign=1 if unknown[row, -1] > 0 else -1)
    groups = None
    if orientation_law == "poses":
        pose = torch.arange(samples) // math.ceil(samples / poses)
        groups = torch.cat([pose, poses + torch.arange(known_loads)])
    return CalibrationRecording(
        readings=readings, loads=believed, magnitude=magnitude, mirror_hint=hint, true_loads=loads, groups=groups
    )


def channel_noise_std(shape: torch.Tensor, magnitude: float, noise_fraction: float) -> float:
    """The simulators' reading noise (raw units): ``noise_fraction`` of a channel's mean full-load signal, ``F`` times
    the mean column norm of ``S`` (``n x p``)."""
    return noise_fraction * float(shape.norm(dim=0).mean()) * magnitude


def reread_last_known_load(
    recording: CalibrationRecording, truth: SensorTruth, noise_fraction: float, count: int, generator: torch.Generator
) -> CalibrationRecording:
    """``recording`` with its last (known-load) row's true load read ``count - 1`` more times, with the simulators' white
    noise (:func:`channel_noise_std`), as an operator holding the known load for longer would record it (the mirror
    hint kept)."""
    shape = torch.linalg.pinv(truth.matrix).T
    noise_std = channel_noise_std(shape, recording.magnitude, noise_fraction)
    extra = recording.true_loads[-1] @ shape + truth.offset
    extra = extra + noise_std * torch.randn(count - 1, shape.shape[1], generator=generator, dtype=shape.dtype)
    return CalibrationRecording(
        readings=torch.cat([recording.readings, extra]),
        loads=torch.cat([recording.loads, recording.loads[-1:].expand(count - 1, -1)]),
        magnitude=recording.magnitude,
        mirror_hint=recording.mirror_hint,
    )


def least_squares_recording(
    sensor: LinearSensor,
    masses: dict[float, float],
    angle_step_deg: float,
    repeats: int,
    errors: LoadApplicationErrors,
    generator: torch.Generator,
) -> CalibrationRecording:
    """The paper's least-squares protocol: every mass at every stage angle, readings averaged.

    For ``n == 2`` the stage angles go round the circle in ``angle_step_deg`` steps; for
    ``n == 3`` the same number of directions lie on a spiral over the sphere.

    Args:
        masses: label -> true value (see :func:`true_masses`); the labels are what the operator believes.
    """
    n = sensor.shape.shape[0]
    count = max(1, round(360 / angle_step_deg))
    directions = direction_grid(n, count).repeat(len(masses), 1)
    labelled = torch.tensor(list(masses), dtype=DTYPE).repeat_interleave(count)
    actual = torch.tensor(list(masses.values()), dtype=DTYPE).repeat_interleave(count)
    loads = applied_loads(directions, actual, errors, generator, set_directions=True)
    readings = sensor.read(loads, generator, repeats=repeats)
    return CalibrationRecording(readings=readings, loads=directions * labelled[:, None])


def evaluation_sweeps(
    sensor: LinearSensor, masses: list[float], samples_per_turn: int, generator: torch.Generator
) -> list[EvaluationSweep]:
    """Each test mass turned once round (exact loads, noisy readings): the reference for accuracy and precision."""
    n = sensor.shape.shape[0]
    directions = direction_grid(n, samples_per_turn)
    sweeps = []
    for mass in masses:
        loads = directions * mass
        sweeps.append(EvaluationSweep(magnitude=mass, readings=sensor.read(loads, generator), loads=loads))
    return sweeps
