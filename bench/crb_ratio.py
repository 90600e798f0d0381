"""Calibration error against the Cramer-Rao bound, closed form and refined, at falling SNR (issue 3, method §5).

For each SNR (``F |s| / noise``, i.e. ``1 / data.noise_fraction``) and sensor (2-axis fingertip,
3-axis force), ``--trials`` sessions with tared readings and no known loads, as in method §5
(or ``n`` exact known loads with ``--known-loads``).
Error: the shape ``S`` (after the best orthogonal alignment to the truth when no load fixes the
frame). Bound: the trace of the Cramer-Rao bound of ``S`` at the true loads and noise (the
rotation gauge removed by the pseudo-inverse when no load fixes the frame). Printed:
``sqrt(mean error^2 / mean bound)`` for the closed form and for each refinement run by the
trainer from it (``model.refinement``: the alternation, the penalised loss with L-BFGS, the
marginal likelihood with L-BFGS, and ``auto``, the default, which picks one of the first and
third by the closed form's SNR; conf/optimizer/lbfgs.yaml). Run by hand:

    python bench/crb_ratio.py --trials 50 [--known-loads] [--refinements alternation marginal auto]

``--laws``: instead, the orientation laws of the simulators (``data.orientation_law``: uniform,
hemisphere, band near the equator, 60-degree cone, 12 poses, each row's pose given to the fit as its
group so a pose's rows share one direction; ``--untied`` withholds it) at each SNR, for n = 2 and 3, tared and
with offsets (``offset_scale`` 0.1, estimated, the bound with offsets), no known loads. Columns: the
closed form, the alternation, the marginal likelihood and auto against the bound, and the coverage of
auto's error bars (fraction of calibration-matrix entries within one reported standard error of the
truth, the frame aligned); then the fraction of sessions whose bars a calibration run calls trustworthy (every
goodness-of-fit check passed, :func:`~sfmnet.eval.diagnostics.calibration_diagnostics`) and the coverage of
those bars alone (what a user is told to believe). Trials run in ``--processes`` processes of one thread each:

    python bench/crb_ratio.py --laws --trials 50 --processes 2 [--learnt-law harmonic] [--only 3:yes:band:20 ...]

``--record FILE`` appends each finished row's sums to ``FILE`` (JSON lines) with a digest of the code that measured
it (``sfmnet/``, ``conf/`` and this file), each session's terms of the sums in seed order (``sessions``) and what each
session's run reported (``details``, see ``--sessions``), so a session the sums hide, such as a trusted one whose bars
miss, can be found and rerun. A row already there for the same code and options is printed from it, not rerun. So the
50-session table (hours) can be built over several runs, each taking some rows with ``--only``:

    python bench/crb_ratio.py --laws --trials 50 --record runs/bench/laws50.jsonl --only 2:no:band:2 ...

``--from-record`` runs nothing: it prints every row the record holds for these options on any code, the latest of
each, with the digest of the code that measured it in a last column (the README's one table of all rows, measured
over many runs and commits):

    python bench/crb_ratio.py --laws --trials 50 --record runs/bench/laws50.jsonl --from-record

``--sessions`` prints a second table after it, a line per session of every row shown (run now, or recorded with
``details``): the refinement auto took and the law it learnt, its bars and its error (``|matrix_std|_F / |C|_F`` and
``|C_fit - C|_F / |C|_F``, the limit :data:`~sfmnet.eval.goodness_of_fit.MAX_RELATIVE_MATRIX_STD_LEARNT_LAW` is set on
the first), the bars' coverage, the RMS of error over bars, whether the run trusts its bars and the first warning that
says why not. So a limit can be drawn on the sessions it would move:

    python bench/crb_ratio.py --laws --trials 50 --record runs/bench/laws50.jsonl --sessions --only 3:yes:cone:20

``--samples`` runs sessions of that many rows instead: a bias that does not shrink with rows (docs/crb_bench.md, "Beyond the
table's 96-200 rows") hides under the variance of the table's small sessions.

``--p-equals-n`` simulates sensors with as many channels as axes (a 2-gauge fingertip, a 3-channel force sensor: the
algebra of an accelerometer or magnetometer), where no subspace lies outside the load space and the noise and the
error bars rest on the constraint residuals alone.

``--true-law`` adds a column before auto's: the marginal given the session's true law of directions on its
grid, held fixed (:class:`TrueLawMarginal`; not for ``poses``, whose law is its 12 drawn directions). No user
knows it; the gap between it and the marginal column is what learning the law costs.

``--law-bounds``: the bound above treats each sample's direction as an unknown parameter. When the
directions are draws from a law the estimator knows, the data say more (a direction confined to a band
cannot be anywhere); this prints, per law (not ``poses``, whose 12 drawn directions are the law) and
SNR, the square root of that bound's trace over this one's, averaged over ``--trials`` sessions. The
known-law bound comes from the marginal model's Fisher information ``E[g g^T]``, ``g`` the score of
``log sum_k N(z; o + F u_k S, s^2 I)`` over a fine quadrature of the law, by Monte Carlo over draws of
``z``; with the rotation gauge removed as above. Its quadrature (20,000 points) cannot resolve the
sphere's posterior at SNR 100, so that column is left out for n = 3:

    python bench/crb_ratio.py --law-bounds --trials 3 [--only 2:no:band:5 ...]

``--unknown-law`` adds the bound of an estimator that does not know the law (any law on the circle or sphere may
have drawn the directions, as for the marginal that learns it): the semiparametric bound, the shape's score with
every change of the law's projected out (:func:`unknown_law_bound`). It is asymptotic (many rows), so a biased
estimator of the table's 96-200 rows can be below it, as a smoothed law is at SNR 2:

    python bench/crb_ratio.py --law-bounds --unknown-law --trials 3 --only 2:no:band:5 3:no:band:5
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import hashlib
import inspect
import json
import math
import warnings
from pathlib import Path
from typing import NamedTuple

import lightning as L
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from sfmnet.cli import config_dir
from sfmnet.simulators.simulated_sensor import FingertipDataModule, ForceSensor3DataModule
from sfmnet.simulators.simulation import circle_arc, oriented_directions, sphere_zone
from sfmnet.eval.diagnostics import calibration_diagnostics
from sfmnet.linalg.directions import direction_grid
from sfmnet.linalg.frame import orthogonal_procrustes, skew_generators
from sfmnet.linalg.uncertainty import GAUGE_RTOL, relative_matrix_std, shape_information
from sfmnet.models.shape_from_motion import LEARNT_LAWS, ShapeFromMotion
from sfmnet.training.fitting import refine_in_process
from sfmnet.training.learner_module import LearnerModule

# The product's default law, so a plain run measures what users get.
LEARNT_LAW_DEFAULT = inspect.signature(ShapeFromMotion).parameters["learnt_law"].default

SENSORS = {
    "2-axis fingertip, p=4, f=96": (FingertipDataModule, {"magnitude": 111.4, "samples": 96}, 2),
    "3-axis force, p=6, f=200": (ForceSensor3DataModule, {"magnitude": 9.81, "samples": 200}, 3),
}


def error2(shape: torch.Tensor, truth: torch.Tensor, align: bool) -> float:
    """Squared error of ``S``, after the best orthogonal alignment when the frame is free."""
    if align:
        shape = orthogonal_procrustes(shape.T, truth.T).T @ shape
    return float((shape - truth).pow(2).sum())


REFINEMENTS = ("alternation", "penalty", "marginal", "auto")


def trial(
    module_cls, kwargs: dict, known_loads: int, snr: float, seed: int, optimizer_cfg, refinements: list[str]
) -> tuple[float, ...]:
    datamodule = module_cls(
        noise_fraction=1 / snr, known_loads=known_loads, mirror_hint=False, offset_scale=0.0, seed=seed, errors={"angle_error_deg": 0.0}, **kwargs
    )
    datamodule.setup()
    recording = datamodule.data.recordings["rotation"]
    truth = torch.linalg.pinv(datamodule.data.truth.matrix.T)
    noise_std = (1 / snr) * float(truth.norm(dim=0).mean()) * recording.magnitude
    known = recording.known
    unknown = recording.true_loads[~known]
    magnitude = recording.magnitude
    maps = magnitude * torch.eye(unknown.shape[1], dtype=unknown.dtype).expand(len(unknown), -1, -1)
    information = shape_information(truth, recording.true_loads[known], unknown / magnitude, maps, estimate_offset=False)
    bound = noise_std**2 * float(torch.linalg.pinv(information, hermitian=True, rtol=GAUGE_RTOL).diagonal().sum())
    errors = []
    for refinement in refinements:
        model = ShapeFromMotion(estimate_offset=False, refinement=refinement)
        model.initialise(recording)
        closed_form = error2(model.physical_shape(), truth, align=known_loads == 0)
        trainer = L.Trainer(
            max_epochs=10, precision="64-true", accelerator="cpu", logger=False, enable_checkpointing=False,
            enable_progress_bar=False, enable_model_summary=False,
        )
        trainer.fit(LearnerModule(model, instantiate(optimizer_cfg)), datamodule=datamodule)
        errors.append(error2(model.physical_shape(), truth, align=known_loads == 0))
    return closed_form, *errors, bound


LAWS = ("uniform", "hemisphere", "band", "cone", "poses")
LAW_SENSORS = {2: (FingertipDataModule, {"magnitude": 111.4, "samples": 96}), 3: (ForceSensor3DataModule, {"magnitude": 9.81, "samples": 200})}
OFFSET_SCALE = 0.1


def law_session(
    n: int, law: str, snr: float, offsets: bool, seed: int, samples: int | None = None, p_equals_n: bool = False
):
    """The simulated session of one ``--laws`` trial, set up (``samples``: rows instead of the table's 96 or 200;
    ``p_equals_n``: ``n`` channels instead of 4 or 6)."""
    module_cls, kwargs = LAW_SENSORS[n]
    if samples is not None:
        kwargs = {**kwargs, "samples": samples}
    if p_equals_n:
        kwargs = {**kwargs, "channels": n}
    datamodule = module_cls(
        noise_fraction=1 / snr, known_loads=0, mirror_hint=False, offset_scale=OFFSET_SCALE if offsets else 0.0,
        orientation_law=law, seed=seed, errors={"angle_error_deg": 0.0}, **kwargs,
    )
    datamodule.setup()
    return datamodule


def per_direction_bound(datamodule, snr: float, offsets: bool) -> tuple[torch.Tensor, float, float]:
    """The true ``S``, the noise and the trace of the shape's Cramer-Rao bound, each sample's direction a parameter."""
    recording = datamodule.data.recordings["rotation"]
    truth = torch.linalg.pinv(datamodule.data.truth.matrix.T)
    noise_std = (1 / snr) * float(truth.norm(dim=0).mean()) * recording.magnitude
    magnitude = recording.magnitude
    n = truth.shape[0]
    maps = magnitude * torch.eye(n, dtype=truth.dtype).expand(len(recording.true_loads), -1, -1)
    information = shape_information(truth, recording.true_loads[:0], recording.true_loads / magnitude, maps, estimate_offset=offsets)
    bound = noise_std**2 * float(torch.linalg.pinv(information, hermitian=True, rtol=GAUGE_RTOL).diagonal()[: truth.numel()].sum())
    return truth, noise_std, bound


def law_support(law: str, dims: int, count: int) -> torch.Tensor:
    """``count x dims`` directions covering an orientation law's support evenly (equal weights): its quadrature."""
    if dims == 2:
        centre, half_width = circle_arc(law)
        angle = centre + half_width * ((torch.arange(count, dtype=torch.float64) + 0.5) / count * 2 - 1)
        if law == "band":
            angle = torch.cat([angle[::2], angle[1::2] + math.pi])
        return torch.stack([angle.cos(), angle.sin()], dim=1)
    low, high = sphere_zone(law)
    # A Fibonacci lattice on the zone: heights evenly spaced (even area, Archimedes), azimuths by the golden angle.
    index = torch.arange(count, dtype=torch.float64)
    z = low + (high - low) * (index + 0.5) / count
    azimuth = index * math.pi * (3 - math.sqrt(5))
    radius = (1 - z**2).sqrt()
    return torch.stack([radius * azimuth.cos(), radius * azimuth.sin(), z], dim=1)


