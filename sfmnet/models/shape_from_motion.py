"""Shape from motion: the factorisation ``Z = M S (+ 1 o^T)`` with the metric constraint as a loss term."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any, NamedTuple

import torch

from sfmnet.data.recording import CalibrationRecording
from sfmnet.errors import SfmnetError
from sfmnet.linalg.anderson import AndersonAcceleration
from sfmnet.linalg.chi_square import robust_noise_variance
from sfmnet.linalg.directions import direction_grid
from sfmnet.linalg.factorisation import (
    closed_form_shape,
    gross_outlier_note,
    metric_unknowns,
    readings_rank_gap,
    require_coverage,
)
from sfmnet.linalg.frame import frame_rotation, known_load_rotation
from sfmnet.linalg.uncertainty import alternation_bias, residual_noise_variance
from sfmnet.linalg.group_means import group_means, harmonic_mean_rows
from sfmnet.linalg.least_squares import least_squares_shape
from sfmnet.linalg.orientation_law import LAW_DEGREES, fit_orientation_law, harmonic_basis, held_out_log_likelihood
from sfmnet.linalg.motion import constrained_motion, unit_motion
from sfmnet.linalg.osculating_valley import valley_scan
from sfmnet.models.linear_calibrator import (
    Batch,
    LinearCalibrator,
    dense_parameter,
    rms_norm,
)
from sfmnet.models.contracts import FitMode
from sfmnet.models.losses import metric_constraint_loss, reconstruction_loss

REFINEMENTS = ("auto", "alternation", "penalty", "marginal")
ROBUST_LOSSES = (None, "huber")
# Below this signal-to-noise ratio (F |s| / noise, from the closed form) "auto" takes the marginal
# likelihood. Measured over the orientation laws of bench/crb_ratio.py --laws: at SNR 20 and below
# the marginal with its learnt distribution of directions is at or near the bound where the
# alternation's incidental-parameter bias shows (and with offsets on non-uniform laws the
# alternation can run away); at SNR 100 the grid is too coarse for the sharp likelihoods on the
# sphere (2-3x the bound) while the alternation is at it.
MARGINAL_BELOW_SNR = 50.0
# Rows x grid directions beyond which "auto" does not take the marginal: each optimiser evaluation
# touches every (row, direction) pair, and a fit makes hundreds (measured on 2 cores, 3 axes at SNR 10, with
# learnt_law=nonparametric: 500 rows 12 s, 2,000 rows 30 s; the held-out choice of law costs more; a hostile
# tester's 4,400-row stream with its motion rows left in ran for over 6 minutes). 2,500 rows on the sphere,
# 10,000 on the circle.
MARGINAL_MAX_CELLS = 5e6
# Relative change of [S; o] in one alternation round at which the alternation has converged, as
# in the streamed fit: below ~1e-9 rounds only creep along the frame, which a few known loads hold weakly.
ALTERNATION_TOLERANCE = 1e-9
# The alternation's shape this many times the closed form's (largest singular value) has run away: the joint
# likelihood of the shape and every sample's direction has no maximum at low SNR (README, "Error against the
# Cramér-Rao bound": at SNR 2 it grew 1000x on a band of directions).
RUNAWAY_GROWTH = 10.0
# Below this SNR (as "auto" estimates it) the alternation's estimate is biased by more than its error bars:
# over the orientation laws of bench/crb_ratio.py --laws it was 0.9-4.9x the Cramer-Rao bound at SNR 5 (and ran
# away at SNR 2), within 1.6x at SNR 20.
ALTERNATION_BIASED_BELOW_SNR = 10.0
# Training steps of the alternation fitted beside a marginal fit (ShapeFromMotion.alternation_beside), as the trainer's
# default epochs: each is up to alternation_steps rounds, to convergence.
ALTERNATION_BESIDE_STEPS = 10
# A training step of the alternation that moves [S; o] by more than this fraction of its norm is not at a fixed point:
# converged, a step moves it by about ALTERNATION_TOLERANCE; walking an osculating valley, by 1e-3 to 1e-2.
ALTERNATION_WALKING_STEP = 1e-6
# The L-BFGS that takes an alternation still walking a valley to its floor (ShapeFromMotion.walk_to_the_valley_floor):
# conf/optimizer/lbfgs.yaml's settings but ten times the iterations, up to VALLEY_WALKS calls each followed by a
# training step of the alternation.
VALLEY_WALKS = 10
VALLEY_LBFGS = {
    "lr": 1.0, "max_iter": 500, "history_size": 50, "line_search_fn": "strong_wolfe",
    "tolerance_grad": 1e-10, "tolerance_change": 1e-14,
}
# Smoothed EM steps of the nonparametric distribution of directions per training step of the marginal refinement.
PRIOR_STEPS = 100
# Width of the smoothing of that distribution per squared angular spread of one sample (1/rad), below a direction SNR
# of UNSMOOTHED_LAW_FROM_SNR: measured on the orientation laws of bench/crb_ratio.py --laws (SNR 2-20).
PRIOR_SMOOTHING = 3.0
# From this direction SNR (the closed form's, one for the whole recording, of a pose's mean when tied) the nonparametric
# law is not smoothed: its EM steps go to the nonparametric maximum-likelihood law (Kiefer and Wolfowitz 1956), whose
# joint fit with the shape has no smoothing bias. bench/crb_ratio.py --laws, 20 sessions a row: on the circle's band at
# SNR 5 the nonparametric law alone came out 1.21x the bound smoothed and 0.93x unsmoothed, and the default law 1.30x
# and 0.94x. At SNR 2 the unsmoothed law cost more than its smoothing (the hemisphere 1.15x to 1.42x, the cone 0.96x to
# 1.44x). Set between the two SNRs measured.
UNSMOOTHED_LAW_FROM_SNR = 3.5
# The marginal's distributions of directions (model.learnt_law): a free weight per grid direction
# (EM, smoothed at low SNR), a log-density of harmonics of the degree the BIC picks, the uniform law, or "held_out" (the
# default): at each update whichever of ShapeFromMotion.held_out_laws fitted to half the directions best predicts
# the other half (README, "Error against the Cramér-Rao bound": each law is ahead on some orientation laws).
LEARNT_LAWS = ("nonparametric", "harmonic", "uniform", "held_out")
# The laws "held_out" chooses between; on a tie the earlier law is kept. Where one direction's spread (1 / direction
# SNR, radians) is under the grid's spacing the harmonic law joins them (held_out_laws): there the nonparametric law is
# a spike per direction on the grid, which holds each direction where the closed form put it, and the harmonic law
# moves the sphere's band and cone with offsets at SNR 20 from 1.22x and 1.13x the bound to 0.98x and 1.02x (10
# sessions; bench/crb_ratio.py --laws). Where the spread is wider the unsmoothed nonparametric law keeps the edges the
# harmonic law was for, and the held-out score took the harmonic law where it was the worse estimate (20 sessions:
# the sphere's band at SNR 5, 1.40x the bound with it and 1.19x without; the circle's band, 1.07x and 0.94x).
HELD_OUT_LAWS = ("uniform", "nonparametric")
# Smoothed EM steps from the uniform law of the nonparametric candidate fitted to one half of the directions.
HELD_OUT_EM_STEPS = 300
# That candidate's smoothing is at least this fraction of the spacing of its directions spread evenly
# (grid_spacing of the half's count). Without it, at SNR 20 on the circle (one sample's spread 3 degrees,
# barely smoothed) 48 directions learnt spikes that predicted the other half worse than the uniform law, so
# the uniform law was taken on bands, hemispheres and cones (bench/crb_ratio.py --laws: 1.5-1.7x the bound,
# 0.9x with this); a full spacing smoothed enough to beat the uniform law on a uniform sphere (1.16x, 1.04x here).
HELD_OUT_WIDTH_PER_SPACING = 0.5
# The widest spacing (radians) of the marginal's direction grid.
MARGINAL_GRID_SPACING = 0.11
# Where one direction's spread (1 / direction SNR, radians) is under this many spacings of the marginal's grid, the
# grid does not resolve a direction: a law learnt on it is a spike per direction (a pose's, tied; a row's, untied),
# which holds each direction where the closed form put it, and "auto" takes the alternation instead (choose_refinement).
# Measured on bench/crb_ratio.py --laws, 3 axes: on the 12 poses x 17 samples at direction SNR 20.6 (spread 2.8 degrees,
# spacing 4.5) the tied marginal was 1.28x the bound and the tied alternation 0.97x; untied, at SNR 20 (50 sessions)
# the sphere's band 1.12x and 1.17x (tared, with offsets) against 0.99x and 0.98x, its hemisphere with offsets 1.11x
# against 1.02x.
RESOLVED_SPREAD_PER_SPACING = 1.0


def grid_spacing(dims: int, count: int) -> float:
    """Radians between neighbours of ``count`` directions spread evenly on the circle (``dims`` 2) or sphere (3):
    ``(area / count)^(1 / (dims - 1))``."""
    area = 2 * math.pi if dims == 2 else 4 * math.pi
    return (area / count) ** (1 / (dims - 1))


def shape_growth(shape: torch.Tensor, closed_form_scale: float) -> float:
    """The largest singular value of ``S`` (``n x p``) over the closed form's: past :data:`RUNAWAY_GROWTH` the alternation ran away."""
    return float(torch.linalg.matrix_norm(shape, ord=2)) / closed_form_scale


