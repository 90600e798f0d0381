"""The paper's Table 1: least squares (the paper's form and the load regression) against shape from motion."""

from __future__ import annotations

from pathlib import Path

from sfmnet.data.recording import CalibrationData
from sfmnet.errors import SfmnetError
from sfmnet.io import write_csv_atomic

# Paper, Table 1: load (g) -> (mean, error %, std dev) for least squares and shape from motion.
PAPER_TABLE1 = {
    60.4: {"least_squares": (60.1, 0.5, 1.20), "shape_from_motion": (60.5, 0.2, 1.13)},
    111.4: {"least_squares": (110.2, 1.1, 0.83), "shape_from_motion": (111.6, 0.2, 0.60)},
}
METHODS = ("least_squares", "regression", "shape_from_motion")
COLUMNS = ["load", *(f"{method}_{figure}" for method in METHODS for figure in ("mean", "error_pct", "std_dev"))]


def table1_rows(metrics: dict[str, dict[str, float]], loads: list[float]) -> list[dict[str, float]]:
    """One row per test load from each method's ``eval/<load>/<figure>`` metrics."""
    return [
        {"load": load, **{f"{m}_{fig}": metrics[m][f"eval/{load:g}/{fig}"] for m in METHODS for fig in ("mean", "error_pct", "std_dev")}}
        for load in loads
    ]


def write_table1(path: Path, rows: list[dict[str, float]]) -> None:
    write_csv_atomic(
        path, COLUMNS, ([f"{row['load']:g}", *(f"{row[column]:.4f}" for column in COLUMNS[1:])] for row in rows)
    )


def format_beside_paper(rows: list[dict[str, float]]) -> str:
    """A plain-text table of the measured rows, with the paper's numbers under the loads it reports (it has no regression)."""
    titles = {"least_squares": "least squares", "regression": "regression", "shape_from_motion": "shape from motion"}
    widths = [max(20, len(titles[m]) + 18) for m in METHODS]
    head = " | ".join([f"{'load':>7}", *(f"{titles[m] + ': mean  err%  std':>{w}}" for m, w in zip(METHODS, widths))])
    lines = [head, "-" * len(head)]
    for row in rows:
        cells = [f"{row[f'{m}_mean']:8.2f} {row[f'{m}_error_pct']:5.2f} {row[f'{m}_std_dev']:5.2f}" for m in METHODS]
        lines.append(" | ".join([f"{row['load']:>7g}", *(f"{c:>{w}}" for c, w in zip(cells, widths))]))
        paper = PAPER_TABLE1.get(round(row["load"], 1))
        if paper:
            cells = [f"{paper[m][0]:8.1f} {paper[m][1]:5.1f} {paper[m][2]:5.2f}" if m in paper else "-" for m in METHODS]
            lines.append(" | ".join([f"{'paper':>7}", *(f"{c:>{w}}" for c, w in zip(cells, widths))]))
    return "\n".join(lines)


def report_table1(metrics: dict[str, dict[str, float]], data: CalibrationData, run_dir: Path) -> str:
    """Write ``table1.csv`` in the run directory and return it as text beside the paper's numbers."""
    missing = [m for m in METHODS if m not in metrics]
    if missing:
        raise SfmnetError(f"table1 needs every method, {', '.join(missing)} did not run: use experiment=table1")
    rows = table1_rows(metrics, [sweep.magnitude for sweep in data.evaluations])
    write_table1(run_dir / "table1.csv", rows)
    return f"Table 1 (written to {run_dir / 'table1.csv'}):\n{format_beside_paper(rows)}"
