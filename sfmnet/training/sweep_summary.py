"""A Hydra callback that gathers every job of a multirun sweep into one ``sweep.csv``."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from sfmnet.io import write_csv_atomic


def sweep_rows(sweep_dir: Path) -> list[dict[str, Any]]:
    """One row per finished job: its number, its overrides (``key=value``) and its metrics."""
    rows = []
    for metrics_path in sorted(sweep_dir.glob("*/metrics.json"), key=lambda p: (len(p.parent.name), p.parent.name)):
        job_dir = metrics_path.parent
        overrides_path = job_dir / ".hydra" / "overrides.yaml"
        overrides = OmegaConf.to_container(OmegaConf.load(overrides_path)) if overrides_path.exists() else []
        row: dict[str, Any] = {"job": job_dir.name}
        row.update(dict(item.split("=", 1) for item in overrides or [] if "=" in item))
        row.update(json.loads(metrics_path.read_text()))
        rows.append(row)
    return rows


def write_sweep_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    columns: list[str] = []
    for row in rows:
        columns.extend(key for key in row if key not in columns)
    write_csv_atomic(path, columns, ([row.get(column, "") for column in columns] for row in rows))


class SweepSummary(Callback):
    """After ``-m``, write ``<sweep dir>/sweep.csv``: one row per job, overrides then metrics."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        rows = sweep_rows(sweep_dir)
        if rows:
            write_sweep_csv(sweep_dir / "sweep.csv", rows)
            print(f"sweep summary ({len(rows)} jobs): {sweep_dir / 'sweep.csv'}")
