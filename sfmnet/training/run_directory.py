"""A run's directory is its own: made new or taken empty, locked while the run lives, never written into twice.

The check runs on Hydra's parsed config (a Hydra callback, before Hydra writes its ``.hydra/``
files), so a quoted path, ``++hydra.run.dir=`` or a sweep run again into its ``hydra.sweep.dir``
are caught as surely as a plain ``hydra.run.dir=``. The lock is a file made with ``O_EXCL``:
of two runs started at once into one directory, exactly one gets it.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from sfmnet.errors import SfmnetError
from sfmnet.io import check_writable_dir, write_error

LOCK_NAME = ".sfmnet-lock"
# A sweep's job that failed says why here, in its own directory (the sweep goes on to its next job).
JOB_ERROR_FILE = "error.txt"
# What a run leaves before it has a result: Hydra's record of its config, its log, the lock, and the
# TensorBoard log the logger opens before the model refuses a setting.
RUN_SCAFFOLD = {".hydra", "train.log", "tensorboard", LOCK_NAME}
# The lock's second line when the claim made the directory (so only then is it removed with the scaffold).
CREATED = "created"


def claim_run_dir(path: Path, option: str) -> None:
    """Make ``path`` (or take it empty) and lock it for this process; refuse one that holds anything or is locked.

    Args:
        path: the run's (or sweep's) directory.
        option: the setting that named it, for the message (``hydra.run.dir``, ``run_dir``).
    """
    path = Path(path)
    if path.parts and path.parts[0].startswith("~"):
        # Hydra takes it literally: a folder named "~" here, which a later `rm -rf ~` would take for the home folder.
        raise SfmnetError(
            f"{option} {path} starts with '~', which Hydra does not expand (it would make a folder named '~' here): "
            f"give the full path, e.g. {option}={Path(path).expanduser()}"
        )
    check_writable_dir(path, option)
    created = not path.exists()
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise write_error(path, error) from None
    held = sorted(entry.name for entry in path.iterdir() if entry.name != LOCK_NAME)
    if held:
        shown = ", ".join(held[:3]) + (", ..." if len(held) > 3 else "")
        raise SfmnetError(
            f"{option} {path} already holds files ({shown}): give a new {option} so nothing of an earlier run is rewritten"
        )
    try:
        descriptor = os.open(path / LOCK_NAME, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
    except FileExistsError:
        raise SfmnetError(
            f"{option} {path} is in use by another run (it holds {LOCK_NAME}; remove that file if no run is using it): "
            f"give a new {option}"
        ) from None
    except OSError as error:
        raise write_error(path / LOCK_NAME, error) from None
    with os.fdopen(descriptor, "w") as lock:
        lock.write(f"{os.getpid()}\n" + (f"{CREATED}\n" if created else ""))


def release_run_dir(path: Path) -> None:
    (Path(path) / LOCK_NAME).unlink(missing_ok=True)


def discard_refused_run(path: Path) -> None:
    """Undo the claim of a run refused before it wrote a result, so the corrected command can use ``path`` again.

    Only the scaffold goes (:data:`RUN_SCAFFOLD`), and the directory itself only if the claim
    made it; a directory holding anything else (a checkpoint, a figure) is left as it is.
    """
    path = Path(path)
    lock = path / LOCK_NAME
    if not lock.is_file() or not {entry.name for entry in path.iterdir()} <= RUN_SCAFFOLD:
        return
    created = CREATED in lock.read_text().split()
    for entry in (path / name for name in RUN_SCAFFOLD):
        if entry.is_dir():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            entry.unlink(missing_ok=True)
    if created:
        path.rmdir()


def is_worker() -> bool:
    """A process a distributed fit started (it re-enters the directory its first process claimed)."""
    return os.environ.get("LOCAL_RANK", "0") != "0"


class RunDirectoryGuard(Callback):
    """Claims ``hydra.run.dir`` (a run) or ``hydra.sweep.dir`` (a sweep) before Hydra writes there; releases it at the end."""

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self.claim(config, "hydra.run.dir")

    def on_run_end(self, config: DictConfig, **kwargs: Any) -> None:
        if not is_worker():
            release_run_dir(Path(config.hydra.run.dir))

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self.claim(config, "hydra.sweep.dir")

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        release_run_dir(Path(config.hydra.sweep.dir))

    @staticmethod
    def claim(config: DictConfig, option: str) -> None:
        from sfmnet.cli import exit_on_user_error

        if not is_worker():
            exit_on_user_error(lambda: claim_run_dir(Path(config.hydra[option.split(".")[1]].dir), option))
