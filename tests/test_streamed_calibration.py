"""Calibration from streamed sums (method §11): the in-memory answers, from blocks, on one or two processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor, write_stream_csv
from sfmnet.training.run import train
from tests.conftest import REPO, compose_config, write_session

SESSION = ["data.magnitude=9.81", "data.time_column=time", "trainer.enable_progress_bar=false"]


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("session") / "session.csv"
    write_session(path, known_loads=2)
    return path


def calibrate(session: Path, run_dir: Path, experiment: str, *overrides: str) -> tuple[dict, dict]:
    hint = "data.mirror_hint={row: 0, axis: fz, sign: 1}"
    metrics = train(compose_config([f"experiment={experiment}", f"data.path={session}", hint, *SESSION, *overrides]), run_dir)
    return json.loads((run_dir / "calibration.json").read_text()), metrics


def relative(a: list, b: list) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_closed_form_from_sums_is_the_in_memory_closed_form(session: Path):
    """Eigendecomposition of the scatter and normal equations in blocks against SVD and lstsq on the whole matrix."""
    cfg = compose_config(["experiment=calibrate_csv", f"data.path={session}", "data.mirror_hint={row: 0, axis: fz, sign: 1}", *SESSION])
    datamodule = instantiate(cfg.data)
    datamodule.setup()
    in_memory = instantiate(cfg.model)
    in_memory.initialise(datamodule.data.recordings["rotation"])
    streamed, _ = calibrate(session, session.parent / "closed", "calibrate_stream", "model.refinement=closed_form", "data.block_rows=37")
    assert relative(streamed["matrix"], in_memory.calibration_matrix().tolist()) < 1e-9
    assert relative(streamed["offset"], in_memory.physical_offset().tolist()) < 1e-9
    assert relative(streamed["singular_values"], in_memory.singular_values.tolist()) < 1e-9


def test_streamed_alternation_reaches_the_in_memory_fixed_point(session: Path, tmp_path: Path):
    memory, memory_metrics = calibrate(session, tmp_path / "memory", "calibrate_csv", "model.refinement=alternation", "trainer.max_epochs=20")
    streamed, metrics = calibrate(session, tmp_path / "stream", "calibrate_stream", "model.tolerance=1e-11", "data.block_rows=50")
    assert relative(streamed["matrix"], memory["matrix"]) < 1e-7
    assert relative(streamed["offset"], memory["offset"]) < 1e-7
    assert streamed["frame"] == "known_loads" and not streamed["warnings"]
    # Same rows, same Cramer-Rao bound; the noise differs only in which direction estimate leaves the residual.
    assert relative(streamed["matrix_std"], memory["matrix_std"]) < 0.05
    assert metrics["coverage"] == pytest.approx(memory_metrics["coverage"], rel=1e-9)
    assert metrics["residual_rms"] == pytest.approx(memory_metrics["residual_rms"], rel=1e-9)
    assert (tmp_path / "stream" / "figures" / "streamed_shape_from_motion_motion.png").stat().st_size > 10_000


def test_a_sample_stands_for_every_row_in_the_error_bars(session: Path, tmp_path: Path):
    every, _ = calibrate(session, tmp_path / "every", "calibrate_stream")
    rows = sum(1 for _ in session.open()) - 1
    quarter, _ = calibrate(session, tmp_path / "quarter", "calibrate_stream", f"model.sample_rows={rows // 4}")
    assert relative(quarter["matrix"], every["matrix"]) < 1e-12
    assert relative(quarter["matrix_std"], every["matrix_std"]) < 0.2


def test_an_unconverged_alternation_says_so(session: Path, tmp_path: Path):
    calibration, metrics = calibrate(session, tmp_path / "short", "calibrate_stream", "trainer.max_epochs=3")
    assert metrics["epochs"] == 3
    assert any("had not converged after 3 passes" in warning for warning in calibration["warnings"])


@pytest.mark.parametrize("continuous", [False, True])
def test_two_processes_give_the_same_calibration(session: Path, tmp_path: Path, continuous: bool):
    """DDP on the CPU (gloo): blocks dealt to two real processes, known rows gathered by a sum. A continuous recording
    (12 poses held 2 s, moves between them) ties each static interval's rows to one direction: the intervals' sums
    are reduced before any interval's direction is taken from them."""
    if continuous:
        generator = torch.Generator().manual_seed(3)
        recording = simulate_stream(stream_sensor(8, 9.81, 0.01, 0.2, generator), 1.0, poses=12, rate=50.0, generator=generator)
        session = tmp_path / "stream.csv"
        write_stream_csv(recording, session)
    hint = [] if continuous else ["data.mirror_hint={row: 0, axis: fz, sign: 1}"]
    single, _ = calibrate(session, tmp_path / "single", "calibrate_stream", "data.block_rows=40", *(["data.mirror_hint=null"] if continuous else []))
    command = [
        sys.executable, "-m", "sfmnet", "train", "experiment=calibrate_stream", f"data.path={session}", *hint,
        f"hydra.run.dir={tmp_path / 'ddp'}", "trainer.devices=2", "trainer.strategy=ddp", "data.block_rows=40", *SESSION,
    ]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300, check=False, env={**os.environ})
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.count("run directory:") == 1
    double = json.loads((tmp_path / "ddp" / "calibration.json").read_text())
    assert single["tied_directions"] is continuous and double["tied_directions"] is continuous
    for key in ("matrix", "offset", "matrix_std", "singular_values"):
        assert relative(double[key], single[key]) <= 1e-10, key


