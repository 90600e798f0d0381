"""How far to trust a calibration without a reference sensor: figures and plain-language warnings."""

from __future__ import annotations

import math
from dataclasses import replace

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.eval.goodness_of_fit import (
    GoodnessOfFit,
    PoseEquations,
    goodness_of_fit,
    untied_extra_poses,
    within_group_noise,
)
from sfmnet.linalg.channel_noise import channel_noise
from sfmnet.linalg.directions import distinct_directions, median_angle_from_poses
from sfmnet.linalg.factorisation import (
    WARN_RANK_GAP,
    direction_coverage,
    known_load_equations,
    metric_unknowns,
    readings_rank_gap,
)
from sfmnet.linalg.frame import orthogonal_procrustes
from sfmnet.linalg.group_means import group_means
from sfmnet.linalg.held_poses import held_pose_clusters
from sfmnet.linalg.osculating_valley import ValleyScan, valley_scan
from sfmnet.linalg.second_quadric import quadric_exponents, second_quadric_ratio
from sfmnet.linalg.uncertainty import CalibrationUncertainty, load_error_rms
from sfmnet.models.linear_calibrator import LinearCalibrator

# Below this the orientations leave part of the load space unvisited (see README, "Diagnostics").
WARN_COVERAGE = 0.5
# Poses found in the readings that scatter more than this many times the fit's noise are not held poses: held rows
# scatter by the reading noise alone, which no fit's residuals fall below (lobes of a continuous sweep do).
MAX_FOUND_POSE_SCATTER = 2.0
# Poses found in the readings that scatter under this fraction of the readings' spread are copies of one row each.
COPY_SCATTER = 1e-9


# A triad's channel reads its own axis at least this many times as strongly as any other, once the triad's turn is
# taken out (:func:`triad_like`). Triads with cross-axis coupling up to 30 % (each off-diagonal entry uniform within
# +-0.3), turned at random: 98 % pass (75 % at 40 %); 3 x 3 matrices of random gauge directions: 8 % (22 % at 2).
TRIAD_DOMINANCE = 3.0


def triad_like(matrix: torch.Tensor) -> bool:
    """Whether the channels are a triad, each reading one load axis of its own (``C``, ``n x n``), however the triad is
    turned in the frame the known loads give: ``C = U P`` (polar), and in every column of ``P``, scaled to unit length,
    one axis's entry is :data:`TRIAD_DOMINANCE` times any other's, and no two channels share that axis. Strain gauges
    turned every way mostly are not (8 % of random gauge directions pass), and their order has no handedness. Judged on
    ``C`` itself, a triad turned 40 degrees in its housing was not one, and its negated known loads went unsaid."""
    _, singular, right = torch.linalg.svd(matrix)
    polar = right.T @ torch.diag(singular) @ right
    sizes = (polar / polar.norm(dim=0, keepdim=True)).abs()
    top = sizes.topk(2, dim=0).values
    axes = sizes.argmax(dim=0)
    return bool((top[0] >= TRIAD_DOMINANCE * top[1]).all()) and len(axes.unique()) == matrix.shape[1]


def left_handed_frame_warning(model: LinearCalibrator, matrix: torch.Tensor) -> str | None:
    """A warning where known loads set a frame that is a mirror image of the channels' (``det C < 0`` with three
    channels for three axes, which are a triad: :func:`triad_like`), else None. Two channels for two axes are a
    fingertip's gauges far more often than a 2-axis accelerometer, and random pairs of gauges look like a turned pair
    too often to tell (46 % of random 2 x 2 matrices at a dominance of 2).

    No check of the fit can see it: every magnitude is right in a mirror image. But the channels of a triad (an
    accelerometer, a magnetometer) are right-handed in the order their maker numbers them, so a left-handed frame is
    most often a known load typed with one sign or two axes wrong (a hostile tester's: every known load negated, gravity
    typed pointing down where an accelerometer at rest reads +g up, 960-1300x the bars; x and y swapped, 430-550x;
    each trusted and silent).
    """
    n, p = matrix.shape
    if not model.frame_fixed or n != p or n != 3 or float(torch.linalg.det(matrix)) >= 0 or not triad_like(matrix):
        return None
    return (
        "the known loads set a load frame that is a mirror image of the channels' (the matrix's determinant is "
        "negative): right only if the channels, in the order given, are a left-handed set; otherwise a known load has "
        "one axis's sign or two of its axes wrong (an accelerometer at rest reads +g upwards, not -g) and every load "
        "comes out mirrored"
    )


