"""A run's stand-alone figures: a PNG in the run directory and the same figure in TensorBoard."""

from __future__ import annotations

from pathlib import Path

from lightning.pytorch.loggers import TensorBoardLogger
from matplotlib import pyplot as plt
from matplotlib.figure import Figure

from sfmnet.io import save_figure_atomic


def publish_figure(figure: Figure, run_dir: Path, tag: str) -> None:
    """Save ``figure`` as ``figures/<tag>.png`` and log it under ``tensorboard/<tag>``, then close it."""
    save_figure_atomic(figure, run_dir / "figures" / f"{tag}.png")
    logger = TensorBoardLogger(save_dir=str(run_dir), name="tensorboard", version=tag)
    logger.experiment.add_figure(tag, figure, close=False)
    logger.experiment.flush()
    plt.close(figure)
