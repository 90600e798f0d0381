"""A continuous recording: a mass carried from pose to pose while the logger runs on, inertial loads included.

The sensor (a :class:`~sfmnet.simulators.simulation.LinearSensor`) holds the mass at its origin. Each
pose is an orientation held still for ``hold`` seconds; between poses the orientation is
interpolated by slerp and the sensor carried along a straight line, both on a minimum-jerk
profile over ``move`` seconds, so the load is physical throughout: ``m (g - a)`` in the sensor
frame, with ``a`` the carrying acceleration (rotation about the mass's own centre adds none).
The recording starts in a move (no rest period first) and ends after the last hold.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import torch

from sfmnet.simulators.simulation import DTYPE, LinearSensor, channel_noise_std, random_directions
from sfmnet.linalg.wrench import STANDARD_GRAVITY

ORIENTATION_LAWS = ("uniform", "below")
WORLD_GRAVITY = torch.tensor([0.0, 0.0, -STANDARD_GRAVITY], dtype=DTYPE)


@dataclass(frozen=True)
class ContinuousRecording:
    """A simulated stream and its truth.

    Attributes:
        time: ``f`` seconds.
        readings: ``f x p`` raw units.
        loads: ``f x 3`` N, the true load of every row (sensor frame), inertial loads included.
        known_loads: ``f x 3`` N, the loads as a user would write them: filled on the static rows of
            the known poses, NaN elsewhere.
        static: ``f`` bool, the rows where the mass is held still (the true static mask).
        pose: ``f`` long, each row's pose index (-1 while moving; a pose revisited at the end keeps its index).
    """

    time: torch.Tensor
    readings: torch.Tensor
    loads: torch.Tensor
    known_loads: torch.Tensor
    static: torch.Tensor
    pose: torch.Tensor

    @property
    def intervals(self) -> torch.Tensor:
        """``k x 2`` half-open row ranges of the true static intervals."""
        edges = torch.diff(torch.cat([torch.zeros(1), self.static.double(), torch.zeros(1)]))
        return torch.stack([torch.nonzero(edges == 1)[:, 0], torch.nonzero(edges == -1)[:, 0]], dim=1)


def stream_sensor(channels: int, magnitude: float, noise_fraction: float, offset_scale: float, generator: torch.Generator) -> LinearSensor:
    """A 3-axis sensor with ``channels`` gauges along random directions (gains 0.1 +- 10 %), offsets and noise.

    Args:
        magnitude: the calibration load (N), which sets the noise: ``noise_fraction`` of a channel's full-load signal.
        offset_scale: std of the channel offsets (raw units).
    """
    directions = random_directions(channels, 3, generator)
    gains = 0.1 * (1 + 0.1 * torch.randn(channels, generator=generator, dtype=DTYPE))
    shape = (directions * gains[:, None]).T
    offset = torch.randn(channels, generator=generator, dtype=DTYPE) * offset_scale
    return LinearSensor(shape=shape, offset=offset, noise_std=channel_noise_std(shape, magnitude, noise_fraction))


def random_rotations(count: int, law: str, generator: torch.Generator) -> torch.Tensor:
    """``count x 3 x 3`` sensor-to-world rotations.

    ``uniform``: uniform over rotations (the mass's gravity direction uniform over the sensor's
    sphere). ``below``: the sensor's z axis within 60 degrees of straight up (uniform over that
    cap) and any turn about it, as when an arm keeps the mass hanging below the sensor.
    """
    if law == "uniform":
        return quaternion_matrix(random_directions(count, 4, generator))
    if law == "below":
        tilt_cos = 1 - 0.5 * torch.rand(count, generator=generator, dtype=DTYPE)
        tilt_axis = 2 * math.pi * torch.rand(count, generator=generator, dtype=DTYPE)
        spin = 2 * math.pi * torch.rand(count, generator=generator, dtype=DTYPE)
        axis = torch.stack([tilt_axis.cos(), tilt_axis.sin(), torch.zeros_like(tilt_axis)], dim=1)
        return axis_angle_matrix(axis, tilt_cos.acos()) @ axis_angle_matrix(torch.tensor([[0.0, 0.0, 1.0]], dtype=DTYPE).expand(count, 3), spin)
    raise ValueError(f"orientation law '{law}': use one of {', '.join(ORIENTATION_LAWS)}")


def quaternion_matrix(q: torch.Tensor) -> torch.Tensor:
    """``k x 3 x 3`` rotations of unit quaternions ``k x 4`` (w, x, y, z)."""
    w, x, y, z = q.unbind(dim=1)
    return torch.stack([
        torch.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], dim=1),
        torch.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], dim=1),
        torch.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], dim=1),
    ], dim=1)


def matrix_quaternion(rotation: torch.Tensor) -> torch.Tensor:
    """``4``, the unit quaternion (w >= 0) of a ``3 x 3`` rotation."""
    m = rotation
    candidates = torch.stack([
        torch.stack([1 + m[0, 0] + m[1, 1] + m[2, 2], m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]]),
        torch.stack([m[2, 1] - m[1, 2], 1 + m[0, 0] - m[1, 1] - m[2, 2], m[0, 1] + m[1, 0], m[0, 2] + m[2, 0]]),
        torch.stack([m[0, 2] - m[2, 0], m[0, 1] + m[1, 0], 1 - m[0, 0] + m[1, 1] - m[2, 2], m[1, 2] + m[2, 1]]),
        torch.stack([m[1, 0] - m[0, 1], m[0, 2] + m[2, 0], m[1, 2] + m[2, 1], 1 - m[0, 0] - m[1, 1] + m[2, 2]]),
    ])
    # The row with the largest diagonal term is the well-conditioned one.
    q = candidates[int(torch.argmax(candidates.diagonal()))]
    q = q / q.norm()
    return q if q[0] >= 0 else -q


def axis_angle_matrix(axis: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """``k x 3 x 3`` rotations by ``angle`` (``k``, rad) about unit ``axis`` (``k x 3``)."""
    half = angle / 2
    return quaternion_matrix(torch.cat([half.cos()[:, None], axis * half.sin()[:, None]], dim=1))


def slerp(q0: torch.Tensor, q1: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """``k x 4`` unit quaternions from ``q0`` to ``q1`` (``4``, the short way) at fractions ``s`` (``k``)."""
    dot = float(q0 @ q1)
    if dot < 0:
        q1, dot = -q1, -dot
    angle = math.acos(min(dot, 1.0))
    if angle < 1e-9:
        return q0.expand(len(s), 4).clone()
    return (torch.sin((1 - s) * angle)[:, None] * q0 + torch.sin(s * angle)[:, None] * q1) / math.sin(angle)


def minimum_jerk(tau: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Position fraction ``s`` and its second derivative ``d2s/dtau2`` of the minimum-jerk profile at ``tau`` in [0, 1]."""
    return 10 * tau**3 - 15 * tau**4 + 6 * tau**5, 60 * tau - 180 * tau**2 + 120 * tau**3


