"""Where does shape from motion stop beating least squares? Sweeps Table 1's load-application errors.

Runs ``python -m sfmnet train -m experiment=table1`` over one error parameter and several
seeds (each seed is a new simulated sensor and session), then prints, for each value, the
mean over seeds of each method's error and precision averaged over the five test masses, and
how often shape from motion is at least as good. Run by hand:

    python bench/table1_crossover.py data.errors.string_misalignment_deg=0,0.5,1,2,4
    python bench/table1_crossover.py data.errors.friction=0,0.003,0.01,0.03 --seeds 8
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

MASSES = ["60.4", "78.3", "95.2", "111.4", "122.8"]


def mean_over_masses(row: dict[str, str], prefix: str, figure: str) -> float:
    return statistics.fmean(float(row[f"{prefix}eval/{m}/{figure}"]) for m in MASSES)


def summarise(rows: list[dict[str, str]], parameter: str) -> list[str]:
    groups: dict[str, list[dict[str, str]]] = defaultdict(list)
    for row in rows:
        groups[row[parameter]].append(row)
    lines = [
        f"| {parameter} | SFM error % | LS error % | SFM std | LS std | SFM as accurate | SFM as precise |",
        "|---|---|---|---|---|---|---|",
    ]
    for value in sorted(groups, key=float):
        group = groups[value]
        sfm_err = [mean_over_masses(r, "", "error_pct") for r in group]
        ls_err = [mean_over_masses(r, "least_squares/", "error_pct") for r in group]
        sfm_std = [mean_over_masses(r, "", "std_dev") for r in group]
        ls_std = [mean_over_masses(r, "least_squares/", "std_dev") for r in group]
        accurate = sum(s <= l for s, l in zip(sfm_err, ls_err))
        precise = sum(s <= l for s, l in zip(sfm_std, ls_std))
        lines.append(
            f"| {value} | {statistics.fmean(sfm_err):.3f} | {statistics.fmean(ls_err):.3f} | "
            f"{statistics.fmean(sfm_std):.3f} | {statistics.fmean(ls_std):.3f} | "
            f"{accurate}/{len(group)} | {precise}/{len(group)} |"
        )
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("sweep", help="one Hydra sweep override, e.g. data.errors.friction=0,0.01")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("overrides", nargs="*", help="more fixed overrides")
    args = parser.parse_args()
    parameter = args.sweep.split("=", 1)[0]
    with tempfile.TemporaryDirectory() as scratch:
        sweep_dir = Path(scratch) / "sweep"
        command = [
            sys.executable, "-m", "sfmnet", "train", "-m", "experiment=table1", args.sweep,
            "seed=" + ",".join(str(s) for s in range(args.seeds)), f"hydra.sweep.dir={sweep_dir}",
            "trainer.enable_progress_bar=false", *args.overrides,
        ]
        print("$", " ".join(command[1:]), file=sys.stderr)
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        rows = list(csv.DictReader((sweep_dir / "sweep.csv").open()))
    print("\n".join(summarise(rows, parameter)))


if __name__ == "__main__":
    main()
