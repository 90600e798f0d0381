"""Figures a person looks at: the recovered motion (paper Figs. 4 and 5), the singular-value spectrum,
human against learnt commands (paper Fig. 6), and a continuous recording's static intervals."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch
from matplotlib.figure import Figure

from sfmnet.preprocessing.static_intervals import StaticIntervals


# Most samples drawn in one scatter.
MAX_POINTS = 20_000


def motion_figure(motion: torch.Tensor, magnitude: float, unit: str, title: str) -> Figure | None:
    """The recovered loads: a polar plot for 2 axes (Fig. 4), points on the sphere for 3 (Fig. 5).

    Args:
        motion: ``f x n`` recovered loads of the unknown-orientation samples.
        magnitude: the true constant magnitude, drawn for reference.

    Returns:
        The figure, or None for other ``n``.
    """
    n = motion.shape[1]
    # Every k-th sample beyond MAX_POINTS: a million points draw for minutes and show no more.
    stride = max(1, math.ceil(len(motion) / MAX_POINTS))
    m = motion.detach().cpu()[::stride]
    deviation = 100 * (m.norm(dim=1) / magnitude - 1)
    if stride > 1:
        title = f"{title} (every {stride}th of {len(motion):,} samples)"
    if n == 2:
        fig = plt.figure(figsize=(9, 4.2))
        polar = fig.add_subplot(1, 2, 1, projection="polar")
        angle = torch.atan2(m[:, 1], m[:, 0])
        polar.plot(angle, m.norm(dim=1), "o", markersize=3, label="recovered")
        circle = torch.linspace(0, 2 * math.pi, 200)
        polar.plot(circle, torch.full_like(circle, magnitude), "k--", linewidth=0.8, label=f"{magnitude:g} {unit}")
        polar.set_rmin(0)
        polar.legend(loc="lower right", fontsize=8)
        # The magnitude error against direction: 1 % noise is invisible on the polar plot.
        ax = fig.add_subplot(1, 2, 2)
        ax.plot(torch.rad2deg(angle), deviation, "o", markersize=3)
        ax.axhline(0, color="k", linewidth=0.8, linestyle="--")
        ax.set_xlabel("direction (deg)")
        ax.set_ylabel("|load| / F - 1 (%)")
        ax.set_xlim(-180, 180)
        fig.tight_layout()
    elif n == 3:
        fig = plt.figure(figsize=(6, 5))
        ax = fig.add_subplot(projection="3d")
        u, v = torch.meshgrid(torch.linspace(0, 2 * math.pi, 24), torch.linspace(0, math.pi, 12), indexing="ij")
        ax.plot_wireframe(
            magnitude * u.cos() * v.sin(), magnitude * u.sin() * v.sin(), magnitude * v.cos(),
            color="0.8", linewidth=0.5,
        )
        points = ax.scatter(m[:, 0], m[:, 1], m[:, 2], s=6, c=deviation, cmap="coolwarm")
        fig.colorbar(points, ax=ax, shrink=0.6, label="|load| / F - 1 (%)")
        ax.set_xlabel(f"fx ({unit})")
        ax.set_ylabel(f"fy ({unit})")
        ax.set_zlabel(f"fz ({unit})")
        ax.set_box_aspect((1, 1, 1))
    else:
        return None
    fig.suptitle(title, fontsize=10)
    return fig


def spectrum_figure(singular_values: torch.Tensor, rank: int, title: str) -> Figure:
    """Singular values on a log scale, the kept rank marked; the gap after it says how well the data is rank n."""
    s = singular_values.detach().cpu()
    fig, ax = plt.subplots(figsize=(5, 3.5))
    index = torch.arange(1, len(s) + 1)
    colours = ["tab:blue" if i <= rank else "tab:gray" for i in index.tolist()]
    ax.bar(index, s.clamp_min(1e-300), color=colours)
    ax.set_yscale("log")
    ax.axvline(rank + 0.5, color="tab:red", linestyle="--", linewidth=1, label=f"rank {rank}")
    ax.set_xlabel("index")
    ax.set_ylabel("singular value")
    ax.set_xticks(index)
    ax.legend(fontsize=8)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def commands_figure(
    period: float, names: list[str], human: np.ndarray, learned: np.ndarray, confidence: np.ndarray, title: str
) -> Figure:
    """The paper's Fig. 6: human and learnt commands over time on one test run, with the learner's confidence.

    Args:
        period: seconds per sample; names: the ``c`` command names.
        human, learned: ``t x c`` command values (labels; text labels are drawn by their index).
        confidence: ``t``.
    """
    t = np.arange(len(human)) * period
    fig, axes = plt.subplots(len(names) + 1, 1, figsize=(9, 1.8 * (len(names) + 1)), sharex=True)
    for axis, name, h, l in zip(axes, names, human.T, learned.T):
        levels = sorted(set(h.tolist()) | set(l.tolist()), key=str)
        numeric = all(isinstance(v, (int, float, np.integer, np.floating)) for v in levels)
        position = {v: (v if numeric else i) for i, v in enumerate(levels)}
        axis.step(t, [position[v] for v in h], where="post", color="black", linewidth=1.2, label="human")
        axis.step(t, [position[v] for v in l], where="post", color="tab:orange", linewidth=1.0, linestyle="--", label="learnt")
        axis.set_yticks(sorted(position.values()), [str(v) for v in sorted(position, key=position.get)])
        axis.set_ylabel(name)
        axis.legend(loc="upper right", fontsize=8)
    axes[-1].plot(t, confidence, color="tab:green", linewidth=0.8)
    axes[-1].set_ylabel("confidence")
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


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
    bottom.set_ylabel("motion statistic")
    bottom.set_xlabel("time (s)" if timed else "row")
    bottom.set_xlim(x[0], to_x(edges[-1] - 1))
    bottom.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig
