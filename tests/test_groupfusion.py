"""Group fault detection + evidence fusion (seed 004, spec 4) and its baselines: kernels."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from raimcore.algorithms import groupfusion as gf
from raimcore.studies.montecarlo import random_geometry

P_FA = 1e-5 / 3600
prob = st.floats(0.0, 1.0)
rel = st.floats(1e-3, 1e3)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(prob, rel), min_size=2, max_size=8), st.randoms())
def test_fusion_is_the_alpha_weighted_mean_in_any_order(evidence, rnd):
    # seed 004 eqs. 10-12, applied pairwise in a random order.
    order = list(evidence)
    rnd.shuffle(order)
    m, a = order[0]
    for m2, a2 in order[1:]:
        m, a = gf.combine_pair(m, a, m2, a2)
    ms = np.array([e[0] for e in evidence])
    al = np.array([e[1] for e in evidence])
    want = np.sum(al * ms) / np.sum(al)
    assert m == pytest.approx(want, abs=1e-9)
    assert a == pytest.approx(al.sum(), rel=1e-9)
    # The closed form used by the batched kernel gives the same.
    fused = gf.fuse(ms[None, :], al[None, :], np.ones((len(ms), 1), dtype=bool))
    assert fused[0, 0] == pytest.approx(want, abs=1e-9)


def test_combine_pair_is_not_plain_dempster():
    # A rule that cannot fail this would be trivial: Dempster's rule would give 0.9 here.
    m, _ = gf.combine_pair(0.75, 1.0, 0.75, 1.0)
    assert m == pytest.approx(0.75)


@pytest.mark.parametrize("dof", [1, 2, 3, 6])
def test_basic_belief_half_at_threshold_and_monotone(dof):
    t = stats.chi2.isf(P_FA, dof)
    assert gf.basic_belief(t, dof, P_FA) == pytest.approx(0.5, abs=1e-12)
    theta = np.concatenate([np.linspace(0, 3 * t, 2001), [10 * t, 1e4]])
    m = gf.basic_belief(theta, np.full(theta.shape, dof), P_FA)
    assert m[0] == 0.0
    assert np.all(np.diff(m) >= 0)
    assert np.all((m >= 0) & (m <= 1))
    assert m[-1] == pytest.approx(1.0, abs=1e-9)
    # Just above T the survival-function branch must not jump (CDF differences would).
    assert gf.basic_belief(t * (1 + 1e-9), dof, P_FA) == pytest.approx(0.5, abs=1e-6)


def test_select_groups_equal_spacing():
    g = gf.select_groups(18, 6)  # default ~ N^2
    total = math.comb(18, 6)
    k = total // 324
    assert g.shape == (total // k, 6)
    assert np.all(np.diff(g, axis=1) > 0)
    assert len({tuple(r) for r in g}) == len(g)
    assert gf.select_groups(8, 6, "all").shape == (28, 6)
    with pytest.raises(ValueError, match="n_sat"):
        gf.select_groups(5, 6)


def _rows(u_enu, sys):
    q = 2
    clk = (np.asarray(sys)[:, None] == np.arange(q)).astype(float)
    return np.concatenate([-u_enu, clk], axis=-1)


def _sky(n, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(0, 2 * np.pi, n)
    el = rng.uniform(0.1, 1.4, n)
    return np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)


def test_group_dof_single_and_dual_system():
    u = _sky(10)
    sys = np.array([0, 0, 0, 0, 0, 0, 1, 1, 1, 1])
    h = _rows(u, sys)
    groups = np.array([[0, 1, 2, 3, 4, 5], [0, 1, 2, 3, 6, 7], [4, 5, 6, 7, 8, 9]])
    y = np.random.default_rng(1).standard_normal(10)
    s = gf.group_chi2(h, y, groups, P_FA)
    # One clock (all GPS): dof = 6 - 4 = 2; two clocks: 6 - 5 = 1 (spec 4).
    np.testing.assert_array_equal(s.dof, [2, 1, 1])
    np.testing.assert_allclose(s.threshold, stats.chi2.isf(P_FA, [2, 1, 1]))
    # theta equals the residual sum of squares of an explicit least squares per group.
    for i, g in enumerate(groups):
        hg = h[g][:, np.abs(h[g]).sum(0) > 0]
        x, *_ = np.linalg.lstsq(hg, y[g], rcond=None)
        assert s.theta[i] == pytest.approx(np.sum((y[g] - hg @ x) ** 2), rel=1e-9)


def test_group_chi2_is_chi2_distributed_without_fault():
    rng = np.random.default_rng(5)
    n_runs = 3000
    h, _ = random_geometry(rng, n_runs, 12)
    y = 3.0 * rng.standard_normal((n_runs, 12))
    g = gf.select_groups(12, 6, 50)
    s = gf.group_chi2(h, y, g, P_FA, 1 / 9.0)
    # One group per run: groups of one run share noise, so they are not independent draws.
    pick = np.arange(n_runs) % len(g)
    theta, dof = s.theta[np.arange(n_runs), pick], s.dof[np.arange(n_runs), pick]
    for d, n_min in ((1, 2000), (2, 40)):  # single-system groups are rare in mixed skies
        th = theta[dof == d]
        assert th.size > n_min
        assert stats.kstest(th, stats.chi2(d).cdf).pvalue > 1e-3
    # ... and a wrong dof is rejected (the test can fail).
    assert stats.kstest(theta[dof == 1], stats.chi2(2).cdf).pvalue < 1e-3


def test_batched_equals_per_group_loop_and_unbatched():
    rng = np.random.default_rng(2)
    h, _ = random_geometry(rng, 20, 14)
    y = 33 * rng.standard_normal((20, 14))
    y[:, 3] += 600
    g = gf.select_groups(14, 6)
    a = gf.gf_isolate(h, y, g, P_FA, weights_lsq=33.0**-2)
    b = gf.gf_isolate_loop(h, y, g, P_FA, weights_lsq=33.0**-2)
    np.testing.assert_allclose(a.m_f, b.m_f, rtol=1e-9)
    np.testing.assert_array_equal(a.isolated, b.isolated)
    c = gf.gf_isolate(h[7], y[7], g, P_FA, weights_lsq=33.0**-2)
    np.testing.assert_allclose(c.m_f, a.m_f[7], rtol=1e-9)
    assert a.isolated[:, 3].mean() > 0.9


def test_gf_isolates_two_large_faults_and_nothing_else():
    rng = np.random.default_rng(3)
    h, _ = random_geometry(rng, 50, 18)
    y = 3.0 * rng.standard_normal((50, 18))
    y[:, [2, 11]] += 200.0
    r = gf.gf_isolate(h, y, gf.select_groups(18, 6), P_FA, weights_lsq=1 / 9.0)
    want = np.zeros(18, dtype=bool)
    want[[2, 11]] = True
    assert np.mean(np.all(r.isolated == want, axis=-1)) > 0.9
    assert np.all(r.m_f[:, [2, 11]] > r.threshold[:, None])


def test_baselines_find_one_large_fault():
    rng = np.random.default_rng(4)
    h, _ = random_geometry(rng, 40, 16)
    y = 3.0 * rng.standard_normal((40, 16))
    y[:, 5] += 300.0
    want = np.zeros(16, dtype=bool)
    want[5] = True
    g = gf.select_groups(16, 6)
    rs = gf.rs_isolate(h, y, P_FA, np.random.default_rng(0), weights_lsq=1 / 9.0)
    qv, score, thr = gf.qv_isolate(h, y, g, P_FA, weights_lsq=1 / 9.0)
    par = gf.parity_isolate(h, y, P_FA, weights_lsq=1 / 9.0)
    for iso in (rs, qv, par):
        assert np.mean(np.all(iso == want, axis=-1)) > 0.8
    # The faulty satellite's groups fail far more often than anyone else's.
    assert np.all(score[:, 5] > 0.6)
    assert np.all(np.delete(score, 5, axis=1) < 0.5)


def test_bad_options_raise_naming_the_parameter():
    h = _rows(_sky(8), [0] * 4 + [1] * 4)
    g = gf.select_groups(8, 6)
    with pytest.raises(ValueError, match="weights must be one of pdop, uniform"):
        gf.gf_isolate(h, np.zeros(8), g, P_FA, weights="dop")
    with pytest.raises(ValueError, match="margin"):
        gf.gf_isolate(h, np.zeros(8), g, P_FA, margin=2)
    with pytest.raises(ValueError, match="p_fa"):
        gf.gf_isolate(h, np.zeros(8), g, 0.0)