def marginal_scores(
    shape: torch.Tensor, noise_std: float, magnitude: float, law: str, offsets: bool, generator: torch.Generator,
    draws: int, quadrature: int = 20_000, grid: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Scores of ``draws`` readings drawn from the marginal model ``p(z) = mean_k N(z; F u_k S + o, s^2 I)``
    (``u_k`` :func:`law_support`): of ``S`` and (``offsets``) ``o``, ``draws x (n p [+ p])``, and with ``grid``
    (``V x n``) the law's scores ``p(z | v) / p(z)`` for each grid direction ``v``, ``draws x V`` (else None).

    ``d/dS = F/s^2 E[u^T (z - F u S - o) | z]``, ``d/do = 1/s^2 E[z - F u S - o | z]``, the posterior over the
    quadrature. ``p(z | v) / p(z)`` is the score of the law moved towards a point mass at ``v``: its span over
    ``v`` is every way the law can change.
    """
    n, p = shape.shape
    support = law_support(law, n, quadrature)
    means = magnitude * support @ shape
    # The offset's value does not change the information: drawn at zero.
    readings = magnitude * oriented_directions(law, draws, n, generator) @ shape
    readings = readings + noise_std * torch.randn(draws, p, generator=generator, dtype=shape.dtype)
    at_grid = magnitude * grid @ shape if grid is not None else None
    scores, law_scores = [], []
    for block in readings.split(250):
        exponents = (block @ means.T - 0.5 * means.pow(2).sum(dim=1)) / noise_std**2
        posterior = torch.softmax(exponents, dim=1)
        first = posterior @ support
        second = torch.einsum("jk,ka,kb->jab", posterior, support, support)
        shape_score = magnitude / noise_std**2 * (first[:, :, None] * block[:, None, :] - magnitude * second @ shape)
        parts = [shape_score.reshape(len(block), n * p)]
        if offsets:
            parts.append((block - magnitude * first @ shape) / noise_std**2)
        scores.append(torch.cat(parts, dim=1))
        if at_grid is not None:
            log_marginal = torch.logsumexp(exponents, dim=1, keepdim=True) - math.log(quadrature)
            law_scores.append(torch.exp((block @ at_grid.T - 0.5 * at_grid.pow(2).sum(dim=1)) / noise_std**2 - log_marginal))
    return torch.cat(scores), torch.cat(law_scores) if grid is not None else None


def gauge_free_trace(shape: torch.Tensor, information: torch.Tensor) -> float:
    """Trace of the shape's part of ``information``'s inverse, the frame's rotation removed as a gauge (the errors
    are taken after aligning it)."""
    n, p = shape.shape
    gauge = torch.stack([(turn @ shape).flatten() for turn in skew_generators(n, shape.dtype)], dim=1)
    gauge = torch.cat([gauge, gauge.new_zeros(information.shape[0] - n * p, gauge.shape[1])])
    basis, _ = torch.linalg.qr(gauge, mode="complete")
    free = basis[:, gauge.shape[1] :]
    covariance = free @ torch.linalg.inv(free.T @ information @ free) @ free.T
    return float(covariance.diagonal()[: n * p].sum())


def known_law_bound(
    shape: torch.Tensor, noise_std: float, magnitude: float, law: str, rows: int, offsets: bool, seed: int,
    draws: int = 2_000, quadrature: int = 20_000,
) -> float:
    """Trace of the shape's Cramer-Rao bound when each of ``rows`` directions is drawn from ``law``, the law known.

    Per row the information is ``E[g g^T]`` with ``g`` the score of the marginal density (:func:`marginal_scores`),
    the expectation by Monte Carlo.
    """
    generator = torch.Generator().manual_seed(seed)
    score, _ = marginal_scores(shape, noise_std, magnitude, law, offsets, generator, draws, quadrature)
    return gauge_free_trace(shape, rows * score.T @ score / draws)


# Ridge strengths (times the mean diagonal of the law scores' Gram matrix) tried for the projection of
# unknown_law_bound; the one that leaves the least information on held-out draws is kept.
PROJECTION_RIDGES = (1e-2, 1e-4, 1e-6, 1e-8)


def unknown_law_bound(
    shape: torch.Tensor, noise_std: float, magnitude: float, law: str, rows: int, offsets: bool, seed: int,
    draws: int = 20_000, grid_size: int | None = None,
) -> float:
    """Trace of the shape's Cramer-Rao bound for an estimator that does not know the law its directions are drawn
    from (any law on the circle or sphere; the noise level known), each of ``rows`` directions drawn from ``law``.

    The semiparametric bound: per row, the information in the part of the shape's score ``g`` that no change of
    the law can mimic, ``E[(g - B h)(g - B h)^T]`` with ``h`` the law's scores on a grid (:func:`marginal_scores`)
    and ``B h`` the projection of ``g`` onto them. ``B`` is fitted by ridge regression on one third of the draws,
    its ridge chosen on another, and the information measured on the last. A ``B`` short of the projection (a
    finite grid, a ridge, Monte Carlo) leaves more information, never less, so this is a lower bound on that
    bound, up to the last third's Monte Carlo error.
    """
    n = shape.shape[0]
    grid = direction_grid(n, grid_size or (720 if n == 2 else 3000))
    generator = torch.Generator().manual_seed(seed)
    parts = [marginal_scores(shape, noise_std, magnitude, law, offsets, generator, draws, grid=grid) for _ in range(3)]
    (fit_g, fit_h), (choose_g, choose_h), (test_g, test_h) = parts
    mean_h = fit_h.mean(dim=0)
    gram = (fit_h - mean_h).T @ (fit_h - mean_h)
    cross = (fit_h - mean_h).T @ fit_g
    scale = float(gram.diagonal().mean())

    def information(ridge: float, g: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        projection = torch.linalg.solve(gram + ridge * scale * torch.eye(len(gram), dtype=gram.dtype), cross)
        left = g - (h - mean_h) @ projection
        return rows * left.T @ left / len(left)

    ridge = max(PROJECTION_RIDGES, key=lambda r: gauge_free_trace(shape, information(r, choose_g, choose_h)))
    return gauge_free_trace(shape, information(ridge, test_g, test_h))


def row_name(n: int, offsets: bool, law: str, snr: float) -> str:
    """A table row's name as ``--only`` takes it, ``n:offsets:law:snr`` (e.g. ``3:yes:band:20``)."""
    return f"{n}:{'yes' if offsets else 'no'}:{law}:{snr:g}"


