"""A hostile user's trial of sfmnet (issue 12): bad and unusual inputs and faults, each outcome classified.

Run by hand, one case at a time, under ``nice`` on a shared machine:

    nice -n 10 python bench/adversarial.py                        # every case
    nice -n 10 python bench/adversarial.py --only 'csv-*' --only rundir-quoted
    python bench/adversarial.py --list                            # names, expectations, descriptions
    nice -n 10 python bench/adversarial.py --csv adversarial.csv  # the table as CSV too

Each case makes its inputs in its own temporary folder, runs the command line (``python -m sfmnet
train ...`` / ``apply ...``) or a Python API snippet (``sfmnet.calibrate``, ``sfmnet.CommandLearner``,
``sfmnet.Calibration``) in a subprocess of its own process group, and its outcome is classified:

- ``refused``: exit 2, exactly one line on stderr, starting ``error:``, no ``Traceback`` (for the API:
  ``SfmnetError`` with a one-line message; the snippet runner prints it as the CLI does);
- ``worked``: exit 0 and, where the case knows the right answer, the answer is right;
- ``traceback``: a Python traceback in the output;
- ``hang``: no exit within the time limit (the process group is killed);
- ``silently wrong``: exit 0 with a wrong answer (a stale result, NaN written, a channel that should
  not be used used, a half-fitted result after Ctrl-C, ...);
- ``lost files``: a file that existed before a command (every file under the case's folder is
  snapshotted as size, mtime_ns and sha256) was changed or deleted, other than what the command is
  documented to write (``apply ... overwrite=true``) and the CSV cache ``.sfmnet-cache/``;
- ``unclean``: any other failure: a non-zero exit without the one ``error:`` line (Ctrl-C's bare
  exit 1, warnings printed before the error, a message over two lines, ...);
- ``harness error``: the trial itself failed (a reference run, ``chattr +i`` for a folder even root
  cannot write, ``mount`` of a tiny tmpfs for a full disk: both need root), not a verdict on sfmnet.

A case expects ``refused`` or ``worked`` (``either`` for the few inputs where a clean refusal and a
right answer are both acceptable). The script exits 1 when any case got anything but what it expects.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import fnmatch
import functools
import hashlib
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import textwrap
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parent.parent
TIMEOUT = 120.0
FIFO_TIMEOUT = 45.0  # a FIFO must be refused at once; waiting 120 s on each would only slow the trial
MAGNITUDE = 9.81

REFUSED, WORKED, EITHER = "refused", "worked", "either"
TRACEBACK, HANG, WRONG, LOST, UNCLEAN, HARNESS = "traceback", "hang", "silently wrong", "lost files", "unclean", "harness error"
CLASSES = [REFUSED, WORKED, TRACEBACK, HANG, WRONG, LOST, UNCLEAN, HARNESS]


# ---------------------------------------------------------------- running commands


@dataclass
class Run:
    """One finished command."""

    args: list[str]
    returncode: int | None
    stdout: str
    stderr: str
    timed_out: bool
    timeout: float

    @property
    def output(self) -> str:
        return self.stdout + self.stderr

    @property
    def ok(self) -> bool:
        return self.returncode == 0 and not self.timed_out

    def stderr_lines(self) -> list[str]:
        return [line for line in self.stderr.splitlines() if line.strip()]

    def result(self) -> Any:
        """What an API snippet passed to ``report(...)`` (its last ``RESULT`` line)."""
        lines = [line for line in self.stdout.splitlines() if line.startswith("RESULT ")]
        if not lines:
            raise HarnessError("the snippet exited 0 without report(...)")
        return json.loads(lines[-1][len("RESULT ") :])


class HarnessError(Exception):
    """The trial itself failed (a reference run, a mount): not a verdict on sfmnet."""


def environment() -> dict[str, str]:
    """The worktree's sfmnet first on the path, debug tracebacks off."""
    env = {k: v for k, v in os.environ.items() if k not in ("SFMNET_DEBUG", "HYDRA_FULL_ERROR")}
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [os.environ.get("PYTHONPATH")])])
    return env


