"""The streamed PCA fit against the usual tools (issue 5, method §11). Run by hand:

    pip install -e ".[bench]"
    python bench/streaming_pca.py                      # samples 1e5, 1e6, 1e7 x channels 8, 64
    python bench/streaming_pca.py --big                # plus a 1e8 x 8 float32 file (3.2 GB) through the CLI

Each method runs in a fresh process on a float32 ``.npy`` (written once to a temporary
folder) so its peak resident memory can be measured; seconds are the fit alone, with the
array already in memory for the in-memory methods and read from disk (page cache warm) for
the streamed one. The in-memory methods work in the file's float32, the streamed statistics
in float64. Methods: the streamed fit through the Trainer (one pass of float64
statistics, ``experiment=pca``'s path), numpy's ``Z.T @ Z`` plus ``eigh`` on the centred array
(the floor for this math), a full ``numpy.linalg.svd``, scikit-learn's
``PCA(svd_solver="covariance_eigh")`` and ``IncrementalPCA``. Ratios are speed relative to
the streamed fit measured in the same run (> 1: that method is faster). A GPU column is added
when torch sees a GPU.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

RANK = 4
METHODS = ["streamed", "numpy_eigh", "numpy_svd", "sklearn_pca", "sklearn_incremental", "torch_gpu"]


def write_matrix(path: Path, rows: int, channels: int, seed: int = 0) -> None:
    """A float32 row matrix with a rank-4 signal, offsets and noise, written block by block."""
    generator = np.random.default_rng(seed)
    mixing = generator.normal(size=(RANK, channels))
    offsets = generator.normal(size=channels) * 100
    out = np.lib.format.open_memmap(path, mode="w+", dtype=np.float32, shape=(rows, channels))
    step = 1_000_000
    for start in range(0, rows, step):
        count = min(step, rows - start)
        block = generator.normal(size=(count, RANK)) @ mixing + 0.1 * generator.normal(size=(count, channels)) + offsets
        out[start : start + count] = block
    out.flush()


def run_method(method: str, path: Path) -> dict:
    """Fit with one method in this process; returns seconds and the leading singular values."""
    if method == "streamed":
        import lightning as L
        import torch

        from sfmnet.readers.row_file import RowFileDataModule
        from sfmnet.models.streaming_pca import StreamingPCA
        from sfmnet.training.learner_module import LearnerModule

        torch.set_num_threads(2)
        datamodule = RowFileDataModule(str(path))
        model = StreamingPCA(rank=RANK)
        trainer = L.Trainer(
            accelerator="cpu", devices=1, max_epochs=1, precision="64-true", logger=False, enable_checkpointing=False,
            enable_progress_bar=False, enable_model_summary=False, use_distributed_sampler=False,
        )
        started = time.perf_counter()
        trainer.fit(LearnerModule(model, optimizer=None), datamodule=datamodule)
        seconds = time.perf_counter() - started
        return {"seconds": seconds, "singular": model.singular_values.tolist()}
    from sklearn.decomposition import PCA, IncrementalPCA

    z = np.load(path)
    if method == "torch_gpu":
        import torch

        if not torch.cuda.is_available():
            return {"skipped": "no GPU"}
        zt = torch.from_numpy(z).cuda()
        torch.cuda.synchronize()
        started = time.perf_counter()
        centred = zt.double() - zt.double().mean(dim=0)
        values = torch.linalg.eigvalsh(centred.T @ centred)
        torch.cuda.synchronize()
        return {"seconds": time.perf_counter() - started, "singular": values.flip(0)[:RANK].sqrt().tolist()}
    started = time.perf_counter()
    if method == "numpy_eigh":
        centred = z - z.mean(axis=0)
        values = np.linalg.eigh(centred.T @ centred)[0][::-1][:RANK]
        singular = np.sqrt(values)
    elif method == "numpy_svd":
        singular = np.linalg.svd(z - z.mean(axis=0), full_matrices=False, compute_uv=False)[:RANK]
    elif method == "sklearn_pca":
        singular = PCA(n_components=RANK, svd_solver="covariance_eigh").fit(z).singular_values_
    elif method == "sklearn_incremental":
        singular = IncrementalPCA(n_components=RANK, batch_size=max(10 * z.shape[1], 100_000)).fit(z).singular_values_
    else:
        raise ValueError(method)
    return {"seconds": time.perf_counter() - started, "singular": [float(v) for v in singular]}


def measure(method: str, path: Path, timeout: float) -> dict:
    """Run one method in a child process; add its peak resident memory (MB)."""
    command = [sys.executable, __file__, "--one", method, str(path)]
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {"skipped": f"over {timeout:g} s"}
    if done.returncode != 0:
        return {"skipped": done.stderr.strip().splitlines()[-1][:60] if done.stderr.strip() else "failed"}
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["peak_mb"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    return result


def measure_fresh(method: str, path: Path, timeout: float) -> dict:
    """As :func:`measure`, in a wrapper process so each peak is that method's alone."""
    command = [sys.executable, __file__, "--measure", method, str(path), str(timeout)]
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", type=float, nargs="+", default=[1e5, 1e6, 1e7])
    parser.add_argument("--channels", type=int, nargs="+", default=[8, 64])
    parser.add_argument("--timeout", type=float, default=300.0)
    parser.add_argument("--big", action="store_true", help="also fit a 1e8 x 8 float32 file through the CLI")
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    parser.add_argument("--measure", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_method(args.one[0], Path(args.one[1]))))
        return
    if args.measure:
        print(json.dumps(measure(args.measure[0], Path(args.measure[1]), float(args.measure[2]))))
        return
    header = "| rows x channels | " + " | ".join(METHODS) + " |"
    print("Seconds (peak MB) [speed relative to streamed]\n")
    print(header)
    print("|" + "---|" * (len(METHODS) + 1))
    with tempfile.TemporaryDirectory() as folder:
        for rows in [int(r) for r in args.rows]:
            for channels in args.channels:
                path = Path(folder) / f"z_{rows}_{channels}.npy"
                write_matrix(path, rows, channels)
                results = {method: measure_fresh(method, path, args.timeout) for method in METHODS}
                base = results["streamed"].get("seconds")
                cells = []
                for method in METHODS:
                    r = results[method]
                    if "skipped" in r:
                        cells.append(r["skipped"])
                        continue
                    ratio = f" [{base / r['seconds']:.2f}x]" if base and method != "streamed" else ""
                    cells.append(f"{r['seconds']:.3f} ({r['peak_mb']:.0f} MB){ratio}")
                print(f"| {rows:.0e} x {channels} | " + " | ".join(cells) + " |", flush=True)
                path.unlink()
        if args.big:
            path = Path(folder) / "z_1e8_8.npy"
            write_matrix(path, 100_000_000, 8)
            run_dir = Path(folder) / "run"
            command = [
                "/usr/bin/time", "-f", "%M", sys.executable, "-m", "sfmnet", "train", "experiment=pca",
                f"data.path={path}", f"model.rank={RANK}", f"hydra.run.dir={run_dir}", "trainer.enable_progress_bar=false",
            ]
            started = time.perf_counter()
            done = subprocess.run(command, check=True, capture_output=True, text=True)
            seconds = time.perf_counter() - started
            peak = int(done.stderr.strip().splitlines()[-1]) / 1024
            print(f"\n1e8 x 8 float32 ({path.stat().st_size / 1e9:.1f} GB) through `python -m sfmnet train experiment=pca`: "
                  f"{seconds:.1f} s start to finish, peak resident memory {peak:.0f} MB")


if __name__ == "__main__":
    main()
