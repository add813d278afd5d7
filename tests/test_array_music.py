"""MUSIC start-up: spectrum, peak picking, source count (MDL / AIC), batching."""

import numpy as np

from trackreplay.cores.array.linear_array import beamwidth_rad, steering_vectors
from trackreplay.cores.array.music import (
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


def _trace_form_spectrum(vectors, n, grid, spacing):
    """The previous form of the spectrum, kept as the reference: c_l by ``np.trace`` per lag, then
    ``tr C + 2 [Re c, −Im c] · [cos; sin]``, one block at a time."""
    from trackreplay.cores.array.music import lag_exponentials

    m = vectors.shape[-1]
    E = lag_exponentials(grid, m, spacing)
    out = []
    for V in vectors.reshape(-1, m, m):
        signal_side = n <= m // 2
        basis = V[:, m - n:] if signal_side else V[:, : m - n]
        C = basis @ np.conj(basis.T)
        c = np.array([np.trace(C, offset=lag) for lag in range(1, m)])
        quad = np.trace(C).real + 2.0 * (np.concatenate([c.real, -c.imag]) @ E)
        out.append(1.0 / np.maximum(M - quad if signal_side else quad, 1e-15 * m))
    return np.array(out).reshape(vectors.shape[:-2] + (len(grid),))


def test_two_product_spectrum_equals_the_trace_form():
    """C's real view × the fixed coefficient map × [1; cos; sin] (cached table, passed table, one
    block, a batch of 40 — split into row blocks for BLAS at both grids —, mixed counts) against the
    per-lag trace form, to 1e-10 relative at 10 and 20 dB (the difference is rounding in
    ‖E_nᴴa‖² = M − ‖E_sᴴa‖², relative size ≈ ε M P at a peak P)."""
    from trackreplay.cores.array.music import lag_exponentials

    rng = np.random.default_rng(16)
    theta = np.deg2rad([-30.0, -12.0, 5.0, 25.0, 45.0])
    for snr in (10.0, 20.0):
        _, vectors = eigen_decomposition(sample_covariance(snapshots(rng, theta, snr, 40)))
        for grid in (angle_grid(np.pi / 360), angle_grid(np.pi / 1800)):
            lags = lag_exponentials(grid, M, 0.5)
            for n in (1, 5, 7, 8, 9, 14):  # both sides of M // 2
                ref = _trace_form_spectrum(vectors, n, grid, 0.5)
                for got in (music_spectrum(vectors, n, grid, 0.5), music_spectrum(vectors, n, grid, 0.5, lags),
                            music_spectrum(vectors[3], n, grid, 0.5)[None],
                            music_spectrum(vectors.reshape(4, 10, M, M), np.full((4, 10), n), grid, 0.5)):
                    got = got.reshape(ref.shape[0] if got.shape[0] > 1 else 1, -1)
                    want = ref if got.shape[0] > 1 else ref[3:4]
                    rel = np.abs(got - want) / want
                    if n < 14:
                        assert np.max(rel) < 1e-10
                    # any count: within the rounding of ‖E_nᴴa‖² itself, ε M P (n = 14 has peaks of 10⁷)
                    assert np.all(rel <= 1e-12 + 4 * np.finfo(float).eps * M * want)
        mixed = rng.integers(1, M, 40)
        got = music_spectrum(vectors, mixed, angle_grid(np.pi / 360), 0.5)
        for b in range(40):
            want = _trace_form_spectrum(vectors[b], int(mixed[b]), angle_grid(np.pi / 360), 0.5)
            assert np.max(np.abs(got[b] - want) / want) < 1e-10


def test_cached_angle_table_follows_the_grid():
    """The table kept per (M, d/λ, grid) is never reused for another grid of the same size, nor for
    the same array changed in place."""
    rng = np.random.default_rng(17)
    _, vectors = eigen_decomposition(sample_covariance(snapshots(rng, np.deg2rad([-10.0, 20.0]), 10.0, 2)))
    grid = angle_grid(np.deg2rad(1.0))
    first = music_spectrum(vectors, 2, grid, 0.5)
    shifted = grid * 0.5
    assert np.allclose(music_spectrum(vectors, 2, shifted, 0.5), _trace_form_spectrum(vectors, 2, shifted, 0.5),
                       rtol=1e-10)
    grid *= 0.5  # in place
    assert np.allclose(music_spectrum(vectors, 2, grid, 0.5), _trace_form_spectrum(vectors, 2, shifted, 0.5),
                       rtol=1e-10)
    assert np.allclose(music_spectrum(vectors, 2, grid, 0.25), _trace_form_spectrum(vectors, 2, grid, 0.25),
                       rtol=1e-10)
    assert np.array_equal(music_spectrum(vectors, 2, angle_grid(np.deg2rad(1.0)), 0.5), first)
    from trackreplay.cores.array import music as module

    for step in np.linspace(0.5, 1.5, 40):  # many grids and spacings: the kept tables stay bounded
        music_spectrum(vectors, 2, angle_grid(np.deg2rad(step)), 0.5)
        music_spectrum(vectors, 2, np.linspace(-1, 1, 91) * step, step / 2)
    assert module._polynomial_table.cache_info().currsize <= module._TABLES_KEPT


def test_one_spectrum_peaks_equal_the_batched_form_bit_for_bit():
    """pick_peaks of one spectrum (Python floats) and of a batch (arrays): the same bits, also for
    ties, plateaus, zeros, infinities and fewer peaks than asked."""
    rng = np.random.default_rng(18)
    _, vectors = eigen_decomposition(sample_covariance(snapshots(rng, np.deg2rad([-30.0, -12.0, 5.0, 25.0, 45.0]),
                                                                 10.0, 50)))
    grid = angle_grid(np.pi / 360)
    spectra = list(music_spectrum(vectors, 5, grid, 0.5))
    x = np.linspace(-1, 1, 9)
    spectra_small = [np.array([0.0, 1.0, 0.0, 2.0, 2.0, 0.0, 1.0, 0.5, 0.0]),  # zeros around, a plateau
                     np.array([1.0, 3.0, 1.0, 3.0, 1.0, 3.0, 1.0, 0.0, 1.0]),  # ties
                     np.array([1.0, np.inf, 1.0, 2.0, 1.0, 0.0, -1.0, 5.0, 1.0]),  # an infinite peak
                     np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0])]  # none inside
    for batch, g in ((np.array(spectra), grid), (np.array(spectra_small), x)):
        for n in (1, 3, 5, 8):
            for refine in (True, False):
                together = pick_peaks(batch, g, n, refine)
                per_row = pick_peaks(batch, g, np.full(len(batch), n), refine)
                assert np.array_equal(together, per_row, equal_nan=True)
                for b, s in enumerate(batch):
                    assert np.array_equal(pick_peaks(s, g, n, refine), together[b], equal_nan=True)
                    assert np.array_equal(pick_peaks(s[None], g, n, refine)[0], together[b], equal_nan=True)


