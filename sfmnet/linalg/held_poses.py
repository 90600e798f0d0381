"""Rows held still at a few poses, found from their readings alone: single-linkage clusters cut at a gap.

A session logged without a time or pose column still tells where the mass was held: the rows of one pose
repeat one reading up to the noise, and poses lie far apart beside it. The minimum spanning tree of the
readings then has short edges inside the poses, about as long as the rows' spacing there, and long ones
between them; a continuous sweep of orientations has none much longer than its spacing.
The scatter inside the clusters is the reading noise no calibration can explain, which is what a fit's
residuals are judged by (see docs/method.md, "Held poses without a pose column").
"""

from __future__ import annotations

import numpy as np
import torch

from sfmnet.linalg.group_means import group_means

# A pose counts from this many rows: fewer say little about the noise.
MIN_POSE_ROWS = 5
# Edges of the tree longer than this many times the rows' median crowding (the distance from a row to its
# (MIN_POSE_ROWS - 1)-th nearest row: within a pose, the noise's scale) part poses.
MIN_GAP = 4.0
# At most this many rows (spread evenly over the recording) are clustered; the rest join the pose they are nearest.
MAX_CLUSTERED_ROWS = 1000
# Rows beyond every pose's reach join the nearest pose while they are at most this share of the rows: a few are
# bumps, which the fit's residuals carry too; more are rows in motion between poses, which stand alone.
MAX_JOINED_STRAYS = 0.01
# Rows joined to the poses found this many at a time.
ASSIGNED_CHUNK_ROWS = 16384


def minimum_spanning_tree(distance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prim's minimum spanning tree of ``s`` points given their ``s x s`` distances.

    Returns:
        ``parent`` (``s``, int): each point's neighbour on the tree, ``-1`` for the first point (the root);
        ``length`` (``s``): the distance to it (0 for the root).
    """
    count = len(distance)
    parent = np.full(count, -1)
    length = np.zeros(count)
    best = distance[0].copy()
    nearest = np.zeros(count, dtype=int)
    outside = np.ones(count, dtype=bool)
    outside[0] = False
    best[0] = np.inf
    for _ in range(count - 1):
        point = int(np.argmin(best))
        parent[point], length[point] = nearest[point], best[point]
        outside[point] = False
        best[point] = np.inf
        closer = outside & (distance[point] < best)
        best[closer] = distance[point, closer]
        nearest[closer] = point
    return parent, length


def tree_components(parent: np.ndarray, cut: np.ndarray) -> np.ndarray:
    """``s`` (int): each point's component once the edges to its parent marked in ``cut`` (``s``, bool) are removed,
    labelled by the component's root point."""
    root = np.where(cut | (parent < 0), np.arange(len(parent)), parent)
    # Pointer jumping: each pass halves every point's path to its component's root.
    while True:
        jumped = root[root]
        if np.array_equal(jumped, root):
            return root
        root = jumped


def exact_distances(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``len(a) x len(b)`` Euclidean distances from differences: the matrix-product shortcut's rounding would part
    readings that are identical (a quantised sensor at rest)."""
    return torch.cdist(a, b, compute_mode="donot_use_mm_for_euclid_dist")


def held_pose_clusters(readings: torch.Tensor) -> torch.Tensor | None:
    """The held poses of rows recorded with no pose or time column, or None where the rows show none.

    Works on a spread sample of at most :data:`MAX_CLUSTERED_ROWS` rows. Each row's crowding is its distance to its
    (:data:`MIN_POSE_ROWS` - 1)-th nearest row; their median is the scale of the noise where rows were held. The
    sample's minimum spanning tree is cut at every edge longer than :data:`MIN_GAP` times that scale. Poses are the
    pieces of at least :data:`MIN_POSE_ROWS` rows; found when there are two or more and they hold at least half the
    sample. Every row of the recording then joins the pose whose mean it is nearest, unless it lies beyond that
    pose's reach (its farthest sampled row from its mean, plus the cut's length) and such rows are more than
    :data:`MAX_JOINED_STRAYS` of the recording: those are rows in motion between poses, and each stands alone.

    A continuous sweep over the sphere shows no such gap; over the circle, pieces that scatter like the signal
    rather than the noise, which :func:`~sfmnet.eval.diagnostics.held_pose_groups` turns away. A few spikes join
    their pose, so that they count in the scatter within poses as they do in the fit's residuals, and two poses
    within a few noise widths may come out as one. So the scatter within the poses found is not below the noise,
    and the checks that compare a fit with it stay on the safe side.

    Args:
        readings: ``f x p`` raw readings (any units; the Euclidean distance between rows is what counts).

    Returns:
        ``f`` (long) labels: poses ``0 .. K-1``, each row standing alone a label of its own; or None.
    """
    rows = len(readings)
    if rows < 2 * MIN_POSE_ROWS:
        return None
    readings = readings.double()
    sample = torch.from_numpy(np.unique(np.linspace(0, rows - 1, min(rows, MAX_CLUSTERED_ROWS)).round().astype(int)))
    distance = exact_distances(readings[sample], readings[sample])
    # Column 0 of each sorted row is the row itself.
    crowding = distance.sort(dim=1).values[:, MIN_POSE_ROWS - 1]
    # Quantised readings repeat exactly: a scale of 0 is the converter's step, not the noise.
    scale = max(float(crowding.median()), positive_floor(crowding))
    parent, length = minimum_spanning_tree(distance.numpy())
    component = tree_components(parent, length > MIN_GAP * scale)
    labels, sizes = np.unique(component, return_counts=True)
    poses = labels[sizes >= MIN_POSE_ROWS]
    if len(poses) < 2 or sizes[sizes >= MIN_POSE_ROWS].sum() * 2 < len(sample):
        return None
    in_pose = np.isin(component, poses)
    members = readings[sample[torch.from_numpy(in_pose)]]
    member_pose = torch.from_numpy(np.searchsorted(poses, component[in_pose]))
    means = group_means(members, member_pose)[0]
    pose, from_mean = nearest_pose(readings, means)
    reach = torch.zeros(len(means), dtype=readings.dtype).scatter_reduce_(
        0, member_pose, (members - means[member_pose]).norm(dim=1), "amax"
    ) + MIN_GAP * scale
    stray = from_mean > reach[pose]
    if int(stray.sum()) > MAX_JOINED_STRAYS * rows:
        pose[stray] = len(means) + torch.nonzero(stray)[:, 0]
    return pose


def positive_floor(values: torch.Tensor) -> float:
    """The smallest positive entry of ``values`` (0 if none): below it, distances are repeats, not scatter."""
    positive = values[values > 0]
    return float(positive.min()) if len(positive) else 0.0


def nearest_pose(readings: torch.Tensor, means: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """For each of ``readings`` (``f x p``), the pose whose mean (``means``, ``K x p``) is nearest (``f``, long) and the
    distance to it (``f``)."""
    # In chunks: a million rows' distances to a hundred poses would be 800 MB at once.
    nearest = [
        exact_distances(readings[start : start + ASSIGNED_CHUNK_ROWS], means).min(dim=1)
        for start in range(0, len(readings), ASSIGNED_CHUNK_ROWS)
    ]
    return torch.cat([n.indices for n in nearest]), torch.cat([n.values for n in nearest])
