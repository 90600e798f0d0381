"""A run's directory is claimed on Hydra's parsed config: however it is named, an earlier run's files are never rewritten."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import pytest

from sfmnet.errors import SfmnetError
from sfmnet.training.run_directory import LOCK_NAME, claim_run_dir, discard_refused_run, release_run_dir
from tests.conftest import REPO

FAST = ["trainer.enable_progress_bar=false", "trainer.max_epochs=1", "~logger"]


def command(*args: str) -> list[str]:
    return [sys.executable, "-m", "sfmnet", "train", *FAST, *args]


def sfmnet(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(command(*args), cwd=REPO, capture_output=True, text=True, timeout=300)


def snapshot(folder: Path) -> dict[str, tuple[int, str]]:
    """Every file under ``folder``: its modification time and the hash of its bytes."""
    return {
        str(path.relative_to(folder)): (path.stat().st_mtime_ns, hashlib.sha256(path.read_bytes()).hexdigest())
        for path in sorted(folder.rglob("*")) if path.is_file()
    }


@pytest.fixture(scope="module")
def earlier_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    run_dir = tmp_path_factory.mktemp("runs") / "earlier"
    done = sfmnet(f"hydra.run.dir={run_dir}")
    assert done.returncode == 0, done.stderr[-2000:]
    assert not (run_dir / LOCK_NAME).exists(), "the lock outlived its run"
    return run_dir


@pytest.mark.parametrize("spelling", ["hydra.run.dir={}", "hydra.run.dir='{}'", '++hydra.run.dir="{}"'])
def test_an_earlier_run_is_never_rewritten(earlier_run: Path, spelling: str):
    before = snapshot(earlier_run)
    again = sfmnet(spelling.format(earlier_run))
    assert again.returncode == 2
    assert again.stderr.strip().splitlines() == [
        f"error: hydra.run.dir {earlier_run} already holds files (.hydra, calibration.json, checkpoints, ...): "
        "give a new hydra.run.dir so nothing of an earlier run is rewritten"
    ]
    assert snapshot(earlier_run) == before


def test_a_sweep_run_again_into_its_directory_is_refused(tmp_path: Path):
    """An earlier sweep's record (its multirun.yaml and a job folder) stands for the sweep: refused before Hydra writes."""
    sweep_dir = tmp_path / "sweep"
    (sweep_dir / "0").mkdir(parents=True)
    (sweep_dir / "multirun.yaml").write_text("hydra: {}\n")
    before = snapshot(sweep_dir)
    again = sfmnet("-m", f"hydra.sweep.dir={sweep_dir}", "seed=0,1")
    assert again.returncode == 2
    assert "error: hydra.sweep.dir" in again.stderr and "already holds files (0, multirun.yaml)" in again.stderr
    assert snapshot(sweep_dir) == before


def test_two_runs_started_at_once_into_one_directory(tmp_path: Path):
    run_dir = tmp_path / "shared"
    processes = [
        subprocess.Popen(command(f"hydra.run.dir={run_dir}", f"seed={seed}"), cwd=REPO, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True)
        for seed in (0, 1)
    ]
    results = [(process.wait(timeout=300), process.stderr.read()) for process in processes]
    assert sorted(code for code, _ in results) == [0, 2], results
    refused = next(stderr for code, stderr in results if code == 2)
    assert "is in use by another run" in refused or "already holds files" in refused
    assert (run_dir / "calibration.json").is_file() and not (run_dir / LOCK_NAME).exists()


def test_the_lock_is_exclusive(tmp_path: Path):
    claim_run_dir(tmp_path / "run", "run_dir")
    with pytest.raises(SfmnetError, match=r"is in use by another run .*: give a new run_dir"):
        claim_run_dir(tmp_path / "run", "run_dir")
    release_run_dir(tmp_path / "run")
    claim_run_dir(tmp_path / "run", "run_dir")


def test_a_refused_run_gives_its_directory_back(tmp_path: Path):
    """Refused before any result: the scaffold (.hydra, train.log, tensorboard, lock) goes, so the corrected command can use the
    directory; a folder the user made stays, empty."""
    refused = sfmnet("experiment=calibrate_csv", f"data.path={tmp_path / 'missing.csv'}", f"hydra.run.dir={tmp_path / 'new'}")
    assert refused.returncode == 2 and "does not exist" in refused.stderr
    assert not (tmp_path / "new").exists()
    # Refused by the model, after the logger (which FAST leaves out) has opened its TensorBoard log.
    late = [sys.executable, "-m", "sfmnet", "train", "model.refinement=marginal", "model.marginal_grid=10", f"hydra.run.dir={tmp_path / 'late'}"]
    refused = subprocess.run(late, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert refused.returncode == 2 and "model.marginal_grid=10" in refused.stderr
    assert not (tmp_path / "late").exists()
    made_by_user = tmp_path / "mine"
    made_by_user.mkdir()
    claim_run_dir(made_by_user, "hydra.run.dir")
    (made_by_user / ".hydra").mkdir()
    (made_by_user / "train.log").write_text("")
    discard_refused_run(made_by_user)
    assert made_by_user.is_dir() and not any(made_by_user.iterdir())


def test_a_run_directory_starting_with_a_tilde_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    """Hydra does not expand '~': the run made a folder named '~' in the current one (a hostile tester's), which a
    later `rm -rf ~` would take for the home folder."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SfmnetError, match=r"hydra.run.dir ~/runs/a starts with '~', which Hydra does not expand"):
        claim_run_dir(Path("~/runs/a"), "hydra.run.dir")
    assert not (tmp_path / "~").exists()
