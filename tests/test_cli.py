"""The command line end to end, in real subprocesses: outputs, sweeps, and one-line errors."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from sfmnet.cli import shared_sweep_dir
from sfmnet.errors import SfmnetError
from sfmnet.training.run import train
from tests.conftest import REPO, compose_config

QUIET = ["trainer.enable_progress_bar=false"]


def sfmnet(*args: str, cwd: Path = REPO, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sfmnet", *args],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_default_train_end_to_end(tmp_path: Path):
    run_dir = tmp_path / "run"
    result = sfmnet("train", f"hydra.run.dir={run_dir}", *QUIET)
    assert result.returncode == 0, result.stderr
    assert f"run directory: {run_dir}" in result.stdout
    assert "shape_from_motion: worst |load| error" in result.stdout
    calibration = json.loads((run_dir / "calibration.json").read_text())
    assert calibration["axes"] == ["fx", "fy"] and len(calibration["channels"]) == 4
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["eval/max_error_pct"] <= 0.3
    assert (run_dir / ".hydra" / "config.yaml").is_file()
    assert (run_dir / "checkpoints" / "shape_from_motion" / "last.ckpt").is_file()


def test_command_word_is_optional(tmp_path: Path):
    """Lightning's DDP launcher restarts workers without the command word (method §12)."""
    result = sfmnet(f"hydra.run.dir={tmp_path / 'run'}", "trainer.fast_dev_run=true", *QUIET)
    assert result.returncode == 0, result.stderr
    assert (tmp_path / "run" / "calibration.json").is_file()


@pytest.mark.parametrize(
    "overrides,message",
    [
        # With noise, degenerate motion shows as an indefinite Q or as poor coverage.
        (["data.motion_span=1"], "the loads are collinear or coplanar"),
        (["experiment=lord3dof", "data.known_loads=3", "data.motion_span=2"], "the loads are collinear or coplanar"),
        (["data.samples=2"], "only 3 samples for 5 unknowns of the metric constraint with offsets"),
        (["experiment=lord3dof", "data.mirror_hint=false"], "fix the 3-axis frame only up to a mirror image"),
        (["model.rank=3"], "model.rank is 3 but the data has 2 load axes"),
        (["model=least_squares"], "learns from a 'least_squares' recording, which this data does not have"),
    ],
    ids=["collinear", "coplanar", "too-few-samples", "no-mirror-bit", "wrong-rank", "no-known-loads"],
)
def test_data_the_method_cannot_use_is_refused(tmp_path: Path, overrides: list[str], message: str):
    """In process (the command line's one line and exit 2 for such an error: the tests below)."""
    with pytest.raises(SfmnetError) as caught:
        train(compose_config([*overrides, "trainer.enable_progress_bar=false"]), tmp_path / "run")
    assert message in str(caught.value)
    assert not (tmp_path / "run" / "calibration.json").exists()


@pytest.mark.parametrize(
    "overrides,message",
    [
        (["experiment=fingertp"], "unknown experiment 'fingertp' (did you mean 'fingertip'?): choose one of"),
        (["data.nosie_fraction=0.1"], "unknown config key 'data.nosie_fraction' (did you mean 'data.noise_fraction'?)"),
        (["experiment=calibrate_csv"], "data.path must be given, e.g. data.path=<value>"),
        (["experiment=calibrate_csv", "data.path=/no/such/file.csv", "data.magnitude=1"], "/no/such/file.csv does not exist"),
        (["data.motion_span=1"], "the loads are collinear or coplanar"),
        (["experiment=table1", "baselines={}"], "baselines={} removes nothing (Hydra merges it into baselines, which keeps"),
    ],
    ids=["unknown-experiment", "misspelt-key", "missing-path", "no-such-file", "collinear", "empty-dict-removes-nothing"],
)
def test_bad_input_one_line_exit_2(tmp_path: Path, overrides: list[str], message: str):
    result = sfmnet("train", f"hydra.run.dir={tmp_path / 'run'}", *overrides, *QUIET)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("error: ") and message in lines[-1], result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "run" / "calibration.json").exists()


def test_debug_switch_shows_traceback(tmp_path: Path):
    result = sfmnet("train", f"hydra.run.dir={tmp_path / 'run'}", "data.motion_span=1", *QUIET, env={"SFMNET_DEBUG": "1"})
    assert result.returncode != 0
    assert "Traceback" in result.stderr


def test_used_run_directory_is_refused(tmp_path: Path):
    run_dir = tmp_path / "mine"
    run_dir.mkdir()
    (run_dir / "notes.txt").write_text("keep me")
    result = sfmnet("train", f"hydra.run.dir={run_dir}", *QUIET)
    assert result.returncode == 2
    assert "already holds files" in result.stderr
    assert sorted(p.name for p in run_dir.iterdir()) == ["notes.txt"]


def test_unknown_command():
    result = sfmnet("calibrate")
    assert result.returncode == 2
    assert "unknown command 'calibrate'" in result.stderr


