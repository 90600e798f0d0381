"""Comparing runs: a 2-setting x 2-seed sweep's summary table, its HParams data in TensorBoard, train.log, and the
progress shown outside a terminal. One real sweep (a subprocess, stdout a pipe) serves every test."""

from __future__ import annotations

import csv
import json
import logging
import statistics
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensorboard.plugins.hparams import plugin_data_pb2

from sfmnet.training.headline_metrics import headline_keys
from sfmnet.training.run import train
from tests.conftest import REPO, compose_config, write_session

SAMPLES = ("48", "96")
SEEDS = ("0", "1")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """The sweep's directory and its console output (progress on: stdout is not a terminal here)."""
    sweep_dir = tmp_path_factory.mktemp("sweep") / "sweep"
    done = subprocess.run(
        [sys.executable, "-m", "sfmnet", "train", "-m", f"data.samples={','.join(SAMPLES)}", f"seed={','.join(SEEDS)}",
         "trainer.max_epochs=2", f"hydra.sweep.dir={sweep_dir}"],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return sweep_dir, done.stdout


def jobs(sweep_dir: Path) -> dict[tuple[str, str], Path]:
    """Each job's directory by its (data.samples, seed), read from the overrides Hydra saved."""
    found = {}
    for overrides in sweep_dir.glob("*/.hydra/overrides.yaml"):
        settings = dict(item.split("=", 1) for item in OmegaConf.to_container(OmegaConf.load(overrides)))
        found[settings["data.samples"], settings["seed"]] = overrides.parent.parent
    return found


def test_summary_table_gives_mean_and_std_over_seeds(sweep: tuple[Path, str]):
    sweep_dir, stdout = sweep
    metrics = {key: json.loads((job / "metrics.json").read_text()) for key, job in jobs(sweep_dir).items()}
    summary = list(csv.DictReader((sweep_dir / "sweep_summary.csv").open()))
    assert [row["data.samples"] for row in summary] == list(SAMPLES) and "seed" not in summary[0]
    for row in summary:
        assert row["n"] == "2"
        for figure in ("eval/max_error_pct", "coverage", "rank_gap"):
            values = [metrics[row["data.samples"], seed][figure] for seed in SEEDS]
            assert row[f"{figure} mean"] == f"{statistics.mean(values):.4g}"
            assert row[f"{figure} std"] == f"{statistics.stdev(values):.4g}"
    # Printed: the table, and both files by absolute path.
    assert f"this table: {sweep_dir / 'sweep_summary.csv'}" in stdout and f"every job: {sweep_dir / 'sweep.csv'}" in stdout
    assert sweep_dir.is_absolute()
    printed = next(line for line in stdout.splitlines() if line.startswith("eval/max_error_pct "))
    assert " ± ".join((summary[0]["eval/max_error_pct mean"], summary[0]["eval/max_error_pct std"])) in printed
    per_job = list(csv.DictReader((sweep_dir / "sweep.csv").open()))
    assert len(per_job) == 4 and all(len(row["rank_gap"].replace(".", "")) <= 4 for row in per_job)


def test_hparams_and_final_figures_in_the_event_files(sweep: tuple[Path, str]):
    job = jobs(sweep[0])["96", "1"]
    metrics = json.loads((job / "metrics.json").read_text())
    events = EventAccumulator(str(job / "tensorboard" / "shape_from_motion"), size_guidance={"scalars": 0})
    events.Reload()
    plugin = {tag: plugin_data_pb2.HParamsPluginData.FromString(content)
              for tag, content in events.PluginTagToContent("hparams").items()}
    settings = plugin["_hparams_/session_start_info"].session_start_info.hparams
    assert settings["data.samples"].number_value == 96 and settings["seed"].number_value == 1
    assert settings["method"].string_value == "shape_from_motion" and settings["experiment_name"].string_value == "fingertip"
    columns = [info.name.tag for info in plugin["_hparams_/experiment"].experiment.metric_infos]
    assert columns == [f"final/{key}" for key in headline_keys(metrics)]
    assert {"final/eval/max_error_pct", "final/coverage", "final/rank_gap"} <= set(columns)
    # Every figure of metrics.json is a scalar, the headline ones with the values the HParams view shows.
    for key, value in metrics.items():
        (logged,) = events.Scalars(f"final/{key}")
        assert logged.value == pytest.approx(value, rel=1e-6, abs=1e-30)
    assert "data.samples: 96" in (job / "tensorboard" / "shape_from_motion" / "hparams.yaml").read_text()


def test_train_log_holds_the_console_and_progress_is_one_line_per_epoch(sweep: tuple[Path, str]):
    sweep_dir, stdout = sweep
    job = jobs(sweep_dir)["48", "0"]
    log = (job / "train.log").read_text()
    headline = next(line for line in stdout.splitlines() if line.startswith("  shape_from_motion: worst |load| error"))
    assert headline in log and f"run directory: {job}" in log
    assert "shape_from_motion epoch 1/2: " in log and "shape_from_motion epoch 2/2: " in log
    # On the console once each (no second handler), with no carriage returns from a bar.
    assert stdout.count(f"run directory: {job}\n") == 1
    assert "\r" not in stdout
    assert stdout.count("shape_from_motion epoch 2/2: loss_epoch ") == 4


def test_headline_keys_put_the_main_method_first():
    keys = ["least_squares/coverage", "coverage", "eval/111.4/mean", "drive_accuracy", "eval/max_error_pct",
            "least_squares/eval/max_error_pct", "residual_rms/ch0"]
    assert headline_keys(keys) == [
        "eval/max_error_pct", "coverage", "drive_accuracy", "least_squares/eval/max_error_pct", "least_squares/coverage"
    ]


def test_a_converged_fit_prints_its_repeated_epochs_once(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    """The default fit converges in its first epoch: the nine after it repeat its figures, and one line says so."""
    cfg = compose_config(["trainer.max_epochs=5"])
    cfg.trainer.enable_progress_bar = True
    with caplog.at_level(logging.INFO, logger="sfmnet.training.progress"):
        train(cfg, tmp_path / "run")
    lines = [record.getMessage() for record in caplog.records if record.name == "sfmnet.training.progress"]
    assert len(lines) == 2, lines
    first, last = lines
    assert first.startswith("shape_from_motion epoch 1/5: loss_epoch ")
    assert last == first.replace("epoch 1/5", "epoch 5/5") + " (unchanged since epoch 1)"


def test_a_streamed_pass_that_logs_nothing_prints_no_line(tmp_path: Path, caplog: pytest.LogCaptureFixture):
    """Two testers' streamed runs began with `streamed_shape_from_motion epoch 1/50: ` and nothing after it: the pass
    summing the moments logs no figures."""
    session = tmp_path / "session.csv"
    write_session(session, known_loads=3)
    cfg = compose_config(["experiment=calibrate_stream", f"data.path={session}", "data.magnitude=9.81"])
    cfg.trainer.enable_progress_bar = True
    with caplog.at_level(logging.INFO, logger="sfmnet.training.progress"):
        train(cfg, tmp_path / "run")
    lines = [record.getMessage() for record in caplog.records if record.name == "sfmnet.training.progress"]
    assert lines and all(not line.endswith(": ") and "train/" in line for line in lines), lines
