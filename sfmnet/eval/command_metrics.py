"""How well learnt commands agree with the teleoperator's (method §8): agreement, kappa, when and which way."""

from __future__ import annotations

import numpy as np

from sfmnet.data.sensorimotor import Command


def accuracy(truth: np.ndarray, predicted: np.ndarray) -> float:
    return float((truth == predicted).mean())


def cohen_kappa(truth: np.ndarray, predicted: np.ndarray) -> float:
    """Agreement beyond chance: ``(p_o - p_e) / (1 - p_e)``, ``p_e`` from the two label frequencies; NaN (undefined)
    where both give one label throughout, so that chance agrees fully."""
    labels = np.union1d(truth, predicted)
    observed = (truth == predicted).mean()
    expected = sum((truth == label).mean() * (predicted == label).mean() for label in labels)
    return float((observed - expected) / (1 - expected)) if expected < 1 else float("nan")


def when_f1(truth: np.ndarray, predicted: np.ndarray) -> float:
    """F1 of "acting" (``!= 0``), whatever the direction: does the learner act when the human does? NaN (undefined)
    where neither ever acts."""
    true_act, predicted_act = truth != 0, predicted != 0
    hits = (true_act & predicted_act).sum()
    total = true_act.sum() + predicted_act.sum()
    return float(2 * hits / total) if total else float("nan")


def direction_accuracy(truth: np.ndarray, predicted: np.ndarray) -> float:
    """Sign agreement where both act (NaN where they never do together)."""
    both = (truth != 0) & (predicted != 0)
    return float((np.sign(truth[both]) == np.sign(predicted[both])).mean()) if both.any() else float("nan")


def auroc(scores: np.ndarray, positives: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` for flagging ``positives`` (Mann-Whitney, ties counted half); NaN
    (undefined) without both classes, or where every score is the same (a learner with no confidence to rank by)."""
    positives = positives.astype(bool)
    if positives.all() or not positives.any() or np.ptp(scores) == 0:
        return float("nan")
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(len(scores))
    sorted_scores = scores[order]
    # Average ranks over ties.
    _, first, counts = np.unique(sorted_scores, return_index=True, return_counts=True)
    for start, count in zip(first, counts):
        ranks[order[start : start + count]] = start + (count + 1) / 2
    n_pos, n_neg = positives.sum(), (~positives).sum()
    return float((ranks[positives].sum() - n_pos * (n_pos + 1) / 2) / (n_pos * n_neg))


def command_metrics(
    commands: list[Command], truth: np.ndarray, predicted: np.ndarray, confidence: np.ndarray
) -> dict[str, float]:
    """Per command ``<name>_accuracy`` and ``<name>_kappa``; for reverse/off/forward commands also
    ``<name>_when_f1`` and ``<name>_direction_accuracy``; and ``confidence_auroc``: how well low
    confidence flags the samples where any command is wrong.

    Args:
        truth, predicted: ``f x c`` label indices.
        confidence: ``f``.
    """
    metrics: dict[str, float] = {}
    for i, command in enumerate(commands):
        t, p = truth[:, i], predicted[:, i]
        metrics[f"{command.name}_accuracy"] = accuracy(t, p)
        metrics[f"{command.name}_kappa"] = cohen_kappa(t, p)
        if command.signed:
            values = np.array(command.labels)
            metrics[f"{command.name}_when_f1"] = when_f1(values[t], values[p])
            metrics[f"{command.name}_direction_accuracy"] = direction_accuracy(values[t], values[p])
    wrong = (truth != predicted).any(axis=1)
    metrics["confidence_auroc"] = auroc(-confidence, wrong)
    return metrics
