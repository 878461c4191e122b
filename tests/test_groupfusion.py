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


# --------------------------------------------------------------------------------------
# Agreement of the fast kernels (issue 17) with the plain-numpy reference path they replace:
# one suite over seeded Monte Carlo inputs, several systems, batched and unbatched.

#: Relative agreement of every statistic. theta is formed by subtraction from the group's
#: pre-fit sum sum(w y^2) (normal equations, in both paths), so it is compared relative to
#: the larger of itself and that sum: a group with theta ~ 1e-9 (far below any threshold,
#: m(F) ~ 1e-5), or a nearly singular one (PDOP ~ 1e4), differs between any two summation
#: orders in digits that the sum it came from does not carry.
REL = 1e-9


def _seeded_runs(seed, n_runs, n_sat, n_faults, systems=("GPS", "BDS"), bias_m=660.0):
    from raimcore.studies import montecarlo as mc

    return mc.simulate_runs(np.random.default_rng(seed), n_runs, n_sat, n_faults, bias_m,
                            33.0, systems=systems)


def _prefit(y, w, groups):
    """sum(w y^2) of every group, (..., G)."""
    w2 = np.broadcast_to(w, np.shape(y)) * np.square(y)
    return w2 @ gf.membership_matrix(groups, np.shape(y)[-1]).T.astype(float)


def _assert_stats_agree(a, b, prefit):
    np.testing.assert_array_equal(a.ok, b.ok)
    np.testing.assert_array_equal(a.dof, b.dof)
    np.testing.assert_array_equal(a.threshold, b.threshold)
    np.testing.assert_array_equal(np.isnan(a.theta), np.isnan(b.theta))
    scale = np.maximum(np.abs(b.theta), prefit)
    assert np.all(np.abs(a.theta - b.theta) <= REL * scale, where=a.ok)
    np.testing.assert_allclose(a.pdop, b.pdop, rtol=REL)
    # Decisions of each group test identical.
    np.testing.assert_array_equal(a.theta > a.threshold, b.theta > b.threshold)


