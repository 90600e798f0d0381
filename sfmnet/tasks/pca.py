"""The PCA task: a row file's principal components from one streamed pass, on one or several processes.

Run directory (written by the first process only)::

    pca.npz        mean (p), components (k x p, orthonormal rows), singular_values (k, of the centred data), columns
    metrics.json   rows, seconds, explained variance
    tensorboard/pca/
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sfmnet.data.rows import RowData
from sfmnet.io import save_npz_atomic
from sfmnet.models.streaming_pca import StreamingPCA
from sfmnet.tasks.base import FittedMethod, MethodResult, Task


class PcaTask(Task):
    """Principal components of a file too large for memory (``model=pca``)."""

    kind = "pca"
    ignores = {
        "baselines": "fits one model",
        "eval.leave_one_group_out": "has no groups to hold out",
        "ckpt_path": "is one pass of sums, which a checkpoint does not hold (rerun it)",
    }

    def evaluate(self, fitted: FittedMethod, data: RowData) -> MethodResult:
        model: StreamingPCA = fitted.model
        moments = model.moments
        total_variance = float(moments.centred_cross().trace())
        explained = float(model.singular_values.pow(2).sum()) / total_variance if total_variance else 1.0
        metrics = {
            "rows": float(moments.count),
            "fit_seconds": fitted.seconds,
            "processes": float(fitted.trainer.world_size),
            "explained_variance_ratio": explained,
        }
        return MethodResult(fitted.name, metrics, model=model)

    def write(self, results: dict[str, MethodResult], data: RowData, run_dir: Path) -> dict[str, float]:
        main = next(iter(results.values()))
        save_pca(main.model, data.channels, run_dir / "pca.npz")
        return dict(main.metrics)

    def summary(self, results: dict[str, MethodResult], data: RowData) -> list[str]:
        main = next(iter(results.values()))
        m, model = main.metrics, main.model
        return [
            f"  {main.name}: {int(m['rows'])} rows x {len(data.channels)} columns in {m['fit_seconds']:.2f} s on "
            f"{int(m['processes'])} process(es); {model.rank} components explain "
            f"{100 * m['explained_variance_ratio']:.2f} % of the variance"
        ]


def save_pca(model: StreamingPCA, columns: list[str], path: Path) -> None:
    save_npz_atomic(
        path,
        mean=model.mean.detach().numpy(),
        components=model.components.detach().numpy(),
        singular_values=model.singular_values.numpy(),
        columns=np.array(columns),
    )
