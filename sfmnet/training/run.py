"""The one run loop: build the data and the task's models from the config, fit each through one Trainer, report.

Every kind of run (``task``: calibration, sensorimotor learning, PCA of a file; by default the
kind its data module declares) goes through :func:`train`. The task (:mod:`sfmnet.tasks`) owns
what is evaluated, written and printed; the logger and callbacks come from the ``logger/`` and
``callbacks/`` config groups (:mod:`sfmnet.training.components`). Each task's module lists the
files its run directory holds.
"""

from __future__ import annotations

import functools
import logging
import os
import shlex
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import lightning as L
import torch
from hydra.utils import instantiate
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig

from sfmnet.cli import unwrapped_user_errors
from sfmnet.config_values import check_config
from sfmnet.errors import FitInterrupted, SfmnetError
from sfmnet.io import check_writable_dir, write_json_atomic
from sfmnet.models.contracts import Learner
from sfmnet.tasks.base import FittedMethod, MethodResult, Task
from sfmnet.tasks.calibration import CalibrationTask
from sfmnet.tasks.pca import PcaTask
from sfmnet.tasks.sensorimotor import SensorimotorTask
from sfmnet.training.components import build_callbacks, build_logger
from sfmnet.training.fitting import fit
from sfmnet.training.tensorboard_summary import log_final_figures, log_settings, run_settings

RESULT_FILES = ("metrics.json", "calibration.json", "learner.npz", "pca.npz")
TASKS: dict[str, type[Task]] = {task.kind: task for task in (CalibrationTask, SensorimotorTask, PcaTask)}
Metrics = dict[str, float]
log = logging.getLogger(__name__)


def quiet_lightning() -> None:
    """Keep the console to the progress bar and our summary; Lightning's notices go to the log file."""
    for name in ("lightning.pytorch.utilities.rank_zero", "lightning.pytorch.accelerators.cuda", "lightning.fabric"):
        logging.getLogger(name).setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message=".*does not have many workers.*")
    warnings.filterwarnings("ignore", message=".*The number of training batches.*")
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")
    warnings.filterwarnings("ignore", message=".*this fit will run with no optimizer.*")
    # A resume writes to a new run directory, as the resume hint says: its best-score bookkeeping is not needed.
    warnings.filterwarnings("ignore", message=".*The dirpath has changed from.*")


def refuse_existing_results(run_dir: Path) -> None:
    existing = [name for name in RESULT_FILES if (run_dir / name).exists()]
    if existing:
        raise SfmnetError(
            f"{run_dir} already holds a run ({', '.join(existing)}): give a new hydra.run.dir so nothing is overwritten"
        )


# From this many rows on, operations are large enough for torch's thread pool to pay off.
THREADED_ROWS = 100_000
MAX_THREADS = 8


def thread_count(setting: int | str, rows: int) -> int:
    """torch's threads for a fit of ``rows`` rows: ``setting``, or for ``auto`` one below :data:`THREADED_ROWS`, else
    every core this process may use (at most :data:`MAX_THREADS`)."""
    if setting != "auto":
        return int(setting)
    return 1 if rows < THREADED_ROWS else min(len(os.sched_getaffinity(0)), MAX_THREADS)


def build_task(cfg: DictConfig, datamodule: L.LightningDataModule) -> Task:
    """``cfg.task``, else the kind the data module declares; a task that does not fit the data is refused."""
    declared = datamodule.task
    kind = cfg.get("task") or declared
    if kind not in TASKS:
        raise SfmnetError(f"task={kind} is not a task: use one of {', '.join(TASKS)} (or leave it unset)")
    if kind != declared:
        raise SfmnetError(f"task={kind} does not fit data for a {declared} run ({type(datamodule).__name__}): drop task=")
    return TASKS[kind](cfg)


def unwrapping_user_errors(run: Callable[..., Metrics]) -> Callable[..., Metrics]:
    """``run``, raising the :class:`SfmnetError` itself where Hydra wrapped it while building a data module or model."""

    @functools.wraps(run)
    def wrapper(*args, **kwargs) -> Metrics:
        with unwrapped_user_errors():
            return run(*args, **kwargs)

    return wrapper


