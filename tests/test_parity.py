"""Parity-vector method (seed 000): identities, equivalences and statistics."""

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy import stats

from raimcore.algorithms.parity import parity_matrix, parity_statistics, parity_test, sse_test

tol = 1e-9


def random_geometry(rng, m, batch=()):
    """Random line-of-sight geometry above the horizon plus a clock column."""
    u = rng.normal(size=batch + (m, 3))
    u[..., 2] = np.abs(u[..., 2]) + 0.1
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    return np.concatenate([-u, np.ones(batch + (m, 1))], axis=-1)


@settings(max_examples=60, deadline=None)
@given(st.integers(5, 12), st.integers(0, 2**32 - 1), st.sampled_from(["potter", "qr"]))
@example(5, 99999999, "potter")  # a first pivot of 4e-4: Potter's rows lose digits
def test_parity_identities(m, seed, method):
    h = random_geometry(np.random.default_rng(seed), m)
    v = parity_matrix(h, method)
    w = np.eye(m) - h @ np.linalg.solve(h.T @ h, h.T)
    assert v.shape == (m - 4, m)
    # Potter divides row i by its pivot d_i = V_ii: the rounding error of W grows by
    # 1/d_i^2 (measured: 1.4e-9 at d = 4e-4, a satellite of leverage 1 - 1.6e-7).
    # QR is orthogonal by construction.
    pivot2 = np.min(np.diag(v)[: m - 4] ** 2) if method == "potter" else 1.0
    bound = max(tol, 50 * np.finfo(float).eps / pivot2)
    assert np.abs(v @ h).max() < tol
    assert np.abs(v @ v.T - np.eye(m - 4)).max() < bound
    assert np.abs(v.T @ v - w).max() < bound


def test_potter_is_upper_triangular_with_positive_diagonal():
    h = random_geometry(np.random.default_rng(3), 8)
    v = parity_matrix(h, "potter")
    assert np.allclose(np.tril(v, -1), 0.0)
    assert np.all(np.diag(v) > 0)


@settings(max_examples=40, deadline=None)
@given(st.integers(6, 11), st.integers(0, 2**32 - 1))
def test_potter_and_qr_statistics_agree_and_equal_sse(m, seed):
    rng = np.random.default_rng(seed)
    h = random_geometry(rng, m)
    z = rng.normal(size=m) * 5.0 + h @ rng.normal(size=4) * 100.0
    a = parity_test(h, z, 5.0, 1e-3, method="qr")
    b = parity_test(h, z, 5.0, 1e-3, method="potter")
    sse, thr, _ = sse_test(h, z, 5.0, 1e-3)
    assert np.isclose(a.statistic, b.statistic, rtol=1e-9)
    assert np.allclose(a.isolation, b.isolation, rtol=1e-8)
    assert np.isclose(a.statistic, sse, rtol=1e-9)  # DF_D == SSE / sigma^2
    assert np.isclose(a.threshold, thr)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_statistics_invariant_to_satellite_order(seed):
    rng = np.random.default_rng(seed)
    h = random_geometry(rng, 8)
    z = rng.normal(size=8)
    perm = rng.permutation(8)
    a = parity_test(h, z, 1.0, 1e-3)
    b = parity_test(h[perm], z[perm], 1.0, 1e-3)
    assert np.isclose(a.statistic, b.statistic)
    assert np.allclose(a.isolation[perm], b.isolation)


def test_batched_equals_loop_and_masked_form():
    rng = np.random.default_rng(7)
    h = random_geometry(rng, 9, (50,))
    z = rng.normal(size=(50, 9)) * 2.0
    batch = parity_test(h, z, 2.0, 1e-4)
    for i in range(50):
        one = parity_test(h[i], z[i], 2.0, 1e-4)
        assert np.isclose(one.statistic, batch.statistic[i])
        assert np.allclose(one.isolation, batch.isolation[i])
        assert one.faulty == batch.faulty[i]
    w = np.full((50, 9), 1 / 4.0)
    masked = parity_statistics(h, z, w, 1e-4, np.full(50, 5))
    assert np.allclose(masked.statistic, batch.statistic)
    assert np.allclose(masked.isolation, batch.isolation)
    assert np.allclose(masked.fault_size_m, batch.fault_size_m)


