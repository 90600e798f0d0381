"""Nothing lost: a run killed partway resumes from its last checkpoint to the uninterrupted result; same seed, same bits."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from sfmnet.training.run import train
from tests.conftest import REPO, compose_config

RUN = ["experiment=lord3dof", "data.samples=5000", "trainer.max_epochs=20", "trainer.enable_progress_bar=false"]


def sfmnet(*args: str) -> list[str]:
    return [sys.executable, "-m", "sfmnet", "train", *RUN, *args]


def test_killed_run_resumes_to_the_uninterrupted_result(tmp_path: Path):
    killed = tmp_path / "killed"
    process = subprocess.Popen(sfmnet(f"hydra.run.dir={killed}"), cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    checkpoint = killed / "checkpoints" / "shape_from_motion" / "last.ckpt"
    deadline = time.monotonic() + 120
    while not checkpoint.is_file() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()
    assert checkpoint.is_file(), "no checkpoint was written before the kill"
    assert not (killed / "calibration.json").exists(), "the run finished before it could be killed"

    resumed = subprocess.run(
        sfmnet(f"hydra.run.dir={tmp_path / 'resumed'}", f"ckpt_path={checkpoint}"),
        cwd=REPO, capture_output=True, text=True, check=False, env={**os.environ},
    )
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    whole = subprocess.run(sfmnet(f"hydra.run.dir={tmp_path / 'whole'}"), cwd=REPO, capture_output=True, check=False)
    assert whole.returncode == 0
    first = json.loads((tmp_path / "resumed" / "calibration.json").read_text())
    second = json.loads((tmp_path / "whole" / "calibration.json").read_text())
    assert first["matrix"] == second["matrix"] and first["offset"] == second["offset"]


def test_missing_checkpoint_is_one_clear_error(tmp_path: Path):
    done = subprocess.run(
        sfmnet(f"hydra.run.dir={tmp_path / 'run'}", f"ckpt_path={tmp_path / 'nope.ckpt'}"),
        cwd=REPO, capture_output=True, text=True, check=False,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [f"error: ckpt_path {tmp_path / 'nope.ckpt'} is not a file: give a run's checkpoints/<method>/last.ckpt"]


def test_same_seed_same_calibration_bit_for_bit(tmp_path: Path):
    results = []
    for name in ("first", "second"):
        train(compose_config(["experiment=lord3dof", "seed=7"]), tmp_path / name)
        results.append(json.loads((tmp_path / name / "calibration.json").read_text()))
    assert results[0]["matrix"] == results[1]["matrix"]
    assert results[0]["offset"] == results[1]["offset"]
    assert results[0]["matrix_std"] == results[1]["matrix_std"]