def test_installed_wheel_finds_its_configs(tmp_path: Path):
    """Outside the checkout, the configs come from inside the installed package (method §12)."""
    # From a copy of the sources: a checkout's stale build/ folder would hide a package left out of the wheel.
    source = tmp_path / "source"
    for name in ("sfmnet", "conf"):
        shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, source / name)
    build = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp_path / "dist"), str(source)],
        capture_output=True, text=True, timeout=300,
    )
    assert build.returncode == 0, build.stderr
    wheel = next((tmp_path / "dist").glob("sfmnet-*.whl"))
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    assert (site / "sfmnet" / "conf" / "experiment" / "table1.yaml").is_file()
    # Every module of the checkout ships (an editable install on the path would hide a missing package).
    modules = {path.relative_to(REPO).as_posix() for path in (REPO / "sfmnet").rglob("*.py")}
    assert modules <= {path.relative_to(site).as_posix() for path in (site / "sfmnet").rglob("*.py")}
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    result = sfmnet(
        "train", "trainer.fast_dev_run=true", f"hydra.run.dir={elsewhere / 'run'}", *QUIET,
        cwd=elsewhere, env={"PYTHONPATH": str(site)},
    )
    assert result.returncode == 0, result.stderr
    assert (elsewhere / "run" / "calibration.json").is_file()


def test_a_sweep_goes_on_past_a_failed_job_and_says_which_failed(tmp_path: Path):
    """Hydra stops a sweep at a job's error (a hostile tester's: the jobs after it never ran, no summary was written)."""
    sweep_dir = tmp_path / "sweep"
    result = sfmnet("train", "-m", "data.motion_span=1,2", "trainer.max_epochs=2", f"hydra.sweep.dir={sweep_dir}", *QUIET)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "error in job 0: " in result.stderr and "the loads are collinear or coplanar" in result.stderr
    assert "collinear" in (sweep_dir / "0" / "error.txt").read_text()
    assert (sweep_dir / "1" / "metrics.json").is_file() and not (sweep_dir / "0" / "metrics.json").exists()
    assert "1 of 2 jobs failed (job 0)" in result.stdout
    with (sweep_dir / "sweep.csv").open() as stream:
        assert [row["job"] for row in csv.DictReader(stream)] == ["1"]


def test_a_sweep_over_experiments_is_summarised_in_one_directory(tmp_path: Path):
    """Each job named the default sweep directory after its own experiment: a hostile tester's sweep over two
    experiments landed in two directories, and the summary of "4 jobs" held only the first experiment's."""
    result = sfmnet("train", "-m", "experiment=fingertip,lord3dof", "trainer.max_epochs=2", *QUIET, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    (sweep_dir,) = (tmp_path / "runs" / "multirun").glob("*/*")
    assert sweep_dir.parent.name == "fingertip+lord3dof"
    with (sweep_dir / "sweep.csv").open() as stream:
        assert [row["experiment"] for row in csv.DictReader(stream)] == ["fingertip", "lord3dof"]
    # A directory given is kept, and a sweep of one experiment keeps the default.
    assert shared_sweep_dir(["experiment=a,b", "hydra.sweep.dir=x"]) == [] == shared_sweep_dir(["experiment=a", "seed=0,1"])
    assert shared_sweep_dir(["experiment=glob(finger*)"])[0].startswith("hydra.sweep.dir=runs/multirun/experiments/")


def test_ctrl_c_or_sigterm_between_a_sweeps_jobs_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch):
    """A hostile tester's Ctrl-C between two jobs was a traceback of Hydra's launcher (status -2), and SIGTERM there
    ended the sweep silently (-15); now both are one line, exit 130, the sweep directory's claim released."""
    import signal

    from sfmnet import cli
    from sfmnet.training.run_directory import LOCK_NAME

    def between_jobs() -> None:
        raise KeyboardInterrupt

    (tmp_path / LOCK_NAME).write_text("claimed")
    monkeypatch.setattr(cli, "SWEEP_DIRS", [tmp_path])
    with pytest.raises(SystemExit) as stopped:
        cli.stop_on_interrupt(between_jobs)
    assert stopped.value.code == 130 and not (tmp_path / LOCK_NAME).exists()
    assert capsys.readouterr().err == (
        f"interrupted: stopped between a sweep's jobs: the finished jobs are in {tmp_path}; run the command again for the rest\n"
    )
    # The command line turns SIGTERM into that same interruption.
    before = signal.getsignal(signal.SIGTERM)
    try:
        with pytest.raises(SystemExit):
            cli.main(["train", "notasetting"])
        assert signal.getsignal(signal.SIGTERM) is cli.terminate_as_interrupt
        with pytest.raises(KeyboardInterrupt):
            cli.terminate_as_interrupt(signal.SIGTERM, None)
    finally:
        signal.signal(signal.SIGTERM, before)


def test_ctrl_c_after_the_fit_is_one_line_naming_the_checkpoint(tmp_path: Path, capsys: pytest.CaptureFixture):
    """A Ctrl-C while the results are written (after the fit's own handler) was a traceback of 100 lines."""
    from sfmnet.cli import exit_on_user_error

    def interrupted() -> None:
        raise KeyboardInterrupt

    with pytest.raises(SystemExit) as stopped:
        exit_on_user_error(interrupted, run_dir=tmp_path)
    assert stopped.value.code == 130 and "run the command again" in capsys.readouterr().err
    checkpoint = tmp_path / "checkpoints" / "shape_from_motion" / "last.ckpt"
    checkpoint.parent.mkdir(parents=True)
    checkpoint.write_bytes(b"")
    with pytest.raises(SystemExit) as stopped:
        exit_on_user_error(interrupted, run_dir=tmp_path)
    message = capsys.readouterr().err
    assert stopped.value.code == 130 and message.startswith("interrupted: stopped after a fit") and f"ckpt_path={checkpoint}" in message
