"""Do the goodness-of-fit checks disown the error bars exactly when they fail? Run by hand:

    python bench/goodness_checks.py [--sessions 6] [--only sweep-drift shuffled-drift ...]

Random sessions outside the package's simulators, calibrated through the public API (``sfmnet.calibrate``, the
alternation, no time column; no known loads unless a case says so) as a user without holds would: a random ``3 x p``
shape and offsets, one 1 kg mass, white noise 1 % of the signal per channel unless a case says otherwise. The
orientations either sweep continuously (a 100 Hz path over most of the sphere, 6,000 rows; ``short sweep``: the same
path logged 200 times over a minute), are drawn uniform at random (3,000 rows), or turn about one tilted axis
(``turntable``, one great circle, 600 rows; ``circle30``, ``circle45``: one circle 30 or 45 degrees off the turntable's
plane), or turn about two random axes in turn (``two circles``: two great circles of 300 rows each, an accelerometer
turned about two axes). The ``known`` cases put three known poses along the axes first (a row each; 20 each on the turntable and the
circles), noise 0.5 % of each channel's span, 600 rows. Each case is clean or carries one
defect:

- ``drift``: each channel's offset drifts 1 % of its full scale over the recording;
- ``warming``: one channel's gain drifts 3 % over the recording (warming up), the truth the sensor at its end, as it will
  be used;
- ``nonlinear``: each channel 0.5 % of its full scale from linear (a square law);
- ``shuffled``: the sweep's rows given in random order (recording order then says nothing);
- ``spread10``: each channel's noise drawn log-uniform over a factor 10 (RMS kept), 8 channels (``-p5``, ``-p4``, ``-p3``:
  5, 4 or 3);
- ``glitch``: ten rows (the 101st to the 110th) each channel 10 of its noise's standard deviations up;
- ``gains``: three of the 8 channels amplified 10x (they carry most of the load), every channel's noise 0.5 % of its
  span (an amplifier's noise grows with its gain);
- ``slip``: the last 30 % of the rows 2 % light;
- ``quantised``: held at 30 poses x 100 rows, read in counts 10x the noise, 3 channels;
- ``mass``: the mass 1 % heavier than the magnitude given (the known loads its true ones).

Printed per case: sessions, how many the run trusts, the matrix error over its bars (Frobenius norms, the truth turned
into the fit's arbitrary frame, or as it is where known loads fix the frame; 1 if the bars are right), and the count
of silent failures (trusted at more than 2x the bars), false alarms (a clean case disowned) and refusals (the error
ranges over the sessions fitted). The checks at stake are README's goodness-of-fit table: serial and neighbour misfit,
channel noise (constraint and outliers), the serial check's quantisation, the known loads' scale and the unknown rows'
coverage, about the origin and about their mean.
"""

from __future__ import annotations

import argparse
import math
import warnings
from typing import NamedTuple

import numpy as np
import torch

import sfmnet
from sfmnet.calibration import calibration_matrix
from sfmnet.errors import SfmnetError
from sfmnet.linalg.frame import orthogonal_procrustes
from sfmnet.simulators.simulation import circle_directions

MAGNITUDE = 9.81


class Case(NamedTuple):
    name: str
    orientations: str  # "sweep", "uniform" or "poses"
    channels: int
    defect: str  # "" or one of the module docstring's


CASES = (
    Case("sweep", "sweep", 6, ""),
    Case("sweep-drift", "sweep", 6, "drift"),
    Case("sweep-nonlinear", "sweep", 6, "nonlinear"),
    Case("sweep-warming", "sweep", 6, "warming"),
    Case("shuffled", "sweep", 6, "shuffled"),
    Case("shuffled-drift", "sweep", 6, "shuffled drift"),
    Case("shuffled-nonlinear", "sweep", 6, "shuffled nonlinear"),
    Case("uniform", "uniform", 8, ""),
    Case("uniform-nonlinear", "uniform", 8, "nonlinear"),
    Case("uniform-warming", "uniform", 8, "warming"),
    Case("shuffled-warming", "uniform", 8, "shuffled warming"),
    Case("spread10", "uniform", 8, "spread10"),
    Case("spread10-slip", "uniform", 8, "spread10 slip"),
    Case("spread10-p5", "uniform", 5, "spread10"),
    Case("spread10-p5-slip", "uniform", 5, "spread10 slip"),
    Case("spread10-p4", "uniform", 4, "spread10"),
    Case("spread10-p3", "uniform", 3, "spread10"),
    Case("spread10-p3-glitch", "uniform", 3, "spread10 glitch"),
    Case("uniform-p3-glitch", "uniform", 3, "glitch"),
    Case("gains", "uniform", 8, "gains"),
    Case("gains-slip", "uniform", 8, "gains slip"),
    Case("poses", "poses", 3, ""),
    Case("poses-quantised", "poses", 3, "quantised"),
    Case("short-sweep", "short sweep", 6, ""),
    Case("short-sweep-drift", "short sweep", 6, "drift"),
    Case("known", "known uniform", 6, ""),
    Case("known-mass", "known uniform", 6, "mass"),
    Case("turntable", "known turntable", 6, ""),
    Case("circle30", "known circle 0.5", 6, ""),
    Case("circle45", "known circle 0.707", 6, ""),
    Case("two-circles", "two circles", 3, ""),
    Case("two-circles-p6", "two circles", 6, ""),
)

