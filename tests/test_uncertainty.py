"""Error bars (Cramer-Rao, method §5) that a user can trust: about 68 % of entries within one standard error."""

from __future__ import annotations

import functools
import math

import pytest
import torch

from sfmnet.linalg.uncertainty import relative_matrix_std
from sfmnet.simulators.simulated_sensor import FingertipDataModule, ForceSensor3DataModule
from sfmnet.simulators.simulation import reread_last_known_load
from sfmnet.models.shape_from_motion import ShapeFromMotion
from sfmnet.training.fitting import refine_in_process


def refined(
    model: ShapeFromMotion, recording, initialise: bool = True, epochs: int = 10, tolerance_change: float = 1e-14
) -> ShapeFromMotion:
    """The closed form, then the refinement the trainer runs (conf/optimizer/lbfgs.yaml's L-BFGS), in this process."""
    optimizer = functools.partial(
        torch.optim.LBFGS, max_iter=50, history_size=50, line_search_fn="strong_wolfe", tolerance_grad=1e-10,
        tolerance_change=tolerance_change,
    )
    return refine_in_process(model, recording, optimizer, epochs, initialise)


@pytest.mark.parametrize("channels", [6, 16])
def test_error_bars_are_honest(channels: int):
    """Offsets, orientations crowded towards one pole, n - 1 known loads and the mirror bit."""
    scores = []
    for seed in range(20):
        datamodule = ForceSensor3DataModule(
            magnitude=9.81, channels=channels, samples=150, known_loads=2, offset_scale=0.3,
            orientation_bias=0.7, errors={"angle_error_deg": 0.0}, seed=seed,
        )
        datamodule.setup()
        recording = datamodule.data.recordings["rotation"]
        model = refined(ShapeFromMotion(estimate_offset=True), recording)
        bars = model.uncertainty(recording, model.fitted_loads(recording))
        truth = datamodule.data.truth
        scores.append(((model.calibration_matrix() - truth.matrix) / bars.matrix_std).flatten())
        scores.append((model.physical_offset() - truth.offset) / bars.offset_std)
    scores = torch.cat(scores)
    within = float((scores.abs() < 1).double().mean())
    rms = float(scores.pow(2).mean().sqrt())
    assert 0.62 < within < 0.75, within
    assert 0.85 < rms < 1.2, rms


def test_error_bars_shrink_with_more_samples_except_the_frame():
    """Offsets come from every orientation; the frame's rotation only from the few known loads."""
    bars = {}
    for samples in (50, 800):
        datamodule = ForceSensor3DataModule(magnitude=9.81, samples=samples, known_loads=3, mirror_hint=False, offset_scale=0.2)
        datamodule.setup()
        recording = datamodule.data.recordings["rotation"]
        model = ShapeFromMotion()
        model.initialise(recording)
        bars[samples] = model.uncertainty(recording, model.fitted_loads(recording))
    # 16 times the samples: a quarter of the offsets' standard errors ...
    offset_ratio = float(bars[800].offset_std.norm() / bars[50].offset_std.norm())
    assert offset_ratio == pytest.approx(0.25, rel=0.25)
    # ... but the matrix, whose orientation rests on three known loads, gains far less.
    matrix_ratio = float(bars[800].matrix_std.norm() / bars[50].matrix_std.norm())
    assert 0.5 < matrix_ratio < 1.0


def test_the_frames_share_of_the_bars_is_what_more_known_load_readings_shrink():
    """The default fingertip session (one known load, one row): that row's noise turning the frame is 92 % of the
    matrix's variance. Twenty-five readings of the same load leave the shape's part as it was and divide the frame's
    by 14 (not 25: the offsets' error turns the known load's direction too)."""
    datamodule = FingertipDataModule(magnitude=111.4, offset_scale=0.05, errors={"angle_error_deg": 0.0}, seed=0)
    datamodule.setup()
    recording, truth = datamodule.data.recordings["rotation"], datamodule.data.truth
    repeated = reread_last_known_load(recording, truth, datamodule.noise_fraction, 25, torch.Generator().manual_seed(1))
    shares, totals, shape_parts = [], [], []
    for session in (recording, repeated):
        model = refined(ShapeFromMotion(refinement="alternation"), session)
        bars = model.uncertainty(session, model.fitted_loads(session))
        total = relative_matrix_std(bars.matrix_std, model.calibration_matrix())
        shares.append(bars.frame_share)
        totals.append(total)
        shape_parts.append(total * math.sqrt(1 - bars.frame_share))
    assert shares[0] > 0.85 and shares[1] < 0.5, shares
    assert shape_parts[1] == pytest.approx(shape_parts[0], rel=0.05)
    frame_parts = [total**2 * share for total, share in zip(totals, shares)]
    assert frame_parts[1] < frame_parts[0] / 10 and totals[1] < totals[0] / 2
    without_known = ShapeFromMotion(refinement="alternation")
    assert refined(without_known, recording.without(recording.known)).uncertainty(
        recording.without(recording.known), without_known.fitted_loads(recording.without(recording.known))
    ).frame_share is None


