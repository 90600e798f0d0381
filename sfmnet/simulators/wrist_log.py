"""A robot wrist's continuous log: a mass turned through poses within a cone below the sensor (a hostile tester's)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class WristLog(NamedTuple):
    """A simulated log and its truth.

    Attributes:
        readings: ``f x p`` raw units; loads: ``f x 3`` N, the known loads on 10 rows of each of the first three holds,
        NaN elsewhere; time: ``f`` seconds; matrix: the true calibration matrix ``pinv(S)^T``, ``3 x p``; magnitude:
        ``F``, N.
    """

    readings: np.ndarray
    loads: np.ndarray
    time: np.ndarray
    matrix: np.ndarray
    magnitude: float


def wrist_log(seed: int, cone: float = 45.0, poses: int = 12, channels: int = 8, noise: float = 0.005) -> WristLog:
    """A ``channels``-channel 3-axis sensor (gains 10 : 1, offsets 200-800) carrying 1 kg through ``poses`` poses within
    ``cone`` degrees of hanging straight down, each held 2 s at 200 Hz with 1.5 s minimum-jerk moves (inertial loads
    0.5-2 m/s^2 peak) between them, white noise ``noise`` of each channel's span.
    """
    rng = np.random.default_rng(seed)
    left, _, right = np.linalg.svd(rng.normal(size=(3, channels)), full_matrices=False)
    shape = 50.0 * (left * np.geomspace(1.0, 0.1, 3)) @ right
    offset = rng.uniform(200, 800, size=channels)
    directions: list[np.ndarray] = []
    while len(directions) < poses:
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        if np.degrees(np.arccos(-direction[2])) <= cone:
            directions.append(direction)
    magnitude, hold, move = 9.81, 400, 300
    tau = np.linspace(0, 1, move + 2)[1:-1]
    blend = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
    loads, held = [], []
    for k, pose in enumerate(directions):
        loads.append(np.repeat(magnitude * pose[None], hold, axis=0))
        held.append(np.full(hold, k))
        if k < poses - 1:
            following = directions[k + 1]
            angle = np.arccos(np.clip(pose @ following, -1, 1))
            path = np.sin((1 - blend) * angle)[:, None] * pose + np.sin(blend * angle)[:, None] * following
            path /= np.sin(angle)
            kick = rng.uniform(0.5, 2.0) * (60 * tau - 180 * tau**2 + 120 * tau**3)[:, None] / 5.77
            axis = rng.normal(size=3)
            loads.append(magnitude * path + kick * axis / np.linalg.norm(axis))
            held.append(np.full(move, -1))
    true_loads, pose_of_row = np.concatenate(loads), np.concatenate(held)
    span = np.abs(magnitude * shape).max(axis=0)
    readings = true_loads @ shape + offset + noise * span * rng.normal(size=(len(true_loads), channels))
    known = np.full_like(true_loads, np.nan)
    for k in range(3):
        rows = np.flatnonzero(pose_of_row == k)
        middle = rows[len(rows) // 2 - 5 : len(rows) // 2 + 5]
        known[middle] = true_loads[middle]
    return WristLog(readings, known, np.arange(len(readings)) / 200.0, np.linalg.pinv(shape).T, magnitude)
