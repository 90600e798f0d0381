"""The Python API: sfmnet.calibrate gives the command line's numbers, from arrays, with one-line errors."""

from __future__ import annotations

import csv
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import sfmnet
from sfmnet.training.run import train
from tests.conftest import REPO, compose_config, experiment_overrides, write_session
from tests.test_cli import QUIET
from tests.test_cli import sfmnet as run_cli


def read_session(path: Path) -> tuple[list[str], np.ndarray]:
    rows = list(csv.reader(path.open()))
    return rows[0], np.array([[float(cell) if cell else np.nan for cell in row] for row in rows[1:]])


def test_calibrate_gives_the_command_lines_calibration(tmp_path: Path):
    """The CLI on a CSV and the API on the same file's arrays: calibration.json's numbers to 1e-9."""
    write_session(tmp_path / "session.csv")
    result = run_cli(
        "train", "experiment=calibrate_csv", f"data.path={tmp_path / 'session.csv'}", "data.magnitude=9.81",
        "data.time_column=time", f"hydra.run.dir={tmp_path / 'cli'}", *QUIET,
    )
    assert result.returncode == 0, result.stderr
    cli = json.loads((tmp_path / "cli" / "calibration.json").read_text())

    header, table = read_session(tmp_path / "session.csv")
    cal = sfmnet.calibrate(
        table[:, 1:7], magnitude=9.81, loads=table[:, 7:10], time=table[:, 0], channels=header[1:7], axes=header[7:10]
    )
    for key in ("matrix", "offset", "matrix_std", "offset_std"):
        assert np.abs(np.array(cli[key]) - getattr(cal, key).numpy()).max() <= 1e-9, key
    assert cal.residual_rms == pytest.approx(cli["residual_rms"], abs=1e-12)
    assert cal.channels == cli["channels"] and cal.axes == cli["axes"] and cal.warnings == cli["warnings"]
    assert cal.extra["method"] == "shape_from_motion" and cal.error_bars_trustworthy


def test_calibrate_without_known_loads_torch_in_and_a_kept_run_dir(tmp_path: Path):
    truth = write_session(tmp_path / "session.csv")
    _, table = read_session(tmp_path / "session.csv")
    readings = torch.from_numpy(table[:, 1:7])
    cal = sfmnet.calibrate(readings, magnitude=9.81, axes=["x", "y", "z"], run_dir=tmp_path / "run")
    assert (tmp_path / "run" / "calibration.json").is_file() and (tmp_path / "run" / "metrics.json").is_file()
    assert cal.extra["frame"].startswith("arbitrary") and cal.axes == ["x", "y", "z"]
    # The frame is free, the metric C^T C is not.
    gram, true_gram = cal.matrix.T @ cal.matrix, truth.T @ truth
    assert (gram - true_gram).norm() < 0.02 * true_gram.norm()
    loads = cal.apply(readings)
    assert isinstance(loads, torch.Tensor) and abs(float(loads.norm(dim=1).mean()) - 9.81) < 0.01


def write_session_path(tmp_path: Path) -> Path:
    write_session(tmp_path / "session.csv")
    return tmp_path / "session.csv"


def test_config_overrides_reach_the_fit(tmp_path: Path):
    _, table = read_session(write_session_path(tmp_path))
    readings, loads = table[:, 1:7], table[:, 7:10]
    default = sfmnet.calibrate(readings, magnitude=9.81, loads=loads)
    dotted = sfmnet.calibrate(readings, magnitude=9.81, loads=loads, **{"model.refinement": "penalty"})
    nested = sfmnet.calibrate(readings, magnitude=9.81, loads=loads, model={"refinement": "penalty"})
    assert torch.equal(dotted.matrix, nested.matrix) and not torch.equal(dotted.matrix, default.matrix)
    # A group by name, as model=... on the command line (the triad model needs p = n: three channels).
    triad = sfmnet.calibrate(readings[:, :3], magnitude=9.81, axes=["x", "y", "z"], model="bias_scale_misalignment")
    assert triad.extra["method"] == "bias_scale_misalignment"


