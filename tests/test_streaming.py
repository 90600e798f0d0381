"""Streamed fits from sufficient statistics (method §11): one pass, memory maps, several processes."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from sfmnet.readers.row_file import RowFileDataModule, ShardSampler, csv_to_npy
from sfmnet.errors import SfmnetError
from sfmnet.linalg.moments import Moments, principal_subspace
from sfmnet.training.run import train
from tests.conftest import REPO, compose_config

QUIET = ["trainer.enable_progress_bar=false"]


def rows_with_offsets(rows: int = 20_000, channels: int = 6, seed: int = 0) -> np.ndarray:
    generator = np.random.default_rng(seed)
    signal = generator.normal(size=(rows, 3)) @ generator.normal(size=(3, channels))
    return (signal + 0.05 * generator.normal(size=(rows, channels)) + 1e4).astype(np.float32)


def test_moments_of_shards_add_up_and_survive_large_offsets():
    z = torch.from_numpy(rows_with_offsets().astype(np.float64))
    whole = Moments.empty(z[:100].mean(dim=0))
    whole.update(z)
    parts = Moments.empty(z[:100].mean(dim=0))
    for block in z.split(3000):
        parts.update(block)
    assert torch.allclose(whole.cross, parts.cross, rtol=1e-12)
    reference = z - z.mean(dim=0)
    assert torch.allclose(whole.centred_cross(), reference.T @ reference, rtol=1e-9)
    components, singular = principal_subspace(whole.centred_cross(), 3)
    assert torch.allclose(singular, torch.linalg.svdvals(reference)[:3], rtol=1e-10)
    assert torch.allclose(components @ components.T, torch.eye(3, dtype=torch.float64), atol=1e-12)


def test_shards_cover_every_block_once_with_equal_steps(monkeypatch):
    seen = []
    for rank in range(3):
        monkeypatch.setattr(ShardSampler, "rank_and_world", staticmethod(lambda rank=rank: (rank, 3)))
        steps = list(ShardSampler(7))
        assert len(steps) == 3
        seen += [block for block in steps if block >= 0]
    assert sorted(seen) == list(range(7))


def pca_run(path: Path, run_dir: Path, *extra: str) -> dict[str, np.ndarray]:
    train(compose_config(["experiment=pca", f"data.path={path}", "model.rank=3", *QUIET, *extra]), run_dir)
    return dict(np.load(run_dir / "pca.npz"))


def test_pca_contract_matches_the_svd(tmp_path: Path):
    z = rows_with_offsets()
    np.save(tmp_path / "z.npy", z)
    result = pca_run(tmp_path / "z.npy", tmp_path / "run", "data.block_rows=3000")
    centred = z.astype(np.float64) - z.astype(np.float64).mean(axis=0)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    assert result["mean"].shape == (6,) and result["components"].shape == (3, 6) and result["singular_values"].shape == (3,)
    assert np.allclose(result["singular_values"], s[:3], rtol=1e-10)
    assert np.allclose(result["components"] @ result["components"].T, np.eye(3), atol=1e-12)
    assert np.allclose(np.abs(result["components"] @ vt[:3].T), np.eye(3), atol=1e-8)


def test_csv_is_converted_once_and_reconverted_when_it_changes(tmp_path: Path):
    z = rows_with_offsets(rows=500)
    path = tmp_path / "z.csv"
    np.savetxt(path, z, delimiter=",", header=",".join(f"s{i}" for i in range(6)), comments="")
    first = csv_to_npy(path, None)
    stamp = first.stat().st_mtime_ns
    assert csv_to_npy(path, None) == first and first.stat().st_mtime_ns == stamp
    assert np.allclose(np.load(first), z, rtol=1e-6)
    with path.open("a") as stream:
        stream.write(",".join(["1"] * 6) + "\n")
    assert csv_to_npy(path, None) != first
    module = RowFileDataModule(str(path))
    module.setup()
    assert module.data.channels == [f"s{i}" for i in range(6)]


def test_bad_row_files(tmp_path: Path):
    (tmp_path / "bad.csv").write_text("a,b\n1,2\n3,x\n")
    with pytest.raises(SfmnetError, match="line 3 has a non-numeric cell"):
        RowFileDataModule(str(tmp_path / "bad.csv")).setup()
    np.save(tmp_path / "one.npy", np.arange(5.0))
    with pytest.raises(SfmnetError, match="shape"):
        RowFileDataModule(str(tmp_path / "one.npy")).setup()
    np.save(tmp_path / "z.npy", rows_with_offsets(rows=100))
    with pytest.raises(SfmnetError, match="model.rank is 9 but the file has 6 columns"):
        train(compose_config(["experiment=pca", f"data.path={tmp_path / 'z.npy'}", "model.rank=9", *QUIET]), tmp_path / "run")


def test_two_processes_give_the_same_numbers(tmp_path: Path):
    """DDP on the CPU (gloo), a real second process; blocks shared so no row counts twice."""
    z = rows_with_offsets(rows=50_000)
    np.save(tmp_path / "z.npy", z)
    single = pca_run(tmp_path / "z.npy", tmp_path / "single", "data.block_rows=7000")
    command = [
        sys.executable, "-m", "sfmnet", "train", "experiment=pca", f"data.path={tmp_path / 'z.npy'}", "model.rank=3",
        f"hydra.run.dir={tmp_path / 'ddp'}", "trainer.devices=2", "trainer.strategy=ddp", "data.block_rows=7000", *QUIET,
    ]
    done = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300, check=False, env={**os.environ})
    assert done.returncode == 0, done.stderr[-2000:]
    assert "on 2 process(es)" in done.stdout
    double = dict(np.load(tmp_path / "ddp" / "pca.npz"))
    for key in ("mean", "components", "singular_values"):
        assert np.abs(double[key] - single[key]).max() <= 1e-10 * np.abs(single[key]).max(), key
