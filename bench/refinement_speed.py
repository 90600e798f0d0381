"""The refinement's gradient path at scale: steps per second and time to reach the answer (issue 5). Run by hand:

    python bench/refinement_speed.py [--samples 1000 10000 100000] [--epochs 20]

A simulated 3-axis sensor (6 channels, offsets, three known loads, 1 % noise). For each number
of orientations: the closed form's time, then each refinement from it, epoch by epoch as the
trainer runs it with the default configs: the alternation (50 Anderson-mixed rounds an epoch)
and the penalised loss with L-BFGS (up to 50 iterations an epoch). "Answer" is each method's
result after ``--epochs`` epochs; reported: epochs per second, the epochs and seconds until the
calibration matrix is within 1e-6 (relative) of the answer, and its error against the truth.
"""

from __future__ import annotations

import argparse
import time

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from sfmnet.cli import config_dir
from sfmnet.simulators.simulated_sensor import ForceSensor3DataModule
from sfmnet.models.shape_from_motion import ShapeFromMotion
from sfmnet.training.fitting import refine_in_process
from sfmnet.training.learner_module import matrix_error

TOLERANCE = 1e-6


def trajectory(model: ShapeFromMotion, recording, epochs: int) -> tuple[list[torch.Tensor], list[float]]:
    """Calibration matrices and elapsed seconds after each epoch of the model's refinement (the trainer's steps)."""
    matrices, times = [], []
    started = time.perf_counter()

    def record() -> None:
        times.append(time.perf_counter() - started)
        matrices.append(model.calibration_matrix())

    optimizer = instantiate(OmegaConf.load(f"{config_dir()}/optimizer/lbfgs.yaml"))
    refine_in_process(model, recording, optimizer, epochs, initialise=False, after_epoch=record)
    return matrices, times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--samples", type=int, nargs="+", default=[1000, 10000, 100000])
    parser.add_argument("--epochs", type=int, default=20)
    args = parser.parse_args()
    torch.set_num_threads(2)
    print("| orientations | closed form (s) | refinement | epochs/s | epochs to answer | seconds to answer | matrix error vs truth |")
    print("|---|---|---|---|---|---|---|")
    for samples in args.samples:
        datamodule = ForceSensor3DataModule(magnitude=9.81, samples=samples, known_loads=3, mirror_hint=False, offset_scale=0.2)
        datamodule.setup()
        recording = datamodule.data.recordings["rotation"]
        for refinement in ("alternation", "penalty"):
            model = ShapeFromMotion(refinement=refinement)
            started = time.perf_counter()
            model.initialise(recording)
            closed = time.perf_counter() - started
            matrices, times = trajectory(model, recording, args.epochs)
            answer = matrices[-1]
            reached = next((i for i, m in enumerate(matrices) if matrix_error(m, answer) < TOLERANCE), None)
            steps_to = f"{reached + 1}" if reached is not None else f"> {args.epochs}"
            seconds_to = f"{times[reached]:.3f}" if reached is not None else "-"
            error = float(matrix_error(answer, datamodule.data.truth.matrix))
            print(
                f"| {samples} | {closed:.3f} | {refinement} | {len(times) / times[-1]:.2f} | {steps_to} | {seconds_to} | {100 * error:.3f} % |",
                flush=True,
            )


if __name__ == "__main__":
    main()