def test_masked_form_equals_dense_subset():
    rng = np.random.default_rng(8)
    h = random_geometry(rng, 10)
    z = rng.normal(size=10)
    keep = np.array([1, 1, 0, 1, 1, 1, 0, 1, 1, 1], dtype=bool)
    dense = parity_test(h[keep], z[keep], 1.0, 1e-3)
    w = keep.astype(float)
    z_nan = np.where(keep, z, np.nan)
    masked = parity_statistics(h, z_nan, w, 1e-3, keep.sum() - 4)
    assert np.isclose(masked.statistic, dense.statistic)
    assert np.allclose(masked.isolation[keep], dense.isolation)
    assert np.all(np.isnan(masked.isolation[~keep]))


def test_isolation_finds_a_large_bias_and_estimates_its_size():
    rng = np.random.default_rng(11)
    h = random_geometry(rng, 10)
    b = np.zeros(10)
    b[4] = 80.0
    res = parity_test(h, rng.normal(size=10) + b, 1.0, 1e-5)
    assert res.alarm and res.faulty == 4
    assert abs(res.fault_size_m[4] - 80.0) < 5.0


def test_false_alarm_rate_matches_p_fa():
    rng = np.random.default_rng(2024)
    n, p_fa = 200_000, 0.01
    h = random_geometry(rng, 7, (n,))
    z = rng.normal(size=(n, 7)) * 3.0
    alarms = int(parity_test(h, z, 3.0, p_fa).alarm.sum())
    assert stats.binomtest(alarms, n, p_fa).pvalue > 1e-3


def test_detection_rate_matches_ncx2():
    rng = np.random.default_rng(99)
    n, p_fa, sigma = 100_000, 1e-3, 3.0
    h = np.broadcast_to(random_geometry(rng, 8), (n, 8, 4))
    v = parity_matrix(h[0])
    b = np.zeros(8)
    b[2] = 15.0
    lam = np.sum((v @ b) ** 2) / sigma**2
    pd = stats.ncx2.sf(stats.chi2.isf(p_fa, 4), 4, lam)
    assert 0.2 < pd < 0.95  # a discriminating operating point
    z = rng.normal(size=(n, 8)) * sigma + b
    hits = int(parity_test(h, z, sigma, p_fa).alarm.sum())
    assert stats.binomtest(hits, n, pd).pvalue > 1e-3


def test_no_isolation_with_one_redundant_measurement():
    rng = np.random.default_rng(5)
    h = random_geometry(rng, 5)
    res = parity_test(h, np.array([0, 0, 0, 0, 100.0]), 1.0, 1e-3)
    assert res.alarm and res.faulty == -1 and np.all(np.isnan(res.isolation))


@pytest.mark.parametrize("kwargs, message", [
    ({"p_fa": 1.5}, "p_fa must be a probability"),
    ({"p_fa": 0.0}, "p_fa must be a probability"),
    ({"sigma_m": -1.0}, "sigma_m must be finite and > 0"),
    ({"z": np.ones(3)}, r"z must have shape \(\.\.\., 6\) to match h \(\.\.\., 6, 4\)"),
    ({"h": np.ones((4, 4))}, "more rows"),
    ({"z": np.full(6, np.nan)}, "z must contain only finite values"),
])
def test_bad_inputs_raise_clear_errors(kwargs, message):
    rng = np.random.default_rng(0)
    args = {"h": random_geometry(rng, 6), "z": np.zeros(6), "sigma_m": 1.0, "p_fa": 1e-3}
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        parity_test(**args)


def test_bad_method_named():
    with pytest.raises(ValueError, match="method must be one of potter, qr"):
        parity_matrix(random_geometry(np.random.default_rng(0), 6), "svd")
