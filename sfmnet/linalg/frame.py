"""The load frame from known loads: orthogonal Procrustes with the mirror made explicit (method §3)."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import WARN_RANK_GAP

# Singular values of the known loads below this fraction of the largest count as missing directions.
SPAN_TOLERANCE = 1e-6
# Halvings of a Gauss-Newton step of the frame's turn (known_load_rotation) before it is given up as not lowering
# the cost.
STEP_HALVINGS = 30
# A Gauss-Newton step of the turn this small (radians) is taken whatever the cost says: it is at the fit.
CONVERGED_TURN = 1e-8


@dataclass(frozen=True)
class MirrorHint:
    """One bit that tells a frame from its mirror image when only ``n - 1`` loads are known.

    The load on sample ``sample`` (an index into the unknown-orientation readings) has a
    component along axis ``axis`` whose sign is ``sign`` (+1 or -1). Any rough knowledge
    serves: "that pull was roughly towards +y". ``axis_name``: the user's name for the axis (its load column), for
    messages.
    """

    sample: int
    axis: int
    sign: int
    axis_name: str | None = None


def orthogonal_procrustes(source: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The orthogonal ``R`` (``n x n``) minimising ``|source R - target|_F``: ``R = U V^T`` of ``svd(source^T target)``.

    Args:
        source: ``k x n`` loads in the recovered frame.
        target: ``k x n`` the same loads in the user's frame.
    """
    u, _, vt = torch.linalg.svd(source.T @ target)
    return u @ vt


def channel_frame_rotation(matrix: torch.Tensor) -> torch.Tensor:
    """The orthogonal ``R`` (``n x n``) that turns a square calibration ``C`` (``n x n``: as many channels as axes) in
    an arbitrary frame into its channels' own: ``R^T C = V Sigma V^T``, symmetric positive definite, from
    ``C = U Sigma V^T`` (the polar decomposition), so ``R = U V^T``.

    With no known load the data fix ``C`` only up to an orthogonal transform, a mirror included. Of those, this one
    puts each load axis nearest its own channel (an accelerometer's or magnetometer's axes are its channels, up to
    small misalignments), with positive gains, and so is right-handed wherever the channels are: the Procrustes
    rotation of ``C`` onto the identity. ``M <- M R``, ``S <- R^T S`` as for :func:`frame_rotation`.
    """
    return orthogonal_procrustes(matrix.T, torch.eye(len(matrix), dtype=matrix.dtype))


def median_per_load(estimated_loads: torch.Tensor, known_loads: torch.Tensor) -> torch.Tensor:
    """Each row's recovered load replaced by the median (per axis) over the rows given the same known load: ``k x n``.

    Procrustes on the rows weighs each known load by its rows through their mean (``sum_j l_j^T e_j``); the median
    keeps that weight while one corrupted row among a pose's hundreds (a dropped packet read as zeros) cannot turn the
    frame or have every known load called contradictory (a hostile tester's session: "42 degrees" off, from one row of
    200). A load given on one row is its own median.
    """
    _, index = torch.unique(known_loads, dim=0, return_inverse=True)
    medians = torch.stack([estimated_loads[index == g].median(dim=0).values for g in range(int(index.max()) + 1)])
    return medians[index]


