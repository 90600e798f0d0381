"""Rows held still at a few poses, found from their readings alone: single-linkage clusters cut at a gap.

A session logged without a time or pose column still tells where the mass was held: the rows of one pose
repeat one reading up to the noise, and poses lie far apart beside it. The minimum spanning tree of the
readings then has short edges inside the poses and a few long ones between them, with a gap between the two
lengths; a continuous sweep of orientations has no such gap (its edges shorten smoothly with the density).
The scatter inside the clusters is the reading noise no calibration can explain, which is what a fit's
residuals are judged by (see docs/method.md, "Held poses without a pose column").
"""

from __future__ import annotations

import numpy as np
import torch

# A pose counts from this many rows: fewer say little about the noise.
MIN_POSE_ROWS = 5
# The shortest edge cut must be this many times the longest kept: poses far apart beside their noise.
MIN_GAP = 4.0
# At most this many rows (spread evenly over the recording) are clustered; the rest join the pose they sit at.
MAX_CLUSTERED_ROWS = 1000
# Rows joined to the poses found this many at a time.
ASSIGNED_CHUNK_ROWS = 16384


def minimum_spanning_tree(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prim's minimum spanning tree of ``points`` (``s x p``) under the Euclidean distance.

    Returns:
        ``parent`` (``s``, int): each point's neighbour on the tree, ``-1`` for the first point (the root);
        ``length`` (``s``): the distance to it (0 for the root).
    """
    count = len(points)
    parent = np.full(count, -1)
    length = np.zeros(count)
    # Differences, not |a|^2 + |b|^2 - 2 a.b: repeated readings (a quantised sensor at rest) must come out 0 apart.
    best = np.sqrt(((points - points[0]) ** 2).sum(axis=1))
    nearest = np.zeros(count, dtype=int)
    outside = np.ones(count, dtype=bool)
    outside[0] = False
    best[0] = np.inf
    for _ in range(count - 1):
        point = int(np.argmin(best))
        parent[point], length[point] = nearest[point], best[point]
        outside[point] = False
        best[point] = np.inf
        distance = np.sqrt(((points - points[point]) ** 2).sum(axis=1))
        closer = outside & (distance < best)
        best[closer] = distance[closer]
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


def held_pose_clusters(readings: torch.Tensor) -> torch.Tensor | None:
    """The held poses of rows recorded with no pose or time column, or None where the rows show none.

    Clusters a spread sample of at most :data:`MAX_CLUSTERED_ROWS` rows: their minimum spanning tree is cut at the
    largest ratio between consecutive edge lengths among its longest half, where that ratio is at least
    :data:`MIN_GAP`. Poses are the pieces of at least :data:`MIN_POSE_ROWS` rows; found when there are two or more
    and they hold at least half of the sample. Every other row joins the nearest pose if it lies within that pose's
    reach (its farthest sampled row from its mean plus the longest edge kept), else stays a pose of its own.

    A continuous sweep, or rows whose poses lie within a few noise widths of each other, show no gap: None, and
    nothing is said about the noise. Two poses taken for one, or a continuous stretch taken for a pose, only widen
    the scatter found inside the poses, so the checks that compare a fit with it stay on the safe side.

    Args:
        readings: ``f x p`` raw readings (any units; the Euclidean distance between rows is what counts).

    Returns:
        ``f`` (long) labels: poses ``0 .. K-1``, each other row a label of its own; or None.
    """
    rows = len(readings)
    if rows < 2 * MIN_POSE_ROWS:
        return None
    sample = np.unique(np.linspace(0, rows - 1, min(rows, MAX_CLUSTERED_ROWS)).round().astype(int))
    points = readings[torch.from_numpy(sample)].double().numpy()
    parent, length = minimum_spanning_tree(points)
    edges = np.sort(length[1:])
    half = len(edges) // 2
    kept, cut = edges[half:-1], edges[half + 1 :]
    if not len(kept):
        return None
    # Quantised readings repeat exactly: from 0 to one count is the converter's step, not a gap between poses.
    positive = edges[edges > 0]
    if not len(positive):
        return None
    ratio = cut / np.maximum(kept, positive[0])
    split = int(np.argmax(ratio))
    if ratio[split] < MIN_GAP:
        return None
    longest_kept = kept[split]
    component = tree_components(parent, length > longest_kept)
    labels, sizes = np.unique(component, return_counts=True)
    poses = labels[sizes >= MIN_POSE_ROWS]
    if len(poses) < 2 or sizes[sizes >= MIN_POSE_ROWS].sum() * 2 < len(sample):
        return None
    return _assign_rows(readings.double(), sample, component, poses, longest_kept)


def _assign_rows(
    readings: torch.Tensor, sample: np.ndarray, component: np.ndarray, poses: np.ndarray, longest_kept: float
) -> torch.Tensor:
    """``f`` (long) labels: each row in the pose (a component of the sample, ``poses`` its labels) whose reach it lies
    within, nearest first; else a label of its own."""
    pose_of_sample = torch.from_numpy(np.searchsorted(poses, component))
    in_pose = torch.from_numpy(np.isin(component, poses))
    sampled = readings[torch.from_numpy(sample)]
    members = sampled[in_pose]
    member_pose = pose_of_sample[in_pose]
    count = torch.bincount(member_pose, minlength=len(poses)).to(readings.dtype)
    means = torch.zeros(len(poses), readings.shape[1], dtype=readings.dtype).index_add_(0, member_pose, members)
    means = means / count[:, None]
    spread = torch.zeros(len(poses), dtype=readings.dtype).scatter_reduce_(
        0, member_pose, (members - means[member_pose]).norm(dim=1), "amax"
    )
    reach = spread + longest_kept
    labels = len(poses) + torch.arange(len(readings))
    # In chunks: a million rows' distances to a hundred poses would be 800 MB at once.
    for start in range(0, len(readings), ASSIGNED_CHUNK_ROWS):
        # Differences, not the matrix-product shortcut, whose rounding would part identical readings.
        rows = readings[start : start + ASSIGNED_CHUNK_ROWS]
        distance = torch.cdist(rows, means, compute_mode="donot_use_mm_for_euclid_dist")
        closest, nearest = distance.min(dim=1)
        chunk = labels[start : start + ASSIGNED_CHUNK_ROWS]
        chunk[closest <= reach[nearest]] = nearest[closest <= reach[nearest]]
    return labels
