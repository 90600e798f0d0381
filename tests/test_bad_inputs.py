"""Every bad input a user can give, in one table: each is refused with one message naming the cause and the remedy.

Each case prepares its files in ``tmp_path`` and returns the action to run; the action must
raise :class:`SfmnetError` whose text matches. The CLI turns exactly these errors into one line
on stderr and exit status 2 (``tests/test_cli.py`` checks that path end to end, and the last
cases here run it for ``train`` and ``apply``).
"""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from sfmnet.apply import apply_calibration
from sfmnet.cli import config_dir, refuse_bare_words
from sfmnet.config_check import check_overrides
from sfmnet.readers.ft_printed_sensor import FtPrintedSensorDataModule
from sfmnet.readers.row_file import RowFileDataModule
from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor, write_stream_csv
from sfmnet.readers.sensorimotor_csv import SensorimotorCsvDataModule
from sfmnet.errors import SfmnetError
from sfmnet.training.run import train
from tests.conftest import REPO, compose_config, lightning_checkpoint, real_data, write_session
from tests.test_csv_and_apply import set_cell

Action = Callable[[], object]


def clock_times_with_a_gap(rows: list[list[str]]) -> None:
    """The time column as a logger's ISO 8601 stamps (read as seconds), one of them lost."""
    for i, row in enumerate(rows[1:]):
        row[0] = f"2026-12-07T13:52:{i // 100:02d}.{i % 100:02d}0"
    rows[40][0] = "n/a"


def calibrate(tmp_path: Path, *overrides: str, edit=None, known_loads: int = 3) -> Action:
    """Write a simulated session (optionally edited) and return the calibrate_csv run on it."""
    session = tmp_path / "session.csv"
    write_session(session, known_loads=known_loads, edit=edit)
    cfg = compose_config(
        ["experiment=calibrate_csv", f"data.path={session}", "data.magnitude=9.81", "data.time_column=time", *overrides]
    )
    return lambda: train(cfg, tmp_path / "run")


def stream(tmp_path: Path, *overrides: str, edit=None, known_loads: int = 3) -> Action:
    """The same simulated session calibrated by streaming it (experiment=calibrate_stream)."""
    return calibrate(tmp_path, "experiment=calibrate_stream", *overrides, edit=edit, known_loads=known_loads)


def blank_last_load(rows: list[list[str]]) -> None:
    rows[-1][9] = ""


def blank_lines_after_header(count: int, then):
    """``then``'s edit, and ``count`` blank lines after the header: every later row's file line moves down by ``count``."""

    def edit(rows: list[list[str]]) -> None:
        then(rows)
        rows[1:1] = [[] for _ in range(count)]

    return edit


def calibrate_file(tmp_path: Path, text: str | bytes, name: str = "session.csv") -> Action:
    path = tmp_path / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    cfg = compose_config(["experiment=calibrate_csv", f"data.path={path}", "data.magnitude=9.81"])
    return lambda: train(cfg, tmp_path / "run")


def rename_column(column: int, name: str):
    def edit(rows: list[list[str]]) -> None:
        rows[0][column] = name

    return edit


def flatten_channel(column: int, value: str = "0.5"):
    def edit(rows: list[list[str]]) -> None:
        for row in rows[1:]:
            row[column] = value

    return edit


def keep_rows(count: int):
    def edit(rows: list[list[str]]) -> None:
        del rows[1 + count : -3]

    return edit


def project_unknown_loads(keep_axes: int):
    """Rewrite the unknown rows' readings as if the loads lay on a line (1) or a plane (2)."""

    def edit(rows: list[list[str]]) -> None:
        readings = np.array([[float(v) for v in row[1:7]] for row in rows[1:]])
        unknown = [i for i, row in enumerate(rows[1:]) if row[7] == ""]
        centred = readings[unknown] - readings[unknown].mean(axis=0)
        u, s, vt = np.linalg.svd(centred, full_matrices=False)
        flat = readings[unknown].mean(axis=0) + (u[:, :keep_axes] * s[:keep_axes]) @ vt[:keep_axes]
        for i, values in zip(unknown, flat):
            rows[1 + i][1:7] = [f"{v:.9f}" for v in values]

    return edit


def constant_column(name: str, value: str):
    def edit(rows: list[list[str]]) -> None:
        rows[0].append(name)
        for row in rows[1:]:
            row.append(value)

    return edit


def contradict_known_loads(rows: list[list[str]]) -> None:
    """The load along +fy written as pointing nearly along -fx (same magnitude): 80 degrees off."""
    angle = np.radians(170.0)
    rows[-2][7:10] = [f"{9.81 * np.cos(angle):.6f}", f"{9.81 * np.sin(angle):.6f}", "0.000000"]


def world_frame_known_loads(rows: list[list[str]]) -> None:
    """Every known load written as gravity in the world's frame, (0, 0, -9.81), as a tester's robot log gave them."""
    for row in rows[1:]:
        if row[7] != "":
            row[7:10] = ["0.000000", "0.000000", "-9.810000"]


def trained_calibration(tmp_path: Path) -> Path:
    calibrate(tmp_path)()
    return tmp_path / "run" / "calibration.json"


