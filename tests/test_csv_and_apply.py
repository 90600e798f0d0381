"""Your own recording in, calibration out, loads out: the file contracts and their errors."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate

from sfmnet.apply import apply_calibration, output_names, taken_names
from sfmnet.eval.calibration_headline import trust_lines
from sfmnet.simulators.simulated_sensor import ForceSensor3DataModule
from sfmnet.errors import SfmnetError
from sfmnet.training.run import train
from tests.conftest import compose_config, write_session
from tests.test_cli import QUIET, sfmnet


def csv_config(path: Path, *overrides: str):
    return compose_config(
        ["experiment=calibrate_csv", f"data.path={path}", "data.magnitude=9.81", "data.time_column=time", *overrides]
    )


def test_csv_contract_end_to_end(tmp_path: Path):
    session = tmp_path / "session.csv"
    truth = write_session(session)
    run_dir = tmp_path / "run"
    result = sfmnet(
        "train", "experiment=calibrate_csv", f"data.path={session}", "data.magnitude=9.81",
        "data.load_columns=[fx,fy,fz]", "data.time_column=time", f"hydra.run.dir={run_dir}", *QUIET,
    )
    assert result.returncode == 0, result.stderr
    calibration = json.loads((run_dir / "calibration.json").read_text())
    matrix = torch.tensor(calibration["matrix"], dtype=torch.float64)
    assert calibration["channels"] == [f"s{i}" for i in range(6)] and calibration["axes"] == ["fx", "fy", "fz"]
    assert len(calibration["matrix_std"]) == 3 and len(calibration["offset_std"]) == 6
    assert float((matrix - truth).norm() / truth.norm()) < 0.02
    # The headline says how far to trust the calibration, with the figures of metrics.json in load units.
    metrics = json.loads((run_dir / "metrics.json").read_text())
    headline = result.stdout
    assert "channels     s0, s1, s2, s3, s4, s5 (6 channels)" in headline
    # Which refinement ran, and the SNR auto chose it by, in the file and on screen.
    assert calibration["refinement"] == "alternation" and calibration["tied_directions"] is False
    assert f"refinement   alternation (direction SNR {calibration['direction_snr']:.3g})" in headline
    assert f"coverage     {metrics['coverage']:.2f}: how evenly the load directions span every axis" in headline
    assert f"residuals    {metrics['load_residual/force_rms']:.4g} N RMS in load units" in headline
    assert (
        f"known loads  {metrics['goodness/known_load_rms']:.4g} N RMS per axis from where the calibration puts them "
        f"({metrics['goodness/known_load_pct']:.3g} % of their size)" in headline
    )
    # How much of the bars the known loads' frame is, beside the file's figure.
    assert 0 <= calibration["matrix_std_frame_share"] == metrics["matrix_std_frame_share"] <= 1
    rows = int(metrics["known_load_rows"])
    assert f"frame        the {rows} known-load rows set it: {100 * metrics['matrix_std_frame_share']:.0f} % of" in headline
    assert "error bars   trustworthy" in headline

    output = tmp_path / "loads.csv"
    applied = sfmnet("apply", f"calibration={run_dir / 'calibration.json'}", f"input={session}", f"output={output}")
    assert applied.returncode == 0, applied.stderr
    rows = list(csv.DictReader(output.open()))
    assert list(rows[0])[-3:] == ["fx_calibrated", "fy_calibrated", "fz_calibrated"]
    assert "columns fx_calibrated, fy_calibrated, fz_calibrated (the input has fx, fy, fz already)" in applied.stdout
    assert rows[0]["time"] == "0.00"  # the input's columns are kept as they were
    magnitudes = [math.dist([0, 0, 0], [float(r[f"{a}_calibrated"]) for a in ["fx", "fy", "fz"]]) for r in rows]
    assert abs(np.mean(magnitudes) / 9.81 - 1) < 0.005
    # The residual in load units is the calibrated loads' departure from the fitted ones: off |load| = F
    # on the unknown rows, off the given load on the known ones (10 %: the fitted direction is not
    # exactly the calibrated load's; a residual in raw units would be 10x off).
    departures = [
        math.dist([float(r[a]) for a in ["fx", "fy", "fz"]], [float(r[f"{a}_calibrated"]) for a in ["fx", "fy", "fz"]])
        if r["fx"] else abs(size - 9.81)
        for r, size in zip(rows, magnitudes)
    ]
    assert math.isclose(float(np.sqrt(np.mean(np.square(departures)))), metrics["load_residual/force_rms"], rel_tol=0.1)
    known = [r for r in rows if r["fx"]]
    applied_known = np.array([[float(r[f"{a}_calibrated"]) for a in ["fx", "fy", "fz"]] for r in known])
    given = np.array([[float(r[a]) for a in ["fx", "fy", "fz"]] for r in known])
    percent = 100 * np.sqrt(np.mean((applied_known - given) ** 2)) / np.sqrt(np.mean(given**2))
    assert math.isclose(percent, metrics["goodness/known_load_pct"], rel_tol=1e-3)
    # Applied again to its own output (a hostile tester's: fx_calibrated twice, and a reader by name found the old).
    again = tmp_path / "loads_again.csv"
    assert sfmnet("apply", f"calibration={run_dir / 'calibration.json'}", f"input={output}", f"output={again}").returncode == 0
    header = next(csv.reader(again.open()))
    assert header[-6:] == [*(f"{a}_calibrated" for a in ["fx", "fy", "fz"]), *(f"{a}_calibrated_2" for a in ["fx", "fy", "fz"])]


def test_load_columns_are_renamed_all_or_none():
    """An input with one of the axes' names among its columns: a hostile tester's had fx but not fy, and the output
    held fx (the input's), fx_calibrated and fy, so a reader taking fx, fy by name mixed an old load with a new one."""
    assert output_names(["fx", "fy"], ["s0", "s1", "s2", "fx"]) == ["fx_calibrated", "fy_calibrated"]
    assert output_names(["fx", "fy"], ["s0", "fy_calibrated", "fx"]) == ["fx_calibrated_2", "fy_calibrated_2"]
    assert output_names(["fx", "fy"], ["s0", "s1"]) == ["fx", "fy"]
    # The note names the columns that took the names, not every axis.
    assert taken_names(["fx", "fy", "fz"], ["z0", "fx", "fy_calibrated", "fz", "fxx"]) == ["fx", "fy_calibrated", "fz"]


def test_npz_input(tmp_path: Path):
    datamodule = ForceSensor3DataModule(magnitude=9.81, known_loads=3, mirror_hint=False)
    datamodule.setup()
    recording = datamodule.data.recordings["rotation"]
    arrays = {f"s{i}": recording.readings[:, i].numpy() for i in range(6)}
    arrays.update({axis: recording.loads[:, i].numpy() for i, axis in enumerate(["fx", "fy", "fz"])})
    np.savez(tmp_path / "session.npz", **arrays)
    cfg = compose_config(["experiment=calibrate_csv", f"data.path={tmp_path / 'session.npz'}", "data.mass=1.0003"])
    metrics = train(cfg, tmp_path / "run")
    assert metrics["rank_gap"] > 10


def set_cell(line: int, column: int, value: str):
    def edit(rows: list[list[str]]) -> None:
        rows[line - 1][column] = value

    return edit


@pytest.mark.parametrize(
    "edit,overrides,message",
    [
        (None, ["data.load_columns=[fx,fy,fzz]"], "load column 'fzz' is not in .* \\(did you mean 'fz'\\?\\)"),
        (None, ["data.channel_columns=[s0,s1,s9]"], "channel column 's9' is not in"),
        (set_cell(5, 2, "n/a"), [], "channel column 's1' of .* is not numeric: \\[\"line 5: 'n/a'\"\\]"),
        (set_cell(7, 3, "nan"), [], "1 empty, NaN or infinite reading values \\(first: line 7 column s2\\)"),
        (set_cell(9, 1, "inf"), [], "1 empty, NaN or infinite reading values \\(first: line 9 column s0\\)"),
        (None, ["data.magnitude=12.0"], "the known load on line .* has magnitude 9.81 but data.magnitude is 12"),
        (None, ["data.mass=1.0"], "exactly one of data.magnitude .* or data.mass"),
        (None, ["data.channel_columns=[s0,s1]"], "2 channel columns for 3 load axes"),
    ],
    ids=["misspelt-load-column", "missing-channel", "non-numeric", "nan", "inf", "wrong-magnitude", "two-magnitudes", "too-few-channels"],
)
def test_bad_files_are_refused(tmp_path: Path, edit, overrides: list[str], message: str):
    session = tmp_path / "session.csv"
    write_session(session, edit=edit)
    with pytest.raises(SfmnetError, match=message):
        train(csv_config(session, *overrides), tmp_path / "run")
    assert not (tmp_path / "run" / "calibration.json").exists()


def test_constant_channel_is_refused(tmp_path: Path):
    def flatten(rows):
        for row in rows[1:]:
            row[4] = "0.5"

    session = tmp_path / "session.csv"
    write_session(session, edit=flatten)
    with pytest.raises(SfmnetError, match="channel s3 of .* is constant"):
        train(csv_config(session), tmp_path / "run")


def test_too_few_distinct_orientations(tmp_path: Path):
    def keep_head(rows):
        del rows[6:-3]  # five unknown orientations and three known loads: eight samples

    session = tmp_path / "session.csv"
    write_session(session, edit=keep_head)
    with pytest.raises(SfmnetError, match="only 8 samples for 9 unknowns of the metric constraint with offsets"):
        train(csv_config(session), tmp_path / "run")


def test_two_known_loads_need_the_mirror_bit(tmp_path: Path):
    session = tmp_path / "session.csv"
    truth = write_session(session, known_loads=2)
    with pytest.raises(SfmnetError, match="only up to a mirror image: set data.mirror_hint="):
        train(csv_config(session), tmp_path / "run")
    # Give the bit: the sign of row 0's true fz (write_session simulates this same session).
    session_data = ForceSensor3DataModule(magnitude=9.81, offset_scale=0.2, known_loads=2, mirror_hint=False)
    session_data.setup()
    sign = 1 if float(session_data.data.recordings["rotation"].true_loads[0, 2]) > 0 else -1
    cfg = csv_config(session, f"data.mirror_hint={{row: 0, axis: fz, sign: {sign}}}")
    train(cfg, tmp_path / "run2")
    matrix = torch.tensor(json.loads((tmp_path / "run2" / "calibration.json").read_text())["matrix"])
    assert float((matrix - truth).norm() / truth.norm()) < 0.05


@pytest.mark.parametrize("experiment", ["calibrate_csv", "calibrate_stream"])
def test_a_mirror_hint_below_blank_lines_names_its_line(tmp_path: Path, experiment: str):
    """A hostile tester's: three empty rows above the hinted row, which counted by the file's lines was another row;
    the wrong mirror was fitted with every check passing. The run now names the line its row is on."""
    session = tmp_path / "session.csv"
    write_session(session, known_loads=2, edit=lambda rows: rows.insert(3, [""] * len(rows[0])) or rows.insert(3, []))
    overrides = [f"experiment={experiment}", f"data.path={session}", "data.magnitude=9.81", "data.time_column=time"]
    warnings = {}
    for row in (1, 5):
        datamodule = instantiate(compose_config([*overrides, f"data.mirror_hint={{row: {row}, axis: fz, sign: 1}}"]).data)
        datamodule.setup()
        warnings[row] = datamodule.data.warnings
    assert not any("mirror_hint" in warning for warning in warnings[1])
    assert any(
        warning.startswith(f"data.mirror_hint.row 5 is line 9 of {session}: 2 blank or comment lines above it are not rows")
        for warning in warnings[5]
    ), warnings[5]


@pytest.mark.parametrize("experiment", ["calibrate_csv", "calibrate_stream"])
def test_channels_in_units_orders_of_magnitude_apart_are_pointed_out(tmp_path: Path, experiment: str):
    """A hostile tester's channels in units 1e5, 1, 1e-3 and 50 apart: fitted in raw units, 5x less accurate than in
    one unit, and disowned by checks that blamed motion and bias."""

    def rescale(rows: list) -> None:
        for row in rows[1:]:
            row[1], row[3] = f"{1e5 * float(row[1]):.9g}", f"{1e-3 * float(row[3]):.9g}"

    warnings = {}
    for name, edit in (("plain", None), ("scaled", rescale)):
        session = tmp_path / f"{name}.csv"
        write_session(session, edit=edit)
        overrides = [f"experiment={experiment}", f"data.path={session}", "data.magnitude=9.81", "data.time_column=time"]
        datamodule = instantiate(compose_config(overrides).data)
        datamodule.setup()
        warnings[name] = datamodule.data.warnings
    assert not any("spreads differ" in warning for warning in warnings["plain"])
    assert any(
        re.match(r"the channels' spreads differ [\d.e+]+x \(channel 's0' [\d.e+]+, 's2' [\d.e+-]+ raw units\)", warning)
        for warning in warnings["scaled"]
    ), warnings["scaled"]


def test_apply_refuses_other_channels_and_existing_output(tmp_path: Path):
    session = tmp_path / "session.csv"
    write_session(session)
    train(csv_config(session), tmp_path / "run")
    calibration = tmp_path / "run" / "calibration.json"
    other = tmp_path / "other.csv"
    other.write_text("a,b,c\n1,2,3\n")
    with pytest.raises(SfmnetError, match="lacks channels s0, s1, s2, s3, s4, s5 of the calibration"):
        apply_calibration(calibration, other, tmp_path / "out.csv", overwrite=False)
    output = tmp_path / "out.csv"
    output.write_text("mine\n")
    with pytest.raises(SfmnetError, match="already exists"):
        apply_calibration(calibration, session, output, overwrite=False)
    assert output.read_text() == "mine\n"
    apply_calibration(calibration, session, output, overwrite=True)
    assert output.read_text().startswith("time,s0")


@pytest.mark.parametrize(
    "content,message",
    [("", "is empty"), ("{not json", "cannot be read as JSON"), ('{"matrix": [[1]]}', "lacks axes, channels, offset")],
)
def test_apply_refuses_bad_calibration_files(tmp_path: Path, content: str, message: str):
    session = tmp_path / "session.csv"
    write_session(session)
    calibration = tmp_path / "calibration.json"
    calibration.write_text(content)
    with pytest.raises(SfmnetError, match=message):
        apply_calibration(calibration, session, tmp_path / "out.csv", overwrite=False)


def test_apply_refuses_missing_calibration(tmp_path: Path):
    with pytest.raises(SfmnetError, match="does not exist"):
        apply_calibration(tmp_path / "none.json", tmp_path / "in.csv", tmp_path / "out.csv", overwrite=False)


def test_trustworthy_bars_beside_warnings_say_the_warnings_are_not_about_them():
    """A coverage or rank-gap warning under "trustworthy" read as a contradiction to a hostile tester."""
    metrics = {"residual_rms": 0.01, "error_bars_trustworthy": 1.0}
    quiet = trust_lines(metrics, ["a", "b", "c"], "N", 9.81, 3)
    warned = trust_lines(metrics, ["a", "b", "c"], "N", 9.81, 3, warnings=2)
    assert quiet[-1].strip() == "error bars   trustworthy: every goodness-of-fit check passed"
    assert "the 2 warnings below: about the data or the estimator chosen, not the bars" in warned[-1]
    disowned = trust_lines({**metrics, "error_bars_trustworthy": 0.0}, ["a", "b", "c"], "N", 9.81, 3, warnings=1)
    assert "NOT TRUSTWORTHY" in disowned[-1] and "not the bars" not in disowned[-1]


@pytest.mark.parametrize("streamed", [False, True], ids=["in-memory", "streamed"])
def test_a_copied_or_computed_channel_is_refused_in_one_line(tmp_path: Path, streamed: bool):
    """A hostile tester's: s3 an exact affine function of s2 crashed in the channel noise (a traceback), or, streamed,
    calibrated as if it had noise of its own."""
    def computed(rows):
        for row in rows[1:]:
            row[4] = f"{2 * float(row[3]) + 1:.9f}"

    session = tmp_path / "session.csv"
    write_session(session, edit=computed)
    experiment = ["experiment=calibrate_stream"] if streamed else []
    with pytest.raises(SfmnetError, match="channels s2, s3 .*are linear functions of one another"):
        train(csv_config(session, *experiment, *QUIET), tmp_path / "run")


def test_apply_says_when_the_calibration_was_not_trustworthy(tmp_path: Path):
    session = tmp_path / "session.csv"
    write_session(session)
    run = tmp_path / "run"
    train(csv_config(session, *QUIET), run)
    trusted = sfmnet("apply", f"calibration={run / 'calibration.json'}", f"input={session}", f"output={tmp_path / 'a.csv'}")
    assert trusted.returncode == 0 and "NOT TRUSTWORTHY" not in trusted.stderr
    assert f"rows of loads (N) to {tmp_path / 'a.csv'}" in trusted.stdout  # in their unit (a new user's: "of loads")
    marked = json.loads((run / "calibration.json").read_text())
    marked.update(error_bars_trustworthy=False, warnings=["the known loads sit 3.1x the noise from the fit"])
    (tmp_path / "marked.json").write_text(json.dumps(marked))
    result = sfmnet("apply", f"calibration={tmp_path / 'marked.json'}", f"input={session}", f"output={tmp_path / 'b.csv'}")
    assert result.returncode == 0 and (tmp_path / "b.csv").is_file()
    assert "NOT TRUSTWORTHY when it was fitted (the known loads sit 3.1x the noise from the fit;" in result.stderr


def test_json_files_hold_no_nan(tmp_path: Path):
    """An undefined figure is null, which every JSON parser reads (NaN is Python's own), and reads back as NaN."""
    from sfmnet.calibration import Calibration
    from sfmnet.io import write_json_atomic

    write_json_atomic(tmp_path / "m.json", {"auroc": math.nan, "bars": [[1.0, math.inf]], "rows": 3})
    strict = json.loads((tmp_path / "m.json").read_text(), parse_constant=lambda name: pytest.fail(f"{name} in JSON"))
    assert strict == {"auroc": None, "bars": [[1.0, None]], "rows": 3}
    session = tmp_path / "session.csv"
    write_session(session)
    train(csv_config(session, *QUIET), tmp_path / "run")
    saved = json.loads((tmp_path / "run" / "calibration.json").read_text())
    saved["matrix_std"][0][0] = None
    (tmp_path / "c.json").write_text(json.dumps(saved))
    assert math.isnan(float(Calibration.load(tmp_path / "c.json").matrix_std[0, 0]))


def test_a_corrupt_cell_far_outside_its_column_is_named(tmp_path: Path):
    """A hostile tester's 0xFFFFFFFF in one cell took the closed form over, and the run blamed the orientations
    ("the loads are collinear or coplanar"), sending the user to record again."""
    def overflow(rows):
        rows[41][3] = "4294967295"

    session = tmp_path / "session.csv"
    write_session(session, edit=overflow)
    with pytest.raises(SfmnetError, match=r"1 reading value over 1e\+04 times .* \(first: line 42 column s2 \(4.29e\+09\)\)"):
        train(csv_config(session, *QUIET), tmp_path / "run")


def test_a_pose_held_for_most_of_the_recording_is_not_a_corrupt_cell(tmp_path: Path):
    """The far-cell check is a gap, not a distance from the median: 95 % of rows at rest on one quantised value leave
    the others far from the median but near one another (a hostile tester's, refused as corrupt by a first version)."""
    from sfmnet.readers.table_file import check_far_cells, read_table

    column = np.r_[np.full(950, 0.5), np.linspace(20.0, 22.0, 50)]
    path = tmp_path / "rest.csv"
    path.write_text("s0\n" + "".join(f"{v:.2f}\n" for v in column))
    check_far_cells(column[:, None], ["s0"], read_table(path), "reading")
    column[3] = 4294967295.0
    path.write_text("s0\n" + "".join(f"{v:.2f}\n" for v in column))
    with pytest.raises(SfmnetError, match=r"first: line 5 column s0 \(4.29e\+09\)"):
        check_far_cells(column[:, None], ["s0"], read_table(path), "reading")


def test_apply_writes_as_the_input_was_written_so_its_output_reads_back(tmp_path: Path):
    """A hostile tester's `;`-separated file with decimal commas came out comma-separated with its cells quoted as
    text beside dot-decimal loads, and applying again to that output was refused ("not numeric")."""
    from sfmnet.apply import apply_calibration

    session = tmp_path / "session.csv"
    write_session(session)
    train(csv_config(session, *QUIET), tmp_path / "run")
    calibration = tmp_path / "run" / "calibration.json"
    semicolons = tmp_path / "semicolons.csv"
    semicolons.write_text(session.read_text().replace(",", ";").replace(".", ","))
    apply_calibration(calibration, semicolons, tmp_path / "once.csv", overwrite=False)
    apply_calibration(calibration, tmp_path / "once.csv", tmp_path / "twice.csv", overwrite=False)
    apply_calibration(calibration, session, tmp_path / "plain.csv", overwrite=False)
    twice = (tmp_path / "twice.csv").read_text().splitlines()
    assert twice[0].endswith("fx_calibrated;fy_calibrated;fz_calibrated;fx_calibrated_2;fy_calibrated_2;fz_calibrated_2")
    plain = list(csv.DictReader((tmp_path / "plain.csv").open()))
    again = list(csv.DictReader((tmp_path / "twice.csv").open(), delimiter=";"))
    for axis in ("fx", "fy", "fz"):
        np.testing.assert_allclose(
            [float(row[f"{axis}_calibrated_2"].replace(",", ".")) for row in again],
            [float(row[f"{axis}_calibrated"]) for row in plain], rtol=1e-8,
        )
