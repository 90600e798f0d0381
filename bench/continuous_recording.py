"""A continuous recording calibrated with and without static-interval detection (issue "Real recordings"). Run by hand:

    python bench/continuous_recording.py                       # seeds 0 1 2, orientations uniform and below
    python bench/continuous_recording.py --seeds 0 --laws below

A simulated 3-axis sensor with 8 channels and offsets (sfmnet/simulators/simulated_stream.py) carries
a 0.8 kg mass (7.85 N) through 30 poses held 2 s each with 1.5 s minimum-jerk moves between
them (43 % of the rows in motion), 3 of the poses known (load columns filled on their static
rows), 100 Hz. Each is calibrated through the real CLI (``python -m sfmnet train
experiment=calibrate_csv ... data.time_column=time``):

- ``(a) detected``: the default, static intervals found and the rows in motion left out;
- ``(b) every row``: ``data.static_intervals=false``;
- ``(c) true static``: only the true static rows, written to a second CSV (detection off).

The force error is the RMS over the true static rows of a fresh recording of the same sensor
(other poses), in N; ``a/c`` must stay at or below 1.25. "found" is the number of intervals
detected against the true number; "ends" the largest distance of a detected interval's ends
from the true ones, in rows (the window is 51 rows). "trusted": the runs whose error bars the run calls trustworthy
(every goodness-of-fit check passed). ``--noise`` sets the noise over the signal (default 0.0005, an SNR of 2,000).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

from sfmnet.calibration import Calibration
from sfmnet.simulators.simulated_stream import simulate_stream, stream_sensor, write_stream_csv
from sfmnet.linalg.wrench import STANDARD_GRAVITY

REPO = Path(__file__).resolve().parent.parent
MASS = 0.8


def calibrate(session: Path, run_dir: Path, *overrides: str) -> Calibration:
    command = [
        sys.executable, "-m", "sfmnet", "train", "experiment=calibrate_csv", f"data.path={session}",
        "data.time_column=time", f"data.magnitude={MASS * STANDARD_GRAVITY}", "data.load_columns=[fx,fy,fz]",
        f"hydra.run.dir={run_dir}", "trainer.enable_progress_bar=false", *overrides,
    ]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)} failed:\n{done.stderr}")
    return Calibration.load(run_dir / "calibration.json")


def force_error(calibration: Calibration, readings: torch.Tensor, loads: torch.Tensor) -> float:
    return float((calibration.apply(readings) - loads).pow(2).sum(dim=1).mean().sqrt())


def run(seed: int, law: str, noise: float, folder: Path, detection: list[str]) -> dict[str, object]:
    generator = torch.Generator().manual_seed(seed)
    sensor = stream_sensor(8, MASS * STANDARD_GRAVITY, noise_fraction=noise, offset_scale=0.2, generator=generator)
    recording = simulate_stream(sensor, MASS, orientation=law, generator=generator)
    test = simulate_stream(sensor, MASS, orientation=law, generator=generator)
    stream, static_only = folder / f"stream-{law}-{seed}.csv", folder / f"static-{law}-{seed}.csv"
    write_stream_csv(recording, stream)
    write_stream_csv(recording, static_only, rows=recording.static)
    runs = {
        "a": calibrate(stream, folder / f"a-{law}-{seed}", *detection),
        "b": calibrate(stream, folder / f"b-{law}-{seed}", "data.static_intervals=false"),
        "c": calibrate(static_only, folder / f"c-{law}-{seed}", "data.static_intervals=false"),
    }
    errors = {name: force_error(c, test.readings[test.static], test.loads[test.static]) for name, c in runs.items()}
    metrics = json.loads((folder / f"a-{law}-{seed}" / "metrics.json").read_text())
    found = np.loadtxt(folder / f"a-{law}-{seed}" / "static_intervals.csv", delimiter=",", skiprows=1, ndmin=2)
    true = recording.intervals.numpy()
    ends = "-"
    if len(found) == len(true):
        ends = str(int(max(np.abs(found[:, 1] - true[:, 0]).max(), np.abs(found[:, 2] + 1 - true[:, 1]).max())))
    return {
        "law": law, "seed": seed, **errors, "ratio": errors["a"] / errors["c"],
        "found": f"{int(metrics['static/intervals'])}/{len(true)}", "ends": ends,
        "kept": f"{int(metrics['static/rows_kept'])}/{int(metrics['static/rows_total'])}",
        "trusted": "".join(name for name, c in runs.items() if c.error_bars_trustworthy) or "-",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--laws", nargs="+", default=["uniform", "below"])
    parser.add_argument("--noise", type=float, default=0.0005, help="noise std over the signal (1 / SNR)")
    parser.add_argument("--detection", nargs="*", default=[], help="overrides for (a), e.g. data.static.threshold=2")
    args = parser.parse_args()
    print(f"{'law':8} {'seed':>4} {'(a) detected':>13} {'(b) every row':>14} {'(c) true static':>16} {'a/c':>6} {'found':>7} {'ends':>5} {'rows kept':>12} {'trusted':>8}")
    with tempfile.TemporaryDirectory() as folder:
        for law in args.laws:
            for seed in args.seeds:
                r = run(seed, law, args.noise, Path(folder), args.detection)
                print(
                    f"{r['law']:8} {r['seed']:>4} {r['a']:>11.4f} N {r['b']:>12.4f} N {r['c']:>14.4f} N {r['ratio']:>6.3f} "
                    f"{r['found']:>7} {r['ends']:>5} {r['kept']:>12} {r['trusted']:>8}",
                    flush=True,
                )


if __name__ == "__main__":
    main()