def runaway_warning(growth: float, remedy: str) -> str:
    """The warning of an alternation whose shape grew ``growth`` times the closed form's, ending with ``remedy``."""
    return (
        f"the alternation ran away: the shape's largest singular value grew to {growth:.3g}x the closed form's, "
        "so this calibration is wrong; at low SNR the likelihood of the shape and every sample's direction has no "
        f"maximum: {remedy}"
    )


def low_snr_warning(snr: float, remedy: str, estimator: str = "alternation") -> str:
    """The warning of ``estimator`` fitted at ``snr`` below :data:`ALTERNATION_BIASED_BELOW_SNR`, ending with ``remedy``."""
    return (
        f"SNR {snr:.1f} (F |s| / noise) is below {ALTERNATION_BIASED_BELOW_SNR:g}, where the {estimator}'s estimate is biased "
        f"by more than its error bars (the bias grows as 1/SNR^2), so neither is to be trusted: {remedy}"
    )


class ScaledBatch(NamedTuple):
    """A batch in the parameters' units: readings (``b x p``), loads (``b x n``, NaN where unknown), the
    unknown-row mask, each row's mass configuration and, with tied directions, its pose (``b``, long; else None)."""

    readings: torch.Tensor
    loads: torch.Tensor
    unknown: torch.Tensor
    configuration: torch.Tensor
    pose: torch.Tensor | None = None