def start(args: Sequence[str], cwd: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    return subprocess.Popen(
        list(args), cwd=cwd, env=env or environment(), stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, errors="replace", start_new_session=True,
        # As from a terminal: a trial started under nohup or from a background job would otherwise inherit an
        # ignored SIGINT, and its Ctrl-C case would test nothing.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )


def finish(process: subprocess.Popen, timeout: float) -> Run:
    """Wait for ``process``; past ``timeout`` kill its whole process group."""
    try:
        stdout, stderr = process.communicate(timeout=timeout)
        timed_out = False
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        stdout, stderr = process.communicate()
        timed_out = True
    return Run(list(map(str, process.args)), process.returncode, stdout, stderr, timed_out, timeout)


def sfmnet(*args: str) -> list[str]:
    return [sys.executable, "-m", "sfmnet", *args]


# ---------------------------------------------------------------- file snapshots

Snapshot = dict[str, tuple[int, int, str]]
CACHE_DIR = ".sfmnet-cache"  # sfmnet's own CSV conversions: it may replace them


def snapshot(root: Path) -> Snapshot:
    """(size, mtime_ns, sha256) of every regular file under ``root`` (FIFOs and devices are never opened)."""
    files: Snapshot = {}
    for folder, _, names in os.walk(root):
        for name in names:
            path = Path(folder) / name
            info = path.lstat()
            if not stat.S_ISREG(info.st_mode):
                continue
            digest = hashlib.sha256()
            with path.open("rb") as stream:
                for block in iter(lambda: stream.read(1 << 20), b""):
                    digest.update(block)
            files[str(path.relative_to(root))] = (info.st_size, info.st_mtime_ns, digest.hexdigest())
    return files


def changes(before: Snapshot, after: Snapshot, allowed: set[str]) -> list[str]:
    """Pre-existing files changed or deleted, except ``allowed`` ones and sfmnet's cache."""
    found = []
    for name, state in before.items():
        if name in allowed or CACHE_DIR in Path(name).parts:
            continue
        if name not in after:
            found.append(f"deleted {name}")
        elif after[name] != state:
            found.append(f"changed {name}")
    return found


# ---------------------------------------------------------------- one case's sandbox

Check = Callable[[], tuple[bool, str]]


@dataclass
class Verdict:
    got: str
    detail: str


@dataclass
class Trial:
    """One case's folder, the commands it runs, what they did to files already there, and its answer checks."""

    tmp: Path
    lost: list[str] = field(default_factory=list)
    checks: list[tuple[Run, Check]] = field(default_factory=list)
    immutable: list[Path] = field(default_factory=list)
    mounts: list[Path] = field(default_factory=list)

    @property
    def run(self) -> Path:
        """The default run directory of ``train``."""
        return self.tmp / "run"

    def path(self, *parts: str) -> Path:
        path = self.tmp.joinpath(*parts)
        path.parent.mkdir(parents=True, exist_ok=True)
        return path

    @contextlib.contextmanager
    def watching(self, allowed: Sequence[Path] = ()) -> Iterator[None]:
        """Record pre-existing files that the commands run inside change or delete."""
        before = snapshot(self.tmp)
        try:
            yield
        finally:
            relative = {str(Path(p).relative_to(self.tmp)) for p in allowed}
            self.lost += changes(before, snapshot(self.tmp), relative)

    def command(self, args: Sequence[str], cwd: Path = REPO, timeout: float = TIMEOUT, allowed: Sequence[Path] = ()) -> Run:
        with self.watching(allowed):
            return finish(start(args, cwd), timeout)

    def train(self, *overrides: str, run_dir: Path | None = None, set_run_dir: bool = True, **kwargs: Any) -> Run:
        """``python -m sfmnet train <overrides>`` into ``run_dir`` (default ``<tmp>/run``), no progress bars."""
        location = [f"hydra.run.dir={run_dir or self.run}"] if set_run_dir else []
        return self.command(sfmnet("train", *overrides, "trainer.enable_progress_bar=false", *location), **kwargs)

    def sweep(self, *overrides: str, sweep_dir: Path, **kwargs: Any) -> Run:
        return self.command(
            sfmnet("train", "-m", *overrides, "trainer.enable_progress_bar=false", f"hydra.sweep.dir={sweep_dir}"), **kwargs
        )

    def apply(self, *options: str, **kwargs: Any) -> Run:
        return self.command(sfmnet("apply", *options), **kwargs)

    def api(self, body: str, data: dict[str, np.ndarray] | None = None, **kwargs: Any) -> Run:
        """Run a Python snippet against the API (``np``, ``sfmnet``, ``data``, ``tmp``, ``report(value)`` in scope)."""
        runner = self.path("api_runner.py")
        runner.write_text(API_RUNNER)
        snippet = self.path("snippet.py")
        snippet.write_text(textwrap.dedent(body))
        arrays = self.path("arrays.npz")
        np.savez(arrays, **(data or {}))
        return self.command([sys.executable, str(runner), str(snippet), str(arrays), str(self.tmp)], **kwargs)

    def together(self, commands: Sequence[Sequence[str]], timeout: float = TIMEOUT) -> list[Run]:
        """Start every command at once, then wait for all."""
        with self.watching():
            processes = [start(args, REPO) for args in commands]
            return [finish(process, timeout) for process in processes]

    def interrupt(self, args: Sequence[str], sig: int, ready: Callable[[], bool], wait: float) -> tuple[Run, bool]:
        """Start ``args``, send ``sig`` to its process group once ``ready()`` or after ``wait`` seconds;
        returns the run and whether the signal was sent while it was still running."""
        with self.watching():
            process = start(args, REPO)
            deadline = time.monotonic() + wait
            while process.poll() is None and not ready() and time.monotonic() < deadline:
                time.sleep(0.05)
            sent = process.poll() is None
            if sent:
                os.killpg(process.pid, sig)
            return finish(process, TIMEOUT), sent

    def verify(self, run: Run, check: Check) -> None:
        """Judge ``run``'s answer with ``check`` if it exits 0."""
        self.checks.append((run, check))

    def make_immutable(self, path: Path) -> None:
        """A folder no one may write into, root included (``chattr +i``)."""
        subprocess.run(["chattr", "+i", str(path)], check=True)
        self.immutable.append(path)

    def mount_tiny(self, path: Path, size: str = "64k") -> None:
        """A nearly full disk: a tiny tmpfs."""
        path.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True, text=True)
        if done.returncode != 0:
            raise HarnessError(f"cannot mount a tmpfs ({done.stderr.strip()})")
        self.mounts.append(path)

    def cleanup(self, keep: bool) -> None:
        for path in self.immutable:
            subprocess.run(["chattr", "-i", str(path)], check=False)
        for path in self.mounts:
            subprocess.run(["umount", "-l", str(path)], check=False)
        if not keep:
            shutil.rmtree(self.tmp, ignore_errors=True)


API_RUNNER = """\
import contextlib, io, json, sys
import numpy as np
import sfmnet

def report(value):
    print("RESULT " + json.dumps(value))

data = dict(np.load(sys.argv[2], allow_pickle=True))
noise = io.StringIO()  # warnings while the snippet runs: shown on stdout, so stderr holds only the verdict
status = 0
try:
    with contextlib.redirect_stderr(noise):
        exec(compile(open(sys.argv[1], encoding="utf-8").read(), "snippet.py", "exec"),
             {"np": np, "sfmnet": sfmnet, "data": data, "tmp": sys.argv[3], "report": report})
except sfmnet.SfmnetError as error:
    print(f"error: {error}", file=sys.stderr)
    status = 2
finally:
    print(noise.getvalue(), end="")
sys.exit(status)
"""


# ---------------------------------------------------------------- the case registry

Body = Callable[[Trial], "Run | Verdict"]


@dataclass(frozen=True)
class Case:
    name: str
    expect: str
    description: str
    body: Body


CASES: dict[str, Case] = {}


def register(name: str, expect: str, description: str, body: Body) -> None:
    assert name not in CASES, f"duplicate case {name}"
    CASES[name] = Case(name, expect, description, body)


def case(name: str, expect: str, description: str) -> Callable[[Body], Body]:
    def decorate(body: Body) -> Body:
        register(name, expect, description, body)
        return body

    return decorate


def one_line(text: str, limit: int = 200) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def judge(trial: Trial, outcome: Run | Verdict) -> Verdict:
    """Classify a case's outcome (hang, lost files and tracebacks first, then the answer, then the exit)."""
    run = outcome if isinstance(outcome, Run) else None
    if run is not None and run.timed_out:
        return Verdict(HANG, f"no exit within {run.timeout:.0f} s (process group killed)")
    if trial.lost:
        return Verdict(LOST, "; ".join(trial.lost[:4]) + (f" (+{len(trial.lost) - 4})" if len(trial.lost) > 4 else ""))
    if isinstance(outcome, Verdict):
        return outcome
    if "Traceback" in run.output:
        # The exception's own line: the last unindented one, past Hydra's "Set the environment variable ..." advice.
        tail = [line for line in run.output.splitlines()
                if line.strip() and not line.startswith((" ", "Set the environment variable HYDRA_FULL_ERROR"))]
        return Verdict(TRACEBACK, f"exit {run.returncode}: {one_line(tail[-1] if tail else '')}")
    if run.returncode == 0:
        for checked, check in trial.checks:
            if checked is run:
                try:
                    right, detail = check()
                except Exception as error:  # a missing or unreadable output of a run that said it worked
                    right, detail = False, f"exit 0 but its output cannot be read: {type(error).__name__}: {error}"
                if not right:
                    return Verdict(WRONG, one_line(detail))
                return Verdict(WORKED, one_line(detail))
        return Verdict(WORKED, "exit 0")
    lines = run.stderr_lines()
    if run.returncode == 2 and len(lines) == 1 and lines[0].startswith("error:"):
        return Verdict(REFUSED, one_line(lines[0]))
    shown = lines[-1] if lines else "(empty stderr)"
    return Verdict(UNCLEAN, f"exit {run.returncode}, {len(lines)} stderr lines, last: {one_line(shown, 150)}")


def expected(case: Case, got: str) -> bool:
    return got == case.expect or (case.expect == EITHER and got in (REFUSED, WORKED))


# ---------------------------------------------------------------- inputs: simulated sessions and files


@dataclass(frozen=True)
class Session:
    """A simulated calibration session: ``load = matrix @ (reading - offset)`` on every row."""

    matrix: np.ndarray  # n x p
    offset: np.ndarray  # p
    readings: np.ndarray  # f x p
    loads: np.ndarray  # f x n, true
    known: np.ndarray  # f x n, NaN where not known
    axes: list[str]

    @property
    def channels(self) -> list[str]:
        return [f"s{i}" for i in range(self.readings.shape[1])]


AXES = {2: ["fx", "fy"], 3: ["fx", "fy", "fz"], 6: ["fx", "fy", "fz", "mx", "my", "mz"]}


def simulate(rows: int = 120, channels: int = 6, axes: int = 3, known: int = 3, seed: int = 0, scale: float = 1.0) -> Session:
    """One mass (``MAGNITUDE``) turned through random orientations, ``known`` rows loaded along the first axes."""
    rng = np.random.default_rng(seed)
    shape = rng.normal(size=(axes, channels))  # reading = load @ shape + offset
    offset = rng.normal(scale=2.0, size=channels)
    directions = rng.normal(size=(rows, axes))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    directions[:known] = np.eye(axes)[:known]
    loads = MAGNITUDE * directions
    readings = loads @ shape + offset + 0.01 * rng.normal(size=(rows, channels))
    known_loads = np.full_like(loads, np.nan)
    known_loads[:known] = loads[:known]
    return Session(np.linalg.pinv(shape).T / scale, offset * scale, readings * scale, loads, known_loads, AXES[axes])


CONFIGURATIONS = {  # conf/data/ft6dof.yaml's five masses and centres of mass
    1: (0.309, (0.0, 0.0, 0.045)),
    2: (1.028, (0.02937, 0.02937, 0.05394)),
    3: (1.028, (-0.02937, 0.02937, 0.05394)),
    4: (1.028, (-0.02937, -0.02937, 0.05394)),
    5: (1.028, (0.02937, -0.02937, 0.05394)),
}
CONFIGURATIONS_OVERRIDE = "data.configurations={" + ", ".join(
    f"{key}: {{mass: {mass}, centre_of_mass: [{', '.join(map(str, com))}]}}" for key, (mass, com) in CONFIGURATIONS.items()
) + "}"


def simulate_six_axis(seed: int = 0, per_configuration: int = 24) -> tuple[Session, np.ndarray]:
    """A six-axis force/torque session over the five configurations, three poses of each known; also the configuration ids."""
    rng = np.random.default_rng(seed)
    shape = rng.normal(size=(6, 8)) * np.array([10, 10, 10, 200, 200, 200])[:, None]
    offset = rng.normal(scale=300.0, size=8)
    wrenches, ids, known_rows = [], [], []
    for key, (mass, com) in CONFIGURATIONS.items():
        directions = rng.normal(size=(per_configuration, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        directions[:3] = np.eye(3)
        force = mass * 9.80665 * directions
        wrenches.append(np.hstack([force, np.cross(np.array(com), force)]))
        known_rows += [len(ids) + i for i in range(3)]
        ids += [key] * per_configuration
    loads = np.vstack(wrenches)
    readings = loads @ shape + offset + rng.normal(size=(len(loads), 8))
    known = np.full_like(loads, np.nan)
    known[known_rows] = loads[known_rows]
    return Session(np.linalg.pinv(shape).T, offset, readings, loads, known, AXES[6]), np.array(ids)


def cells(session: Session, time: bool = True, digits: int = 9) -> list[list[str]]:
    """The session as a table of strings (header first); load cells empty where unknown."""
    header = [*(["time"] if time else []), *session.channels, *session.axes]
    rows = [header]
    for i, (z, f) in enumerate(zip(session.readings, session.known)):
        rows.append([*([f"{0.01 * i:.2f}"] if time else []), *(f"{v:.{digits}f}" for v in z), *("" if np.isnan(v) else f"{v:.6f}" for v in f)])
    return rows


def render(rows: list[list[str]], sep: str = ",", newline: str = "\n", quote: bool = False) -> str:
    quoted = (lambda cell: f'"{cell}"') if quote else (lambda cell: cell)
    return "".join(sep.join(quoted(cell) for cell in row) + newline for row in rows)


def write(path: Path, text: str, bom: bool = False, encoding: str = "utf-8") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes((("\ufeff" if bom else "") + text).encode(encoding))
    return path


def as_array(rows: list[list[str]]) -> np.ndarray:
    """The table's numbers as float64 (NaN for empty cells): the same values the CSV holds."""
    return np.array([[float(cell) if cell else np.nan for cell in row] for row in rows[1:]])


def session_csv(trial: Trial, name: str = "session.csv", session: Session | None = None, time: bool = True, **style: Any) -> Path:
    """The standard session (``simulate()``), as a plain CSV unless ``style`` says otherwise."""
    bom = style.pop("bom", False)
    return write(trial.path(name), render(cells(session or simulate(), time=time), **style), bom=bom)


def key_of(override: str) -> str:
    return override.lstrip("+~").split("=", 1)[0]


def merged(base: list[str], extra: Sequence[str]) -> list[str]:
    """``base`` then ``extra``, each of ``extra`` replacing the base override of its key (never two values for one key)."""
    keys = {key_of(item) for item in extra}
    return [item for item in base if key_of(item) not in keys] + list(extra)


def calibrate_args(path: Path | str, *extra: str, magnitude: float | None = MAGNITUDE, time_column: bool = True) -> list[str]:
    """``experiment=calibrate_csv`` on ``path`` (3 epochs: enough for the alternation on 120 rows)."""
    base = ["experiment=calibrate_csv", f"data.path={path}", *([f"data.magnitude={magnitude}"] if magnitude is not None else []),
            *(["data.time_column=time"] if time_column else []), "trainer.max_epochs=3"]
    return merged(base, extra)


def stream_args(path: Path | str, *extra: str, time_column: bool = True) -> list[str]:
    base = ["experiment=calibrate_stream", f"data.path={path}", f"data.magnitude={MAGNITUDE}", *(["data.time_column=time"] if time_column else [])]
    return merged(base, extra)


def write_log(path: Path, rows: int = 400, seed: int = 0, labels: Sequence[str] = ("back", "stop", "go"),
              sep: str = ",", bom: bool = False, newline: str = "\n", edit: Callable[[list[list[str]]], None] | None = None) -> Path:
    """A sensorimotor log: four sensors that follow one command column (segments of 10 to 30 rows)."""
    rng = np.random.default_rng(seed)
    commands: list[int] = []
    while len(commands) < rows:
        commands += [int(rng.integers(len(labels)))] * int(rng.integers(10, 30))
    level = np.array(commands[:rows], dtype=float) - 1.0
    sensors = np.stack([level, 0.5 * level, np.abs(level), np.zeros(rows)], axis=1) + 0.1 * rng.normal(size=(rows, 4))
    table = [["a", "b", "c", "d", "command"]]
    table += [[*(f"{v:.5f}" for v in s), labels[c]] for s, c in zip(sensors, commands)]
    if edit:
        edit(table)
    return write(path, render(table, sep=sep, newline=newline), bom=bom)


def log_args(path: Path | str, *extra: str) -> list[str]:
    return merged(["experiment=sensorimotor_csv", f"data.path={path}", "data.sensor_columns=[a,b,c,d]", "data.command_columns=[command]"], extra)


def write_rows_csv(path: Path, values: np.ndarray, fmt: str = "{:.6f}") -> Path:
    """A numeric CSV for ``experiment=pca`` (header c0, c1, ...)."""
    header = ",".join(f"c{i}" for i in range(values.shape[1]))
    lines = [header, *(",".join(fmt.format(v) for v in row) for row in values)]
    return write(path, "\n".join(lines) + "\n")


def pca_args(path: Path | str, *extra: str, rank: int = 2) -> list[str]:
    return merged(["experiment=pca", f"data.path={path}", f"model.rank={rank}"], extra)


def fake_run(folder: Path) -> None:
    """What an earlier run left: its config, results and the user's notes."""
    write(folder / ".hydra" / "config.yaml", "experiment_name: earlier\nseed: 7\n")
    write(folder / "calibration.json", json.dumps({"matrix": [[1.0]], "note": "earlier run"}))
    write(folder / "metrics.json", "{}\n")
    write(folder / "notes.txt", "my notes on this run\n")


def write_calibration(path: Path, session: Session, **replace: Any) -> Path:
    """A calibration.json for ``session``'s true matrix (keys in ``replace`` swapped in as given)."""
    content = {"matrix": session.matrix.tolist(), "offset": session.offset.tolist(),
               "channels": session.channels, "axes": session.axes, **replace}
    return write(path, json.dumps(content))


def readings_csv(trial: Trial, name: str = "readings.csv", session: Session | None = None, **style: Any) -> Path:
    """New readings for ``apply``: the channels only (plus a sample index)."""
    session = session or simulate(seed=5)
    rows = [["sample", *session.channels]] + [[str(i), *(f"{v:.9f}" for v in z)] for i, z in enumerate(session.readings)]
    bom = style.pop("bom", False)
    return write(trial.path(name), render(rows, **style), bom=bom)


# ---------------------------------------------------------------- answers


def read_calibration(run_dir: Path) -> dict[str, Any]:
    return json.loads((run_dir / "calibration.json").read_text())


def matrix_of(run_dir: Path) -> np.ndarray:
    return np.array(read_calibration(run_dir)["matrix"], dtype=float)


def load_error(matrix: np.ndarray, offset: np.ndarray, session: Session, channels: Sequence[str] | None = None) -> float:
    """Worst axis's RMS load error relative to that axis's RMS load, with the fitted calibration
    (on the named ``channels`` of the session, the CSV's time column included, if given)."""
    readings = session.readings
    if channels is not None:
        columns = {"time": 0.01 * np.arange(len(readings)), **{name: readings[:, i] for i, name in enumerate(session.channels)}}
        readings = np.stack([columns[name] for name in channels], axis=1)
    loads = (readings - offset) @ matrix.T
    return float(np.max(np.sqrt(((loads - session.loads) ** 2).mean(0)) / np.sqrt((session.loads**2).mean(0))))


def near_truth(run_dir: Path, session: Session, tolerance: float = 0.02) -> Check:
    def check() -> tuple[bool, str]:
        calibration = read_calibration(run_dir)
        matrix, offset = np.array(calibration["matrix"], float), np.array(calibration["offset"], float)
        if not np.isfinite(matrix).all() or not np.isfinite(offset).all():
            return False, "NaN or infinite entries in calibration.json's matrix or offset"
        error = load_error(matrix, offset, session, calibration["channels"])
        return error < tolerance, f"load error {error:.2%} of the true loads (limit {tolerance:.0%})"

    return check


def same_as(run_dir: Path, reference: Callable[[], np.ndarray], what: str, tolerance: float = 1e-9) -> Check:
    """The run's matrix equals a reference run's within ``tolerance`` (max abs entry difference)."""

    def check() -> tuple[bool, str]:
        mine = matrix_of(run_dir)
        theirs = reference()
        if mine.shape != theirs.shape:
            return False, f"matrix {mine.shape} but {what}'s is {theirs.shape}"
        difference = float(np.max(np.abs(mine - theirs)))
        return difference <= tolerance, f"max |matrix - {what}'s| = {difference:.1e} (limit {tolerance:.0e})"

    return check


def never_right(reason: str) -> Check:
    """For input whose every answer is wrong (e.g. complex readings): exit 0 is silently wrong."""
    return lambda: (False, reason)


def channels_exclude(run_dir: Path, forbidden: Sequence[str]) -> Check:
    def check() -> tuple[bool, str]:
        used = read_calibration(run_dir)["channels"]
        bad = [name for name in forbidden if name in used]
        return not bad, (f"column(s) {bad} used as calibration channels" if bad else f"channels {used}")

    return check


# ---------------------------------------------------------------- references (computed once per trial, on demand)

WORKDIR: Path = Path(tempfile.gettempdir())


@functools.cache
def reference_run(kind: str) -> Path:
    """The run directory of a plain run: ``csv`` and ``stream`` (the standard session's plain CSV by calibrate_csv
    and calibrate_stream), ``fingertip`` (the default experiment, 2 epochs)."""
    folder = WORKDIR / f"reference-{kind}"
    shutil.rmtree(folder, ignore_errors=True)
    trial = Trial(folder)
    args = {"csv": calibrate_args, "stream": stream_args}[kind](session_csv(trial)) if kind != "fingertip" else [
        "experiment=fingertip", "trainer.max_epochs=2"]
    run = trial.train(*args)
    if not run.ok:
        raise HarnessError(f"the {kind} reference run failed: {one_line(run.stderr[-300:])}")
    return trial.run


def reference(kind: str) -> np.ndarray:
    return matrix_of(reference_run(kind))


def checkpoint_of(kind: str) -> Path:
    """A reference run's checkpoint (its last.ckpt where there are several)."""
    found = sorted(reference_run(kind).glob("checkpoints/**/*.ckpt"), key=lambda path: (path.name == "last.ckpt", str(path)))
    if not found:
        raise HarnessError(f"the {kind} reference run wrote no checkpoint")
    return found[-1]


def same_as_csv(run_dir: Path, tolerance: float = 1e-9) -> Check:
    return same_as(run_dir, lambda: reference("csv"), "plain CSV", tolerance)


# ================================================================ cases: run directories


@case("rundir-used", REFUSED, "hydra.run.dir= a folder an earlier run left: refused, nothing of it rewritten")
def _(t: Trial) -> Run:
    fake_run(t.run)
    return t.train(*calibrate_args(session_csv(t)))


@case("rundir-real-rerun", REFUSED, "the same command twice into one hydra.run.dir: the second refused, the first run untouched")
def _(t: Trial) -> Run:
    args = calibrate_args(session_csv(t))
    if not t.train(*args).ok:
        raise HarnessError("the first run failed")
    return t.train(*args)


RUN_DIR_SPELLINGS: list[tuple[str, str, Callable[[Path], str]]] = [
    ("rundir-quoted", "a used run dir given in double quotes", lambda run: f'hydra.run.dir="{run}"'),
    ("rundir-single-quoted", "a used run dir given in single quotes", lambda run: f"hydra.run.dir='{run}'"),
    ("rundir-plusplus", "a used run dir given as ++hydra.run.dir=", lambda run: f"++hydra.run.dir={run}"),
    ("rundir-trailing-slash", "a used run dir with a trailing slash", lambda run: f"hydra.run.dir={run}/"),
    ("rundir-dotdot", "a used run dir spelt through x/..", lambda run: f"hydra.run.dir={run.parent / 'x' / '..' / run.name}"),
    ("rundir-interpolated", "a used run dir spelt with ${experiment_name}",
     lambda run: "hydra.run.dir=" + str(run.parent / "${experiment_name}")),
]
for _name, _description, _spell in RUN_DIR_SPELLINGS:

    def _body(t: Trial, spell: Callable[[Path], str] = _spell, interpolated: bool = "interpolated" in _name) -> Run:
        run = t.tmp / "calibrate_csv" if interpolated else t.run
        fake_run(run)
        return t.train(*calibrate_args(session_csv(t)), spell(run), set_run_dir=False)

    register(_name, REFUSED, _description + ": refused, the earlier run untouched", _body)


@case("rundir-plus", REFUSED, "+hydra.run.dir= (the key exists: Hydra refuses to add one)")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t)), f"+hydra.run.dir={t.run}", set_run_dir=False)


@case("rundir-symlink", REFUSED, "hydra.run.dir= a symlink to a used run dir: refused")
def _(t: Trial) -> Run:
    fake_run(t.run)
    (t.tmp / "link").symlink_to(t.run)
    return t.train(*calibrate_args(session_csv(t)), run_dir=t.tmp / "link")


@case("rundir-relative", REFUSED, "a used run dir given relative to the working folder (cwd = the case folder)")
def _(t: Trial) -> Run:
    fake_run(t.run)
    return t.train(*calibrate_args(session_csv(t)), run_dir=Path("run"), cwd=t.tmp)


@case("rundir-hidden-only", REFUSED, "a run dir holding only a hidden .hydra/ of an earlier run: refused")
def _(t: Trial) -> Run:
    write(t.run / ".hydra" / "config.yaml", "seed: 3\n")
    return t.train(*calibrate_args(session_csv(t)))


@case("rundir-is-input-folder", REFUSED, "hydra.run.dir= the folder holding the input CSV: refused, the CSV untouched")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t)), run_dir=t.tmp)


@case("rundir-empty-existing", WORKED, "hydra.run.dir= an existing empty folder: a new run, allowed")
def _(t: Trial) -> Run:
    t.run.mkdir()
    run = t.train(*calibrate_args(session_csv(t)))
    t.verify(run, same_as_csv(t.run))
    return run


