"""Shape from motion in plain numpy, the reference bench/streamed_calibration.py times sfmnet against.

The same algorithm as ``experiment=calibrate_csv model.refinement=alternation`` for one mass
with offsets (method §2-5): the centred truncated SVD, the ellipsoid fit in the load subspace
(the metric constraint), the frame from the known loads by orthogonal Procrustes, the
Anderson-accelerated alternation (each row's unit direction by Newton's method, each round
ending with the rotation that fits the known loads) to a 1e-9 relative step, and the
Cramer-Rao error bars of the matrix (the per-row directions eliminated). No checks,
diagnostics, figures or files: a lower bound on what the numerics cost. Run as a script it
calibrates a bench session file and prints the matrix and the seconds as JSON:

    python bench/numpy_reference.py session.npy 9.81
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

TOLERANCE = 1e-9
MAX_ROUNDS = 1000
CHUNK_ROWS = 20_000


def closed_form(readings: np.ndarray, magnitude: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Shape ``S`` (``n x p``) and offsets ``o`` (``p``) from the SVD and the ellipsoid through the subspace coordinates."""
    centre = readings.mean(axis=0)
    _, _, vt = np.linalg.svd(readings - centre, full_matrices=False)
    basis = vt[:n]
    y = (readings - centre) @ basis.T
    rows, cols = np.triu_indices(n)
    design = np.concatenate([y[:, rows] * y[:, cols], y], axis=1)
    coefficients = np.linalg.lstsq(design, np.ones(len(y)), rcond=None)[0]
    quadric = np.zeros((n, n))
    quadric[rows, cols] = coefficients[: len(rows)]
    quadric = (quadric + quadric.T) / 2
    linear = coefficients[len(rows) :]
    middle = -np.linalg.solve(quadric, linear) / 2
    quadric /= 1 + middle @ quadric @ middle
    root = np.linalg.cholesky(quadric) * magnitude  # m = (y - middle) root
    shape = np.linalg.solve(root, basis)
    return shape, centre + middle @ basis


