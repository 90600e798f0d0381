"""The closed form's glitch screen (method §2, "A glitch") on spikes it was not tuned on, and on clean sessions whose
right rows lie far from the rest. Run by hand:

    python bench/glitch_screen.py [--sessions 20]

Spikes: 2,400 rows with orientations uniform on the sphere, 6 channels, 3 axes with offsets, a 9.81 load at SNR 20
(or 5); channel 0 of rows 100.. off by each sample's size times the channel's span (a spike lasting 1-3 samples, each
with its own noise). Printed per row: how many sessions' starts (``closed_form_shape``) are bad, refused or over
twice the error (``|S^T S - S_true^T S_true| / |S_true^T S_true|``) the start has without the spike plus 0.01, the
worst start error, and how many sessions left every sample of the spike out.

Clean caps: ``rows`` orientations in a cap about +z and three known loads held once at -x, -y, -z (right rows, far
from the cap). Printed: how many sessions left any row out of the start, and how many refused it.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import torch

from sfmnet.errors import SfmnetError
from sfmnet.linalg.factorisation import closed_form_shape

MAGNITUDE = 9.81
SPIKE_ROW = 100
# (sizes of the spike's samples in spans, SNR)
SPIKES = [
    ([5.0], 20.0),
    ([5.0, 5.0], 20.0),
    ([5.0, 5.0, 5.0], 20.0),
    ([20.0, 20.0], 20.0),
    ([2.0, 2.0], 20.0),
    ([2.0, 2.0, 2.0], 20.0),
    ([5.0, 2.5], 20.0),
    ([5.0, 3.0, 1.5], 20.0),
    ([5.0, 5.0], 5.0),
]
# (cap half-angle in degrees, SNR, rows)
CAPS = [(35.0, 50.0, 1000), (35.0, 20.0, 1000), (35.0, 5.0, 1000), (60.0, 20.0, 100), (45.0, 20.0, 30000)]


def directions(rng: np.random.Generator, rows: int, cap: float | None) -> np.ndarray:
    """``rows x 3`` unit vectors, uniform on the sphere or within ``cap`` degrees of +z."""
    found: list[np.ndarray] = []
    while sum(len(block) for block in found) < rows:
        block = rng.normal(size=(4 * rows, 3))
        block /= np.linalg.norm(block, axis=1, keepdims=True)
        found.append(block if cap is None else block[block[:, 2] > math.cos(math.radians(cap))])
    return np.vstack(found)[:rows]


def session(seed: int, rows: int, snr: float, cap: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Readings ``rows x 6`` and the true shape ``3 x 6``."""
    rng = np.random.default_rng(seed)
    shape = rng.normal(size=(3, 6))
    shape /= np.linalg.norm(shape, axis=0).mean()
    loads = directions(rng, rows, cap)
    if cap is not None:
        loads = np.vstack([loads, -np.eye(3)])
    readings = MAGNITUDE * loads @ shape + 3 * rng.normal(size=6) + MAGNITUDE / snr * rng.normal(size=(len(loads), 6))
    return readings, shape


def start(readings: np.ndarray) -> tuple[np.ndarray | None, list[int]]:
    """The closed form's shape (None where refused) and the rows it left out."""
    try:
        solution = closed_form_shape(torch.from_numpy(readings), 3, MAGNITUDE, offsets=True)
    except SfmnetError:
        return None, []
    return solution.shape.numpy(), torch.nonzero(solution.left_out)[:, 0].tolist()


def gram_error(estimate: np.ndarray | None, truth: np.ndarray) -> float:
    if estimate is None:
        return math.inf
    gram = truth.T @ truth
    return float(np.linalg.norm(estimate.T @ estimate - gram) / np.linalg.norm(gram))


def spike_row(sizes: list[float], snr: float, sessions: int) -> str:
    bad, whole, worst = 0, 0, 0.0
    for seed in range(sessions):
        readings, truth = session(seed, 2400, snr, None)
        rng = np.random.default_rng(1000 + seed)
        span = float(np.ptp(readings[:, 0]))
        rows = list(range(SPIKE_ROW, SPIKE_ROW + len(sizes)))
        readings[rows, 0] += np.array(sizes) * span + MAGNITUDE / snr * rng.normal(size=len(sizes))
        estimate, left_out = start(readings)
        clean, _ = start(np.delete(readings, rows, axis=0))
        error = gram_error(estimate, truth)
        bad += error > 2 * gram_error(clean, truth) + 0.01
        whole += set(rows) <= set(left_out)
        worst = max(worst, error)
    spans = ", ".join(f"{size:g}" for size in sizes)
    return f"| {spans} | {snr:g} | {bad} of {sessions} | {worst:.3g} | {whole} of {sessions} |"


def cap_row(cap: float, snr: float, rows: int, sessions: int) -> str:
    left, refused = 0, 0
    for seed in range(sessions):
        readings, _ = session(seed, rows, snr, cap)
        estimate, left_out = start(readings)
        left += bool(left_out)
        refused += estimate is None
    return f"| {cap:g} | {snr:g} | {rows} | {left} of {sessions} | {refused} of {sessions} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sessions", type=int, default=20)
    args = parser.parse_args()
    print("| spike (spans per sample) | SNR | bad starts | worst start error | left out whole |")
    print("|---|---|---|---|---|")
    for sizes, snr in SPIKES:
        print(spike_row(sizes, snr, args.sessions), flush=True)
    print()
    print("| cap (degrees) | SNR | rows | sessions leaving a row out | refused |")
    print("|---|---|---|---|---|")
    for cap, snr, rows in CAPS:
        print(cap_row(cap, snr, rows, max(2, args.sessions // 4) if rows > 10000 else args.sessions), flush=True)


if __name__ == "__main__":
    main()