@case("rundir-is-file", REFUSED, "hydra.run.dir= an existing file: refused, the file untouched")
def _(t: Trial) -> Run:
    write(t.run, "a file, not a folder\n")
    return t.train(*calibrate_args(session_csv(t)))


@case("rundir-under-file", REFUSED, "hydra.run.dir= a path under an existing file")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t)), run_dir=session_csv(t, "other.csv") / "run")


@case("rundir-readonly", REFUSED, "hydra.run.dir= an empty folder no one may write into (chattr +i)")
def _(t: Trial) -> Run:
    path = session_csv(t)
    t.run.mkdir()
    t.make_immutable(t.run)
    return t.train(*calibrate_args(path))


@case("rundir-readonly-parent", REFUSED, "hydra.run.dir= a new folder inside a folder no one may write into")
def _(t: Trial) -> Run:
    path = session_csv(t)
    locked = t.tmp / "locked"
    locked.mkdir()
    t.make_immutable(locked)
    return t.train(*calibrate_args(path), run_dir=locked / "run")


@case("rundir-uncreatable", REFUSED, "hydra.run.dir= under /proc, where no folder can be made")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t)), run_dir=Path("/proc/sfmnet-adversarial/run"))


@case("rundir-disk-full", REFUSED, "hydra.run.dir= on a 64 kB disk that fills up mid-run: one line naming the path")
def _(t: Trial) -> Run:
    path = session_csv(t)
    t.mount_tiny(t.tmp / "tiny")
    return t.train(*calibrate_args(path), run_dir=t.tmp / "tiny" / "run")


@case("rundir-two-at-once", REFUSED, "two runs started at once into one new hydra.run.dir: one must be refused")
def _(t: Trial) -> Run | Verdict:
    args = sfmnet("train", *calibrate_args(session_csv(t)), "trainer.enable_progress_bar=false", f"hydra.run.dir={t.run}")
    first, second = t.together([args, args])
    if first.ok and second.ok:
        return Verdict(WRONG, "both exited 0 writing one run dir: one result overwrote the other")
    return second if first.ok else first


@case("sweep-rerun", REFUSED, "-m re-run into the same hydra.sweep.dir: refused, the first sweep untouched")
def _(t: Trial) -> Run:
    args = ["experiment=fingertip", "trainer.max_epochs=2", "seed=0,1"]
    if not t.sweep(*args, sweep_dir=t.tmp / "sweep").ok:
        raise HarnessError("the first sweep failed")
    return t.sweep(*args, sweep_dir=t.tmp / "sweep")


@case("sweep-dir-user-files", REFUSED, "-m into a hydra.sweep.dir holding the user's multirun.yaml and 0/: refused")
def _(t: Trial) -> Run:
    write(t.tmp / "sweep" / "multirun.yaml", "my own notes\n")
    fake_run(t.tmp / "sweep" / "0")
    return t.sweep("experiment=fingertip", "trainer.max_epochs=2", "seed=0,1", sweep_dir=t.tmp / "sweep")


@case("sweep-quoted-dir", REFUSED, "-m with a quoted used hydra.sweep.dir")
def _(t: Trial) -> Run:
    fake_run(t.tmp / "sweep" / "0")
    return t.command(sfmnet("train", "-m", "experiment=fingertip", "trainer.max_epochs=2", "seed=0,1",
                            "trainer.enable_progress_bar=false", f'hydra.sweep.dir="{t.tmp / "sweep"}"'))


# ================================================================ cases: files as people write them


def csv_variant(name: str, expect: str, description: str, make: Callable[[Trial], Path], *extra: str, tolerance: float = 1e-9) -> None:
    """A case: the standard session written another way; worked means the plain CSV's matrix."""

    def body(t: Trial) -> Run:
        run = t.train(*calibrate_args(make(t), *extra))
        t.verify(run, same_as_csv(t.run, tolerance))
        return run

    register(name, expect, description, body)


def semicolon_decimal_comma(t: Trial) -> Path:
    rows = [[cell.replace(".", ",") for cell in row] for row in cells(simulate())]
    return write(t.path("session.csv"), render(rows, sep=";"))


def with_blank_rows(text: str, blank: str) -> str:
    lines = text.splitlines(keepends=True)
    return "".join(line + (blank if i % 10 == 5 else "") for i, line in enumerate(lines))


csv_variant("csv-bom", WORKED, "a UTF-8 BOM (Excel's 'CSV UTF-8'): the plain file's matrix", lambda t: session_csv(t, bom=True))
csv_variant("csv-crlf", WORKED, "Windows line endings", lambda t: session_csv(t, newline="\r\n"))
csv_variant("csv-bom-crlf", WORKED, "BOM and Windows line endings together", lambda t: session_csv(t, bom=True, newline="\r\n"))
csv_variant("csv-cr-only", EITHER, "old Mac line endings (CR only)", lambda t: session_csv(t, newline="\r"))
csv_variant("csv-trailing-blank-lines", WORKED, "three empty lines at the end",
            lambda t: write(t.path("session.csv"), render(cells(simulate())) + "\n\n\n"))
csv_variant("csv-leading-blank-line", EITHER, "an empty line before the header",
            lambda t: write(t.path("session.csv"), "\n" + render(cells(simulate()))))
csv_variant("csv-quoted-cells", WORKED, "every cell in double quotes", lambda t: session_csv(t, quote=True))
csv_variant("csv-semicolon", WORKED, "';' separators, decimal points", lambda t: session_csv(t, sep=";"))
csv_variant("csv-semicolon-decimal-comma", WORKED, "';' separators and decimal commas (European Excel)", semicolon_decimal_comma)
csv_variant("csv-tab", WORKED, "tab separators in a .csv", lambda t: session_csv(t, sep="\t"))
csv_variant("tsv-file", WORKED, "a .tsv with tabs and empty load cells", lambda t: session_csv(t, "session.tsv", sep="\t"))
csv_variant("csv-space-after-comma", WORKED, "', ' separators (a space after each comma)", lambda t: session_csv(t, sep=", "))
csv_variant("csv-comma-rows", EITHER, "',,,' rows (Excel's empty rows) every tenth line",
            lambda t: write(t.path("session.csv"), with_blank_rows(render(cells(simulate())), ",,,,,,,,,\n")))
csv_variant("csv-trailing-comma", EITHER, "every line ends with a comma (an empty last column)",
            lambda t: session_csv(t, newline=",\n"))
csv_variant("csv-no-extension", WORKED, "the CSV saved without a file extension", lambda t: session_csv(t, "session"))
csv_variant("csv-uppercase-extension", WORKED, "SESSION.CSV", lambda t: session_csv(t, "SESSION.CSV"))
csv_variant("csv-utf16", EITHER, "Excel's 'Unicode text' (UTF-16 with BOM, tabs) saved as .csv",
            lambda t: write(t.path("session.csv"), render(cells(simulate()), sep="\t"), encoding="utf-16"))
csv_variant("csv-quoted-decimal-comma", EITHER, "',' separators with decimal commas in quoted cells",
            lambda t: write(t.path("session.csv"), render([[c.replace(".", ",") for c in r] for r in cells(simulate())], quote=True)))


def renamed_channel(name: str) -> Callable[[Trial], Path]:
    def make(t: Trial) -> Path:
        rows = cells(simulate())
        rows[0][1] = name
        return write(t.path("session.csv"), render(rows), encoding="cp1252" if "µ" in name else "utf-8")

    return make


csv_variant("csv-latin1-header", EITHER, "a cp1252 header cell 's0_µV' (not UTF-8)", renamed_channel("s0_µV"))
csv_variant("csv-unicode-channel", WORKED, "a channel named 'Dehnung_ä_σ' in UTF-8", renamed_channel("Dehnung_ä_σ"))


@case("csv-unicode-load-columns", WORKED, "load columns named Fₓ, Fᵧ, F_z (data.load_columns=[Fₓ,Fᵧ,F_z])")
def _(t: Trial) -> Run:
    rows = cells(simulate())
    rows[0][-3:] = ["Fₓ", "Fᵧ", "F_z"]
    run = t.train(*calibrate_args(write(t.path("session.csv"), render(rows)), "data.load_columns=[Fₓ,Fᵧ,F_z]"))
    t.verify(run, same_as_csv(t.run))
    return run


@case("csv-stray-quote", REFUSED, "a stray double quote opening a cell on line 6")
def _(t: Trial) -> Run:
    rows = cells(simulate())
    rows[5][2] = '"' + rows[5][2]
    return t.train(*calibrate_args(write(t.path("session.csv"), render(rows))))


def edited(edit: Callable[[list[list[str]]], None]) -> Callable[[Trial], Path]:
    def make(t: Trial) -> Path:
        rows = cells(simulate())
        edit(rows)
        return write(t.path("session.csv"), render(rows))

    return make


def set_cells(*changes: tuple[int, int, str]) -> Callable[[list[list[str]]], None]:
    def edit(rows: list[list[str]]) -> None:
        for row, column, value in changes:
            rows[row][column] = value

    return edit


BAD_FILES: list[tuple[str, str, Callable[[Trial], Path]]] = [
    ("csv-zero-byte", "a zero-byte file", lambda t: write(t.path("session.csv"), "")),
    ("csv-whitespace-only", "a file of spaces and newlines", lambda t: write(t.path("session.csv"), "  \n\n \t\n")),
    ("csv-header-only", "a header and no rows", lambda t: write(t.path("session.csv"), render(cells(simulate())[:1]))),
    ("csv-short-row", "line 8 one cell short", edited(lambda rows: rows[7].pop())),
    ("csv-long-row", "line 8 one cell too many", edited(lambda rows: rows[7].append("1.0"))),
    ("csv-excel-error", "an Excel '#DIV/0!' in a channel", edited(set_cells((9, 2, "#DIV/0!")))),
    ("csv-units-in-cells", "a reading written '0.39 V'", edited(set_cells((9, 2, "0.39 V")))),
    ("csv-thousands-separator", "a quoted '1,234.5' reading", edited(set_cells((9, 2, '"1,234.5"')))),
    ("csv-duplicate-columns", "two columns named s0", edited(set_cells((0, 2, "s0")))),
    ("csv-time-backwards", "the time column going backwards once", edited(set_cells((20, 0, "0.01")))),
    ("csv-partial-known-load", "a known load row with only fx and fy filled", edited(set_cells((1, 9, "")))),
    ("csv-known-load-text", "a known load cell 'approx 9.81'", edited(set_cells((1, 7, "approx 9.81")))),
    ("csv-one-known-load", "one known load for three axes", edited(set_cells((2, 7, ""), (2, 8, ""), (2, 9, ""), (3, 7, ""), (3, 8, ""), (3, 9, "")))),
    ("csv-gzip", "a gzip-compressed CSV named .csv.gz",
     lambda t: write_gzip(t.path("session.csv.gz"), render(cells(simulate())))),
    ("csv-binary-garbage", "random bytes named .csv", lambda t: write_bytes(t.path("session.csv"), np.random.default_rng(0).bytes(4000))),
]


def write_gzip(path: Path, text: str) -> Path:
    import gzip

    path.write_bytes(gzip.compress(text.encode()))
    return path


def write_bytes(path: Path, content: bytes) -> Path:
    path.write_bytes(content)
    return path


for _name, _description, _make in BAD_FILES:
    register(_name, REFUSED, _description + ": refused in one line",
             lambda t, make=_make: t.train(*calibrate_args(make(t))))


csv_variant("csv-empty-header-cell", EITHER, "a channel column with an empty header cell: refused, or the plain matrix",
            edited(set_cells((0, 3, ""))))


@case("csv-units-row", EITHER, "a second header row of units (s, V, ..., N): refused, or skipped with the plain matrix")
def _(t: Trial) -> Run:
    rows = cells(simulate())
    rows.insert(1, ["s", *["V"] * 6, "N", "N", "N"])
    run = t.train(*calibrate_args(write(t.path("session.csv"), render(rows))))
    t.verify(run, same_as_csv(t.run))
    return run


@case("csv-comment-line", EITHER, "a '# recorded 2024-05-01, rig 3' line above the header")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(write(t.path("session.csv"), "# recorded 2024-05-01, rig 3\n" + render(cells(simulate())))))
    t.verify(run, same_as_csv(t.run))
    return run


@case("csv-time-miscased", REFUSED, "data.time_column=Time for a column named time: refused, never a channel")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(session_csv(t), "data.time_column=Time"))
    t.verify(run, channels_exclude(t.run, ["time"]))
    return run


@case("csv-time-misspelt", REFUSED, "data.time_column=timestmp: refused")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(session_csv(t), "data.time_column=timestmp"))
    t.verify(run, channels_exclude(t.run, ["time"]))
    return run


@case("csv-time-bom", WORKED, "BOM before the time column's name with data.time_column=time: time is not a channel")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(session_csv(t, bom=True)))
    t.verify(run, channels_exclude(t.run, ["time"]))
    return run


@case("csv-time-not-named", WORKED, "a time column left unnamed: used as a channel only with a warning naming it")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(session_csv(t), time_column=False))

    def check() -> tuple[bool, str]:
        if "time" not in read_calibration(t.run)["channels"]:
            return True, "time not used as a channel"
        warned = [line for line in run.output.splitlines() if "time" in line and ("warn" in line.lower() or "monoton" in line.lower())]
        return bool(warned), one_line(warned[0]) if warned else "the monotonic time column used as a channel without a warning"

    t.verify(run, check)
    return run


@case("csv-huge-values", WORKED, "readings in micro-units (x 1e12): the matrix scales by 1e-12")
def _(t: Trial) -> Run:
    session = simulate(scale=1e12)
    run = t.train(*calibrate_args(session_csv(t, session=session)))
    t.verify(run, near_truth(t.run, session))
    return run


@case("csv-tiny-values", WORKED, "readings in tera-units (x 1e-12)")
def _(t: Trial) -> Run:
    session = simulate(scale=1e-12)
    rows = cells(session, digits=22)
    run = t.train(*calibrate_args(write(t.path("session.csv"), render(rows))))
    t.verify(run, near_truth(t.run, session))
    return run


@case("csv-all-loads-known", WORKED, "every row's load known")
def _(t: Trial) -> Run:
    session = simulate(known=0)
    session = Session(session.matrix, session.offset, session.readings, session.loads, session.loads.copy(), session.axes)
    run = t.train(*calibrate_args(session_csv(t, session=session)))
    t.verify(run, near_truth(t.run, session))
    return run


def channel_count_case(name: str, channels: int, description: str) -> None:
    @case(name, WORKED, description)
    def _(t: Trial) -> Run:
        session = simulate(channels=channels, rows=200)
        run = t.train(*calibrate_args(session_csv(t, session=session)))
        t.verify(run, near_truth(t.run, session))
        return run


channel_count_case("csv-p-equals-n", 3, "three channels for three axes (p = n), three known loads")
channel_count_case("csv-sixteen-channels", 16, "sixteen channels for three axes")


@case("csv-duplicate-rows", WORKED, "every row written twice (a logger that repeats samples)")
def _(t: Trial) -> Run:
    session = simulate()
    rows = cells(session, time=False)
    doubled = [rows[0]] + [row for row in rows[1:] for _ in range(2)]
    run = t.train(*calibrate_args(write(t.path("session.csv"), render(doubled)), time_column=False))
    t.verify(run, near_truth(t.run, session))
    return run


