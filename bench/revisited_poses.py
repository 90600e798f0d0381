"""Drift over a recording, and what a revisited pose lets the goodness of fit see of it. Run by hand:

    python bench/revisited_poses.py [--sessions 6]

Sessions of the package's continuous-recording simulator (sfmnet/simulators/simulated_stream.py): a 3-axis sensor of
3 or 6 channels, 1 kg held at 12 poses for 2 s each (3 of them known loads set by a jig) and then at the first pose
again, logged at 100 or 25 Hz while held (the rows in motion are not logged), white noise 1 % or 3 % of a channel's
full-load signal. Over the recording the sensor's gain grows by 1 %, or its offsets move by 1 % of each channel's
full-load signal, or neither. Each session is calibrated twice through ``sfmnet.calibrate`` with its time column:
with the pose labels (``poses``, ``data.group_column``: the revisit tied to the first hold, and the two compared,
README "Goodness of fit") and without (each hold its own pose). Printed per row: the RMS over sessions of the matrix
error over the bars (Frobenius norms, the frame the known loads fix), how many sessions call their bars trustworthy,
and how many of those are over 2x their bars; for the labelled fit also what it called them before the revisit check
(the same run with that one warning set aside) and the range of ``goodness/revisit_z``; and the sessions refused (a
one-line error: known loads the readings cannot place, on the noisiest 3-gauge sensors).
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import warnings
from pathlib import Path

import numpy as np
import torch

import sfmnet
from sfmnet.calibration import calibration_matrix
from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor

MAGNITUDE = 9.81
REVISIT_WARNING = "reads differently at each visit"
CASES = [
    (channels, noise, rate, drift)
    for drift in ("none", "gain", "offset")
    for channels in (3, 6)
    for noise in (0.01, 0.03)
    for rate in (100.0, 25.0)
]


def session(seed: int, channels: int, noise: float, rate: float, drift: str):
    """A revisiting recording's held rows: readings, known loads, time, pose labels, and the true ``C``."""
    generator = torch.Generator().manual_seed(seed)
    sensor = stream_sensor(channels, MAGNITUDE, noise, 0.2, generator)
    recording = simulate_stream(
        sensor, MAGNITUDE / 9.80665, poses=12, rate=rate, revisit=True, generator=generator,
        gain_drift=0.01 if drift == "gain" else 0.0, offset_drift=0.01 if drift == "offset" else 0.0,
    )
    held = recording.static
    columns = (recording.readings, recording.known_loads, recording.time, recording.pose.double())
    return (*(column[held].numpy() for column in columns), calibration_matrix(sensor.shape).numpy())


def judged(calibration: sfmnet.Calibration, truth: np.ndarray) -> tuple[float, bool, bool]:
    """Squared error over squared bars, trusted, and trusted but for the revisit check."""
    error = np.asarray(calibration.matrix) - truth
    ratio = float((error**2).sum() / (np.asarray(calibration.matrix_std) ** 2).sum())
    trusted = calibration.error_bars_trustworthy
    others = [warning for warning in calibration.warnings if REVISIT_WARNING not in warning]
    return ratio, trusted, trusted or (bool(calibration.warnings) and not others)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--sessions", type=int, default=6)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    torch.set_num_threads(1)
    print(
        "| drift | channels | noise | rate | labelled: error / bars (RMS) | trusted (before the check) | trusted over 2x "
        "(before) | revisit z | unlabelled: error / bars | trusted | trusted over 2x | refused |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for channels, noise, rate, drift in CASES:
        labelled, unlabelled, z, refused = [], [], [], 0
        for seed in range(args.sessions):
            readings, known, time, poses, truth = session(seed, channels, noise, rate, drift)
            try:
                with tempfile.TemporaryDirectory() as run_dir:
                    fit = sfmnet.calibrate(readings, MAGNITUDE, known, time, poses, run_dir=run_dir)
                    z.append(json.loads((Path(run_dir) / "metrics.json").read_text())["goodness/revisit_z"])
                labelled.append(judged(fit, truth))
                unlabelled.append(judged(sfmnet.calibrate(readings, MAGNITUDE, known, time), truth))
            except sfmnet.SfmnetError:
                # A 3-gauge sensor of condition number 11 at 3 % noise cannot place its known loads: refused.
                refused += 1

        def cells(results: list[tuple[float, bool, bool]], before: bool) -> str:
            ratios = [r for r, _, _ in results]
            trusted = sum(t for _, t, _ in results)
            over = sum(t and r > 4 for r, t, _ in results)
            text = f"{math.sqrt(sum(ratios) / len(ratios)):.2f} | {trusted}"
            if before:
                text += f" ({sum(b for _, _, b in results)})"
            text += f" | {over}"
            if before:
                text += f" ({sum(b and r > 4 for r, _, b in results)})"
            return text

        print(
            f"| {drift} | {channels} | {100 * noise:g} % | {rate:g} Hz | {cells(labelled, True)} | "
            f"{min(z):.1f} to {max(z):.1f} | {cells(unlabelled, False)} | {refused} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
