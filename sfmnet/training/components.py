"""The one place a run's logger and callbacks are built, from the ``logger/`` and ``callbacks/`` config groups."""

from __future__ import annotations

from pathlib import Path

from hydra.utils import instantiate
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.loggers import Logger
from matplotlib import pyplot as plt
from matplotlib.figure import Figure
from omegaconf import DictConfig

from sfmnet.io import save_figure_atomic
from sfmnet.models.contracts import Learner


def build_logger(cfg: DictConfig, run_dir: Path, version: str) -> Logger | None:
    """``cfg.logger`` writing under ``run_dir`` as ``version`` (a method's name, or a figure's tag); None when off."""
    if not cfg.get("logger"):
        return None
    return instantiate(cfg.logger, save_dir=str(run_dir), version=version)


def build_callbacks(cfg: DictConfig, run_dir: Path, method: str, model: Learner) -> list[Callback]:
    """``cfg.callbacks`` for fitting ``method``: the checkpoint into ``checkpoints/<method>``; the progress bar only
    where the trainer shows one."""
    callbacks = []
    for key, callback_cfg in (cfg.get("callbacks") or {}).items():
        if key == "model_checkpoint":
            callbacks.append(instantiate(callback_cfg, dirpath=str(run_dir / "checkpoints" / method)))
        elif key == "progress_bar":
            if cfg.trainer.get("enable_progress_bar", True):
                callbacks.append(instantiate(callback_cfg))
        else:
            callbacks.append(instantiate(callback_cfg))
    return callbacks


def publish_figure(figure: Figure, png: Path, tag: str, logger: Logger | None, step: int = 0) -> None:
    """Save ``figure`` as ``png`` and log it as ``tag`` in the logger's TensorBoard (if any), then close it."""
    save_figure_atomic(figure, png)
    experiment = getattr(logger, "experiment", None) if logger is not None else None
    if experiment is not None and hasattr(experiment, "add_figure"):
        experiment.add_figure(tag, figure, global_step=step, close=False)
        # The trainer may have finalised its writer already; this figure is ours to flush.
        experiment.flush()
    plt.close(figure)