def write_text(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def apply_to(tmp_path: Path, calibration: Path, readings_text: str | None = None, output_exists: bool = False) -> Action:
    source = tmp_path / "readings.csv"
    if readings_text is None:
        write_session(source)
    else:
        source.write_text(readings_text)
    output = tmp_path / "loads.csv"
    if output_exists:
        output.write_text("keep me\n")
    return lambda: apply_calibration(calibration, source, output, overwrite=False)


def corrupt_calibration(tmp_path: Path) -> Action:
    path = tmp_path / "calibration.json"
    path.write_text('{"matrix": [[1, 2], ')
    return apply_to(tmp_path, path, "s0,s1\n1,2\n")


def wrong_channel_calibration(tmp_path: Path) -> Action:
    calibration = trained_calibration(tmp_path)
    return apply_to(tmp_path, calibration, "a,b,c\n1,2,3\n")


def ft_printed_sensor_without_three_poses(tmp_path: Path) -> Action:
    """The real sensor's folder with three of the first configuration's twelve pose files left out (a hostile
    tester's), the default known poses 0, 4 and 9 kept."""
    folder = tmp_path / "ft"
    folder.mkdir()
    for file in sorted(real_data("ft_printed_sensor").glob("data_0.0_*.csv"))[3:]:
        (folder / file.name).symlink_to(file)
    configurations = OmegaConf.to_container(OmegaConf.load(REPO / "conf" / "data" / "ft_printed_sensor.yaml").configurations)
    return lambda: FtPrintedSensorDataModule(str(folder), configurations, [0], axes=3, known_poses=[0, 4, 9]).setup()


def sensorimotor(tmp_path: Path, text: str, sensors: list[str], commands: list[str]) -> Action:
    path = tmp_path / "log.csv"
    path.write_text(text)
    return lambda: SensorimotorCsvDataModule(str(path), sensor_columns=sensors, command_columns=commands).setup()


def log_text(rows: int, constant: float | None = None) -> str:
    generator = np.random.default_rng(0)
    lines = ["a,b,cmd"]
    for i in range(rows):
        a, b = generator.uniform(size=2)
        lines.append(f"{a:.4f},{b if constant is None else constant:.4f},{['go', 'stop', 'turn'][i % 3]}")
    return "\n".join(lines) + "\n"


def row_file(tmp_path: Path, name: str, content) -> Action:
    path = tmp_path / name
    if isinstance(content, str):
        path.write_text(content)
    else:
        np.save(path, content)
    return lambda: RowFileDataModule(str(path)).setup()


def pca_with_cell(tmp_path: Path, row: int, value: float) -> Action:
    """PCA (experiment=pca) of 12,000 x 4 rows whose ``row`` (0-based) holds ``value`` in its column 2."""
    rows = np.random.default_rng(0).normal(size=(12_000, 4))
    rows[row, 2] = value
    np.save(tmp_path / "rows.npy", rows)
    cfg = compose_config(["experiment=pca", f"data.path={tmp_path / 'rows.npy'}", "model.rank=2"])
    return lambda: train(cfg, tmp_path / "run")


def pca_rank(tmp_path: Path) -> Action:
    np.save(tmp_path / "rows.npy", np.random.default_rng(0).normal(size=(100, 4)))
    cfg = compose_config(["experiment=pca", f"data.path={tmp_path / 'rows.npy'}", "model.rank=7"])
    return lambda: train(cfg, tmp_path / "run")


def unreadable_npy(tmp_path: Path) -> Action:
    (tmp_path / "session.npy").write_bytes(b"\x93NUMPY garbage that is not an array")
    cfg = compose_config(["experiment=calibrate_csv", f"data.path={tmp_path / 'session.npy'}", "data.magnitude=9.81"])
    return lambda: train(cfg, tmp_path / "run")


def continuous(
    tmp_path: Path, poses: int, known_in_motion: bool = False, known_at_edge: bool = False, hold: float = 2.0,
    retime: Callable[[torch.Tensor], torch.Tensor] | None = None,
) -> Action:
    """A continuous recording (sfmnet/simulators/simulated_stream.py) calibrated with its time column (static intervals
    on); ``retime`` rewrites the time column as a faulty logger would."""
    generator = torch.Generator().manual_seed(0)
    sensor = stream_sensor(6, 9.81, noise_fraction=0.001, offset_scale=0.2, generator=generator)
    recording = simulate_stream(sensor, 1.0, poses=poses, hold=hold, rate=50.0, generator=generator)
    if retime is not None:
        recording.time[:] = retime(recording.time)
    if known_in_motion:
        # A load written on line 42 (data row 40), in the middle of the first move.
        recording.known_loads[40] = recording.loads[40]
    if known_at_edge:
        # One known row (line 75, data row 73) two samples before the first hold begins (row 75).
        recording.known_loads[73] = recording.loads[75]
    write_stream_csv(recording, tmp_path / "stream.csv")
    cfg = compose_config([
        "experiment=calibrate_csv", f"data.path={tmp_path / 'stream.csv'}", "data.mass=1.0", "data.time_column=time",
    ])
    return lambda: train(cfg, tmp_path / "run")


def fifo(tmp_path: Path, name: str) -> Path:
    """A FIFO at ``tmp_path / name``. Should a reader open it after all, a writer comes and goes every
    second from 10 s on (for a minute), so each open sees an empty file and the case fails instead of hanging."""
    path = tmp_path / name
    os.mkfifo(path)

    def unblock() -> None:
        time.sleep(10)
        for _ in range(60):
            try:
                os.close(os.open(path, os.O_WRONLY | os.O_NONBLOCK))
            except OSError:
                pass  # no reader now: the FIFO was refused, as it should be
            time.sleep(1)

    threading.Thread(target=unblock, daemon=True).start()
    return path


def calibrate_path(tmp_path: Path, path: Path, experiment: str = "calibrate_csv") -> Action:
    cfg = compose_config([f"experiment={experiment}", f"data.path={path}", "data.magnitude=9.81"])
    return lambda: train(cfg, tmp_path / "run")


def sensorimotor_empty_command(tmp_path: Path, cell: str, labels: list[str], blank_lines: int = 0) -> Action:
    """A log whose command on line 5 is ``cell`` (the rest cycle through ``labels``), ``blank_lines`` after the header."""
    lines = log_text(300).splitlines()
    lines = [lines[0], *(f"{line.rsplit(',', 1)[0]},{labels[i % len(labels)]}" for i, line in enumerate(lines[1:]))]
    lines[4] = f"{lines[4].rsplit(',', 1)[0]},{cell}"
    lines[1:1] = [""] * blank_lines
    return sensorimotor(tmp_path, "\n".join(lines) + "\n", ["a", "b"], ["cmd"])


def array_file(tmp_path: Path, name: str, write: Callable[[Path], object], *overrides: str) -> Action:
    """``write`` makes ``name`` in ``tmp_path``; returns the run of ``overrides`` (an experiment) on it as data.path."""
    path = tmp_path / name
    write(path)
    cfg = compose_config([*overrides, f"data.path={path}"])
    return lambda: train(cfg, tmp_path / "run")


def calibrate_array(tmp_path: Path, name: str, write: Callable[[Path], object]) -> Action:
    """A calibrate_csv run on an array file, its columns named s0..s3, fx, fy, fz."""
    return array_file(
        tmp_path, name, write, "experiment=calibrate_csv", "data.magnitude=9.81", "data.columns=[s0,s1,s2,s3,fx,fy,fz]"
    )


def session_columns(**columns: np.ndarray) -> Callable[[Path], object]:
    return lambda path: np.savez(path, **columns)


def resume_from(tmp_path: Path, write: Callable[[Path], object]) -> Action:
    """The default run resumed from a checkpoint file that ``write`` makes."""
    write(tmp_path / "last.ckpt")
    cfg = compose_config([f"ckpt_path={tmp_path / 'last.ckpt'}"])
    return lambda: train(cfg, tmp_path / "run")


def truncated_checkpoint(path: Path) -> None:
    lightning_checkpoint(path)
    path.write_bytes(path.read_bytes()[:200])


def calibration_json(tmp_path: Path, matrix_text: str) -> Action:
    """apply with a calibration file whose matrix is ``matrix_text`` (JSON), for channels s0, s1 and one axis."""
    path = tmp_path / "calibration.json"
    path.write_text(f'{{"matrix": {matrix_text}, "offset": [0, 0], "channels": ["s0", "s1"], "axes": ["fx"]}}')
    return apply_to(tmp_path, path, "s0,s1\n1,2\n")


def apply_into(tmp_path: Path, output: Path, *patches) -> Action:
    """apply of a valid calibration writing ``output``, under the ``patches`` (file-system faults)."""
    calibration = tmp_path / "calibration.json"
    calibration.write_text('{"matrix": [[1, 2]], "offset": [0, 0], "channels": ["s0", "s1"], "axes": ["fx"]}')
    (tmp_path / "readings.csv").write_text("s0,s1\n1,2\n")

    def action() -> None:
        with contextlib.ExitStack() as stack:
            for patch in patches:
                stack.enter_context(patch)
            apply_calibration(calibration, tmp_path / "readings.csv", output, overwrite=False)

    return action


def read_only_run_dir(tmp_path: Path) -> Action:
    """A run into a folder without write permission (root ignores the bits, so the check is shown them)."""
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    cfg = compose_config([])

    def action() -> None:
        with mock.patch("os.access", lambda path, mode: not Path(path).is_relative_to(locked)):
            train(cfg, locked / "run")

    return action


def run_into_file(tmp_path: Path, run_dir: str) -> Action:
    """A run whose directory is, or lies under, the file ``tmp_path/taken``."""
    (tmp_path / "taken").write_text("keep me\n")
    cfg = compose_config([])
    return lambda: train(cfg, tmp_path / run_dir)


def overrides_of(*overrides: str, sweep: bool = False) -> Callable[[Path], Action]:
    return lambda tmp_path: (lambda: check_overrides([item.format(tmp=tmp_path) for item in overrides], config_dir(), sweep=sweep))


def escaped_reference(tmp_path: Path) -> Action:
    cfg = compose_config(["experiment=calibrate_csv", 'data.path="/data/a\\${x}.csv"', "data.magnitude=9.81"])
    return lambda: train(cfg, tmp_path / "run")


def denied(*args, **kwargs) -> None:
    raise PermissionError(errno.EACCES, "Permission denied")


def disk_full(*args) -> None:
    raise OSError(errno.ENOSPC, "No space left on device")


def simulated(*overrides: str) -> Callable[[Path], Action]:
    return lambda tmp_path: (lambda: train(compose_config(list(overrides)), tmp_path / "run"))


RNG = np.random.default_rng(0)
SEVEN_COLUMNS = RNG.normal(size=(50, 7))


CASES: dict[str, tuple[Callable[[Path], Action], str]] = {
    # train, calibration from a file (conf/data/csv.yaml)
    "empty file": (lambda t: calibrate_file(t, ""), r"is empty: give a CSV with a header row"),
    "header only": (lambda t: calibrate_file(t, "s0,s1,fx,fy,fz\n"), r"has a header but no data rows"),
    # A hostile tester's: every channel was called constant.
    "one data row": (lambda t: calibrate_file(t, "s0,s1,s2,fx,fy,fz\n1,2,3,,,\n"), r"has one data row: a calibration needs"),
    "non-numeric cell": (lambda t: calibrate(t, edit=set_cell(5, 2, "n/a")), r"channel column 's1' of .* is not numeric"),
    "NaN value": (lambda t: calibrate(t, edit=set_cell(7, 3, "nan")), r"1 empty, NaN or infinite reading values \(first: line 7 column s2\)"),
    "infinite value": (lambda t: calibrate(t, edit=set_cell(9, 1, "-inf")), r"1 empty, NaN or infinite reading values \(first: line 9 column s0\)"),
    # A hostile tester's (through the Python API): "gives only some of fx, fy, fz".
    "infinite known load": (lambda t: calibrate(t, edit=set_cell(99, 8, "inf")), r"1 infinite load values \(first: line 99 column fy \(inf\)\)"),
    # A hostile tester's: the refusal named no remedy.
    "ISO clock times, one lost": (
        lambda t: calibrate(t, edit=clock_times_with_a_gap), r"^line 41 of .*session.csv has time 'n/a' among dates or clock times: give every row a time"
    ),
    "stream: ISO clock times, one lost": (
        lambda t: stream(t, edit=clock_times_with_a_gap), r"session.csv line 41 has a non-numeric cell \('n/a' in column time\): every cell must be a number"
    ),
    # Clock times listed among the channels (a time column not named as one).
    "clock times as a channel": (
        lambda t: calibrate(t, "data.time_column=null", "data.channel_columns=[time,s0,s1,s2,s3,s4,s5]", edit=clock_times_with_a_gap),
        r"channel column 'time' of .* is not numeric: .*\(dates or clock times: a time column may hold them, named by data.time_column",
    ),
    # A hostile tester's: calibrated in an arbitrary frame labelled fx, fy, fz (175 % off, trusted, no warning).
    "load columns named, empty on every row": (
        lambda t: calibrate(t, known_loads=0),
        r"the load columns fx, fy, fz are empty on every row of .*session.csv, so no known load fixes the frame: .*"
        r"set data.load_columns=\[\]",
    ),
    "no known loads, their empty columns left in": (
        lambda t: calibrate(t, "data.load_columns=[]", "data.axes=[x,y,z]", known_loads=0),
        r"columns fx, fy, fz of .*session.csv are empty on every row, so not a channel: list the channels with data.channel_columns",
    ),
    "NaN value after blank lines": (
        lambda t: calibrate(t, edit=blank_lines_after_header(3, set_cell(7, 3, "nan"))),
        r"1 empty, NaN or infinite reading values \(first: line 10 column s2\)",
    ),
    "value of 1e30": (lambda t: calibrate(t, edit=set_cell(4, 2, "1e30")), r"1 reading values beyond 1e\+15 \(first: line 4 column s1 \(1e\+30\)\): a corrupt cell or a unit slip"),
    "duplicate column names": (lambda t: calibrate(t, edit=rename_column(2, "s0")), r"duplicate column names: s0; rename them"),
    "channel named twice": (lambda t: calibrate(t, "data.channel_columns=[s0,s0,s1,s2,s3]"), r"column 's0' is named as a channel column twice: give each column one role, once"),
    "time column named as a channel": (lambda t: calibrate(t, "data.channel_columns=[time,s0,s1,s2,s3,s4,s5]"), r"column 'time' is named as both a channel and a time column"),
    "missing column": (lambda t: calibrate(t, "data.load_columns=[fx,fy,fzz]"), r"load column 'fzz' is not in .* \(did you mean 'fz'\?\)"),
    "four load columns": (lambda t: calibrate(t, "data.load_columns=[fx,fy,fz,s5]"), r"4 load axes \(fx, fy, fz, s5\): a calibration has 2"),
    "fewer channels than loads": (lambda t: calibrate(t, "data.channel_columns=[s0,s1]"), r"2 channel columns for 3 load axes"),
    "fewer samples than unknowns": (lambda t: calibrate(t, edit=keep_rows(5)), r"only 8 samples for 9 unknowns of the metric constraint with offsets"),
    "collinear motion": (lambda t: calibrate(t, edit=project_unknown_loads(1)), r"collinear"),
    "coplanar motion": (lambda t: calibrate(t, edit=project_unknown_loads(2)), r"coplanar"),
    "constant channel": (lambda t: calibrate(t, edit=flatten_channel(4)), r"channel s3 of .* is constant"),
    # A hostile tester's: 1.234 is not exact in binary, so the column's standard deviation came out 1.5e-13, not 0.
    "constant channel, inexact value": (lambda t: calibrate(t, edit=flatten_channel(4, "1.234")), r"channel s3 of .* is constant"),
    "wrong magnitude": (lambda t: calibrate(t, "data.magnitude=12.0"), r"has magnitude 9.81 but data.magnitude is 12"),
    "contradictory known loads": (lambda t: calibrate(t, edit=contradict_known_loads), r"known load \d of 3 lies \d+ degrees from where the readings put it \(at (9\d|10\d) % of its size\) .*: the known loads contradict each other"),
    "n-1 known loads without the mirror bit": (lambda t: calibrate(t, known_loads=2), r"only up to a mirror image: set data.mirror_hint="),
    "known loads in the world's frame": (
        lambda t: calibrate(t, edit=world_frame_known_loads),
        r"span 1 of 3 load directions \(the known rows' readings point up to \d+ degrees from their mean direction where their "
        r"loads lie on one line: .*not "
        r"gravity in the world's frame\).*, or none \(data.load_columns=\[\]",
    ),
    "non-existent path": (lambda t: (lambda: train(compose_config(["experiment=calibrate_csv", f"data.path={t / 'nope.csv'}", "data.magnitude=9.81"]), t / "run")), r"nope.csv does not exist: check data.path"),
    "unreadable file": (unreadable_npy, r"cannot be read as .npy"),
    # A new user's, run from another folder: the built-in experiments' recordings were "not a folder ...: check data.path".
    "real recordings' folder missing": (
        lambda t: (lambda: train(compose_config(["experiment=ft_printed_sensor_6dof", "paths.data_dir=nowhere/data"]), t / "run")),
        r"^the real recordings' folder nowhere/data \(paths.data_dir, relative to .*, the folder you run in\) does not exist: set "
        r"SFMNET_DATA_DIR to the folder holding ft_printed_sensor/",
    ),
    # 3 known poses give 9 equations less the frame's 3: with 2 more poses, 8 for the 9 unknowns.
    "too few static intervals": (
        lambda t: continuous(t, poses=5), r"5 static intervals found but a 3-axis calibration with offsets and 3 known poses needs at least 6 \(the unknowns "
        r"of its metric constraint\): record more poses held still, each for at least 1.6 s \(the shortest interval kept, 1.08 s, and "
        r"the moving window, 0.54 s, half of which reaches into the move at each end\)",
    ),
    "known load in motion": (lambda t: continuous(t, poses=10, known_in_motion=True), r"the known load on line 42 of .*stream.csv was recorded in motion"),
    "time cell empty": (
        lambda t: calibrate(t, edit=set_cell(6, 0, "")),
        r"the time on line 6 of .*session.csv is empty or not a number: rows must be in time order",
    ),
    "time cell empty after blank lines, streamed": (
        lambda t: stream(t, edit=blank_lines_after_header(2, set_cell(6, 0, ""))),
        r"the time on line 8 of .*session.csv is empty or not a number",
    ),
    "time out of order": (
        lambda t: calibrate(t, edit=set_cell(6, 0, "0.001")),
        r"the time on line 6 of .*session.csv is 0.029 s before the row before's, more than 2 ticks of 0.01 s \(jitter\)",
    ),
    "time in ms read as s": (
        lambda t: continuous(t, poses=10, retime=lambda time: time * 1000),
        r"the static-interval window of 0.5 s spans under two rows of this recording \(20 s a row\): check data.time_unit",
    ),
    "time in s read as ms": (
        lambda t: continuous(t, poses=10, retime=lambda time: time / 1000),
        r"the static-interval window of 0.5 s spans [\d,]+ rows, over a quarter of the recording's 1,750 \(2e-05 s a row\): "
        r"check data.time_unit \(a time column in s read as ms, or a spreadsheet's serial dates, which need data.time_unit=d\?\)",
    ),
    # Every third row 10 periods after the one before (a rate that changes within the file, or stamps not the rows').
    "time column of two rates": (
        lambda t: continuous(t, poses=10, retime=lambda time: time + 0.2 * (torch.arange(len(time)) // 3)),
        r"583 of the time column's 1,749 steps are gaps \(over 5 ticks of 0.02 s\): its rate changes within the file.*"
        r"a burst of rows at each held pose .*data.static_intervals=false.*data.group_column",
    ),
    "time spike": (
        lambda t: calibrate(t, edit=set_cell(6, 0, "99.0")),
        r"the time on line 6 of .*session.csv is 99 s after the next row's and the row before's: a corrupt stamp",
    ),
    # A tester's logger restarted halfway: its clock back at 0 on the second half (had: "repair or drop that row").
    "clock restarted": (
        lambda t: continuous(t, poses=10, retime=lambda time: torch.where(time < 10, time, time - 10)),
        r"the time on line \d+ of .*stream.csv is 9.98 s before the row before's: the clock restarted there, or two logs were "
        r"joined, .*split the file where the clock restarts",
    ),
    # Stamped on a host as packets arrive, 2 rows late on average (exponential): 1 in 10 rows steps back past the jitter.
    "stamps that jitter past the rows' spacing": (
        lambda t: continuous(
            t, poses=10, retime=lambda time: time + torch.empty_like(time).exponential_(50.0, generator=torch.Generator().manual_seed(1))
        ),
        r"\d+ of 1,749 steps of the time column \(from line 2 of .*stream.csv\) go back by more than 2 ticks \(of .* s, read from these stamps\), the first "
        r"on line \d+ .*: the stamps jitter by more than the rows' spacing .*sort the rows by time",
    ),
    "time running backwards": (
        lambda t: continuous(t, poses=10, retime=lambda time: time.flip(0)),
        r"the time column does not increase \(its median step is -0.02 s\): rows must be in time order; sort the file",
    ),
    # Held 0.6 s, under the 1 s shortest interval (two 0.5 s windows): the pose was still, not moving.
    "known pose held too briefly": (
        lambda t: continuous(t, poses=12, hold=0.6),
        r"the known load on line \d+ of .*stream.csv was held still for only 0.\d+ s \(\d+ rows\), under the shortest "
        r"static interval of 1.\d+ s there: hold the known pose longer, or lower data.static.min_duration",
    ),
    "known load at an interval's edge": (
        lambda t: continuous(t, poses=10, known_at_edge=True),
        r"the known load on line 75 of .*stream.csv lies at the edge of a static interval",
    ),
    "time column mis-cased": (lambda t: calibrate(t, "data.time_column=Time"), r"time column 'Time' is not in .* \(did you mean 'time'\?\)"),
    "time column misspelt, static intervals off": (
        lambda t: calibrate(t, "data.time_column=tiem", "data.static_intervals=false"), r"time column 'tiem' is not in .* \(did you mean 'time'\?\)",
    ),
    "group column missing": (lambda t: calibrate(t, "data.group_column=pose"), r"group column 'pose' is not in .*session.csv"),
    "group column that is not the pose (a session id)": (
        lambda t: calibrate(
            t, "data.group_column=session", "data.load_columns=[]", "data.axes=[x,y,z]", "data.channel_columns=[s0,s1,s2,s3,s4,s5]",
            edit=constant_column("session", "7"), known_loads=0,
        ),
        r"groups \(static intervals, or data.group_column\) hold 1 poses, .* too few for the 9 unknowns .* "
        r"set model.tie_directions=false if the groups are not poses",
    ),
    "stray quote": (
        lambda t: calibrate_file(t, 's0,s1,fx,fy,fz\n1,2,,,\n"3,4,,,\n5,6,,,\n'),
        r"session.csv line 3: unexpected end of data \(a stray '\"'\?\): quote whole cells",
    ),
    "quote inside a cell": (lambda t: calibrate_file(t, 's0,s1,fx,fy,fz\n1,"2"x,,,\n'), r"session.csv line 2: ',' expected after '\"'"),
    "quoted cell over several lines": (
        lambda t: calibrate_file(t, 's0,s1,fx,fy,fz\n1,"2,,,\n3",4,,,\n'),
        r"line 2 has 6 cells but the header has 5 \(a quoted cell runs over several lines: a stray '\"'\?\)",
    ),
    "decimal commas in a comma-separated file": (
        lambda t: calibrate_file(t, "s0,s1,fx,fy,fz\n1,5,2,,,\n"),
        r"line 2 has 6 cells but the header has 5 \(if ',' is also the decimal mark, save the file ';'-separated\)",
    ),
    # The file already reads its decimal commas: a word among them is no decimal-mark problem.
    "word among decimal commas in a ';'-separated file": (
        lambda t: calibrate_file(t, "s0;s1;s2;fx;fy;fz\n" + "".join(f"{i},5;{i},25;{i % 3},75;;;\n" for i in range(9)) + "abc;1,5;2;;;\n"),
        r"channel column 's0' of .*session.csv is not numeric: \[\"line 11: 'abc'\"\]$",
    ),
    "quoted decimal comma in a comma-separated file": (
        lambda t: calibrate(t, edit=set_cell(5, 2, "1,5")), r"channel column 's1' of .* is not numeric: .*\(',' as the decimal mark",
    ),
    "not UTF-8 text": (lambda t: calibrate_file(t, "s0,s\xb5,fx,fy,fz\n1,2,,,\n".encode("latin-1")), r"line 1 is not UTF-8 text \(byte 0xb5\): save it as 'CSV UTF-8'"),
    "not UTF-8 text further down": (
        lambda t: calibrate_file(t, ("s0,s1,fx,fy,fz\n" + "1,2,,,\n" * 3000 + "3,4,,,\xb5\n").encode("latin-1")),
        r"line 3002 is not UTF-8 text \(byte 0xb5\): save it as 'CSV UTF-8'",
    ),
    "FIFO as data.path": (lambda t: calibrate_path(t, fifo(t, "session.csv")), r"session.csv is a FIFO \(named pipe\), not a regular file: data.path needs"),
    "directory as data.path": (lambda t: calibrate_path(t, t), r"is a directory, not a regular file: data.path needs"),
    # train, a calibration streamed from its file (conf/data/calibration_rows.yaml)
    "stream: time column mis-cased": (lambda t: stream(t, "data.time_column=TIME"), r"time column 'TIME' is not in .*session.csv \(did you mean 'time'\?\)"),
    "stream: time column misspelt, static intervals off": (
        lambda t: stream(t, "data.time_column=tme", "data.static_intervals=false"), r"time column 'tme' is not in .*session.csv \(did you mean 'time'\?\)",
    ),
    "stream: FIFO as data.path": (
        lambda t: calibrate_path(t, fifo(t, "session.csv"), "calibrate_stream"), r"is a FIFO \(named pipe\), not a regular file: data.path needs",
    ),
    "stream: partly known load": (
        lambda t: stream(t, edit=blank_last_load), r"line \d+ of .*session.csv gives only some of fx, fy, fz: fill every load column"
    ),
    "stream: NaN value": (lambda t: stream(t, edit=set_cell(7, 3, "nan")), r"line 7 of .*session.csv has a NaN, empty or infinite channel cell, or one beyond 1e\+15 \(s2\)"),
    "stream: load columns named, empty on every row": (
        lambda t: stream(t, known_loads=0), r"the load columns fx, fy, fz are empty on every row of the file, so no known load"
    ),
    "stream: no known loads, their empty columns left in": (
        lambda t: stream(t, "data.load_columns=[]", "data.axes=[x,y,z]", known_loads=0),
        r"columns fx, fy, fz of .*session.csv are empty on each of the first \d+ rows, so not a channel",
    ),
    "stream: value of 1e30": (
        lambda t: stream(t, edit=set_cell(4, 2, "1e30")), r"line 4 of .*session.csv has a NaN, empty or infinite channel cell, or one beyond 1e\+15 \(s1\)"
    ),
    "stream: NaN value after blank lines": (
        lambda t: stream(t, edit=blank_lines_after_header(2, set_cell(7, 3, "nan"))),
        r"line 9 of .*session.csv has a NaN, empty or infinite channel cell",
    ),
    "stream: missing column": (lambda t: stream(t, "data.load_columns=[fx,fy,fzz]"), r"load column 'fzz' is not in .*session.csv"),
    # A hostile tester's: the stream fitted it (a zero column of C) and called the channel a timestamp that only rises.
    "stream: constant channel": (lambda t: stream(t, edit=flatten_channel(4, "1.234")), r"channel s3 is constant on every row fitted"),
    "stream: wrong magnitude": (
        lambda t: stream(t, "data.magnitude=12.0"), r"known load on line \d+ of .*session.csv has magnitude 9.81 but data.magnitude is 12"
    ),
    "stream: collinear motion": (lambda t: stream(t, edit=project_unknown_loads(1)), r"collinear"),
    "stream: every load known": (lambda t: stream(t, "model.max_known_rows=2"), r"3 rows have known loads \(model.max_known_rows is 2\)"),
    "stream: one pass": (lambda t: stream(t, "trainer.max_epochs=1"), r"needs two passes .* set trainer.max_epochs to 2 or more"),
    "stream: in-memory model": (lambda t: stream(t, "model=shape_from_motion"), r"learns from a 'rotation' recording, which this data does not have"),
    # apply
    "missing calibration.json": (lambda t: apply_to(t, t / "none.json", "s0\n1\n"), r"calibration file .* does not exist"),
    "corrupt calibration.json": (corrupt_calibration, r"cannot be read as JSON"),
    "channel count mismatch at apply": (wrong_channel_calibration, r"lacks channels s0, s1, s2, s3, s4, s5 of the calibration"),
    "apply: FIFO as input": (
        lambda t: apply_to(t, trained_calibration(t)) and (lambda: apply_calibration(t / "run" / "calibration.json", fifo(t, "in.csv"), t / "out.csv", False)),
        r"in.csv is a FIFO \(named pipe\), not a regular file: input= needs",
    ),
    "apply: FIFO as calibration": (lambda t: apply_to(t, fifo(t, "calibration.json")), r"calibration file .* is a FIFO \(named pipe\), not a regular file"),
    "apply: .npz input": (
        lambda t: np.savez(t / "in.npz", s0=np.ones(3)) or (lambda: apply_calibration(trained_calibration(t), t / "in.npz", t / "out.csv", False)),
        r"input=.*in.npz is not a CSV",
    ),
    "apply: a channel named twice in the calibration": (
        lambda t: apply_to(t, write_text(t / "c.json", '{"matrix": [[1, 2]], "offset": [0, 0], "channels": ["s0", "s0"], "axes": ["fx"]}')),
        r"calibration file .*c.json names channel s0 twice",
    ),
    "apply: output is the calibration file": (
        lambda t: apply_to(t, trained_calibration(t)) and (lambda: apply_calibration(
            t / "run" / "calibration.json", t / "readings.csv", t / "run" / "calibration.json", True)),
        r"output= is the calibration file: write the loads to a new file",
    ),
    "output path already exists": (lambda t: apply_to(t, trained_calibration(t), output_exists=True), r"loads.csv already exists: choose another output= or add overwrite=true"),
    # simulated sensors and other data modules
    "metric constraint without a magnitude": (simulated("model.rank=5", "experiment=lord3dof"), r"model.rank is 5 but the data has 3 load axes"),
    "six axes with too few known wrenches": (simulated("experiment=ft6dof", "data.known_per_configuration=1"), r"only 5 rows have one: give at least 7 known loads spanning every axis"),
    "MK-V runs too short to move every sensor": (simulated("experiment=mkv_pca", "data.steps=40", "data.train_rooms=1"), r"sensor column .*bump_rear.* is constant in the training data"),
    "real recordings folder missing": (lambda t: (lambda: FtPrintedSensorDataModule(str(t / "none"), {}, [0]).setup()), r"is not a folder of the sensor's CSV files"),
    "real recordings: a known pose past the files read": (
        ft_printed_sensor_without_three_poses, r"data.known_poses names pose 9, but .* holds 9 poses \(0-8, in file-name order"
    ),
    "sensorimotor: command column missing": (lambda t: sensorimotor(t, log_text(300), ["a", "b"], ["command"]), r"command column 'command' is not in .* \(did you mean 'cmd'\?\)"),
    "sensorimotor: constant sensor": (lambda t: sensorimotor(t, log_text(300, constant=1.0), ["a", "b"], ["cmd"]), r"sensor column b is constant in the training data"),
    "sensorimotor: constant sensor, inexact value": (lambda t: sensorimotor(t, log_text(300, constant=1.234), ["a", "b"], ["cmd"]), r"sensor column b is constant in the training data"),
    "sensorimotor: fewer rows than columns": (lambda t: sensorimotor(t, log_text(6), ["a", "b"], ["cmd"]), r"only 4 training samples for 5 columns"),
    "sensorimotor: empty text command": (lambda t: sensorimotor_empty_command(t, "", ["go", "stop"]), r"has 1 empty cells in command column 'cmd' \(first: line 5\)"),
    "sensorimotor: empty numeric command": (lambda t: sensorimotor_empty_command(t, "", ["-1", "1"]), r"has 1 empty cells in command column 'cmd' \(first: line 5\)"),
    "sensorimotor: empty command after a blank line": (
        lambda t: sensorimotor_empty_command(t, "", ["go", "stop"], blank_lines=1), r"has 1 empty cells in command column 'cmd' \(first: line 6\)"
    ),
    # A hostile tester's (primordial learning on their own logs): each ran to exit 0 with a meaningless score.
    "sensorimotor: the command also a sensor": (
        lambda t: sensorimotor(t, log_text(300), ["a", "b", "cmd"], ["cmd"]), r"column 'cmd' is named as both a sensor and a command column"
    ),
    "sensorimotor: a sensor named twice": (
        lambda t: sensorimotor(t, log_text(300), ["a", "a", "b"], ["cmd"]), r"column 'a' is named as a sensor column twice"
    ),
    "sensorimotor: a command that never varies": (
        lambda t: sensorimotor(t, log_text(300).replace(",stop\n", ",go\n").replace(",turn\n", ",go\n"), ["a", "b"], ["cmd"]),
        r"command column cmd takes one value \('go'\) on every training row: there is no mapping from sensors to commands",
    ),
    "sensorimotor: a continuous command": (
        lambda t: sensorimotor(t, log_text(300).replace("a,b,cmd", "cmd,b,label"), ["b"], ["cmd"]),
        r"command column 'cmd' takes 296 different values in 300 rows: a command is one of a few labels .* bin it",
    ),
    "sensorimotor: nothing held out": (
        lambda t: (lambda: (t / "log.csv").write_text(log_text(300)) and SensorimotorCsvDataModule(
            str(t / "log.csv"), ["a", "b"], ["cmd"], test_fraction=0.001).setup()),
        r"data.test_fraction=0.001 holds out none of the 300 rows: give at least 0.0033",
    ),
    "sensorimotor: no header line": (
        lambda t: sensorimotor(t, log_text(300).split("\n", 1)[1], ["a", "b"], ["cmd"]),
        r"the first line of .*log.csv holds numbers \(0.6370, 0.2698, go\), not column names: add a first line naming the columns",
    ),
    "sensorimotor: a column spelt otherwise": (
        lambda t: sensorimotor(t, log_text(300).replace("a,b,cmd", "Wheel L,b,cmd"), ["wheel_l", "b"], ["cmd"]),
        r"sensor column 'wheel_l' is not in .* \(did you mean 'Wheel L'\?\)",
    ),
    "rows: stray quote": (lambda t: row_file(t, "rows.csv", 'a,b\n1,2\n"3,4\n'), r"rows.csv line 3: unexpected end of data"),
    "rows: quoted decimal comma": (
        lambda t: row_file(t, "rows.csv", 'a,b\n1,2\n3,"4,5"\n'),
        r"line 3 has a non-numeric cell \('4,5' in column b\): every cell must be a number \(',' as the decimal mark",
    ),
    "rows: empty rows are no rows": (lambda t: row_file(t, "rows.csv", "a,b\n,\n1,2\n,\n"), r"has 1 data rows: give a CSV with a header and at least two rows"),
    "rows: cache folder cannot be written": (
        lambda t: (t / "rows.csv").write_text("a,b\n1,2\n3,4\n") and (lambda: RowFileDataModule(str(t / "rows.csv"), cache_dir=str(t / "rows.csv" / "cache")).setup()),
        r"the CSV's conversion cannot be written to .*: set data.cache_dir to a writable folder",
    ),
    "rows: FIFO as data.path": (lambda t: (lambda: RowFileDataModule(str(fifo(t, "rows.csv"))).setup()), r"is a FIFO \(named pipe\), not a regular file"),
    "rows: non-numeric CSV cell": (lambda t: row_file(t, "rows.csv", "a,b\n1,2\n3,x\n"), r"line 3 has a non-numeric cell"),
    "rows: a whitespace table": (
        lambda t: row_file(t, "rows.txt", "a b\n1 2\n3 4\n"), r"rows.txt is a .txt table, which is read whole: a streamed run reads a .csv or a .npy"
    ),
    "rows: not a matrix": (lambda t: row_file(t, "rows.npy", np.arange(5.0)), r"holds an array of shape \(5,\): save a C-order 2-D array"),
    "rows: rank above the columns": (pca_rank, r"model.rank is 7 but the file has 4 columns: choose 1 to 4"),
    # Past the first rows (SHIFT_ROWS) a cell is seen only in the sums: 1e30 squared is still finite.
    "pca: value of 1e30 far into the file": (
        lambda t: pca_with_cell(t, 11_000, 1e30), r"data row 11000 \(0-based\) of .*rows.npy has a NaN, empty or infinite channel cell, or one beyond 1e\+15"
    ),
    "pca: NaN far into the file": (lambda t: pca_with_cell(t, 11_500, np.nan), r"data row 11500 \(0-based\) of .*rows.npy has a NaN"),
    # config values of the wrong type or out of range (sfmnet/config_values.py), refused before anything is built
    "text magnitude": (lambda t: calibrate(t, "data.magnitude=abc"), r"data.magnitude is 'abc': give a number > 0"),
    "text mirror sign": (
        lambda t: calibrate(t, "data.mirror_hint={row:0,axis:fz,sign:up}", known_loads=2),
        r"data.mirror_hint is \{.*'sign': 'up'\}: give null or \{row: <0-based data row>, axis: <load column>, sign: 1 or -1\}",
    ),
    "mirror hint not a mapping": (lambda t: calibrate(t, "data.mirror_hint=3"), r"data.mirror_hint is 3: give null or \{row"),
    "simulator's mirror hint not a bool": (simulated("data.mirror_hint=abc"), r"data.mirror_hint is 'abc': give null or .* \(a simulator's: true or false\)"),
    "text mass in six-axis configurations": (
        simulated("experiment=ft6dof", "data.configurations.0.mass=abc"),
        r"data.configurations\[0\] is \{'mass': 'abc', .*\}: give \{mass: <kg, > 0>, centre_of_mass: \[x, y, z\]",
    ),
    "no six-axis configurations": (simulated("experiment=ft6dof", "data.configurations=[]"), r"data.configurations is \[\]: give one"),
    "fractional rank": (simulated("model.rank=2.5"), r"model.rank is 2.5: give a whole number >= 1"),
    "negative seed": (simulated("seed=-1"), r"seed is -1: give a whole number >= 0 and <= 4294967295"),
    "no threads": (simulated("threads=0"), r"threads is 0: give a whole number >= 1"),
    "negative weight decay": (simulated("experiment=mkv_autoencoder", "model.weight_decay=-1"), r"model.weight_decay is -1: give a number >= 0"),
    "a robot run of no steps": (simulated("experiment=mkv_pca", "data.steps=0"), r"data.steps is 0: give a whole number >= 2"),
    "leave-one-group-out without groups": (
        simulated("eval.leave_one_group_out=true", "trainer.max_epochs=1"),
        r"eval.leave_one_group_out holds out one group \(pose\) at a time, and this data has none",
    ),
    "a setting no one reads": (simulated("+data.sample=5"), r"data.sample is not a setting of data \(.*FingertipDataModule\): did you mean data.samples\?"),
    "marginal grid too coarse for the sphere": (
        simulated("experiment=lord3dof", "model.refinement=marginal", "model.marginal_grid=200"),
        r"model.marginal_grid=200 spaces the sphere's directions 14.4 degrees apart: give at least 1039",
    ),
    "unknown learnt law": (simulated("model.learnt_law=smooth"), r"model.learnt_law is 'smooth': use one of nonparametric, harmonic, uniform, held_out"),
    "metric weight 0": (simulated("model.metric_weight=0"), r"model.metric_weight is 0: give a number > 0 \(0 drops the metric constraint"),
    "text metric weight": (simulated("model.metric_weight=abc"), r"model.metric_weight is 'abc': give a number > 0"),
    "negative known-load tolerance": (lambda t: calibrate(t, "data.known_load_tolerance=-0.1"), r"data.known_load_tolerance is -0.1: give a number >= 0"),
    "negative learning rate": (simulated("model.refinement=penalty", "optimizer.lr=-1"), r"optimizer.lr is -1: give a number > 0"),
    "text in a simulator's error model": (simulated("data.errors.friction=abc"), r"data.errors.friction is 'abc': give a number"),
    "PCA model on calibration data": (simulated("model=pca", "model.rank=2"), r"StreamingPCA learns from a 'rows' recording, which this data does not have"),
    "fingertip: more known loads than axes": (simulated("data.known_loads=3"), r"data.known_loads is 3 but this sensor has 2 load axes: give 0 to 2"),
    "fingertip: fewer channels than axes": (simulated("data.channels=1"), r"data.channels is 1: a sensor with 2 load axes needs at least 2"),
    "unknown orientation law": (simulated("data.orientation_law=spiral"), r"data.orientation_law is 'spiral': use one of uniform"),
    "six axes: too few channels": (simulated("experiment=ft6dof", "data.channels=3"), r"data.channels is 3: a six-axis sensor needs at least 6"),
    "accelerator this machine lacks": (
        simulated("trainer.accelerator=mps"),
        r"Lightning cannot make a Trainer of these trainer settings \(.*MPSAccelerator.*\): check trainer.accelerator",
    ),
    **({} if torch.cuda.is_available() else {
        "GPU on a machine without one": (simulated("trainer.accelerator=gpu"), r"\(No supported gpu backend found!\): check trainer.accelerator"),
    }),
    # array files given as data.path
    "zero-byte .npy": (lambda t: calibrate_array(t, "s.npy", lambda p: p.write_bytes(b"")), r"s.npy cannot be read as .npy \(.*\): it is truncated or not a .npy file"),
    "zero-byte .npz": (lambda t: calibrate_array(t, "s.npz", lambda p: p.write_bytes(b"")), r"s.npz cannot be read as .npz \(.*\): it is truncated"),
    "empty .npy": (lambda t: calibrate_array(t, "s.npy", lambda p: np.save(p, np.zeros((0, 7)))), r"s.npy: its array is empty: save at least one row"),
    "empty .npz": (lambda t: calibrate_array(t, "s.npz", session_columns()), r"s.npz holds no arrays: save one array per column"),
    "uneven .npz": (
        lambda t: calibrate_array(t, "s.npz", session_columns(s0=np.arange(10.0), s1=np.arange(7.0), fx=np.arange(10.0))),
        r"s.npz holds columns of different lengths \(s0 10, s1 7, fx 10\): every column needs one value per row",
    ),
    "complex .npy": (lambda t: calibrate_array(t, "s.npy", lambda p: np.save(p, SEVEN_COLUMNS + 1j)), r"s.npy: its array holds complex numbers: save real values"),
    "complex .npz": (lambda t: calibrate_array(t, "s.npz", session_columns(s0=SEVEN_COLUMNS[:, 0] * 1j)), r"s.npz: column 's0' holds complex numbers"),
    "text .npz": (lambda t: calibrate_array(t, "s.npz", session_columns(s0=np.array(["a", "b"]))), r"s.npz: column 's0' holds <U1 values, not numbers"),
    "stream: .npz": (
        lambda t: array_file(t, "s.npz", session_columns(s0=np.arange(3.0)), "experiment=calibrate_stream", "data.magnitude=9.81"),
        r"s.npz is an .npz archive, which cannot be streamed: save the rows as one 2-D .npy or a CSV",
    ),
    "stream: complex .npy": (
        lambda t: array_file(t, "s.npy", lambda p: np.save(p, SEVEN_COLUMNS + 1j), "experiment=calibrate_stream", "data.magnitude=9.81"),
        r"s.npy holds complex numbers: save real values",
    ),
    "rows: zero-byte .npy": (
        lambda t: array_file(t, "rows.npy", lambda p: p.write_bytes(b""), "experiment=pca", "model.rank=2"),
        r"rows.npy cannot be read as .npy \(.*\): it is truncated or not a .npy file",
    ),
    "rows: .npy cut off halfway": (
        lambda t: array_file(t, "rows.npy", lambda p: np.save(p, SEVEN_COLUMNS) or p.write_bytes(p.read_bytes()[:-8]),
                             "experiment=pca", "model.rank=2"),
        r"rows.npy is cut off: its header says \d+ x 7 float64 values \(\d+ bytes\) but the file has \d+ bytes: copy or save it again",
    ),
    # checkpoints given as ckpt_path
    "truncated checkpoint": (lambda t: resume_from(t, truncated_checkpoint), r"last.ckpt is not a checkpoint \(not the zip archive torch.save writes"),
    "text file as checkpoint": (lambda t: resume_from(t, lambda p: p.write_text("epoch=3\n")), r"last.ckpt is not a checkpoint \(not the zip archive"),
    "torch.save of a dict as checkpoint": (
        lambda t: resume_from(t, lambda p: torch.save({"weights": torch.ones(2)}, p)),
        r"last.ckpt is not a Lightning checkpoint \(it lacks state_dict, epoch, pytorch-lightning_version\)",
    ),
    "pickled module as checkpoint": (
        lambda t: resume_from(t, lambda p: torch.save(torch.nn.Linear(2, 2), p)),
        r"last.ckpt is not a Lightning checkpoint \(it holds pickled objects",
    ),
    # calibration files for apply
    "text in a calibration matrix": (lambda t: calibration_json(t, '[["a", 1]]'), r"calibration.json: matrix holds something other than numbers"),
    "NaN in a calibration matrix": (lambda t: calibration_json(t, "[[NaN, 1]]"), r"calibration.json: matrix holds NaN or infinite values"),
    # file-system faults: one line naming the path and what to do, nothing left behind
    "run directory is a file": (lambda t: run_into_file(t, "taken"), r"taken cannot be a folder: .*taken is a file; choose another run directory"),
    "run directory under a file": (lambda t: run_into_file(t, "taken/run"), r"taken/run cannot be a folder: .*taken is a file"),
    "read-only run directory": (read_only_run_dir, r"locked/run cannot be written: .*locked is read-only for you; choose another run directory"),
    "apply: output is a folder": (lambda t: apply_into(t, t), r"output=.* is a folder: give the file to write, e.g. output=.*loads.csv"),
    "apply: output in a read-only folder": (
        lambda t: apply_into(t, t / "loads.csv", mock.patch("tempfile.mkstemp", denied)),
        r"cannot write .*loads.csv \(Permission denied\): choose a folder you may write to",
    ),
    "apply: disk full": (
        lambda t: apply_into(t, t / "loads.csv", mock.patch("os.replace", disk_full)),
        r"cannot write .*loads.csv \(No space left on device\): the disk is full",
    ),
    # Hydra's grammar and sweeps (sfmnet/config_check.py), before Hydra starts
    "non-ASCII letter in an unquoted path": (
        overrides_of("experiment=calibrate_csv", "data.path=/data/sé.csv", "data.magnitude=1"),
        r"""Hydra cannot read data.path=/data/sé.csv: .*; quote it: 'data.path="/data/sé.csv"'""",
    ),
    "non-ASCII names in an unquoted list": (
        overrides_of("data.load_columns=[Fₓ,Fᵧ]"), r"""quote it: 'data.load_columns=\["Fₓ","Fᵧ"\]'""",
    ),
    "'=' in an unquoted path": (overrides_of("data.path=/data/a=b.csv"), r"""quote it: 'data.path="/data/a=b.csv"'"""),
    "a list never closed": (
        overrides_of("data.load_columns=[fx,fy"), r"Hydra cannot read data.load_columns=\[fx,fy: a '\[' is not closed by a '\]'",
    ),
    "the README's placeholder left in": (
        overrides_of("data.configurations={{1: {{mass: 1, centre_of_mass: [0, 0, 0.1]}}, 2: {{...}}}}"),
        r"'\.\.\.' stands for entries to write out in full \(the README's examples use it\): give every one",
    ),
    "a path with a space, unquoted": (
        lambda t: (lambda: refuse_bare_words(["experiment=calibrate_csv", "data.path=my", "session.csv"])),
        r"'session.csv' is not a setting; it follows data.path=my: a value holding spaces must be quoted whole, "
        r"e.g. 'data.path=my session.csv'",
    ),
    "'[' in an unquoted path": (overrides_of("data.path=/data/a[1].csv"), r"""quote it: 'data.path="/data/a\[1\].csv"'"""),
    "'${' in a path": (
        overrides_of("experiment=calibrate_csv", "data.path=/data/a${{x}}.csv", "data.magnitude=1"),
        r"data.path refers to something that does not exist \(Interpolation key 'x' not found\): '\$\{' starts a reference",
    ),
    "'${' escaped in a path": (escaped_reference, r"data.path is '/data/a\$\{x\}.csv': Hydra reads '\$\{' as a reference to another key again"),
    "several experiments without -m": (
        overrides_of("experiment=fingertip,lord3dof"),
        r"experiment=fingertip,lord3dof gives several values: add -m to run one job per value",
    ),
    "unknown experiment in a choice sweep": (
        overrides_of("experiment=choice(fingertip,lord3)", sweep=True), r"unknown experiment 'lord3' \(did you mean 'lord3dof'\?\)",
    ),
    "run directory is a file, on the command line": (
        lambda t: (t / "taken").write_text("") or overrides_of("hydra.run.dir={tmp}/taken")(t), r"taken cannot be a folder: .* choose another hydra.run.dir",
    ),
    "config value checked before Hydra starts": (overrides_of("threads=0"), r"threads is 0: give a whole number >= 1"),
    "+ on a key that exists": (overrides_of("+seed=3"), r"Hydra cannot apply these overrides: Could not append to config. An item is already at 'seed'"),
    "unknown config key": (lambda t: (lambda: check_overrides(["experiment=lord3dof", "data.nosie_fraction=0.1"], config_dir())), r"unknown config key 'data.nosie_fraction' \(did you mean 'data.noise_fraction'\?\)"),
    "a key only some swept experiments have": (
        overrides_of("experiment=mkv_pca,fingertip", "eval.closed_loop=null", sweep=True),
        r"^config key 'eval.closed_loop' is not in the jobs with experiment=fingertip: sweep over configs that all have it",
    ),
    "unknown experiment in a sweep": (lambda t: (lambda: check_overrides(["experiment=fingertip,lord3"], config_dir(), sweep=True)), r"unknown experiment 'lord3' \(did you mean 'lord3dof'\?\)"),
    "unknown experiment": (lambda t: (lambda: check_overrides(["experiment=lord3", "seed=1"], config_dir())), r"unknown experiment 'lord3'"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bad_input_is_refused_with_one_clear_message(case: str, tmp_path: Path):
    prepare, message = CASES[case]
    action = prepare(tmp_path)
    with pytest.raises(SfmnetError, match=message) as caught:
        action()
    assert "\n" not in str(caught.value)
    # Nothing a user made is overwritten: a refused apply leaves an existing output as it was.
    if (tmp_path / "loads.csv").exists() and case == "output path already exists":
        assert (tmp_path / "loads.csv").read_text() == "keep me\n"
    # Nor is anything written: no loads, no half-written temporary file.
    assert case == "output path already exists" or not (tmp_path / "loads.csv").exists()
    assert not list(tmp_path.rglob("*.tmp"))


def test_known_loads_both_ways_along_one_line_are_not_taken_for_the_worlds_frame():
    """Known loads +z on some rows and -z on others, right in the sensor's frame: too few directions, but the readings
    pointing opposite ways are what such loads give (a tester's: told "up to 180 degrees ... the world's frame")."""
    import sfmnet

    rng = np.random.default_rng(0)
    shape = np.eye(3) + 0.1 * rng.normal(size=(3, 6))[:, :3]
    loads = rng.normal(size=(600, 3))
    loads *= 9.81 / np.linalg.norm(loads, axis=1, keepdims=True)
    loads[:20] = [0.0, 0.0, 9.81]
    loads[20:30] = [0.0, 0.0, -9.81]
    readings = loads @ shape + 0.01 * rng.normal(size=loads.shape)
    known = np.full_like(loads, np.nan)
    known[:30] = loads[:30]
    with pytest.raises(SfmnetError, match=r"^the known loads span 1 of 3 load directions: give at least 2"):
        sfmnet.calibrate(readings, 9.81, known)


def test_table_is_long_enough():
    assert len(CASES) >= 25


@pytest.mark.parametrize(
    "args,message",
    [
        (["train", "experiment=calibrate_csv", "data.path=/nonexistent/session.csv", "data.magnitude=9.81"], "error: /nonexistent/session.csv does not exist: check data.path"),
        (["apply", "calibration=/nonexistent/c.json", "input=/nonexistent/r.csv", "output=/tmp/never.csv"], "error: calibration file /nonexistent/c.json does not exist: give the calibration.json of a run"),
        (["train", "hydra.run.dir={tmp}/taken"], "error: {tmp}/taken cannot be a folder: {tmp}/taken is a file; choose another hydra.run.dir"),
        # The command line quotes a bare value Hydra cannot take (sfmnet.cli.quote_plain_value): the path is read.
        (["train", "experiment=calibrate_csv", "data.path=/data/sé.csv", "data.load_columns=[Fₓ,Fᵧ,F_z]", "data.magnitude=9.81"], "error: /data/sé.csv does not exist: check data.path"),
        (["train", "foo"], "error: 'foo' is not a setting: write key=value, e.g. experiment=foo (python -m sfmnet train --help)"),
        (["train", "trainer.accelerator=mps"], "error: Lightning cannot make a Trainer of these trainer settings ("),
        (["apply", "calibration={tmp}/nan.json", "input={tmp}/readings.csv", "output={tmp}/loads.csv"], "error: calibration file {tmp}/nan.json: matrix holds NaN"),
    ],
    ids=["train", "apply", "run-dir-is-a-file", "unquoted-non-ascii-path-is-read", "bare-word", "missing-accelerator", "apply-nan-calibration"],
)
def test_cli_prints_one_line_and_exits_2(args: list[str], message: str, tmp_path: Path):
    """``message``: the start of the one line on stderr (``{tmp}``: the test's folder, where the files below lie)."""
    (tmp_path / "taken").write_text("keep me\n")
    (tmp_path / "nan.json").write_text('{"matrix": [[NaN, 1]], "offset": [0, 0], "channels": ["s0", "s1"], "axes": ["fx"]}')
    (tmp_path / "readings.csv").write_text("s0,s1\n1,2\n")
    args = [arg.format(tmp=tmp_path) for arg in args]
    if args[0] == "train" and not any(arg.startswith("hydra.run.dir=") for arg in args):
        args = [*args, f"hydra.run.dir={tmp_path / 'run'}", "trainer.enable_progress_bar=false"]
    done = subprocess.run([sys.executable, "-m", "sfmnet", *args], cwd=REPO, capture_output=True, text=True, check=False)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(message.format(tmp=tmp_path)), done.stderr
    assert "Traceback" not in done.stdout + done.stderr
    assert (tmp_path / "taken").read_text() == "keep me\n"
    assert not (tmp_path / "loads.csv").exists() and not (tmp_path / "run" / "calibration.json").exists()