def simulate_stream(
    sensor: LinearSensor,
    mass: float,
    poses: int = 30,
    hold: float = 2.0,
    move: float = 1.5,
    rate: float = 100.0,
    known_poses: int = 3,
    orientation: str = "uniform",
    reach: float = 0.4,
    revisit: bool = False,
    gain_drift: float = 0.0,
    offset_drift: float = 0.0,
    generator: torch.Generator | None = None,
) -> ContinuousRecording:
    """Carry ``mass`` (kg) on ``sensor`` through ``poses`` orientations, recording at ``rate`` Hz.

    Args:
        hold: seconds each pose is held still.
        move: seconds each move between poses takes (one move also leads into the first pose).
        known_poses: poses set by a jig with the load along -z, -x, -y in turn (spread through the
            sequence); their static rows carry the true load in :attr:`ContinuousRecording.known_loads`.
        orientation: the law of the other poses' orientations (:func:`random_rotations`).
        reach: the sensor's position is drawn uniformly in a cube of this side (m) for each pose.
        revisit: return to the first pose at the end and hold it again (its rows labelled pose 0 again).
        gain_drift: the sensor's gain grows linearly by this fraction from the first row to the last (a temperature
            drift), so that a revisited pose reads differently.
        offset_drift: each channel's offset moves linearly by this fraction of the channel's full-load signal
            (``mass g |S_c|``) from the first row to the last.
    """
    generator = generator or torch.Generator().manual_seed(0)
    rotations = random_rotations(poses + 1, orientation, generator)
    # The jig's poses: gravity (world -z) along the sensor's -z, -x, -y.
    jig = [torch.eye(3, dtype=DTYPE), axis_angle_matrix(torch.tensor([[0.0, 1.0, 0.0]], dtype=DTYPE), torch.tensor([-math.pi / 2], dtype=DTYPE))[0],
           axis_angle_matrix(torch.tensor([[1.0, 0.0, 0.0]], dtype=DTYPE), torch.tensor([math.pi / 2], dtype=DTYPE))[0]]
    known = [round((k + 0.5) * poses / known_poses) for k in range(known_poses)]
    for k, pose in enumerate(known):
        rotations[1 + pose] = jig[k % 3]
    positions = reach * torch.rand(poses + 1, 3, generator=generator, dtype=DTYPE)
    if revisit:
        rotations, positions = torch.cat([rotations, rotations[1:2]]), torch.cat([positions, positions[1:2]])
    step = 1.0 / rate
    time, orientation_rows, acceleration, pose_rows = [], [], [], []
    clock = 0.0
    for k in range(len(rotations) - 1):
        # Move from waypoint k (the start, or pose k - 1) into pose k, then hold it.
        moving = torch.arange(round(move * rate), dtype=DTYPE) * step
        s, s2 = minimum_jerk(moving / move)
        quaternions = slerp(matrix_quaternion(rotations[k]), matrix_quaternion(rotations[k + 1]), s)
        orientation_rows.append(quaternion_matrix(quaternions))
        acceleration.append(s2[:, None] * (positions[k + 1] - positions[k]) / move**2)
        holding = torch.arange(round(hold * rate), dtype=DTYPE) * step
        orientation_rows.append(rotations[k + 1].expand(len(holding), 3, 3))
        acceleration.append(torch.zeros(len(holding), 3, dtype=DTYPE))
        time.append(torch.cat([clock + moving, clock + move + holding]))
        pose_rows.append(torch.cat([torch.full((len(moving),), -1), torch.full((len(holding),), k % poses)]))
        clock += move + hold
    rotation = torch.cat(orientation_rows)
    # The sensor carries the mass: it feels m (g - a), written in the sensor frame (R^T v).
    world = mass * (WORLD_GRAVITY - torch.cat(acceleration))
    loads = torch.einsum("fji,fj->fi", rotation, world)
    pose = torch.cat(pose_rows)
    static = pose >= 0
    known_rows = static & torch.isin(pose, torch.tensor(known))
    believed = torch.full_like(loads, float("nan"))
    believed[known_rows] = loads[known_rows]
    time = torch.cat(time)
    elapsed = (time / time[-1])[:, None]
    full_load = mass * STANDARD_GRAVITY * sensor.shape.norm(dim=0)
    readings = sensor.read(loads, generator) + elapsed * (gain_drift * loads @ sensor.shape + offset_drift * full_load)
    return ContinuousRecording(
        time=time, readings=readings, loads=loads, known_loads=believed, static=static, pose=pose,
    )


def write_stream_csv(
    recording: ContinuousRecording, path: Path, rows: torch.Tensor | None = None, pose_column: bool = False
) -> None:
    """The recording as a CSV: ``time``, ``s0 ... s{p-1}``, ``fx, fy, fz`` (empty where the load is unknown).

    Args:
        rows: ``f`` bool, the rows to write (default all).
        pose_column: add a ``pose`` column, each row's pose (empty while moving), for ``data.group_column``.
    """
    keep = torch.ones(len(recording.time), dtype=torch.bool) if rows is None else rows
    p = recording.readings.shape[1]
    with Path(path).open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["time", *(f"s{i}" for i in range(p)), "fx", "fy", "fz", *(["pose"] if pose_column else [])])
        for t, z, f, k in zip(
            recording.time[keep].tolist(), recording.readings[keep].tolist(), recording.known_loads[keep].tolist(),
            recording.pose[keep].tolist(),
        ):
            pose = ([str(k) if k >= 0 else ""] if pose_column else [])
            writer.writerow([f"{t:.4f}", *(f"{v:.9g}" for v in z), *("" if math.isnan(v) else f"{v:.6f}" for v in f), *pose])
