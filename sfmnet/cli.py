"""Command line: ``python -m sfmnet [train] [key=value ...] [-m]``.

Hydra parses all of ``sys.argv``, so the command word is taken off first. ``train`` is the
default command because Lightning's DDP launcher restarts worker processes as
``python -m sfmnet <overrides>`` without it (method §12).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TypeVar

from sfmnet.errors import FitInterrupted, SfmnetError

T = TypeVar("T")

USAGE = """\
usage: python -m sfmnet [train] [key=value ...] [-m]
       python -m sfmnet apply calibration=<json> input=<csv> output=<csv> [overwrite=true]

commands:
  train    fit an experiment and write its run directory (the default command)
           python -m sfmnet train                        experiment=fingertip, the default
           python -m sfmnet train experiment=table1      least squares vs shape from motion
           python -m sfmnet train -m data.noise_fraction=0.005,0.01,0.02   a sweep
           python -m sfmnet train --help                 every config group and key
  apply    turn a CSV of raw readings into loads with a run's calibration.json; the input's
           columns are kept and the loads added (an existing output needs overwrite=true)

errors print one line and exit with status 2; set SFMNET_DEBUG=1 for the full traceback.
"""


MULTIRUN_FLAGS = ("-m", "--multirun")


def config_dir() -> str:
    """The configs: ``conf/`` of a checkout, else the copy a wheel installs as ``sfmnet/conf``."""
    package = Path(__file__).resolve().parent
    checkout = package.parent / "conf"
    return str(checkout if (checkout / "train.yaml").is_file() else package / "conf")


def debug_enabled() -> bool:
    return any(os.environ.get(name, "") not in ("", "0") for name in ("SFMNET_DEBUG", "HYDRA_FULL_ERROR"))


def user_error(error: BaseException) -> SfmnetError | None:
    """The :class:`SfmnetError` behind ``error``, if any (Hydra wraps errors raised while instantiating)."""
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        if isinstance(current, SfmnetError):
            return current
        seen.add(id(current))
        current = current.__cause__ or current.__context__
    return None


@contextlib.contextmanager
def unwrapped_user_errors() -> Iterator[None]:
    """Raise the :class:`SfmnetError` itself where Hydra wrapped it (while building a data module or model)."""
    try:
        yield
    except Exception as error:
        cause = user_error(error)
        if cause is None or cause is error:
            raise
        raise cause from None


def exit_on_user_error(
    action: Callable[[], T], refused: Callable[[], None] | None = None, run_dir: Path | None = None
) -> T:
    """Run ``action``; a user error becomes one line on stderr and exit status 2 (an interrupted fit: 130).

    ``refused``: run after a user error other than an interruption (e.g. undo the run directory's claim).
    ``run_dir``: where a Ctrl-C outside the fit (while results are written) finds the checkpoints to name.
    """
    try:
        return action()
    except KeyboardInterrupt:
        if debug_enabled():
            raise
        print(f"interrupted: {interrupted_outside_fit(run_dir)}", file=sys.stderr)
        sys.exit(FitInterrupted.exit_status)
    except Exception as error:
        cause = user_error(error)
        if cause is None or debug_enabled():
            raise
        interrupted = isinstance(cause, FitInterrupted)
        if refused is not None and not interrupted:
            refused()
        print(f"{'interrupted' if interrupted else 'error'}: {cause}", file=sys.stderr)
        sys.exit(cause.exit_status if interrupted else 2)


def interrupted_outside_fit(run_dir: Path | None) -> str:
    """What a Ctrl-C outside a fit (reading the data, writing the results) left, and how to go on."""
    checkpoints = sorted(run_dir.glob("checkpoints/*/last.ckpt")) if run_dir is not None else []
    if not checkpoints:
        return "stopped before any fit finished an epoch: run the command again"
    resume = checkpoints[0] if len(checkpoints) == 1 else run_dir / "checkpoints" / "<method>" / "last.ckpt"
    return (
        f"stopped after a fit, while its results were written: {run_dir} may hold only part of them; resume with "
        f"ckpt_path={resume} (and a new hydra.run.dir) to write them whole"
    )


# The sweep's jobs that failed, by job number: the sweep goes on, and exits with status 2 at the end.
FAILED_JOBS: list[str] = []
# The sweep's directory, once its first job has started (for a Ctrl-C between jobs).
SWEEP_DIRS: list[Path] = []


def stop_on_interrupt(hydra_task: Callable[[], None]) -> None:
    """Run Hydra's ``hydra_task``; a Ctrl-C (or SIGTERM) outside every job, between a sweep's jobs or before the first,
    is one line and exit status 130 (it was a traceback of Hydra's launcher, a hostile tester's)."""
    try:
        hydra_task()
    except KeyboardInterrupt:
        if debug_enabled():
            raise
        from sfmnet.training.run_directory import release_run_dir

        if SWEEP_DIRS:
            release_run_dir(SWEEP_DIRS[-1])
            where = f"between a sweep's jobs: the finished jobs are in {SWEEP_DIRS[-1]}"
        else:
            where = "before a run started"
        print(f"interrupted: stopped {where}; run the command again for the rest", file=sys.stderr)
        sys.exit(FitInterrupted.exit_status)


def terminate_as_interrupt(signum: int, frame: object) -> None:
    """SIGTERM (a scheduler's, ``kill``) stops a run as Ctrl-C does: one line, the claim released, exit status 130
    (outside a fit it ended the process silently, status -15)."""
    raise KeyboardInterrupt


def run_sweep_job(action: Callable[[], object], job_dir: Path) -> None:
    """Run one job of a sweep (``-m``): a failure is one line on stderr and the job's ``error.txt``, and the sweep goes
    on to its next job (Hydra would stop it, leaving the finished jobs unsummarised); a Ctrl-C stops the sweep
    (:func:`exit_on_user_error`)."""
    from sfmnet.training.run_directory import JOB_ERROR_FILE

    def job() -> None:
        try:
            action()
        except Exception as error:
            cause = user_error(error)
            if debug_enabled() or isinstance(cause, FitInterrupted):
                raise
            if cause is not None:
                message, detail = str(cause), ""
            else:
                message = (
                    f"{type(error).__name__}: {error} (a fault in sfmnet, not in your input; the traceback is in "
                    f"{job_dir / JOB_ERROR_FILE})"
                ).replace("\n", " ")
                detail = "".join(traceback.format_exception(error))
            (job_dir / JOB_ERROR_FILE).write_text(f"{message}\n{detail}")
            print(f"error in job {job_dir.name}: {message}", file=sys.stderr)
            FAILED_JOBS.append(job_dir.name)

    exit_on_user_error(job, run_dir=job_dir)


def shared_sweep_dir(overrides: list[str]) -> list[str]:
    """A sweep over experiments without its own ``hydra.sweep.dir``: one directory named after them all.

    Each job resolves the default ``runs/multirun/${experiment_name}/...`` from its own experiment, so the jobs of a
    sweep over two experiments landed in two directories and the sweep's summary held only the first's (a hostile
    tester's, exit 0).
    """
    if any(o.lstrip("+").startswith("hydra.sweep.dir=") for o in overrides):
        return []
    swept = [o.split("=", 1)[1] for o in overrides if o.startswith("experiment=") and ("," in o or "(" in o)]
    if not swept:
        return []
    names = swept[0].split(",") if "(" not in swept[0] else ["experiments"]
    return [f"hydra.sweep.dir=runs/multirun/{'+'.join(name.strip() for name in names)}/${{now:%Y-%m-%d_%H-%M-%S-%f}}"]


def check_train_arguments(args: list[str]) -> list[str]:
    """Typos and bad values, caught before Hydra starts (a DDP worker re-enters checked); the run directory is claimed
    on Hydra's parsed config (:mod:`sfmnet.training.run_directory`). Returns the overrides for Hydra (a sweep's keys
    that only its swept configs define, forced: :func:`~sfmnet.config_check.check_overrides`)."""
    if os.environ.get("LOCAL_RANK", "0") != "0" or "--help" in args or "-h" in args:
        return args
    refuse_bare_words(args)
    from sfmnet.config_check import check_overrides

    sweep = any(flag in args for flag in MULTIRUN_FLAGS)
    overrides = check_overrides([a for a in args if a not in MULTIRUN_FLAGS], config_dir(), sweep=sweep)
    return [*overrides, *(shared_sweep_dir(overrides) if sweep else []), *(a for a in args if a in MULTIRUN_FLAGS)]


def train_command() -> None:
    import hydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode
    from omegaconf import DictConfig

    from sfmnet.training.run import train

    from sfmnet.training.run_directory import discard_refused_run, is_worker, release_run_dir

    @hydra.main(version_base="1.3", config_path=config_dir(), config_name="train")
    def task(cfg: DictConfig) -> None:
        # Python's warnings too go to the console and train.log through Hydra's job logging (sfmnet/console.py).
        logging.captureWarnings(True)
        run_dir = Path(HydraConfig.get().runtime.output_dir)
        if HydraConfig.get().mode == RunMode.RUN:
            try:
                # A refused single run gives its directory back.
                exit_on_user_error(lambda: train(cfg, run_dir), lambda: discard_refused_run(run_dir), run_dir)
            finally:
                # An interrupted one keeps what it wrote, but not its claim: the directory is free for the next run.
                if not is_worker():
                    release_run_dir(run_dir)
        else:
            SWEEP_DIRS.append(Path(HydraConfig.get().sweep.dir))
            try:
                # A sweep's job keeps its directory beside the others, with its error.
                run_sweep_job(lambda: train(cfg, run_dir), run_dir)
            except SystemExit:
                # Interrupted: the sweep ends here, without Hydra's end of sweep, which would release its claim.
                release_run_dir(Path(HydraConfig.get().sweep.dir))
                raise

    stop_on_interrupt(task)
    if FAILED_JOBS:
        sys.exit(2)


def apply_command() -> None:
    from sfmnet.apply import apply_command as run_apply

    exit_on_user_error(lambda: run_apply(sys.argv[1:]))


COMMANDS: dict[str, Callable[[], None]] = {"train": train_command, "apply": apply_command}


# Characters that make a value a list, a sweep, a function call or already quoted: those are Hydra's to read.
HYDRA_SYNTAX = set("'\"[]{}(),")


def quote_plain_value(override: str) -> str:
    """``key=value`` with ``value`` in double quotes when Hydra's grammar cannot take it bare (non-ASCII letters,
    ``=``) and it holds nothing of Hydra's own syntax, e.g. ``data.path=/data/Messung_Größe.csv``; in a plain
    list each such element, e.g. ``data.load_columns=[Fₓ,Fᵧ,F_z]``."""
    key, equals, value = override.partition("=")
    if not equals or not value or key.startswith("-") or "\\" in value:
        return override
    if value.startswith("[") and value.endswith("]") and not HYDRA_SYNTAX & set(value[1:-1]) - {","}:
        return f"{key}=[{','.join(quoted_element(element) for element in value[1:-1].split(','))}]"
    if HYDRA_SYNTAX & set(value):
        return override
    return f"{key}={quoted_element(value)}"


def quoted_element(value: str) -> str:
    """``value`` in double quotes if Hydra's grammar cannot take it bare (non-ASCII letters, ``=``)."""
    return value if value.isascii() and "=" not in value else f'"{value}"'


def refuse_bare_words(args: list[str]) -> None:
    """A word that is no ``key=value``, ``+key=value`` or ``~key`` (Hydra would answer with its usage and exit 1)."""
    if any(arg.startswith("-") and arg not in MULTIRUN_FLAGS for arg in args):
        return  # Hydra's own flags (--cfg job, --info, ...) take bare words as their values
    for before, arg in zip([None, *args], args):
        if arg not in MULTIRUN_FLAGS and "=" not in arg and not arg.startswith("~"):
            if before is not None and "=" in before:
                # The shell splits an unquoted value at its spaces: `data.path=my session.csv` arrives as two words.
                raise SfmnetError(
                    f"'{arg}' is not a setting; it follows {before}: a value holding spaces must be quoted whole, "
                    f"e.g. '{before} {arg}'"
                )
            raise SfmnetError(f"'{arg}' is not a setting: write key=value, e.g. experiment={arg} (python -m sfmnet train --help)")


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if args and args[0] in ("-h", "--help", "help"):
        print(USAGE, end="")
        return
    command = "train"
    if args and not args[0].startswith(("-", "+", "~")) and "=" not in args[0]:
        command = args.pop(0)
        if command not in COMMANDS:
            print(f"error: unknown command '{command}': use one of {', '.join(COMMANDS)} (python -m sfmnet --help)", file=sys.stderr)
            sys.exit(2)
    if os.environ.get("LOCAL_RANK", "0") == "0":
        signal.signal(signal.SIGTERM, terminate_as_interrupt)
    if command == "train":
        args = [quote_plain_value(arg) for arg in args]
        args = exit_on_user_error(lambda: check_train_arguments(args))
    if command == "train" and any(flag in args for flag in MULTIRUN_FLAGS):
        # Hydra's parser takes -m only before or after all the overrides, not among them.
        args = ["-m", *(a for a in args if a not in MULTIRUN_FLAGS)]
    sys.argv = [sys.argv[0], *args]
    COMMANDS[command]()