def test_auto_refinement_integrates_directions_out_at_low_snr():
    """At SNR 2 the marginal likelihood is nearer the truth than the alternation (bench: 1.0x against 1.2x the bound)."""
    from sfmnet.simulators.simulated_sensor import FingertipDataModule
    from sfmnet.linalg.frame import orthogonal_procrustes

    errors = {"auto": 0.0, "alternation": 0.0}
    for seed in range(8):
        datamodule = FingertipDataModule(
            magnitude=111.4, samples=96, known_loads=0, mirror_hint=False, noise_fraction=0.5, seed=seed,
            errors={"angle_error_deg": 0.0},
        )
        datamodule.setup()
        recording = datamodule.data.recordings["rotation"]
        truth = torch.linalg.pinv(datamodule.data.truth.matrix.T)
        for refinement in errors:
            model = refined(ShapeFromMotion(estimate_offset=False, refinement=refinement), recording)
            if refinement == "auto":
                assert model.refinement == "marginal" and model.snr < 10
            shape = model.physical_shape()
            aligned = orthogonal_procrustes(shape.T, truth.T).T @ shape
            errors[refinement] += float((aligned - truth).pow(2).sum())
    assert errors["auto"] < 0.85 * errors["alternation"], errors


def test_auto_refinement_keeps_the_alternation_at_good_snr():
    datamodule = ForceSensor3DataModule(magnitude=9.81, known_loads=3, mirror_hint=False, offset_scale=0.2)
    datamodule.setup()
    model = ShapeFromMotion()
    model.initialise(datamodule.data.recordings["rotation"])
    assert model.refinement == "alternation" and model.snr > 50


@pytest.mark.parametrize("channels, tolerance", [(6, 0.1), (3, 0.2)])
def test_auto_s_snr_is_the_simulated_one_whether_p_exceeds_n_or_equals_it(channels, tolerance):
    """The closed form's SNR that ``auto`` chooses by counts the residual's degrees of freedom (each row's direction
    takes up two of its p components): the plain RMS of the residuals overstated it 1.25x at p = 6 and 1.57x at p = 3;
    counted, 1.01x and 0.88x (at p = n the closed form's residuals are all its misfit), hence the wider tolerance."""
    estimates = []
    for seed in range(5):
        datamodule = ForceSensor3DataModule(
            channels=channels, magnitude=9.81, samples=200, known_loads=0, mirror_hint=False, noise_fraction=1 / 20,
            offset_scale=0.1, seed=seed, errors={"angle_error_deg": 0.0},
        )
        datamodule.setup()
        model = ShapeFromMotion(refinement="alternation")
        model.initialise(datamodule.data.recordings["rotation"])
        estimates.append(model.snr)
    assert sum(estimates) / len(estimates) == pytest.approx(20, rel=tolerance), estimates


