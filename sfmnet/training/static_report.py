"""What a run says about the static intervals it fitted: a CSV, metrics, a console line and a figure."""

from __future__ import annotations

from pathlib import Path

from lightning.pytorch.loggers import Logger

from sfmnet.data.recording import CalibrationData
from sfmnet.eval.figures import static_intervals_figure
from sfmnet.io import write_csv_atomic
from sfmnet.preprocessing.static_intervals import StaticIntervals
from sfmnet.training.components import publish_figure


def report_static_intervals(data: CalibrationData, run_dir: Path, logger: Logger | None) -> tuple[dict[str, float], str | None]:
    """Write ``static_intervals.csv`` and ``figures/static_intervals.png`` (also to ``logger``'s TensorBoard).

    Returns:
        the metrics ``static/intervals``, ``static/rows_kept``, ``static/rows_total``, ``static/time_gaps`` and
        ``static/repeated_rows``, ``static/noise_correlation`` (the worst channel's
        :attr:`~sfmnet.preprocessing.static_intervals.StaticIntervals.noise_correlation`, where measured), and the
        console line (empty and None without detection).
    """
    detection = data.static_intervals
    if detection is None:
        return {}, None
    line = describe(detection)
    if not detection.independent:
        write_csv_atomic(run_dir / "static_intervals.csv", INTERVAL_COLUMNS, interval_rows(detection))
        title = line.replace("static intervals: ", "Static intervals: ", 1)
        figure = static_intervals_figure(detection, data.channels, title)
        publish_figure(figure, run_dir / "figures" / "static_intervals.png", "static_intervals", logger)
    metrics = {
        "static/intervals": float(detection.count),
        "static/rows_kept": float(detection.rows_kept),
        "static/rows_total": float(len(detection.mask)),
        "static/time_gaps": float(len(detection.gap_rows)),
        "static/repeated_rows": float(detection.repeats.whole),
    }
    worst = detection.most_correlated_channel
    if worst is not None:
        metrics["static/noise_correlation"] = float(detection.noise_correlation[worst])
    return metrics, line


def describe(detection: StaticIntervals) -> str:
    """One line: how many intervals and rows were kept, with the settings used."""
    kept, total = detection.rows_kept, len(detection.mask)
    if detection.independent:
        return (
            f"static intervals: none needed, consecutive rows are as different as any two (independent poses, "
            f"serial ratio {detection.serial_ratio:.2f}): {kept:,} of {total:,} rows kept"
        )
    if detection.period is None:
        settings = f"window {detection.window_rows} rows, intervals of at least {detection.min_rows} rows"
    else:
        window, shortest = detection.window_rows * detection.period, detection.min_rows * detection.period
        settings = f"window {window:.3g} s, intervals of at least {shortest:.3g} s"
    time_notes = []
    if len(detection.gap_rows):
        time_notes.append(f"{len(detection.gap_rows)} gaps in the time column split the stream")
    if detection.jitter_rows:
        time_notes.append(f"{detection.jitter_rows} stamps not after the row before's taken as jitter, in file order")
    return (
        f"static intervals: {detection.count} found, {kept:,} of {total:,} rows kept "
        f"({settings}, threshold {detection.threshold:g} x the noise variance)"
        + "".join(f"; {note}" for note in time_notes)
    )


INTERVAL_COLUMNS = ["interval", "first_row", "last_row", "start_time", "end_time", "rows"]


def interval_rows(detection: StaticIntervals) -> list[list]:
    """One row per interval: index, first and last row (0-based data rows), start and end time (s), rows."""
    rows = []
    for k, (first, stop) in enumerate(detection.intervals.tolist()):
        times = ["", ""] if detection.interval_times is None else [f"{t:.6g}" for t in detection.interval_times[k]]
        rows.append([k, first, stop - 1, *times, stop - first])
    return rows
