"""Which of a run's metrics are its headline figures: the columns of TensorBoard's HParams view and of a sweep's table.

They are the figures the tasks' summary lines print (:mod:`sfmnet.tasks`), for every kind of run;
a baseline's are the same names under its prefix (``least_squares/eval/max_error_pct``).
"""

from __future__ import annotations

import re
from collections.abc import Iterable

# In the order a table shows them; ``*`` stands for any characters but "/".
HEADLINE_METRICS = (
    # calibration
    "eval/max_error_pct", "eval/max_std_dev", "lopo/force_rms", "lopo/torque_rms", "test/force_rms", "test/torque_rms",
    "test/magnitude_rms", "matrix_error_relative", "matrix_std_relative", "matrix_std_frame_share", "coverage", "rank_gap", "goodness/outliers",
    # sensorimotor learning (per command)
    "rank", "*_accuracy", "*_kappa", "*_when_f1", "confidence_auroc", "subspace_angle_deg",
    # sensorimotor learning, closed loop (per policy)
    "closed_loop/*/moving_fraction", "closed_loop/*/escape_rate", "closed_loop/*/bumps_per_minute",
    # PCA
    "explained_variance_ratio",
)
PATTERNS = tuple(re.compile(re.escape(pattern).replace(r"\*", "[^/]*")) for pattern in HEADLINE_METRICS)


def headline_position(figure: str) -> int | None:
    """The position of ``figure`` (a metric name without a method prefix) in :data:`HEADLINE_METRICS`, or None."""
    return next((i for i, pattern in enumerate(PATTERNS) if pattern.fullmatch(figure)), None)


def headline_keys(keys: Iterable[str]) -> list[str]:
    """The headline figures among metric names ``keys`` (``metrics.json``'s): the main method's first, then each
    baseline's, each in :data:`HEADLINE_METRICS` order."""
    ranked = []
    methods: dict[str, int] = {"": 0}
    for order, key in enumerate(keys):
        prefix, _, figure = key.partition("/")
        for method, name in (("", key), (prefix, figure)):
            position = headline_position(name) if name else None
            if position is not None:
                ranked.append(((methods.setdefault(method, len(methods)), position, order), key))
                break
    return [key for _, key in sorted(ranked)]