KNOWN_DIRECTIONS = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def session(case: Case, seed: int) -> tuple[np.ndarray, np.ndarray | None, torch.Tensor]:
    """One session's readings (``f x p``), known loads (``f x 3``, NaN where unknown; None without) and true ``C``."""
    generator = np.random.default_rng(seed)
    shape, offset = generator.normal(size=(3, case.channels)), generator.normal(size=case.channels) * 5
    if "gains" in case.defect:
        shape[:, :3] *= 10
    if case.orientations.startswith("known"):
        return known_session(case, generator, shape, offset)
    if case.orientations in ("sweep", "short sweep"):
        time = np.arange(6000) / 100 if case.orientations == "sweep" else np.arange(200) * 0.3
        elevation = 1.2 * np.sin(0.31 * time + generator.uniform(0, 2 * np.pi))
        azimuth = 0.47 * time
        directions = np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth), np.sin(elevation)], 1)
    elif case.orientations == "two circles":
        axes = generator.normal(size=(2, 3))
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        directions = np.concatenate([circle_directions(generator.uniform(0, 2 * np.pi, 300), axis) for axis in axes])
    else:
        directions = generator.normal(size=(30 if case.orientations == "poses" else 3000, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        if case.orientations == "poses":
            directions = np.repeat(directions, 100, axis=0)
    loads = MAGNITUDE * directions
    rows = len(loads)
    if "slip" in case.defect:
        loads[int(0.7 * rows):] *= 0.98
    linear = loads @ shape
    scale = np.abs(linear).max(axis=0)
    readings = linear + offset
    if "drift" in case.defect:
        readings += np.outer(np.arange(rows) / (rows - 1), 0.01 * scale * generator.choice([-1, 1], size=case.channels))
    if "nonlinear" in case.defect:
        readings += 0.005 * linear**2 / scale
    if "warming" in case.defect:
        drifting = generator.integers(case.channels)
        readings[:, drifting] += 0.03 * (np.arange(rows) / (rows - 1) - 1) * linear[:, drifting]
    noise = np.full(case.channels, 0.01 * MAGNITUDE * np.linalg.norm(shape) / math.sqrt(3 * case.channels))
    if "spread10" in case.defect:
        factors = np.exp(generator.uniform(0, math.log(10), size=case.channels))
        noise *= factors / np.sqrt(np.mean(factors**2))
    if "gains" in case.defect:
        noise = 0.005 * scale
    readings += generator.normal(size=readings.shape) * noise
    if "glitch" in case.defect:
        readings[100:110] += 10 * noise
    if "quantised" in case.defect:
        step = 10 * noise.mean()
        readings = step * np.round(readings / step)
    if "shuffled" in case.defect:
        readings = readings[generator.permutation(rows)]
    return readings, None, calibration_matrix(torch.from_numpy(shape))


def known_session(
    case: Case, generator: np.random.Generator, shape: np.ndarray, offset: np.ndarray
) -> tuple[np.ndarray, np.ndarray, torch.Tensor]:
    """A ``known`` case's session (:func:`session`): three known poses, then 600 rows uniform or on one circle (a
    turntable's great circle, or ``known circle h``: the directions ``h`` along its axis)."""
    if case.orientations == "known turntable" or case.orientations.startswith("known circle"):
        height = float(case.orientations.split()[-1]) if case.orientations.startswith("known circle") else 0.0
        axis = np.array([0.2, 0.1, 1.0]) / np.linalg.norm([0.2, 0.1, 1.0])
        directions = circle_directions(generator.uniform(0, 2 * np.pi, 600), axis, height)
        known = np.repeat(KNOWN_DIRECTIONS, 20, axis=0)
    else:
        directions = generator.normal(size=(600, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        known = KNOWN_DIRECTIONS
    loads = MAGNITUDE * (1.01 if case.defect == "mass" else 1.0) * np.concatenate([known, directions])
    linear = loads @ shape
    readings = linear + offset + generator.normal(size=linear.shape) * 0.005 * np.abs(linear).max(axis=0)
    given = np.full_like(loads, np.nan)
    given[: len(known)] = loads[: len(known)]
    return readings, given, calibration_matrix(torch.from_numpy(shape))


def bars_ratio(calibration: sfmnet.Calibration, truth: torch.Tensor, frame_fixed: bool) -> float:
    """The matrix error over its bars; without known loads (``frame_fixed`` False) the truth turned into the fit's
    frame, which nothing fixes."""
    matrix = calibration.matrix.to(truth.dtype)
    turn = torch.eye(3, dtype=truth.dtype) if frame_fixed else orthogonal_procrustes(truth.T, matrix.T)
    return float((turn.T @ truth - matrix).norm() / calibration.matrix_std.to(truth.dtype).norm())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=6)
    parser.add_argument("--only", nargs="*", help="case names (default: all)")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    print("| case | sessions | trusted | error / bars | silent failures | false alarms | refused |")
    print("|---|---|---|---|---|---|---|")
    for case in CASES:
        if args.only and case.name not in args.only:
            continue
        trusted, ratios, refused = [], [], 0
        for seed in range(args.sessions):
            readings, loads, truth = session(case, seed)
            try:
                calibration = sfmnet.calibrate(readings, MAGNITUDE, loads, axes=3, **{"model.refinement": "alternation"})
            except SfmnetError:
                refused += 1
                continue
            trusted.append(calibration.error_bars_trustworthy)
            ratios.append(bars_ratio(calibration, truth, loads is not None))
        silent = sum(t and r > 2 for t, r in zip(trusted, ratios))
        # Shuffling alone is no defect; one or two circles of orientations are one, though the case names none.
        clean = case.defect in ("", "shuffled", "spread10", "gains") and "circle" not in case.orientations and case.name != "turntable"
        false_alarms = sum(not t for t in trusted) + refused if clean else 0
        span = f"{min(ratios):.2f}-{max(ratios):.2f}" if ratios else "-"
        print(
            f"| {case.name} | {args.sessions} | {sum(trusted)} | {span} | {silent} | {false_alarms} | {refused} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