def law_bound_table(trials: int, snrs: list[float], only: list[str], unknown_law: bool) -> None:
    """Print the ``--law-bounds`` table, a row per law and SNR: sqrt(known-law bound / per-direction bound) and (with
    ``unknown_law``) sqrt(unknown-law bound / per-direction bound), each bound summed over sessions (``only``: rows
    named ``n:offsets:law:snr``)."""
    columns = ["known-law bound / CRB", *(["unknown-law bound / CRB"] if unknown_law else [])]
    print("| n | offsets | law | SNR | " + " | ".join(columns) + " |")
    print("|---|---|---|---|" + "---|" * len(columns))
    for n in (2, 3):
        for offsets in (False, True):
            for law in LAWS[:-1]:
                for snr in snrs:
                    row = row_name(n, offsets, law, snr)
                    if (only and row not in only) or (n == 3 and snr > 20):
                        continue
                    bounds = torch.zeros(1 + len(columns), dtype=torch.float64)
                    for seed in range(trials):
                        datamodule = law_session(n, law, snr, offsets, seed)
                        truth, noise_std, bound = per_direction_bound(datamodule, snr, offsets)
                        recording = datamodule.data.recordings["rotation"]
                        arguments = (truth, noise_std, recording.magnitude, law, len(recording.readings), offsets, seed)
                        bounds += torch.tensor(
                            [bound, known_law_bound(*arguments), *([unknown_law_bound(*arguments)] if unknown_law else [])]
                        )
                    cells = " | ".join(f"{float((b / bounds[0]).sqrt()):.2f}" for b in bounds[1:])
                    print(f"| {n} | {'yes' if offsets else 'no'} | {law} | {snr:g} | {cells} |", flush=True)


