"""Figures a person looks at: the recovered motion (paper Figs. 4 and 5), the singular-value spectrum,
human against learnt commands (paper Fig. 6), and a continuous recording's static intervals."""

from __future__ import annotations

import math
import textwrap

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter, MaxNLocator

from sfmnet.preprocessing.static_intervals import StaticIntervals


# Most samples drawn in one scatter.
MAX_POINTS = 20_000
# Legends sit here, to the right of their axes, so that they never cover data.
OUTSIDE_RIGHT = {"loc": "upper left", "bbox_to_anchor": (1.02, 1.0), "fontsize": 8, "frameon": False}
MAGNITUDE_ERROR_LABEL = "magnitude error |load| / F - 1 (%)"


def method_title(name: str) -> str:
    """A method's config name in words for a figure title: ``shape_from_motion`` -> ``Shape from motion``."""
    words = name.replace("_", " ")
    return words[:1].upper() + words[1:]


def ordinal(k: int) -> str:
    """``1st``, ``2nd``, ``3rd``, ``4th``, ..., ``11th``, ``21st``."""
    suffix = "th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")
    return f"{k}{suffix}"


def motion_figure(
    motion: torch.Tensor, magnitude: float, unit: str, title: str, axis_names: list[str] | None = None
) -> Figure | None:
    """The recovered loads: a polar plot for 2 axes (Fig. 4), points on the sphere for 3 (Fig. 5).

    Args:
        motion: ``f x n`` recovered loads of the unknown-orientation samples (``unit``).
        magnitude: the true constant magnitude ``F``, drawn for reference (``unit``).
        axis_names: the ``n`` axis names (default ``fx, fy, fz``).

    Returns:
        The figure, or None for other ``n``.
    """
    n = motion.shape[1]
    names = axis_names or ["fx", "fy", "fz"][:n]
    # Every k-th sample beyond MAX_POINTS: a million points draw for minutes and show no more.
    stride = max(1, math.ceil(len(motion) / MAX_POINTS))
    m = motion.detach().cpu()[::stride]
    deviation = 100 * (m.norm(dim=1) / magnitude - 1)
    if stride > 1:
        title = f"{title} (every {ordinal(stride)} of {len(motion):,} samples)"
    title = "\n".join(textwrap.wrap(title, 80))
    if n == 2:
        fig = plt.figure(figsize=(10, 4.2))
        polar = fig.add_subplot(1, 2, 1, projection="polar")
        angle = torch.atan2(m[:, 1], m[:, 0])
        polar.plot(angle, m.norm(dim=1), "o", markersize=3, label="calibrated samples")
        circle = torch.linspace(0, 2 * math.pi, 200)
        polar.plot(circle, torch.full_like(circle, magnitude), "k--", linewidth=0.8, label=f"F = {magnitude:g} {unit}")
        polar.set_rlim(0, 1.08 * float(m.norm(dim=1).max()))
        # Radial ticks inside the circle, with their unit: the samples lie on it and would hide them.
        polar.set_rticks([r for r in MaxNLocator(4).tick_values(0, 0.75 * magnitude) if 0 < r <= 0.75 * magnitude])
        polar.yaxis.set_major_formatter(FuncFormatter(lambda r, _: f"{r:g} {unit}"))
        polar.set_rlabel_position(112.5)
        polar.set_xlabel(f"load direction from {names[0]} towards {names[1]}", fontsize=9)
        polar.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, fontsize=8, frameon=False)
        # The magnitude error against direction: 1 % noise is invisible on the polar plot.
        ax = fig.add_subplot(1, 2, 2)
        ax.plot(torch.rad2deg(angle), deviation, "o", markersize=3)
        ax.axhline(0, color="k", linewidth=0.8, linestyle="--")
        ax.set_xlabel(f"load direction from {names[0]} (deg)")
        ax.set_ylabel(MAGNITUDE_ERROR_LABEL)
        ax.set_xlim(-180, 180)
        ax.set_xticks(range(-180, 181, 90))
        fig.suptitle(title, fontsize=10)
        fig.tight_layout()
    elif n == 3:
        fig = plt.figure(figsize=(6.5, 5))
        ax = fig.add_subplot(projection="3d")
        u, v = torch.meshgrid(torch.linspace(0, 2 * math.pi, 24), torch.linspace(0, math.pi, 12), indexing="ij")
        ax.plot_wireframe(
            magnitude * u.cos() * v.sin(), magnitude * u.sin() * v.sin(), magnitude * v.cos(),
            color="0.8", linewidth=0.5,
        )
        # A diverging map centred on 0: white is the exact magnitude, red too large, blue too small.
        limit = float(deviation.abs().max()) or 1.0
        points = ax.scatter(m[:, 0], m[:, 1], m[:, 2], s=6, c=deviation, cmap="coolwarm", norm=Normalize(-limit, limit))
        fig.colorbar(points, ax=ax, shrink=0.6, pad=0.12, label=MAGNITUDE_ERROR_LABEL)
        for set_label, name in zip((ax.set_xlabel, ax.set_ylabel, ax.set_zlabel), names):
            set_label(f"{name} ({unit})")
        ax.set_box_aspect((1, 1, 1))
        fig.suptitle(title, fontsize=10)
    else:
        return None
    return fig


