"""MUSIC start-up: spectrum, peak picking, source count (MDL / AIC), batching."""

import numpy as np

from pipeline.cores.array.linear_array import beamwidth_rad, steering_vectors
from pipeline.cores.array.music import (
    angle_grid,
    eigen_decomposition,
    music,
    music_spectrum,
    pick_peaks,
    sample_covariance,
    source_count,
)

M, NS = 15, 30
GRID = angle_grid(np.deg2rad(0.1))


def snapshots(rng, theta, snr_db, trials, n_snapshots=NS, n_sensors=M):
    A = steering_vectors(np.asarray(theta), n_sensors, 0.5)
    N = A.shape[-1]
    S = (rng.standard_normal((trials, N, n_snapshots)) + 1j * rng.standard_normal((trials, N, n_snapshots)))
    S *= np.sqrt(0.5 * 10 ** (snr_db / 10))
    noise = rng.standard_normal((trials, n_sensors, n_snapshots)) + 1j * rng.standard_normal((trials, n_sensors, n_snapshots))
    return A @ S + np.sqrt(0.5) * noise


def test_resolves_two_sources_beyond_the_beamwidth_at_10_db():
    rng = np.random.default_rng(11)
    sep = 1.2 * beamwidth_rad(M)  # 1.2 × (2/M rad) ≈ 9.2°
    theta = np.array([0.1, 0.1 + sep])
    angles, counts, spectrum, _ = music(snapshots(rng, theta, 10.0, 300), 0.5, GRID)
    assert np.all(counts == 2)
    err = np.abs(angles - theta)
    assert np.all(err < np.deg2rad(0.5))  # both peaks found, each well inside its half-beamwidth
    # a dip between the two peaks in every trial
    mid = np.argmin(np.abs(GRID - theta.mean()))
    peaks = [np.argmin(np.abs(GRID - t)) for t in theta]
    assert np.all(spectrum[:, mid] < 0.5 * np.minimum(spectrum[:, peaks[0]], spectrum[:, peaks[1]]))


def test_source_count_is_right_at_10_db():
    rng = np.random.default_rng(12)
    for theta in (np.array([0.1, 0.1 + 1.2 * beamwidth_rad(M)]), np.deg2rad([-30.0, -12.0, 5.0, 25.0, 45.0])):
        X = snapshots(rng, theta, 10.0, 300)
        values, _ = eigen_decomposition(sample_covariance(X))
        mdl = source_count(values, NS, "mdl")
        aic = source_count(values, NS, "aic")
        assert np.all(mdl == len(theta))
        # AIC is not consistent: it overestimates now and then, never underestimates here
        assert np.mean(aic == len(theta)) > 0.7 and np.all(aic >= len(theta))


def test_noise_only_counts_zero_sources():
    rng = np.random.default_rng(13)
    X = snapshots(rng, np.zeros(0), 0.0, 200)
    values, _ = eigen_decomposition(sample_covariance(X))
    assert np.mean(source_count(values, NS, "mdl") == 0) > 0.95


def test_spectrum_matches_the_noise_subspace_definition():
    """Vectorised ‖a‖² − ‖E_sᴴa‖² form against 1 / (aᴴ E_n E_nᴴ a) per angle, by a plain loop."""
    rng = np.random.default_rng(14)
    X = snapshots(rng, np.deg2rad([-10.0, 20.0]), 5.0, 3)
    _, vectors = eigen_decomposition(sample_covariance(X))
    grid = angle_grid(np.deg2rad(1.0))
    for n in (2, 9):  # signal side and noise side of the product
        fast = music_spectrum(vectors, n, grid, 0.5)
        for b in range(3):
            En = vectors[b][:, : M - n]
            slow = [1.0 / np.real(np.conj(a) @ En @ np.conj(En.T) @ a)
                    for a in steering_vectors(grid, M, 0.5).T]
            assert np.allclose(fast[b], slow, rtol=1e-8)


def test_peaks_are_refined_below_the_grid_step_and_sorted():
    theta = np.deg2rad(np.array([-23.37, 11.52]))  # off the grid
    A = steering_vectors(theta, M, 0.5)
    R = A @ np.conj(A.T) * 100 + np.eye(M)  # exact covariance, 20 dB
    _, vectors = eigen_decomposition(R)
    grid = angle_grid(np.deg2rad(0.5))
    spec = music_spectrum(vectors, 2, grid, 0.5)
    refined = pick_peaks(spec, grid, 2)
    coarse = pick_peaks(spec, grid, 2, refine=False)
    assert np.all(np.diff(refined) > 0)
    assert np.all(np.abs(refined - theta) < np.abs(coarse - theta) + 1e-12)
    assert np.all(np.abs(refined - theta) < np.deg2rad(0.05))


def test_batched_over_scans_and_runs_equals_one_by_one():
    rng = np.random.default_rng(15)
    X = snapshots(rng, np.deg2rad([-5.0, 30.0]), 5.0, 12).reshape(3, 4, M, NS)
    angles, counts, spec, _ = music(X, 0.5, GRID)
    for i in range(3):
        for j in range(4):
            a1, c1, s1, _ = music(X[i, j], 0.5, GRID)
            assert c1 == counts[i, j]
            assert np.allclose(s1, spec[i, j]) and np.allclose(a1, angles[i, j, : c1], equal_nan=True)


def test_fewer_peaks_than_asked_are_nan():
    spec = np.array([[0.0, 1.0, 0.0, 0.0, 0.0]])
    out = pick_peaks(spec, np.linspace(-1, 1, 5), 3)
    assert out.shape == (1, 3) and np.isfinite(out[0, 0]) and np.all(np.isnan(out[0, 1:]))