def test_a_long_recording_s_information_comes_from_an_even_sample():
    """Beyond INFORMATION_SAMPLE_ROWS unknown rows, every k-th stands for k: the information agrees with the full sum."""
    from sfmnet.linalg.uncertainty import INFORMATION_SAMPLE_ROWS, shape_information, unknown_rows_information

    generator = torch.Generator().manual_seed(0)
    shape = torch.randn(3, 6, generator=generator, dtype=torch.float64)
    rows = 3 * INFORMATION_SAMPLE_ROWS + 7
    directions = torch.nn.functional.normalize(torch.randn(rows, 3, generator=generator, dtype=torch.float64), dim=1)
    maps = 9.81 * torch.eye(3, dtype=torch.float64).expand(rows, 3, 3)
    known = 9.81 * torch.eye(3, dtype=torch.float64)
    sampled = shape_information(shape, known, directions, maps, estimate_offset=True)
    full = sum(
        unknown_rows_information(shape, directions[start : start + 50_000], maps[start : start + 50_000], True)
        for start in range(0, rows, 50_000)
    ) + shape_information(shape, known, directions[:0], maps[:0], estimate_offset=True)
    assert float((sampled - full).norm() / full.norm()) < 0.01


def test_an_alternation_that_runs_away_says_so():
    """At SNR 2 on a band of directions the alternation's shape grows without bound (README: 1000x the truth's
    singular value); at SNR 5 it is biased beyond its error bars; the fit says so, where on good data it says nothing."""
    from sfmnet.simulators.simulated_sensor import FingertipDataModule

    def notes(noise_fraction: float, law: str) -> list[str]:
        datamodule = FingertipDataModule(
            magnitude=111.4, samples=96, known_loads=0, mirror_hint=False, noise_fraction=noise_fraction, seed=4,
            orientation_law=law, errors={"angle_error_deg": 0.0},
        )
        datamodule.setup()
        model = refined(ShapeFromMotion(estimate_offset=False, refinement="alternation"), datamodule.data.recordings["rotation"])
        return model.fit_warnings

    assert any(note.startswith("the alternation ran away") for note in notes(0.5, "band"))
    # At SNR 5 it converges, to a shape biased by more than its error bars: said too.
    assert [note[:4] for note in notes(0.2, "uniform")] == ["SNR "]
    assert notes(0.05, "uniform") == []
    assert notes(0.01, "uniform") == []


def test_the_marginal_s_error_bars_rest_on_its_own_direction_estimates():
    """2-axis band of directions at SNR 5, tared, no known loads (bench/crb_ratio.py --laws): a noisy row's argmin
    direction scatters wider than the band, and information evaluated there made the bars too small (the RMS
    matrix error 2.04x the RMS bar over 10 sessions). At the posterior-mean directions under the learnt law
    (:meth:`ShapeFromMotion.information_directions`) it is 1.51x; these 8 sessions 2.15x and 1.58x with the law
    smoothed, 1.43x and 0.92x since it is not (from a direction SNR of 3.5; the error itself smaller)."""
    from sfmnet.simulators.simulated_sensor import FingertipDataModule
    from sfmnet.linalg.frame import orthogonal_procrustes

    squares = {"posterior": 0.0, "argmin": 0.0}
    error2 = 0.0
    for seed in range(8):
        datamodule = FingertipDataModule(
            magnitude=111.4, samples=96, known_loads=0, mirror_hint=False, noise_fraction=0.2, orientation_law="band",
            seed=seed, errors={"angle_error_deg": 0.0},
        )
        datamodule.setup()
        recording = datamodule.data.recordings["rotation"]
        model = refined(ShapeFromMotion(estimate_offset=False), recording)
        assert model.refinement == "marginal"
        truth = datamodule.data.truth.matrix
        # The bars are in the fit's own frame: the truth is turned into it.
        turn = orthogonal_procrustes(model.physical_shape().T, torch.linalg.pinv(truth.T).T).T
        error2 += float((model.calibration_matrix() - turn.T @ truth).pow(2).sum())
        unknown = model.unknown_directions(recording)
        loads = model.fitted_loads(recording, unknown)
        squares["posterior"] += float(model.uncertainty(recording, loads, unknown).matrix_std.pow(2).sum())
        model.information_directions = lambda recording, directions: directions
        squares["argmin"] += float(model.uncertainty(recording, loads, unknown).matrix_std.pow(2).sum())
    ratios = {k: (error2 / v) ** 0.5 for k, v in squares.items()}
    # The premise (bars at the argmin too small), then the mend: a fifth or more off the misfit of the bars, and
    # bars that describe the error.
    assert ratios["argmin"] > 1.3, ratios
    assert ratios["posterior"] < 0.8 * ratios["argmin"], ratios
    assert ratios["posterior"] < 1.1, ratios