@case("csv-shuffled", WORKED, "the rows shuffled (no time column): the unshuffled file's matrix to 1e-7")
def _(t: Trial) -> Run:
    rows = cells(simulate(), time=False)
    body = rows[1:]
    order = np.random.default_rng(1).permutation(len(body))
    shuffled = [rows[0], *(body[i] for i in order)]
    plain = write(t.path("plain", "session.csv"), render(rows))
    if not t.train(*calibrate_args(plain, time_column=False), run_dir=t.tmp / "plain-run").ok:
        raise HarnessError("the unshuffled run failed")
    run = t.train(*calibrate_args(write(t.path("session.csv"), render(shuffled)), time_column=False))
    t.verify(run, same_as(t.run, lambda: matrix_of(t.tmp / "plain-run"), "unshuffled file", 1e-7))
    return run


# ---- paths


def path_case(name: str, expect: str, description: str, folder: str, quote: bool) -> None:
    def body(t: Trial) -> Run:
        path = session_csv(t, f"{folder}/session.csv")
        given = f"'{path}'" if quote else str(path)
        run = t.train(*calibrate_args(given))
        t.verify(run, same_as_csv(t.run))
        return run

    register(name, expect, description, body)


path_case("path-non-ascii", WORKED, "data.path with non-ASCII letters (Messung_Größe_東京)", "Messung_Größe_東京", False)
path_case("path-space", WORKED, "data.path with a space", "my session", False)
path_case("path-equals", EITHER, "data.path with '=' unquoted: worked, or refused saying how to quote", "gain=2", False)
path_case("path-equals-quoted", WORKED, "data.path with '=' in single quotes", "gain=2", True)
path_case("path-bracket", EITHER, "data.path with '[1]' unquoted", "rig[1]", False)
path_case("path-bracket-quoted", WORKED, "data.path with '[1]' in single quotes", "rig[1]", True)
path_case("path-comma", EITHER, "data.path with ',' unquoted (Hydra reads a list)", "a,b", False)
path_case("path-comma-quoted", WORKED, "data.path with ',' in single quotes", "a,b", True)
path_case("path-dollar", EITHER, "data.path with '${x}' in a folder name, unquoted", "${x}", False)
path_case("path-dollar-quoted", EITHER, "data.path with '${x}' in single quotes (Hydra still interpolates)", "${x}", True)


@case("path-relative", WORKED, "data.path=session.csv relative to the working folder (cwd = the case folder)")
def _(t: Trial) -> Run:
    session_csv(t)
    run = t.train(*calibrate_args("session.csv"), cwd=t.tmp)
    t.verify(run, same_as_csv(t.run))
    return run


@case("path-symlink", WORKED, "data.path a symlink to the session")
def _(t: Trial) -> Run:
    (t.tmp / "link.csv").symlink_to(session_csv(t))
    run = t.train(*calibrate_args(t.tmp / "link.csv"))
    t.verify(run, same_as_csv(t.run))
    return run


@case("rundir-non-ascii", WORKED, "hydra.run.dir with non-ASCII letters")
def _(t: Trial) -> Run:
    run_dir = t.tmp / "Läufe_試験" / "run"
    run = t.train(*calibrate_args(session_csv(t)), run_dir=run_dir)
    t.verify(run, same_as_csv(run_dir))
    return run


NOT_FILES: list[tuple[str, str, Callable[[Trial], Path]]] = [
    ("path-dangling-symlink", "data.path a symlink to nothing", lambda t: dangling(t)),
    ("path-directory", "data.path a folder", lambda t: t.tmp),
    ("path-dev-null", "data.path=/dev/null", lambda t: Path("/dev/null")),
    ("path-missing", "data.path a file that does not exist", lambda t: t.tmp / "nope.csv"),
]


def dangling(t: Trial) -> Path:
    (t.tmp / "gone.csv").symlink_to(t.tmp / "never-written.csv")
    return t.tmp / "gone.csv"


for _name, _description, _make in NOT_FILES:
    register(_name, REFUSED, _description + ": refused in one line", lambda t, make=_make: t.train(*calibrate_args(make(t))))


def fifo(t: Trial, name: str) -> Path:
    path = t.path(name)
    os.mkfifo(path)
    return path


FIFO_RUNS: list[tuple[str, Callable[[Path], list[str]]]] = [
    ("fifo-calibrate-csv", lambda path: calibrate_args(path)),
    ("fifo-calibrate-stream", lambda path: stream_args(path)),
    ("fifo-pca", lambda path: pca_args(path)),
    ("fifo-sensorimotor", lambda path: log_args(path)),
]
for _name, _args in FIFO_RUNS:
    register(_name, REFUSED, f"data.path a FIFO nobody writes to ({_name[5:]}): refused at once, never a hang",
             lambda t, args=_args: t.train(*args(fifo(t, "session.csv")), timeout=FIFO_TIMEOUT))


# ================================================================ cases: streamed files and the CSV cache


def stream_variant(name: str, expect: str, description: str, make: Callable[[Trial], Path]) -> None:
    def body(t: Trial) -> Run:
        run = t.train(*stream_args(make(t)))
        t.verify(run, same_as(t.run, lambda: reference("stream"), "plain CSV streamed", 1e-9))
        return run

    register(name, expect, description, body)


stream_variant("stream-bom", WORKED, "calibrate_stream on a CSV with a UTF-8 BOM: the plain file's matrix", lambda t: session_csv(t, bom=True))
stream_variant("stream-crlf", WORKED, "calibrate_stream on Windows line endings", lambda t: session_csv(t, newline="\r\n"))
stream_variant("stream-comma-rows", EITHER, "calibrate_stream with ',,,' rows every tenth line: skipped, or refused",
               lambda t: write(t.path("session.csv"), with_blank_rows(render(cells(simulate())), ",,,,,,,,,\n")))
stream_variant("stream-semicolon", WORKED, "calibrate_stream on ';' separators", lambda t: session_csv(t, sep=";"))


@case("stream-100k-rows", WORKED, "calibrate_stream on a CSV of exactly 100,000 rows (a multiple of the conversion's chunk)")
def _(t: Trial) -> Run:
    session = simulate(rows=100_000, seed=3)
    run = t.train(*stream_args(session_csv(t, session=session, time=False), time_column=False))
    t.verify(run, near_truth(t.run, session))
    return run


def fixed_width_session(seed: int) -> tuple[Session, str]:
    """A session whose CSV has the same size whatever the seed (every cell fixed width)."""
    session = simulate(seed=seed)
    rows = [[*session.channels, *session.axes]]
    rows += [[*(f"{v:+010.5f}" for v in z), *("" if np.isnan(v) else f"{v:+09.5f}" for v in f)] for z, f in zip(session.readings, session.known)]
    return session, render(rows)


@case("stream-stale-cache", WORKED, "a session CSV replaced by another of the same size and mtime (os.utime): fitted afresh")
def _(t: Trial) -> Run:
    first, first_text = fixed_width_session(0)
    second, second_text = fixed_width_session(1)
    assert len(first_text) == len(second_text)
    path = write(t.path("session.csv"), first_text)
    if not t.train(*stream_args(path, time_column=False), run_dir=t.tmp / "first").ok:
        raise HarnessError("the first streamed run failed")
    before = path.stat()
    write(path, second_text)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    run = t.train(*stream_args(path, time_column=False))
    t.verify(run, near_truth(t.run, second))
    return run


@case("pca-stale-cache", WORKED, "a rows CSV replaced by another of the same size and mtime: pca's mean is the new file's")
def _(t: Trial) -> Run:
    rng = np.random.default_rng(0)
    old, new = rng.uniform(1, 2, size=(500, 3)), rng.uniform(1, 2, size=(500, 3)) + [0, 0, 0.5]
    path = write_rows_csv(t.path("rows.csv"), old)
    if not t.train(*pca_args(path), run_dir=t.tmp / "first").ok:
        raise HarnessError("the first pca run failed")
    before = path.stat()
    write_rows_csv(path, new)
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    run = t.train(*pca_args(path))
    t.verify(run, pca_mean_is(t.run, np.round(new, 6)))
    return run


def pca_mean_is(run_dir: Path, values: np.ndarray) -> Check:
    def check() -> tuple[bool, str]:
        mean = np.load(run_dir / "pca.npz")["mean"]
        difference = float(np.max(np.abs(mean - values.mean(axis=0))))
        return difference < 1e-9, f"max |mean - numpy's| = {difference:.1e} over {len(values)} rows"

    return check


@case("pca-concurrent-conversion", WORKED, "two pca runs converting one new CSV at once: both right")
def _(t: Trial) -> Run | Verdict:
    values = np.round(np.random.default_rng(2).normal(size=(20_000, 4)), 6)
    path = write_rows_csv(t.path("rows.csv"), values)
    runs = t.together([sfmnet("train", *pca_args(path), "trainer.enable_progress_bar=false", f"hydra.run.dir={t.tmp / name}")
                       for name in ("one", "two")])
    for run, name in zip(runs, ("one", "two")):
        if not run.ok:
            return run
        right, detail = pca_mean_is(t.tmp / name, values)()
        if not right:
            return Verdict(WRONG, f"run {name}: {detail}")
    return Verdict(WORKED, "both runs exit 0 with numpy's mean")


@case("pca-100k-rows-csv", WORKED, "pca on a CSV of exactly 100,000 rows")
def _(t: Trial) -> Run:
    values = np.round(np.random.default_rng(4).normal(size=(100_000, 3)), 6)
    run = t.train(*pca_args(write_rows_csv(t.path("rows.csv"), values)))
    t.verify(run, pca_mean_is(t.run, values))
    return run


@case("pca-comma-rows", EITHER, "pca on a CSV with ',,' rows: skipped (numpy's mean of the real rows) or refused")
def _(t: Trial) -> Run:
    values = np.round(np.random.default_rng(5).normal(size=(300, 3)), 6)
    text = with_blank_rows(write_rows_csv(t.path("plain.csv"), values).read_text(), ",,\n")
    run = t.train(*pca_args(write(t.path("rows.csv"), text)))
    t.verify(run, pca_mean_is(t.run, values))
    return run


def npy_case(name: str, expect: str, description: str, array: Callable[[], np.ndarray], compare: bool = True) -> None:
    """pca on a ``.npy``; worked means numpy's mean of the array."""

    def body(t: Trial) -> Run:
        values = array()
        path = t.path("rows.npy")
        np.save(path, values)
        run = t.train(*pca_args(path))
        if compare:
            t.verify(run, pca_mean_is(t.run, np.asarray(values, dtype=float)))
        return run

    register(name, expect, description, body)


def _normal(rows: int = 300, columns: int = 4) -> np.ndarray:
    return np.random.default_rng(6).normal(size=(rows, columns))


npy_case("pca-npy-nan", REFUSED, "pca on a .npy with a NaN in row 150", lambda: np.where(np.arange(1200).reshape(300, 4) == 601, np.nan, _normal()), False)
npy_case("pca-npy-inf", REFUSED, "pca on a .npy with an inf in row 200", lambda: np.where(np.arange(1200).reshape(300, 4) == 801, np.inf, _normal()), False)
npy_case("pca-npy-empty", REFUSED, "pca on a .npy of shape (0, 4)", lambda: np.zeros((0, 4)), False)
npy_case("pca-npy-one-row", REFUSED, "pca on a .npy with one row", lambda: _normal(1), False)
npy_case("pca-npy-complex", REFUSED, "pca on a complex .npy", lambda: _normal() + 1j, False)
npy_case("pca-npy-3d", REFUSED, "pca on a 3-D .npy", lambda: _normal().reshape(30, 10, 4), False)
npy_case("pca-npy-int16", WORKED, "pca on raw int16 counts", lambda: (_normal() * 1000).astype(np.int16))
npy_case("pca-npy-big-endian", WORKED, "pca on a big-endian float64 .npy", lambda: _normal().astype(">f8"))
npy_case("pca-npy-fortran", EITHER, "pca on a Fortran-order .npy", lambda: np.asfortranarray(_normal()))
npy_case("pca-npy-bool", EITHER, "pca on a boolean .npy", lambda: _normal() > 0)


@case("pca-npy-zero-byte", REFUSED, "pca on a zero-byte rows.npy")
def _(t: Trial) -> Run:
    return t.train(*pca_args(write(t.path("rows.npy"), "")))