def calibration_diagnostics(
    model: LinearCalibrator,
    recording: CalibrationRecording,
    channels: list[str],
    loads: torch.Tensor,
    uncertainty: CalibrationUncertainty,
    load_unit: str,
) -> tuple[dict[str, float], list[str], GoodnessOfFit]:
    """Diagnostic metrics of a fitted model, the warnings they call for, and its goodness of fit.

    Args:
        loads: ``f x n``, each row's fitted load (:meth:`LinearCalibrator.fitted_loads`).
        uncertainty: the fit's error bars (its noise estimate is what the checks compare with).

    Returns:
        ``rank_gap`` (singular value n over n+1 of the readings, where ``p > n``),
        ``condition_number`` (of the calibration matrix), ``coverage`` (shape from motion: 1 for
        orientations spread over the whole circle or sphere), ``residual_rms/<channel>`` (raw
        units), the residuals in load units (:func:`load_residuals`) and the
        :func:`~sfmnet.eval.goodness_of_fit.goodness_of_fit` figures; the warnings
        (goodness-of-fit ones included); the goodness of fit itself.
    """
    n = recording.rank
    metrics: dict[str, float] = {}
    warnings: list[str] = []
    rank_gap = readings_rank_gap(model.singular_values, n)
    if rank_gap is not None:
        metrics["rank_gap"] = rank_gap
        if rank_gap < WARN_RANK_GAP:
            warnings.append(
                f"rank gap {rank_gap:.2f} (< {WARN_RANK_GAP:g}): the readings are barely rank {n}; "
                "the sensor is noisy or nonlinear, or the loads do not span every axis"
            )
    matrix = model.calibration_matrix()
    matrix_singular = torch.linalg.svdvals(matrix)
    metrics["condition_number"] = float(matrix_singular[0] / matrix_singular[-1])
    coverage = model.coverage
    if math.isfinite(coverage):
        metrics["coverage"] = coverage
        if coverage < WARN_COVERAGE:
            warnings.append(
                f"coverage {coverage:.2f} (< {WARN_COVERAGE:g}; 1 is a full {'circle' if n == 2 else 'sphere'}): "
                "the orientations leave part of the load space unvisited; turn the mass through more of it"
            )
    handedness = left_handed_frame_warning(model, matrix)
    if handedness:
        warnings.append(handedness)
    residuals = model.fitted_residuals(recording, loads)
    # Norms, not squares: no second f x p array (a million-row recording's is 48 MB).
    residual = torch.linalg.vector_norm(residuals, dim=0) / math.sqrt(len(residuals))
    metrics.update({f"residual_rms/{name}": float(value) for name, value in zip(channels, residual)})
    metrics.update(load_residuals(residuals, matrix))
    # An unconstrained row's load is free in all n dimensions; a constrained one has d - 1 free.
    direction_dims = recording.maps.shape[1] if model.constrained else recording.rank + 1
    known = recording.known
    groups = recording.same_load_groups
    found = groups is None
    if found:
        groups = held_pose_groups(recording, uncertainty.noise_std)
    pose_sums = model.interval_sums()
    # Pose means of a sample of every w-th row (a streamed fit without sums) see only 1 / w of the fit's parameters.
    share = 1.0 if pose_sums is not None else 1 / model.unknown_row_weight(recording)
    # A force's direction is its load's; a wrench's (six axes) is not its load's first axes, so none is judged.
    directions = loads / loads.norm(dim=1, keepdim=True) if loads.shape[1] == direction_dims else None
    constraint = constraint_terms(model, recording)
    goodness = goodness_of_fit(
        residuals,
        recording.readings,
        known,
        direction_dims,
        uncertainty.noise_std,
        bool(model.robust),
        groups,
        model.motion_of(recording.readings[known]),
        recording.loads[known],
        matrix,
        load_unit,
        constraint,
        osculating_valley(model, recording, uncertainty),
        distinct_poses(model, recording, loads, uncertainty.noise_std),
        uncertainty.matrix_std,
        refinement_disagreement(model, recording, uncertainty),
        model.learnt_orientation_law,
        global_parameters(model, recording, direction_dims) * share,
        pose_sums,
        poses_found=found,
        alternation_bias=model.alternation_bias(),
        serial_design=torch.cat([loads, torch.ones(len(loads), 1, dtype=loads.dtype)], dim=1) if model.estimate_offset else loads,
        serial_directions=directions,
        # What the magnitude constraint itself sees: the unknown rows' directions.
        unknown_row_coverage=direction_coverage(directions[~known])
        if model.constrained and directions is not None and bool((~known).any()) else None,
        unknown_row_centred_coverage=direction_coverage(directions[~known], centred=True)
        if model.constrained and directions is not None and directions.shape[1] == 3 and int((~known).sum()) > 3
        else None,
        channel_names=channels,
        second_quadric_ratio=second_quadric(model, recording, uncertainty, constraint),
    )
    metrics.update(goodness.metrics)
    return metrics, [*warnings, *goodness.warnings], goodness