def law_contains(law: str, directions: torch.Tensor) -> torch.Tensor:
    """Which of ``k x dims`` unit directions lie in an orientation law's support: ``k`` (bool)."""
    if directions.shape[1] == 3:
        low, high = sphere_zone(law)
        return (directions[:, 2] >= low) & (directions[:, 2] <= high)
    centre, half_width = circle_arc(law)
    angle = torch.atan2(directions[:, 1], directions[:, 0])

    def within(middle: float) -> torch.Tensor:
        return (torch.remainder(angle - middle + math.pi, 2 * math.pi) - math.pi).abs() <= half_width

    return within(centre) | within(centre + math.pi) if law == "band" else within(centre)


class TrueLawMarginal(ShapeFromMotion):
    """The marginal refinement given a session's true law of directions (uniform on its support), held fixed.

    The law is stated in the truth's frame, so the closed form is first turned into it (no known load
    fixes the frame, so the turn changes no likelihood).
    """

    def __init__(self, law: str, truth: torch.Tensor, estimate_offset: bool) -> None:
        # Its law is set once (below) and never learnt, so none of the learnt laws' candidates is built.
        super().__init__(estimate_offset=estimate_offset, refinement="marginal", learnt_law="uniform")
        self.true_law, self.truth = law, truth

    def initialise(self, recording) -> None:
        super().initialise(recording)
        turn = orthogonal_procrustes(self.physical_shape().T, self.truth.T).T
        with torch.no_grad():
            self.shape.copy_(turn.to(self.shape.dtype) @ self.shape)
        weights = law_contains(self.true_law, self.grid).to(self.grid.dtype)
        self.log_prior[:] = (weights / weights.sum()).clamp_min(torch.finfo(weights.dtype).tiny).log()

    def update_law(self, batch) -> None:
        """The law is known: nothing to learn."""


