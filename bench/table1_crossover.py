"""Where does shape from motion stop beating least squares? Sweeps Table 1's load-application errors.

Runs ``python -m sfmnet train -m experiment=table1`` over one error parameter and several
seeds (each seed is a new simulated sensor and session), then prints, for each value, the
mean over seeds of each method's error and precision averaged over the five test masses (least
squares in both forms: the paper's shape fit and the loads regressed on the readings), and how
often shape from motion is at least as good as the better least-squares form of the same seed. Run by hand:

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
# Column label -> metric prefix: shape from motion, least squares in the paper's form, the load regression.
METHODS = {"SFM": "", "LS": "least_squares/", "Reg": "regression/"}


def mean_over_masses(row: dict[str, str], prefix: str, figure: str) -> float:
    return statistics.fmean(float(row[f"{prefix}eval/{m}/{figure}"]) for m in MASSES)


def summarise(rows: list[dict[str, str]], parameter: str) -> list[str]:
    """One Markdown row per value: each method's error % and std dev (means over masses, then seeds) and how
    many seeds shape from motion is at least as accurate (precise) as the better least-squares form in that seed."""
    groups: dict[str, list[dict[str, str]]] = defaultdict(list)
    for row in rows:
        groups[row[parameter]].append(row)
    lines = [
        f"| {parameter} | SFM error % | LS error % | Reg error % | SFM std | LS std | Reg std "
        "| SFM as accurate as the better LS | SFM as precise as the better LS |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for value in sorted(groups, key=float):
        group = groups[value]
        err = {m: [mean_over_masses(r, prefix, "error_pct") for r in group] for m, prefix in METHODS.items()}
        std = {m: [mean_over_masses(r, prefix, "std_dev") for r in group] for m, prefix in METHODS.items()}
        accurate = sum(s <= min(l, g) for s, l, g in zip(err["SFM"], err["LS"], err["Reg"]))
        precise = sum(s <= min(l, g) for s, l, g in zip(std["SFM"], std["LS"], std["Reg"]))
        lines.append(
            f"| {value} | " + " | ".join(f"{statistics.fmean(err[m]):.3f}" for m in METHODS) + " | "
            + " | ".join(f"{statistics.fmean(std[m]):.3f}" for m in METHODS)
            + f" | {accurate}/{len(group)} | {precise}/{len(group)} |"
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