def held_pose_groups(recording: CalibrationRecording, fit_noise: float) -> torch.Tensor | None:
    """``f`` (long): the poses the rows were held at, found in their readings where no time or pose column gives them
    (:func:`~sfmnet.linalg.held_poses.held_pose_clusters`), split by load as
    :attr:`~sfmnet.data.recording.CalibrationRecording.same_load_groups` splits given ones; None where the rows show
    none, or where they scatter more than :data:`MAX_FOUND_POSE_SCATTER` times ``fit_noise`` (raw units) within them, or
    under :data:`COPY_SCATTER` of the readings' spread (copies of one reading)."""
    # One configuration at a time: another mass's poses may lie among this one's readings.
    configuration = recording.row_configuration
    clusters = torch.empty(len(configuration), dtype=torch.long)
    found, offset = False, 0
    for value in torch.unique(configuration):
        rows = configuration == value
        poses = held_pose_clusters(recording.readings[rows])
        found |= poses is not None
        labels = torch.arange(int(rows.sum())) if poses is None else poses
        clusters[rows] = offset + labels
        offset += int(labels.max()) + 1
    if not found:
        return None
    groups = replace(recording, groups=clusters).same_load_groups
    within = within_group_noise(recording.readings, groups)
    # Rows identical to rounding are one reading logged several times (the repeated-rows check says so), not a pose
    # held with its noise: judged against them, any fit would miss by 1e14x.
    copies = within <= COPY_SCATTER * float(recording.readings.std())
    return groups if not copies and within <= MAX_FOUND_POSE_SCATTER * fit_noise else None


def global_parameters(model: LinearCalibrator, recording: CalibrationRecording, direction_dims: int) -> int:
    """The fit's parameters shared by every row: the shape's ``n p`` and the offsets' ``p`` (when estimated), less the
    ``d (d - 1) / 2`` of the directions' rotation where no known load fixes the frame (a gauge, not a parameter)."""
    n, p = recording.rank, recording.readings.shape[1]
    gauge = 0 if bool(recording.known.any()) else direction_dims * (direction_dims - 1) // 2
    return n * p + (p if model.estimate_offset else 0) - gauge


def load_residuals(residuals: torch.Tensor, matrix: torch.Tensor) -> dict[str, float]:
    """The residuals in load units: RMS over rows of ``|C r_j|``, the force axes (first up to three) and the rest.

    ``C (z - o) = m + C r`` (``C S = I``), so ``C r_j`` is how far the calibration puts row ``j``'s
    load from the load the fit gave it: off the known load, or off the constant magnitude ``F``.

    Args:
        residuals: ``f x p``, ``z - m S - o`` (raw units); matrix: ``C``, ``n x p``.

    Returns:
        ``load_residual/force_rms`` and, with more than three axes, ``load_residual/torque_rms`` (load units).
    """
    loads = residuals @ matrix.T
    rms = lambda part: float(torch.linalg.vector_norm(part) / math.sqrt(len(part)))  # noqa: E731
    metrics = {"load_residual/force_rms": rms(loads[:, :3])}
    if loads.shape[1] > 3:
        metrics["load_residual/torque_rms"] = rms(loads[:, 3:])
    return metrics


def one_constrained_mass(model: LinearCalibrator, recording: CalibrationRecording) -> bool:
    """Whether every unknown row is one constant-magnitude mass (no six-axis configurations) under a constrained model."""
    return recording.direction_maps is None and model.constrained


def refinement_disagreement(
    model: LinearCalibrator, recording: CalibrationRecording, uncertainty: CalibrationUncertainty
) -> float | None:
    """How far the alternation fitted beside the model (:meth:`LinearCalibrator.alternation_beside`) lies from it, in
    its error bars: ``|R C_alt - C|_F / |matrix_std|_F``, ``R`` the orthogonal map that best turns the alternation's frame
    into the fit's (the frame has its own check, the known loads'). None without one (one constant-magnitude mass only)."""
    if not one_constrained_mass(model, recording):
        return None
    beside = model.alternation_beside(recording)
    bars = float(uncertainty.matrix_std.norm())
    if beside is None or not bars > 0:
        return None
    matrix, other = model.calibration_matrix(), beside.calibration_matrix()
    turn = orthogonal_procrustes(other.T, matrix.T)
    return float((turn.T @ other - matrix).norm()) / bars


