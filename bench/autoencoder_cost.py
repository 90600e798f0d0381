"""What it costs a linear autoencoder to find the eigenspace learner's subspace (issue 4, method §10).

On the MK-V training vectors (conf/data/mkv.yaml) and the rank the eigenspace learner chose,
trains the autoencoder through the trainer with each optimiser and reports the epochs and
seconds until its largest principal angle to the PCA subspace falls below 2 degrees, and
where it ends; the PCA closed form's time is measured in the same run. Run by hand:

    python bench/autoencoder_cost.py [--epochs 100]
"""

from __future__ import annotations

import argparse
import logging
import time
import warnings

import lightning as L
import torch
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate

from sfmnet.cli import config_dir
from sfmnet.models.eigenspace_learner import EigenspaceLearner
from sfmnet.models.linear_autoencoder import LinearAutoencoder
from sfmnet.training.fitting import fit

TARGET_DEG = 2.0


class AngleClock(L.Callback):
    """Records the first epoch (and seconds since fitting began) at which the angle is below the target."""

    def __init__(self) -> None:
        self.started = time.perf_counter()
        self.reached: tuple[int, float] | None = None

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.reached is None and pl_module.model.monitor()["subspace_angle_deg"] < TARGET_DEG:
            self.reached = (trainer.current_epoch + 1, time.perf_counter() - self.started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--epochs", type=int, default=100)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    torch.set_num_threads(1)
    runs = {
        "L-BFGS, full batch": (["optimizer=lbfgs"], None),
        "Adam lr 1e-2, full batch": (["optimizer=adam", "optimizer.lr=1e-2"], None),
        "Adam lr 1e-3, batches of 256": (["optimizer=adam", "optimizer.lr=1e-3"], 256),
    }
    with initialize_config_dir(config_dir=config_dir(), version_base="1.3"):
        base = ["experiment=mkv_autoencoder", "trainer.enable_progress_bar=false", f"trainer.max_epochs={args.epochs}"]
        cfgs = {name: compose(config_name="train", overrides=[*base, *overrides]) for name, (overrides, _) in runs.items()}
    datamodule = instantiate(next(iter(cfgs.values())).data)
    datamodule.setup()
    started = time.perf_counter()
    pca = EigenspaceLearner()
    pca.initialise(datamodule.data)
    pca_seconds = time.perf_counter() - started
    print(f"PCA closed form (standardise, rank {pca.rank} by parallel analysis, SVD): {pca_seconds:.3f} s\n")
    print("| optimiser | epochs to < 2 deg | seconds to < 2 deg | final angle (deg) | seconds, all epochs | x PCA time |")
    print("|---|---|---|---|---|---|")
    for name, (_, batch_size) in runs.items():
        cfg = cfgs[name]
        datamodule.batch_size = batch_size
        model = LinearAutoencoder(rank=pca.rank, seed=cfg.seed)
        clock = AngleClock()
        started = time.perf_counter()
        fit(model, cfg, datamodule, logger=False, enable_checkpointing=False, callbacks=[clock])
        seconds = time.perf_counter() - started
        reached = clock.reached
        epochs, to_target = (f"{reached[0]}", f"{reached[1]:.2f}") if reached else ("not reached", "-")
        angle = model.monitor()["subspace_angle_deg"]
        ratio = f"{reached[1] / pca_seconds:.1f}" if reached else "-"
        print(f"| {name} | {epochs} | {to_target} | {angle:.3f} | {seconds:.2f} | {ratio} |", flush=True)


if __name__ == "__main__":
    main()
