"""Valid inputs stay accepted by the checks at the boundary (sfmnet/config_values.py, sfmnet/config_check.py);
the refused ones are in tests/test_bad_inputs.py."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest
import torch

from sfmnet.calibration import Calibration
from sfmnet.cli import config_dir
from sfmnet.errors import SfmnetError
from sfmnet.config_check import check_overrides
from sfmnet.config_values import check_config
from sfmnet.io import check_writable_dir, write_text_atomic
from sfmnet.readers.table_file import read_table
from sfmnet.training.run import MAX_THREADS, THREADED_ROWS, thread_count, train
from tests.conftest import EXPERIMENTS, compose_config, write_session

# What each experiment that reads the user's file needs to compose (the files are not opened by the checks).
FILE_SETTINGS = {
    "calibrate_csv": ["data.path=/data/session.csv", "data.magnitude=9.81"],
    "calibrate_stream": ["data.path=/data/session.csv", "data.magnitude=9.81"],
    "pca": ["data.path=/data/rows.npy", "model.rank=2"],
    "sensorimotor_csv": ["data.path=/data/log.csv", "data.sensor_columns=[a,b]", "data.command_columns=[drive]"],
}


@pytest.mark.parametrize("experiment", EXPERIMENTS)
def test_every_experiment_passes_the_checks(experiment: str):
    check_config(compose_config([f"experiment={experiment}", *FILE_SETTINGS.get(experiment, [])]))


@pytest.mark.parametrize(
    "overrides",
    [
        ["data.magnitude=100"],  # a whole number where a number is declared
        ["seed=4294967295", "threads=2", "trainer.max_epochs=1"],
        ["model.metric_weight=1e-9", "model.rank=2", "ckpt_path=null", "threads=auto"],
        ["experiment=calibrate_csv", "data.path=/data/s.csv", "data.mass=1", "data.mirror_hint={row:3,axis:fz,sign:-1}"],
        ["experiment=calibrate_csv", "data.path=/data/s.csv", "data.load_columns=[fx,fy,fz,mx,my,mz]",
         "data.configuration_column=config", "data.configurations={1:{mass:1,centre_of_mass:[0,0,0.1]}}"],
        ["experiment=ft6dof", "data.configurations.0.mass=2"],
        ["data.errors={friction:0.01}", "data.orientation_law=poses", "data.samples=12", "data.poses=12"],
    ],
)
def test_values_of_the_right_kind_pass(overrides: list[str]):
    check_config(compose_config(overrides))
    check_overrides(overrides, config_dir())


@pytest.mark.parametrize(
    "overrides",
    [
        ["experiment=choice(fingertip,lord3dof)", "data.samples=range(48,97,48)"],
        ["experiment=glob(finger*)", "seed=0,1"],
        ["experiment=fingertip,lord3dof", "model.metric_weight=choice(10,1000)"],
    ],
)
def test_sweep_syntax_passes_with_m(overrides: list[str]):
    check_overrides(overrides, config_dir(), sweep=True)


def test_removing_a_key_the_config_lacks_is_one_line():
    """`~baselines.regression` was Hydra's raw error with exit 1 (a hostile tester's, after the README's example)."""
    with pytest.raises(SfmnetError, match=r"^~baselines.regression removes nothing: the config has no baselines.regression "
                       r"\(baselines holds linear_autoencoder, least_squares\)$"):
        check_overrides(["experiment=wall_following", "~baselines.regression"], config_dir())
    assert check_overrides(["experiment=wall_following", "~baselines.least_squares"], config_dir())[1] == "~baselines.least_squares"


def test_a_key_every_swept_experiment_has_but_the_default_lacks_is_forced_for_hydra():
    """Hydra composes a sweep's own config from the default experiment (fingertip, no eval.closed_loop) before any
    job's, and refused `-m experiment=mkv_pca,mkv_compare eval.closed_loop=null` though every job has the key."""
    given = ["experiment=mkv_pca,mkv_compare", "eval.closed_loop=null", "seed=0"]
    assert check_overrides(given, config_dir(), sweep=True) == [given[0], "++eval.closed_loop=null", "seed=0"]
    assert check_overrides(["experiment=mkv_pca", "eval.closed_loop=null"], config_dir()) == ["experiment=mkv_pca", "eval.closed_loop=null"]


def test_a_path_with_unusual_letters_runs_when_quoted(tmp_path: Path):
    """Non-ASCII letters, '=' and brackets: Hydra takes them quoted, as the refusal of the unquoted form says."""
    session = tmp_path / "séance=[1].csv"
    write_session(session)
    overrides = ["experiment=calibrate_csv", f'data.path="{session}"', "data.magnitude=9.81", "trainer.max_epochs=2"]
    check_overrides([*overrides, f"hydra.run.dir={tmp_path / 'run'}"], config_dir())
    train(compose_config(overrides), tmp_path / "run")
    assert json.loads((tmp_path / "run" / "calibration.json").read_text())["axes"] == ["fx", "fy", "fz"]


def test_a_new_nested_run_directory_passes_and_nothing_is_made(tmp_path: Path):
    check_writable_dir(tmp_path / "a" / "b" / "run", "hydra.run.dir")
    assert list(tmp_path.iterdir()) == []


def test_npz_columns_as_arrays_of_one_column_and_bools_are_read(tmp_path: Path):
    np.savez(tmp_path / "s.npz", s0=np.arange(4.0)[:, None], flag=np.array([True, False, True, True]))
    table = read_table(tmp_path / "s.npz")
    assert table.columns["s0"].tolist() == [0.0, 1.0, 2.0, 3.0] and table.columns["flag"].tolist() == [1.0, 0.0, 1.0, 1.0]


def test_a_calibration_without_its_optional_figures_loads(tmp_path: Path):
    """NaN is refused in matrix and offset only: a residual or error bar that could not be computed may be NaN."""
    calibration = Calibration(torch.eye(2), torch.zeros(2), ["s0", "s1"], ["fx", "fy"], matrix_std=torch.full((2, 2), float("nan")))
    calibration.save(tmp_path / "calibration.json")
    loaded = Calibration.load(tmp_path / "calibration.json")
    assert loaded.matrix.tolist() == [[1.0, 0.0], [0.0, 1.0]] and torch.isnan(loaded.matrix_std).all()


def test_auto_threads_follow_the_rows():
    cores = min(len(os.sched_getaffinity(0)), MAX_THREADS)
    assert [thread_count("auto", rows) for rows in (0, THREADED_ROWS - 1, THREADED_ROWS)] == [1, 1, cores]
    assert thread_count(3, 10) == 3


def test_written_outputs_get_the_mode_of_any_new_file(tmp_path: Path):
    # The atomic write goes through a private temporary file; the output must not stay private (0600).
    previous = os.umask(0o027)
    try:
        write_text_atomic(tmp_path / "calibration.json", "{}")
        (tmp_path / "plain.txt").write_text("{}")
    finally:
        os.umask(previous)
    mode = stat.S_IMODE((tmp_path / "calibration.json").stat().st_mode)
    assert mode == stat.S_IMODE((tmp_path / "plain.txt").stat().st_mode) == 0o640