def constraint_terms(model: LinearCalibrator, recording: CalibrationRecording) -> tuple[torch.Tensor, torch.Tensor, float] | None:
    """What :func:`~sfmnet.eval.goodness_of_fit.constraint_noise_ratio` needs, where it applies: more
    channels than axes, one constant magnitude, unknown-load rows, a constrained model."""
    unknown = ~recording.known
    p, n = recording.readings.shape[1], recording.rank
    if p <= n or not one_constrained_mass(model, recording) or int(unknown.sum()) <= n:
        return None
    # One f x p array, made in place: a million rows' is 48 MB.
    off_space = recording.readings[unknown] - model.physical_offset()
    loads = off_space @ model.calibration_matrix().T
    off_space.addmm_(loads, model.physical_shape(), alpha=-1)
    return loads, off_space, recording.magnitude


def osculating_valley(
    model: LinearCalibrator, recording: CalibrationRecording, uncertainty: CalibrationUncertainty
) -> tuple[ValleyScan, float] | None:
    """:func:`~sfmnet.linalg.osculating_valley.valley_scan` and the RMS load error the bars predict
    (:func:`~sfmnet.linalg.uncertainty.load_error_rms`), where the valley exists: one constant-magnitude
    mass, offsets estimated (tared readings fix the sphere's centre), a constrained model. The scan's
    likelihood is the joint one (each row's direction fitted) with Gaussian noise, the one the
    alternation maximises; a marginal or robust fit maximises another, whose optimum the scan would
    take for a valley."""
    unknown = ~recording.known
    if not one_constrained_mass(model, recording) or not model.estimate_offset:
        return None
    if not model.joint_likelihood or model.robust:
        return None
    if int(unknown.sum()) <= recording.rank or not uncertainty.noise_std > 0:
        return None
    known, shape = recording.known, model.physical_shape()
    readings, weight = recording.readings[unknown], model.unknown_row_weight(recording)
    poses = model.unknown_poses(recording)
    if poses is not None:
        # A pose's rows share one direction: its likelihood is its mean's, weighted by its rows, up to a constant.
        readings, _, counts = group_means(readings, poses)
        weight = weight * counts.to(readings.dtype)
    scan = valley_scan(
        readings,
        shape,
        model.physical_offset(),
        recording.magnitude,
        uncertainty.noise_std,
        recording.readings[known],
        recording.loads[known],
        weight,
    )
    return scan, load_error_rms(shape, model.calibration_matrix(), uncertainty, recording.magnitude)


# From this SNR (F |s| over the fit's noise) up, a marginal fit's rows are judged by the second quadric's ratio; below
# it every quadric is within their noise and the ratio tells nothing: at SNR 10 (the fit's 9.5-12 on the sphere) rows
# over the sphere, hemisphere and band read 1.1-4.2 with 3 channels and 2.2-15 with 6, whether their bars held or not.
# At SNR 20 and 50 (3 channels, 64 sessions) the marginal's silent failures read 1.3-1.6 and cost 2 of 45 bars that
# held (method §5, "Two circles of orientations"; bench/crb_ratio.py --laws --p-equals-n).
SECOND_QUADRIC_MARGINAL_FROM_SNR = 15.0


