"""A fit's settings and final figures in its TensorBoard run, so runs and sweeps compare in the HParams view.

Each method's run (``tensorboard/<method>/``) gets, at the end of the run:

- every figure of ``metrics.json`` that is the method's as a scalar ``final/<name>`` at the fit's last step;
- its settings (:func:`run_settings`) with its headline figures (:mod:`sfmnet.training.headline_metrics`)
  through the hparams plugin: one row of the HParams view, one column per setting and per figure;
- series over items (e.g. ``leave_one_group_out/force_rms``, stepped by the held-out group).

The settings are logged before the fit too, so Lightning's ``hparams.yaml`` holds them.
"""

from __future__ import annotations

from typing import Any

from lightning.pytorch.loggers import Logger, TensorBoardLogger
from omegaconf import DictConfig, OmegaConf

from sfmnet.training.headline_metrics import headline_keys

FINAL = "final/"


def run_settings(cfg: DictConfig, method: str, model_cfg: DictConfig) -> dict[str, Any]:
    """The settings that tell one method's fit from another's, with the command line's dotted keys.

    The experiment, the method, the seed, and every key of the method's model, the data, the
    optimiser and ``eval``, and ``trainer.max_epochs``; interpolations resolved, ``_target_`` and
    the like left out (the method's name says which model).
    """
    settings: dict[str, Any] = {"experiment_name": cfg.experiment_name, "method": method, "seed": cfg.seed}
    for prefix, node in (("model", model_cfg), ("data", cfg.data), ("optimizer", cfg.optimizer), ("eval", cfg.get("eval"))):
        if node is not None:
            settings.update(flat_settings(OmegaConf.to_container(node, resolve=True), prefix))
    settings["trainer.max_epochs"] = cfg.trainer.max_epochs
    return settings


def flat_settings(node: Any, prefix: str) -> dict[str, Any]:
    """``{"a": {"b": 1}}`` as ``{"<prefix>.a.b": 1}``; keys starting with "_" (Hydra's) dropped; lists kept whole."""
    if not isinstance(node, dict):
        return {prefix: node}
    flat: dict[str, Any] = {}
    for key, value in node.items():
        if not str(key).startswith("_"):
            flat.update(flat_settings(value, f"{prefix}.{key}"))
    return flat


def log_settings(logger: Logger | None, settings: dict[str, Any]) -> None:
    """Before the fit: the settings into the logger's ``hparams.yaml`` (no plugin summary without figures)."""
    if logger is not None:
        logger.log_hyperparams(settings)


def log_final_figures(
    logger: Logger | None,
    settings: dict[str, Any],
    metrics: dict[str, float],
    series: dict[str, dict[int, float]],
    step: int,
) -> None:
    """After the run: ``metrics`` (one method's, unprefixed) as ``final/<name>`` scalars at ``step``, the headline ones
    with ``settings`` through the hparams plugin (TensorBoard's logger; others log them as scalars), and ``series``
    (tag to ``{step: value}``); then the event files are closed."""
    if logger is None:
        return
    headline = headline_keys(metrics) or list(metrics)
    logger.log_metrics({FINAL + key: value for key, value in metrics.items() if key not in headline}, step)
    figures = {FINAL + key: metrics[key] for key in headline}
    if isinstance(logger, TensorBoardLogger):
        logger.log_hyperparams(settings, figures, step)
    else:
        logger.log_metrics(figures, step)
    for tag, values in series.items():
        for item, value in values.items():
            logger.log_metrics({tag: value}, item)
    # The trainer closed its writer at the end of the fit; these events reopened it.
    logger.finalize("success")