@pytest.mark.parametrize(
    "arguments, message",
    [
        ({"readings": np.ones(5)}, r"readings has shape \(5,\): give a 2-D array"),
        ({"readings": [["a", "b"]]}, r"readings is not a numeric array"),
        ({"readings": [[1.0, 2.0], [3.0]]}, r"readings is not a numeric array \(.*inhomogeneous"),
        ({"readings": np.ones((4, 6)) + 1j}, r"readings is complex: give real raw readings"),
        ({"time": ["noon"] * 99}, r"time is not a numeric array"),
        ({"loads": np.full((7, 3), np.nan)}, r"loads has 7 rows but readings has 99"),
        ({"loads": np.full((99, 3), np.nan)}, r"loads is NaN on every row, so no known load fixes the frame: .*loads=None"),
        # A hostile tester's: refused for the fourth column's magnitude ("12.39 but data.magnitude is 9.81").
        ({"loads": np.vstack([np.full((1, 4), 4.905), np.full((98, 4), np.nan)])}, r"4 load axes \(l0, l1, l2, l3\): a calibration has 2 \(a fingertip\), 3 .* or 6"),
        ({"time": np.arange(3.0)}, r"time has shape \(3,\) but readings has 99 rows"),
        ({"channels": ["a"] * 6}, r"give 6 distinct channel names"),
        ({"model.no_such_key": 1}, r"model.no_such_key is not a config key"),
        ({"magnitude": None}, r"exactly one of data.magnitude"),
        ({"model": "no_such_model"}, r"model=no_such_model is not an option of the config group model: choose one of .*bias_scale_misalignment"),
    ],
)
def test_bad_input_is_one_line(tmp_path: Path, arguments: dict, message: str):
    _, table = read_session(write_session_path(tmp_path))
    given = {"readings": table[:, 1:7], "magnitude": 9.81, "loads": table[:, 7:10], **arguments}
    with pytest.raises(sfmnet.SfmnetError, match=message) as caught:
        sfmnet.calibrate(**given)
    assert "\n" not in str(caught.value)


def test_calibration_round_trips_through_its_file(tmp_path: Path):
    _, table = read_session(write_session_path(tmp_path))
    cal = sfmnet.calibrate(table[:, 1:7], magnitude=9.81, loads=table[:, 7:10])
    cal.save(str(tmp_path / "cal.json"))
    # A file a user already has is kept unless they say to replace it.
    saved = (tmp_path / "cal.json").read_text()
    with pytest.raises(sfmnet.SfmnetError, match=r"cal.json already exists: choose another path or pass overwrite=True$"):
        sfmnet.Calibration.load(str(tmp_path / "cal.json")).save(tmp_path / "cal.json")
    assert (tmp_path / "cal.json").read_text() == saved
    with pytest.raises(sfmnet.SfmnetError, match=r"is a folder: give the file to write"):
        cal.save(tmp_path)
    cal.save(tmp_path / "cal.json", overwrite=True)
    again = sfmnet.Calibration.load(str(tmp_path / "cal.json"))
    assert again.to_dict() == cal.to_dict()
    assert np.array_equal(again.apply(table[:4, 1:7]), cal.apply(table[:4, 1:7]))
    with pytest.raises(sfmnet.SfmnetError, match=r"give \(f, 6\) raw readings"):
        cal.apply(table[:4, 1:5])


def test_import_sfmnet_is_light():
    code = "import sys, sfmnet; print(sorted(m for m in ('lightning', 'hydra', 'matplotlib') if m in sys.modules))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, check=True)
    assert result.stdout.strip() == "[]"