def frame_rotation(
    estimated_loads: torch.Tensor,
    known_loads: torch.Tensor,
    hint_motion: torch.Tensor | None = None,
    hint: MirrorHint | None = None,
    rank_gap: float | None = None,
    circle_gap: Callable[[], float | None] | None = None,
) -> torch.Tensor:
    """The orthogonal transform ``R`` that takes recovered loads into the frame of the known loads.

    With ``k >= n`` spanning loads, Procrustes fixes ``R`` completely. With loads spanning
    ``n - 1`` directions, ``R`` is fixed only up to a mirror across their span; the caller's
    :class:`MirrorHint` picks the side.

    Args:
        estimated_loads: ``k x n``, the known samples' loads in the recovered frame.
        known_loads: ``k x n``, the same loads as the user knows them.
        hint_motion: ``1 x n``, the recovered load of the hint sample (with ``hint``).
        hint: which side of the mirror the hint sample lies on.
        rank_gap: the readings' (:func:`~sfmnet.linalg.factorisation.readings_rank_gap`), and circle_gap: the
            same of the unknown-load rows about their mean, computed only where it is asked for, for
            :func:`check_agreement`'s message.

    Returns:
        ``R``, ``n x n`` orthogonal, so that ``M <- M R`` and ``S <- R^T S``.

    Raises:
        SfmnetError: loads that span fewer than ``n - 1`` directions, or ``n - 1`` without a hint.
    """
    n = known_loads.shape[1]
    per_row = estimated_loads
    estimated_loads = median_per_load(estimated_loads, known_loads)
    singular = torch.linalg.svdvals(known_loads)
    span = int((singular > SPAN_TOLERANCE * singular[0]).sum()) if len(singular) else 0
    if span < n - 1:
        # One load given on rows the sensor read in different directions: loads in the world's frame (gravity's).
        spread = 0.0
        if span == 1 and len(known_loads) > 1:
            # Each reading's direction on the line's side its load is on: +z and -z loads read opposite ways rightly.
            line = torch.linalg.svd(known_loads)[2][0]
            directions = per_row / per_row.norm(dim=1, keepdim=True) * torch.sign(known_loads @ line)[:, None]
            mean = directions.mean(dim=0)
            cosines = directions @ (mean / mean.norm())
            spread = float(torch.rad2deg(torch.arccos(cosines.min().clamp(-1.0, 1.0))))
        world = (
            f" (the known rows' readings point up to {spread:.0f} degrees from their mean direction where their loads lie "
            "on one line: known loads are the load on the sensor in its own frame, turning with it, not gravity in the "
            "world's frame)" if spread > MAX_DISAGREEMENT_DEG else ""
        )
        raise SfmnetError(
            f"the known loads span {span} of {n} load directions{world}: give at least {n - 1} "
            f"non-parallel known loads (and a mirror hint), {n} to fix the frame alone, or none "
            "(data.load_columns=[]: every load's size is right, its frame arbitrary, or with as many channels as axes "
            "the channels' own)"
        )
    u, _, vt = torch.linalg.svd(estimated_loads.T @ known_loads)
    rotation = u @ vt
    if span == n:
        return check_agreement(estimated_loads @ rotation, known_loads, rotation, rank_gap, circle_gap)
    if hint is None or hint_motion is None:
        raise SfmnetError(
            f"{span} known loads fix the {n}-axis frame only up to a mirror image: set "
            "data.mirror_hint={row: <row>, axis: <axis>, sign: <1|-1>} (the rough sign of one unknown "
            f"row's load component), or give {n} non-coplanar known loads"
        )
    if not 0 <= hint.axis < n or hint.sign not in (-1, 1):
        raise SfmnetError(
            f"mirror_hint needs an axis in 0..{n - 1} and a sign of +1 or -1, got axis {hint.axis}, sign {hint.sign}"
        )
    # The other image reflects the direction the known loads leave free (last singular vector).
    flip = torch.eye(n, dtype=rotation.dtype)
    flip[-1, -1] = -1
    mirrored = u @ flip @ vt
    components = [float((hint_motion @ image)[0, hint.axis]) for image in (rotation, mirrored)]
    agrees = [component * hint.sign > 0 for component in components]
    # A load near the known loads' span reads nearly alike in both images: its sign there is noise (a hostile tester's
    # hint on a row of a known pose's hold chose the image by its sign alone, every check passing).
    elevation = float((hint_motion[0] @ u[:, -1]).abs() / hint_motion[0].norm().clamp_min(torch.finfo(u.dtype).tiny))
    if agrees[0] == agrees[1] or elevation < MIN_HINT_ELEVATION:
        normal = ", ".join(f"{value:.2f}" for value in vt[-1].tolist())
        axis = hint.axis_name or f"{hint.axis} (0-based)"
        why = (
            f"its row's load has sign {math.copysign(1, components[0]):+.0f} on axis {axis} in both images "
            f"({components[0]:.3g} and {components[1]:.3g})"
            if agrees[0] == agrees[1]
            else f"its row's load lies {math.degrees(math.asin(min(elevation, 1.0))):.1f} degrees out of the known loads' "
            f"span, where noise sets its sign on axis {axis} ({components[0]:.3g} in one image, {components[1]:.3g} in "
            "the other)"
        )
        raise SfmnetError(
            f"the mirror hint cannot pick the mirror image: {why}: hint a row whose load points well out of the known "
            f"loads' span, on the axis it points along most (the direction they leave free is ({normal})), or give {n} "
            "known loads spanning every axis"
        )
    rotation = rotation if agrees[0] else mirrored
    return check_agreement(estimated_loads @ rotation, known_loads, rotation, rank_gap, circle_gap)