def test_one_block_equals_its_row_of_a_batch():
    """music() on one block (SciPy's LAPACK zheevd, np.dot, the float peak path) and on a batch
    (numpy's eigh, matmul, the array path): the same counts, eigenvalues, spectra and peaks to rounding."""
    rng = np.random.default_rng(19)
    X = snapshots(rng, np.deg2rad([-30.0, -12.0, 5.0, 25.0, 45.0]), 10.0, 20)
    for n in (5, None):
        angles, counts, spec, values = music(X, 0.5, GRID, n)
        for b in range(len(X)):
            a1, c1, s1, v1 = music(X[b], 0.5, GRID, n)
            assert c1.shape == () and c1 == counts[b]
            assert np.allclose(v1, values[b], rtol=1e-12, atol=1e-12)
            assert np.allclose(s1, spec[b], rtol=1e-9)
            assert np.allclose(a1, angles[b], rtol=0, atol=1e-9, equal_nan=True)
    values, vectors = eigen_decomposition(sample_covariance(X[0]))
    ref_values, ref_vectors = np.linalg.eigh(sample_covariance(X[0]))
    assert np.allclose(values, ref_values, rtol=1e-12)
    assert np.allclose(vectors @ np.diag(values) @ np.conj(vectors.T), sample_covariance(X[0]), atol=1e-12)
    assert np.allclose(np.abs(np.sum(np.conj(vectors) * ref_vectors, axis=0)), 1.0, atol=1e-9)



def test_stacks_shared_among_threads_give_the_bits_of_one_call(monkeypatch):
    """split_over_threads cuts a stack among threads; every matrix goes through the routine it
    would have met in one call (EVDs, inverses; leading axes kept), and a piece's error is raised."""
    import pytest

    import trackreplay.stack_threads as bl

    monkeypatch.setattr(bl, "_cores", lambda: 3)
    monkeypatch.setattr(bl, "THREAD_MIN_WORK", 1)  # split even this small stack
    rng = np.random.default_rng(8)
    X = rng.normal(size=(2, 301, 5, 7)) + 1j * rng.normal(size=(2, 301, 5, 7))
    R = X @ np.conj(np.swapaxes(X, -1, -2))
    pieces = []

    def eigh(a):
        pieces.append(a.shape[0])
        return np.linalg.eigh(a)

    values, vectors = bl.split_over_threads(eigh, R)
    assert sorted(pieces) == [200, 201, 201]  # the flattened stack of 602 in three
    expected = np.linalg.eigh(R)
    assert values.shape == expected[0].shape and vectors.shape == expected[1].shape
    assert values.tobytes() == expected[0].tobytes() and vectors.tobytes() == expected[1].tobytes()
    import trackreplay.batched_linalg

    monkeypatch.setattr(trackreplay.batched_linalg, "stack_runner", None)
    bl.install()  # as a replay does: the core's EVDs go through the splitter, with the same bits
    assert trackreplay.batched_linalg.stack_runner is bl.split_over_threads
    assert all(a.tobytes() == b.tobytes() for a, b in zip(eigen_decomposition(R), expected))
    assert bl.split_over_threads(np.linalg.inv, R).tobytes() == np.linalg.inv(R).tobytes()
    singular = R.copy()
    singular[1, 250] = 0.0
    with pytest.raises(np.linalg.LinAlgError):
        bl.split_over_threads(np.linalg.inv, singular)
    monkeypatch.setattr(bl, "_cores", lambda: 1)  # one core: one call, as before
    pieces.clear()
    bl.split_over_threads(eigh, R)
    assert pieces == [2]