def spectrum_figure(singular_values: torch.Tensor, rank: int, title: str, value_unit: str) -> Figure:
    """Singular values on a log scale, the kept rank marked; the gap after it says how well the data is rank n.

    Args:
        value_unit: what the singular values are measured in (e.g. ``raw reading units``).
    """
    s = singular_values.detach().cpu()
    fig, ax = plt.subplots(figsize=(6, 3.5))
    index = torch.arange(1, len(s) + 1)
    colours = ["tab:blue" if i <= rank else "tab:gray" for i in index.tolist()]
    ax.bar(index, s.clamp_min(1e-300), color=colours)
    ax.set_yscale("log")
    ax.axvline(rank + 0.5, color="tab:red", linestyle="--", linewidth=1)
    ax.set_xlabel("component (number, 1 = largest)")
    ax.set_ylabel(f"singular value ({value_unit})")
    ax.set_xticks(index)
    ax.legend(handles=[Patch(color="tab:blue", label=f"kept (rank {rank})"), Patch(color="tab:gray", label="discarded")], **OUTSIDE_RIGHT)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def commands_figure(
    period: float,
    names: list[str],
    levels: list[list],
    human: np.ndarray,
    learned: np.ndarray,
    confidence: np.ndarray,
    title: str,
) -> Figure:
    """The paper's Fig. 6: human and learnt commands over time on one test run, with the learner's confidence.

    A command is one of a few categorical levels, so each is drawn as a raster, a row per level:
    where the human chose the level (upper band) and where the learner did (lower band).

    Args:
        period: seconds per sample; names: the ``c`` command names; levels: each command's levels, bottom row first.
        human, learned: ``t x c`` command labels (values of ``levels``).
        confidence: ``t``, in (0, 1].
    """
    t = np.arange(len(human) + 1) * period
    rows = [len(lv) for lv in levels]
    fig, axes = plt.subplots(
        len(names) + 1, 1, figsize=(10, 1.2 + 0.55 * sum(rows) + 1.6), sharex=True,
        gridspec_kw={"height_ratios": [*rows, 2.5]},
    )
    for axis, name, options, h, l in zip(axes, names, levels, human.T, learned.T):
        for row, level in enumerate(options):
            for values, bottom, colour in ((h, row + 0.02, "black"), (l, row - 0.42, "tab:orange")):
                axis.broken_barh(level_runs(values == level, t), (bottom, 0.4), color=colour, linewidth=0)
        axis.set_yticks(range(len(options)), [str(v) for v in options])
        axis.set_ylim(-0.55, len(options) - 0.45)
        axis.set_ylabel(f"{name}\n(level)")
    bands = [Patch(color="black", label="human (upper band)"), Patch(color="tab:orange", label="learnt (lower band)")]
    axes[0].legend(handles=bands, **OUTSIDE_RIGHT)
    axes[-1].plot(t[:-1], confidence, color="tab:green", linewidth=0.8)
    axes[-1].set_ylabel("confidence\n(0-1)")
    axes[-1].set_xlabel("time (s)")
    axes[-1].set_xlim(t[0], t[-1])
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def level_runs(chosen: np.ndarray, edges: np.ndarray) -> list[tuple[float, float]]:
    """The runs of True in ``chosen`` (``t``) as ``(start, duration)`` on the time axis ``edges`` (``t + 1``)."""
    change = np.diff(np.concatenate([[0], chosen.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(change == 1), np.flatnonzero(change == -1)
    return [(float(edges[a]), float(edges[b] - edges[a])) for a, b in zip(starts, stops)]


def static_intervals_figure(detection: StaticIntervals, channels: list[str], title: str) -> Figure:
    """A continuous recording with its static intervals shaded: the first channels above, the motion statistic below.

    Args:
        detection: the detector's result (its thinned preview of the stream is what is drawn).
        channels: the names of the previewed channels (the first ones).
    """
    rows = detection.preview_rows
    timed = detection.preview_time is not None
    x = detection.preview_time if timed else rows
    to_x = (lambda r: np.interp(r, rows, detection.preview_time)) if timed else (lambda r: np.asarray(r, dtype=float))
    # Each drawn point of the statistic is the largest of the rows it stands for, so short motion shows.
    edges = np.append(rows, len(detection.statistic))
    peaks = np.maximum.reduceat(detection.statistic, rows) if len(rows) else rows
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 5.2), sharex=True, gridspec_kw={"height_ratios": [3, 2]})
    for axis in (top, bottom):
        for first, stop in detection.intervals:
            axis.axvspan(to_x(first), to_x(stop - 1), color="tab:green", alpha=0.18, linewidth=0)
    for values, name in zip(detection.preview_readings.T, channels):
        top.plot(x, values, linewidth=0.7, label=name)
    top.set_ylabel("reading (raw units)")
    top.plot([], [], color="tab:green", alpha=0.4, linewidth=8, label="static (kept)")
    top.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    bottom.plot(x, np.maximum(peaks, 1e-3), color="0.3", linewidth=0.7, label="windowed variance / noise variance\n(mean over channels)")
    bottom.axhline(detection.threshold, color="tab:red", linestyle="--", linewidth=1, label=f"threshold {detection.threshold:g}")
    bottom.set_yscale("log")
    bottom.set_ylabel("motion statistic\n(x noise variance)")
    bottom.set_xlabel("time (s)" if timed else "row")
    bottom.set_xlim(x[0], to_x(edges[-1] - 1))
    bottom.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
