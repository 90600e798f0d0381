"""Poses held more than once: do their holds agree? (README, "Goodness of fit"; method §5, "Drift over the recording")

A pose the recording returns to (the first pose held again at the end, a reference pose between others) should read
the same each time up to the noise. A drift over the recording (temperature, creep, a sensor not warmed up) moves
it, and so does a pose not repeated exactly. Neither is visible within one hold, and with few poses the fit absorbs
most of a slow drift into the shape: a revisit is what exposes it. The holds of a pose are compared by their means
against the noise within the holds, as a one-way analysis of variance in the whitened readings (eq. D1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sfmnet.linalg.chi_square import f_ratio_z
from sfmnet.preprocessing.static_intervals import CHUNK_ROWS, noise_correlation


@dataclass(frozen=True)
class RevisitedPoses:
    """How far the holds of poses held more than once are apart, against the noise within the holds.

    Attributes:
        ratio: ``sqrt(T / dof)`` (eq. D1): 1 when the holds of a pose differ by noise alone.
        z: how many standard deviations ``T / dof`` lies above ``F(dof, nu)``'s expectation, ~N(0, 1) then.
        dof: ``p * sum_g (H_g - 1)`` (``p``: the rank of the noise's covariance within holds).
        poses: the poses held more than once.
        holds: the holds of those poses.
        worst_pose: the label (as in the file) of the pose whose holds are furthest apart, per degree of freedom.
        worst_starts: the first row of each of its holds (0-based, of the rows given; the reader makes them the file's).
        worst_start_times: the time of those rows (seconds), or None without a time column.
        worst_channel: the channel whose mean moves most between its holds, against the channel's span.
        worst_change: that move as a fraction of the channel's span over every hold's mean.
    """

    ratio: float
    z: float
    dof: int
    poses: int
    holds: int
    worst_pose: str
    worst_starts: list[int]
    worst_start_times: list[float] | None
    worst_channel: int
    worst_change: float


def hold_ids(labels: np.ndarray, intervals: np.ndarray | None) -> np.ndarray:
    """``f`` int64: the hold of each row, a run of consecutive rows with one pose label (and one static interval).

    Args:
        labels: ``f`` the pose of each row (in row order); intervals: ``f`` each row's static interval, or None
            where the rows were not split into intervals.
    """
    change = labels[1:] != labels[:-1]
    if intervals is not None:
        change |= intervals[1:] != intervals[:-1]
    return np.concatenate([[0], np.cumsum(change)]).astype(np.int64)


def holds_per_pose(labels: np.ndarray, holds: np.ndarray) -> dict[float, int]:
    """How many holds (``holds``, runs of rows) each labelled pose has; unlabelled (NaN) rows left out."""
    _, first = np.unique(holds, return_index=True)
    hold_labels = labels[first]
    poses, counts = np.unique(hold_labels[~np.isnan(hold_labels)], return_counts=True)
    return dict(zip(poses.tolist(), counts.tolist()))


def revisited_poses(
    readings: np.ndarray, labels: np.ndarray, holds: np.ndarray, time: np.ndarray | None = None
) -> RevisitedPoses | None:
    """Compare the holds of every pose held more than once (eq. D1).

    ``T = sum_g sum_{h in g} n_h (zbar_h - zbar_g)^T W^-1 (zbar_h - zbar_g)``, with ``zbar_h`` a hold's mean reading,
    ``zbar_g`` its pose's (weighted by rows), ``n_h`` its rows and ``W`` the readings' covariance within holds
    (pooled over every hold), is ``chi2(p sum_g (H_g - 1))`` when a pose reads the same at each visit up to white
    noise. Noise correlated in time makes a hold's mean vary ``tau`` times more than ``W / n_h``: ``W`` is scaled by
    each channel's ``max(tau, 1)``, measured over the holds themselves by batch means a quarter of the median hold long
    (:func:`~sfmnet.preprocessing.static_intervals.noise_correlation`, eq. N1), so that what is left is slower than a
    hold. ``T / dof`` is then ``F(dof, nu)`` with ``nu`` the batch means' degrees of freedom (the noise's size
    estimated, not known), scored by :func:`~sfmnet.linalg.chi_square.f_ratio_z`.

    Args:
        readings: ``f x p`` raw units, the rows fitted, in recording order.
        labels: ``f`` the pose of each row (the file's labels; NaN cells are poses of their own, never revisited).
        holds: ``f`` int, each row's hold (:func:`hold_ids`): runs of consecutive rows.
        time: ``f`` seconds, or None.

    Returns:
        None where no pose is held twice, or the holds leave too few rows to estimate ``W`` (or no noise within them).
    """
    f, p = readings.shape
    _, first, index = np.unique(holds, return_index=True, return_inverse=True)
    index = index.reshape(-1)
    count = len(first)
    if f - count < 2 * p:
        return None
    hold_label = labels[first]
    visits = holds_per_pose(labels, holds)
    revisited = [label for label, count in visits.items() if count > 1]
    if not revisited:
        return None
    # About the first row, so that raw counts with large offsets lose no precision in the sums.
    shifted = readings - readings[0]
    rows = np.bincount(index, minlength=count).astype(float)
    means = np.stack([np.bincount(index, shifted[:, c], minlength=count) for c in range(p)], axis=1) / rows[:, None]
    deviation = shifted - means[index]
    within = deviation.T @ deviation / (f - count)
    # Measured over the labelled holds, not the detector's intervals: an interval that merged two holds and the move
    # between them would read as strongly correlated noise and switch the check off.
    spans = np.stack([first, first + rows.astype(np.int64)], axis=1)
    correlation, noise_dof = noise_correlation(shifted, spans, max(2, int(np.median(rows)) // 4), CHUNK_ROWS)
    scale = np.sqrt(np.where(np.isfinite(correlation), np.maximum(correlation, 1.0), 1.0))
    within = within * np.outer(scale, scale)
    # A channel that is a combination of others (or constant within holds) adds no degree of freedom.
    inverse, rank = np.linalg.pinv(within, hermitian=True), int(np.linalg.matrix_rank(within, hermitian=True))
    if rank == 0:
        return None
    total, dof, worst = 0.0, 0, (math.nan, -1.0, np.array([], dtype=np.int64))
    for label in revisited:
        members = np.nonzero(hold_label == label)[0]
        weights = rows[members]
        offset = means[members] - weights @ means[members] / weights.sum()
        statistic = float(np.einsum("h,hi,ij,hj->", weights, offset, inverse, offset))
        pose_dof = rank * (len(members) - 1)
        total, dof = total + statistic, dof + pose_dof
        if math.sqrt(statistic / pose_dof) > worst[1]:
            worst = (float(label), math.sqrt(statistic / pose_dof), members)
    label, _, members = worst
    span = np.ptp(means, axis=0)
    move = np.ptp(means[members], axis=0) / np.where(span > 0, span, np.inf)
    channel = int(np.argmax(move))
    starts = [int(first[m]) for m in members]
    return RevisitedPoses(
        ratio=math.sqrt(total / dof),
        z=f_ratio_z(total / dof, dof, noise_dof if noise_dof > 0 else math.inf),
        dof=dof,
        poses=len(revisited),
        holds=sum(visits[label] for label in revisited),
        worst_pose=f"{label:.15g}",
        worst_starts=starts,
        worst_start_times=None if time is None else [float(time[s]) for s in starts],
        worst_channel=channel,
        worst_change=float(move[channel]),
    )
