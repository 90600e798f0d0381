"""A streamed fit from a row file: one pass of sufficient statistics through the Trainer, on one or several processes.

Run directory (written by the first process only)::

    pca.npz        mean (p), components (k x p, orthonormal rows), singular_values (k, of the centred data), columns
    metrics.json   rows, seconds, explained variance
    tensorboard/pca/
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from lightning.pytorch.loggers import TensorBoardLogger
from omegaconf import DictConfig

from sfmnet.data.row_file import RowFileDataModule
from sfmnet.io import save_npz_atomic, write_json_atomic
from sfmnet.models.streaming_pca import StreamingPCA
from sfmnet.training.fitting import fit
from sfmnet.training.progress import ProgressBar


def train_streaming(cfg: DictConfig, datamodule: RowFileDataModule, run_dir: Path) -> dict[str, float]:
    model: StreamingPCA = instantiate(cfg.model)
    logger = TensorBoardLogger(save_dir=str(run_dir), name="tensorboard", version=model.name, default_hp_metric=False)
    callbacks = [ProgressBar()] if cfg.trainer.get("enable_progress_bar", True) else []
    started = time.perf_counter()
    trainer = fit(
        model, cfg, datamodule, logger=logger, callbacks=callbacks, enable_checkpointing=False,
        default_root_dir=str(run_dir),
    )
    seconds = time.perf_counter() - started
    moments = model.moments
    total_variance = float(moments.centred_cross().trace())
    metrics = {
        "rows": float(moments.count),
        "fit_seconds": seconds,
        "processes": float(trainer.world_size),
        "explained_variance_ratio": float(model.singular_values.pow(2).sum()) / total_variance if total_variance else 1.0,
    }
    if trainer.is_global_zero:
        save_pca(model, datamodule.data.channels, run_dir / "pca.npz")
        write_json_atomic(run_dir / "metrics.json", metrics)
        print(f"\nrun directory: {run_dir}")
        print(
            f"  pca: {int(metrics['rows'])} rows x {len(datamodule.data.channels)} columns in {seconds:.2f} s on "
            f"{trainer.world_size} process(es); {model.rank} components explain "
            f"{100 * metrics['explained_variance_ratio']:.2f} % of the variance"
        )
    return metrics


def save_pca(model: StreamingPCA, columns: list[str], path: Path) -> None:
    save_npz_atomic(
        path,
        mean=model.mean.detach().numpy(),
        components=model.components.detach().numpy(),
        singular_values=model.singular_values.numpy(),
        columns=np.array(columns),
    )
