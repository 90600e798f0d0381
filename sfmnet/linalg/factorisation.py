"""Closed-form shape from motion (paper section 4, eqs. 5-11; method §2 and §4).

Conventions used across sfmnet (row vectors, as in the paper):

- ``Z``: readings, ``f x p`` (f samples, p raw channels).
- ``M``: motion, ``f x n`` (one load per row, in load units).
- ``S``: shape, ``n x p``; the model is ``Z = M S (+ 1 o^T)``  (eq. 5).
- The calibration matrix ``C = pinv(S)^T`` is ``n x p``: ``load = C (z - o)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from sfmnet.errors import SfmnetError
from sfmnet.linalg.chi_square import robust_noise_variance

# Singular values below this fraction of the largest are treated as numerically zero.
RANK_TOLERANCE = 1e-9


@dataclass(frozen=True)
class AffineFactors:
    """Rank-n factors of the readings, known only up to an invertible n x n transform (eq. 9).

    Attributes:
        motion: ``M^ = U* Sigma*^(1/2)``, ``f x n`` (eq. 8).
        shape: ``S^ = Sigma*^(1/2) V*^T``, ``n x p`` (eq. 8).
        singular_values: all ``min(f, p)`` singular values of the (centred) readings.
        mean: the column mean that was removed, ``p`` (zeros when not centred).
    """

    motion: torch.Tensor
    shape: torch.Tensor
    singular_values: torch.Tensor
    mean: torch.Tensor


def truncated_svd_factors(readings: torch.Tensor, rank: int, centre: bool = False) -> AffineFactors:
    """Best rank-n factorisation of the readings by truncated SVD (paper eqs. 6-8).

    Args:
        readings: ``Z``, ``f x p``.
        rank: ``n``, the number of load dimensions.
        centre: remove the column mean first (for offsets, method §4, and for PCA).

    Returns:
        The affine factors ``M^`` (``f x n``) and ``S^`` (``n x p``) with ``M^ S^ = Z*``.

    Raises:
        SfmnetError: if there are fewer samples or channels than ``rank``, or the
            readings do not span ``rank`` dimensions (e.g. all loads collinear).
    """
    f, p = readings.shape
    if p < rank:
        raise SfmnetError(
            f"the sensor has {p} channels but {rank} load axes are asked for: "
            f"a calibration needs at least as many channels as load axes"
        )
    if f < rank:
        raise SfmnetError(
            f"only {f} samples for a rank-{rank} factorisation: record at least {rank} (many more is better)"
        )
    mean = readings.mean(dim=0) if centre else torch.zeros(p, dtype=readings.dtype)
    u, s, vt = torch.linalg.svd(readings - mean, full_matrices=False)
    if s[rank - 1] <= RANK_TOLERANCE * s[0]:
        raise SfmnetError(
            f"the readings span fewer than {rank} dimensions (singular value {rank} is "
            f"{float(s[rank - 1] / s[0]):.1e} of the largest): the loads are collinear or coplanar; "
            f"turn the mass through orientations that span all {rank} load axes"
        )
    root = s[:rank].sqrt()
    return AffineFactors(
        motion=u[:, :rank] * root,
        shape=root[:, None] * vt[:rank],
        singular_values=s,
        mean=mean,
    )


def quadratic_design(points: torch.Tensor) -> torch.Tensor:
    """Rows ``[y_a y_b]`` for ``a <= b`` (doubled off the diagonal): ``y Q y^T = design @ vech(Q)``.

    Args:
        points: ``f x n``.

    Returns:
        ``f x n(n+1)/2``, the generalisation of the paper's ``[m1^2, 2 m1 m2, m2^2]`` (eq. 11).
    """
    n = points.shape[1]
    rows, cols = torch.triu_indices(n, n)
    weight = torch.where(rows == cols, 1.0, 2.0).to(points.dtype)
    return points[:, rows] * points[:, cols] * weight


def symmetric_from_upper(values: torch.Tensor, n: int) -> torch.Tensor:
    """Inverse of the packing used by :func:`quadratic_design`: ``n(n+1)/2`` values to ``n x n``."""
    rows, cols = torch.triu_indices(n, n)
    q = torch.zeros(n, n, dtype=values.dtype)
    q[rows, cols] = values
    q[cols, rows] = values
    return q


def metric_unknowns(rank: int, offsets: bool) -> int:
    """Unknowns of the metric constraint: ``n(n+1)/2`` entries of ``Q``, plus ``n`` for the centre with offsets."""
    return rank * (rank + 1) // 2 + (rank if offsets else 0)


def known_load_equations(rank: int, known_loads: int) -> int:
    """Equations of the metric constraint's unknowns that ``known_loads`` distinct known loads give: ``n`` each, less
    the ``n(n-1)/2`` that turn the frame into theirs (a rotation the unknown poses alone leave free)."""
    return rank * known_loads - rank * (rank - 1) // 2 if known_loads else 0


def metric_gram(motion: torch.Tensor, magnitude: float) -> torch.Tensor:
    """Solve the metric constraint ``m^_j Q m^_j^T = F^2`` for ``Q = B B^T`` by least squares (eq. 11).

    Args:
        motion: affine motion ``M^``, ``f x n``.
        magnitude: ``F``, the constant load magnitude (load units).

    Returns:
        ``Q``, ``n x n``, symmetric positive definite.

    Raises:
        SfmnetError: with fewer samples than the ``n(n+1)/2`` unknowns, or when ``Q`` is not
            positive definite (the motion does not span the space).
    """
    f, n = motion.shape
    unknowns = metric_unknowns(n, offsets=False)
    if f < unknowns:
        raise SfmnetError(
            f"only {f} samples for {unknowns} unknowns of the metric constraint: "
            f"record at least {unknowns} orientations (dozens give a good calibration)"
        )
    coefficients = torch.linalg.lstsq(metric_design(motion, centre_free=False), motion.new_ones(f, 1)).solution[:, 0]
    return ellipsoid_from_coefficients(coefficients, n, magnitude).gram


def positive_definite_or_raise(q: torch.Tensor) -> torch.Tensor:
    """Return ``q`` if it is positive definite, else raise the error method §2 step 4 asks for."""
    eigenvalues = torch.linalg.eigvalsh(q)
    if eigenvalues[0] <= RANK_TOLERANCE * eigenvalues[-1].abs():
        raise SfmnetError(
            "the metric constraint has no positive-definite solution (Q eigenvalues "
            f"{[round(float(v), 6) for v in eigenvalues]}): the loads are collinear or coplanar (turned about one "
            "axis only: one circle of orientations, tilted or not), or their magnitude is not constant; turn one mass "
            "through orientations that span every load axis, about a second axis as well"
        )
    return q


def metric_shape(affine_shape: torch.Tensor, gram: torch.Tensor) -> torch.Tensor:
    """``S = B^-1 S^`` with ``B`` the Cholesky factor of ``Q = B B^T`` (eq. 10; ``M = M^ B`` correspondingly).

    Args:
        affine_shape: ``S^``, ``n x p``.
        gram: ``Q``, ``n x n``.

    Returns:
        ``S``, ``n x p``, right up to an orthogonal transform of the load frame.
    """
    return torch.linalg.solve_triangular(torch.linalg.cholesky(gram), affine_shape, upper=False)


@dataclass(frozen=True)
class EllipsoidFit:
    """Centre and metric of the motion when the readings carry unknown offsets (method §4).

    Attributes:
        centre: ``c``, ``n``, in the coordinates of the affine motion.
        gram: ``Q``, ``n x n``, so that ``(y - c) Q (y - c)^T = F^2``.
    """

    centre: torch.Tensor
    gram: torch.Tensor


def fit_ellipsoid(points: torch.Tensor, magnitude: float) -> EllipsoidFit:
    """Fit ``y A y^T + b y^T = 1`` by least squares, then ``c = -A^-1 b / 2``, ``Q = F^2 A / (1 + c A c^T)``.

    Args:
        points: the centred readings projected on the principal subspace, ``f x n``.
        magnitude: ``F``.

    Raises:
        SfmnetError: too few samples for the ``n(n+1)/2 + n`` unknowns, or no ellipsoid.
    """
    f, n = points.shape
    unknowns = metric_unknowns(n, offsets=True)
    if f < unknowns:
        raise SfmnetError(
            f"only {f} samples for {unknowns} unknowns of the metric constraint with offsets: "
            f"record at least {unknowns} orientations (dozens give a good calibration)"
        )
    coefficients = torch.linalg.lstsq(metric_design(points, centre_free=True), points.new_ones(f, 1)).solution[:, 0]
    return ellipsoid_from_coefficients(coefficients, n, magnitude)


def metric_design(points: torch.Tensor, centre_free: bool) -> torch.Tensor:
    """Rows of the metric constraint's linear system ``design @ coefficients = 1``.

    Args:
        points: ``f x n``.
        centre_free: add the linear terms ``y`` of an ellipsoid with an unknown centre (offsets).

    Returns:
        ``f x n(n+1)/2`` (:func:`quadratic_design`), or ``f x (n(n+1)/2 + n)`` with the centre free.
    """
    quadratic = quadratic_design(points)
    return torch.cat([quadratic, points], dim=1) if centre_free else quadratic


def ellipsoid_from_coefficients(coefficients: torch.Tensor, n: int, magnitude: float) -> EllipsoidFit:
    """The ellipsoid ``y A y^T + b y^T = 1`` (``b`` absent: centred) as centre ``c = -A^-1 b / 2`` and
    metric ``Q = F^2 A / (1 + c A c^T)`` (eq. 11 with method §4's offsets).

    Args:
        coefficients: ``vech(A)`` (``n(n+1)/2``), then ``b`` (``n``) when the centre is free.
        n: the dimension.
        magnitude: ``F``.

    Raises:
        SfmnetError: no ellipsoid (``A`` or ``Q`` not positive definite).
    """
    a = positive_definite_or_raise(symmetric_from_upper(coefficients[: n * (n + 1) // 2], n))
    b = coefficients[n * (n + 1) // 2 :]
    if len(b) == 0:
        return EllipsoidFit(centre=a.new_zeros(n), gram=positive_definite_or_raise(magnitude**2 * a))
    centre = -torch.linalg.solve(a, b) / 2
    scale = 1 + centre @ a @ centre
    return EllipsoidFit(centre=centre, gram=positive_definite_or_raise(magnitude**2 * a / scale))


# A distinct reading whose leverage in the metric constraint's least squares is this many times the mean's (``k / u``, ``k``
# its unknowns, ``u`` the distinct readings) could take it over. On the printed sensor's light load
# (../shared/data/ft_printed_sensor, configuration 0, 23,997 rows, 1,163 distinct readings) two rows, one of them a
# channel jumping 4,143 counts, sit at 129x and 78x, the rest under 2.8x, and left it no positive-definite solution;
# one more row with a channel's sign flipped, at 116x, bent its start to 2.39 N RMS off the 3.03 N loads (0.54 N without).
# With a glitch of 2-12x the readings' span on one channel of one row in 2,400 (12 held poses, 10 seeds;
# tests/test_gross_outliers.py), every session it broke had that row at 124-267x; clean sessions' largest was 1.4-1.5x.
GROSS_OUTLIER_LEVERAGE = 50.0

# But a lone row can lie far from the rest and be right: a known load held once beside a thousand rows in a 35-degree
# cap sits at 87-110x. So a reading past the leverage limit is left out only where, added to the least squares of every
# other reading, it raises their residual sum of squares by over this fraction (:func:`takeover_fraction`). Lone known
# loads in caps measure 0.064 at most (82 rows past the limit in 54 sessions: SNR 5-50, 100-30,000 rows); the glitches
# above 1.4-1,100 (22 past it in 24 sessions, 2-100 spans), the printed sensor's three 9-28. In standard errors the lone
# rows reach 42 at 30,000 rows, which is why it is not a studentised residual: the cap's fit carries the
# errors-in-variables bias of a quadric, which does not shrink with rows.
GROSS_OUTLIER_TAKEOVER = 0.25

# Readings past this fraction of the leverage limit may hide a candidate (:func:`takeover_screen`): a spike of 2.5 spans
# beside one of 5 sits at 39x the mean leverage, under the limit, and fits the start to itself where the one of 5 is
# judged. Clean sessions' readings stay under 3x; a known load held for three rows, 17-38x.
SUSPECT_FRACTION = 0.2


@dataclass(frozen=True)
class ClosedFormShape:
    """The closed form's calibration (paper eqs. 5-11; method §4 with offsets).

    Attributes:
        shape: ``S``, ``n x p`` (raw units per load unit), right up to an orthogonal transform of the load frame;
            without a magnitude the affine ``S^`` (eq. 8).
        offset: ``o``, ``p`` (the column mean without a magnitude; zeros without offsets).
        singular_values: all singular values of the (centred) readings it was solved on.
        left_out: ``f`` (bool), the gross outliers left out (:func:`gross_outliers`).
    """

    shape: torch.Tensor
    offset: torch.Tensor
    singular_values: torch.Tensor
    left_out: torch.Tensor


def closed_form_shape(readings: torch.Tensor, rank: int, magnitude: float | None, offsets: bool) -> ClosedFormShape:
    """Truncated SVD (eqs. 6-8), then the metric constraint ``|m_j| = F`` (eqs. 10-11; an ellipsoid with offsets,
    method §4).

    The metric constraint is a least-squares fit of a quadric, where a row's weight grows as the fourth power of its
    distance: one glitched row far outside the rest takes it over, pulling the start the refinement sets out from or
    leaving it no positive-definite solution at all. So the rows :func:`gross_outliers` finds are left out of it
    (method §2, "A glitch"); on clean recordings there are none.

    Args:
        readings: ``Z``, ``f x p`` (raw units).
        rank: ``n``.
        magnitude: ``F`` (load units); None: no metric constraint (the affine factors, PCA).
        offsets: estimate the channel offsets ``o``.

    Raises:
        SfmnetError: the readings span fewer than ``n`` dimensions, or no positive-definite metric fits them.
    """
    left_out = torch.zeros(len(readings), dtype=torch.bool)
    if magnitude is not None:
        left_out = gross_outliers(truncated_svd_factors(readings, rank, centre=offsets).motion, offsets)
    return ClosedFormShape(*metric_solution(readings[~left_out], rank, magnitude, offsets), left_out=left_out)


def metric_solution(
    readings: torch.Tensor, rank: int, magnitude: float | None, offsets: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`closed_form_shape` on every row given: ``(S, o, singular values)``."""
    factors = truncated_svd_factors(readings, rank, centre=offsets)
    shape, offset = factors.shape, factors.mean
    if magnitude is not None and offsets:
        ellipsoid = fit_ellipsoid(factors.motion, magnitude)
        offset = factors.mean + ellipsoid.centre @ factors.shape
        shape = metric_shape(factors.shape, ellipsoid.gram)
    elif magnitude is not None:
        shape = metric_shape(factors.shape, metric_gram(factors.motion, magnitude))
    return shape, offset, factors.singular_values


def gross_outliers(points: torch.Tensor, offsets: bool) -> torch.Tensor:
    """Rows that take over the metric constraint's least squares without belonging to it: ``f`` (bool).

    A distinct reading is one where both
    - its leverage there, ``h = d (D^T D)^+ d^T`` (:func:`design_leverage`; ``D`` the design of the distinct readings,
      :func:`metric_design`, ``u x k``: ``k = n(n+1)/2``, with offsets ``+ n``), is over :func:`leverage_limit`: the
      design is quadratic in the readings, so a row's pull grows as the fourth power of its distance, and a glitch a
      few times the readings' span outweighs thousands of rows; and
    - added to the least squares of the others, it raises their residual sum of squares by over
      :data:`GROSS_OUTLIER_TAKEOVER` (:func:`takeover_fraction`): a lone row far from the rest that is right (a known
      load held once) agrees with them and moves their fit only where they leave it loose.

    Distinct readings, not rows: rows repeating one corrupted reading (a dropped packet read as zeros) would share
    their leverage and hide. Glitches hide one another too (the samples of a spike that lasts two or three), from
    the leverage and from the take-over alike, so the screen (:func:`takeover_screen`) also judges the readings of
    high leverage together, and is repeated on what is left until it leaves nothing more out. A pose
    held for many rows cannot be left out this way: its readings differ by the noise and share their leverage.

    Args:
        points: the (centred) readings projected on the principal subspace, ``f x n``.
        offsets: the design has the centre's linear terms.
    """
    distinct, index = torch.unique(points, dim=0, return_inverse=True)
    design = metric_design(distinct, centre_free=offsets)
    gross = torch.zeros(len(design), dtype=torch.bool)
    while True:
        kept = torch.nonzero(~gross)[:, 0]
        found = takeover_screen(design[kept])
        if not bool(found.any()):
            return gross[index]
        gross[kept[found]] = True


def takeover_screen(design: torch.Tensor) -> torch.Tensor:
    """One pass of :func:`gross_outliers`' screen on the distinct readings' design ``D`` (``u x k``): the readings it
    leaves out, ``u`` (bool).

    Each candidate (past :func:`leverage_limit`) is judged against every other reading, the other candidates among
    them: lone known loads judged beside one another hold the fit where the rest leave it loose. One that takes it
    over is left out. Where none does, the high-leverage readings (past :data:`SUSPECT_FRACTION` of the limit) may
    hide one another (a spike decaying over two or three samples, the smaller ones under the limit): if together
    they take over the bulk, every reading under that fraction, by more than each one's share of the limit, the
    candidate that takes the bulk over most, judged alone against it, is left out, and the next pass judges the rest
    without it. Right lone rows together move a cap's fit by about the sum of what each does (three known loads
    beside a 35-degree cap: 0.27 together, 0.09-0.18 alone), which is why each has its share; the three samples of a
    decaying spike, 3.1 together and 2.6 each alone, 0.0005-0.009 each beside the others.
    """
    leverage = design_leverage(design, design.T @ design)
    limit = leverage_limit(design.shape[1], len(design))
    candidates = torch.nonzero(leverage > limit)[:, 0]
    found = torch.zeros(len(design), dtype=torch.bool)
    if not len(candidates):
        return found
    bulk = leverage <= SUSPECT_FRACTION * limit
    ones = design.new_ones(int(bulk.sum()))
    bulk_residual = ones - design[bulk] @ torch.linalg.lstsq(design[bulk], ones[:, None]).solution[:, 0]
    # Floored at a relative 1e-8 so that exact (simulated) readings do not score rounding.
    variance = max(robust_noise_variance(bulk_residual**2, torch.ones_like(bulk_residual)), 1e-16)
    high = ~bulk
    high[candidates] = False
    # The others' normal equations built up from the bulk's, not taken down from every row's, which a glitch dominates.
    bulk_fit = LeastSquaresRows.of(design[bulk])
    rest_fit = bulk_fit.plus(design[high])
    for i, candidate in enumerate(candidates):
        peers = design[torch.cat([candidates[:i], candidates[i + 1 :]])]
        fraction = takeover_fraction(design[candidate[None]], rest_fit.plus(peers), variance)
        found[candidate] = fraction > GROSS_OUTLIER_TAKEOVER
    if bool(found.any()):
        return found
    suspects = torch.nonzero(~bulk)[:, 0]
    if takeover_fraction(design[suspects], bulk_fit, variance) > GROSS_OUTLIER_TAKEOVER * len(suspects):
        alone = torch.tensor([takeover_fraction(design[candidate[None]], bulk_fit, variance) for candidate in candidates])
        found[candidates[alone.argmax()]] = True
    return found


@dataclass(frozen=True)
class LeastSquaresRows:
    """The normal equations of ``D c = 1`` over some rows: ``N = D^T D`` (``k x k``), ``b = D^T 1`` (``k``), and the
    number of rows."""

    normal: torch.Tensor
    right: torch.Tensor
    rows: int

    @staticmethod
    def of(design: torch.Tensor) -> LeastSquaresRows:
        return LeastSquaresRows(design.T @ design, design.sum(dim=0), len(design))

    def plus(self, design: torch.Tensor) -> LeastSquaresRows:
        return LeastSquaresRows(self.normal + design.T @ design, self.right + design.sum(dim=0), self.rows + len(design))


def takeover_fraction(group: torch.Tensor, others: LeastSquaresRows, variance: float) -> float:
    """How far a group of rows ``D_G`` (``g x k``), added to the least squares ``D c = 1`` of others, raises the others'
    residual sum of squares, as a fraction of ``o s^2`` (``o`` the others' rows, ``s^2`` their noise variance).

    With ``N`` the others' normal matrix and ``c`` their fit, ``Q = D_G N^+ D_G^T`` and ``r = 1 - D_G c`` the group's
    residuals, adding the group moves the coefficients by ``N^+ D_G^T (I + Q)^-1 r`` (Woodbury), which raises the
    others' sum of squares by ``r^T (I + Q)^-1 Q (I + Q)^-1 r`` (for one row, ``r^2 q / (1 + q)^2``). A group with a
    row in a direction the others do not measure moves nothing they fit and scores 0.
    """
    eigenvalues, basis = torch.linalg.eigh(others.normal)
    measured = eigenvalues > RANK_TOLERANCE * eigenvalues[-1]
    rows = group @ basis
    if bool((rows[:, ~measured].abs() > RANK_TOLERANCE * rows.abs().max()).any()):
        return 0.0
    coefficients = basis[:, measured] @ (others.right @ basis[:, measured] / eigenvalues[measured])
    spread = (rows[:, measured] / eigenvalues[measured]) @ rows[:, measured].T
    residual = 1 - group @ coefficients
    pulled = torch.linalg.solve(torch.eye(len(group), dtype=group.dtype) + spread, residual)
    return float(pulled @ spread @ pulled) / (others.rows * variance)


def design_leverage(design: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """Each row's leverage ``h_j = d_j N^+ d_j^T`` in a least squares with normal matrix ``N = D^T D``: ``f`` for
    ``design`` ``f x k`` (a block of ``D``'s rows, so that a stream can take it pass by pass)."""
    return ((design @ torch.linalg.pinv(normal)) * design).sum(dim=1)


def leverage_limit(unknowns: int, rows: float) -> float:
    """:data:`GROSS_OUTLIER_LEVERAGE` times the mean leverage, ``k / f`` (the leverages sum to the ``k`` unknowns)."""
    return GROSS_OUTLIER_LEVERAGE * unknowns / rows


def gross_outlier_note(left_out: int, rows: int, robust: bool = False) -> str:
    """What a fit says when :func:`closed_form_shape` left gross outliers out of its start."""
    fit = (
        "the robust fit down-weights them"
        if robust
        else "the fit itself weighs every row: remove them (outlier_rows in calibration.json) or set model.robust=huber"
    )
    return (
        f"{left_out} of {rows} rows lie far outside all the others (leverage over {GROSS_OUTLIER_LEVERAGE:g}x the "
        "mean row's: a glitch, a spike, a corrupted sample), enough to take the closed form over, so its start was "
        f"solved without them; {fit}"
    )


# Below this the readings hardly support a rank-n calibration (README, "Diagnostics"): the load space's weakest
# direction stands barely above the noise, from too little of the sphere visited or too noisy a sensor.
WARN_RANK_GAP = 3.0


def readings_rank_gap(singular_values: torch.Tensor, rank: int) -> float | None:
    """``sigma_n / sigma_(n+1)`` of the readings (about their mean where offsets are fitted); None where ``p = n``.

    Args:
        singular_values: the readings' singular values, descending (``p`` of them, or fewer with fewer rows).
        rank: ``n``, the load axes.
    """
    if len(singular_values) <= rank:
        return None
    return float(singular_values[rank - 1] / singular_values[rank])


# Below this coverage the motion is (nearly) collinear or coplanar: good sessions measure
# 0.55-0.9 even at SNR 2, degenerate ones with noise 0.01-0.18 (see tests).
MIN_COVERAGE = 0.25


def motion_coverage(motion_gram: torch.Tensor, count: float, magnitude: float) -> float:
    """How fully the recovered loads span the space: ``sigma_min(M) / (F sqrt(f / n))``.

    1 for loads spread evenly over the whole circle or sphere; 0 for collinear (2-D) or
    coplanar (3-D) loads, whose noise the metric upgrade would otherwise blow up into a
    plausible-looking but meaningless calibration.

    Args:
        motion_gram: ``M^T M`` (``n x n``) of the ``f x n`` recovered loads (about the origin).
        count: ``f``.
        magnitude: ``F``.
    """
    n = motion_gram.shape[0]
    smallest = float(torch.linalg.eigvalsh(motion_gram)[0])
    return math.sqrt(max(smallest, 0.0)) / (magnitude * math.sqrt(count / n))


# The rows of unknown load must span the load space to this coverage (:func:`direction_coverage` of their directions
# alone; 1 for the whole sphere) for the error bars to hold. Turned nearly in one plane (a turntable), they tell the
# magnitude constraint nothing to first order across it: the calibration there rests on the known loads and on each row's
# noise read as a load across the plane, which first-order bars do not describe (a hostile tester's turntables, one great
# circle and three known poses of 20 or 100 rows: 10 of 16 trusted, 8 of them at 2.5-8.5x their bars, the coverage over
# every row 0.30-0.58). The laws whose bars hold sit above it: a band within 30 degrees of the equator 0.5, the circle's
# two arcs within 30 degrees of an axis 0.42, a 60-degree cone 0.79 (bench/crb_ratio.py --laws).
MIN_UNKNOWN_ROW_COVERAGE = 0.3


# Nor may the rows of unknown load lie nearly in one plane off the origin: a circle of orientations (a turntable tilted,
# a wrist turned about one tilted axis, ``a^T u = h``), on which every metric ``C^T (I + lambda (a a^T - h^2 I)) C`` keeps
# the magnitude (method §5, "One circle, tilted or not"; :func:`direction_coverage` about the directions' mean under
# this; 1 for the whole sphere). Only the known loads choose among them, and the bars, from information at directions noise scattered
# off the circle, may not say how well (bench/goodness_checks.py, circles 30 and 45 degrees off the plane with three known
# poses of 20 rows: 14 and 2 of 20 sessions trusted, one at 2.5x its bars, others' errors up to 108x). The laws whose
# bars hold sit above it (true directions): a 60-degree cone 0.24-0.26, a hemisphere or the band 0.49-0.52.
MIN_UNKNOWN_ROW_CENTRED_COVERAGE = 0.1


def direction_coverage(loads: torch.Tensor, centred: bool = False) -> float:
    """:func:`motion_coverage` of the directions of ``loads`` (``f x n``, nonzero), whatever their magnitudes, about the
    origin or (``centred``) about their mean: ``sqrt(n lambda_min(cov(u)))``, 0 for directions on one circle."""
    directions = loads / loads.norm(dim=1, keepdim=True).clamp_min(torch.finfo(loads.dtype).tiny)
    if centred:
        directions = directions - directions.mean(dim=0)
    return motion_coverage(directions.T @ directions, len(directions), 1.0)


def require_coverage(motion_gram: torch.Tensor, count: float, magnitude: float) -> float:
    """:func:`motion_coverage`, raising :class:`SfmnetError` below :data:`MIN_COVERAGE`."""
    coverage = motion_coverage(motion_gram, count, magnitude)
    if coverage < MIN_COVERAGE:
        n = motion_gram.shape[0]
        raise SfmnetError(
            f"the recovered loads barely span {n} dimensions (coverage {coverage:.2f}, a full "
            f"{'circle' if n == 2 else 'sphere'} is 1): the loads are collinear or coplanar"
            f"{' (turned about one axis only: one circle of orientations, tilted or not)' if n == 3 else ''}; turn the "
            f"mass through orientations that span all {n} load axes"
        )
    return coverage
