"""Robot-wrist logs whose poses stay in a cone below the sensor, by ``auto`` and by the penalised fit. Run by hand:

    python bench/cone_logs.py [--seeds 0 1 2 3 4 5 6 7] [--cones 45 30]

Each log (sfmnet/simulators/wrist_log.py: 8 channels, 12 poses held 2 s at 200 Hz with 1.5 s moves between them, SNR
about 1,500, three known poses) goes through ``sfmnet.calibrate`` with its time column, as a user's would: ``auto``
(the alternation at this SNR) and ``model.refinement=penalty`` (L-BFGS on the same loss, the baseline). On a cap of
directions with offsets the loss is a long curved valley (method §5). Printed per log: each fit's matrix error (the
Frobenius norm over the truth's), its bars (``|matrix_std|_F`` over the same) and whether the run trusts them, and
``auto``'s error over the penalised fit's. Logs the readings cannot place (too few spanned axes, contradicting known
loads) are refused by both and listed as such.
"""

from __future__ import annotations

import argparse
import logging
import warnings

import numpy as np

import sfmnet
from sfmnet.simulators.wrist_log import wrist_log


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(range(8)))
    parser.add_argument("--cones", type=float, nargs="+", default=[45.0, 30.0])
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    logging.disable(logging.WARNING)
    print("| cone | seed | auto error % | auto bars % | trusted | penalty error % | penalty bars % | trusted "
          "| auto / penalty |")
    print("|---|---|---|---|---|---|---|---|---|")
    ratios = []
    for cone in args.cones:
        for seed in args.seeds:
            log = wrist_log(seed, cone)
            row = []
            try:
                for options in ({}, {"model.refinement": "penalty"}):
                    calibration = sfmnet.calibrate(log.readings, log.magnitude, log.loads, time=log.time, **options)
                    scale = np.linalg.norm(log.matrix)
                    row.append((np.linalg.norm(calibration.matrix - log.matrix) / scale,
                                np.linalg.norm(calibration.matrix_std) / scale, calibration.error_bars_trustworthy))
            except sfmnet.SfmnetError as error:
                print(f"| {cone:g} | {seed} | refused: {str(error)[:90]}... | | | | | | |")
                continue
            (auto, auto_bars, auto_trusted), (penalty, penalty_bars, penalty_trusted) = row
            ratios.append(auto / penalty)
            print(f"| {cone:g} | {seed} | {100 * auto:.2f} | {100 * auto_bars:.2f} | {'yes' if auto_trusted else 'no'} "
                  f"| {100 * penalty:.2f} | {100 * penalty_bars:.2f} | {'yes' if penalty_trusted else 'no'} "
                  f"| {auto / penalty:.2f} |")
    if ratios:
        print(f"\nauto / penalty over {len(ratios)} logs: median {np.median(ratios):.2f}, worst {max(ratios):.2f}")


if __name__ == "__main__":
    main()