# A hint row's load must point at least this far (sine of the angle, ~6 degrees) out of the known loads' span.
MIN_HINT_ELEVATION = 0.1

# Known loads set to 0.2 degrees sit well inside this, and so does a nonlinear real sensor's
# closed-form frame (11 degrees on ../shared/data/ft_printed_sensor); a mislabelled load does not.
MAX_DISAGREEMENT_DEG = 30.0


def check_agreement(
    placed: torch.Tensor,
    known_loads: torch.Tensor,
    rotation: torch.Tensor,
    rank_gap: float | None = None,
    circle_gap: Callable[[], float | None] | None = None,
) -> torch.Tensor:
    """Return ``rotation`` unless a known load lies far from where the readings put it once the frame is fitted.

    Args:
        rank_gap: the readings' ``sigma_n / sigma_(n+1)``; under :data:`WARN_RANK_GAP` the readings barely span
            the load space, which places the known loads badly however right they are, so the message says so first.
        circle_gap: computes the same of the unknown-load rows about their mean; under :data:`WARN_RANK_GAP` (where
            ``rank_gap`` is not) they lie on one circle of orientations, through which the constant magnitude passes
            many calibrations, and the message says that first.

    Raises:
        SfmnetError: the known loads contradict each other (their angles differ from the readings').
    """
    cosine = (placed * known_loads).sum(dim=1) / (placed.norm(dim=1) * known_loads.norm(dim=1))
    angles = torch.rad2deg(torch.arccos(cosine.clamp(-1.0, 1.0)))
    worst = int(angles.argmax())
    if float(angles[worst]) <= MAX_DISAGREEMENT_DEG:
        return rotation
    n = known_loads.shape[1]
    where = (
        f"known load {worst + 1} of {len(known_loads)} lies {float(angles[worst]):.0f} degrees from where the readings "
        f"put it (at {100 * float(placed[worst].norm() / known_loads[worst].norm()):.0f} % of its size) relative to the "
        "other known loads"
    )
    if rank_gap is not None and rank_gap < WARN_RANK_GAP:
        raise SfmnetError(
            f"the readings barely span {n} load axes (rank gap {rank_gap:.2f}, under {WARN_RANK_GAP:g}), too weakly to "
            f"place the known loads, so {where}: the orientations cover too little of the "
            f"{'circle' if n == 2 else 'sphere'} or the sensor is too noisy; turn the mass through more of it or load "
            "the sensor more heavily, then check the known loads' columns, signs and rows"
        )
    unknown_gap = circle_gap() if circle_gap is not None and n == 3 else None
    if unknown_gap is not None and unknown_gap < WARN_RANK_GAP:
        raise SfmnetError(
            f"the rows of unknown load lie on one circle of orientations, or nearly (their readings about their mean "
            f"barely span {n} dimensions: rank gap {unknown_gap:.2f}, under {WARN_RANK_GAP:g}): the mass was turned about "
            "one axis only, or through a small cap, and the constant magnitude fits a family of calibrations through "
            f"such rows, so {where}; turn the mass about a second axis as well"
        )
    raise SfmnetError(
        f"{where}: the known loads contradict each other, or their rows' readings are too noisy to place them (far "
        "from 100 % says so); check their columns, signs and rows"
    )


