"""Shape-from-motion calibration streamed from disk against the same fit in memory (issue 5, method §11). Run by hand:

    python bench/streamed_calibration.py                 # 1e5, 1e6, 1e7 orientations
    python bench/streamed_calibration.py --rows 1e8      # a 3.6 GB float32 session (streamed only)

A simulated 3-axis session (6 channels, offsets, 1 % noise, three known loads at the end,
each the mean of 1000 samples) is
written once as a float32 ``.npy`` (columns s0..s5, fx, fy, fz; NaN where the load is unknown)
and calibrated by ``python -m sfmnet train``, each run in its own process so its peak resident
memory is its own:

- ``streamed``: ``experiment=calibrate_stream`` (pass 1 moments, pass 2 the metric constraint,
  then one Anderson-accelerated alternation round per pass until a round moves the parameters
  by less than 1e-9);
- ``streamed x2``: the same on two processes (``trainer.devices=2 trainer.strategy=ddp``);
- ``in memory``: ``experiment=calibrate_csv model.refinement=alternation trainer.max_epochs=1``
  (the closed form, then Anderson-accelerated alternation rounds on the whole array to a 1e-9 step);
- ``numpy``: ``bench/numpy_reference.py``, the same algorithm in plain numpy (closed form, plain
  Anderson-accelerated alternation to a 1e-9 step, the matrix's Cramer-Rao error bars; no checks, figures or files).

Seconds are the run start to finish (Python start, reading, fitting, error bars, figures), the median of
``--repeats`` runs of each fit taken in turns; memory is the largest peak of those runs;
ratios are each fit's speed relative to the streamed one measured in the same run
(> 1: faster than streamed). "vs in memory" is the relative difference of the streamed and numpy
matrices from the in-memory one, "error" the streamed matrix's relative error against the simulated truth.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

MAGNITUDE = 9.81
CHANNELS = 6
COLUMNS = [*(f"s{i}" for i in range(CHANNELS)), "fx", "fy", "fz"]


def write_session(path: Path, rows: int, seed: int = 0) -> np.ndarray:
    """The session, block by block; returns the true calibration matrix (3 x 6)."""
    generator = np.random.default_rng(seed)
    shape = generator.normal(size=(3, CHANNELS))
    offset = generator.normal(size=CHANNELS) * 0.2 * MAGNITUDE
    noise = 0.01 * MAGNITUDE * np.sqrt((shape**2).sum(axis=1).mean())
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(rows, len(COLUMNS)))
    step = 1_000_000
    for start in range(0, rows, step):
        count = min(step, rows - start)
        directions = generator.normal(size=(count, 3))
        loads = MAGNITUDE * directions / np.linalg.norm(directions, axis=1, keepdims=True)
        block = np.full((count, len(COLUMNS)), np.nan)
        block[:, :CHANNELS] = loads @ shape + offset + noise * generator.normal(size=(count, CHANNELS))
        out[start : start + count] = block
    known = MAGNITUDE * np.eye(3)
    # Each known load as the mean of 1000 samples at its pose, as one records them.
    out[-3:, :CHANNELS] = known @ shape + offset + noise / np.sqrt(1000) * generator.normal(size=(3, CHANNELS))
    out[-3:, CHANNELS:] = known
    out.flush()
    return np.linalg.pinv(shape).T


def median_run(results: list[dict]) -> dict:
    """Several runs of one fit (each a fresh process): the median seconds, the largest peak memory, the last matrix.

    Python's start (importing torch and Lightning) alone varies by a second or two between runs
    on a shared machine, so one run of each fit cannot rank two fits a few percent apart.
    """
    done = [result for result in results if "skipped" not in result]
    if len(done) < len(results):
        return next(result for result in results if "skipped" in result)
    return {
        **done[-1],
        "seconds": statistics.median(result["seconds"] for result in done),
        "peak_mb": max(result["peak_mb"] for result in done),
    }


def calibrate(path: Path, run_dir: Path, timeout: float, *overrides: str) -> dict:
    """One run of the CLI under /usr/bin/time; its seconds, peak memory, passes and matrix."""
    shutil.rmtree(run_dir, ignore_errors=True)
    command = [
        "/usr/bin/time", "-f", "%M", sys.executable, "-m", "sfmnet", "train", f"data.path={path}",
        f"data.columns=[{','.join(COLUMNS)}]", f"data.magnitude={MAGNITUDE}", f"hydra.run.dir={run_dir}",
        "trainer.enable_progress_bar=false", *overrides,
    ]
    result = timed(command, timeout)
    if "skipped" not in result:
        result["passes"] = json.loads((run_dir / "metrics.json").read_text())["epochs"]
        result["matrix"] = np.array(json.loads((run_dir / "calibration.json").read_text())["matrix"])
    return result


def numpy_reference(path: Path, timeout: float) -> dict:
    """bench/numpy_reference.py on the session, in its own process: seconds, peak memory, matrix."""
    command = ["/usr/bin/time", "-f", "%M", sys.executable, str(Path(__file__).with_name("numpy_reference.py")), str(path), str(MAGNITUDE)]
    result = timed(command, timeout)
    if "skipped" not in result:
        result["matrix"] = np.array(json.loads(result.pop("stdout"))["matrix"])
    return result


def timed(command: list[str], timeout: float) -> dict:
    """Run ``command`` (under ``/usr/bin/time -f %M``): its seconds, peak memory (MB) and stdout, or why it was skipped."""
    started = time.perf_counter()
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"skipped": f"over {timeout:g} s"}
    seconds = time.perf_counter() - started
    if done.returncode != 0:
        return {"skipped": (done.stderr.strip().splitlines() or ["failed"])[-2][:80]}
    return {"seconds": seconds, "peak_mb": int(done.stderr.strip().splitlines()[-1]) / 1024, "stdout": done.stdout}


def relative(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=float, nargs="+", default=[1e5, 1e6])
    parser.add_argument("--timeout", type=float, default=600.0)
    parser.add_argument("--in-memory-up-to", type=float, default=1e6, help="skip the in-memory fit above this many rows")
    parser.add_argument("--repeats", type=int, default=5, help="runs of each fit, their median seconds reported")
    args = parser.parse_args()
    print("| orientations | file | streamed | streamed x2 | in memory [speed vs streamed] | numpy [speed vs streamed] | vs in memory (streamed, numpy) | error vs truth |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as folder:
        for rows in [int(r) for r in args.rows]:
            path = Path(folder) / f"session_{rows}.npy"
            truth = write_session(path, rows)
            stream_args = ("experiment=calibrate_stream",)
            in_memory = rows <= args.in_memory_up_to
            # The fits take turns, so a slow spell of the machine falls on each of them alike.
            runs = {
                "streamed": lambda: calibrate(path, Path(folder) / f"s{rows}", args.timeout, *stream_args),
                "double": lambda: calibrate(path, Path(folder) / f"d{rows}", args.timeout, *stream_args,
                                            "trainer.devices=2", "trainer.strategy=ddp"),
                "memory": lambda: calibrate(path, Path(folder) / f"m{rows}", args.timeout, "experiment=calibrate_csv",
                                            "model.refinement=alternation", "trainer.max_epochs=1")
                if in_memory else {"skipped": "not run"},
                "reference": lambda: numpy_reference(path, args.timeout) if in_memory else {"skipped": "not run"},
            }
            trials = {name: [] for name in runs}
            for _ in range(args.repeats):
                for name, run in runs.items():
                    trials[name].append(run())
            streamed, double, memory, reference = (median_run(trials[name]) for name in runs)

            def cell(result: dict, passes: bool = False) -> str:
                if "skipped" in result:
                    return result["skipped"]
                extra = f", {result['passes']:.0f} passes" if passes else ""
                return f"{result['seconds']:.1f} s ({result['peak_mb']:.0f} MB{extra})"

            def speed(result: dict) -> str:
                return f" [{streamed['seconds'] / result['seconds']:.2f}x]" if "seconds" in result and "seconds" in streamed else ""

            def agreement(result: dict) -> str:
                return f"{relative(result['matrix'], memory['matrix']):.1e}" if "matrix" in memory and "matrix" in result else "-"

            error = f"{100 * relative(streamed['matrix'], truth):.4f} %" if "matrix" in streamed else "-"
            print(
                f"| {rows:.0e} | {path.stat().st_size / 1e6:.0f} MB | {cell(streamed, passes=True)} | {cell(double)} | "
                f"{cell(memory)}{speed(memory)} | {cell(reference)}{speed(reference)} | {agreement(streamed)}, "
                f"{agreement(reference)} | {error} |",
                flush=True,
            )
            path.unlink()


if __name__ == "__main__":
    main()