def test_block_size_does_not_change_the_answer(session: Path, tmp_path: Path):
    small, _ = calibrate(session, tmp_path / "small", "calibrate_stream", "data.block_rows=7")
    whole, _ = calibrate(session, tmp_path / "whole", "calibrate_stream")
    assert relative(small["matrix"], whole["matrix"]) < 1e-10
    assert torch.tensor(small["matrix"]).shape == (3, 6)


def write_fingertip(path: Path, law: str, noise_fraction: float) -> Path:
    """A 2-axis session (96 rows, orientations by ``law``; time, s0..s3, no loads) as a CSV."""
    from sfmnet.simulators.simulated_sensor import FingertipDataModule

    datamodule = FingertipDataModule(
        magnitude=111.4, samples=96, known_loads=0, mirror_hint=False, noise_fraction=noise_fraction, seed=4,
        orientation_law=law, errors={"angle_error_deg": 0.0},
    )
    datamodule.setup()
    readings = datamodule.data.recordings["rotation"].readings.numpy()
    table = np.column_stack([0.01 * np.arange(len(readings)), readings])
    np.savetxt(path, table, delimiter=",", header="time,s0,s1,s2,s3", comments="", fmt="%.9f")
    return path


@pytest.mark.parametrize(
    ("law", "noise_fraction", "problem"),
    [("band", 0.5, "the alternation ran away"), ("uniform", 0.2, "SNR "), ("band", 0.05, None), ("uniform", 0.05, None)],
)
def test_a_biased_or_runaway_alternation_says_so_and_disowns_its_error_bars(
    tmp_path: Path, law: str, noise_fraction: float, problem: str | None
):
    """At SNR 2 on a band the streamed alternation circles far from the closed form without converging (8.7x its
    largest singular value): a failed fit, not a slow one, so more passes are not the advice. At SNR 5 it converges,
    but to a shape biased by more than its error bars. At SNR 20 neither."""
    session = write_fingertip(tmp_path / "session.csv", law, noise_fraction)
    overrides = ["data.magnitude=111.4", "data.load_columns=[]", "data.axes=[x,y]", "data.time_column=time", "trainer.enable_progress_bar=false"]
    train(compose_config(["experiment=calibrate_stream", f"data.path={session}", *overrides]), tmp_path / "run")
    calibration = json.loads((tmp_path / "run" / "calibration.json").read_text())
    problems = [w for w in calibration["warnings"] if w.startswith(("the alternation ran away", "SNR "))]
    assert [w[: len(problem)] for w in problems] == ([problem] if problem else [])
    assert not any("raise trainer.max_epochs" in warning for warning in calibration["warnings"])
    assert calibration["error_bars_trustworthy"] == (problem is None)


def test_the_streamed_alternation_s_snr_is_the_simulated_one(tmp_path: Path):
    """The SNR its low-SNR warning gives counts the residuals' degrees of freedom (each row's direction takes up one of
    its four components): the simulated SNR 5 (noise 20 % of F |s|) was given as 6.1, now 5.2."""
    session = write_fingertip(tmp_path / "session.csv", "uniform", 0.2)
    overrides = ["data.magnitude=111.4", "data.load_columns=[]", "data.axes=[x,y]", "data.time_column=time", "trainer.enable_progress_bar=false"]
    train(compose_config(["experiment=calibrate_stream", f"data.path={session}", *overrides]), tmp_path / "run")
    warnings = json.loads((tmp_path / "run" / "calibration.json").read_text())["warnings"]
    snr = [float(w.split()[1]) for w in warnings if w.startswith("SNR ")]
    assert len(snr) == 1 and snr[0] == pytest.approx(5, rel=0.1), warnings


