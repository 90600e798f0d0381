"""A Hydra callback that gathers a multirun sweep: every job in ``sweep.csv``, each setting over its seeds in a table.

A *setting* is a job's overrides other than ``seed``; its jobs differ only in the seed. The
table (printed, and ``sweep_summary.csv``) gives each setting's headline figures
(:mod:`sfmnet.training.headline_metrics`) as mean and standard deviation over its jobs.
Numbers are written to 4 significant digits; ``metrics.json`` in each job keeps them whole.
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from sfmnet.io import write_csv_atomic
from sfmnet.training.headline_metrics import headline_keys
from sfmnet.training.run_directory import JOB_ERROR_FILE

SEED = "seed"


def sweep_rows(sweep_dir: Path) -> tuple[list[dict[str, Any]], list[str]]:
    """One row per finished job (its number, its overrides ``key=value``, its metrics), and the override keys."""
    rows, override_keys = [], []
    for metrics_path in sorted(sweep_dir.glob("*/metrics.json"), key=lambda p: (len(p.parent.name), p.parent.name)):
        job_dir = metrics_path.parent
        overrides_path = job_dir / ".hydra" / "overrides.yaml"
        overrides = OmegaConf.to_container(OmegaConf.load(overrides_path)) if overrides_path.exists() else []
        settings = dict(item.split("=", 1) for item in overrides or [] if "=" in item)
        override_keys.extend(key for key in settings if key not in override_keys)
        rows.append({"job": job_dir.name, **settings, **json.loads(metrics_path.read_text())})
    return rows, override_keys


def number(value: Any) -> Any:
    """A float at 4 significant digits; anything else as it is."""
    return f"{value:.4g}" if isinstance(value, float) else value


def write_sweep_csv(path: Path, rows: list[dict[str, Any]], override_keys: list[str]) -> None:
    """Every job: its number, its overrides, its headline figures, then the rest of its metrics."""
    metrics: list[str] = []
    for row in rows:
        metrics.extend(key for key in row if key not in metrics and key != "job" and key not in override_keys)
    headline = headline_keys(metrics)
    columns = ["job", *override_keys, *headline, *(key for key in metrics if key not in headline)]
    write_csv_atomic(path, columns, ([number(row.get(column, "")) for column in columns] for row in rows))


def seed_summary(rows: list[dict[str, Any]], override_keys: list[str]) -> tuple[list[str], list[dict[str, Any]]]:
    """Each setting's headline figures over its jobs (seeds).

    Returns:
        The setting keys (the overrides other than ``seed`` that vary between jobs) and one row per setting, in
        the sweep's order: those keys' values, ``n`` (its jobs), and per headline figure ``<figure> mean`` and
        ``<figure> std`` (the sample standard deviation, None for one job).
    """
    varying = [key for key in override_keys if key != SEED and len({row.get(key) for row in rows}) > 1]
    groups: dict[tuple[Any, ...], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row.get(key) for key in varying), []).append(row)
    figures = headline_keys(dict.fromkeys(key for row in rows for key in row))
    summary = []
    for values, jobs in groups.items():
        line: dict[str, Any] = {**dict(zip(varying, values)), "n": len(jobs)}
        for figure in figures:
            # None: a figure the job could not define (metrics.json's null).
            found = [float(job[figure]) for job in jobs if job.get(figure) is not None]
            line[f"{figure} mean"] = statistics.fmean(found) if found else None
            line[f"{figure} std"] = statistics.stdev(found) if len(found) > 1 else None
        summary.append(line)
    return varying, summary


def write_summary_csv(path: Path, summary: list[dict[str, Any]]) -> None:
    columns = list(summary[0])
    write_csv_atomic(path, columns, ([number(line[c]) if line[c] is not None else "" for c in columns] for line in summary))


def summary_table(varying: list[str], summary: list[dict[str, Any]]) -> list[str]:
    """The summary as text: a column per setting, a line per headline figure, ``mean ± std`` (4 significant digits)."""
    headers = [" ".join(f"{key}={line[key]}" for key in varying) or "all jobs" for line in summary]
    figures = [column.removesuffix(" mean") for column in summary[0] if column.endswith(" mean")]
    cells = [["n", *(str(line["n"]) for line in summary)]]
    for figure in figures:
        cells.append([figure, *(mean_and_std(line[f"{figure} mean"], line[f"{figure} std"]) for line in summary)])
    widths = [max(len(text) for text in column) for column in zip(["", *headers], *cells)]
    return ["  ".join(text.ljust(width) for text, width in zip(line, widths)).rstrip() for line in [["", *headers], *cells]]


def mean_and_std(mean: float | None, std: float | None) -> str:
    if mean is None:
        return "-"
    return f"{mean:.4g}" if std is None else f"{mean:.4g} ± {std:.4g}"


class SweepSummary(Callback):
    """After ``-m``: ``<sweep dir>/sweep.csv`` (one row per job) and ``sweep_summary.csv`` (one per setting), and
    the summary printed (print, not logging: Hydra's job logging still writes to the last job's ``train.log``)."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir).resolve()
        rows, override_keys = sweep_rows(sweep_dir)
        failed = sorted((path.parent.name for path in sweep_dir.glob(f"*/{JOB_ERROR_FILE}")), key=lambda job: (len(job), job))
        if failed:
            print(
                f"\n{len(failed)} of {len(rows) + len(failed)} jobs failed (job {', '.join(failed)}): each job's "
                f"{JOB_ERROR_FILE} says why" + ("; the table below is of the others" if rows else "")
            )
        if not rows:
            return
        write_sweep_csv(sweep_dir / "sweep.csv", rows, override_keys)
        varying, summary = seed_summary(rows, override_keys)
        write_summary_csv(sweep_dir / "sweep_summary.csv", summary)
        jobs = f"{len(rows)} job{'s' if len(rows) != 1 else ''}"
        print(f"\nsweep of {jobs}: each setting's mean ± standard deviation over its seeds")
        for line in summary_table(varying, summary):
            print(line)
        print(f"every job: {sweep_dir / 'sweep.csv'}\nthis table: {sweep_dir / 'sweep_summary.csv'}")
