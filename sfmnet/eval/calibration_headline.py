"""The few lines under a calibration's headline that say how far to trust it, on a user's own data too.

They need no reference sensor: the channels fitted, how much of the load space the samples
visited, the residuals in load units, the known loads' misfit and whether the error bars can be
believed (every goodness-of-fit check passed). The figures are those of ``metrics.json``.
"""

from __future__ import annotations

import math
from typing import Any

from sfmnet.eval.diagnostics import WARN_COVERAGE

# Channel names listed in full up to this many characters; beyond, the first ones and a count.
CHANNELS_WIDTH = 70
# From this share of the bars' variance the known-load frame, not the orientations, is what limits the calibration.
FRAME_DOMINATES = 0.5


def trust_lines(
    metrics: dict[str, float],
    channels: list[str],
    load_unit: str,
    magnitude: float,
    axes: int,
    estimator: dict[str, Any] | None = None,
    warnings: int = 0,
) -> list[str]:
    """Indented lines: channels, the refinement, coverage, residuals (load and raw units), known loads, error bars.

    Args:
        metrics: the method's metrics (``coverage``, ``residual_rms``, ``load_residual/*``, ``goodness/*``, ...).
        channels: the channels fitted; load_unit: ``"N"``, or ``"N, N m"`` for force and torque.
        magnitude: ``F``, the calibration load's constant magnitude (load units); NaN where there is none.
        axes: ``n``, the load axes.
        estimator: the calibration file's account of the refinement (``refinement``, ``direction_snr``, ...).
        warnings: how many warnings follow the lines; with trustworthy bars the line says they are about the data
            (coverage, rank gap) or the estimator chosen, not the bars.
    """
    force_unit, _, torque_unit = load_unit.partition(", ")
    lines = [f"channels     {channel_list(channels)}"]
    if estimator and "refinement" in estimator:
        lines.append(f"refinement   {refinement_words(estimator)}")
    if "coverage" in metrics:
        space = "circle" if axes == 2 else "sphere"
        lines.append(
            f"coverage     {metrics['coverage']:.2f}: how evenly the load directions span every axis (1 = the whole "
            f"{space} or as even; {'a quarter circle about 0.6, one line 0' if axes == 2 else 'one plane 0'}; below "
            f"{WARN_COVERAGE:g} warns)"
        )
    if "load_residual/force_rms" in metrics:
        residual = f"{metrics['load_residual/force_rms']:.4g} {force_unit} RMS in load units"
        if math.isfinite(magnitude) and magnitude > 0 and torque_unit == "":
            residual += f" ({100 * metrics['load_residual/force_rms'] / magnitude:.3g} % of F = {magnitude:g} {force_unit})"
        if "load_residual/torque_rms" in metrics:
            residual += f", torque {metrics['load_residual/torque_rms']:.4g} {torque_unit} RMS"
        lines.append(f"residuals    {residual}; {metrics['residual_rms']:.4g} raw units RMS per channel")
    if "goodness/known_load_rms" in metrics:
        percent = f" ({metrics['goodness/known_load_pct']:.3g} % of their size)" if "goodness/known_load_pct" in metrics else ""
        distance = f"{metrics['goodness/known_load_rms']:.4g} {load_unit} RMS per axis"
        if "goodness/known_load_torque_rms" in metrics:
            percent = ""  # a percentage of a size mixing N and N m says nothing
            distance = (
                f"{metrics['goodness/known_load_force_rms']:.4g} {force_unit} RMS per force axis and "
                f"{metrics['goodness/known_load_torque_rms']:.4g} {torque_unit} per torque axis"
            )
        lines.append(
            f"known loads  {distance} from where the calibration puts them"
            f"{percent}, {metrics['goodness/known_load_ratio']:.2g}x what the noise explains"
        )
        if "matrix_std_frame_share" in metrics:
            lines.append(frame_line(metrics["matrix_std_frame_share"], int(metrics["known_load_rows"])))
    elif estimator and str(estimator.get("frame", "")).startswith("channels"):
        lines.append(
            "known loads  none given: the load frame is the channels' own, each axis nearest its channel (magnitudes are right)"
        )
    else:
        lines.append("known loads  none given: the load frame is arbitrary (magnitudes are right)")
    if metrics.get("error_bars_trustworthy", 1.0):
        caveat = ""
        if warnings:
            caveat = f"; the {warnings} warning{'s' if warnings > 1 else ''} below: about the data or the estimator chosen, not the bars"
        lines.append(f"error bars   trustworthy: every goodness-of-fit check passed{caveat}")
    else:
        lines.append("error bars   NOT TRUSTWORTHY: a goodness-of-fit check or the fit failed (the warnings say which)")
    return [f"    {line}" for line in lines]


def frame_line(share: float, rows: int) -> str:
    """Where the error bars come from: the frame the known-load rows set, or the shape the orientations give."""
    words = f"frame        the {rows} known-load row{'s' if rows > 1 else ''} set{'' if rows > 1 else 's'} it: {100 * share:.0f} % of the error bars' variance"
    if share >= FRAME_DOMINATES:
        return words + " (more readings of the known loads shrink the bars; more orientations barely do)"
    return words + " (the rest is the shape the orientations give)"


def refinement_words(estimator: dict[str, Any]) -> str:
    """``marginal (direction SNR 3.1, directions tied to poses), law of directions learnt: nonparametric``."""
    details = []
    if "direction_snr" in estimator:
        details.append(f"direction SNR {estimator['direction_snr']:.3g}")
    if estimator.get("tied_directions"):
        details.append("directions tied to poses")
    words = estimator["refinement"] + (f" ({', '.join(details)})" if details else "")
    if "laws_learnt" in estimator:
        words += f", law of directions learnt: {', '.join(sorted(set(estimator['laws_learnt'])))}"
    return words


def channel_list(channels: list[str]) -> str:
    """``a, b, c (3)``, or the first names that fit :data:`CHANNELS_WIDTH` and how many more."""
    shown: list[str] = []
    for name in channels:
        if len(", ".join([*shown, name])) > CHANNELS_WIDTH:
            break
        shown.append(name)
    more = f", ... and {len(channels) - len(shown)} more" if len(shown) < len(channels) else ""
    return f"{', '.join(shown)}{more} ({len(channels)} channels)"
