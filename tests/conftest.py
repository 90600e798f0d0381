"""Shared helpers: compose the real configs the way the CLI does."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from sfmnet.cli import config_dir

REPO = Path(__file__).resolve().parent.parent
EXPERIMENTS = sorted(p.stem for p in (REPO / "conf" / "experiment").glob("*.yaml"))


def compose_config(overrides: list[str] | None = None) -> DictConfig:
    """The config the CLI would build from ``overrides`` (progress bars off, to keep test logs readable)."""
    with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
        return compose(config_name="train", overrides=["trainer.enable_progress_bar=false", *(overrides or [])])


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    path = tmp_path / "run"
    path.mkdir()
    return path
