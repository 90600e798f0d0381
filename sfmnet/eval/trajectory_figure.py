"""The closed-loop figure: where each policy drove the MK-V in one test room (sfmnet.eval.closed_loop)."""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Circle, Rectangle

from sfmnet.eval.closed_loop import in_contact, onsets
from sfmnet.simulators.mkv_robot import Room, Run

COLUMNS = 3
# Panel size and the margins around panels, inches (fixed: a layout engine costs a second a figure).
PANEL = (3.8, 3.0)
TOP, BOTTOM, LEFT, RIGHT, BETWEEN_ROWS, BETWEEN_COLUMNS = 1.2, 0.9, 0.6, 0.2, 1.25, 0.6


def trajectory_figure(room: Room, runs: dict[str, list[Run]], captions: dict[str, str], title: str) -> Figure:
    """One panel per policy: the room's walls and obstacles, each run's path from the centre, where bumps began.

    Args:
        room: the room every run drove in.
        runs: by policy, its runs in this room (the same starts for every policy).
        captions: by policy, a line under its name (e.g. its closed-loop figures).
        title: the figure's title.
    """
    rows = math.ceil(len(runs) / COLUMNS)
    columns = min(COLUMNS, len(runs))
    width = LEFT + RIGHT + columns * PANEL[0] + (columns - 1) * BETWEEN_COLUMNS
    height = TOP + BOTTOM + rows * PANEL[1] + (rows - 1) * BETWEEN_ROWS
    fig, axes = plt.subplots(rows, columns, figsize=(width, height), squeeze=False)
    fig.subplots_adjust(
        left=LEFT / width, right=1 - RIGHT / width, bottom=BOTTOM / height, top=1 - TOP / height,
        wspace=BETWEEN_COLUMNS / PANEL[0], hspace=BETWEEN_ROWS / PANEL[1],
    )
    colours = plt.get_cmap("tab10").colors
    for ax, (policy, policy_runs) in zip(axes.flat, runs.items()):
        ax.add_patch(Rectangle((0, 0), room.width, room.depth, fill=False, edgecolor="black", linewidth=1.2))
        for x, y, radius in room.obstacles:
            ax.add_patch(Circle((x, y), radius, facecolor="0.75", edgecolor="0.4"))
        for number, run in enumerate(policy_runs):
            colour = colours[number % len(colours)]
            x, y = run.poses[:, 0], run.poses[:, 1]
            ax.plot(x, y, color=colour, linewidth=1.0)
            ax.plot(x[-1], y[-1], "o", color=colour, markersize=5)
            bumps = onsets(in_contact(run))
            ax.plot(x[bumps], y[bumps], "x", color="red", markersize=6, markeredgewidth=1.5)
        ax.plot(room.width / 2, room.depth / 2, "k^", markersize=7)
        ax.set_xlim(-0.2, room.width + 0.2)
        ax.set_ylim(-0.2, room.depth + 0.2)
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_title(f"{policy.replace('_', ' ')}\n{captions.get(policy, '')}", fontsize=9)
    for ax in axes.flat[len(runs) :]:
        ax.axis("off")
    longest = max(len(policy_runs) for policy_runs in runs.values())
    handles = [Line2D([], [], color=colours[i % len(colours)], label=f"run {i + 1}") for i in range(longest)]
    handles += [
        Line2D([], [], marker="^", color="black", linestyle="", label="start (room centre)"),
        Line2D([], [], marker="o", color="0.3", linestyle="", label="end of run"),
        Line2D([], [], marker="x", color="red", linestyle="", label="bump (switch closes)"),
        Line2D([], [], marker="o", color="0.75", markeredgecolor="0.4", linestyle="", markersize=9, label="obstacle"),
    ]
    fig.legend(handles=handles, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncol=len(handles), fontsize=8, frameon=False)
    fig.suptitle(title)
    return fig
