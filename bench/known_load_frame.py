"""Error bars where the frame rests on known loads: the matrix error in the known loads' frame over the bars. Run by hand:

    python bench/known_load_frame.py [--sessions 60] [--law hemisphere] [--noise 0.03] [--samples 400] [--known-rows 1]
    python bench/known_load_frame.py --sensor force3 --sessions 12 --law uniform --noise 0.05 --samples 2400

Sessions of the simulated fingertip (`experiment=fingertip`: 4 gauges, offsets, one known load along fx with its
stage's 0.2-degree angle error, the mirror hint) or, ``--sensor force3``, of the simulated 3-axis sensor
(`experiment=lord3dof`: 6 channels, offsets, three known loads along the axes, each read once), fitted as a run fits
them (``model.refinement=auto``), seeds 0 to ``--sessions - 1``. ``--known-rows k`` reads the (last) known load ``k``
times instead of once (fresh noise each). Printed:
the RMS over sessions of the matrix error, in the fit's own frame (no alignment to the truth: the frame is what the
known load sets), over the reported standard error (Frobenius norms; 1 if the bars are right), the fraction of
sessions past 1x and 2x (0.32 and 0.046 for a normal error along one direction, the frame's rotation, which most of
these bars are), the mean share of the bars' variance that is the frame (``matrix_std_frame_share``), and the
sessions the goodness of fit trusts.
"""

from __future__ import annotations

import argparse
import math
import warnings

import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from sfmnet.cli import config_dir
from sfmnet.data.recording import CalibrationRecording
from sfmnet.eval.diagnostics import calibration_diagnostics
from sfmnet.linalg.uncertainty import relative_matrix_std
from sfmnet.models.shape_from_motion import ShapeFromMotion
from sfmnet.simulators.simulated_sensor import FingertipDataModule, ForceSensor3DataModule
from sfmnet.simulators.simulation import reread_last_known_load
from sfmnet.training.fitting import refine_in_process


# Each sensor's data config, load unit and the changes to it.
SENSORS = {
    "fingertip": ("fingertip", "gf", {}),
    "force3": ("lord3dof", "N", {"known_loads": 3, "mirror_hint": False}),
}


def session(
    sensor: str, seed: int, law: str, noise: float, samples: int, known_rows: int
) -> tuple[CalibrationRecording, torch.Tensor]:
    """One session as the sensor's experiment simulates it (:data:`SENSORS`), its last known load read ``known_rows``
    times."""
    data, _, changes = SENSORS[sensor]
    cfg = OmegaConf.load(f"{config_dir()}/data/{data}.yaml")
    cfg.merge_with({"seed": seed, "orientation_law": law, "noise_fraction": noise, "samples": samples, **changes})
    datamodule: FingertipDataModule | ForceSensor3DataModule = instantiate(cfg)
    datamodule.setup()
    recording, truth = datamodule.data.recordings["rotation"], datamodule.data.truth
    if known_rows > 1:
        recording = reread_last_known_load(recording, truth, noise, known_rows, torch.Generator().manual_seed(10_000 + seed))
    return recording, truth.matrix


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sensor", choices=list(SENSORS), default="fingertip")
    parser.add_argument("--sessions", type=int, default=60)
    parser.add_argument("--law", default="hemisphere")
    parser.add_argument("--noise", type=float, default=0.03)
    parser.add_argument("--samples", type=int, default=400)
    parser.add_argument("--known-rows", type=int, default=1)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    torch.set_num_threads(1)
    optimizer = instantiate(OmegaConf.load(f"{config_dir()}/optimizer/lbfgs.yaml"))
    ratios, shares, trusted = [], [], 0
    for seed in range(args.sessions):
        recording, truth = session(args.sensor, seed, args.law, args.noise, args.samples, args.known_rows)
        model = refine_in_process(ShapeFromMotion(), recording, optimizer)
        loads = model.fitted_loads(recording)
        bars = model.uncertainty(recording, loads)
        channels = [f"ch{i}" for i in range(recording.readings.shape[1])]
        trusted += calibration_diagnostics(model, recording, channels, loads, bars, SENSORS[args.sensor][1])[2].trustworthy
        matrix = model.calibration_matrix()
        ratios.append(float((matrix - truth).norm() / truth.norm()) / relative_matrix_std(bars.matrix_std, matrix))
        shares.append(bars.frame_share)
    rms = math.sqrt(sum(r * r for r in ratios) / len(ratios))
    print(
        f"{args.sensor}, {args.law}, noise {args.noise:g}, {args.samples} rows, known load read {args.known_rows}x, {args.sessions} sessions: "
        f"error / bars RMS {rms:.2f}, past 1x {sum(r > 1 for r in ratios) / len(ratios):.2f}, "
        f"past 2x {sum(r > 2 for r in ratios) / len(ratios):.3f}, worst {max(ratios):.2f}; "
        f"frame share {sum(shares) / len(shares):.2f}; trusted {trusted} of {args.sessions}"
    )


if __name__ == "__main__":
    main()
