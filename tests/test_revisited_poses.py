"""Pose labels on a continuous recording: a pose held more than once is checked for drift between its holds
(sfmnet/preprocessing/revisited_poses.py), and rows of a static interval left unlabelled are tied to it."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import torch

import sfmnet
from sfmnet.calibration import calibration_matrix
from sfmnet.eval.goodness_of_fit import REVISIT_Z
from sfmnet.preprocessing.revisited_poses import hold_ids, revisited_poses
from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor
from sfmnet.training.run import train
from tests.conftest import compose_config

def pose_sequence(rows: int) -> np.ndarray:
    """12 poses of ``rows`` rows each, then poses 0 and 5 held again."""
    return np.repeat(np.r_[np.arange(12), 0, 5].astype(float), rows)


def held_readings(
    generator: np.random.Generator, labels: np.ndarray, drift: float = 0.0, correlation: float = 0.0
) -> np.ndarray:
    """Three channels of unequal noise (AR(1) of lag-one ``correlation``) about each pose's reading, plus ``drift``
    times the row's fraction of the recording on every channel."""
    truth = generator.normal(size=(12, 3)) * 10
    white = generator.normal(size=(len(labels), 3))
    noise = white.copy()
    for row in range(1, len(noise)):
        noise[row] = correlation * noise[row - 1] + np.sqrt(1 - correlation**2) * white[row]
    ramp = np.linspace(0, 1, len(labels))[:, None]
    return truth[labels.astype(int)] + noise * np.array([1.0, 2.0, 0.5]) + drift * ramp


def test_holds_are_runs_of_one_label_within_one_interval():
    labels = np.array([3.0, 3, 3, 7, 7, 3, 3, np.nan, np.nan])
    assert hold_ids(labels, None).tolist() == [0, 0, 0, 1, 1, 2, 2, 3, 4]
    # A static interval ending between two rows of one label splits the hold.
    intervals = np.array([0, 0, 1, 1, 1, 1, 1, 2, 2])
    assert hold_ids(labels, intervals).tolist() == [0, 0, 1, 2, 2, 3, 3, 4, 5]


def test_holds_that_differ_by_noise_alone_pass_and_a_drift_is_caught():
    generator = np.random.default_rng(0)
    labels = pose_sequence(50)
    holds = hold_ids(labels, None)
    z = np.array([revisited_poses(held_readings(generator, labels), labels, holds).z for _ in range(200)])
    # Under white noise z is near standard normal (a little under it: the noise's correlation, measured from the holds,
    # counts as at least 1): the limit leaves about 1 run in 1,000 flagged.
    assert abs(z.mean()) < 0.3 and 0.7 < z.std() < 1.2 and (z > REVISIT_Z).sum() <= 1
    figures = revisited_poses(held_readings(generator, labels, drift=2.0), labels, holds)
    assert figures.z > REVISIT_Z and figures.poses == 2 and figures.holds == 4 and figures.dof == 6
    # Pose 0 spans the whole recording, so it moved furthest.
    assert figures.worst_pose == "0" and figures.worst_starts == [0, 600]


def test_noise_correlated_within_a_hold_is_not_taken_for_drift():
    """AR(0.8) noise: a hold's mean varies about 9x what its rows' scatter says. Measured over the holds, that is
    scaled out; the same figure taken as white noise calls it drift in most sessions."""
    generator = np.random.default_rng(1)
    labels = pose_sequence(200)
    holds = hold_ids(labels, None)
    readings = [held_readings(generator, labels, correlation=0.8) for _ in range(20)]
    z = [revisited_poses(r, labels, holds).z for r in readings]
    assert max(z) < REVISIT_Z
    with mock.patch("sfmnet.preprocessing.revisited_poses.noise_correlation", lambda *_: (np.ones(3), 0)):
        white = [revisited_poses(r, labels, holds).z for r in readings]
    assert np.mean(np.array(white) > REVISIT_Z) > 0.5


def test_no_pose_held_twice_gives_no_figures():
    labels = np.repeat(np.arange(12.0), 50)
    readings = np.random.default_rng(2).normal(size=(len(labels), 3))
    assert revisited_poses(readings, labels, hold_ids(labels, None)) is None