def second_quadric(
    model: LinearCalibrator,
    recording: CalibrationRecording,
    uncertainty: CalibrationUncertainty,
    constraint: tuple[torch.Tensor, torch.Tensor, float] | None = None,
) -> float | None:
    """:func:`~sfmnet.linalg.second_quadric.second_quadric_ratio` of the unknown rows' loads over the magnitude, where only
    the constant magnitude fixes the calibration and each row's direction was fitted on its own: one constant-magnitude
    mass, no known loads (they pin the family eq. Q1 leaves free), untied (a few tied poses' means carry little of that
    noise, and their bars held where they read near 1: method §5, "Two circles of orientations"), and a joint-likelihood
    fit (the alternation's bars count each fitted direction's noise as information) or a marginal one from
    :data:`SECOND_QUADRIC_MARGINAL_FROM_SNR` up (it integrates the directions out, but a law learnt on rows near a
    second quadric concentrates there and leaves the family as free; below that SNR every quadric is within the
    noise). Each channel's noise is the readings' off the load space where they tell the channels apart
    (``constraint``, :func:`constraint_terms`; six channels or more for three axes), else the fit's one noise for all.
    None elsewhere, or with no more rows than the quadric's monomials."""
    if not one_constrained_mass(model, recording) or bool(recording.known.any()):
        return None
    if model.unknown_poses(recording) is not None or not uncertainty.noise_std > 0:
        return None
    matrix, magnitude = model.calibration_matrix(), recording.magnitude
    # The fit's own SNR (a fit gone wrong along the family has a shrunken shape, and reads low).
    if not model.joint_likelihood and model.signal_to_noise_at(magnitude, uncertainty.noise_std) < SECOND_QUADRIC_MARGINAL_FROM_SNR:
        return None
    if len(recording.readings) <= len(quadric_exponents(recording.rank, model.estimate_offset)):
        return None
    points = (recording.readings - model.physical_offset()) @ matrix.T / magnitude
    channels = None if constraint is None else channel_noise(constraint[1], matrix)
    # Unequal channel noise taken as equal misplaces the noise across the load space: two circles read up to 3.
    variances = torch.full((matrix.shape[1],), uncertainty.noise_std**2, dtype=matrix.dtype) if channels is None else channels.variances
    covariance = (matrix * variances) @ matrix.T / magnitude**2
    return second_quadric_ratio(points, covariance, model.estimate_offset)


# Rows within this many standard deviations of a direction's noise (or this angle, radians, at most) are one pose.
POSE_NOISE_SIGMAS = 10.0
MAX_POSE_TOLERANCE = 0.3


def distinct_poses(
    model: LinearCalibrator, recording: CalibrationRecording, loads: torch.Tensor, noise_std: float
) -> PoseEquations | None:
    """How many equations of the metric constraint the rows' poses give, how many it needs, and whether the rows
    sit at their poses.

    Rows held in one orientation repeat one equation ``|m| = F``: only distinct directions count
    (:func:`~sfmnet.linalg.directions.distinct_directions`, within ``POSE_NOISE_SIGMAS`` of a
    direction's noise ``s |C|_F sqrt((n-1)/n) / F``; one along a known load adds nothing), and the known
    loads give :func:`~sfmnet.linalg.factorisation.known_load_equations`. Where
    they number fewer than ``n(n+1)/2 (+ n)`` (:func:`~sfmnet.linalg.factorisation.metric_unknowns`)
    the shape is not determined, however many rows repeat them; where they number exactly that, it is
    determined with nothing left to test it. Fitted row by row (untied), the error bars
    need ``n(n+1)/2`` more (:func:`~sfmnet.eval.goodness_of_fit.untied_extra_poses`): where fewer are found, the
    rows' median angle from their pose's mean (:func:`~sfmnet.linalg.directions.median_angle_from_poses`) over a
    direction's RMS noise says whether they were held there (about 0.8) or sweep between them. One constant-magnitude
    mass only.
    """
    if not one_constrained_mass(model, recording):
        return None
    n, magnitude = recording.rank, recording.magnitude
    needed = metric_unknowns(n, model.estimate_offset)
    tied = model.unknown_poses(recording) is not None
    untied_needed = needed + untied_extra_poses(n)
    enough = needed if tied else untied_needed
    known = recording.known
    angle = noise_std * float(model.calibration_matrix().norm()) * math.sqrt((n - 1) / n) / magnitude
    tolerance = min(POSE_NOISE_SIGMAS * angle, MAX_POSE_TOLERANCE)
    directions = loads[~known] / loads[~known].norm(dim=1, keepdim=True)
    if known.any():
        # An unknown pose along a known load repeats equations the known load already gives.
        known_directions = loads[known] / loads[known].norm(dim=1, keepdim=True)
        directions = directions[~(directions @ known_directions.T > math.cos(tolerance)).any(dim=1)]
    known_equations = known_load_equations(n, recording.distinct_known_loads)
    # Counted one past what suffices: a calibration the poses only just determine is told from one they over-determine.
    leaders = distinct_directions(directions, tolerance, max(enough - known_equations, 0) + 1)
    equations = len(leaders) + known_equations
    scatter = float("nan")
    if len(leaders) and equations < enough and angle > 0:
        scatter = median_angle_from_poses(directions, leaders) / angle
    return PoseEquations(equations, needed, tied, untied_needed, scatter)