def skew_generators(n: int, dtype: torch.dtype) -> torch.Tensor:
    """The ``n (n - 1) / 2`` generators ``E_a`` of rotations in ``n`` dimensions, ``a x n x n``."""
    rows, cols = torch.triu_indices(n, n, offset=1)
    generators = torch.zeros(len(rows), n, n, dtype=dtype)
    generators[torch.arange(len(rows)), rows, cols] = 1.0
    generators[torch.arange(len(rows)), cols, rows] = -1.0
    return generators


@torch.no_grad()
def known_load_rotation(
    known_readings: torch.Tensor, known_loads: torch.Tensor, shape: torch.Tensor, magnitude: float, iterations: int = 20
) -> torch.Tensor:
    """The rotation ``R`` minimising ``sum_k |y_k - F l_k / |l_k| R S|^2`` over the known-load rows (method §5).

    With one mass and free directions the unknown rows' cost does not change when ``S`` turns
    into ``R S`` (their directions turn with it), so only the few known loads hold the frame and
    the alternation turns it towards them by tiny steps (a slow mode of its iteration). This
    minimises over the turn directly: Gauss-Newton on ``R = exp(sum_a w_a E_a) R_0`` from
    ``R_0 = I``, each step halved until the sum falls, so the turn never fits the known loads worse than none. The
    sum is not Procrustes' unless ``S S^T`` is a multiple of ``I``, and for the same reason a known load whose size is
    not the mass's would turn the frame: each is taken at the magnitude ``F``, its direction alone setting the frame
    (the reader lets a size 2 % off through; a hostile tester's one known load 1.9 % heavy turned a fingertip's frame
    to 3.6x its bars, trusted). Whether the sizes agree with ``F`` is the goodness of fit's to judge
    (:func:`~sfmnet.eval.goodness_of_fit.known_load_scale`).

    Args:
        known_readings: ``k x p`` readings minus offsets ``y_k``; known_loads: ``k x n`` loads
            ``l_k``; shape: ``S``, ``n x p``; magnitude: ``F``, in the loads' units.

    Returns:
        ``R``, ``n x n``.
    """
    known_loads = magnitude * known_loads / known_loads.norm(dim=1, keepdim=True)
    n = shape.shape[0]
    generators = skew_generators(n, shape.dtype)
    rotation = torch.eye(n, dtype=shape.dtype)

    def cost(turn: torch.Tensor) -> float:
        return float((known_readings - known_loads @ turn @ shape).pow(2).sum())

    current = cost(rotation)
    for _ in range(iterations):
        turned = rotation @ shape
        residual = (known_readings - known_loads @ turned).flatten()
        # d(l R S)/dw_a at w = 0 is l E_a R S.
        jacobian = torch.stack([(known_loads @ generator @ turned).flatten() for generator in generators], dim=1)
        step = torch.linalg.lstsq(jacobian, residual[:, None]).solution[:, 0]
        if float(step.norm()) <= 1e-15:
            break
        # Halved until the cost falls: far from the known loads (a shape still far from the truth) full Gauss-Newton
        # steps swing back and forth and can end at a worse turn than none. Near the fit they converge quadratically,
        # and a cost that rounding keeps from falling must not stop them short (runs on 1 and 2 processes differed).
        for _ in range(STEP_HALVINGS):
            trial = torch.linalg.matrix_exp(torch.einsum("a,aij->ij", step, generators)) @ rotation
            trial_cost = cost(trial)
            if trial_cost < current or float(step.norm()) < CONVERGED_TURN:
                rotation, current = trial, trial_cost
                break
            step = step / 2
        else:
            break
    return rotation