def test_readme_python_api_example_runs(tmp_path: Path, monkeypatch):
    """Every line of the README's "Python API" example, as a user would paste it."""
    readme = (REPO / "README.md").read_text()
    example = re.search(r"### Python API.*?```python\n(.*?)```", readme, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    exec(compile(example, "README.md (Python API)", "exec"), {})
    assert (tmp_path / "cal.json").is_file()


def test_command_learner_reads_the_command_lines_commands(tmp_path: Path):
    """CommandLearner on a log's first 70 % gives the CLI's held-out predictions (experiment=sensorimotor_csv)."""
    overrides = experiment_overrides("sensorimotor_csv", tmp_path)
    train(compose_config(["experiment=sensorimotor_csv", *overrides]), tmp_path / "run")
    rows = list(csv.DictReader((tmp_path / "log.csv").open()))
    sensors = next(o for o in overrides if o.startswith("data.sensor_columns=")).split("=", 1)[1].strip("[]").split(",")
    readings = np.array([[float(row[name]) for name in sensors] for row in rows])
    commands = np.array([[row["drive"], row["steer"]] for row in rows], dtype=object)
    split = round(0.7 * len(rows))
    learner = sfmnet.CommandLearner().fit(readings[:split], commands[:split])
    predicted = list(csv.DictReader((tmp_path / "run" / "predictions.csv").open()))
    assert learner.rank_ == json.loads((tmp_path / "run" / "metrics.json").read_text())["rank"]
    assert (learner.predict(readings[split:]) == [[p["drive_learnt"], p["steer_learnt"]] for p in predicted]).all()
    confidence = np.array([float(p["confidence"]) for p in predicted])
    assert np.abs(learner.predict_confidence(readings[split:]) - confidence).max() < 1e-6
    assert learner.transform(readings[split:]).shape == (len(rows) - split, learner.basis_.shape[1])


def test_command_learner_errors_and_the_autoencoder(tmp_path: Path):
    generator = np.random.default_rng(0)
    sensors = generator.normal(size=(400, 4))
    commands = np.where(sensors[:, 0] > 0, "go", "stop")
    with pytest.raises(sfmnet.SfmnetError, match="not fitted yet"):
        sfmnet.CommandLearner().predict(sensors)
    with pytest.raises(sfmnet.SfmnetError, match="no parameter 'ranks'"):
        sfmnet.CommandLearner().set_params(ranks=2)
    learner = sfmnet.CommandLearner(learner="autoencoder", rank=2, max_epochs=5).fit(sensors, commands)
    assert learner.predict(sensors).shape == (400,) and set(learner.labels_[0]) == {"go", "stop"}
    assert (learner.predict(sensors) == commands).mean() > 0.6
    with pytest.raises(sfmnet.SfmnetError, match="sensors has 3 columns but the learner was fitted on 4"):
        learner.predict(sensors[:, :3])
    with pytest.raises(sfmnet.SfmnetError, match=r"sensors has 4 NaN or infinite values \(first: row 0, column 0\)"):
        learner.predict(np.full((1, 4), np.nan))
    holed = sensors.copy()
    holed[7, 2] = np.inf
    with pytest.raises(sfmnet.SfmnetError, match=r"sensors has 1 NaN or infinite values \(first: row 7, column 2\)"):
        sfmnet.CommandLearner().fit(holed, commands)
    for missing in (None, float("nan")):
        labels = commands.astype(object)
        labels[3] = missing
        with pytest.raises(sfmnet.SfmnetError, match=r"commands has 1 missing labels \(None or NaN; first: row 3"):
            sfmnet.CommandLearner().fit(sensors, labels)
    # In the words of the parameters, not the command line's keys (a hostile tester's "model.rank is 20").
    for settings, message in (({"rank": 2.5}, "^rank is 2.5"), ({"max_epochs": -1}, "^max_epochs is -1"),
                              ({"rank_rule": "bogus"}, "^rank_rule is 'bogus'")):
        with pytest.raises(sfmnet.SfmnetError, match=message):
            sfmnet.CommandLearner(**settings).fit(sensors, commands)


class Labels(list):
    """What a pandas index offers: row labels that compare with ``equals``."""

    def equals(self, other: object) -> bool:
        return list(self) == list(other)


class Frame:
    """What a pandas DataFrame offers a learner: named columns, row labels and its values as an array (pandas is not
    required); a one-dimensional one stands for a Series."""

    def __init__(self, values: np.ndarray, columns: list[str] | None = None, index: list | None = None) -> None:
        self.values = values
        self.index = Labels(range(len(values)) if index is None else index)
        if columns is not None:
            self.columns = columns

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        return self.values if dtype is None else self.values.astype(dtype)

    def __getitem__(self, names: list) -> Frame:
        return Frame(self.values[:, [self.columns.index(name) for name in names]], list(names), self.index)


def test_arguments_whose_row_labels_differ_are_refused():
    """Tables and series are paired by position, as arrays are: where their row labels (a pandas index) differ, say
    so rather than pair each reading with another row's load, time or command (a frame filtered or sorted on its own)."""
    table = np.arange(40.0).reshape(10, 4)
    readings = Frame(table[:, :3], ["a", "b", "c"], index=list(range(10, 20)))
    shuffled = list(range(10, 20))[::-1]
    with pytest.raises(sfmnet.SfmnetError, match=r"^loads and readings have different row labels \(index\): .*loads.reindex\(readings.index\)"):
        sfmnet.calibrate(readings, magnitude=1.0, loads=Frame(table[:, 3:], ["x"], index=shuffled))
    with pytest.raises(sfmnet.SfmnetError, match=r"^time and readings have different row labels"):
        sfmnet.calibrate(readings, magnitude=1.0, axes=["x", "y"], time=Frame(table[:, 0], index=shuffled))
    with pytest.raises(sfmnet.SfmnetError, match=r"^commands and sensors have different row labels"):
        sfmnet.CommandLearner().fit(readings, Frame(np.array(["go"] * 5 + ["stop"] * 5), index=shuffled))


def test_calibrate_and_apply_read_a_table_by_its_column_names(tmp_path: Path):
    """A hostile tester's: a DataFrame's columns were read by position, so a reordered frame gave loads 222 % off
    through apply with no warning, and channels=[...] named a reordered frame's columns wrongly."""
    write_session(tmp_path / "session.csv")
    header, table = read_session(tmp_path / "session.csv")
    channels, axes = header[1:7], header[7:10]
    reference = sfmnet.calibrate(table[:, 1:7], magnitude=9.81, loads=table[:, 7:10], time=table[:, 0], channels=channels, axes=axes)
    order = [3, 0, 5, 1, 4, 2]
    readings = Frame(table[:, 1:7][:, order], [channels[i] for i in order])
    loads = Frame(table[:, [9, 7, 8]], [axes[2], axes[0], axes[1]])
    # The table's names are the channels and axes, in the table's order...
    named = sfmnet.calibrate(readings, magnitude=9.81, loads=loads, time=table[:, 0])
    assert named.channels == readings.columns and named.axes == loads.columns
    # ... or channels=[...] and axes=[...] pick them by name.
    picked = sfmnet.calibrate(readings, magnitude=9.81, loads=loads, time=table[:, 0], channels=channels, axes=axes)
    np.testing.assert_allclose(picked.matrix.numpy(), reference.matrix.numpy(), rtol=0, atol=1e-9)
    expected = reference.apply(table[:, 1:7])
    np.testing.assert_array_equal(reference.apply(table[::-1, 1:7]), expected[::-1])  # a reversed view, negative strides
    for calibration in (reference, named, picked):
        # Whatever the order of the table's columns, or of the calibration's, each load is in its axis's column.
        applied = calibration.apply(readings)[:, [calibration.axes.index(axis) for axis in axes]]
        np.testing.assert_allclose(applied, expected, rtol=0, atol=1e-9 * np.abs(expected).max())
    with pytest.raises(sfmnet.SfmnetError, match=r"readings has no column s5: the calibration's channels are .*read by name"):
        reference.apply(Frame(table[:, 1:7], [*channels[:5], "ch9"]))
    # A tester's: a time column left among the channels was "not a numeric array", the column unnamed.
    stamped = Frame(np.column_stack([np.full(len(table), "2026-12-07T10:00", dtype=object), table[:, 1:7]]), ["stamp", *channels])
    with pytest.raises(sfmnet.SfmnetError, match=r"^column 'stamp' of readings is not numbers .*: pick the columns to read by name, channels=\[...\], and give a time"):
        sfmnet.calibrate(stamped, magnitude=9.81, loads=loads)
    with pytest.raises(sfmnet.SfmnetError, match="loads has no column fw: the axes asked for are fw"):
        sfmnet.calibrate(readings, magnitude=9.81, loads=loads, axes=["fw", "fy", "fz"])
    # A second tester's: a string split into letters, a count ignored beside a table, names that clash unexplained.
    with pytest.raises(sfmnet.SfmnetError, match=r"^channels='s0' is one string: give a list of names"):
        sfmnet.calibrate(readings, magnitude=9.81, loads=loads, channels="s0")
    with pytest.raises(sfmnet.SfmnetError, match=r"^channels=3 but readings has 6 columns"):
        sfmnet.calibrate(readings, magnitude=9.81, loads=loads, channels=3)
    with pytest.raises(sfmnet.SfmnetError, match=r"not channels=\['0', .*\('0', '1', '2' named twice\)$"):
        sfmnet.calibrate(Frame(table[:, 1:7], list(range(6))), magnitude=9.81, loads=Frame(table[:, 7:10], [0, 1, 2]))


def test_command_learner_reads_a_table_by_its_column_names():
    """A hostile tester's: fitted on a DataFrame, predicting on its columns reordered scored 0.19 against 0.99, by
    position, with no warning (scikit-learn refuses; apply matches a calibration's channels by name)."""
    generator = np.random.default_rng(1)
    sensors = generator.normal(size=(400, 3)) * [1.0, 5.0, 0.2]
    commands = np.where(sensors[:, 0] > 0, "go", "stop")
    learner = sfmnet.CommandLearner(rank=2).fit(Frame(sensors, ["left", "right", "gyro"]), commands)
    assert list(learner.feature_names_in_) == ["left", "right", "gyro"]
    reordered = Frame(sensors[:, [2, 0, 1]], ["gyro", "left", "right"])
    np.testing.assert_array_equal(learner.predict(reordered), learner.predict(Frame(sensors, ["left", "right", "gyro"])))
    with pytest.raises(sfmnet.SfmnetError, match="sensors has no column right: the learner was fitted on columns left, right, gyro"):
        learner.predict(Frame(sensors, ["left", "rigth", "gyro"]))
    with pytest.warns(UserWarning, match="sensors has no column names, but the learner was fitted on named columns"):
        learner.predict(sensors)
    # Numbers are names too (a DataFrame made from an array), and a name given twice is refused.
    numbered = sfmnet.CommandLearner(rank=2).fit(Frame(sensors, [0, 1, 2]), commands)
    np.testing.assert_array_equal(numbered.predict(Frame(sensors[:, [2, 0, 1]], [2, 0, 1])), numbered.predict(Frame(sensors, [0, 1, 2])))
    # Beyond 1e15, as the command line refuses (times 1e160 overflowed the standardisation and scored 0.38).
    with pytest.raises(sfmnet.SfmnetError, match=r"sensors has 1200 values beyond 1e\+15 \(first: row 0, column 0\)"):
        sfmnet.CommandLearner(rank=2).fit(sensors * 1e160, commands)
    with pytest.raises(sfmnet.SfmnetError, match=r"sensors has columns named twice \(a\)"):
        sfmnet.CommandLearner(rank=2).fit(Frame(sensors, ["a", "a", "c"]), commands)
    # At a rank of the sensors' count every sensor vector fits: the confidence is 1, not rounding to rank by.
    assert (sfmnet.CommandLearner(rank=3).fit(sensors, commands).predict_confidence(sensors) == 1).all()
    with pytest.raises(sfmnet.SfmnetError, match="^rank is 4 but there are 3 sensors: commands read from the sensors alone are undetermined"):
        sfmnet.CommandLearner(rank=4).fit(sensors, commands)
    with pytest.raises(sfmnet.SfmnetError, match=r"command column c0 takes one value \('go'\) on every training row"):
        sfmnet.CommandLearner().fit(sensors, np.full(400, "go"))


def test_integer_counts_and_wrong_widths_in_apply(tmp_path: Path):
    _, table = read_session(write_session_path(tmp_path))
    cal = sfmnet.calibrate(table[:, 1:7], magnitude=9.81, loads=table[:, 7:10])
    counts = np.round(table[:5, 1:7] * 1000)
    scaled = sfmnet.Calibration(cal.matrix / 1000, cal.offset * 1000, cal.channels, cal.axes)
    assert torch.allclose(scaled.apply(torch.from_numpy(counts.astype(np.int64))), torch.from_numpy(scaled.apply(counts)))
    with pytest.raises(sfmnet.SfmnetError, match=r"give \(f, 6\) raw readings"):
        cal.apply(torch.zeros(4, 5, dtype=torch.float64))


def test_mirror_hint_from_python_with_n_minus_one_known_loads(tmp_path: Path):
    """Two known loads in 3-D leave a mirror image; the hint, given as a mapping, picks the right one. The hint is
    on a row whose load points out of the known loads' plane, along that plane's normal (where the images differ)."""
    _, table = read_session(write_session_path(tmp_path))
    readings, loads = table[:, 1:7], table[:, 7:10]
    reference = sfmnet.calibrate(readings, magnitude=9.81, loads=loads, axes=["fx", "fy", "fz"])
    two_known = loads.copy()
    two_known[np.flatnonzero(np.isfinite(loads).all(axis=1))[-1]] = np.nan
    known = two_known[np.isfinite(two_known).all(axis=1)]
    normal = np.cross(known[0], known[1])
    unknown = np.flatnonzero(np.isnan(two_known).any(axis=1))
    # The hint: roughly which way that row's load pointed (here from the three-load calibration).
    applied = np.asarray(reference.apply(readings))
    row = int(unknown[np.argmax(np.abs(applied[unknown] @ normal))])
    axis = int(np.argmax(np.abs(normal)))
    hint = {"row": row, "axis": ["fx", "fy", "fz"][axis], "sign": int(np.sign(applied[row, axis]))}
    with pytest.raises(sfmnet.SfmnetError, match="mirror"):
        sfmnet.calibrate(readings, magnitude=9.81, loads=two_known, axes=["fx", "fy", "fz"])
    cal = sfmnet.calibrate(readings, magnitude=9.81, loads=two_known, axes=["fx", "fy", "fz"], data={"mirror_hint": hint})
    assert (cal.matrix - reference.matrix).norm() < 0.01 * reference.matrix.norm()
    flipped = {**hint, "sign": -hint["sign"]}
    mirrored = sfmnet.calibrate(readings, magnitude=9.81, loads=two_known, axes=["fx", "fy", "fz"], data={"mirror_hint": flipped})
    assert (mirrored.matrix - reference.matrix).norm() > 0.5 * reference.matrix.norm()


@pytest.mark.parametrize(
    "arguments, message",
    [
        ({"model.refinement": "bogus"}, r"model.refinement is 'bogus'"),
        ({"trainer": {"max_epochs": -1}}, r"trainer.max_epochs is -1: give a whole number >= 1"),
        ({"trainer": {"max_epochs": 0}}, r"trainer.max_epochs is 0: give a whole number >= 1 \(0 trains nothing"),
        ({"magnitude": "abc"}, r"magnitude is 'abc': give a number"),
        ({"readings": np.ones((99, 6)) * 1j}, r"readings is complex"),
        ({"loads": None}, r"name the n load axes"),
        # checked before the data module is built from it
        ({"data": {"static_intervals": True, "static": {"threshold": "abc"}}}, r"data.static.threshold is 'abc': give a number > 0"),
    ],
)
def test_more_bad_input_is_one_line(tmp_path: Path, arguments: dict, message: str):
    _, table = read_session(write_session_path(tmp_path))
    given = {"readings": table[:, 1:7], "magnitude": 9.81, "loads": table[:, 7:10], **arguments}
    with pytest.raises(sfmnet.SfmnetError, match=message):
        sfmnet.calibrate(**given)


def test_run_dir_that_is_a_file_is_refused(tmp_path: Path):
    _, table = read_session(write_session_path(tmp_path))
    (tmp_path / "file").write_text("mine")
    for run_dir in (tmp_path / "file", tmp_path / "file" / "run"):
        with pytest.raises(sfmnet.SfmnetError, match="is a file"):
            sfmnet.calibrate(table[:, 1:7], magnitude=9.81, loads=table[:, 7:10], run_dir=run_dir)
    assert (tmp_path / "file").read_text() == "mine"


def test_every_load_known_calibrates(tmp_path: Path):
    """No row of unknown orientation: nothing to draw of the recovered motion, and the fit is least squares' (the
    motion figure once failed on its empty array)."""
    rng = np.random.default_rng(0)
    shape = rng.normal(size=(3, 6))
    directions = rng.normal(size=(300, 3))
    loads = 9.81 * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    readings = loads @ shape + 0.01 * rng.normal(size=(300, 6))
    calibration = sfmnet.calibrate(readings, 9.81, loads, run_dir=tmp_path / "run")
    np.testing.assert_allclose(calibration.matrix, np.linalg.pinv(shape).T, atol=2e-3)
    assert not (tmp_path / "run" / "figures" / "shape_from_motion_motion.png").exists()