@unwrapping_user_errors
def train(cfg: DictConfig, run_dir: Path, datamodule: L.LightningDataModule | None = None) -> Metrics:
    """Run the configured experiment into ``run_dir``; return the flat metrics also written to ``metrics.json``.

    ``datamodule``: built by the caller (the Python API's arrays) instead of from ``cfg.data``.
    """
    run_dir = Path(run_dir)
    refuse_existing_results(run_dir)
    check_writable_dir(run_dir, "run directory")
    check_config(cfg)
    quiet_lightning()
    L.seed_everything(cfg.seed, workers=True, verbose=False)
    torch.set_num_threads(thread_count(cfg.threads, rows=0))  # reading or simulating: small operations
    if datamodule is None:
        datamodule = instantiate(cfg.data)
    datamodule.setup("fit")
    torch.set_num_threads(thread_count(cfg.threads, datamodule.rows))
    task = build_task(cfg, datamodule)
    data = datamodule.data
    results: dict[str, MethodResult] = {}
    fits: dict[str, FittedMethod] = {}
    for position, (name, model) in enumerate(task.models().items()):
        # Resuming (ckpt_path) applies to the main method; baselines refit, as deterministically.
        ckpt_path = cfg.get("ckpt_path") if position == 0 else None
        settings = run_settings(cfg, name, cfg.model if position == 0 else cfg.baselines[name])
        try:
            fits[name] = fit_method(name, model, cfg, datamodule, run_dir, task, ckpt_path, settings)
        except FitInterrupted as interrupted:
            if position == 0:
                raise
            # A baseline's own checkpoint cannot be resumed: ckpt_path resumes the main method (a hostile tester's).
            main_checkpoint = run_dir / "checkpoints" / next(iter(fits)) / "last.ckpt"
            if not main_checkpoint.is_file():
                raise
            raise FitInterrupted(
                f"{interrupted.stopped or name}, a baseline: resume with ckpt_path={main_checkpoint} (and a new "
                "hydra.run.dir); the main method resumes at its end and the baselines are fitted again from their start",
                interrupted.stopped,
            ) from None
        results[name] = task.evaluate(fits[name], data)
    task.after_fits(data, results, run_dir)
    main = next(iter(results.values()))
    if rank_zero_only.rank != 0:
        # Other processes of a distributed fit (same numbers): the first one writes and reports.
        return main.metrics
    metrics = task.write(results, data, run_dir)
    write_json_atomic(run_dir / "metrics.json", metrics)
    for name, fitted in fits.items():
        log_final_figures(fitted.logger, fitted.settings, method_metrics(metrics, name, list(results)),
                          results[name].series, fitted.trainer.global_step)
    log.info(f"run directory: {run_dir}")
    for line in task.summary(results, data):
        log.info(line)
    if cfg.get("report"):
        log.info(instantiate(cfg.report)({n: r.metrics for n, r in results.items()}, data, run_dir))
    # Quoted where the path has spaces or brackets, so that the line pastes into a shell as it is.
    log.info(f"inspect: tensorboard --logdir {shlex.quote(str(run_dir))}")
    return metrics


def method_metrics(metrics: Metrics, name: str, methods: list[str]) -> Metrics:
    """``name``'s figures among the run's ``metrics`` (``metrics.json``: the main method's, the first of ``methods``,
    unprefixed; each baseline's under ``<name>/``)."""
    main, *baselines = methods
    if name != main:
        return {key.removeprefix(f"{name}/"): value for key, value in metrics.items() if key.startswith(f"{name}/")}
    return {key: value for key, value in metrics.items() if key.partition("/")[0] not in baselines}


def fit_method(
    name: str,
    model: Learner,
    cfg: DictConfig,
    datamodule: L.LightningDataModule,
    run_dir: Path,
    task: Task,
    ckpt_path: str | None,
    settings: dict[str, object],
) -> FittedMethod:
    """Fit one model through a Trainer from ``cfg.trainer``, with the run's logger (given ``settings``) and callbacks."""
    logger = build_logger(cfg, run_dir, name)
    log_settings(logger, settings)
    callbacks = build_callbacks(cfg, run_dir, name, model)
    started = time.perf_counter()
    trainer = fit(
        model, cfg, datamodule, ckpt_path=ckpt_path, true_matrix=task.true_matrix(datamodule.data),
        logger=logger if logger is not None else False, callbacks=callbacks, default_root_dir=str(run_dir),
        enable_checkpointing=any(isinstance(callback, ModelCheckpoint) for callback in callbacks),
    )
    return FittedMethod(name, model, trainer, time.perf_counter() - started, logger, run_dir, settings)
