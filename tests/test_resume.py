"""Nothing lost: a run killed or stopped partway resumes from its last checkpoint to the uninterrupted result, bit for bit.

The killed runs send themselves the signal at the end of an epoch (``tests/signal_at_epoch.py``),
before that epoch's checkpoint is written, so the fit is cut off mid-way at a known point.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor, write_stream_csv
from sfmnet.training.run import train
from tests.conftest import REPO, SMALL_SPHERE_GRID, compose_config, write_session
from tests.test_gross_outliers import held_poses

# Two L-BFGS iterations an epoch: the fit is still moving when it is killed, its optimiser history in play.
CALIBRATION = [
    "experiment=lord3dof", "data.samples=300", "model.refinement=marginal", f"model.marginal_grid={SMALL_SPHERE_GRID}",
    "optimizer.max_iter=2", "trainer.max_epochs=8",
]
# Closed loop off: it runs after the fit, which is what is killed and resumed here.
EIGENSPACE = ["experiment=mkv_pca", "trainer.max_epochs=6", "eval.closed_loop=null"]


def sfmnet(run_dir: Path, *args: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "sfmnet", "train", f"hydra.run.dir={run_dir}", "trainer.enable_progress_bar=false", *args]
    return subprocess.run(command, cwd=REPO, capture_output=True, text=True, check=False)


def signal_at(epoch: int, signal: str) -> list[str]:
    return [
        "+callbacks.signal._target_=tests.signal_at_epoch.SignalAtEpoch",
        f"+callbacks.signal.epoch={epoch}",
        f"+callbacks.signal.signal={signal}",
    ]


def killed_then_resumed(tmp_path: Path, run: list[str], method: str, epoch: int) -> subprocess.CompletedProcess:
    """SIGKILL ``run`` at the end of ``epoch``; resume it from the newest checkpoint into ``tmp_path / "resumed"``."""
    killed = sfmnet(tmp_path / "killed", *run, *signal_at(epoch, "SIGKILL"))
    assert killed.returncode == -9, killed.stderr[-2000:]
    checkpoints = tmp_path / "killed" / "checkpoints" / method
    # Every finished epoch left its checkpoint; the run stopped before its results.
    assert sorted(p.name for p in checkpoints.glob("epoch*.ckpt")) == [f"epoch{e:03d}.ckpt" for e in range(epoch)]
    assert not (tmp_path / "killed" / "metrics.json").exists()
    last = checkpoints / "last.ckpt"
    assert torch.load(last, weights_only=False)["epoch"] == epoch - 1
    resumed = sfmnet(tmp_path / "resumed", *run, f"ckpt_path={last}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    return resumed


def uninterrupted(tmp_path: Path, run: list[str]) -> Path:
    """``run`` from start to finish into ``tmp_path / "whole"``."""
    whole = sfmnet(tmp_path / "whole", *run)
    assert whole.returncode == 0, whole.stderr[-2000:]
    return tmp_path / "whole"


def assert_same_calibration(first_dir: Path, second_dir: Path) -> None:
    first, second = (json.loads((folder / "calibration.json").read_text()) for folder in (first_dir, second_dir))
    for key in ("matrix", "offset", "matrix_std"):
        assert first[key] == second[key], key


def test_calibration_killed_mid_fit_resumes_bit_for_bit(tmp_path: Path):
    killed_then_resumed(tmp_path, CALIBRATION, "shape_from_motion", epoch=4)
    resumed = tmp_path / "resumed"
    whole = uninterrupted(tmp_path, CALIBRATION)
    assert_same_calibration(resumed, whole)
    assert json.loads((resumed / "metrics.json").read_text())["epochs"] == 8


def test_eigenspace_learner_killed_mid_fit_resumes_bit_for_bit(tmp_path: Path):
    killed_then_resumed(tmp_path, EIGENSPACE, "eigenspace", epoch=3)
    resumed = tmp_path / "resumed"
    whole = uninterrupted(tmp_path, EIGENSPACE)
    with np.load(resumed / "learner.npz") as first, np.load(whole / "learner.npz") as second:
        assert sorted(first.files) == sorted(second.files)
        for name in first.files:
            assert np.array_equal(first[name], second[name]), name


@pytest.mark.parametrize("continuous", [False, True])
def test_streamed_fit_killed_between_passes_resumes_bit_for_bit(tmp_path: Path, continuous: bool):
    """Independent poses (each row its own direction), and a continuous recording whose static intervals' rows share
    one (their directions taken again, at the resumed pass's start, from the checkpoint's interval sums)."""
    session = tmp_path / "session.csv"
    if continuous:
        generator = torch.Generator().manual_seed(3)
        recording = simulate_stream(stream_sensor(8, 9.81, 0.01, 0.2, generator), 1.0, poses=12, rate=50.0, generator=generator)
        write_stream_csv(recording, session)
    else:
        write_session(session, known_loads=2)
    run = [
        "experiment=calibrate_stream", f"data.path={session}", "data.magnitude=9.81", "data.time_column=time",
        *([] if continuous else ["data.mirror_hint={row: 0, axis: fz, sign: 1}"]), "data.block_rows=50",
    ]
    # Killed after the moments, the metric constraint and two alternation rounds: the resumed fit keeps them.
    says = killed_then_resumed(tmp_path, run, "streamed_shape_from_motion", epoch=4).stdout
    assert "keeps the passes it finished and reads the one it was in again from its start" in says
    resumed = tmp_path / "resumed"
    whole = uninterrupted(tmp_path, run)
    assert_same_calibration(resumed, whole)
    assert json.loads((resumed / "metrics.json").read_text())["epochs"] == json.loads((whole / "metrics.json").read_text())["epochs"]
    assert json.loads((whole / "calibration.json").read_text())["tied_directions"] is continuous


def test_ctrl_c_names_the_checkpoint_to_resume_from(tmp_path: Path):
    """Ctrl-C: one line naming the newest checkpoint, exit 130 (resuming from it is the SIGKILL tests' business)."""
    stopped = sfmnet(tmp_path / "stopped", *CALIBRATION, *signal_at(3, "SIGINT"))
    last = tmp_path / "stopped" / "checkpoints" / "shape_from_motion" / "last.ckpt"
    assert stopped.returncode == 130
    assert "Traceback" not in stopped.stderr
    assert stopped.stderr.strip().splitlines() == [
        f"interrupted: ShapeFromMotion stopped in epoch 4: resume with ckpt_path={last} (and a new hydra.run.dir); "
        "the result is the uninterrupted run's"
    ]
    assert torch.load(last, weights_only=False)["epoch"] == 2
    assert not (tmp_path / "stopped" / "calibration.json").exists()


def test_ctrl_c_in_a_baseline_names_the_main_method_s_checkpoint(tmp_path: Path):
    """A hostile tester's: a Ctrl-C in the autoencoder baseline named its own checkpoint, which ckpt_path (the main
    method's) refused as "a checkpoint of another fit". The main method's resumes to the uninterrupted run."""
    run = [*EIGENSPACE, "experiment=mkv_compare"]
    stopped = sfmnet(tmp_path / "stopped", *run, *signal_at(2, "SIGINT"), "+callbacks.signal.model=LinearAutoencoder")
    last = tmp_path / "stopped" / "checkpoints" / "eigenspace" / "last.ckpt"
    assert stopped.returncode == 130 and stopped.stderr.strip().splitlines() == [
        f"interrupted: LinearAutoencoder stopped in epoch 3, a baseline: resume with ckpt_path={last} (and a new "
        "hydra.run.dir); the main method resumes at its end and the baselines are fitted again from their start"
    ]
    resumed = sfmnet(tmp_path / "resumed", *run, f"ckpt_path={last}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    whole = uninterrupted(tmp_path, run)
    figures = [
        {key: value for key, value in json.loads((folder / "metrics.json").read_text()).items() if not key.endswith("fit_seconds")}
        for folder in (tmp_path / "resumed", whole)
    ]
    assert figures[0] == figures[1] and "linear_autoencoder/drive_accuracy" in figures[0]


def test_resuming_under_other_settings_is_refused(tmp_path: Path):
    """A hostile tester's resume with another data.test_fraction, whose tensors had the same shapes, mixed the old split's
    standardisation with the new split's and exited 0. More epochs (a trainer setting) are still allowed."""
    run = [*CALIBRATION, "trainer.max_epochs=1"]
    first = sfmnet(tmp_path / "first", *run)
    assert first.returncode == 0, first.stderr[-2000:]
    last = tmp_path / "first" / "checkpoints" / "shape_from_motion" / "last.ckpt"
    other = sfmnet(tmp_path / "other", *run, "data.noise_fraction=0.02", f"ckpt_path={last}")
    assert other.returncode == 2 and other.stderr.strip().splitlines() == [
        f"error: ckpt_path {last} was written with data.noise_fraction=0.01, this run has 0.02: resume with the "
        "interrupted run's settings (its .hydra/config.yaml), or start afresh without ckpt_path"
    ]
    longer = sfmnet(tmp_path / "longer", *CALIBRATION, "trainer.max_epochs=2", f"ckpt_path={last}")
    assert longer.returncode == 0, longer.stderr[-2000:]


def test_missing_checkpoint_is_one_clear_error(tmp_path: Path):
    done = sfmnet(tmp_path / "run", *CALIBRATION, f"ckpt_path={tmp_path / 'nope.ckpt'}")
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


def test_streamed_fit_killed_after_leaving_out_a_glitch_resumes_bit_for_bit(tmp_path: Path):
    """Killed after the moments, the metric pass a glitch took over and the moments read again without it (method §2,
    "A glitch"): the resumed fit still knows which rows to leave out of the metric pass it reads next."""
    readings, _ = held_poses(0, glitch_spans=5.0, rows_per_pose=40)
    session = tmp_path / "session.csv"
    np.savetxt(session, readings.numpy(), delimiter=",", header=",".join(f"s{i}" for i in range(8)), comments="")
    run = [
        "experiment=calibrate_stream", f"data.path={session}", "data.magnitude=3.0", "data.load_columns=[]",
        "data.axes=[x,y,z]", "data.block_rows=50",
    ]
    killed_then_resumed(tmp_path, run, "streamed_shape_from_motion", epoch=3)
    resumed = tmp_path / "resumed"
    whole = uninterrupted(tmp_path, run)
    assert_same_calibration(resumed, whole)
    assert any(w.startswith("1 of 480 rows lie far outside") for w in json.loads((resumed / "calibration.json").read_text())["warnings"])


def test_a_ctrl_c_while_refitting_without_each_group_names_the_finished_fit_s_checkpoint(tmp_path: Path):
    """A new user's Ctrl-C in a leave-one-pose-out fold was told "stopped in epoch 5, before its first checkpoint: run
    it again from the start", with the finished fit's last.ckpt on disk and resuming from it working."""
    from unittest import mock

    from sfmnet.errors import FitInterrupted

    generator = torch.Generator().manual_seed(0)
    sensor = stream_sensor(6, 9.81, 0.002, 0.2, generator)
    write_stream_csv(simulate_stream(sensor, 1.0, poses=8, rate=50.0, generator=generator), tmp_path / "s.csv", pose_column=True)
    cfg = compose_config([
        "experiment=calibrate_csv", f"data.path={tmp_path / 's.csv'}", "data.magnitude=9.81", "data.time_column=time",
        "data.group_column=pose", "eval.leave_one_group_out=true",
    ])
    interrupted = mock.patch("sfmnet.tasks.calibration.leave_one_group_out", side_effect=FitInterrupted("a fold"))
    with interrupted, pytest.raises(FitInterrupted, match=r"^stopped while refitting without each group .* resume with "
                                    r"ckpt_path=.*run/checkpoints/shape_from_motion/last.ckpt"):
        train(cfg, tmp_path / "run")
    assert (tmp_path / "run" / "checkpoints" / "shape_from_motion" / "last.ckpt").is_file()