class ShapeFromMotion(LinearCalibrator):
    """Rank-n factorisation of raw readings into motion ``M`` and shape ``S``, the metric constraint a loss term.

    Loss (method §5), readings in units of their RMS norm and loads in units of ``F``::

        L = (1/f) [ sum_j |z_j - u_j D_c S - o|^2                        unknown-load rows
                    + metric_weight * sum_j ((|u_j|^2 - 1) / 2)^2     unknown-load rows
                    + sum_k |z_k - f_k S - o|^2 ]                      known-load rows

    An unknown row's load is ``m_j = u_j D_c``: its unit direction ``u_j`` through the direction
    map of its mass configuration (:class:`CalibrationRecording`; ``D = F I`` for a force
    sensor, so ``m_j = F u_j``; the gravity direction to the wrench for six axes, method §6).
    Each ``u_j`` is the minimiser of its own terms given ``S`` and ``o`` (:func:`constrained_motion`,
    variable projection), so the trainer's optimiser works on ``S`` and ``o`` alone: a small,
    well-conditioned problem. Known loads are used as their rows' motion, their
    maximum-likelihood use, which also holds the frame during training.
    ``metric_weight = 0`` is the unconstrained affine factorisation (truncated SVD, or PCA
    when centred); large weights approach the hard constraint of maximum likelihood.

    The first step of fitting is the closed form (paper eqs. 7-11, method §2-4) for one mass;
    with several mass configurations (six axes) it is least squares on the known loads,
    which the unknown orientations then refine.

    Refinement, in the trainer's steps:

    - ``"alternation"``: method §5's alternation, ``u_j <- argmin_{|u|=1} |z_j - o - u D S|``
      (:func:`unit_motion`) then ``[S; o] <- lstsq([M 1], Z)`` (:meth:`alternate`), the motion always exactly on
      the constraint. At low SNR it stays far closer to the Cramer-Rao bound than the exact
      penalised minimum, whose per-sample directions are incidental parameters that bias
      ``S`` (README, "Error against the Cramer-Rao bound").
    - ``"penalty"``: the trainer's optimiser on the loss above with each ``u_j`` its exact argmin.
    - ``"marginal"``: the optimiser on the negative log marginal likelihood, each unknown
      direction integrated over a grid (:meth:`marginal_loss`) weighted by the distribution of
      directions, which is learnt with the shape (:meth:`update_law`), the noise level too: no
      per-sample parameters, so no incidental-parameter bias, and no assumed orientation law.
    - ``"auto"`` (default): ``"marginal"`` below ``MARGINAL_BELOW_SNR`` as estimated from the
      closed form, else ``"alternation"``; where the marginal's grid cannot resolve one direction, the alternation
      but where the marginal is needed (:meth:`choose_refinement`).

    Args:
        rank: ``n``, the number of load axes (2, 3, 6, ...); None takes it from the data.
        metric_weight: weight of the metric-constraint loss (0: unconstrained).
        estimate_offset: learn channel offsets (ellipsoid closed form, method §4); else tared readings.
        refinement: ``"auto"``, ``"alternation"``, ``"penalty"`` or ``"marginal"`` (see above).
        marginal_grid: directions in the marginal's grid (default 512 on a circle, 2000 on a sphere).
        learnt_law: the marginal's distribution of directions, ``"held_out"`` (the default): at each update the
            uniform or the nonparametric law (and the harmonic law where a direction's spread is under the grid's
            spacing, :meth:`held_out_laws`), whichever fitted to half the free directions best predicts the other
            half (:meth:`update_law`); or one law always: ``"nonparametric"`` (a weight per grid direction, smoothed
            below direction SNR :data:`UNSMOOTHED_LAW_FROM_SNR`), ``"harmonic"`` (a log-density of degree 0-4, by
            the BIC), ``"uniform"`` (not learnt).
        alternation_steps: alternation rounds per training step (full batches only).
        robust: ``"huber"`` weights each row of the alternation's least-squares step by Huber's
            rule on its residual, so a few bad rows (motion, a bump, a slipped mass) cannot pull
            the shape; None: plain least squares. Needs the alternation (``auto`` then takes it).
        huber_threshold: rows whose residual norm exceeds this many times the median row's are
            down-weighted in proportion (weight ``threshold * median / |r_j|``).
        tie_directions: where the recording has groups of rows in one orientation (static intervals, or
            ``data.group_column``'s poses; :meth:`CalibrationRecording.same_load_groups`), each group's rows
            share one direction: the alternation's and the marginal's per-direction terms are those of the
            group's mean reading, weighted by its row count (method §5, "tied directions"). Far fewer
            incidental directions, so far less bias at low SNR. Not with ``robust`` (a bad row would pull
            its pose's direction).
    """

    name = "shape_from_motion"
    recording = "rotation"

    def __init__(
        self,
        rank: int | None = None,
        metric_weight: float = 1000.0,
        estimate_offset: bool = True,
        refinement: str = "auto",
        alternation_steps: int = 50,
        marginal_grid: int | None = None,
        learnt_law: str = "held_out",
        robust: str | None = None,
        huber_threshold: float = 3.0,
        tie_directions: bool = True,
    ) -> None:
        super().__init__(estimate_offset=estimate_offset)
        if refinement not in REFINEMENTS:
            raise SfmnetError(f"model.refinement is '{refinement}': use one of {', '.join(REFINEMENTS)}")
        if learnt_law not in LEARNT_LAWS:
            raise SfmnetError(f"model.learnt_law is '{learnt_law}': use one of {', '.join(LEARNT_LAWS)}")
        if robust not in ROBUST_LOSSES:
            raise SfmnetError(f"model.robust is '{robust}': use null (least squares) or huber")
        if robust and refinement not in ("auto", "alternation"):
            raise SfmnetError(
                f"model.robust=huber reweights the alternation's rows, not model.refinement={refinement}: "
                "set model.refinement=alternation (or auto)"
            )
        if refinement == "marginal" and not metric_weight > 0:
            raise SfmnetError("model.refinement=marginal integrates over directions on the sphere: it needs metric_weight > 0")
        if not huber_threshold > 0:
            raise SfmnetError(f"model.huber_threshold must be positive, got {huber_threshold}")
        self.robust = robust
        self.huber_threshold = huber_threshold
        self.rank = rank
        self.metric_weight = metric_weight
        self.refinement = refinement
        self.alternation_steps = alternation_steps
        self.marginal_grid = marginal_grid
        self.learnt_law = learnt_law
        self.tie_directions = tie_directions
        self.register_buffer("grid", None)
        self.register_buffer("log_prior", None)
        self.law_bases: dict[int, torch.Tensor] | None = None
        self.law_choice: list[str] = []
        self.law_learnt: list[str] = []
        self.register_parameter("log_noise", None)
        self.register_buffer("direction_maps", None)
        self.register_buffer("row_configuration", None)
        self.register_buffer("row_pose", None)
        self.rows_per_direction = 1.0
        # How far the alternation's last step moved [S; o], a fraction of its norm, where it ended short of convergence.
        self.alternation_still_moving = 0.0

    @property
    def fit_failed(self) -> bool:
        return bool(self.fit_problems())

    @property
    def fit_warnings(self) -> list[str]:
        return [*super().fit_warnings, *self.fit_problems()]

    def fit_problems(self, unconverged: bool = True) -> list[str]:
        """Why the alternation's answer and error bars are not to be trusted: it ran away, the SNR is too low for it, or
        (``unconverged``) its last step ended short of convergence having moved ``[S; o]`` by over
        :data:`ALTERNATION_WALKING_STEP` of its norm."""
        if self.refinement != "alternation":
            return []
        growth = shape_growth(self.shape.detach(), self.closed_form_scale)
        if growth > RUNAWAY_GROWTH:
            return [runaway_warning(growth, "use model.refinement=marginal (or auto)")]
        if self.constrained and self.direction_snr < ALTERNATION_BIASED_BELOW_SNR:
            return [low_snr_warning(self.direction_snr, "set model.refinement=marginal")]
        if unconverged and self.alternation_still_moving > ALTERNATION_WALKING_STEP:
            return [
                f"the alternation had not converged: its last training step still moved the calibration by "
                f"{self.alternation_still_moving:.1e} of its norm, so this calibration and its error bars describe a point "
                "on the way (on part of the sphere with offsets it can walk a valley of calibrations as likely as each "
                "other): train longer (trainer.max_epochs), turn the mass through more of the sphere, or give known loads"
            ]
        return []

    @property
    def learnt_orientation_law(self) -> bool:
        """The marginal learnt a law other than the uniform one for some mass configuration (:attr:`law_learnt`)."""
        return self.refinement == "marginal" and any(law != "uniform" for law in self.law_learnt)

    def alternation_bias(self) -> float | None:
        """:func:`~sfmnet.linalg.uncertainty.alternation_bias` at :attr:`direction_snr`, where the alternation fitted one
        constant-magnitude mass; None elsewhere (the marginal integrates the directions out)."""
        if self.refinement != "alternation" or not self.constrained or len(self.direction_maps) > 1:
            return None
        return alternation_bias(self.physical_shape(), self.direction_snr)

    def alternation_beside(self, recording: CalibrationRecording) -> ShapeFromMotion | None:
        """The alternation fitted to the same rows with the same options, beside a marginal fit at a direction SNR where
        the alternation's own bias is within its bars (from :data:`ALTERNATION_BIASED_BELOW_SNR`); None elsewhere, or
        where it ran away. It costs a few closed-form rounds, little beside the marginal's."""
        if self.refinement != "marginal" or self.direction_snr < ALTERNATION_BIASED_BELOW_SNR:
            return None
        beside = self.alternation_fit(recording)
        # One still walking a valley is still the alternation's answer, the one a user would get: compared all the same.
        return None if beside.fit_problems(unconverged=False) else beside

    def alternation_fit(self, recording: CalibrationRecording) -> ShapeFromMotion:
        """The alternation with this model's options fitted to ``recording``: :data:`ALTERNATION_BESIDE_STEPS` steps."""
        beside = ShapeFromMotion(
            rank=self.rank, metric_weight=self.metric_weight, estimate_offset=self.estimate_offset,
            refinement="alternation", alternation_steps=self.alternation_steps, tie_directions=self.tie_directions,
        )
        beside.initialise(recording)
        batch = recording.whole_batch()
        for _ in range(ALTERNATION_BESIDE_STEPS):
            beside.alternate(batch)
        return beside

    def estimator_description(self) -> dict[str, Any]:
        """The refinement that ran (``auto``'s choice), the SNR it was chosen by, whether the directions were tied
        to poses and, for the marginal, the law of directions learnt per mass configuration (:attr:`law_learnt`)."""
        description: dict[str, Any] = {"refinement": self.refinement}
        if self.constrained:
            description.update(direction_snr=self.direction_snr, tied_directions=self.tied)
        if self.refinement == "marginal":
            description.update(learnt_law=self.learnt_law, laws_learnt=list(self.law_learnt))
        return description

    @property
    def constrained(self) -> bool:
        return self.metric_weight > 0

    @property
    def joint_likelihood(self) -> bool:
        return self.refinement != "marginal"

    def fit_mode(self) -> FitMode:
        """The alternation (and ``auto`` until the data choose) refines by :meth:`alternate`; the rest by the optimiser."""
        return FitMode.ALTERNATION if self.refinement in ("alternation", "auto") else FitMode.STEPS

    def initialise(self, recording: CalibrationRecording) -> None:
        self.rank = self.rank or recording.rank
        if recording.rank != self.rank:
            raise SfmnetError(
                f"model.rank is {self.rank} but the data has {recording.rank} load axes: set model.rank={recording.rank}"
            )
        if self.constrained and recording.direction_maps is None and not math.isfinite(recording.magnitude):
            raise SfmnetError("the metric constraint needs the load magnitude: set data.magnitude (load units)")
        if recording.direction_maps is not None and self.constrained:
            self.start_from_known_loads(recording)
        else:
            self.start_from_closed_form(recording)
        if self.constrained:
            directions = self.directions(recording.readings / self.reading_scale, recording.row_configuration, 0.0)
            self.coverage = require_coverage(directions.T @ directions, len(directions), 1.0)
        self.orient(recording)
        self.closed_form_scale = float(torch.linalg.matrix_norm(self.shape.detach(), ord=2))
        if self.constrained:
            self.tie_poses(recording)
            noise, rms = self.closed_form_noise(recording)
            self.snr = self.signal_to_noise_at(self.load_scale.max(), noise)
        if self.refinement == "auto":
            self.refinement = self.choose_refinement(recording, rms) if self.constrained else "alternation"
        if self.refinement == "marginal":
            # The marginal learns its noise; it starts where the README's tables were measured from, the residuals' RMS.
            self.start_marginal(rms)

    def choose_refinement(self, recording: CalibrationRecording, rms: float) -> str:
        """``auto``'s refinement, from the closed form (method §5, "Which refinement auto takes").

        The marginal below :data:`MARGINAL_BELOW_SNR` (direction SNR), the alternation above. Where one direction's
        spread is under the marginal grid's spacing (:meth:`grid_resolves_direction`), a law learnt on the grid holds
        each direction where the closed form put it and the marginal hardly moves from there, so the alternation is
        taken unless it cannot be used: the readings have no channel off the load space
        (:meth:`readings_in_load_space`, tied or not), or, untied, it walks an osculating valley
        (:meth:`alternation_walks_valley`). Untied, the marginal is kept too where it has no law to learn, the closed
        form's directions' law being uniform (:meth:`law_at_start`), and with several mass configurations (six axes,
        not measured there).
        """
        marginal = self.direction_snr < MARGINAL_BELOW_SNR and not self.robust
        rows = round(len(recording.readings) / self.rows_per_direction)
        if marginal and rows * self.grid_size(self.direction_maps.shape[1]) > MARGINAL_MAX_CELLS:
            self.notes.append(
                f"SNR {self.direction_snr:.0f} is low enough for the marginal refinement, but on {rows:,} "
                f"{'poses' if self.tied else 'rows'} it would take "
                "long: the alternation was used, whose bias grows as 1/SNR^2; set model.refinement=marginal to "
                "insist, or fit pose means"
            )
            return "alternation"
        if not marginal or self.grid_resolves_direction():
            return "marginal" if marginal else "alternation"
        if self.readings_in_load_space(recording):
            return "marginal"
        if self.tied:
            return "alternation"
        if len(self.direction_maps) > 1 or self.law_at_start(recording, rms) == "uniform" or self.alternation_walks_valley(recording):
            return "marginal"
        return "alternation"

    def tie_poses(self, recording: CalibrationRecording) -> None:
        """Each row's pose (:attr:`row_pose`) where the directions are tied, and the unknown rows per direction
        (:attr:`rows_per_direction`, the harmonic mean over the poses)."""
        poses = recording.same_load_groups if self.tie_directions and not self.robust else None
        unknown = ~recording.known
        self.row_pose, self.rows_per_direction = poses, 1.0
        if poses is not None and bool(unknown.any()):
            self.require_poses(recording, len(poses[unknown].unique()))
            self.rows_per_direction = harmonic_mean_rows(torch.unique(poses[unknown], return_counts=True)[1])

    def require_poses(self, recording: CalibrationRecording, poses: int) -> None:
        """Tied, the unknown rows give one equation ``|m| = F`` per pose and a distinct known load ``n``: fewer than
        the shape's unknowns leave it undetermined (a group column that is not the pose, e.g. a session id)."""
        n = self.rank
        needed = metric_unknowns(n, self.estimate_offset)
        equations = poses + n * recording.distinct_known_loads
        if self.constrained and recording.direction_maps is None and equations < needed:
            raise SfmnetError(
                f"the recording's groups (static intervals, or data.group_column) hold {poses} poses, whose rows share one "
                f"direction each: too few for the {needed} unknowns of the shape{' and offsets' if self.estimate_offset else ''}; "
                "give data.group_column the pose each row was held in, or set model.tie_directions=false if the groups "
                "are not poses"
            )

    @property
    def tied(self) -> bool:
        return self.row_pose is not None

    def grid_resolves_direction(self) -> bool:
        """Whether one direction's spread (``1 / direction SNR`` radians) reaches :data:`RESOLVED_SPREAD_PER_SPACING`
        of the marginal grid's spacing (:func:`grid_spacing`): on the default grids, below direction SNR 81 on the
        circle (never past :data:`MARGINAL_BELOW_SNR`) and 12.6 on the sphere."""
        d = self.direction_maps.shape[1]
        return 1 / self.direction_snr >= RESOLVED_SPREAD_PER_SPACING * grid_spacing(d, self.grid_size(d))

    def readings_in_load_space(self, recording: CalibrationRecording) -> bool:
        """As many channels as axes (``p = n``: an accelerometer, a magnetometer): no reading lies off the load space, so
        each row's fitted direction takes up all of its noise but the radial part, and the alternation's bias is far
        beyond its bars (bench/crb_ratio.py --laws --p-equals-n, 3 axes at SNR 20: 5-47x the bound on the sphere, the
        hemisphere and the band, where the marginal is at it). Tied, 12 poses leave the alternation 3 equations over
        the shape's and offsets' 9 unknowns, and where poses nearly coincide it runs off along what they leave
        undetermined: at SNR 10 and 5 (a pose's direction SNR 41 and 21, 30 sessions each) it was 3.2x and 3.1x the
        bound, 42x and 30x in its worst sessions, where the marginal was 0.37x and 0.23x, 1.4x and 1.0x at worst."""
        return recording.readings.shape[1] <= self.rank

    @torch.no_grad()
    def law_at_start(self, recording: CalibrationRecording, rms: float) -> str:
        """The law of directions ``learnt_law`` takes at the closed form (:meth:`update_law` once, the marginal set up
        from ``rms``): ``"uniform"`` where the held-out choice finds nothing the uniform law does not predict."""
        self.start_marginal(rms)
        self.update_law(recording.whole_batch())
        law = self.law_choice[0]
        # The refinement chosen starts afresh: the marginal from the uniform law, as it always does.
        self.grid = self.log_prior = None
        self.register_parameter("log_noise", None)
        self.law_bases, self.law_choice, self.law_learnt = None, [], []
        return law

    @torch.no_grad()
    def alternation_walks_valley(self, recording: CalibrationRecording) -> bool:
        """Whether the alternation, fitted as :meth:`alternation_fit` fits it, walks an osculating valley: its fit lies
        on one (:func:`valley_scan`: a calibration along it as likely as the fit, with offsets estimated) and one more
        training step still moves ``[S; o]`` by more than :data:`ALTERNATION_WALKING_STEP` of its norm.

        On a cap of directions with offsets the alternation's per-row bias can walk the valley: on the sphere's
        60-degree cone with offsets at SNR 20 (bench/crb_ratio.py --laws) its shape kept growing over the trainer's
        steps, 3.7-3.9x the bound in 2 of 10 sessions, while every session had a valley and no session of the band,
        the hemisphere or the whole sphere had one. Where it stops on the valley, it is mostly nearer the truth than
        the marginal, whose grid is coarser than a direction's spread there: on that cone, 50 sessions, it walked in 6,
        and taking it in the other 44 made the row 0.76x the bound against the marginal's 1.09x (docs/crb_bench.md,
        "Where the alternation walks the valley").
        """
        if not self.estimate_offset:
            return False
        beside = self.alternation_fit(recording)
        known = recording.known
        noise, _ = beside.closed_form_noise(recording)
        scan = valley_scan(
            recording.readings[~known], beside.physical_shape(), beside.physical_offset(), recording.magnitude, noise,
            recording.readings[known], recording.loads[known],
        )
        if scan.likely_change <= 0:
            return False
        beside.alternate(recording.whole_batch())
        return beside.alternation_still_moving > ALTERNATION_WALKING_STEP

    @property
    def direction_snr(self) -> float:
        """The closed form's SNR (``F |s| / noise`` of one row) for one direction's data: a tied pose's mean reading
        has ``sqrt(rows per pose)`` times a row's (:attr:`rows_per_direction`). The refinement's bias and the marginal's grid go by it."""
        return self.snr * math.sqrt(self.rows_per_direction)

    def closed_form_noise(self, recording: CalibrationRecording) -> tuple[float, float]:
        """The noise of one channel, raw units, from the closed form's residuals (:func:`residual_noise_variance`: one free
        direction per unknown row, or per pose when tied): the noise its SNR (``F |s| / noise``) is judged by; and
        the residuals' plain RMS."""
        residuals = self.fitted_residuals(recording, self.fitted_loads(recording))
        f, p = residuals.shape
        poses = self.unknown_poses(recording)
        free = int((~recording.known).sum()) if poses is None else len(poses.unique())
        squares = float(residuals.pow(2).sum())
        rms = math.sqrt(squares / residuals.numel())
        d = self.direction_maps.shape[1]
        if self.robust:
            # A robust fit is judged without its outliers: a glitch would otherwise set its SNR (untied, as robust is).
            dof = torch.where(recording.known, p, p - d + 1)
            return math.sqrt(robust_noise_variance(residuals.pow(2).sum(dim=1), dof)), rms
        variance = residual_noise_variance(squares, f * p, free, d, (self.rank + self.estimate_offset) * p)
        return math.sqrt(variance), rms

    def start_marginal(self, noise: float) -> None:
        """The direction grid of the marginal likelihood, and its noise level started at ``noise`` (raw units)."""
        d = self.direction_maps.shape[1]
        self.grid = direction_grid(d, self.grid_size(d))
        # One distribution of directions per mass configuration, uniform to start with.
        configurations = len(self.direction_maps)
        self.log_prior = self.uniform_law().to(self.shape.dtype).repeat(configurations, 1)
        if "harmonic" in (self.learnt_law, *self.held_out_laws()):
            self.law_bases = {degree: harmonic_basis(self.grid, degree) for degree in LAW_DEGREES}
        # held_out starts, and stays where a configuration has too few directions to split, nonparametric.
        self.law_choice = ["nonparametric" if self.learnt_law == "held_out" else self.learnt_law] * configurations
        self.law_learnt = ["uniform"] * configurations
        self.log_noise = dense_parameter((torch.as_tensor(noise, dtype=self.shape.dtype) / self.reading_scale).log())

    def held_out_laws(self) -> tuple[str, ...]:
        """The laws ``learnt_law="held_out"`` chooses between: :data:`HELD_OUT_LAWS`, and the harmonic law where one
        direction's spread (``1 / direction SNR`` radians) is under the grid's spacing; none for another ``learnt_law``."""
        if self.learnt_law != "held_out":
            return ()
        d = self.direction_maps.shape[1]
        return HELD_OUT_LAWS + (() if self.grid_resolves_direction() else ("harmonic",))

    def grid_size(self, dims: int) -> int:
        """Directions in the marginal's grid: ``marginal_grid``, else 512 on a circle and 2000 on a sphere.

        A grid coarser than :data:`MARGINAL_GRID_SPACING` is refused: it puts every sample on one of a few
        directions (on the simulated 3-axis sensor, 200 directions 14 degrees apart gave 2.3 % matrix
        error against 1.7 % with 2000, and 64 gave 17 %).
        """
        if self.marginal_grid is None:
            return 512 if dims == 2 else 2000
        if dims <= 3 and grid_spacing(dims, self.marginal_grid) > MARGINAL_GRID_SPACING:
            least = math.ceil(grid_spacing(dims, 1) ** (dims - 1) / MARGINAL_GRID_SPACING ** (dims - 1))
            shape = "circle" if dims == 2 else "sphere"
            raise SfmnetError(
                f"model.marginal_grid={self.marginal_grid} spaces the {shape}'s directions "
                f"{math.degrees(grid_spacing(dims, self.marginal_grid)):.1f} degrees apart: give at least {least} "
                f"(the marginal needs them within {math.degrees(MARGINAL_GRID_SPACING):.1f} degrees) or null"
            )
        return self.marginal_grid

    def grid_log_likelihood(self, rows: torch.Tensor, configuration: int) -> torch.Tensor:
        """``-|z_j - o - u_k D_c S|^2 / 2 s^2`` for ``b`` offset-free rows (``b x p``, dimensionless) and grid point ``k``: ``b x K``."""
        predictions = self.grid @ (self.direction_maps[configuration] @ self.shape)
        distance2 = rows.pow(2).sum(dim=1, keepdim=True) - 2 * rows @ predictions.T + predictions.pow(2).sum(dim=1)
        return -distance2 / (2 * torch.exp(2 * self.log_noise))

    def prepare_step(self, batch: Batch) -> None:
        """Before each of the trainer's steps on ``batch``: the marginal refinement updates the directions' distribution."""
        if self.refinement == "marginal":
            self.update_law(batch)

    @torch.no_grad()
    def end_fit(self, recording: CalibrationRecording) -> None:
        """After the marginal refinement's last step: its frame turned to fit the known loads
        (:func:`known_load_rotation`, as the alternation does each round), then its law learnt again in that frame.

        The marginal likelihood of the unknown rows does not change when ``S`` and the law of directions turn
        together, so the known loads alone should set the frame. The grid's sum is not quite invariant: where a
        direction's spread is under the grid's spacing it prefers some frames by more than a few known loads can
        outweigh. Three known loads read once and 2,400 uniform rows at SNR 20 (3 axes, 6 channels) left the frame
        0.8-4.6 degrees from the known loads' fit and the error bars, which assume it there, 1.7x too small (method §3).
        Without known loads, the channels' frame again where the fit started in it (``LinearCalibrator.end_fit``), the
        law learnt again in it too.
        """
        if self.walks_to_the_valley_floor():
            self.walk_to_the_valley_floor(recording.whole_batch())
        if self.frame_of_channels:
            super().end_fit(recording)
            if self.refinement == "marginal":
                self.update_law(recording.whole_batch())
            return
        if self.refinement != "marginal" or len(self.direction_maps) != 1 or not bool(recording.known.any()):
            return  # nothing turns, so the law learnt at the last step stands
        known = recording.known
        centred = recording.readings[known] / self.reading_scale - self.offset.detach()
        self.shape.copy_(self.turned_to_known_loads(centred, recording.loads[known] / self.load_scale, self.shape.detach()))
        self.update_law(recording.whole_batch())

    def walks_to_the_valley_floor(self) -> bool:
        """Whether the alternation, still moving after its last step, is taken on to its loss's minimum
        (:meth:`walk_to_the_valley_floor`): where a direction is sharp enough for ``auto`` to take the alternation, from
        :data:`MARGINAL_BELOW_SNR`, and not with Huber's weights, which that loss does not carry.

        Below it the alternation's own minimum is not the truth's neighbourhood: each row's fitted direction soaks up
        noise, and on a cap with offsets the minimum runs away along the valley. On the 60-degree cone with offsets at
        SNR 20 (tests/test_orientation_laws.py) the walk took a shape still moving at 3.7x the bound to a minimum 2.2x
        the closed form's size, which no check then flagged; there ``auto`` takes the marginal.
        """
        return (
            self.refinement == "alternation" and self.alternation_still_moving > ALTERNATION_WALKING_STEP
            and self.direction_snr >= MARGINAL_BELOW_SNR and not self.robust
        )

    def walk_to_the_valley_floor(self, batch: Batch) -> None:
        """Where the alternation ended still moving: L-BFGS on its loss with each row's direction its exact minimiser
        (variable projection, as ``refinement=penalty`` runs it), then one more training step of the alternation to
        say whether that is its fixed point (:attr:`alternation_still_moving`).

        On a cap of directions with offsets the loss is a long curved valley, which the alternation walks by short
        steps (block coordinate descent), where quasi-Newton steps follow it. A hostile tester's robot-wrist logs, 12
        poses within 45 degrees of hanging down, SNR 1500, three known loads: one of eight ended the trainer's 10 epochs
        74 % from the truth, still moving; 100 epochs, the penalised fit and this walk all end at 6.6 %.
        """
        parameters = [self.shape, self.offset] if self.estimate_offset else [self.shape]

        def closure() -> torch.Tensor:
            for parameter in parameters:
                parameter.grad = None
            loss = self.loss(batch)["loss"]
            loss.backward()
            return loss

        for _ in range(VALLEY_WALKS):
            # A fresh history each walk: the alternation's step in between moved the parameters.
            with torch.enable_grad():
                torch.optim.LBFGS(parameters, **VALLEY_LBFGS).step(closure)
            self.alternate(batch)
            if self.alternation_still_moving <= ALTERNATION_WALKING_STEP:
                break
        for parameter in parameters:
            parameter.grad = None

    @torch.no_grad()
    def update_law(self, batch: Batch) -> None:
        """The distribution of directions of each configuration the rows support, ``S``, ``o``, ``s`` held.

        From the free directions' grid likelihoods ``L_jk = N(z_j; o + u_k D_c S, s^2 I)`` (:meth:`fit_law`).
        ``learnt_law="held_out"`` first picks the law: the uniform law, the nonparametric one (smoothed at least
        :data:`HELD_OUT_WIDTH_PER_SPACING` of its directions' spacing) and, where a direction's spread is under the
        grid's spacing, the harmonic one (:meth:`held_out_laws`) are each fitted to half the directions and
        scored on the other half (:func:`held_out_log_likelihood`), so the nonparametric law's free weights are
        learnt only where they predict directions they were not fitted to (:attr:`law_choice`).
        """
        index, readings, loads = batch
        centred = readings / self.reading_scale - self.offset
        unknown = torch.isnan(loads).any(dim=1)
        for c, log_likelihood, _ in self.direction_log_likelihoods(centred, unknown, index):
            if self.learnt_law == "held_out" and len(log_likelihood) >= 2:
                uniform = self.uniform_law()
                scores = {
                    law: held_out_log_likelihood(
                        log_likelihood,
                        lambda half, law=law: self.fit_law(
                            law, half, c, uniform, HELD_OUT_EM_STEPS, self.held_out_width(len(half))
                        )[0],
                    )
                    for law in self.held_out_laws()
                }
                self.law_choice[c] = max(scores, key=scores.get)
            self.log_prior[c], self.law_learnt[c] = self.fit_law(
                self.law_choice[c], log_likelihood, c, self.log_prior[c], least_width=self.tied_law_width(len(log_likelihood))
            )

    def held_out_width(self, directions: int) -> float:
        """The least smoothing width (radians) of a nonparametric law learnt from ``directions`` free directions, as
        the held-out choice scores it: :data:`HELD_OUT_WIDTH_PER_SPACING` of their spacing (:func:`grid_spacing`)."""
        return HELD_OUT_WIDTH_PER_SPACING * grid_spacing(self.grid.shape[1], directions)

    def tied_law_width(self, poses: int) -> float:
        """The nonparametric law's least smoothing width (radians) when learnt from ``poses`` tied directions:
        :meth:`held_out_width`, the width the held-out choice scores it at; untied, 0.

        A pose's direction rests on its mean reading, so a few poses give a few sharp directions, and the unsmoothed law
        is a spike at each: the marginal with it is then the profile likelihood over the poses' directions, with the
        alternation's bias (on the sphere's 12 poses at SNR 2 it let an axis of ``S`` the poses hardly span grow 2.3-2.7x
        in 2 of 10 sessions). Untied rows are many and their directions overlap, and there the width costs more than it
        gives (the sphere's band at SNR 5, 20 sessions: 1.19x the bound unsmoothed, 1.58x at this width): method §5.
        """
        return self.held_out_width(poses) if self.tied else 0.0

    def uniform_law(self) -> torch.Tensor:
        """Log-weights of the uniform law on the marginal's grid, ``K``."""
        return self.grid.new_full((len(self.grid),), -math.log(len(self.grid)))

    def fit_law(
        self,
        law: str,
        log_likelihood: torch.Tensor,
        configuration: int,
        start: torch.Tensor,
        em_steps: int = PRIOR_STEPS,
        least_width: float = 0.0,
    ) -> tuple[torch.Tensor, str]:
        """Log-weights (``K``) of ``law`` fitted to directions' grid log-likelihoods (``g x K``), started from
        ``start``, and what was fitted in words (:attr:`law_learnt`).

        ``"nonparametric"``: a weight per grid direction (:meth:`smoothed_em_law`); ``"harmonic"``: a
        log-density of degree 0 to 4, the degree by the BIC (:func:`fit_orientation_law`), so a band is not
        smoothed towards uniform; ``"uniform"``: every grid direction alike, whatever the rows.
        ``least_width``: the nonparametric law's least smoothing width, radians (:meth:`prior_kernel`).
        """
        if law == "uniform":
            return self.uniform_law(), law
        if law == "harmonic":
            log_weights, degree = fit_orientation_law(log_likelihood, self.law_bases, start)
            return log_weights, f"harmonic of degree {degree}"
        return self.smoothed_em_law(log_likelihood, configuration, start, em_steps, least_width), law

    def direction_log_likelihoods(
        self, centred: torch.Tensor, unknown: torch.Tensor, index: torch.Tensor
    ) -> Iterator[tuple[int, torch.Tensor, torch.Tensor]]:
        """Per mass configuration ``c`` of the unknown rows: ``c``, the grid log-likelihoods of each free direction
        (``g x K``) and the rows' squared distances from their direction's reading (a scalar).

        Untied, one direction per row (:meth:`grid_log_likelihood`, distances 0). Tied, one per pose:
        ``sum_j |z_j - mu|^2 = sum_j |z_j - z_bar|^2 + c_g |z_bar - mu|^2``, so a pose's term is its mean's
        log-likelihood times its row count ``c_g``, and the within-pose scatter is left over.

        Args:
            centred: ``b x p`` readings minus offsets (dimensionless); unknown: ``b`` mask; index: ``b`` rows.
        """
        configuration = self.row_configuration[index]
        for c in configuration[unknown].unique().tolist():
            rows = unknown & (configuration == c)
            log_likelihood, _, scatter = self.free_direction_log_likelihoods(
                centred[rows], self.row_pose[index][rows] if self.tied else None, c
            )
            yield c, log_likelihood, scatter

    def free_direction_log_likelihoods(
        self, centred: torch.Tensor, pose: torch.Tensor | None, configuration: int
    ) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor]:
        """One configuration's rows (``b x p``, offsets removed, dimensionless) as free directions: their grid
        log-likelihoods (``g x K``), each row's direction (``b``, into the ``g``; None: one per row) and the rows'
        squared distances from their direction's reading (a scalar), as in :meth:`direction_log_likelihoods`.

        Args:
            pose: ``b`` (long) labels of the rows' poses when tied, else None.
        """
        if pose is None:
            return self.grid_log_likelihood(centred, configuration), None, centred.new_zeros(())
        means, index, counts = group_means(centred, pose)
        scatter = (centred - means[index]).pow(2).sum()
        return counts[:, None].to(means.dtype) * self.grid_log_likelihood(means, configuration), index, scatter

    def smoothed_em_law(
        self,
        log_likelihood: torch.Tensor,
        configuration: int,
        start: torch.Tensor,
        steps: int = PRIOR_STEPS,
        least_width: float = 0.0,
    ) -> torch.Tensor:
        """``steps`` smoothed EM steps (Silverman et al. 1990) from the law ``start`` (log-weights): log-weights, ``K``.

        ``w <- K^T (w * L^T (1 / (L w))) / f_c`` with ``L`` the ``f_c x K`` grid likelihoods (each row
        scaled by its largest entry) and ``K`` of :meth:`prior_kernel`: EM's step towards the
        nonparametric maximum-likelihood mixing distribution, smoothed to the resolution the data support
        (from a direction SNR of :data:`UNSMOOTHED_LAW_FROM_SNR`, and without ``least_width``, plain EM: ``K = I``).
        """
        likelihood = torch.exp(log_likelihood - log_likelihood.max(dim=1, keepdim=True).values)
        kernel = self.prior_kernel(configuration, least_width)
        prior = start.exp()
        for _ in range(steps):
            prior = prior * (likelihood.T @ (1 / (likelihood @ prior))) / len(likelihood)
            if kernel is not None:
                prior = kernel.T @ prior
        # Grid points the data rule out keep a floor, so the log stays finite.
        return prior.clamp_min(torch.finfo(prior.dtype).tiny).log()

    def prior_kernel(self, configuration: int, least_width: float = 0.0) -> torch.Tensor | None:
        """The smoothing kernel of :meth:`smoothed_em_law` between grid points, ``K x K`` (rows sum to one), or None
        for none.

        A von Mises-Fisher kernel ``exp(kappa u_k . u_l)``, ``kappa = 1 / h^2``, of angular width
        ``h = max(PRIOR_SMOOTHING * a^2, least_width)`` (radians), ``a = s / rms(singular values of D_c S)`` the spread of
        one sample's direction (of a pose's mean, ``s`` over the square root of the rows per pose, when tied). Smoothing
        tames the unsmoothed estimate's spikes where ``a`` is wide (SNR ~ 2); from a direction SNR of
        :data:`UNSMOOTHED_LAW_FROM_SNR` its bias costs more than the spikes, and ``h = least_width`` (None when 0).
        """
        width = least_width
        if self.direction_snr < UNSMOOTHED_LAW_FROM_SNR:
            singular = torch.linalg.svdvals(self.direction_maps[configuration] @ self.shape.detach())
            # A tied direction rests on its pose's mean reading, whose noise is smaller.
            noise = torch.exp(self.log_noise.detach()) / math.sqrt(self.rows_per_direction)
            spread = float(noise / singular.pow(2).mean().sqrt())
            width = max(PRIOR_SMOOTHING * spread**2, least_width)
        if width == 0.0:
            return None
        return torch.softmax(self.grid @ self.grid.T / width**2, dim=1)

    def marginal_loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Negative log marginal likelihood per row, each unknown direction integrated over the grid.

        ``-log p(z_j) = -logsumexp_k(log w_ck - |z_j - o - u_k D_c S|^2 / 2 s^2) + p log s`` (unknown rows,
        ``w_c`` the learnt distribution of directions of configuration ``c``, :meth:`update_law`),
        ``|z_k - f_k S - o|^2 / 2 s^2 + p log s`` (known rows), constants dropped. Unlike the joint
        maximum likelihood it has no per-sample direction parameters, so no incidental-parameter bias.
        With tied directions one integral per pose (:meth:`direction_log_likelihoods`).
        """
        index, readings, loads = batch
        centred = readings / self.reading_scale - self.offset
        loads = loads / self.load_scale
        unknown = torch.isnan(loads).any(dim=1)
        variance = torch.exp(2 * self.log_noise)
        p = centred.shape[1]
        known_residual = centred[~unknown] - loads[~unknown] @ self.shape
        total = (known_residual.pow(2).sum(dim=1) / (2 * variance)).sum()
        for c, log_likelihood, scatter in self.direction_log_likelihoods(centred, unknown, index):
            total = total + scatter / (2 * variance) - torch.logsumexp(self.log_prior[c] + log_likelihood, dim=1).sum()
        total = total + len(centred) * p * self.log_noise
        loss = total / len(centred)
        return {"marginal_nll": loss, "noise": torch.exp(self.log_noise).detach(), "loss": loss}

    def start_from_closed_form(self, recording: CalibrationRecording) -> None:
        """The paper's closed form for one mass: truncated SVD, then the metric constraint (eqs. 7-11;
        :func:`closed_form_shape`, which leaves out a glitch that would take it over)."""
        magnitude = recording.magnitude
        # Every row of a rotation recording is the same mass, known loads included.
        readings = recording.readings
        needed = (
            metric_unknowns(self.rank, self.estimate_offset) if self.constrained else self.rank + self.estimate_offset
        )
        if len(readings) < needed:
            raise SfmnetError(
                f"only {len(readings)} samples for {needed} unknowns of the metric constraint"
                f"{' with offsets' if self.estimate_offset else ''}: record at least {needed} orientations "
                "(dozens give a good calibration)"
            )
        solution = closed_form_shape(readings, self.rank, magnitude if self.constrained else None, self.estimate_offset)
        left_out = int(solution.left_out.sum())
        if left_out:
            self.notes.append(gross_outlier_note(left_out, len(readings), self.robust))
        self.singular_values = solution.singular_values
        self.set_solution(
            solution.shape, solution.offset, rms_norm(readings), load_scale=magnitude if self.constrained else 1.0
        )
        self.set_direction_maps(recording)

    def start_from_known_loads(self, recording: CalibrationRecording) -> None:
        """Several mass configurations (six axes, method §6): least squares on the known loads as the start."""
        known = recording.known
        needed = self.rank + self.estimate_offset
        if int(known.sum()) < needed:
            raise SfmnetError(
                f"a {self.rank}-axis calibration from several mass configurations starts from its known loads, but "
                f"only {int(known.sum())} rows have one: give at least {needed} known loads spanning every axis "
                "(a few known poses in each of at least three configurations)"
            )
        shape, offset = least_squares_shape(recording.loads[known], recording.readings[known], self.estimate_offset)
        readings = recording.readings
        self.singular_values = torch.linalg.svdvals(readings - readings.mean(dim=0) if self.estimate_offset else readings)
        maps = recording.maps
        # One scale per axis (forces and torques differ by orders of magnitude), never zero.
        scale = maps.norm(dim=1).pow(2).mean(dim=0).sqrt()
        self.set_solution(shape, offset, rms_norm(recording.readings), load_scale=scale.clamp_min(1e-3 * float(scale.max())))
        self.set_direction_maps(recording)

    def set_direction_maps(self, recording: CalibrationRecording) -> None:
        if self.constrained:
            self.direction_maps = recording.maps / self.load_scale.reshape(1, 1, -1)
            self.row_configuration = recording.row_configuration

    def directions(self, readings: torch.Tensor, configuration: torch.Tensor, metric_weight: float) -> torch.Tensor:
        """Unit-direction estimates ``u`` of unknown-load rows, ``b x d`` (:func:`constrained_motion` per configuration).

        Args:
            readings: ``b x p`` divided by ``reading_scale``; configuration: ``b`` (long).
            metric_weight: ``w`` (0: the least-squares directions, off the unit sphere).
        """
        if len(self.direction_maps) == 1 and metric_weight == 0:
            # One mass, plain least squares: u = (z - o) pinv(D S), one product over the rows.
            effective_shape = self.direction_maps[0] @ self.shape.detach()
            projection = torch.linalg.solve(effective_shape @ effective_shape.T, effective_shape).T
            return readings @ projection - self.offset.detach() @ projection
        readings = readings - self.offset.detach()
        if len(self.direction_maps) == 1:
            return constrained_motion(readings, self.direction_maps[0] @ self.shape.detach(), metric_weight)
        directions = readings.new_zeros(len(readings), self.direction_maps.shape[1])
        for c in configuration.unique().tolist():
            rows = configuration == c
            effective_shape = self.direction_maps[c] @ self.shape.detach()
            directions[rows] = constrained_motion(readings[rows], effective_shape, metric_weight)
        return directions

    def row_directions(
        self,
        readings: torch.Tensor,
        configuration: torch.Tensor,
        multipliers: torch.Tensor | None = None,
        pose: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Unknown rows' directions as the refinement uses them: on the unit sphere (alternation) or the penalty's argmin.

        ``multipliers``: :func:`unit_motion`'s warm start of one mass's rows (read and overwritten), else unused.
        ``pose``: ``b`` (long), rows of one pose share the direction of their mean reading (tied directions:
        ``argmin_u sum_j |z_j - o - u D S|^2`` is the argmin for ``z_bar``), or None.
        """
        if pose is not None:
            means, index, _ = group_means(readings, pose)
            pose_configuration = configuration.new_zeros(len(means)).scatter_(0, index, configuration)
            return self.row_directions(means, pose_configuration)[index]
        if self.refinement == "penalty":
            return self.directions(readings, configuration, self.metric_weight)
        readings = readings - self.offset.detach()
        if len(self.direction_maps) == 1:
            return unit_motion(readings, self.direction_maps[0] @ self.shape.detach(), multipliers=multipliers)
        directions = readings.new_zeros(len(readings), self.direction_maps.shape[1])
        for c in configuration.unique().tolist():
            rows = configuration == c
            directions[rows] = unit_motion(readings[rows], self.direction_maps[c] @ self.shape.detach())
        return directions

    def batch_motion(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Dimensionless readings, motion (``b x n``), directions (``b x d``, zero on known rows) and the unknown-row mask."""
        return self.scaled_motion(self.scaled_batch(batch))

    def scaled_batch(self, batch: Batch) -> ScaledBatch:
        """``batch`` in the parameters' units: readings over ``reading_scale``, loads over ``load_scale``."""
        index, readings, loads = batch
        configuration = self.row_configuration[index] if self.constrained else index
        pose = self.row_pose[index] if self.tied else None
        return ScaledBatch(readings / self.reading_scale, loads / self.load_scale, torch.isnan(loads).any(dim=1), configuration, pose)

    def scaled_motion(
        self, batch: ScaledBatch, multipliers: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`batch_motion` of a batch already scaled; ``multipliers`` (one per row) as in :meth:`row_directions`."""
        readings, loads, unknown, configuration, pose = batch
        if self.constrained and len(self.direction_maps) == 1:
            # One mass: every row's direction at once (a known row's is discarded), no masked copies of a long
            # recording; the few known rows are overwritten in place (a pose holds rows of one load only).
            known = ~unknown
            directions = self.row_directions(readings, configuration, multipliers, pose)
            directions[known] = 0.0
            motion = directions @ self.direction_maps[0]
            motion[known] = loads[known]
            return readings, motion, directions, unknown
        motion = loads.clone()
        if not self.constrained:
            motion[unknown] = constrained_motion(readings[unknown] - self.offset.detach(), self.shape.detach(), 0.0)
            return readings, motion, readings.new_zeros(len(readings), self.rank), unknown
        directions = readings.new_zeros(len(readings), self.direction_maps.shape[1])
        directions[unknown] = self.row_directions(
            readings[unknown], configuration[unknown], pose=None if pose is None else pose[unknown]
        )
        for c in configuration[unknown].unique().tolist():
            rows = unknown & (configuration == c)
            motion[rows] = directions[rows] @ self.direction_maps[c]
        return readings, motion, directions, unknown

    def loss(self, batch: Batch) -> dict[str, torch.Tensor]:
        if self.refinement == "marginal":
            return self.marginal_loss(batch)
        return self.loss_terms(*self.batch_motion(batch))

    def loss_terms(
        self, readings: torch.Tensor, motion: torch.Tensor, directions: torch.Tensor, unknown: torch.Tensor
    ) -> dict[str, torch.Tensor]:
        """The loss terms at the current ``(S, o)`` for rows' motion already solved (:meth:`scaled_motion`'s four)."""
        terms = {
            "reconstruction": reconstruction_loss(readings, motion, self.shape, self.offset, unknown),
            "metric_constraint": metric_constraint_loss(directions, unknown) if self.constrained else readings.new_zeros(()),
            "known_load": reconstruction_loss(readings, motion, self.shape, self.offset, ~unknown),
        }
        terms["loss"] = terms["reconstruction"] + self.metric_weight * terms["metric_constraint"] + terms["known_load"]
        return terms

    @torch.no_grad()
    def alternation_map(self, motion_state: tuple[torch.Tensor, ...]) -> torch.Tensor:
        """One round of method §5's alternation from the current ``(S, o)``; returns the new ``[S; o]`` (``(n+1) x p``).

        ``u_j <- the unit direction nearest z_j - o`` (:func:`unit_motion`), then ``[S; o] <- lstsq([M 1], Z)``
        with the known loads as their rows' motion (Huber-weighted rows when ``robust``), then the
        frame turned to fit the known loads (:func:`known_load_rotation`: only they hold it, so the
        plain rounds would turn it by tiny steps). The least
        squares is solved about the rows' (weighted) means, which keeps the offset column from
        making it ill-conditioned, through ``n x n`` normal equations: a few passes over the rows.

        Args:
            motion_state: :meth:`scaled_motion` of the batch at the current ``(S, o)`` (the first step).
        """
        readings, motion, _, unknown = motion_state
        weights = None
        if self.robust:
            residual = (readings - motion @ self.shape - self.offset).norm(dim=1)
            weights = huber_weights(residual, self.huber_threshold)[:, None]
        if not self.estimate_offset:
            weighted = motion if weights is None else motion * weights
            shape = torch.linalg.solve(weighted.T @ motion, weighted.T @ readings)
            return torch.cat([shape, self.offset.detach()[None]])
        total = len(motion) if weights is None else weights.sum()
        motion_mean = (motion if weights is None else motion * weights).sum(dim=0) / total
        readings_mean = (readings if weights is None else readings * weights).sum(dim=0) / total
        centred = motion - motion_mean
        weighted = centred if weights is None else centred * weights
        # The weighted centred motion sums to zero, so the readings need no centring of their own.
        shape = torch.linalg.solve(weighted.T @ centred, weighted.T @ readings)
        offset = readings_mean - motion_mean @ shape
        if self.constrained:
            shape = self.turned_to_known_loads(readings[~unknown] - offset, motion[~unknown], shape)
        return torch.cat([shape, offset[None]])

    def descended_motion(
        self,
        scaled: ScaledBatch,
        multipliers: torch.Tensor,
        plain: torch.Tensor | None,
        accepted_loss: float,
    ) -> tuple[tuple[torch.Tensor, ...], float]:
        """:meth:`scaled_motion` at the current ``(S, o)`` and its loss, where Anderson's mix did not raise the loss
        above ``accepted_loss`` (the last round's start); else at ``plain``, that round's unaccelerated ``[S; o]``, set
        as the current one.

        A plain round never raises the loss: each of its steps (directions, then the least squares, then the turn onto
        the known loads) minimises it over what it changes. Mixing rounds extrapolates, and on a cap of directions with
        offsets, where the loss is a long curved valley, unchecked mixes climbed out of it: a hostile tester's 8-channel
        sensor with 12 poses in a 45-degree cone at SNR 1500 ended 277 % from the truth, its residual 1.37x the noise.
        """
        motion_state = self.scaled_motion(scaled, multipliers)
        loss = float(self.loss_terms(*motion_state)["loss"])
        if plain is None or loss <= accepted_loss:
            return motion_state, loss
        self.set_shape_and_offset(plain)
        motion_state = self.scaled_motion(scaled, multipliers)
        return motion_state, float(self.loss_terms(*motion_state)["loss"])

    def shape_and_offset(self) -> torch.Tensor:
        """``[S; o]``, ``(n+1) x p`` (parameter units), detached."""
        return torch.cat([self.shape.detach(), self.offset.detach()[None]])

    def set_shape_and_offset(self, stacked: torch.Tensor) -> None:
        """``S`` and ``o`` from ``[S; o]`` (``(n+1) x p``, parameter units)."""
        self.shape.copy_(stacked[: self.rank])
        self.offset.copy_(stacked[self.rank])

    def turned_to_known_loads(self, centred: torch.Tensor, loads: torch.Tensor, shape: torch.Tensor) -> torch.Tensor:
        """``R S`` with ``R`` the rotation that best fits the known rows (:func:`known_load_rotation`), where one mass's
        frame rests on them; else ``S``. ``centred``: their readings minus offsets, ``k x p``; ``loads``: ``k x n``
        (both scaled as the parameters are); ``shape``: ``S``, ``n x p``."""
        if len(self.direction_maps) != 1 or not len(loads):
            return shape
        magnitude = float(torch.linalg.matrix_norm(self.direction_maps[0], ord=2))
        return known_load_rotation(centred, loads, shape, magnitude) @ shape

    @torch.no_grad()
    def alternate(self, batch: Batch) -> dict[str, torch.Tensor]:
        """Up to ``alternation_steps`` rounds of :meth:`alternation_map` on a full batch, Anderson-accelerated (a mix
        that raised the loss replaced by the plain round: :meth:`descended_motion`), until a round moves ``[S; o]`` by
        less than ``ALTERNATION_TOLERANCE`` of its norm.

        Returns the loss terms at the final ``(S, o)`` with the last round's directions: at the fixed
        point those are the final ones to that tolerance, and a million rows' direction solve is saved.
        """
        scaled = self.scaled_batch(batch)
        acceleration = AndersonAcceleration()
        start = self.shape_and_offset()
        # Each row's multiplier from the last round starts the next round's direction solve.
        multipliers = scaled.readings.new_full((len(scaled.readings),), float("nan"))
        converged = False
        plain, accepted_loss = None, math.inf
        for _ in range(self.alternation_steps):
            motion_state, accepted_loss = self.descended_motion(scaled, multipliers, plain, accepted_loss)
            plain = self.alternation_map(motion_state)
            current = acceleration.step(self.shape_and_offset(), plain)
            self.set_shape_and_offset(current)
            if acceleration.step_norm <= ALTERNATION_TOLERANCE * float(current.norm()):
                converged = True
                break
        else:
            motion_state, _ = self.descended_motion(scaled, multipliers, plain, accepted_loss)
            current = self.shape_and_offset()
        self.alternation_still_moving = 0.0 if converged else float((current - start).norm() / current.norm())
        return self.loss_terms(*motion_state)

    def unknown_directions(self, recording: CalibrationRecording) -> tuple[torch.Tensor, torch.Tensor]:
        """The unknown-load rows' directions, put exactly on the unit sphere, and their maps (load units)."""
        unknown = ~recording.known
        if not self.constrained:
            n = recording.rank
            loads = self.motion_of(recording.readings[unknown])
            return loads, torch.eye(n, dtype=loads.dtype).expand(len(loads), n, n)
        configuration = recording.row_configuration[unknown]
        # The refinement's own direction estimates, so residuals and error bars describe its fixed point.
        directions = self.row_directions(
            recording.readings[unknown] / self.reading_scale, configuration, pose=self.unknown_poses(recording)
        )
        maps = recording.maps
        # One mass: one map seen by every row (a view; a million rows' own copies would be 72 MB).
        row_maps = maps.expand(len(directions), -1, -1) if len(maps) == 1 else maps[configuration]
        return directions / directions.norm(dim=1, keepdim=True), row_maps

    def information_directions(self, recording: CalibrationRecording, directions: torch.Tensor) -> torch.Tensor:
        """The marginal's error bars at its own direction estimates: each unknown row's posterior-mean direction under
        the learnt law, ``normalise(sum_k softmax_k(log w_ck + log L_jk) u_k)`` (a pose's, tied), ``f' x d``; the
        other refinements' at ``directions``.

        A noisy row's argmin direction scatters wider than the true one, most along a weakly spanned axis (a
        band, a cone), so information evaluated there overstates it. bench/crb_ratio.py --laws, 10 sessions a row:
        the RMS matrix error over the RMS bar on the 2-axis band at SNR 5 went from 2.04 to 1.51, and the bars'
        68 % coverage from 0.54 to 0.57 there, 0.47 to 0.57 on the 3-axis band at SNR 5, 0.60 to 0.66 on the 2-axis
        band with offsets (but 0.77 to 0.80 on the 2-axis cone with offsets at SNR 20); unchanged on uniform laws.
        """
        if self.refinement != "marginal":
            return directions
        unknown = ~recording.known
        centred = recording.readings[unknown] / self.reading_scale - self.offset.detach()
        configuration = recording.row_configuration[unknown]
        poses = self.unknown_poses(recording)
        estimates = centred.new_zeros(len(centred), self.grid.shape[1])
        with torch.no_grad():
            for c in configuration.unique().tolist():
                rows = configuration == c
                log_likelihood, index, _ = self.free_direction_log_likelihoods(centred[rows], None if poses is None else poses[rows], c)
                means = torch.softmax(self.log_prior[c] + log_likelihood, dim=1) @ self.grid
                estimates[rows] = means if index is None else means[index]
        return estimates / estimates.norm(dim=1, keepdim=True).clamp_min(torch.finfo(estimates.dtype).tiny)

    def unknown_poses(self, recording: CalibrationRecording) -> torch.Tensor | None:
        poses = recording.same_load_groups if self.tied else None
        return None if poses is None else poses[~recording.known]

    @torch.no_grad()
    def orient(self, recording: CalibrationRecording) -> None:
        """Turn the closed-form solution into the known loads' frame by Procrustes (method §3).

        Training then keeps that frame: the known-load term holds it, and with ``n - 1``
        known loads the mirror image is a discrete jump no gradient step makes. Without
        known loads the frame stays arbitrary (``frame_fixed`` is False), turned to the channels' own where there
        are as many as axes (:meth:`turn_to_channels`). A start from known loads is in their frame already.
        """
        known = recording.known
        self.frame_fixed = bool(known.any())
        if not self.frame_fixed:
            self.turn_to_channels()
            return
        if recording.direction_maps is not None:
            return
        hint = recording.mirror_hint
        hint_motion = None
        if hint is not None:
            unknown_rows = torch.nonzero(~known)[:, 0]
            if not 0 <= hint.sample < len(unknown_rows):
                raise SfmnetError(
                    f"mirror_hint.sample is {hint.sample} but there are {len(unknown_rows)} unknown-orientation rows"
                )
            hint_motion = self.motion_of(recording.readings[unknown_rows[hint.sample]][None])
        def circle_gap() -> float | None:
            # About their mean, the unknown rows' readings that lie on one circle of orientations span n - 1 dimensions.
            unknown_readings = recording.readings[~known]
            return readings_rank_gap(torch.linalg.svdvals(unknown_readings - unknown_readings.mean(dim=0)), recording.rank)

        rotation = frame_rotation(
            self.motion_of(recording.readings[known]), recording.loads[known], hint_motion, hint,
            readings_rank_gap(self.singular_values, recording.rank), circle_gap,
        )
        self.shape.copy_(rotation.T @ self.shape)


def huber_weights(residual_norms: torch.Tensor, threshold: float) -> torch.Tensor:
    """Iteratively reweighted least squares weights of Huber's loss on each row's residual norm ``r_j`` (``f``).

    ``w_j = min(1, c / r_j)`` with ``c = threshold * median(r)``: rows within ``c`` count fully, rows
    beyond it as if their residual were ``c`` (Huber's loss is quadratic inside, linear outside).
    """
    limit = threshold * residual_norms.median()
    return (limit / residual_norms.clamp_min(torch.finfo(residual_norms.dtype).tiny)).clamp(max=1.0)