@pytest.mark.parametrize("systems, n_sat, r", [
    (("GPS", "BDS"), 14, 6), (("GPS", "BDS"), 18, 6), (("GPS", "BDS"), 22, 6),
    (("GPS",), 9, 7),  # one clock, dof 3: the chdtr branch of m(F)
    (("GPS", "BDS", "GAL", "GLO"), 16, 9),
])
def test_fast_group_chi2_agrees_with_the_reference_kernel(systems, n_sat, r):
    h, y, _ = _seeded_runs(n_sat, 60, n_sat, 2, systems)
    g = gf.select_groups(n_sat, r)
    w = 33.0**-2
    fast = gf.group_chi2(h, y, g, P_FA, w)
    ref = gf.group_chi2(h, y, g, P_FA, w, reference=True)
    assert fast.theta.shape == (60, len(g))
    _assert_stats_agree(fast, ref, _prefit(y, w, g))
    # Most groups agree to 1e-9 of theta itself, not only of the pre-fit sum.
    close = np.abs(fast.theta - ref.theta) <= REL * ref.theta
    assert np.mean(close[fast.ok]) > 0.99
    # Unbatched, and per-satellite weights.
    _assert_stats_agree(gf.group_chi2(h[3], y[3], g, P_FA, w),
                        gf.group_chi2(h[3], y[3], g, P_FA, w, reference=True),
                        _prefit(y[3], w, g))
    wv = np.random.default_rng(1).uniform(0.5, 2.0, y.shape) * w
    _assert_stats_agree(gf.group_chi2(h, y, g, P_FA, wv),
                        gf.group_chi2(h, y, g, P_FA, wv, reference=True), _prefit(y, wv, g))
    # ... and against one explicit least squares per group (independent of both).
    for k, j in ((0, 0), (5, len(g) // 2), (59, len(g) - 1)):
        hg = h[k, g[j]][:, np.abs(h[k, g[j]]).sum(0) > 0]
        x, *_ = np.linalg.lstsq(hg, y[k, g[j]], rcond=None)
        want = np.sum((y[k, g[j]] - hg @ x) ** 2) * w
        assert abs(fast.theta[k, j] - want) <= 1e-9 * _prefit(y[k], w, g)[j]


@pytest.mark.parametrize("n_sat, n_faults", [(14, 1), (18, 2), (22, 3)])
def test_fast_isolators_make_the_reference_decisions(n_sat, n_faults):
    h, y, _ = _seeded_runs(100 + n_sat, 250, n_sat, n_faults)
    g = gf.select_groups(n_sat, 6)
    w = 33.0**-2
    a = gf.gf_isolate(h, y, g, P_FA, weights_lsq=w)
    b = gf.gf_isolate(h, y, g, P_FA, weights_lsq=w, reference=True)
    np.testing.assert_array_equal(a.isolated, b.isolated)
    np.testing.assert_allclose(a.m_f, b.m_f, rtol=REL)
    np.testing.assert_allclose(a.threshold, b.threshold, rtol=REL)
    for norm in ("share", "max"):
        qa = gf.qv_isolate(h, y, g, P_FA, weights_lsq=w, norm=norm)
        qb = gf.qv_isolate(h, y, g, P_FA, weights_lsq=w, norm=norm, reference=True)
        np.testing.assert_array_equal(qa[0], qb[0])
        np.testing.assert_allclose(qa[1], qb[1], rtol=REL)
    ra = gf.rs_isolate(h, y, P_FA, np.random.default_rng(7), weights_lsq=w)
    rb = gf.rs_isolate(h, y, P_FA, np.random.default_rng(7), weights_lsq=w, reference=True)
    np.testing.assert_array_equal(ra, rb)
    # The comparison can fail: the isolators do isolate (and differ between seeds for RS).
    assert a.isolated.any() and ra.any()
    assert not np.array_equal(
        ra, gf.rs_isolate(h, y, P_FA, np.random.default_rng(8), weights_lsq=w))


def test_a_nan_run_does_not_poison_its_neighbours():
    h, y, _ = _seeded_runs(3, 20, 16, 1)
    g = gf.select_groups(16, 6)
    clean = gf.group_chi2(h, y, g, P_FA, 33.0**-2)
    y = y.copy()
    y[4, 2] = np.nan
    s = gf.group_chi2(h, y, g, P_FA, 33.0**-2)
    keep = np.arange(20) != 4
    np.testing.assert_array_equal(s.theta[keep], clean.theta[keep])
    assert np.all(np.isnan(s.theta[4, np.any(g == 2, axis=-1)]))
    ref = gf.group_chi2(h, y, g, P_FA, 33.0**-2, reference=True)
    np.testing.assert_array_equal(np.isnan(s.theta), np.isnan(ref.theta))


def test_gf_and_qv_share_group_statistics_but_never_stale_ones():
    h, y, _ = _seeded_runs(4, 30, 16, 2)
    g = gf.select_groups(16, 6)
    r = gf.gf_isolate(h, y, g, P_FA, weights_lsq=33.0**-2)
    with pytest.raises(ValueError, match="read-only"):
        r.groups.theta[0, 0] = 0.0  # shared with the next caller: frozen
    qv_shared = gf.qv_isolate(h, y, g, P_FA, weights_lsq=33.0**-2)
    qv_fresh = gf.qv_isolate(h, y, g, P_FA, weights_lsq=33.0**-2, reference=True)
    np.testing.assert_array_equal(qv_shared[0], qv_fresh[0])
    # Mutating the inputs in place (same array objects) must give new statistics.
    y[:, 5] += 2000.0
    again = gf.gf_isolate(h, y, g, P_FA, weights_lsq=33.0**-2)
    assert again.groups is not r.groups
    assert again.isolated[:, 5].all()
    np.testing.assert_array_equal(again.isolated, gf.gf_isolate(
        h, y, g, P_FA, weights_lsq=33.0**-2, reference=True).isolated)
    # Other weights or p_fa: not the cached answer either.
    other = gf.gf_isolate(h, y, g, 1e-3, weights_lsq=33.0**-2)
    assert not np.array_equal(other.groups.threshold, again.groups.threshold)


@pytest.mark.parametrize("systems", [("GPS", "BDS"), ("GPS", "BDS", "GAL", "GLO")])
def test_fast_propagation_is_the_constellation_propagation_bit_for_bit(systems):
    from raimcore.studies import montecarlo as mc

    t = np.random.default_rng(0).uniform(0.0, 86_400.0, 400)
    fast = mc._positions_ecef_m(systems, t)
    np.testing.assert_array_equal(fast, mc._constellation(systems).positions_ecef_m(t))
    assert fast.shape == (400, len(mc._constellation(systems)), 3)


def test_fuse_in_row_blocks_equals_one_product():
    # fuse cuts its products into row blocks (BLAS on one thread); 300 runs x 400 groups
    # x 20 satellites is 10 blocks, the last one short.
    rng = np.random.default_rng(6)
    g = gf.select_groups(20, 6, 400)
    member = gf.membership_matrix(g, 20)
    m_f = rng.random((300, len(g)))
    alpha = np.where(rng.random(m_f.shape) < 0.1, 0.0, rng.uniform(0.1, 2.0, m_f.shape))
    want = np.einsum("rg,rg,gn->rn", alpha, m_f, member) / np.einsum("rg,gn->rn", alpha,
                                                                        member)
    np.testing.assert_allclose(gf.fuse(m_f, alpha, member), want, rtol=1e-12)
    np.testing.assert_allclose(gf.fuse(m_f[7], alpha[7], member), want[7], rtol=1e-12)


@pytest.mark.parametrize(("n_sat", "r", "n_groups"), [
    (6, 4, None), (9, 5, 20), (12, 6, "all"), (13, 5, 1), (22, 6, None), (17, 8, 300)])
def test_groups_are_itertools_combinations_at_equal_spacing(n_sat, r, n_groups):
    import itertools

    got = gf.select_groups(n_sat, r, n_groups)
    total = math.comb(n_sat, r)
    want_n = total if n_groups == "all" else min(n_sat**2 if n_groups is None else n_groups,
                                                 total)
    step = 1 if want_n >= total else total // want_n
    count = total if step == 1 else total // step
    ref = list(itertools.islice(itertools.combinations(range(n_sat), r), 0, step * count,
                                step))
    assert got.tolist() == [list(c) for c in ref]
