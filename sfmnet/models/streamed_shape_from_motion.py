"""Shape from motion from streamed sufficient statistics: a calibration whose memory does not grow with the session."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch

from sfmnet.data.recording import CalibrationRecording, empty_load_columns, first_magnitude_mismatch
from sfmnet.data.rows import IntervalSums, RowBlock, StreamedRecording
from sfmnet.errors import SfmnetError
from sfmnet.linalg.anderson import AndersonAcceleration
from sfmnet.linalg.channel_dependence import dependent_channels, dependent_channels_message
from sfmnet.linalg.factorisation import (
    design_leverage,
    ellipsoid_from_coefficients,
    gross_outlier_note,
    leverage_limit,
    metric_design,
    metric_shape,
    metric_unknowns,
    readings_rank_gap,
    require_coverage,
)
from sfmnet.linalg.frame import frame_rotation, known_load_rotation
from sfmnet.linalg.group_means import harmonic_mean_rows
from sfmnet.linalg.motion import unit_motion
from sfmnet.linalg.moments import (
    Moments,
    cross_product,
    principal_subspace,
    singular_values_from_scatter,
)
from sfmnet.linalg.uncertainty import CalibrationUncertainty, alternation_bias, calibration_uncertainty, residual_noise_variance
from sfmnet.models.contracts import FitMode
from sfmnet.models.linear_calibrator import LinearCalibrator, UnknownRows
from sfmnet.models.shape_from_motion import (
    ALTERNATION_BIASED_BELOW_SNR,
    RUNAWAY_GROWTH,
    low_snr_warning,
    runaway_warning,
    shape_growth,
)
from sfmnet.preprocessing.static_intervals import intervals_of

REFINEMENTS = ("alternation", "closed_form")
# Rounds the alternation mixes: one per pass, so a longer memory than in memory pays.
ANDERSON_HISTORY = 10
# An alternation still moving after its passes whose shape's largest singular value has grown this many
# times the closed form's is running away, not converging slowly (a 2-axis band at SNR 2 circled at 8.7x
# for hundreds of passes); on data it can calibrate it converges within a few percent of the closed form.
GROWTH_WHILE_UNCONVERGED = 2.0


class StreamedShapeFromMotion(LinearCalibrator):
    """The closed form (paper eqs. 6-11, method §2-4) and method §5's alternation, each pass a sum over rows.

    One trainer epoch is one pass over the file; what each pass adds up is all the next step needs:

    1. ``count``, ``sum z`` and ``Z^T Z`` (float64, about a fixed shift; :class:`Moments`): the
       truncated SVD of the (centred) readings is the eigendecomposition of their scatter,
       ``Z*^T Z* = V Sigma^2 V^T``, so ``S^ = Sigma^(1/2) V^T`` and each row's affine motion is
       ``m^ = (z - mean) V Sigma^(-1/2)`` (eq. 8). The pass also gathers the known-load rows
       and a systematic sample of rows (for error bars and figures).
    2. The metric constraint's normal equations, ``D^T D`` and ``D^T 1`` of the design
       ``D = [quadratic(m^), m^]`` (eq. 11, method §4), from the rows projected with pass 1's
       subspace: ``Q`` and the ellipsoid's centre give ``S`` and ``o``, turned into the known
       loads' frame by Procrustes (method §3). This is the paper's closed form. Where it has no
       positive-definite solution, passes 1 and 2 are read again without the rows whose leverage
       in it was extreme (method §2, "A glitch").
    3. Each further pass is one alternation round (``refinement="alternation"``):
       ``u_j = argmin_{|u|=1} |z_j - o - F u S|`` (:func:`unit_motion`), or, with static intervals and
       ``tie_directions``, one direction per interval from its mean reading (method §5, tied directions: pass 1's
       sums per interval hold it), then
       ``[S; o] = solve(A, B)`` with ``A = [M 1]^T [M 1]`` and ``B = [M 1]^T Z`` summed over the pass, known loads as their rows' motion, then the
       frame turned to fit the known loads (:func:`known_load_rotation`); Anderson-accelerated
       across passes, stopped once a round moves the parameters by less than ``tolerance``
       (relative). The fixed point is the in-memory alternation's.

    Every sum is over each row once, in float64, and reduced across processes by the
    trainer's strategy, so one or several processes give the same numbers. Memory is
    ``O(p^2 + sample_rows p)`` whatever the number of rows.

    Args:
        estimate_offset: learn channel offsets (ellipsoid closed form); else tared readings.
        refinement: ``"alternation"`` (default) or ``"closed_form"`` (stop after pass 2).
        tie_directions: the rows of one static interval share one direction, as in memory; untied, each row's
            direction is its own parameter, whose bias (``(n - 1) / (2 SNR^2)`` of the shape) does not shrink with
            the rows while the error bars do.
        tolerance: relative parameter change at which the alternation has converged.
        sample_rows: rows kept (every ``k``-th) for the Cramer-Rao error bars and figures.
        max_known_rows: known-load rows gathered in memory (a few are the point of the method).
    """

    name = "streamed_shape_from_motion"
    recording = StreamedRecording.recording
    dev_run_passes = 3  # moments, metric constraint, one alternation round
    constrained = True

    def __init__(
        self,
        estimate_offset: bool = True,
        refinement: str = "alternation",
        tie_directions: bool = True,
        tolerance: float = 1e-9,
        sample_rows: int = 100_000,
        max_known_rows: int = 10_000,
    ) -> None:
        super().__init__(estimate_offset=estimate_offset)
        if refinement not in REFINEMENTS:
            raise SfmnetError(f"model.refinement is '{refinement}': use one of {', '.join(REFINEMENTS)}")
        self.refinement = refinement
        self.tie_directions = tie_directions
        self.tolerance = tolerance
        self.sample_rows = sample_rows
        self.max_known_rows = max_known_rows
        self.passes = 0
        self.converged = False
        # Set where pass 2 found no positive-definite metric (method §2, "A glitch"): what names the rows that took it
        # over (its subspace, normal matrix and leverage limit), for reading passes 1 and 2 again without them, and the
        # error it found.
        self.metric_screen: dict[str, torch.Tensor | float] | None = None
        self.metric_failure = ""
        self.metric_left_out = torch.zeros((), dtype=torch.float64)

    def fit_mode(self) -> FitMode:
        return FitMode.PASSES

    # What finished passes leave for the next ones. A checkpoint (taken at the end of a pass) keeps
    # it, so a resumed fit keeps the passes it finished and reads the interrupted one again.
    PASS_STATE = (
        "passes", "converged", "sample", "first_partial_row", "known", "centre", "singular_values", "affine_shape",
        "projection", "coverage", "frame_fixed", "frame_of_channels", "reading_scale", "load_scale", "closed_form_scale",
        "residual_squares", "interval_readings", "interval_residuals", "metric_screen", "metric_failure", "metric_left_out",
    )

    def get_extra_state(self) -> dict[str, object]:
        state: dict[str, object] = {name: getattr(self, name) for name in self.PASS_STATE if hasattr(self, name)}
        if hasattr(self, "moments"):
            state["moments"] = {name: getattr(self.moments, name) for name in ("shift", "count", "total", "cross")}
        if hasattr(self, "acceleration"):
            state["acceleration"] = self.acceleration.state_dict()
        return state

    def set_extra_state(self, state: dict[str, object]) -> None:
        for name in self.PASS_STATE:
            if name in state:
                setattr(self, name, state[name])
        if "moments" in state:
            self.moments = Moments(**state["moments"])
        if "acceleration" in state:
            self.acceleration = AndersonAcceleration(history=ANDERSON_HISTORY)
            self.acceleration.load_state_dict(state["acceleration"])

    @property
    def rank(self) -> int:
        return self.data.rank

    def initialise(self, recording: StreamedRecording) -> None:
        self.data = recording
        n, p = recording.rank, len(recording.channels)
        self.stride = math.ceil(recording.rows / self.sample_rows)
        self.set_solution(
            torch.zeros(n, p, dtype=torch.float64), torch.zeros(p, dtype=torch.float64),
            torch.ones((), dtype=torch.float64), recording.magnitude,
        )

    # -- passes ---------------------------------------------------------------------------------

    def begin_pass(self) -> None:
        n, p = self.rank, len(self.data.channels)
        if self.passes == 0:
            self.moments = Moments.empty(self.data.shift)
            self.known_rows: list[torch.Tensor] = []
            self.first_partial_row = self.data.rows
            # Readings, loads and the static interval (plus one; 0: none) of every stride-th row.
            self.sample = torch.zeros(math.ceil(self.data.rows / self.stride), p + n + 1, dtype=torch.float64)
            # Per static interval: rows, sum z and sum |z|^2 (the noise within poses from every row, not the sample's).
            self.interval_readings = torch.zeros(self.intervals, p + 2, dtype=torch.float64)
            # Each channel's least and largest reading: a constant one carries no load (the range, not the variance,
            # which rounding leaves at ~1e-13 for a column of 1.234).
            self.channel_range = torch.stack([torch.full((p,), math.inf), torch.full((p,), -math.inf)]).double()
        elif self.passes == 1:
            m = metric_unknowns(n, self.estimate_offset)
            self.metric_normal = torch.zeros(m, m, dtype=torch.float64)
            self.metric_target = torch.zeros(m, dtype=torch.float64)
            self.metric_left_out = torch.zeros((), dtype=torch.float64)
        else:
            k = n + self.estimate_offset
            self.design_gram = torch.zeros(k, k, dtype=torch.float64)
            self.design_readings = torch.zeros(k, p, dtype=torch.float64)
            self.residual_squares = torch.zeros(p, dtype=torch.float64)
            # Per static interval: sum of residuals and of the rows' residual degrees of freedom (the poses' means).
            self.interval_residuals = torch.zeros(self.intervals, p + 1, dtype=torch.float64)
            self.pass_directions = self.interval_directions() if self.tied else None

    def accumulate(self, block: RowBlock) -> None:
        """Add one block (readings minus the data's shift) to this pass's sums; rows in motion are left out."""
        rows = torch.arange(block.start, block.start + len(block.readings))
        if block.loads.shape[1] < self.rank:
            # No load columns: every row's load is unknown.
            block = RowBlock(block.start, block.readings, block.readings.new_full((len(block.readings), self.rank), math.nan))
        if self.data.keep is not None:
            static = torch.from_numpy(self.data.keep[block.start : block.start + len(block.readings)])
            block, rows = RowBlock(block.start, block.readings[static], block.loads[static]), rows[static]
        gross = self.gross_rows(block.readings) if self.metric_screen is not None and self.passes < 2 else None
        if self.passes == 0:
            self.accumulate_moments(block, rows, gross)
        elif self.passes == 1:
            design = metric_design(self.affine_motion(block.readings), self.estimate_offset)
            if gross is not None:
                self.metric_left_out += gross.sum()
                design = design[~gross]
            self.metric_normal += cross_product(design)
            self.metric_target += design.sum(dim=0)
        else:
            self.accumulate_alternation(block, rows)

    @property
    def rows_read(self) -> int:
        """The static rows each pass reads: the moments' (the closed form's) and any it left out as gross outliers."""
        return int(self.moments.count) + int(self.metric_left_out)

    def gross_rows(self, shifted: torch.Tensor) -> torch.Tensor:
        """Which of a block's rows (readings minus the shift) took the first metric pass over: their leverage in it, at
        its subspace, past its limit (:func:`design_leverage`, :func:`leverage_limit`). Each row's, where in memory each
        distinct reading's (:func:`~sfmnet.linalg.factorisation.gross_outliers`): a stream cannot tell which rows repeat
        one reading, and many that do share their leverage and pass."""
        screen = self.metric_screen
        motion = (shifted - (screen["centre"] - self.data.shift)) @ screen["projection"]
        return design_leverage(metric_design(motion, self.estimate_offset), screen["normal"]) > screen["limit"]

    def accumulate_moments(self, block: RowBlock, rows: torch.Tensor, gross: torch.Tensor | None = None) -> None:
        """``rows``: each block row's index in the file; ``gross``: rows left out of the moments (:meth:`gross_rows`)."""
        self.moments.add_shifted(block.readings if gross is None else block.readings[~gross])
        if len(block.readings):
            low, high = self.channel_range
            self.channel_range = torch.stack([torch.minimum(low, block.readings.min(dim=0).values),
                                              torch.maximum(high, block.readings.max(dim=0).values)])
        given = torch.isfinite(block.loads)
        known = given.all(dim=1)
        partial = torch.nonzero(given.any(dim=1) & ~known)
        if len(partial):
            self.first_partial_row = min(self.first_partial_row, int(rows[partial[0]]))
        if known.any():
            self.known_rows.append(torch.cat([rows[known, None].double(), block.readings[known], block.loads[known]], 1))
        interval = self.interval_of(rows)
        squares = block.readings.pow(2).sum(dim=1, keepdim=True)
        self.add_to_intervals(self.interval_readings, interval, torch.cat([torch.ones_like(squares), block.readings, squares], 1))
        sampled = rows % self.stride == 0
        interval = 1 + interval[sampled]
        self.sample[rows[sampled] // self.stride] = torch.cat(
            [block.readings[sampled], block.loads[sampled], interval[:, None].double()], dim=1
        )

    @property
    def intervals(self) -> int:
        """The stream's static intervals (0 without them)."""
        return 0 if self.data.intervals is None else len(self.data.intervals)

    @property
    def tied(self) -> bool:
        """Whether a static interval's rows share one direction (``tie_directions`` and the stream has intervals)."""
        return self.tie_directions and self.intervals > 0

    def interval_directions(self) -> torch.Tensor:
        """Each static interval's direction at the current fit, ``k x n``: ``argmin_{|u|=1} |zbar_k - o - F u S|`` of its
        mean reading ``zbar_k`` (pass 1's sums), the exact constrained least squares of its rows (method §5)."""
        p = len(self.data.channels)
        means = self.interval_readings[:, 1 : p + 1] / self.interval_readings[:, :1].clamp_min(1)
        centred = means - (self.physical_offset() - self.data.shift)
        return unit_motion(centred, self.data.magnitude * self.physical_shape())

    def row_directions(self, centred: torch.Tensor, interval: torch.Tensor, directions: torch.Tensor | None) -> torch.Tensor:
        """Unit directions (``b x n``) of rows with readings less offsets ``centred`` (``b x p``): the interval's
        (``directions``, :meth:`interval_directions`) for rows in one (``interval`` >= 0), where tied; each row's own
        elsewhere."""
        inside = interval >= 0 if directions is not None else torch.zeros_like(interval, dtype=torch.bool)
        result = centred.new_empty(len(centred), self.rank)
        result[~inside] = unit_motion(centred[~inside], self.data.magnitude * self.physical_shape())
        if directions is not None:
            result[inside] = directions[interval[inside]]
        return result

    def interval_sums(self) -> IntervalSums | None:
        """Each static interval's sums over every row (:class:`IntervalSums`), the residuals those of the last
        alternation pass (at the fit, once it has converged); None without intervals or before that pass (the closed
        form alone: the pose checks then use the sample)."""
        if not self.intervals or self.passes <= 2:
            return None
        p = self.interval_readings.shape[1] - 2
        readings, residuals = self.interval_readings, self.interval_residuals
        return IntervalSums(
            counts=readings[:, 0], readings=readings[:, 1 : p + 1], squares=readings[:, p + 1],
            residuals=residuals[:, :p], dof=residuals[:, p],
        )

    @staticmethod
    def add_to_intervals(sums: torch.Tensor, interval: torch.Tensor, values: torch.Tensor) -> None:
        """Add each row's ``values`` (``b x c``) to its static interval's row of ``sums`` (``k x c``), ``interval``
        (``b``) from :meth:`interval_of`; rows outside every interval (-1) add nothing."""
        inside = interval >= 0
        sums.index_add_(0, interval[inside], values[inside])

    def interval_of(self, rows: torch.Tensor) -> torch.Tensor:
        """Each of ``rows`` (file indices)'s static interval, ``r`` long; -1 outside them or without them."""
        if self.data.intervals is None:
            return torch.full((len(rows),), -1, dtype=torch.long)
        return torch.from_numpy(intervals_of(rows.numpy(), self.data.intervals))

    def affine_motion(self, shifted: torch.Tensor) -> torch.Tensor:
        """``m^ = (z - c) V Sigma^(-1/2)`` (eq. 8), ``b x n``, for readings minus the shift."""
        return (shifted - (self.centre - self.data.shift)) @ self.projection

    def accumulate_alternation(self, block: RowBlock, rows: torch.Tensor) -> None:
        centred = block.readings - (self.physical_offset() - self.data.shift)
        known = torch.isfinite(block.loads).all(dim=1)
        interval = self.interval_of(rows)
        motion = self.data.magnitude * self.row_directions(centred, interval, self.pass_directions)
        motion[known] = block.loads[known]
        residual = centred - motion @ self.physical_shape()
        self.residual_squares += residual.pow(2).sum(dim=0)
        p, n = residual.shape[1], self.rank
        dof = torch.where(known, p, p - n + 1)[:, None].double()
        self.add_to_intervals(self.interval_residuals, interval, torch.cat([residual, dof], dim=1))
        design = torch.cat([motion, torch.ones_like(motion[:, :1])], dim=1) if self.estimate_offset else motion
        self.design_gram += cross_product(design)
        self.design_readings += cross_product(design, block.readings if self.estimate_offset else block.readings + self.data.shift)

    def reduce(self, strategy) -> None:
        """Sum this pass's statistics over processes (each row was read by exactly one)."""
        if self.passes == 0:
            for name in ("count", "total", "cross"):
                setattr(self.moments, name, strategy.reduce(getattr(self.moments, name), reduce_op="sum"))
            self.sample = strategy.reduce(self.sample, reduce_op="sum")
            self.interval_readings = strategy.reduce(self.interval_readings, reduce_op="sum")
            ranges = gather_by_rank(strategy, self.channel_range.flatten()).reshape(-1, 2, len(self.data.channels))
            self.channel_range = torch.stack([ranges[:, 0].min(dim=0).values, ranges[:, 1].max(dim=0).values])
            self.first_partial_row = int(gather_by_rank(strategy, torch.tensor([float(self.first_partial_row)])).min())
            self.known = gather_rows(strategy, self.known_rows, 1 + len(self.data.channels) + self.rank, self.max_known_rows)
        elif self.passes == 1:
            for name in ("metric_normal", "metric_target", "metric_left_out"):
                setattr(self, name, strategy.reduce(getattr(self, name), reduce_op="sum"))
        else:
            for name in ("design_gram", "design_readings", "residual_squares", "interval_residuals"):
                setattr(self, name, strategy.reduce(getattr(self, name), reduce_op="sum"))

    @torch.no_grad()
    def finalise(self) -> None:
        if self.passes == 0:
            self.solve_subspace()
        elif self.passes == 1:
            if not self.solve_metric():
                return
            # After the metric's solve, which says first where the loads do not span the load space.
            dependent = dependent_channels(self.moments.centred_cross(), int(self.moments.count), self.rank)
            if dependent:
                raise SfmnetError(dependent_channels_message([self.data.channels[k] for k in dependent], ""))
        elif not self.converged:
            self.solve_alternation()
        self.passes += 1

    # -- solves -----------------------------------------------------------------------------------

    def solve_subspace(self) -> None:
        """Pass 1: the principal subspace of the readings (eqs. 6-8) and the known rows' checks."""
        moments, data, n = self.moments, self.data, self.rank
        data.require_plausible(moments)
        if self.first_partial_row < data.rows:
            raise SfmnetError(
                f"{data.row_place(self.first_partial_row)} gives only some of "
                f"{', '.join(data.load_columns)}: fill every load column on a known row, or none"
            )
        needed = metric_unknowns(n, self.estimate_offset)
        if moments.count < needed:
            raise SfmnetError(
                f"only {int(moments.count)} samples for {needed} unknowns of the metric constraint: record at least "
                f"{needed} orientations (dozens give a good calibration)"
            )
        constant = [name for name, low, high in zip(data.channels, *self.channel_range.tolist()) if low == high]
        if constant:
            raise SfmnetError(
                f"channel {', '.join(constant)} is constant on every row fitted: it carries no load information; "
                "leave it out with data.channel_columns=[...]"
            )
        self.check_known_magnitudes()
        self.centre = moments.mean() if self.estimate_offset else torch.zeros_like(moments.shift)
        scatter = moments.cross_about(self.centre)
        self.singular_values = singular_values_from_scatter(scatter)
        components, singular = principal_subspace(scatter, n)
        if singular[-1] <= 1e-9 * singular[0]:
            raise SfmnetError(
                f"the readings span fewer than {n} dimensions: the loads are collinear or coplanar; turn the mass "
                f"through orientations that span all {n} load axes"
            )
        self.affine_shape = singular.sqrt()[:, None] * components
        self.projection = components.T / singular.sqrt()
        self.reading_scale = (moments.centred_cross().trace() / moments.count).sqrt()

    def check_known_magnitudes(self) -> None:
        if self.data.load_columns and not len(self.known):
            raise SfmnetError(empty_load_columns(self.data.load_columns, "the file"))
        forces = self.known_loads()
        magnitudes = np.full(len(forces), self.data.magnitude)
        off = first_magnitude_mismatch(forces.numpy(), magnitudes, self.data.known_load_tolerance)
        if off is not None:
            raise SfmnetError(
                f"the known load on {self.data.row_place(int(self.known[off, 0]))} has magnitude "
                f"{float(forces[off].norm()):.6g} but data.magnitude is {self.data.magnitude:.6g} "
                f"({100 * self.data.known_load_tolerance:g} % allowed): the known loads must be the calibration mass; "
                "check the load columns, units and mass"
            )

    def known_readings(self) -> torch.Tensor:
        """``k x p`` raw readings of the known-load rows (in file order)."""
        return self.known[:, 1 : 1 + len(self.data.channels)] + self.data.shift

    def known_loads(self) -> torch.Tensor:
        """``k x n``."""
        return self.known[:, 1 + len(self.data.channels) :]

    def solve_metric(self) -> bool:
        """Pass 2: the metric constraint (eq. 11, with the ellipsoid's centre for offsets), then the frame (method §3).

        Where it has no positive-definite solution, False: passes 1 and 2 are to be read again without the rows whose
        leverage in this one passes :func:`leverage_limit` (method §2, "A glitch", as :func:`closed_form_shape` does in
        memory). If it has none then either, this pass's error.
        """
        n = self.rank
        coefficients = torch.linalg.lstsq(self.metric_normal, self.metric_target[:, None]).solution[:, 0]
        try:
            ellipsoid = ellipsoid_from_coefficients(coefficients, n, self.data.magnitude)
        except SfmnetError as error:
            if self.metric_screen is not None:
                raise SfmnetError(
                    f"{self.metric_failure}; or corrupted rows took it over that a stream cannot single out (many rows "
                    "repeating one reading, e.g. zeros from dropped packets): remove them, or calibrate in memory with "
                    'experiment=calibrate_csv, which finds them (method §2, "A glitch")'
                ) from None
            self.metric_failure = str(error)
            self.metric_screen = {
                "centre": self.centre, "projection": self.projection, "normal": self.metric_normal,
                "limit": leverage_limit(len(self.metric_normal), float(self.moments.count)),
            }
            self.passes = 0
            return False
        left_out = int(self.metric_left_out)
        if left_out:
            self.notes.append(gross_outlier_note(left_out, self.rows_read))
        offset = self.centre + ellipsoid.centre @ self.affine_shape
        self.store(metric_shape(self.affine_shape, ellipsoid.gram), offset)
        matrix = self.calibration_matrix()
        motion_gram = matrix @ self.moments.cross_about(offset) @ matrix.T
        self.coverage = require_coverage(motion_gram, float(self.moments.count), self.data.magnitude)
        self.orient()
        self.closed_form_scale = float(torch.linalg.matrix_norm(self.shape.detach(), ord=2))
        self.acceleration = AndersonAcceleration(history=ANDERSON_HISTORY)
        self.converged = self.refinement == "closed_form"
        return True

    def orient(self) -> None:
        """Procrustes onto the known loads (mirror picked by the hint row with ``n - 1`` of them); without them, the
        channels' own frame where there are as many as axes (:meth:`turn_to_channels`)."""
        self.frame_fixed = len(self.known) > 0
        if not self.frame_fixed:
            self.turn_to_channels()
            return
        hint = self.data.mirror_hint
        hint_motion = self.motion_of(self.data.hint_reading[None]) if hint is not None else None
        rotation = frame_rotation(
            self.motion_of(self.known_readings()), self.known_loads(), hint_motion, hint,
            readings_rank_gap(self.singular_values, self.rank),
        )
        self.shape.copy_(rotation.T @ self.shape)

    def solve_alternation(self) -> None:
        """One alternation round from this pass's sums, Anderson-mixed with the rounds before."""
        solution = torch.linalg.solve(self.design_gram, self.design_readings)
        offset = solution[self.rank] + self.data.shift if self.estimate_offset else torch.zeros_like(self.data.shift)
        shape = solution[: self.rank]
        if len(self.known):
            shape = known_load_rotation(self.known_readings() - offset, self.known_loads(), shape, self.data.magnitude) @ shape
        mapped = self.dimensionless(shape, offset)
        current = torch.cat([self.shape.detach(), self.offset.detach()[None]])
        mixed = self.acceleration.step(current, mapped)
        self.shape.copy_(mixed[: self.rank])
        self.offset.copy_(mixed[self.rank])
        self.converged = self.acceleration.step_norm <= self.tolerance * float(current.norm())

    def dimensionless(self, shape: torch.Tensor, offset: torch.Tensor) -> torch.Tensor:
        """``[S; o]`` (physical) in the parameters' units, ``(n + 1) x p``."""
        return torch.cat([shape * self.load_scale / self.reading_scale, (offset / self.reading_scale)[None]])

    def store(self, shape: torch.Tensor, offset: torch.Tensor) -> None:
        """Write a physical solution into the parameters in place (the strategy holds them)."""
        solution = self.dimensionless(shape, offset)
        self.shape.copy_(solution[: self.rank])
        self.offset.copy_(solution[self.rank])

    # -- reporting --------------------------------------------------------------------------------

    def monitor(self) -> dict[str, float]:
        if self.passes <= 2:
            return {}
        return {
            "train/residual_rms": float((self.residual_squares.sum() / (self.rows_read * len(self.data.channels))).sqrt()),
            "train/alternation_step": self.acceleration.step_norm,
        }

    @property
    def fit_failed(self) -> bool:
        return bool(self.fit_problems())

    def fit_problems(self) -> list[str]:
        """Why the answer and error bars are not to be trusted: the alternation ran away, or the SNR is too low for
        the alternation or the closed form."""
        remedy = "calibrate in memory with experiment=calibrate_csv (its auto refinement avoids the bias)"
        if self.refinement == "closed_form" and self.passes >= 2:
            snr = self.closed_form_signal_to_noise()
            return [low_snr_warning(snr, remedy, "closed form")] if snr < ALTERNATION_BIASED_BELOW_SNR else []
        if self.passes <= 2:
            return []
        growth = shape_growth(self.shape.detach(), self.closed_form_scale)
        if growth > (RUNAWAY_GROWTH if self.converged else GROWTH_WHILE_UNCONVERGED):
            remedy = "more passes will not help; calibrate in memory with experiment=calibrate_csv (its auto refinement "
            return [runaway_warning(growth, remedy + "takes the marginal likelihood at low SNR) or keep model.refinement=closed_form")]
        snr = self.direction_snr()
        if snr < ALTERNATION_BIASED_BELOW_SNR:
            return [low_snr_warning(snr, remedy)]
        return []

    def alternation_bias(self) -> float | None:
        """:func:`~sfmnet.linalg.uncertainty.alternation_bias` at a direction's SNR (a pose mean's where tied), once the
        alternation has run; None for the closed form."""
        if self.refinement == "closed_form" or self.passes <= 2:
            return None
        return alternation_bias(self.physical_shape(), self.direction_snr())

    def direction_snr(self) -> float:
        """A fitted direction's SNR: a row's (:meth:`signal_to_noise`) or, tied, a pose mean's, ``sqrt(rows per
        direction)`` times sharper; the alternation's bias goes by it (method §5)."""
        return self.signal_to_noise() * math.sqrt(self.rows_per_direction)

    def closed_form_signal_to_noise(self) -> float:
        """``F |s| / noise`` after the closed form alone, the noise from the readings' scatter off the load space.

        The last ``p - n`` squared singular values of the readings (pass 1's) hold noise only, ``f (p - n) sigma^2``
        in all; with ``p = n`` there are none and the SNR is not measured (infinite).
        """
        p, n = len(self.data.channels), self.rank
        if p == n:
            return math.inf
        noise = float((self.singular_values[n:].pow(2).sum() / (self.moments.count * (p - n))).sqrt())
        if noise == 0:
            return math.inf
        return self.signal_to_noise_at(self.data.magnitude, noise)

    def signal_to_noise(self) -> float:
        """``F |s| / noise`` with the noise from the last pass's residuals (:func:`residual_noise_variance`, a free direction per
        unknown row), as ``ShapeFromMotion`` judges it by."""
        p, n = len(self.data.channels), self.rank
        variance = residual_noise_variance(
            float(self.residual_squares.sum()), self.rows_read * p, self.free_directions, n, (n + self.estimate_offset) * p
        )
        return self.signal_to_noise_at(self.data.magnitude, math.sqrt(variance))

    def estimator_description(self) -> dict[str, Any]:
        """The streamed refinement that ran, for the calibration file."""
        return {"refinement": self.refinement, "tied_directions": self.tied_fit}

    @property
    def fit_warnings(self) -> list[str]:
        problems = self.fit_problems()
        if not (problems or self.converged):
            step = self.acceleration.step_norm
            problems = [
                f"the alternation had not converged after {self.passes} passes (last step {step:.1e}, "
                f"relative tolerance {self.tolerance:g}): raise trainer.max_epochs"
            ]
        return [*super().fit_warnings, *problems]

    def report_recording(self, recording: StreamedRecording) -> CalibrationRecording:
        """The sampled rows (every ``stride``-th) and the known-load rows, in memory, for error bars, figures and the
        goodness of fit; grouped by their static intervals (the poses they were held in), where the stream has them."""
        if self.passes < 2:
            raise SfmnetError(
                f"a streamed calibration needs two passes for its closed form (moments, then the metric constraint) "
                f"but ran {self.passes}: set trainer.max_epochs to 2 or more"
            )
        p, n = len(self.data.channels), self.rank
        sampled = self.sample[torch.isnan(self.sample[:, p : p + n]).any(dim=1)]
        groups = None
        if self.data.intervals is not None:
            groups = torch.cat([sampled[:, p + n].long() - 1, self.interval_of(self.known[:, 0].long())])
        return CalibrationRecording(
            readings=torch.cat([sampled[:, :p] + self.data.shift, self.known_readings()]),
            loads=torch.cat([sampled[:, p : p + n], self.known_loads()]),
            magnitude=self.data.magnitude,
            groups=groups,
        )

    @property
    def tied_fit(self) -> bool:
        """Whether the fit reported tied each static interval's rows to one direction (an alternation pass ran tied)."""
        return self.tied and self.passes > 2

    def unknown_directions(self, recording: CalibrationRecording) -> tuple[torch.Tensor, torch.Tensor]:
        magnitude = self.data.magnitude
        unknown = ~recording.known
        centred = recording.readings[unknown] - self.physical_offset()
        tied = self.tied_fit and recording.groups is not None
        interval = recording.groups[unknown] if tied else torch.full((len(centred),), -1, dtype=torch.long)
        directions = self.row_directions(centred, interval, self.interval_directions() if tied else None)
        n = self.rank
        return directions, magnitude * torch.eye(n, dtype=directions.dtype).expand(len(directions), n, n)

    def unknown_poses(self, recording: CalibrationRecording) -> torch.Tensor | None:
        """The sample's unknown rows' static intervals where the fit tied them (a row outside every interval its own
        pose); None untied."""
        if not self.tied_fit or recording.groups is None:
            return None
        poses = recording.groups[~recording.known].clone()
        outside = poses < 0
        poses[outside] = self.intervals + torch.arange(int(outside.sum()))
        return poses

    @property
    def unknown_rows_streamed(self) -> int:
        """Rows streamed (motion left out) whose load is unknown."""
        return self.rows_read - len(self.known)

    def tied_direction_rows(self) -> torch.Tensor:
        """Tied, the unknown rows (every row streamed, not the sample's) behind each direction the fit solved for: a
        static interval's that holds any, then one for each unknown row outside every interval."""
        known = self.interval_of(self.known[:, 0].long())
        known_rows = torch.bincount(known[known >= 0], minlength=self.intervals).to(self.interval_readings.dtype)
        per_interval = self.interval_readings[:, 0] - known_rows
        outside = max(self.unknown_rows_streamed - int(per_interval.sum()), 0)
        return torch.cat([per_interval[per_interval > 0], per_interval.new_ones(outside)])

    @property
    def free_directions(self) -> float:
        """The directions the fit solved for: one per unknown row, or tied, one per static interval holding unknown
        rows and one per unknown row outside them."""
        return float(len(self.tied_direction_rows())) if self.tied_fit else float(self.unknown_rows_streamed)

    @property
    def rows_per_direction(self) -> float:
        """Unknown rows per fitted direction (:func:`~sfmnet.linalg.group_means.harmonic_mean_rows`); 1 untied."""
        rows = self.tied_direction_rows() if self.tied_fit else None
        return harmonic_mean_rows(rows) if rows is not None and len(rows) else 1.0

    def unknown_row_weight(self, recording: CalibrationRecording) -> float:
        """The sample's unknown rows (:meth:`report_recording`) stand for every unknown row streamed."""
        return self.unknown_rows_streamed / int((~recording.known).sum())

    def uncertainty(
        self, recording: CalibrationRecording, loads: torch.Tensor, unknown: UnknownRows | None = None
    ) -> CalibrationUncertainty:
        """Cramer-Rao standard errors with the sampled rows standing for every unknown-load row.

        The noise comes from the last alternation pass's residuals over every row (from the
        sample, scaled, after the closed form alone).
        """
        directions, maps = self.unknown_directions(recording) if unknown is None else unknown
        weight = self.unknown_row_weight(recording)
        if self.passes > 2:
            residual = float(self.residual_squares.sum())
        else:
            fitted = self.fitted_residuals(recording, loads).pow(2).sum(dim=1)
            residual = float(fitted[~recording.known].sum()) * weight + float(fitted[recording.known].sum())
        return calibration_uncertainty(
            self.physical_shape(), loads[recording.known], directions, maps, self.estimate_offset,
            residual_sum_of_squares=residual, observations=self.rows_read * len(self.data.channels),
            unknown_weight=weight, free_directions=self.free_directions,
        )

    def residual_rms(self, recording: CalibrationRecording, loads: torch.Tensor | None = None) -> float:
        """Over every row (not the sample ``recording``, ``loads`` unused): the last alternation pass's residuals
        ``Z - M S - o`` (the fitted, constrained loads); after the closed form alone, exact from the moments but
        only off the row space of ``S``."""
        if self.passes > 2:
            return float((self.residual_squares.sum() / (self.rows_read * len(self.data.channels))).sqrt())
        shape = self.physical_shape()
        complement = torch.eye(shape.shape[1], dtype=shape.dtype) - shape.T @ torch.linalg.solve(shape @ shape.T, shape)
        residual = torch.trace(complement @ self.moments.cross_about(self.physical_offset()) @ complement)
        return float((residual.clamp_min(0) / (self.moments.count * shape.shape[1])).sqrt())