@case("pca-npy-truncated", REFUSED, "pca on a .npy cut off halfway (a copy that did not finish)")
def _(t: Trial) -> Run:
    np.save(t.path("full.npy"), _normal(2000))
    content = t.path("full.npy").read_bytes()
    return t.train(*pca_args(write_bytes(t.path("rows.npy"), content[: len(content) // 2])))


@case("pca-rank-equals-p", WORKED, "pca with model.rank = the column count")
def _(t: Trial) -> Run:
    values = _normal()
    np.save(t.path("rows.npy"), values)
    run = t.train(*pca_args(t.path("rows.npy"), rank=4))
    t.verify(run, pca_mean_is(t.run, values))
    return run


@case("pca-cache-dir-file", REFUSED, "pca on a CSV with data.cache_dir= an existing file")
def _(t: Trial) -> Run:
    path = write_rows_csv(t.path("rows.csv"), _normal())
    return t.train(*pca_args(path, f"data.cache_dir={write(t.path('not-a-folder'), 'x')}"))


@case("pca-cache-dir-readonly", REFUSED, "pca on a CSV whose data.cache_dir no one may write into")
def _(t: Trial) -> Run:
    path = write_rows_csv(t.path("rows.csv"), _normal())
    (t.tmp / "cache").mkdir()
    t.make_immutable(t.tmp / "cache")
    return t.train(*pca_args(path, f"data.cache_dir={t.tmp / 'cache'}"))


# ================================================================ cases: arrays for calibrate_csv


def standard_array() -> tuple[np.ndarray, list[str]]:
    rows = cells(simulate())
    return as_array(rows), rows[0]


def columns_override(names: list[str]) -> str:
    return f"data.columns=[{','.join(names)}]"


def array_case(name: str, expect: str, description: str, save: Callable[[Path], Path], *extra: str, wrong: str | None = None) -> None:
    """calibrate_csv on an array file; worked means the plain CSV's matrix (the same numbers), or is ``wrong`` whatever it gives."""

    def body(t: Trial) -> Run:
        run = t.train(*calibrate_args(save(t.tmp), *extra))
        t.verify(run, never_right(wrong) if wrong else same_as_csv(t.run))
        return run

    register(name, expect, description, body)


def save_npy(transform: Callable[[np.ndarray], np.ndarray]) -> Callable[[Path], Path]:
    def save(folder: Path) -> Path:
        np.save(folder / "session.npy", transform(standard_array()[0]))
        return folder / "session.npy"

    return save


def save_npz(make: Callable[[np.ndarray, list[str]], dict[str, np.ndarray]]) -> Callable[[Path], Path]:
    def save(folder: Path) -> Path:
        array, names = standard_array()
        np.savez(folder / "session.npz", **make(array, names))
        return folder / "session.npz"

    return save


NAMES = columns_override(["time", *[f"s{i}" for i in range(6)], "fx", "fy", "fz"])

array_case("npy-valid", WORKED, "the session as a float64 .npy with data.columns", save_npy(lambda a: a), NAMES)
array_case("npy-big-endian", WORKED, "a big-endian .npy", save_npy(lambda a: a.astype(">f8")), NAMES)
array_case("npy-fortran", WORKED, "a Fortran-order .npy", save_npy(np.asfortranarray), NAMES)
array_case("npz-valid", WORKED, "an .npz, one array per column", save_npz(lambda a, names: {n: a[:, i] for i, n in enumerate(names)}))
array_case("npy-empty", REFUSED, "a .npy of shape (0, 10)", save_npy(lambda a: a[:0]), NAMES)
array_case("npy-complex", REFUSED, "a complex .npy (imaginary parts 0.1)", save_npy(lambda a: a + 0.1j), NAMES,
           wrong="exit 0 on complex readings: imaginary parts dropped")
array_case("npy-1d", REFUSED, "a 1-D .npy", save_npy(np.ravel), NAMES)
array_case("npy-no-columns", REFUSED, "a .npy without data.columns", save_npy(lambda a: a))
array_case("npy-wrong-column-count", REFUSED, "a .npy with data.columns naming 9 of 10 columns", save_npy(lambda a: a),
           columns_override(["time", *[f"s{i}" for i in range(5)], "fx", "fy", "fz"]))
array_case("npy-structured", EITHER, "a structured .npy (named fields) without data.columns",
           save_npy(lambda a: np.rec.fromarrays(a.T, names=["time", *[f"s{i}" for i in range(6)], "fx", "fy", "fz"])))
array_case("npz-ragged", REFUSED, "an .npz whose arrays differ in length",
           save_npz(lambda a, names: {n: (a[:-5, i] if n == "s3" else a[:, i]) for i, n in enumerate(names)}))
array_case("npz-complex", REFUSED, "an .npz with a complex channel (imaginary parts 1)",
           save_npz(lambda a, names: {n: (a[:, i] + 1j if n == "s2" else a[:, i]) for i, n in enumerate(names)}),
           wrong="exit 0 on a complex channel: imaginary parts dropped")
array_case("npz-2d-member", REFUSED, "an .npz with one member 2-D (two channels in one array)",
           save_npz(lambda a, names: {**{n: a[:, i] for i, n in enumerate(names) if n not in ("s0", "s1")}, "s01": a[:, 1:3]}))
array_case("npz-text-member", EITHER, "an .npz with a channel saved as strings of numbers",
           save_npz(lambda a, names: {n: (a[:, i].astype(str) if n == "s4" else a[:, i]) for i, n in enumerate(names)}))
array_case("npz-empty", REFUSED, "an .npz with no arrays", save_npz(lambda a, names: {}))


@case("npy-object", REFUSED, "a pickled object .npy")
def _(t: Trial) -> Run:
    np.save(t.path("session.npy"), np.array([[1, "a"], [2, None]], dtype=object), allow_pickle=True)
    return t.train(*calibrate_args(t.path("session.npy"), columns_override(["a", "b"])))


@case("npy-zero-byte", REFUSED, "a zero-byte session.npy")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(write(t.path("session.npy"), ""), NAMES))


@case("npy-int-counts", WORKED, "raw int32 counts in a .npy: the same matrix as the same counts as float64")
def _(t: Trial) -> Run:
    array, names = standard_array()
    counts = array.copy()
    counts[:, 1:7] = np.round(counts[:, 1:7] * 1000)
    np.save(t.path("float.npy"), counts)
    if not t.train(*calibrate_args(t.path("float.npy"), NAMES, "data.magnitude=9.81"), run_dir=t.tmp / "float-run").ok:
        raise HarnessError("the float64 run failed")
    np.savez(t.path("counts.npz"), **{n: (counts[:, i].astype(np.int32) if n.startswith("s") else counts[:, i]) for i, n in enumerate(names)})
    run = t.train(*calibrate_args(t.path("counts.npz")))
    t.verify(run, same_as(t.run, lambda: matrix_of(t.tmp / "float-run"), "float64 counts", 1e-9))
    return run


# ================================================================ cases: config values of the wrong type (calibrate_csv)

BAD_VALUES: list[tuple[str, str, str]] = [
    ("magnitude-text", "data.magnitude=abc", "a magnitude in words"),
    ("magnitude-negative", "data.magnitude=-9.81", "a negative magnitude"),
    ("magnitude-zero", "data.magnitude=0", "a zero magnitude"),
    ("magnitude-nan", "data.magnitude=nan", "a NaN magnitude"),
    ("magnitude-inf", "data.magnitude=inf", "an infinite magnitude"),
    ("magnitude-list", "data.magnitude=[9.81]", "a magnitude in brackets"),
    ("rank-fraction", "model.rank=2.5", "model.rank=2.5"),
    ("rank-zero", "model.rank=0", "model.rank=0"),
    ("rank-text", "model.rank=three", "model.rank in words"),
    ("seed-text", "seed=abc", "a seed in words"),
    ("threads-zero", "threads=0", "threads=0"),
    ("threads-negative", "threads=-2", "threads=-2"),
    ("threads-text", "threads=many", "threads in words"),
    ("metric-weight-text", "model.metric_weight=abc", "model.metric_weight in words"),
    ("metric-weight-negative", "model.metric_weight=-1", "a negative metric weight"),
    ("accelerator-bogus", "trainer.accelerator=tpu9", "an accelerator that does not exist"),
    ("max-epochs-negative", "trainer.max_epochs=-1", "Lightning's 'no limit' on a calibration (would never end)"),
    ("max-epochs-text", "trainer.max_epochs=ten", "max_epochs in words"),
    ("devices-zero", "trainer.devices=0", "trainer.devices=0"),
    ("fast-dev-run-text", "trainer.fast_dev_run=abc", "trainer.fast_dev_run in words"),
    ("refinement-bogus", "model.refinement=sideways", "a refinement that does not exist"),
    ("robust-bogus", "model.robust=tukey", "a robust loss that does not exist"),
    ("huber-negative", "model.huber_threshold=-1", "model.robust=huber with a negative threshold"),
    ("lr-negative", "optimizer.lr=-1", "a negative learning rate for the penalty refinement"),
    ("alternation-steps-zero", "model.alternation_steps=0", "zero alternation steps"),
    ("marginal-grid-tiny", "model.marginal_grid=2", "a two-direction marginal grid"),
    ("known-tolerance-negative", "data.known_load_tolerance=-0.5", "a negative known-load tolerance"),
    ("static-threshold-negative", "data.static.threshold=-1", "a negative static threshold"),
    ("static-window-zero", "data.static.window=0", "a zero static window"),
    ("static-intervals-text", "data.static_intervals=maybe", "data.static_intervals=maybe"),
    ("time-unit-bogus", "data.time_unit=fortnight", "a time unit that does not exist"),
    ("load-columns-empty-no-axes", "data.load_columns=[]", "no load columns and no axes"),
    ("load-columns-duplicate", "data.load_columns=[fx,fy,fx]", "a load column named twice"),
    ("channels-duplicate", "data.channel_columns=[s0,s0,s1,s2,s3]", "a channel named twice"),
    ("channels-include-time", "data.channel_columns=[time,s0,s1,s2,s3,s4,s5]", "the time column also named as a channel"),
    ("channels-include-load", "data.channel_columns=[s0,s1,s2,s3,s4,fx]", "a load column also named as a channel"),
    ("task-mismatch", "task=pca", "task=pca on a calibration file"),
    ("group-column-missing", "data.group_column=pose", "a group column that is not in the file"),
    ("config-key-typo", "data.magnitud=9.81", "a misspelt key"),
    ("plus-unknown-key", "+data.foo=1", "+ a key no one reads"),
    ("delete-path", "~data.path", "~data.path (deleting a required key)"),
    ("path-empty", "data.path=", "data.path= with nothing after it"),
    ("path-null", "data.path=null", "data.path=null"),
    ("model-group-typo", "model=shape_from_moton", "a misspelt model"),
    ("experiment-typo", "experiment=calibrate", "an experiment that does not exist"),
    ("experiment-list-without-m", "experiment=calibrate_csv,calibrate_stream", "a list of experiments without -m (suggest -m)"),
    ("magnitude-decimal-comma", "data.magnitude=9,81", "a magnitude with a decimal comma (Hydra reads a list)"),
    ("override-no-equals", "foo", "a bare word among the overrides"),
]
NEEDS = {"huber-negative": ["model.robust=huber", "model.refinement=alternation"], "lr-negative": ["model.refinement=penalty"],
         "alternation-steps-zero": ["model.refinement=alternation"], "marginal-grid-tiny": ["model.refinement=marginal"]}
for _name, _override, _description in BAD_VALUES:

    def _bad_value_body(t: Trial, override: str = _override, name: str = _name) -> Run:
        run = t.train(*calibrate_args(session_csv(t), *NEEDS.get(name, []), override))
        t.verify(run, near_truth(t.run, simulate()))  # accepted anyway: is the answer at least right?
        return run

    register(_name, REFUSED, f"{_description} ({_override}): refused in one line", _bad_value_body)


@case("load-columns-string", REFUSED, "data.load_columns=fx (a word, not a list): refused, fy and fz never channels")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(session_csv(t), "data.load_columns=fx"))
    t.verify(run, channels_exclude(t.run, ["fy", "fz"]))
    return run


@case("accelerator-gpu", WORKED if shutil.which("nvidia-smi") else REFUSED, "trainer.accelerator=gpu (refused on a machine without one)")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t), "trainer.accelerator=gpu"))


def either_near_truth(name: str, description: str, *overrides: str, tolerance: float = 0.02) -> None:
    """An odd value that may be refused, or may work if the answer is still right."""

    def body(t: Trial) -> Run:
        run = t.train(*calibrate_args(session_csv(t), *overrides))
        t.verify(run, near_truth(t.run, simulate(), tolerance))
        return run

    register(name, EITHER, description, body)


either_near_truth("seed-negative", "seed=-1", "seed=-1")
either_near_truth("seed-huge", "seed=2**70", "seed=1180591620717411303424")
either_near_truth("metric-weight-zero", "model.metric_weight=0 on a file with offsets: refused, or still right", "model.metric_weight=0", tolerance=0.05)
either_near_truth("max-epochs-zero", "trainer.max_epochs=0 (the closed form only?)", "trainer.max_epochs=0")
either_near_truth("precision-16", "trainer.precision=16-mixed on the CPU", "trainer.precision=16-mixed")
either_near_truth("override-twice", "seed=1 then seed=2", "seed=1", "seed=2")


@case("mass-instead-of-magnitude", WORKED, "data.mass=1.0 (kg) instead of data.magnitude")
def _(t: Trial) -> Run:
    run = t.train(*calibrate_args(session_csv(t), "data.mass=1.0003416", magnitude=None))
    t.verify(run, near_truth(t.run, simulate()))
    return run


@case("mass-text", REFUSED, "data.mass=one")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t), "data.mass=one", magnitude=None))


@case("mass-and-magnitude-disagree", REFUSED, "data.mass=2 beside data.magnitude=9.81")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t), "data.mass=2"))


@case("gravity-zero", REFUSED, "data.mass=1 with data.gravity=0")
def _(t: Trial) -> Run:
    return t.train(*calibrate_args(session_csv(t), "data.mass=1", "data.gravity=0", magnitude=None))


# ---- the mirror hint (two known loads for three axes)


def mirror_session() -> tuple[Session, int, int]:
    """Two known loads; an unknown row with a clearly signed fz, and that sign."""
    session = simulate(known=2, rows=150)
    row = int(np.argmax(np.abs(session.loads[10:, 2]))) + 10
    return session, row, int(np.sign(session.loads[row, 2]))


MIRROR_HINTS = [
    ("mirror-sign-text", "{row: %d, axis: fz, sign: up}", "a mirror sign in words"),
    ("mirror-hint-number", "5", "a mirror hint that is a number, not a mapping"),
    ("mirror-hint-list", "[%d,fz,1]", "a mirror hint that is a list"),
    ("mirror-row-out-of-range", "{row: 100000, axis: fz, sign: 1}", "a mirror hint row past the end"),
    ("mirror-axis-unknown", "{row: %d, axis: fw, sign: 1}", "a mirror hint axis that is not a load column"),
    ("mirror-sign-zero", "{row: %d, axis: fz, sign: 0}", "a mirror sign of 0"),
    ("mirror-row-negative", "{row: -3, axis: fz, sign: 1}", "a negative mirror hint row"),
]
for _name, _hint, _description in MIRROR_HINTS:

    def _mirror_body(t: Trial, hint: str = _hint) -> Run:
        session, row, _ = mirror_session()
        value = hint % row if "%d" in hint else hint
        run = t.train(*calibrate_args(session_csv(t, session=session), f"data.mirror_hint={value}"))
        t.verify(run, near_truth(t.run, session))
        return run

    register(_name, REFUSED, f"{_description}: refused in one line", _mirror_body)


@case("mirror-hint-valid", WORKED, "two known loads and the right mirror hint: the true calibration")
def _(t: Trial) -> Run:
    session, row, sign = mirror_session()
    run = t.train(*calibrate_args(session_csv(t, session=session), f"data.mirror_hint={{row: {row}, axis: fz, sign: {sign}}}"))
    t.verify(run, near_truth(t.run, session))
    return run


# ---- six axes


def six_axis_csv(t: Trial) -> tuple[Path, Session]:
    session, ids = simulate_six_axis()
    rows = cells(session, time=False)
    rows[0].append("config")
    for row, key in zip(rows[1:], ids):
        row.append(str(key))
    return write(t.path("ft.csv"), render(rows)), session


def six_axis_args(path: Path, configurations: str = CONFIGURATIONS_OVERRIDE) -> list[str]:
    return ["experiment=calibrate_csv", f"data.path={path}", "data.load_columns=[fx,fy,fz,mx,my,mz]",
            "data.configuration_column=config", configurations, "trainer.max_epochs=3"]


@case("six-axis-valid", WORKED, "a six-axis CSV, five configurations, three known poses each")
def _(t: Trial) -> Run:
    path, session = six_axis_csv(t)
    run = t.train(*six_axis_args(path))
    t.verify(run, near_truth(t.run, session, 0.05))
    return run


SIX_AXIS_BAD = [
    ("six-axis-text-mass", "mass: 0.309", "mass: heavy", "a mass in words"),
    ("six-axis-negative-mass", "mass: 0.309", "mass: -0.309", "a negative mass"),
    ("six-axis-short-centre", "centre_of_mass: [0.0, 0.0, 0.045]", "centre_of_mass: [0.0, 0.045]", "a centre of mass with two coordinates"),
    ("six-axis-text-centre", "centre_of_mass: [0.0, 0.0, 0.045]", "centre_of_mass: [0.0, 0.0, high]", "a centre of mass with a word"),
    ("six-axis-missing-configuration", ", 5: {mass: 1.028, centre_of_mass: [0.02937, -0.02937, 0.05394]}", "", "configuration 5 missing from the mapping"),
    ("six-axis-configurations-number", None, "data.configurations=5", "data.configurations=5 (not a mapping)"),
]
for _name, _old, _new, _description in SIX_AXIS_BAD:

    def _six_body(t: Trial, old: str | None = _old, new: str = _new) -> Run:
        path, session = six_axis_csv(t)
        override = new if old is None else CONFIGURATIONS_OVERRIDE.replace(old, new, 1)
        run = t.train(*six_axis_args(path, override))
        t.verify(run, near_truth(t.run, session, 0.05))
        return run

    register(_name, REFUSED, f"six axes, {_description}: refused in one line", _six_body)


# ================================================================ cases: checkpoints