@pytest.mark.parametrize(("noise_fraction", "warned"), [(0.01, False), (0.2, True)])
def test_a_streamed_closed_form_at_low_snr_is_not_trusted(tmp_path: Path, noise_fraction: float, warned: bool):
    """The closed form (an algebraic ellipsoid fit) is biased at low SNR as the alternation is: its noise is measured
    off the load space (the scatter's last p - n eigenvalues), and below SNR 10 the bars are disowned."""
    session = tmp_path / "session.csv"
    write_session(session, known_loads=2, noise_fraction=noise_fraction)
    calibration, _ = calibrate(session, tmp_path / "run", "calibrate_stream", "model.refinement=closed_form")
    problems = [w for w in calibration["warnings"] if w.startswith("SNR ") and "the closed form's estimate" in w]
    assert len(problems) == int(warned)
    assert calibration["error_bars_trustworthy"] == (not warned)


def test_a_refused_row_far_in_a_streamed_csv_is_named_by_its_file_line(tmp_path: Path):
    """Rows the streamed model refuses in its passes (here the last row's load given in part) are named by the
    line an editor shows, past blank lines, in the user's CSV (not the .npy the CSV was converted to)."""
    from sfmnet.errors import SfmnetError

    def blank_lines_and_partial_last_load(rows: list[list[str]]) -> None:
        rows[-1][-1] = ""
        rows[1:1] = [[], []]

    session = tmp_path / "session.csv"
    write_session(session, known_loads=3, edit=blank_lines_and_partial_last_load)
    last_line = len(session.read_text().splitlines())
    cfg = compose_config(["experiment=calibrate_stream", f"data.path={session}", *SESSION, "data.static_intervals=false"])
    with pytest.raises(SfmnetError, match=rf"^line {last_line} of .*session.csv gives only some of fx, fy, fz"):
        train(cfg, tmp_path / "run")


def test_a_corrupt_cell_far_outside_its_column_is_named_in_a_stream(tmp_path: Path):
    """A 0xFFFFFFFF in one cell of a streamed session took the closed form over and the run blamed the orientations
    ("the loads barely span 3 dimensions ... collinear or coplanar"); it is now named by its line, as in memory."""
    from sfmnet.errors import SfmnetError

    def overflow(rows: list[list[str]]) -> None:
        rows[41][2] = "4294967295"

    session = tmp_path / "session.csv"
    write_session(session, known_loads=3, edit=overflow)
    cfg = compose_config(["experiment=calibrate_stream", f"data.path={session}", *SESSION])
    with pytest.raises(SfmnetError, match=r"^1 reading value over 1e\+04 times .*\(first: line 42 of .*session.csv column s1 \(4.29e\+09\)\)"):
        train(cfg, tmp_path / "run")


def test_a_text_column_beside_the_listed_channels_is_not_read(session: Path, tmp_path: Path):
    """A CSV with an operator's note column: streamed with the channels listed, the same calibration as without it."""
    noted = tmp_path / "noted.csv"
    write_session(noted, known_loads=2, edit=lambda rows: [row.insert(1, "note" if i == 0 else f"pose {i % 7}") for i, row in enumerate(rows)])
    channels = "data.channel_columns=[s0,s1,s2,s3,s4,s5]"
    plain, _ = calibrate(session, tmp_path / "plain", "calibrate_stream", "model.refinement=closed_form", channels)
    with_note, _ = calibrate(noted, tmp_path / "noted", "calibrate_stream", "model.refinement=closed_form", channels)
    assert with_note["matrix"] == plain["matrix"] and with_note["offset"] == plain["offset"]


@pytest.mark.parametrize("tied", [True, False])
def test_a_long_streamed_hold_ties_its_rows_to_one_direction(tmp_path: Path, tied: bool):
    """A 3-channel sensor (``p = n``) at SNR 12, 20 poses held 5 s at 400 Hz, logged only while held (a hostile
    tester's accelerometer). With
    a direction per row the alternation's bias, about ``(n - 1) / (2 SNR^2)`` of the shape, does not shrink with the
    rows while the bars do: the stream was trusted at 4.7-6x its bars where the in-memory fit, tied to the static
    intervals, was within them. Tied, the stream is that fit."""
    generator = torch.Generator().manual_seed(1)
    sensor = stream_sensor(3, 9.81, 0.08, 0.2, generator)
    recording = simulate_stream(sensor, 1.0, poses=20, hold=5.0, move=1.0, rate=400.0, generator=generator)
    path = tmp_path / "stream.csv"
    write_stream_csv(recording, path, rows=recording.static)
    calibration, _ = calibrate(
        path, tmp_path / "run", "calibrate_stream", f"model.tie_directions={str(tied).lower()}", "data.mirror_hint=null"
    )
    truth = torch.linalg.pinv(sensor.shape).T.numpy()
    matrix, bars = np.asarray(calibration["matrix"]), np.asarray(calibration["matrix_std"])
    error_over_bars = float(np.linalg.norm(matrix - truth) / np.linalg.norm(bars))
    assert calibration["tied_directions"] is tied
    if tied:
        assert error_over_bars < 2 and calibration["error_bars_trustworthy"], (error_over_bars, calibration["warnings"])
    else:
        assert error_over_bars > 3, error_over_bars