def procrustes(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation ``R`` minimising ``|source R - target|``."""
    u, _, vt = np.linalg.svd(source.T @ target)
    return u @ vt


def unit_directions(centred: np.ndarray, shape: np.ndarray) -> np.ndarray:
    """Per row ``argmin_{|u|=1} |z - u S|``: Newton on the trust-region boundary equation (as ``unit_motion``)."""
    eigenvalues, basis = np.linalg.eigh(shape @ shape.T)
    coefficients = centred @ shape.T @ basis
    low = np.maximum(np.linalg.norm(coefficients, axis=1) - eigenvalues[-1], np.abs(coefficients[:, 0]) - eigenvalues[0])
    s = np.maximum(low, 0.0)
    rows = np.arange(len(s))
    squares = coefficients**2
    for _ in range(100):
        inverse = 1 / (eigenvalues + s[rows, None])
        terms = squares[rows] * inverse**2
        norm2 = terms.sum(axis=1)
        step = (np.sqrt(norm2) - 1) * norm2 / (terms * inverse).sum(axis=1)
        s[rows] = np.maximum(s[rows] + step, low[rows])
        rows = rows[np.abs(step) > 1e-13 * (s[rows] + eigenvalues[0])]
        if len(rows) == 0:
            break
    directions = (coefficients / (eigenvalues + s[:, None])) @ basis.T
    return directions / np.linalg.norm(directions, axis=1, keepdims=True)


def known_load_rotation(known_readings: np.ndarray, known_loads: np.ndarray, shape: np.ndarray, magnitude: float) -> np.ndarray:
    """The rotation ``R`` minimising ``sum_k |y_k - F l_k / |l_k| R S|^2`` (as ``sfmnet.linalg.frame.known_load_rotation``):
    Gauss-Newton steps ``R <- polar(I + W) R`` on the skew part ``W``."""
    known_loads = magnitude * known_loads / np.linalg.norm(known_loads, axis=1, keepdims=True)
    n = shape.shape[0]
    rows, cols = np.triu_indices(n, 1)
    generators = np.zeros((len(rows), n, n))
    generators[np.arange(len(rows)), rows, cols] = 1.0
    generators[np.arange(len(rows)), cols, rows] = -1.0
    rotation = np.eye(n)
    for _ in range(20):
        turned = rotation @ shape
        residual = (known_readings - known_loads @ turned).ravel()
        jacobian = np.stack([(known_loads @ g @ turned).ravel() for g in generators], axis=1)
        step = np.linalg.lstsq(jacobian, residual, rcond=None)[0]
        u, _, vt = np.linalg.svd(np.eye(n) + np.einsum("a,aij->ij", step, generators))
        rotation = u @ vt @ rotation
        if np.linalg.norm(step) <= 1e-15:
            break
    return rotation


def alternation_round(
    readings: np.ndarray, known: np.ndarray, loads: np.ndarray, magnitude: float, parameters: np.ndarray
) -> np.ndarray:
    """One round on ``[S; o]``: unit directions, least squares of the readings on ``[M 1]``, then the known loads' frame."""
    shape, offset = parameters[:-1], parameters[-1]
    motion = magnitude * unit_directions(readings - offset, magnitude * shape)
    motion[known] = loads[known]
    motion_mean, readings_mean = motion.mean(axis=0), readings.mean(axis=0)
    centred = motion - motion_mean
    new_shape = np.linalg.solve(centred.T @ centred, centred.T @ (readings - readings_mean))
    new_offset = readings_mean - motion_mean @ new_shape
    new_shape = known_load_rotation(readings[known] - new_offset, loads[known], new_shape, magnitude) @ new_shape
    return np.vstack([new_shape, new_offset])


def alternation(
    readings: np.ndarray, known: np.ndarray, loads: np.ndarray, magnitude: float, shape: np.ndarray, offset: np.ndarray
) -> tuple[np.ndarray, np.ndarray, int]:
    """Rounds mixed by Anderson acceleration (5 rounds of history, restarted when a step grows) to a relative step of TOLERANCE."""
    current = np.vstack([shape, offset])
    mapped_history: list[np.ndarray] = []
    residual_history: list[np.ndarray] = []
    best = np.inf
    for rounds in range(1, MAX_ROUNDS + 1):
        mapped = alternation_round(readings, known, loads, magnitude, current)
        residual = (mapped - current).ravel()
        step = np.linalg.norm(residual)
        if step > best:
            mapped_history, residual_history, following = [], [], mapped
        else:
            best = step
            mapped_history = [*mapped_history, mapped.ravel()][-5:]
            residual_history = [*residual_history, residual][-5:]
            r = np.stack(residual_history, axis=1)
            gamma = np.linalg.lstsq(r[:, 1:] - r[:, :1], -r[:, 0], rcond=None)[0]
            weights = np.concatenate([[1 - gamma.sum()], gamma])
            following = (np.stack(mapped_history, axis=1) @ weights).reshape(current.shape)
        current = following
        if step <= TOLERANCE * np.linalg.norm(current):
            break
    return current[:-1], current[-1], rounds


def matrix_std(
    readings: np.ndarray, known: np.ndarray, loads: np.ndarray, magnitude: float, shape: np.ndarray, offset: np.ndarray
) -> np.ndarray:
    """Cramer-Rao standard errors of ``C = (S S^T)^-1 S``: information ``sum_j (w_j w_j^T) kron Q_j``
    (``w_j = [m_j, 1]``, ``Q_j`` the projector off row ``j``'s direction tangents), then the delta method."""
    n, p = shape.shape
    k = n + 1
    matrix = np.linalg.solve(shape @ shape.T, shape)
    information = np.zeros((k * k, p * p))
    residual_squares = 0.0
    for start in range(0, len(readings), CHUNK_ROWS):
        rows = slice(start, start + CHUNK_ROWS)
        z, fixed = readings[rows], known[rows]
        directions = unit_directions(z - offset, magnitude * shape)
        motion = np.where(fixed[:, None], loads[rows], magnitude * directions)
        residual_squares += float(np.sum((z - motion @ shape - offset) ** 2))
        v = directions.copy()
        v[:, 0] += np.where(directions[:, 0] >= 0, 1.0, -1.0)
        reflection = np.eye(n) - 2 * v[:, :, None] * v[:, None, :] / np.sum(v**2, axis=1)[:, None, None]
        tangent = np.einsum("jde,dp->jpe", reflection[:, :, 1:], magnitude * shape)
        gram = tangent.transpose(0, 2, 1) @ tangent
        projector = np.eye(p) - tangent @ np.linalg.solve(gram, tangent.transpose(0, 2, 1))
        projector[fixed] = np.eye(p)
        weights = np.concatenate([motion, np.ones((len(motion), 1))], axis=1)
        outer = (weights[:, :, None] * weights[:, None, :]).reshape(len(z), k * k)
        information += outer.T @ projector.reshape(len(z), p * p)
    information = information.reshape(k, k, p, p).transpose(0, 2, 1, 3).reshape(k * p, k * p)
    parameters = k * p + (n - 1) * int((~known).sum())
    noise_var = residual_squares / max(readings.size - parameters, 1)
    covariance = noise_var * np.linalg.inv(information)[: n * p, : n * p]
    # d C / d S by forward differences (n p columns), then the delta method.
    jacobian = np.empty((n * p, n * p))
    eps = 1e-7 * np.abs(shape).max()
    for i in range(n * p):
        bumped = shape.copy().reshape(-1)
        bumped[i] += eps
        bumped = bumped.reshape(n, p)
        jacobian[:, i] = ((np.linalg.solve(bumped @ bumped.T, bumped) - matrix) / eps).reshape(-1)
    return np.sqrt(np.einsum("ab,bc,ac->a", jacobian, covariance, jacobian)).reshape(n, p)


def calibrate(readings: np.ndarray, loads: np.ndarray, magnitude: float) -> dict:
    """The calibration matrix, its standard errors and the alternation's rounds."""
    n = loads.shape[1]
    known = np.isfinite(loads).all(axis=1)
    shape, offset = closed_form(readings[~known], magnitude, n)
    motion = (readings[known] - offset) @ np.linalg.solve(shape @ shape.T, shape).T
    rotation = procrustes(motion, loads[known])
    shape = rotation.T @ shape
    shape, offset, rounds = alternation(readings, known, loads, magnitude, shape, offset)
    return {
        "matrix": np.linalg.solve(shape @ shape.T, shape),
        "matrix_std": matrix_std(readings, known, loads, magnitude, shape, offset),
        "rounds": rounds,
    }


def main() -> None:
    path, magnitude = sys.argv[1], float(sys.argv[2])
    started = time.perf_counter()
    table = np.load(path).astype(np.float64)
    result = calibrate(table[:, :-3], table[:, -3:], magnitude)
    seconds = time.perf_counter() - started
    print(json.dumps({"seconds": seconds, "rounds": result["rounds"], "matrix": result["matrix"].tolist(),
                      "matrix_std": result["matrix_std"].tolist()}))


if __name__ == "__main__":
    main()
