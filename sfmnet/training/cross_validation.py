"""Leave-one-group-out errors (e.g. leave one pose out on real recordings): every method refitted per fold."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from hydra.utils import instantiate
from matplotlib import pyplot as plt
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from omegaconf import DictConfig

from sfmnet.data.calibration_datamodule import FixedCalibrationDataModule
from sfmnet.data.recording import CalibrationData
from sfmnet.errors import SfmnetError
from sfmnet.eval.figures import OUTSIDE_RIGHT
from sfmnet.eval.held_out import load_errors
from sfmnet.io import write_csv_atomic
from sfmnet.training.fitting import fit
from sfmnet.training.progress import each_with_progress


@dataclass(frozen=True)
class FoldError:
    method: str
    group: int
    rows: int
    errors: dict[str, float]


def known_load_groups(data: CalibrationData, recording: str) -> list[int]:
    """Groups of ``recording`` holding a known load: they fix the frame, so they are in every fit and never held out."""
    rec = data.recordings[recording]
    if rec.groups is None:
        raise SfmnetError(
            "eval.leave_one_group_out holds out one group (pose) at a time, and this data has none: give the poses "
            "(data.group_column=..., or a continuous recording's static intervals) or drop eval.leave_one_group_out"
        )
    return sorted(set(rec.groups[rec.known].tolist()))


def held_out_groups(data: CalibrationData, recording: str) -> list[int]:
    """Groups of ``recording`` with no known load: holding out a known pose would change the method, not test it."""
    known = known_load_groups(data, recording)
    return sorted(set(data.recordings[recording].groups.tolist()) - set(known))


def leave_one_group_out(
    cfg: DictConfig, data: CalibrationData, models: dict[str, DictConfig], main_recording: str, progress: bool
) -> list[FoldError]:
    """Refit every method without each held-out group and measure its load error on that group.

    The groups held out are those of the main method's recording that carry no known load,
    so every method is scored on the same rows. The error is against the rows' true loads.
    """
    folds = []
    for group in each_with_progress(held_out_groups(data, main_recording), "leave one group out", progress):
        fold = FixedCalibrationDataModule(data.without_group(group))
        for name, model_cfg in models.items():
            model = instantiate(model_cfg)
            fit(model, cfg, fold, logger=False, enable_checkpointing=False, enable_progress_bar=False, callbacks=[])
            recording = data.recordings[model.recording]
            held = recording.groups == group
            truth = recording.true_loads if recording.true_loads is not None else recording.loads
            calibration = model.to_calibration(data.channels, data.axes)
            errors = load_errors(calibration, recording.readings[held], truth[held])
            folds.append(FoldError(name, group, int(held.sum()), errors))
    return folds


def summarise_folds(folds: list[FoldError]) -> dict[str, dict[str, float]]:
    """Per method, the RMS over all held-out rows: ``{method: {force_rms, [torque_rms]}}``."""
    summary: dict[str, dict[str, float]] = {}
    for method in dict.fromkeys(f.method for f in folds):
        mine = [f for f in folds if f.method == method]
        rows = sum(f.rows for f in mine)
        summary[method] = {
            key: (sum(f.errors[key] ** 2 * f.rows for f in mine) / rows) ** 0.5 for key in mine[0].errors
        }
    return summary


def write_folds(folds: list[FoldError], path: Path) -> None:
    keys = list(folds[0].errors)
    write_csv_atomic(path, ["method", "group", "rows", *keys], [[f.method, f.group, f.rows, *f.errors.values()] for f in folds])


def folds_figure(folds: list[FoldError], unit: str, known_groups: list[int]) -> Figure:
    """Held-out force (and torque) error per group, methods side by side; the known-load groups, never held out, marked.

    Args:
        unit: the load unit, ``"<force unit>[, <torque unit>]"``.
        known_groups: groups with a known load (in every fit, so they have no held-out error).
    """
    keys = list(folds[0].errors)
    force_unit, _, torque_unit = unit.partition(", ")
    units = {"force_rms": force_unit, "torque_rms": torque_unit}
    labels = {"force_rms": "held-out force error", "torque_rms": "held-out torque error"}
    methods = list(dict.fromkeys(f.method for f in folds))
    groups = sorted({f.group for f in folds} | set(known_groups))
    slot = {g: i for i, g in enumerate(groups)}
    figure, axes = plt.subplots(1, len(keys), figsize=(5.5 * len(keys) + 1.5, 3.6), squeeze=False)
    width = 0.8 / len(methods)
    for axis, key in zip(axes[0], keys):
        for i, method in enumerate(methods):
            mine = [f for f in folds if f.method == method]
            positions = [slot[f.group] - 0.4 + (i + 0.5) * width for f in mine]
            axis.bar(positions, [f.errors[key] for f in mine], width=width, label=method.replace("_", " "))
        for group in known_groups:
            axis.axvspan(slot[group] - 0.45, slot[group] + 0.45, color="0.88", linewidth=0)
            axis.text(slot[group], 0.5, "known load", rotation=90, ha="center", va="center", fontsize=8, color="0.35",
                      transform=axis.get_xaxis_transform())
        axis.set_xticks(range(len(groups)), [str(g) for g in groups])
        axis.set_xlim(-0.6, len(groups) - 0.4)
        axis.set_xlabel("held-out group (pose number)")
        axis.set_ylabel(f"{labels.get(key, key)}, RMS ({units.get(key, unit)})")
    handles, _ = axes[0][-1].get_legend_handles_labels()
    if known_groups:
        handles.append(Patch(color="0.88", label="known load:\nin every fit, not held out"))
    axes[0][-1].legend(handles=handles, **OUTSIDE_RIGHT)
    figure.suptitle("Leave one group out: each method refitted without a group, scored on it")
    figure.tight_layout()
    return figure