def law_trial(args: tuple) -> tuple[tuple[float, ...], dict]:
    """Squared shape errors of the closed form, alternation, marginal, (with ``true_law``) the marginal given the true
    law (NaN on ``poses``) and auto, the bound, auto's coverage counts, and whether its bars are trusted (with those counts
    again where they are); and what auto's run reported (``--sessions``)."""
    n, law, snr, offsets, seed, optimizer_cfg, learnt_law, tie, true_law, samples, p_equals_n = args
    torch.set_num_threads(1)
    warnings.filterwarnings("ignore")
    datamodule = law_session(n, law, snr, offsets, seed, samples, p_equals_n)
    recording = datamodule.data.recordings["rotation"]
    if not tie:
        # The poses' labels withheld: every row its own direction.
        recording = dataclasses.replace(recording, groups=None)
    truth, noise_std, bound = per_direction_bound(datamodule, snr, offsets)
    fitted = {}
    for refinement in ("alternation", "marginal"):
        model = ShapeFromMotion(estimate_offset=offsets, refinement=refinement, learnt_law=learnt_law)
        model.initialise(recording)
        closed_form = error2(model.physical_shape(), truth, align=True)
        fitted[refinement] = refine_in_process(model, recording, instantiate(optimizer_cfg), initialise=False)
    chooser = ShapeFromMotion(estimate_offset=offsets)
    chooser.initialise(recording)
    auto = fitted[chooser.refinement]
    alignment = orthogonal_procrustes(auto.physical_shape().T, truth.T).T
    loads = auto.fitted_loads(recording)
    uncertainty = auto.uncertainty(recording, loads)
    bars = uncertainty.matrix_std
    matrix = auto.calibration_matrix()
    # The bars are in the fit's own frame, so the truth is turned into it (C = pinv(S)^T turns as S does);
    # turning the fit instead mixes the rows of C, whose bars differ.
    misses = matrix - alignment.T @ datamodule.data.truth.matrix
    within = (misses.abs() < bars).sum()
    # Whether a calibration run would call these bars trustworthy (every goodness-of-fit check passed, the fit sound).
    channels = [f"c{i}" for i in range(recording.readings.shape[1])]
    _, _, goodness = calibration_diagnostics(auto, recording, channels, loads, uncertainty, "N")
    trusted = float(goodness.trustworthy and not auto.fit_failed)
    details = {
        "seed": seed, "refinement": chooser.refinement, "laws_learnt": list(auto.law_learnt),
        "relative_bars": relative_matrix_std(bars, matrix), "relative_error": float(misses.norm() / matrix.norm()),
        "coverage": float(within) / bars.numel(), "error_over_bars": float((misses / bars).pow(2).mean().sqrt()),
        "trusted": bool(trusted), "warnings": [*auto.fit_warnings, *goodness.warnings],
    }
    errors = [error2(model.physical_shape(), truth, align=True) for model in fitted.values()]
    if true_law:
        known = float("nan")
        if law != "poses":
            model = refine_in_process(TrueLawMarginal(law, truth, offsets), recording, instantiate(optimizer_cfg))
            known = error2(model.physical_shape(), truth, align=True)
        errors.append(known)
    auto_error = errors[list(fitted).index(chooser.refinement)]
    sums = closed_form, *errors, auto_error, bound, float(within), float(bars.numel()), trusted, trusted * float(within), trusted * float(bars.numel())
    return sums, details