def revisiting_stream(drift: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 3-channel sensor (p = n) held at 12 poses and the first again at the end, its gain drifting by ``drift``
    over the recording; the rows in motion are not logged. Readings, known loads, time and pose labels."""
    generator = torch.Generator().manual_seed(0)
    sensor = stream_sensor(3, 9.81, 0.01, 0.2, generator)
    recording = simulate_stream(sensor, 1.0, poses=12, rate=50.0, revisit=True, gain_drift=drift, generator=generator)
    static = recording.static
    return (
        recording.readings[static].numpy(), recording.known_loads[static].numpy(), recording.time[static].numpy(),
        recording.pose[static].numpy().astype(float),
    )


@pytest.mark.parametrize("drift", [0.0, 0.01])
def test_a_drift_hidden_by_tying_a_revisited_pose_is_flagged(drift: float):
    readings, loads, time, poses = revisiting_stream(drift)
    labelled = sfmnet.calibrate(readings, 9.81, loads, time, poses)
    drift_warnings = [warning for warning in labelled.warnings if "reads differently at each visit" in warning]
    if drift:
        # Tied into one pose, the revisit's drift passes every other check: only this one sees it.
        assert drift_warnings == labelled.warnings and not labelled.error_bars_trustworthy
        assert "pose 0 (holds starting at 1.5 s, 43.5 s)" in drift_warnings[0]
    else:
        assert labelled.error_bars_trustworthy and not labelled.warnings


def test_unlabelled_rows_at_the_edges_of_a_hold_are_tied_to_it():
    """The simulator labels only the rows it held still; the detector's intervals reach a row or two into each move.
    Each such row a pose of its own, one row per direction, had pulled `auto` to the marginal on this 3-channel
    sensor: 26x its bars (flagged) where the same stream without labels is 0.67x."""
    generator = torch.Generator().manual_seed(3)
    sensor = stream_sensor(3, 9.81, 0.01, 0.2, generator)
    recording = simulate_stream(sensor, 1.0, poses=12, rate=50.0, generator=generator)
    labels = recording.pose.double().numpy()
    labels[labels < 0] = np.nan
    arrays = (recording.readings.numpy(), 9.81, recording.known_loads.numpy(), recording.time.numpy())
    unlabelled, labelled = sfmnet.calibrate(*arrays), sfmnet.calibrate(*arrays, labels)
    truth = calibration_matrix(sensor.shape)
    errors = [float((calibration.matrix - truth).norm() / calibration.matrix_std.norm()) for calibration in (unlabelled, labelled)]
    assert labelled.error_bars_trustworthy and errors[1] < 1.2 * errors[0] < 1.5


def test_a_revisit_too_short_to_be_kept_is_named_not_skipped_in_silence():
    readings, loads, time, poses = revisiting_stream(0.0)
    revisit = np.nonzero(poses == 0)[0]
    # The revisit cut to its first 10 rows (0.2 s), shorter than the shortest static interval kept.
    keep = np.ones(len(poses), dtype=bool)
    keep[revisit[revisit > revisit[0] + 200][10:]] = False
    calibration = sfmnet.calibrate(readings[keep], 9.81, loads[keep], time[keep], poses[keep])
    assert any("pose 0 is labelled in separate runs" in warning for warning in calibration.warnings)


def test_without_a_time_column_the_revisit_is_named_by_the_files_rows():
    readings, loads, _, poses = revisiting_stream(0.01)
    # Detected in row order, the intervals' edges trimmed: the row named is still the file's, inside the revisit.
    calibration = sfmnet.calibrate(readings, 9.81, loads, None, poses, **{"data.static_intervals": True})
    warning = next(w for w in calibration.warnings if "reads differently at each visit" in w)
    first, revisit = (int(row) for row in re.search(r"data rows (\d+), (\d+)\)", warning).groups())
    assert poses[first] == poses[revisit] == 0 and revisit >= 1200


def test_a_pose_column_of_text_labels_is_read_as_poses(tmp_path: Path):
    """A new user's pose labels (`1-0`) were refused as not numeric, though the README asks only for a column naming
    each pose: text labels tie the same rows as numbers, and a message names the pose as the file writes it."""
    readings, loads, time, poses = revisiting_stream(0.01)
    columns = ["time", "s0", "s1", "s2", "fx", "fy", "fz", "pose"]
    paths = {}
    labellings = {
        "numbers": lambda pose: f"{pose:g}",
        # Text labels, among numbers (a hostile tester's, refused as not numeric), and 1234567 (named 1.23457e+06).
        "text": lambda pose: f"P-{pose:g}" if pose % 2 == 0 else f"{pose:g}", "large": lambda pose: str(1234567 + int(pose)),
    }
    for name, label in labellings.items():
        paths[name] = tmp_path / f"{name}.csv"
        with paths[name].open("w", newline="") as stream:
            writer = csv.writer(stream)
            writer.writerow(columns)
            for t, z, f, pose in zip(time, readings, loads, poses):
                writer.writerow([f"{t:.3f}", *(f"{v:.9g}" for v in z), *("" if np.isnan(v) else f"{v:.6f}" for v in f), label(pose)])
    calibrations = []
    for name, path in paths.items():
        cfg = compose_config([
            "experiment=calibrate_csv", f"data.path={path}", "data.magnitude=9.81", "data.time_column=time",
            "data.group_column=pose",
        ])
        train(cfg, tmp_path / name)
        calibrations.append(json.loads((tmp_path / name / "calibration.json").read_text()))
    for calibration, named in zip(calibrations, ["0", "P-0", "1234567"]):
        np.testing.assert_array_equal(calibration["matrix"], calibrations[0]["matrix"])
        assert any(f"pose {named} (holds starting at" in warning for warning in calibration["warnings"]), named
