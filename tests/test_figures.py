"""Figures a reader can put in a paper, checked on matplotlib's objects before they are saved: a unit on
every axis, legends clear of the data, a diverging colour map centred on 0, commands as a raster of
levels, the poses that were never held out marked."""

from __future__ import annotations

import re

import matplotlib.pyplot as plt
import numpy as np
import pytest
import torch
from matplotlib.axes import Axes
from matplotlib.collections import PolyCollection
from matplotlib.figure import Figure

from sfmnet.eval.figures import commands_figure, level_runs, method_title, motion_figure, ordinal, spectrum_figure
from sfmnet.training.cross_validation import FoldError, folds_figure

UNIT = re.compile(r"\(.+\)")


def circle_of_loads(n: int, magnitude: float = 9.81, rows: int = 60) -> torch.Tensor:
    """``rows x n`` loads of about ``magnitude`` in directions spread over the circle or sphere."""
    generator = torch.Generator().manual_seed(0)
    directions = torch.randn(rows, n, generator=generator, dtype=torch.float64)
    directions /= directions.norm(dim=1, keepdim=True)
    return directions * magnitude * (1 + 0.01 * torch.randn(rows, 1, generator=generator, dtype=torch.float64))


def data_axes(figure: Figure) -> list[Axes]:
    """The axes that hold data (a colour bar's axes excluded)."""
    return [axis for axis in figure.axes if axis.get_label() != "<colorbar>"]


def assert_units_and_legends_outside(figure: Figure) -> None:
    """Each data axes' y label (the bottom one's x label) names a unit; no legend overlaps any data axes."""
    figure.canvas.draw()
    axes = [axis for axis in data_axes(figure) if axis.name != "polar"]
    for axis in axes:
        assert UNIT.search(axis.get_ylabel()), f"no unit in y label {axis.get_ylabel()!r}"
    assert UNIT.search(axes[-1].get_xlabel()), f"no unit in x label {axes[-1].get_xlabel()!r}"
    legends = [axis.get_legend() for axis in figure.axes if axis.get_legend() is not None]
    assert legends, "no legend"
    for legend in legends:
        box = legend.get_window_extent()
        for axis in data_axes(figure):
            assert not box.overlaps(axis.get_window_extent()), f"legend over the data of {axis.get_title() or axis.name}"


def test_polar_motion_figure_has_units_on_its_radial_ticks_and_its_legend_outside():
    figure = motion_figure(circle_of_loads(2, 111.4), 111.4, "gf", "Shape from motion: calibrated loads")
    assert_units_and_legends_outside(figure)
    polar = next(axis for axis in figure.axes if axis.name == "polar")
    labels = [label.get_text() for label in polar.get_yticklabels() if label.get_text()]
    assert labels and all(label.endswith(" gf") for label in labels), labels
    # The radial tick labels stay inside the circle the samples lie on.
    assert max(polar.get_yticks()) < 111.4
    plt.close(figure)


def test_sphere_colour_map_is_centred_on_zero():
    figure = motion_figure(circle_of_loads(3), 9.81, "N", "Shape from motion: calibrated loads", ["fx", "fy", "fz"])
    scatter = next(c for axis in figure.axes for c in axis.collections if c.get_array() is not None)
    assert scatter.norm.vmin == -scatter.norm.vmax != 0
    assert all(UNIT.search(label) for label in (figure.axes[0].get_xlabel(), figure.axes[0].get_zlabel()))
    plt.close(figure)


def test_spectrum_figure_labels_and_legend():
    figure = spectrum_figure(torch.tensor([50.0, 20.0, 10.0, 0.1, 0.05]), 3, "Shape from motion: singular values", "raw reading units")
    assert_units_and_legends_outside(figure)
    assert figure.axes[0].get_ylabel() == "singular value (raw reading units)"
    plt.close(figure)


def test_commands_are_a_raster_of_levels_not_a_line():
    levels = ["Move-Forward", "Sharp-Right-Turn", "Slight-Left-Turn"]
    human = np.array(["Move-Forward"] * 5 + ["Slight-Left-Turn"] * 3 + ["Move-Forward"] * 2, dtype=object)[:, None]
    learned = np.array(["Move-Forward"] * 4 + ["Sharp-Right-Turn"] * 6, dtype=object)[:, None]
    confidence = np.linspace(0.5, 0.9, 10)
    figure = commands_figure(0.5, ["OUTPUT"], [levels], human, learned, confidence, "Eigenspace: commands")
    assert_units_and_legends_outside(figure)
    commands = figure.axes[0]
    # No line joins one level to another: the levels have no order a line could show.
    assert not commands.get_lines()
    assert [label.get_text() for label in commands.get_yticklabels()] == levels
    bars = [c for c in commands.collections if isinstance(c, PolyCollection)]
    # One band per level and person; each band's bars cover the time that person chose that level.
    covered = {}
    for bar in bars:
        bottom = round(float(bar.get_paths()[0].vertices[:, 1].min()), 2) if bar.get_paths() else None
        covered[bottom] = sum(float(np.ptp(path.vertices[:, 0])) for path in bar.get_paths())
    assert len(bars) == 2 * len(levels)
    assert covered[0.02] == pytest.approx(3.5) and covered[-0.42] == pytest.approx(2.0)  # Move-Forward
    assert covered[0.58] == pytest.approx(3.0) and covered[2.02] == pytest.approx(1.5)  # Sharp-Right, Slight-Left
    plt.close(figure)


def test_level_runs():
    chosen = np.array([False, True, True, False, True])
    assert level_runs(chosen, np.arange(6) * 0.5) == [(0.5, 1.0), (2.0, 0.5)]
    assert level_runs(np.zeros(3, dtype=bool), np.arange(4.0)) == []


def test_leave_one_out_marks_the_known_poses():
    folds = [
        FoldError(method, group, 10, {"force_rms": 0.1 * group, "torque_rms": 0.01 * group})
        for method in ("shape_from_motion", "least_squares")
        for group in (1, 2, 3, 5)
    ]
    figure = folds_figure(folds, "N, N m", known_groups=[0, 4])
    assert_units_and_legends_outside(figure)
    for axis in figure.axes:
        assert [label.get_text() for label in axis.get_xticklabels()] == ["0", "1", "2", "3", "4", "5"]
        assert [text.get_text() for text in axis.texts] == ["known load", "known load"]
    assert [axis.get_ylabel() for axis in figure.axes] == ["held-out force error, RMS (N)", "held-out torque error, RMS (N m)"]
    assert any("known load" in text.get_text() for text in figure.axes[-1].get_legend().get_texts())
    plt.close(figure)


def test_titles_in_words():
    assert method_title("shape_from_motion") == "Shape from motion"
    assert [ordinal(k) for k in (1, 2, 3, 4, 11, 12, 13, 21, 22, 101, 111)] == [
        "1st", "2nd", "3rd", "4th", "11th", "12th", "13th", "21st", "22nd", "101st", "111th"
    ]
