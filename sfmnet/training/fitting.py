"""Fitting one model: its closed form, then the optimiser's epochs, through one Lightning Trainer."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import lightning as L
import torch
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from lightning.pytorch.trainer.states import TrainerStatus
from omegaconf import DictConfig, OmegaConf

from sfmnet.errors import FitInterrupted, SfmnetError
from sfmnet.data.recording import CalibrationRecording
from sfmnet.models.linear_calibrator import LinearCalibrator
from sfmnet.models.contracts import FitMode, Learner
from sfmnet.training.learner_module import LearnerModule, OptimizerFactory

log = logging.getLogger(__name__)


def fit(
    model: Learner,
    cfg: DictConfig,
    datamodule: L.LightningDataModule,
    ckpt_path: str | None = None,
    true_matrix: torch.Tensor | None = None,
    **trainer_options,
) -> L.Trainer:
    """Fit ``model`` with the optimiser ``cfg.optimizer`` and a Trainer from ``cfg.trainer`` (plus ``trainer_options``).

    ``ckpt_path``: a checkpoint of an interrupted run of the same config; training resumes
    from it (model, optimiser state and epoch) to the result the uninterrupted run would give.
    ``true_matrix``: simulated truth, logged against every epoch.
    """
    passes = model.fit_mode() is FitMode.PASSES
    if ckpt_path is not None and not Path(ckpt_path).is_file():
        raise SfmnetError(f"ckpt_path {ckpt_path} is not a file: give a run's checkpoints/<method>/last.ckpt")
    if ckpt_path is not None and passes:
        log.info(f"resuming from {ckpt_path}: a fit in passes over a file keeps the passes it finished and reads the one "
                 "it was in again from its start")
    if passes:
        # The row data module deals its blocks to processes itself; a distributed sampler would split them again.
        trainer_options["use_distributed_sampler"] = False
        if cfg.trainer.get("fast_dev_run"):
            # A dev run of a fit in passes: one block a pass, as many passes as a result needs.
            trainer_options.update(fast_dev_run=False, limit_train_batches=1, max_epochs=model.dev_run_passes)
    module = LearnerModule(
        model=model, optimizer=instantiate(cfg.optimizer), true_matrix=true_matrix, fit_settings=fit_settings(cfg)
    )
    trainer = build_trainer(cfg, **trainer_options)
    try:
        trainer.fit(module, datamodule=datamodule, ckpt_path=ckpt_path)
    except SystemExit:
        # Lightning's answer to Ctrl-C: it tears the fit down and exits with status 1.
        if trainer.state.status is TrainerStatus.INTERRUPTED:
            raise FitInterrupted(resume_hint(trainer), stopped_where(trainer)) from None
        raise
    except RuntimeError as error:
        if ckpt_path is not None and "state_dict" in str(error):
            first = next((line.strip() for line in str(error).splitlines()[1:] if line.strip()), str(error))
            raise SfmnetError(
                f"ckpt_path {ckpt_path} is a checkpoint of another fit ({first.rstrip('.')}): resume with a checkpoint "
                "of this same config's run"
            ) from None
        raise
    return trainer


# What a fit depends on, which a resumed run must share with the interrupted one (not the trainer's settings: a
# resumed run may be given more epochs, or other devices).
FIT_CONFIG_GROUPS = ("data", "model", "optimizer", "seed")


def fit_settings(cfg: DictConfig) -> dict[str, Any]:
    """``cfg``'s :data:`FIT_CONFIG_GROUPS`, flat (``data.test_fraction``: value) and resolved, file paths absolute."""
    settings: dict[str, Any] = {}
    for group in FIT_CONFIG_GROUPS:
        if group not in cfg:
            continue
        value = cfg[group]
        container = OmegaConf.to_container(value, resolve=True) if isinstance(value, DictConfig) else value
        settings.update(flat_settings(container, group))
    return {key: str(Path(value).resolve()) if key.endswith(".path") and isinstance(value, str) else value
            for key, value in settings.items()}


def flat_settings(value: Any, prefix: str) -> dict[str, Any]:
    if isinstance(value, dict):
        return {key: item for name, child in value.items() for key, item in flat_settings(child, f"{prefix}.{name}").items()}
    return {prefix: value}


def stopped_where(trainer: L.Trainer) -> str:
    return f"{type(trainer.lightning_module.model).__name__} stopped in epoch {trainer.current_epoch + 1}"


def resume_hint(trainer: L.Trainer) -> str:
    """Where an interrupted fit stopped and the checkpoint to resume it from."""
    stopped = stopped_where(trainer)
    checkpoint = trainer.checkpoint_callback
    last = Path(checkpoint.dirpath) / "last.ckpt" if checkpoint is not None and checkpoint.dirpath else None
    if last is None or not last.is_file():
        return f"{stopped}, before its first checkpoint: run it again from the start"
    return f"{stopped}: resume with ckpt_path={last} (and a new hydra.run.dir); the result is the uninterrupted run's"


def build_trainer(cfg: DictConfig, **trainer_options) -> L.Trainer:
    """A Trainer from ``cfg.trainer``; settings Lightning refuses (an accelerator this machine lacks) are one line."""
    try:
        return instantiate(cfg.trainer, **trainer_options)
    except InstantiationException as error:
        cause = error.__cause__ or error
        reason = " ".join(str(cause).split()) or type(cause).__name__
        raise SfmnetError(
            f"Lightning cannot make a Trainer of these trainer settings ({reason}): check trainer.accelerator (cpu runs "
            "everywhere), trainer.devices, trainer.strategy and trainer.precision"
        ) from None


def refine_in_process(
    model: LinearCalibrator,
    recording: CalibrationRecording,
    optimizer: OptimizerFactory,
    epochs: int = 10,
    initialise: bool = True,
    after_epoch: Callable[[], None] | None = None,
) -> LinearCalibrator:
    """The refinement steps :class:`LearnerModule` runs, on the whole recording as one batch, without a Trainer.

    For benchmarks and tests that fit thousands of small sessions, where the Trainer's start-up
    would dominate: the closed form (``initialise``), then per epoch the model's own alternation,
    or its ``prepare_step`` followed by one step of ``optimizer`` (built from the parameters);
    ``after_epoch`` is called after each (e.g. to time the refinement), and the model's ``end_fit`` after the last.
    """
    if initialise:
        model.initialise(recording)
    batch = recording.whole_batch()
    if model.fit_mode() is FitMode.ALTERNATION:
        def epoch() -> None:
            model.alternate(batch)
    else:
        step = optimizer([p for p in model.parameters() if p.requires_grad])

        def closure() -> torch.Tensor:
            step.zero_grad()
            loss = model.loss(batch)["loss"]
            loss.backward()
            return loss

        def epoch() -> None:
            model.prepare_step(batch)
            step.step(closure)

    for _ in range(epochs):
        epoch()
        if after_epoch is not None:
            after_epoch()
    model.end_fit(recording)
    return model