def code_digest() -> str:
    """A digest of the code a row's figures depend on: every file under ``sfmnet/`` and ``conf/``, and this one."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.blake2b(digest_size=8)
    for path in sorted([*(root / "sfmnet").rglob("*.py"), *(root / "conf").rglob("*.yaml"), Path(__file__).resolve()]):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


class RecordedRow(NamedTuple):
    """A row of ``--record``: its sums over sessions, the digest of the code that measured it and what each session's
    run reported (``details``, None where the record predates them)."""

    sums: list[float]
    code: str
    details: list[dict] | None


def recorded_rows(record: Path | None, key: dict, any_code: bool = False) -> dict[str, RecordedRow]:
    """The rows ``record`` holds measured under ``key`` (the code's digest and the options), by name, the latest entry
    of each row (``any_code``: whatever the digest)."""
    if record is None or not record.exists():
        return {}
    rows = {}
    for line in record.read_text().splitlines():
        entry = json.loads(line)
        code = entry["key"]["code"]
        if entry["key"] == (key | {"code": code} if any_code else key):
            rows[entry["row"]] = RecordedRow(entry["sums"], code, entry.get("details"))
    return rows


def law_table(
    trials: int, snrs: list[float], processes: int, optimizer_cfg, learnt_law: str, only: list[str], tie: bool, true_law: bool,
    samples: int | None = None, p_equals_n: bool = False, record: Path | None = None, from_record: bool = False,
    sessions: bool = False,
) -> None:
    """Print the ``--laws`` table as Markdown, one row at a time (``only``: rows named ``n:offsets:law:snr``, e.g. ``3:yes:band:20``;
    ``record``: see ``--record``; ``from_record``: the record's rows on any code, nothing run, see ``--from-record``;
    ``sessions``: then the sessions' table, see ``--sessions``)."""
    import multiprocessing

    key = {
        "code": code_digest(), "trials": trials, "learnt_law": learnt_law, "tie": tie, "true_law": true_law,
        "samples": samples, "p_equals_n": p_equals_n, "optimizer": OmegaConf.to_container(optimizer_cfg),
    }
    done = recorded_rows(record, key, any_code=from_record)

    columns = ["closed form", "alternation", "marginal", *(["marginal, true law"] if true_law else []), "auto"]
    print("| n | offsets | law | SNR | " + " | ".join(f"{c} / CRB" for c in columns)
          + " | auto 68 % coverage | trusted | coverage of trusted bars |" + (" code |" if from_record else ""))
    print("|---|---|---|---|" + "---|" * (len(columns) + 3 + from_record))
    shown: dict[str, list[dict] | None] = {}
    with contextlib.nullcontext() if from_record else multiprocessing.get_context("spawn").Pool(processes) as pool:
        for n in (2, 3):
            for offsets in (False, True):
                for law in LAWS:
                    for snr in snrs:
                        row = row_name(n, offsets, law, snr)
                        if only and row not in only:
                            continue
                        if row in done:
                            sums = torch.tensor(done[row].sums)
                            shown[row] = done[row].details
                        elif from_record:
                            continue
                        else:
                            jobs = [
                                (n, law, snr, offsets, seed, optimizer_cfg, learnt_law, tie, true_law, samples, p_equals_n)
                                for seed in range(trials)
                            ]
                            figures, details = zip(*pool.map(law_trial, jobs))
                            sums, shown[row] = torch.tensor(figures).sum(dim=0), list(details)
                            if record is not None:
                                record.parent.mkdir(parents=True, exist_ok=True)
                                entry = {
                                    "key": key, "row": row, "sums": sums.tolist(), "sessions": figures, "details": shown[row]
                                }
                                with record.open("a") as file:
                                    file.write(json.dumps(entry) + "\n")
                        *errors, bound, within, entries, trusted, trusted_within, trusted_entries = sums
                        # The true law's column has no figure on poses; a NaN elsewhere is a failed fit and shows as one.
                        cells = [f"{float((e / bound).sqrt()):.2f}" for e in errors]
                        if true_law and law == "poses":
                            cells[3] = "-"
                        ratios = " | ".join(cells)
                        coverage = float(within / entries)
                        trusted_coverage = f"{float(trusted_within / trusted_entries):.2f}" if trusted > 0 else "-"
                        print(
                            f"| {n} | {'yes' if offsets else 'no'} | {law} | {snr:g} | {ratios} | {coverage:.2f} | "
                            f"{float(trusted) / trials:.2f} | {trusted_coverage} |" + (f" {done[row].code} |" if from_record else ""),
                            flush=True,
                        )
    if sessions:
        print_sessions(shown)


def print_sessions(shown: dict[str, list[dict] | None]) -> None:
    """The ``--sessions`` table: a line per session of each row in ``shown`` (row name to its sessions' details)."""
    print("\n| row | seed | auto took | law learnt | bars % | error % | coverage | error / bars | trusted | first warning |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for row, details in shown.items():
        for d in details or []:
            warning = d["warnings"][0][:60] + "..." if d["warnings"] else ""
            print(
                f"| {row} | {d['seed']} | {d['refinement']} | {', '.join(d['laws_learnt']) or '-'} | "
                f"{100 * d['relative_bars']:.1f} | {100 * d['relative_error']:.1f} | {d['coverage']:.2f} | "
                f"{d['error_over_bars']:.2f} | {'yes' if d['trusted'] else 'no'} | {warning} |"
            )
    bare = [row for row, details in shown.items() if details is None]
    if bare:
        print(f"\nRecorded without per-session details (run them again to see them): {' '.join(bare)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--snr", type=float, nargs="+", default=[100, 20, 5, 2])
    parser.add_argument("--known-loads", action="store_true", help="add n exact known loads (else none, as in method §5)")
    parser.add_argument("--refinements", nargs="+", default=list(REFINEMENTS), choices=REFINEMENTS)
    parser.add_argument("--laws", action="store_true", help="the orientation-law table (see above)")
    parser.add_argument("--processes", type=int, default=1, help="trial processes for --laws (one thread each)")
    parser.add_argument("--law-bounds", action="store_true", help="the known-law bound against the per-direction one (see above)")
    parser.add_argument("--unknown-law", action="store_true", help="--law-bounds: add the bound with the law unknown (see above)")
    parser.add_argument("--untied", action="store_true", help="--laws: withhold the poses' labels (no tied directions)")
    parser.add_argument("--learnt-law", default=LEARNT_LAW_DEFAULT, choices=LEARNT_LAWS, help="the marginal's law of directions (model.learnt_law)")
    parser.add_argument("--true-law", action="store_true", help="--laws: add the marginal given the true law of directions (see above)")
    parser.add_argument("--only", nargs="+", default=[], help="--laws or --law-bounds rows to run, as n:offsets:law:snr (e.g. 3:yes:band:20)")
    parser.add_argument("--samples", type=int, default=None, help="--laws: rows per session instead of 96 (n = 2) and 200 (n = 3)")
    parser.add_argument("--p-equals-n", action="store_true", help="--laws: as many channels as axes (see above)")
    parser.add_argument("--record", type=Path, default=None, help="--laws: JSON-lines file of finished rows (see above)")
    parser.add_argument("--from-record", action="store_true", help="--laws --record: print the record's rows on any code, run nothing (see above)")
    parser.add_argument("--sessions", action="store_true", help="--laws: then a line per session of each row shown (see above)")
    args = parser.parse_args()
    if args.from_record and not (args.laws and args.record):
        parser.error("--from-record prints the --laws table from a --record file: give both")
    warnings.filterwarnings("ignore")
    import logging

    logging.getLogger("lightning.pytorch").setLevel(logging.ERROR)
    torch.set_num_threads(1)
    optimizer_cfg = OmegaConf.load(f"{config_dir()}/optimizer/lbfgs.yaml")
    if args.laws:
        law_table(
            args.trials, args.snr, args.processes, optimizer_cfg, args.learnt_law, args.only, not args.untied, args.true_law,
            args.samples, args.p_equals_n, args.record, args.from_record, args.sessions,
        )
        return
    if args.law_bounds:
        law_bound_table(args.trials, args.snr, args.only, args.unknown_law)
        return
    print("| sensor | SNR | closed form / CRB | " + " | ".join(f"{r} / CRB" for r in args.refinements) + " |")
    print("|---|---|" + "---|" * (len(args.refinements) + 1))
    for name, (module_cls, kwargs, rank) in SENSORS.items():
        known = rank if args.known_loads else 0
        for snr in args.snr:
            results = torch.tensor(
                [trial(module_cls, kwargs, known, snr, seed, optimizer_cfg, args.refinements) for seed in range(args.trials)]
            )
            *errors, bound = results.mean(dim=0)
            ratios = " | ".join(f"{float((e / bound).sqrt()):.2f}" for e in errors)
            print(f"| {name} | {snr:g} | {ratios} |", flush=True)


if __name__ == "__main__":
    main()