def resume_case(name: str, expect: str, description: str, make: Callable[[Trial], Path]) -> None:
    def body(t: Trial) -> Run:
        path = session_csv(t)
        run = t.train(*calibrate_args(path, f"ckpt_path={make(t)}"))
        t.verify(run, same_as_csv(t.run, 0.0))
        return run

    register(name, expect, description, body)


def truncated_checkpoint(t: Trial) -> Path:
    content = checkpoint_of("csv").read_bytes()
    return write_bytes(t.path("last.ckpt"), content[: len(content) // 2])


def foreign_checkpoint(t: Trial) -> Path:
    subprocess.run([sys.executable, "-c", f"import torch; torch.save({{'weights': torch.ones(3)}}, {str(t.path('last.ckpt'))!r})"],
                   check=True, env=environment())
    return t.path("last.ckpt")


resume_case("ckpt-resume-finished", WORKED, "ckpt_path= the same config's finished last.ckpt into a new run dir: the same matrix bit for bit",
            lambda t: checkpoint_of("csv"))
resume_case("ckpt-truncated", REFUSED, "ckpt_path= a checkpoint cut in half", truncated_checkpoint)
resume_case("ckpt-foreign-torch", REFUSED, "ckpt_path= a torch.save of some other dict", foreign_checkpoint)
resume_case("ckpt-text-file", REFUSED, "ckpt_path= a text file", lambda t: write(t.path("last.ckpt"), "not a checkpoint\n"))
resume_case("ckpt-zero-byte", REFUSED, "ckpt_path= a zero-byte file", lambda t: write(t.path("last.ckpt"), ""))
resume_case("ckpt-directory", REFUSED, "ckpt_path= a folder", lambda t: t.tmp)
resume_case("ckpt-other-experiment", REFUSED, "ckpt_path= the fingertip experiment's checkpoint (2 axes, 4 channels)",
            lambda t: checkpoint_of("fingertip"))
resume_case("ckpt-fifo", REFUSED, "ckpt_path= a FIFO", lambda t: fifo(t, "last.ckpt"))


# ================================================================ cases: signals mid-fit

LONG_FIT = ["experiment=lord3dof", "data.samples=5000", "model.refinement=penalty", "trainer.max_epochs=12"]


def mid_fit_checkpoint(run_dir: Path) -> Callable[[], bool]:
    return lambda: any(run_dir.glob("checkpoints/**/*.ckpt"))


def checkpoint_epoch(path: Path) -> int:
    code = f"import torch; print(torch.load({str(path)!r}, map_location='cpu', weights_only=False)['epoch'])"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environment(), check=True)
    return int(done.stdout.strip())


@case("sigint-mid-fit", REFUSED, "Ctrl-C (SIGINT to the group) mid-fit: non-zero exit, one line naming an existing checkpoint, no traceback")
def _(t: Trial) -> Run | Verdict:
    args = sfmnet("train", *LONG_FIT, "trainer.enable_progress_bar=false", f"hydra.run.dir={t.run}")
    run, sent = t.interrupt(args, signal.SIGINT, mid_fit_checkpoint(t.run), wait=20.0)
    if not sent:
        raise HarnessError("the fit ended before Ctrl-C")
    if run.timed_out or "Traceback" in run.output:
        return run
    if run.returncode == 0:
        written = (t.run / "calibration.json").exists()
        return Verdict(WRONG if written else UNCLEAN, "exit 0 after Ctrl-C" + (": calibration.json written from a half fit" if written else ""))
    lines = run.stderr_lines()
    named = [word.strip("'\".,:;()") for word in (lines[0].split() if len(lines) == 1 else []) if ".ckpt" in word]
    existing = [word for word in named if Path(word.split("=", 1)[-1]).is_file()]
    if existing:
        return Verdict(REFUSED, f"exit {run.returncode}: {one_line(lines[0])}")
    return Verdict(UNCLEAN, f"exit {run.returncode}, {len(lines)} stderr lines, no existing checkpoint named: "
                            f"{one_line(lines[-1] if lines else '(empty stderr)', 150)}")


@case("sigkill-resume", WORKED, "SIGKILL once a checkpoint appears mid-fit, resume with ckpt_path: the uninterrupted matrix bit for bit")
def _(t: Trial) -> Run | Verdict:
    killed = t.tmp / "killed"
    args = sfmnet("train", *LONG_FIT, "trainer.enable_progress_bar=false", f"hydra.run.dir={killed}")
    run, sent = t.interrupt(args, signal.SIGKILL, mid_fit_checkpoint(killed), wait=TIMEOUT)
    found = sorted(killed.glob("checkpoints/**/*.ckpt"))
    if not sent or not found:
        return Verdict(UNCLEAN, "the fit ended before any checkpoint appeared" if not sent else "killed with no checkpoint written")
    epoch = checkpoint_epoch(found[-1])
    if epoch >= 11:
        return Verdict(UNCLEAN, f"the first checkpoint appeared only after the last epoch ({epoch}): nothing mid-fit to resume from")
    resumed = t.train(*LONG_FIT, f"ckpt_path={found[-1]}", run_dir=t.tmp / "resumed")
    if not resumed.ok:
        return resumed
    if not t.train(*LONG_FIT, run_dir=t.tmp / "whole").ok:
        raise HarnessError("the uninterrupted run failed")
    t.verify(resumed, same_as(t.tmp / "resumed", lambda: matrix_of(t.tmp / "whole"), f"uninterrupted run (killed after epoch {epoch})", 0.0))
    return resumed


# ================================================================ cases: sweeps and the command line


@case("sweep-choice", WORKED, "-m seed=choice(0,1): two jobs, each with a calibration")
def _(t: Trial) -> Run:
    run = t.sweep("experiment=fingertip", "trainer.max_epochs=2", "seed=choice(0,1)", sweep_dir=t.tmp / "sweep")
    t.verify(run, lambda: (len(list(t.tmp.glob("sweep/*/calibration.json"))) == 2,
                           f"{len(list(t.tmp.glob('sweep/*/calibration.json')))} job calibrations"))
    return run


@case("sweep-range", WORKED, "-m seed=range(0,2)")
def _(t: Trial) -> Run:
    run = t.sweep("experiment=fingertip", "trainer.max_epochs=2", "seed=range(0,2)", sweep_dir=t.tmp / "sweep")
    t.verify(run, lambda: (len(list(t.tmp.glob("sweep/*/calibration.json"))) == 2, "two job calibrations"))
    return run


@case("sweep-two-experiments", WORKED, "-m experiment=fingertip,lord3dof: one job each and sweep.csv")
def _(t: Trial) -> Run:
    run = t.sweep("experiment=fingertip,lord3dof", "trainer.max_epochs=2", sweep_dir=t.tmp / "sweep")
    t.verify(run, lambda: ((t.tmp / "sweep" / "sweep.csv").is_file() and len(list(t.tmp.glob("sweep/*/calibration.json"))) == 2,
                           "sweep.csv and two job calibrations"))
    return run


@case("sweep-typo-in-list", REFUSED, "-m data.noise_fraction=0.01,abc: refused before any job runs")
def _(t: Trial) -> Run:
    return t.sweep("experiment=fingertip", "trainer.max_epochs=2", "data.noise_fraction=0.01,abc", sweep_dir=t.tmp / "sweep")


@case("cli-cfg-job", WORKED, "train --cfg job prints the config and writes nothing")
def _(t: Trial) -> Run:
    run = t.command(sfmnet("train", "experiment=lord3dof", f"hydra.run.dir={t.run}", "--cfg", "job"))
    t.verify(run, lambda: (not t.run.exists() and "experiment_name" in run.stdout, "config printed, no run dir"))
    return run


@case("cli-unknown-command", REFUSED, "python -m sfmnet trian")
def _(t: Trial) -> Run:
    return t.command(sfmnet("trian", "experiment=lord3dof"))


@case("cli-apply-no-options", REFUSED, "python -m sfmnet apply with nothing else")
def _(t: Trial) -> Run:
    return t.command(sfmnet("apply"))


# ================================================================ cases: every experiment with an odd override

ODD_EXPERIMENTS: list[tuple[str, str, list[str]]] = [
    ("fingertip", REFUSED, ["data.samples=2"]),
    ("lord3dof", REFUSED, ["data.channels=2"]),
    ("table1", REFUSED, ["data.repeats=0"]),
    ("ft6dof", REFUSED, ["data.known_per_configuration=0"]),
    ("ft_printed_sensor", REFUSED, ["data.known_poses=[0,0,0]"]),
    ("ft_printed_sensor_6dof", REFUSED, ["data.use_configurations=[0]"]),
    ("imu_accelerometer", REFUSED, ["data.magnitude=-9.81"]),
    ("calibrate_stream", REFUSED, ["data.block_rows=0"]),
    ("pca", REFUSED, ["model.rank=abc"]),
    ("mkv_pca", REFUSED, ["data.steps=0"]),
    ("mkv_autoencoder", REFUSED, ["model.weight_decay=-1"]),
    ("mkv_compare", REFUSED, ["model.rank_rule=coinflip"]),
    ("sensorimotor_csv", REFUSED, ["data.test_fraction=1.5"]),
    ("wall_following", REFUSED, ["data.test_fraction=0"]),
    ("calibrate_csv", REFUSED, ["data.held_out_intervals=perhaps"]),
    ("lord3dof", WORKED, ["data.noise_fraction=0"]),
    ("fingertip", WORKED, ["data.offset_scale=0", "model.estimate_offset=false"]),
    ("calibrate_stream", WORKED, ["data.block_rows=7"]),
    ("mkv_pca", WORKED, ["data.train_rooms=1", "data.test_rooms=1", "data.steps=3000", "model.rank=3"]),
]


def experiment_inputs(t: Trial, experiment: str) -> list[str]:
    """What an experiment on the user's files needs."""
    if experiment in ("calibrate_csv", "calibrate_stream"):
        return (calibrate_args if experiment == "calibrate_csv" else stream_args)(session_csv(t))[1:]
    if experiment == "pca":
        np.save(t.path("rows.npy"), _normal())
        return [f"data.path={t.path('rows.npy')}"]
    if experiment == "sensorimotor_csv":
        return log_args(write_log(t.path("log.csv")))[1:]
    return []


for _experiment, _expect, _overrides in ODD_EXPERIMENTS:

    def _odd_body(t: Trial, experiment: str = _experiment, overrides: list[str] = _overrides) -> Run:
        run = t.train(f"experiment={experiment}", *experiment_inputs(t, experiment), *overrides)
        if experiment == "lord3dof" and overrides == ["data.noise_fraction=0"]:
            t.verify(run, lambda: (np.isfinite(matrix_of(t.run)).all() and "nan" not in (t.run / "calibration.json").read_text().lower(),
                                   "finite matrix, no NaN written"))
        return run

    register(f"experiment-{_experiment}-{_overrides[0].split('=')[0].split('.')[-1]}" + ("-ok" if _expect == WORKED else ""),
             _expect, f"experiment={_experiment} {' '.join(_overrides)}", _odd_body)


# ================================================================ cases: sensorimotor logs


def accuracy_at_least(run_dir: Path, limit: float = 0.8) -> Check:
    def check() -> tuple[bool, str]:
        metrics = json.loads((run_dir / "metrics.json").read_text())
        accuracy = float(metrics.get("command_accuracy", float("nan")))
        return accuracy >= limit, f"held-out command accuracy {accuracy:.3f}"

    return check


def log_variant(name: str, expect: str, description: str, make: Callable[[Trial], Path]) -> None:
    def body(t: Trial) -> Run:
        run = t.train(*log_args(make(t)))
        t.verify(run, accuracy_at_least(t.run))
        return run

    register(name, expect, description, body)


log_variant("log-valid", WORKED, "a plain sensorimotor log", lambda t: write_log(t.path("log.csv")))
log_variant("log-bom", WORKED, "a sensorimotor log with a UTF-8 BOM", lambda t: write_log(t.path("log.csv"), bom=True))
log_variant("log-semicolon", WORKED, "a sensorimotor log with ';' separators", lambda t: write_log(t.path("log.csv"), sep=";"))
log_variant("log-crlf", WORKED, "a sensorimotor log with Windows line endings", lambda t: write_log(t.path("log.csv"), newline="\r\n"))
log_variant("log-numeric-commands", WORKED, "commands written -1, 0, 1", lambda t: write_log(t.path("log.csv"), labels=("-1", "0", "1")))


@case("log-empty-command-cells", REFUSED, "empty command cells in a sensorimotor log: refused, never a 'nan' command")
def _(t: Trial) -> Run:
    def blank(rows: list[list[str]]) -> None:
        for row in rows[20::17]:
            row[-1] = ""

    run = t.train(*log_args(write_log(t.path("log.csv"), edit=blank)))

    def check() -> tuple[bool, str]:
        with (t.run / "predictions.csv").open(newline="") as stream:
            labels = {value for row in csv.DictReader(stream) for key, value in row.items() if key.startswith("command_")}
        extra = labels - {"back", "stop", "go"}
        return not extra, f"commands {sorted(extra)} made of empty cells" if extra else "only the log's commands"

    t.verify(run, check)
    return run


@case("log-command-also-sensor", REFUSED, "the command column also named as a sensor")
def _(t: Trial) -> Run:
    return t.train(*log_args(write_log(t.path("log.csv")), "data.sensor_columns=[a,b,c,command]"))


@case("log-text-sensor", REFUSED, "a sensor cell 'n/a'")
def _(t: Trial) -> Run:
    return t.train(*log_args(write_log(t.path("log.csv"), edit=lambda rows: rows[30].__setitem__(1, "n/a"))))


@case("log-one-label", EITHER, "a command column with one label throughout")
def _(t: Trial) -> Run:
    return t.train(*log_args(write_log(t.path("log.csv"), edit=lambda rows: [row.__setitem__(-1, "go") for row in rows[1:]])))


# ================================================================ cases: apply


def apply_args(calibration: Path, source: Path, output: Path, *extra: str) -> list[str]:
    return [f"calibration={calibration}", f"input={source}", f"output={output}", *extra]


def loads_right(output: Path, session: Session) -> Check:
    """Every output row's load columns equal C (z - o) of its readings (to the 9 digits written)."""

    def check() -> tuple[bool, str]:
        text = output.read_text(encoding="utf-8-sig")
        rows = list(csv.reader(text.splitlines(), delimiter=";" if text.count(";") > text.count(",") else ","))
        header = rows[0]
        if len(rows) - 1 != len(session.readings):
            return False, f"{len(rows) - 1} rows written for {len(session.readings)} readings"
        index = [header.index(f"{name}_calibrated" if f"{name}_calibrated" in header else name) for name in session.axes]
        got = np.array([[float(row[i]) for i in index] for row in rows[1:]])
        want = (session.readings - session.offset) @ session.matrix.T
        error = float(np.max(np.abs(got - want)) / np.abs(want).max())
        return error < 1e-6, f"{len(got)} rows, max relative load error {error:.1e}"

    return check


def apply_case(name: str, expect: str, description: str, calibration: Callable[[Trial, Session], Path] | None = None,
               source: Callable[[Trial, Session], Path] | None = None, output: Callable[[Trial], Path] | None = None,
               extra: Sequence[str] = (), check: bool = True, may_replace_output: bool = False, wrong: str | None = None) -> None:
    """``apply`` of a calibration to readings; worked means the right loads (``check``), or is ``wrong`` whatever it writes."""

    def body(t: Trial) -> Run:
        session = simulate(seed=5)
        cal = (calibration or (lambda t, s: write_calibration(t.path("calibration.json"), s)))(t, session)
        src = (source or (lambda t, s: readings_csv(t, session=s)))(t, session)
        out = (output or (lambda t: t.tmp / "loads.csv"))(t)
        run = t.apply(*apply_args(cal, src, out, *extra), allowed=[out] if may_replace_output else [])
        if wrong:
            t.verify(run, never_right(wrong))
        elif check:
            t.verify(run, loads_right(out, session))
        return run

    register(name, expect, description, body)


def bad_calibration(**replace: Any) -> Callable[[Trial, Session], Path]:
    return lambda t, s: write_calibration(t.path("calibration.json"), s, **replace)


def with_nan_reading(t: Trial, s: Session) -> Path:
    path = readings_csv(t, session=s)
    lines = path.read_text().splitlines()
    lines[4] = lines[4].rsplit(",", 1)[0] + ",nan"
    return write(path, "\n".join(lines) + "\n")


def with_empty_reading(t: Trial, s: Session) -> Path:
    path = readings_csv(t, session=s)
    lines = path.read_text().splitlines()
    lines[4] = lines[4].rsplit(",", 1)[0] + ","
    return write(path, "\n".join(lines) + "\n")


def reordered_with_extra(t: Trial, s: Session) -> Path:
    rows = [["note", *reversed(s.channels), "temperature"]]
    rows += [["ok", *(f"{v:.9f}" for v in reversed(z)), "21.5"] for z in s.readings]
    return write(t.path("readings.csv"), render(rows))


def with_fx_column(t: Trial, s: Session) -> Path:
    rows = [[*s.channels, "fx"]] + [[*(f"{v:.9f}" for v in z), "0"] for z in s.readings]
    return write(t.path("readings.csv"), render(rows))


apply_case("apply-valid", WORKED, "apply a calibration to new readings: loads = C (z - o)")
apply_case("apply-input-bom", WORKED, "readings with a UTF-8 BOM", source=lambda t, s: readings_csv(t, session=s, bom=True))
apply_case("apply-input-semicolon", WORKED, "readings with ';' separators", source=lambda t, s: readings_csv(t, session=s, sep=";"))
apply_case("apply-input-crlf", WORKED, "readings with Windows line endings", source=lambda t, s: readings_csv(t, session=s, newline="\r\n"))
apply_case("apply-input-quoted", WORKED, "readings with every cell quoted", source=lambda t, s: readings_csv(t, session=s, quote=True))
apply_case("apply-input-reordered", WORKED, "readings with the channels reversed and extra columns", source=reordered_with_extra)
apply_case("apply-input-has-fx", WORKED, "readings that already hold a column fx (loads added as fx_calibrated)", source=with_fx_column)
apply_case("apply-input-nan", REFUSED, "a NaN reading", source=with_nan_reading, check=False)
apply_case("apply-input-empty-cell", REFUSED, "an empty reading cell", source=with_empty_reading, check=False)
apply_case("apply-input-header-only", EITHER, "readings with a header and no rows",
           source=lambda t, s: write(t.path("readings.csv"), ",".join(["sample", *s.channels]) + "\n"), check=False)
apply_case("apply-input-directory", REFUSED, "input= a folder", source=lambda t, s: t.tmp, check=False)
apply_case("apply-input-missing", REFUSED, "input= a file that does not exist", source=lambda t, s: t.tmp / "nope.csv", check=False)
apply_case("apply-calibration-nan", REFUSED, "a calibration.json with NaN in its matrix (never NaN loads with exit 0)",
           calibration=lambda t, s: write(t.path("calibration.json"), json.dumps({"matrix": [[float("nan")] * 6] * 3, "offset": s.offset.tolist(),
                                                                                   "channels": s.channels, "axes": s.axes})),
           wrong="exit 0 with a NaN calibration matrix: NaN loads written")
apply_case("apply-calibration-text", REFUSED, "a calibration.json with text in its matrix",
           calibration=bad_calibration(matrix=[["1.0", "x", 0, 0, 0, 0]] * 3), check=False)
apply_case("apply-calibration-null-offset", REFUSED, "a calibration.json with null in its offset",
           calibration=bad_calibration(offset=[None] * 6), check=False)
apply_case("apply-calibration-infinity", REFUSED, "a calibration.json with Infinity in its offset",
           calibration=lambda t, s: write(t.path("calibration.json"), json.dumps({"matrix": s.matrix.tolist(), "offset": [float("inf")] * 6,
                                                                                   "channels": s.channels, "axes": s.axes})),
           wrong="exit 0 with an infinite offset: infinite or NaN loads written")
apply_case("apply-calibration-ragged", REFUSED, "a calibration.json with a ragged matrix",
           calibration=bad_calibration(matrix=[[1.0] * 6, [1.0] * 5, [1.0] * 6]), check=False)
apply_case("apply-calibration-std-text", REFUSED, "a calibration.json with text in matrix_std",
           calibration=bad_calibration(matrix_std="unknown"), check=False)
apply_case("apply-calibration-duplicate-channels", REFUSED, "a calibration.json naming channel s0 twice",
           calibration=bad_calibration(channels=["s0", "s0", "s2", "s3", "s4", "s5"]), check=False)
apply_case("apply-calibration-channels-numbers", REFUSED, "a calibration.json whose channels are numbers",
           calibration=bad_calibration(channels=[0, 1, 2, 3, 4, 5]), check=False)
apply_case("apply-calibration-binary", REFUSED, "calibration= random bytes",
           calibration=lambda t, s: write_bytes(t.path("calibration.json"), np.random.default_rng(1).bytes(500)), check=False)
apply_case("apply-calibration-directory", REFUSED, "calibration= a folder", calibration=lambda t, s: t.tmp, check=False)
apply_case("apply-output-directory", REFUSED, "output= an existing folder (with overwrite=true)",
           output=lambda t: t.tmp, extra=["overwrite=true"], check=False)
apply_case("apply-output-missing-parent", EITHER, "output= in a folder that does not exist",
           output=lambda t: t.tmp / "new" / "loads.csv")
apply_case("apply-output-exists", REFUSED, "output= an existing file without overwrite=true",
           output=lambda t: write(t.path("loads.csv"), "keep me\n"), check=False)
apply_case("apply-overwrite", WORKED, "output= an existing file with overwrite=true (documented to replace it)",
           output=lambda t: write(t.path("loads.csv"), "old loads\n"), extra=["overwrite=true"], may_replace_output=True)
apply_case("apply-output-is-input-symlink", REFUSED, "output= a symlink to the input, with overwrite=true",
           output=lambda t: symlink(t.tmp / "out.csv", t.tmp / "readings.csv"), extra=["overwrite=true"], check=False)
apply_case("apply-output-is-calibration", REFUSED, "output= the calibration.json itself, with overwrite=true",
           output=lambda t: t.tmp / "calibration.json", extra=["overwrite=true"], check=False)
apply_case("apply-unknown-option", REFUSED, "apply with 'overwrite' misspelt 'ovewrite=true'", extra=["ovewrite=true"], check=False)


def symlink(link: Path, target: Path) -> Path:
    link.symlink_to(target)
    return link


@case("apply-input-fifo", REFUSED, "input= a FIFO nobody writes to: refused at once")
def _(t: Trial) -> Run:
    cal = write_calibration(t.path("calibration.json"), simulate(seed=5))
    return t.apply(*apply_args(cal, fifo(t, "readings.csv"), t.tmp / "loads.csv"), timeout=FIFO_TIMEOUT)


@case("apply-output-readonly", REFUSED, "output= in a folder no one may write into (chattr +i)")
def _(t: Trial) -> Run:
    session = simulate(seed=5)
    cal, src = write_calibration(t.path("calibration.json"), session), readings_csv(t, session=session)
    (t.tmp / "locked").mkdir()
    t.make_immutable(t.tmp / "locked")
    return t.apply(*apply_args(cal, src, t.tmp / "locked" / "loads.csv"))


@case("apply-output-disk-full", REFUSED, "output= on a 64 kB disk too small for the loads")
def _(t: Trial) -> Run:
    session = simulate(seed=5, rows=3000)
    cal, src = write_calibration(t.path("calibration.json"), session), readings_csv(t, session=session)
    t.mount_tiny(t.tmp / "tiny")
    return t.apply(*apply_args(cal, src, t.tmp / "tiny" / "loads.csv"))


# ================================================================ cases: the Python API (sfmnet.calibrate, Calibration)


def session_arrays(session: Session | None = None) -> dict[str, np.ndarray]:
    session = session or simulate()
    return {"readings": session.readings, "known": session.known, "loads": session.loads, "matrix": session.matrix, "offset": session.offset}


REPORT_CAL = 'report({"matrix": cal.matrix.tolist(), "offset": cal.offset.tolist()})'


def api_near_truth(run: Run, session: Session, tolerance: float = 0.02) -> Check:
    def check() -> tuple[bool, str]:
        result = run.result()
        matrix, offset = np.array(result["matrix"], float), np.array(result["offset"], float)
        if not np.isfinite(matrix).all():
            return False, "NaN in the returned matrix"
        error = load_error(matrix, offset, session)
        return error < tolerance, f"load error {error:.2%} (limit {tolerance:.0%})"

    return check


def api_case(name: str, expect: str, description: str, call: str, session: Session | None = None, tolerance: float = 0.02) -> None:
    """``cal = <call>`` on the standard session's arrays (``readings``, ``known``); worked means near the truth."""

    def body(t: Trial) -> Run:
        simulated = session or simulate()
        run = t.api(f"cal = {call}\n{REPORT_CAL}\n", session_arrays(simulated))
        t.verify(run, api_near_truth(run, simulated, tolerance))
        return run

    register(name, expect, description, body)


R, K = 'data["readings"]', 'data["known"]'
api_case("api-valid", WORKED, "sfmnet.calibrate(readings, 9.81, known)", f"sfmnet.calibrate({R}, magnitude=9.81, loads={K})")
api_case("api-float32", WORKED, "float32 readings", f"sfmnet.calibrate({R}.astype(np.float32), 9.81, {K})", tolerance=0.03)
api_case("api-torch", WORKED, "torch tensors in", f"sfmnet.calibrate(__import__('torch').from_numpy({R}), 9.81, __import__('torch').from_numpy({K}))")
api_case("api-lists", WORKED, "nested lists in", f"sfmnet.calibrate({R}.tolist(), 9.81, {K}.tolist())")
api_case("api-mass-override", WORKED, "**{'data.mass': 1.0003416} instead of a magnitude", f"sfmnet.calibrate({R}, loads={K}, **{{'data.mass': 1.0003416}})")
api_case("api-alternation", WORKED, "model.refinement=alternation as a mapping", f"sfmnet.calibrate({R}, 9.81, {K}, model={{'refinement': 'alternation'}})")
api_case("api-p-equals-n", WORKED, "three channels, three axes", f"sfmnet.calibrate({R}, 9.81, {K})", session=simulate(channels=3, rows=200))
api_case("api-sixteen-channels", WORKED, "sixteen channels", f"sfmnet.calibrate({R}, 9.81, {K})", session=simulate(channels=16, rows=200))
api_case("api-huge-scale", WORKED, "readings x 1e12", f"sfmnet.calibrate({R}, 9.81, {K})", session=simulate(scale=1e12))
api_case("api-tiny-scale", WORKED, "readings x 1e-12", f"sfmnet.calibrate({R}, 9.81, {K})", session=simulate(scale=1e-12))
api_case("api-big-offset", WORKED, "a 1e6 offset on every channel",
         f"sfmnet.calibrate({R}, 9.81, {K})", session=(lambda s: Session(s.matrix, s.offset + 1e6, s.readings + 1e6, s.loads, s.known, s.axes))(simulate()))
api_case("api-all-known", WORKED, "every row's load known", f"sfmnet.calibrate({R}, 9.81, data['loads'])")
api_case("api-nan-readings", REFUSED, "a NaN reading", f"sfmnet.calibrate(np.where(np.arange({R}.size).reshape({R}.shape) == 40, np.nan, {R}), 9.81, {K})")
api_case("api-inf-readings", REFUSED, "an infinite reading", f"sfmnet.calibrate(np.where(np.arange({R}.size).reshape({R}.shape) == 40, np.inf, {R}), 9.81, {K})")
api_case("api-partial-known-row", REFUSED, "a known row with fz NaN", f"sfmnet.calibrate({R}, 9.81, np.where(np.arange({K}.size).reshape({K}.shape) == 2, np.nan, {K}))")
api_case("api-loads-short", REFUSED, "loads with fewer rows than readings", f"sfmnet.calibrate({R}, 9.81, {K}[:-1])")
api_case("api-loads-1d", REFUSED, "loads as a 1-D array", f"sfmnet.calibrate({R}, 9.81, {K}[:, 0])")
api_case("api-readings-1d", REFUSED, "readings as a 1-D array", f"sfmnet.calibrate({R}[:, 0], 9.81, {K})")
api_case("api-readings-3d", REFUSED, "readings as a 3-D array", f"sfmnet.calibrate({R}[None], 9.81, {K})")
api_case("api-empty", REFUSED, "readings of shape (0, 6)", f"sfmnet.calibrate({R}[:0], 9.81, {K}[:0])")
api_case("api-ragged-lists", REFUSED, "ragged nested lists", "sfmnet.calibrate([[1.0, 2.0], [3.0]], 9.81, axes=['x', 'y'])")
api_case("api-string-readings", EITHER, "readings as strings of numbers", f"sfmnet.calibrate({R}.astype(str), 9.81, {K})")
api_case("api-complex", REFUSED, "complex readings", f"sfmnet.calibrate({R} + 1j, 9.81, {K})")
api_case("api-magnitude-text", REFUSED, "magnitude='abc'", f"sfmnet.calibrate({R}, 'abc', {K})")
api_case("api-magnitude-missing", REFUSED, "no magnitude and no mass", f"sfmnet.calibrate({R}, loads={K})")
api_case("api-magnitude-negative", REFUSED, "magnitude=-9.81", f"sfmnet.calibrate({R}, -9.81, {K})")
api_case("api-magnitude-nan", REFUSED, "magnitude=NaN", f"sfmnet.calibrate({R}, float('nan'), {K})")
api_case("api-p-less-than-n", REFUSED, "two channels for three axes", f"sfmnet.calibrate({R}[:, :2], 9.81, {K})")
api_case("api-duplicate-channels", REFUSED, "channels named twice", f"sfmnet.calibrate({R}, 9.81, {K}, channels=['a', 'a', 'b', 'c', 'd', 'e'])")
api_case("api-time-backwards", REFUSED, "time going backwards", f"sfmnet.calibrate({R}, 9.81, {K}, time=-np.arange(len({R})) * 0.01)")
api_case("api-time-nan", REFUSED, "a NaN time", f"sfmnet.calibrate({R}, 9.81, {K}, time=np.where(np.arange(len({R})) == 7, np.nan, np.arange(len({R})) * 0.01))")
api_case("api-unknown-key", REFUSED, "**{'model.bogus': 1}", f"sfmnet.calibrate({R}, 9.81, {K}, **{{'model.bogus': 1}})")
api_case("api-refinement-number", REFUSED, "**{'model.refinement': 5}", f"sfmnet.calibrate({R}, 9.81, {K}, **{{'model.refinement': 5}})")
api_case("api-model-unknown", REFUSED, "model='nope'", f"sfmnet.calibrate({R}, 9.81, {K}, model='nope')")
api_case("api-max-epochs-negative", REFUSED, "trainer={'max_epochs': -1}", f"sfmnet.calibrate({R}, 9.81, {K}, trainer={{'max_epochs': -1}})")
api_case("api-threads-zero", REFUSED, "threads=0", f"sfmnet.calibrate({R}, 9.81, {K}, threads=0)")
api_case("api-seed-text", REFUSED, "seed='abc'", f"sfmnet.calibrate({R}, 9.81, {K}, seed='abc')")
api_case("api-rank-fraction", REFUSED, "model={'rank': 2.5}", f"sfmnet.calibrate({R}, 9.81, {K}, model={{'rank': 2.5}})")
api_case("api-mirror-sign-text", REFUSED, "two known loads and a mirror hint with sign 'up'",
         f"sfmnet.calibrate({R}, 9.81, {K}, data={{'mirror_hint': {{'row': 30, 'axis': 'z', 'sign': 'up'}}}})", session=simulate(known=2))
api_case("api-one-known-load", REFUSED, "one known load for three axes", f"sfmnet.calibrate({R}, 9.81, {K})", session=simulate(known=1))


@case("api-no-loads-axes", WORKED, "loads=None, axes=[x,y,z]: every magnitude right (frame arbitrary)")
def _(t: Trial) -> Run:
    session = simulate()
    run = t.api(f"""
        cal = sfmnet.calibrate({R}, 9.81, axes=['x', 'y', 'z'])
        report({{"norms": np.linalg.norm(cal.apply({R}), axis=1).tolist()}})
    """, session_arrays(session))

    def check() -> tuple[bool, str]:
        norms = np.array(run.result()["norms"])
        error = float(np.max(np.abs(norms - MAGNITUDE)) / MAGNITUDE)
        return error < 0.01, f"worst |load| error {error:.2%}"

    t.verify(run, check)
    return run


@case("api-run-dir-used", REFUSED, "run_dir= a folder holding an earlier run: refused, untouched")
def _(t: Trial) -> Run:
    fake_run(t.run)
    return t.api(f"sfmnet.calibrate({R}, 9.81, {K}, run_dir=tmp + '/run')", session_arrays())


@case("api-run-dir-file", REFUSED, "run_dir= an existing file")
def _(t: Trial) -> Run:
    write(t.run, "a file\n")
    return t.api(f"sfmnet.calibrate({R}, 9.81, {K}, run_dir=tmp + '/run')", session_arrays())


@case("api-run-dir-non-ascii", WORKED, "run_dir= a new folder with non-ASCII letters: calibration.json there")
def _(t: Trial) -> Run:
    # The session's own channel names, so the calibration.json written there can be read against it.
    channels = simulate().channels
    run = t.api(f"cal = sfmnet.calibrate({R}, 9.81, {K}, channels={channels}, run_dir=tmp + '/Läufe_試験')\n{REPORT_CAL}",
                session_arrays())
    t.verify(run, near_truth(t.tmp / "Läufe_試験", simulate()))
    return run


@case("api-verbose", WORKED, "verbose=True prints the summary")
def _(t: Trial) -> Run:
    run = t.api(f"cal = sfmnet.calibrate({R}, 9.81, {K}, verbose=True)\n{REPORT_CAL}", session_arrays())
    t.verify(run, api_near_truth(run, simulate()))
    return run


@case("api-save-load-roundtrip", WORKED, "Calibration.save then .load to a non-ASCII path: the same matrix")
def _(t: Trial) -> Run:
    run = t.api(f"""
        cal = sfmnet.calibrate({R}, 9.81, {K})
        cal.save(tmp + '/Kalibrierung_ä.json')
        again = sfmnet.Calibration.load(tmp + '/Kalibrierung_ä.json')
        report({{"same": bool((cal.matrix == again.matrix).all() and (cal.offset == again.offset).all())}})
    """, session_arrays())
    t.verify(run, lambda: (run.result()["same"], "save/load round trip exact" if run.result()["same"] else "save/load changed the matrix"))
    return run


@case("api-load-nan-json", REFUSED, "Calibration.load of a file with NaN in its matrix: refused, never NaN loads")
def _(t: Trial) -> Run:
    session = simulate()
    write(t.path("cal.json"), json.dumps({"matrix": [[float("nan")] * 6] * 3, "offset": [0.0] * 6, "channels": session.channels, "axes": session.axes}))
    run = t.api("report(sfmnet.Calibration.load(tmp + '/cal.json').apply(np.ones((2, 6))).tolist())")
    t.verify(run, never_right("a NaN calibration loaded without a word: its loads are NaN"))
    return run


@case("api-all-nan-loads", EITHER, "loads given, every row NaN: refused, or at least said to be in an arbitrary frame")
def _(t: Trial) -> Run:
    run = t.api(f"""
        cal = sfmnet.calibrate({R}, 9.81, np.full_like({K}, np.nan))
        report({{"frame": str(cal.extra.get("frame", "")), "warnings": cal.warnings}})
    """, session_arrays())

    def check() -> tuple[bool, str]:
        result = run.result()
        said = "arbitrary" in result["frame"] or any("arbitrary" in w for w in result["warnings"])
        return said, f"frame {result['frame']!r}" if said else "a calibration in a frame no load fixed, not said to be arbitrary"

    t.verify(run, check)
    return run


@case("api-load-text-json", REFUSED, "Calibration.load of a file with text in its matrix")
def _(t: Trial) -> Run:
    write_calibration(t.path("cal.json"), simulate(), matrix=[["a"] * 6] * 3)
    return t.api("sfmnet.Calibration.load(tmp + '/cal.json')")


@case("api-apply-wrong-width", REFUSED, "Calibration.apply of readings with 5 columns for 6 channels")
def _(t: Trial) -> Run:
    write_calibration(t.path("cal.json"), simulate())
    return t.api("sfmnet.Calibration.load(tmp + '/cal.json').apply(np.ones((4, 5)))")


@case("api-apply-one-reading", EITHER, "Calibration.apply of one reading as a 1-D array: refused, or its load")
def _(t: Trial) -> Run:
    session = simulate()
    write_calibration(t.path("cal.json"), session)
    run = t.api(f"report(np.asarray(sfmnet.Calibration.load(tmp + '/cal.json').apply({R}[0])).tolist())", session_arrays(session))
    t.verify(run, lambda: (np.allclose(np.ravel(run.result()), session.matrix @ (session.readings[0] - session.offset)), "the row's load"))
    return run


# ================================================================ cases: the Python API (CommandLearner)


def learner_arrays(rows: int = 400) -> dict[str, np.ndarray]:
    """Sensors that follow one command label, as in ``write_log``."""
    rng = np.random.default_rng(0)
    labels = np.array(["back", "stop", "go"])
    codes = np.repeat(rng.integers(3, size=rows // 20 + 1), 20)[:rows]
    level = codes - 1.0
    sensors = np.stack([level, 0.5 * level, np.abs(level), rng.normal(size=rows)], axis=1) + 0.1 * rng.normal(size=(rows, 4))
    return {"sensors": sensors, "commands": labels[codes]}


S, C = 'data["sensors"]', 'data["commands"]'


def learner_case(name: str, expect: str, description: str, code: str, accuracy: float | None = None,
                 judge_result: Callable[[Any], tuple[bool, str]] | None = None) -> None:
    """A CommandLearner snippet; worked means a training accuracy of at least ``accuracy``, or ``judge_result`` of what it reports."""
    if accuracy is not None:
        judge_result = lambda value: (value >= accuracy, f"training accuracy {value:.3f}")

    def body(t: Trial) -> Run:
        run = t.api(code, learner_arrays())
        if judge_result is not None:
            t.verify(run, lambda: judge_result(run.result()))
        return run

    register(name, expect, description, body)


NO_MISSING_LABEL = lambda labels: (not {"None", "nan"} & set(labels), f"labels learnt: {labels}")
FIT_AND_SCORE = "report(float((learner.predict({S}) == {C}).mean()))"
learner_case("learner-valid", WORKED, "CommandLearner().fit then predict on its own data",
             f"learner = sfmnet.CommandLearner().fit({S}, {C})\n" + FIT_AND_SCORE.format(S=S, C=C), accuracy=0.9)
learner_case("learner-autoencoder", WORKED, "CommandLearner('autoencoder', max_epochs=5)",
             f"learner = sfmnet.CommandLearner('autoencoder', max_epochs=5).fit({S}, {C})\n" + FIT_AND_SCORE.format(S=S, C=C), accuracy=0.9)
learner_case("learner-nan-sensors", REFUSED, "a NaN sensor value", f"sfmnet.CommandLearner().fit(np.where(np.arange({S}.size).reshape({S}.shape) == 9, np.nan, {S}), {C})")
learner_case("learner-rows-mismatch", REFUSED, "one command row short", f"sfmnet.CommandLearner().fit({S}, {C}[:-1])")
learner_case("learner-one-sample", REFUSED, "one sample", f"sfmnet.CommandLearner().fit({S}[:1], {C}[:1])")
learner_case("learner-text-sensors", EITHER, "sensors as strings of numbers",
             f"learner = sfmnet.CommandLearner().fit({S}.astype(str), {C})\n" + FIT_AND_SCORE.format(S=S, C=C), accuracy=0.9)
learner_case("learner-bogus-kind", REFUSED, "learner='forest'", f"sfmnet.CommandLearner('forest').fit({S}, {C})")
learner_case("learner-rank-fraction", REFUSED, "rank=2.5", f"sfmnet.CommandLearner(rank=2.5).fit({S}, {C})")
learner_case("learner-rank-zero", REFUSED, "rank=0", f"sfmnet.CommandLearner(rank=0).fit({S}, {C})")
learner_case("learner-rank-too-big", REFUSED, "rank=50 for 7 columns", f"sfmnet.CommandLearner(rank=50).fit({S}, {C})")
learner_case("learner-rank-rule-bogus", REFUSED, "rank_rule='vibes'", f"sfmnet.CommandLearner(rank_rule='vibes').fit({S}, {C})")
learner_case("learner-none-labels", REFUSED, "commands with None (missing) labels",
             f"c = {C}.astype(object); c[5] = None\nlearner = sfmnet.CommandLearner().fit({S}, c)\nreport([str(v) for v in learner.labels_[0]])",
             judge_result=NO_MISSING_LABEL)
learner_case("learner-nan-labels", REFUSED, "numeric commands with NaN",
             f"c = np.where({C} == 'go', 1.0, 0.0); c[5] = np.nan\nlearner = sfmnet.CommandLearner().fit({S}, c)\nreport([str(v) for v in learner.labels_[0]])",
             judge_result=NO_MISSING_LABEL)
learner_case("learner-predict-unfitted", REFUSED, "predict before fit", f"sfmnet.CommandLearner().predict({S})")
learner_case("learner-predict-wrong-width", REFUSED, "predict with 3 sensor columns for 4", f"sfmnet.CommandLearner().fit({S}, {C}).predict({S}[:, :3])")
learner_case("learner-predict-nan", REFUSED, "predict from a NaN sensor row: refused, never a label from NaN",
             f"learner = sfmnet.CommandLearner().fit({S}, {C})\nreport(learner.predict(np.full((2, 4), np.nan)).tolist())",
             judge_result=lambda labels: (False, f"labels {labels} read from NaN sensors"))
learner_case("learner-max-epochs-negative", REFUSED, "an autoencoder with max_epochs=-1 (would never end)",
             f"sfmnet.CommandLearner('autoencoder', max_epochs=-1).fit({S}, {C})")
learner_case("learner-constant-sensor", REFUSED, "a constant sensor column", f"s = {S}.copy(); s[:, 3] = 1.0\nsfmnet.CommandLearner().fit(s, {C})")
learner_case("learner-set-params-bogus", REFUSED, "set_params(depth=3)", "sfmnet.CommandLearner().set_params(depth=3)")
learner_case("learner-seed-negative", EITHER, "seed=-1", f"learner = sfmnet.CommandLearner(seed=-1).fit({S}, {C})\n" + FIT_AND_SCORE.format(S=S, C=C), accuracy=0.9)
learner_case("learner-mixed-labels", EITHER, "labels mixing ints and strings",
             f"c = {C}.astype(object); c[c == 'stop'] = 0\nlearner = sfmnet.CommandLearner().fit({S}, c)\nreport(float((learner.predict({S}) == c).mean()))",
             accuracy=0.9)


# ================================================================ the trial


def run_case(case: Case, keep: bool) -> tuple[Verdict, float]:
    trial = Trial(Path(tempfile.mkdtemp(prefix=f"{case.name}-", dir=WORKDIR)))
    began = time.monotonic()
    try:
        verdict = judge(trial, case.body(trial))
    except Exception as error:  # the trial's own failure (a reference run, a mount, a bug here), not sfmnet's
        verdict = Verdict(HARNESS, one_line(f"{type(error).__name__}: {error}"))
    finally:
        trial.cleanup(keep)
    return verdict, time.monotonic() - began


def main() -> int:
    global WORKDIR
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--only", action="append", metavar="NAME", help="run the cases matching this name or glob (repeatable)")
    parser.add_argument("--list", action="store_true", help="list the cases and exit")
    parser.add_argument("--csv", type=Path, help="also write the table as CSV here")
    parser.add_argument("--keep", action="store_true", help="keep each case's folder (under the work folder)")
    parser.add_argument("--workdir", type=Path, help="where case folders go (default: a new temporary folder)")
    options = parser.parse_args()

    selected = [c for c in CASES.values() if not options.only or any(fnmatch.fnmatchcase(c.name, p) for p in options.only)]
    if options.list:
        for c in selected:
            print(f"{c.name:40} {c.expect:8} {c.description}")
        print(f"{len(selected)} cases")
        return 0
    if not selected:
        print(f"no case matches {options.only}", file=sys.stderr)
        return 2
    WORKDIR = options.workdir or Path(tempfile.mkdtemp(prefix="sfmnet-adversarial-"))
    WORKDIR.mkdir(parents=True, exist_ok=True)
    print(f"{len(selected)} cases; case folders under {WORKDIR}")

    results: list[tuple[Case, Verdict, float]] = []
    for number, c in enumerate(selected, start=1):
        verdict, seconds = run_case(c, options.keep)
        results.append((c, verdict, seconds))
        mark = "  " if expected(c, verdict.got) else "!!"
        print(f"{mark} [{number}/{len(selected)}] {c.name:40} {c.expect:8} {verdict.got:15} {seconds:6.1f}s  {verdict.detail}", flush=True)

    print(f"\n{'case':40} {'expected':8} {'got':15} detail")
    for c, verdict, _ in results:
        print(f"{c.name:40} {c.expect:8} {verdict.got:15} {verdict.detail}")
    counts = Counter(verdict.got for _, verdict, _ in results)
    unexpected = [c.name for c, verdict, _ in results if not expected(c, verdict.got)]
    print("\n" + ", ".join(f"{name}: {counts[name]}" for name in CLASSES if counts[name]) + f"; {len(results)} cases, {len(unexpected)} not as expected")
    if options.csv:
        with options.csv.open("w", newline="") as stream:
            writer = csv.writer(stream)
            writer.writerow(["name", "expected", "got", "as_expected", "seconds", "detail", "description"])
            for c, verdict, seconds in results:
                writer.writerow([c.name, c.expect, verdict.got, expected(c, verdict.got), f"{seconds:.1f}", verdict.detail, c.description])
    if options.workdir is None and not options.keep:
        shutil.rmtree(WORKDIR, ignore_errors=True)
    return 1 if unexpected else 0


if __name__ == "__main__":
    sys.exit(main())