def gather_by_rank(strategy, value: torch.Tensor) -> torch.Tensor:
    """Every process's ``value`` (``k``), stacked ``world x k``, through the strategy's sum."""
    world, rank = getattr(strategy, "world_size", 1), getattr(strategy, "global_rank", 0)
    slots = torch.zeros(world, *value.shape, dtype=value.dtype)
    slots[rank] = value
    return strategy.reduce(slots, reduce_op="sum")


def gather_rows(strategy, blocks: list[torch.Tensor], width: int, limit: int) -> torch.Tensor:
    """Rows collected by every process (each a ``r x width`` list, first column the row index), sorted by that index.

    Each process writes its rows into its own range of one buffer and the strategy sums the
    buffers: exact, with no collective beyond the sum every statistic uses.
    """
    mine = torch.cat(blocks) if blocks else torch.zeros(0, width, dtype=torch.float64)
    counts = gather_by_rank(strategy, torch.tensor([float(len(mine))]))[:, 0].long()
    total = int(counts.sum())
    if total > limit:
        raise SfmnetError(
            f"{total} rows have known loads (model.max_known_rows is {limit}): shape from motion needs only a few; "
            "with every load known, fit least squares in memory (experiment=calibrate_csv model=least_squares)"
        )
    start = int(counts[: getattr(strategy, "global_rank", 0)].sum())
    buffer = torch.zeros(total, width, dtype=torch.float64)
    buffer[start : start + len(mine)] = mine
    buffer = strategy.reduce(buffer, reduce_op="sum")
    return buffer[torch.argsort(buffer[:, 0])]
