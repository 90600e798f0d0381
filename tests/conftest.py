"""Shared helpers: compose the real configs the way the CLI does."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from sfmnet.cli import config_dir
from sfmnet.simulators.mkv_robot import MkvDataModule
from sfmnet.simulators.simulated_sensor import ForceSensor3DataModule

REPO = Path(__file__).resolve().parent.parent
EXPERIMENTS = sorted(p.stem for p in (REPO / "conf" / "experiment").glob("*.yaml"))
# A sphere grid a little over the least the marginal allows (model.marginal_grid), for tests of what does not depend on
# it: the held-out law's EM steps on the default 2000 directions take most of a marginal fit's time (about 3x as long).
SMALL_SPHERE_GRID = 1100
# The real recordings (README, "Real data"), as conf/paths/default.yaml finds them from the checkout.
DATA_DIR = Path(os.environ.get("SFMNET_DATA_DIR", REPO.parent / "shared" / "data")).resolve()
# Experiments that read the real recordings.
REAL_DATA_EXPERIMENTS = {
    "ft_printed_sensor": "ft_printed_sensor",
    "ft_printed_sensor_6dof": "ft_printed_sensor",
    "imu_accelerometer": "imu_xsens",
    "wall_following": "wall_following",
}


def real_data(relative: str) -> Path:
    """``DATA_DIR / relative``; absent, the test is skipped, except under ``CI=true`` where that is a failure."""
    path = DATA_DIR / relative
    if not path.exists():
        if os.environ.get("CI") == "true":
            pytest.fail(f"{path} is missing: CI runs with the real recordings at ../shared/data or SFMNET_DATA_DIR")
        pytest.skip(f"real data not found at {path} (set SFMNET_DATA_DIR)")
    return path


def compose_config(overrides: list[str] | None = None) -> DictConfig:
    """The config the CLI would build from ``overrides`` (progress bars off, to keep test logs readable).

    The real recordings are looked up where the tests find them, whatever the working directory.
    """
    defaults = ["trainer.enable_progress_bar=false", f"paths.data_dir={DATA_DIR}"]
    with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
        return compose(config_name="train", overrides=[*defaults, *(overrides or [])])


@pytest.fixture(autouse=True)
def one_torch_thread() -> None:
    """One torch thread per test, as a run of small data sets for itself (config key ``threads``): xdist runs a process
    per core, and torch's pool on top of that makes these fits' small operations wait on each other (the held-out law's
    sphere test beside another busy core: 43 s with torch's default two threads, 31 s with one)."""
    torch.set_num_threads(1)


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    path = tmp_path / "run"
    path.mkdir()
    return path


def write_session(path: Path, known_loads: int = 3, seed: int = 0, edit=None, noise_fraction: float = 0.01) -> torch.Tensor:
    """A simulated 3-axis session as a CSV (time, s0..s5, fx, fy, fz); returns the true matrix."""
    datamodule = ForceSensor3DataModule(
        magnitude=9.81, offset_scale=0.2, known_loads=known_loads, mirror_hint=False, seed=seed,
        noise_fraction=noise_fraction,
    )
    datamodule.setup()
    recording = datamodule.data.recordings["rotation"]
    rows = [["time", *(f"s{i}" for i in range(6)), "fx", "fy", "fz"]]
    for i, (z, f) in enumerate(zip(recording.readings.tolist(), recording.loads.tolist())):
        rows.append([f"{0.01 * i:.2f}", *(f"{v:.9f}" for v in z), *("" if math.isnan(v) else f"{v:.6f}" for v in f)])
    if edit:
        edit(rows)
    with path.open("w", newline="") as stream:
        csv.writer(stream).writerows(rows)
    return datamodule.data.truth.matrix


def lightning_checkpoint(path: Path) -> Path:
    """A file shaped like a Lightning checkpoint, with nothing in it to restore: passes the check of ckpt_path."""
    torch.save({"state_dict": {}, "epoch": 0, "pytorch-lightning_version": "2"}, path)
    return path


def experiment_overrides(experiment: str, tmp_path: Path) -> list[str]:
    """What an experiment that reads the user's file needs: a simulated session written to disk.

    An experiment on the real recordings is skipped where they are absent (not under ``CI=true``).
    """
    if experiment in REAL_DATA_EXPERIMENTS:
        real_data(REAL_DATA_EXPERIMENTS[experiment])
    if experiment in ("calibrate_csv", "calibrate_stream"):
        write_session(tmp_path / "session.csv")
        return [f"data.path={tmp_path / 'session.csv'}", "data.magnitude=9.81", "data.time_column=time"]
    if experiment == "pca":
        generator = np.random.default_rng(0)
        np.save(tmp_path / "rows.npy", generator.normal(size=(5000, 6)) @ generator.normal(size=(6, 6)))
        return [f"data.path={tmp_path / 'rows.npy'}", "model.rank=2"]
    if experiment == "sensorimotor_csv":
        # The MK-V's own sensors and commands, written out as a log with text command labels.
        data = MkvDataModule(train_rooms=2, test_rooms=1, episodes_per_room=2, steps=1000).build()
        names = ["back", "off", "ahead"]
        with (tmp_path / "log.csv").open("w", newline="") as stream:
            writer = csv.writer(stream)
            writer.writerow([*data.sensors, "drive", "steer"])
            for episode in data.train:
                for sensors, commands in zip(episode.sensors.tolist(), episode.commands.tolist()):
                    writer.writerow([*sensors, *(names[c] for c in commands)])
        return [
            f"data.path={tmp_path / 'log.csv'}",
            # Rear bumps are rare (0.2 % of steps): a short log may never see one.
            f"data.sensor_columns=[{','.join(name for name in data.sensors if name != 'bump_rear')}]",
            "data.command_columns=[drive,steer]",
        ]
    return []
