"""ARAIM MHSS kernel (raimcore.araim): shared/ARAIM.md sections 3-9 and 12.

Reference values: Blanch et al., ION GNSS 2012 ("B2012"), Appendix J worked example
(10 satellites, 2 constellations), kept below in ``B2012_APPENDIX_J`` with their source.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as hs
from scipy import optimize, stats
from scipy.special import ndtr, ndtri

from raimcore.araim import (
    PARAMS,
    defaults,
    determine_modes,
    mhss,
    p_at_least,
    sigma_tropo_m,
    sigma_user_add_m,
    sigma_user_ed259a_m,
)
from raimcore.araim.modes import mode_keys, restrict_modes

one_cm = 1e-2
one_mm = 1e-3
ADD = "add-v4.2"
B2012 = "blanch-2012"

# ----------------------------------------------------------------------------------------
# Reference: B2012 Appendix J worked example. Source: Blanch J., Walter T., Enge P., Lee Y.,
# Pervan B., Rippl M., Spletter A., "Advanced RAIM user algorithm description: integrity
# support message processing, fault detection, exclusion, and protection level
# calculation", ION GNSS 2012, Appendix J; numbers as transcribed (G, C_int, C_acc, the
# assumptions and the results) in a public MATLAB reproduction of the appendix
# ("araim_blanch_et_al.m", found with the code search; the paper itself was not reachable
# here). The paper's "10e-4" etc. are read as 1e-4 (10^-4): P_sat = 1e-4 is the only
# value consistent with its N_sat,max = 2.
B2012_APPENDIX_J = {
    "G": np.array([[0.0225, 0.9951, -0.0966, 1, 0],
                   [0.6750, -0.6900, -0.2612, 1, 0],
                   [0.0723, -0.6601, -0.7477, 1, 0],
                   [-0.9398, 0.2553, -0.2269, 1, 0],
                   [-0.5907, -0.7539, -0.2877, 1, 0],
                   [-0.3236, -0.0354, -0.9455, 0, 1],
                   [-0.6748, 0.4356, -0.5957, 0, 1],
                   [0.0938, -0.7004, -0.7075, 0, 1],
                   [0.5571, 0.3088, -0.7709, 0, 1],
                   [0.6622, 0.6958, -0.2780, 0, 1]]),
    "C_int": np.array([3.8865, 1.4377, 0.8604, 1.6383, 1.3229, 0.8434, 0.8963, 0.8669,
                       0.8573, 1.3616]),  # m^2
    "C_acc": np.array([3.5740, 1.1252, 0.5479, 1.3258, 1.0104, 0.5309, 0.5838, 0.5544,
                       0.5448, 1.0491]),  # m^2
    "sigma_ura_m": 0.75, "sigma_ure_m": 0.50, "b_nom_m": 0.50, "p_sat": 1e-4,
    "p_const": 1e-4,
    # Results (rounded as published)
    "n_sat_max": 2, "n_const_max": 1, "n_modes": 57, "k_fa_v": 5.3953,
    "sigma_3_const_m": (2.5760, 2.5577), "sigma_ss_3_const_m": (1.5307, 1.5292),
    "b_3_const_m": (2.8935, 2.0875),
    "vpl_m": 19.7, "hpl_m": 14.9, "emt_m": 11.8, "sigma_acc_v_m": 1.47,
}


def b2012_args(ref=B2012_APPENDIX_J):
    n = len(ref["C_int"])
    return (ref["G"], np.sqrt(ref["C_int"]), np.sqrt(ref["C_acc"]),
            np.full(n, ref["b_nom_m"]), np.zeros(n), np.full(n, ref["p_sat"]),
            np.full(2, ref["p_const"]))


# ------------------------------------------------------------------------------ helpers


def geometry(az_deg, el_deg, cons, n_const):
    """Rows [-u_E, -u_N, -u_U, one-hot clock] from azimuths and elevations (deg)."""
    az, el = np.radians(az_deg), np.radians(el_deg)
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)
    clock = (np.asarray(cons)[:, None] == np.arange(n_const)).astype(float)
    return np.concatenate([-u, np.broadcast_to(clock, u.shape[:-1] + (n_const,))], axis=-1)


# 7 GPS + 6 Galileo satellites, a fixed open-sky geometry.
AZ = np.array([10, 70, 135, 200, 250, 300, 330, 40, 100, 170, 225, 280, 350.0])
EL = np.array([60, 25, 40, 15, 70, 35, 10, 50, 20, 65, 30, 12, 45.0])
CONS = np.array([0] * 7 + [1] * 6)


def sky(**over):
    """Arguments of mhss for the 13-satellite sky (MAAST-like ISM, ADD airborne model)."""
    g = geometry(AZ, EL, CONS, 2)
    el = np.radians(EL)
    system = np.where(CONS == 0, "GPS", "GAL")
    common = sigma_tropo_m(el) ** 2 + sigma_user_add_m(el, system) ** 2
    ura = np.where(CONS == 0, 1.0, 1.5)
    s_int = np.sqrt(ura**2 + common)
    s_acc = np.sqrt((0.66 * ura) ** 2 + common)
    args = dict(G=g, sigma_int_m=s_int, sigma_acc_m=s_acc, b_int_m=np.full(13, 0.75),
                b_acc_m=np.full(13, 0.25), p_sat=np.where(CONS == 0, 1e-5, 3e-5),
                p_const=np.array([1e-8, 2e-4]))
    args.update(over)
    return args


def call(args, **kw):
    a = dict(args)
    return mhss(a.pop("G"), a.pop("sigma_int_m"), a.pop("sigma_acc_m"), a.pop("b_int_m"),
                a.pop("b_acc_m"), a.pop("p_sat"), a.pop("p_const"), **a, **kw)


def qm(x):
    return np.where(x < 0, 1.0, ndtr(-np.maximum(x, 0.0)))


def q_inv(p):
    return -ndtri(p)


def subset_matrix(g, cint, removed):
    """Position rows of the subset WLS matrix by a pseudo-inverse (independent path)."""
    n = len(cint)
    keep = ~removed
    cols = [0, 1, 2] + [c for c in range(3, g.shape[1]) if np.any(g[keep, c] != 0)]
    sw = 1.0 / np.sqrt(cint[keep])
    s_red = np.linalg.pinv(sw[:, None] * g[keep][:, cols]) * sw[None, :]
    s = np.zeros((3, n))
    s[:, keep] = s_red[:3]
    return s


# ------------------------------------------------------------------------- validation


def test_b2012_appendix_j_error_model():
    """C_int of the worked example = sigma_URA^2 + tropo^2 + GPS airborne^2 (section 2)."""
    ref = B2012_APPENDIX_J
    g = ref["G"]
    el = np.arcsin(-g[:, 2] / np.linalg.norm(g[:, :3], axis=1))
    common = sigma_tropo_m(el) ** 2 + sigma_user_add_m(el, "GPS") ** 2
    np.testing.assert_allclose(ref["sigma_ura_m"] ** 2 + common, ref["C_int"], atol=1e-4)
    np.testing.assert_allclose(ref["sigma_ure_m"] ** 2 + common, ref["C_acc"], atol=1e-4)


def test_b2012_appendix_j_worked_example():
    ref = B2012_APPENDIX_J
    res = mhss(*b2012_args(), rules=B2012, tol_pl_m=1e-4)
    assert res.status == "ok"
    assert res.n_modes == ref["n_modes"] == 10 + 45 + 2
    assert res.k_fa[2] == pytest.approx(ref["k_fa_v"], abs=1e-4)
    assert np.round(res.vpl_m, 1) == ref["vpl_m"]
    assert np.round(res.hpl_m, 1) == ref["hpl_m"]
    assert np.round(res.emt_m, 1) == ref["emt_m"]
    assert np.round(res.sigma_acc_v_m, 2) == ref["sigma_acc_v_m"]
    m = res.modes
    const_modes = np.flatnonzero(m.consts.any(axis=-1))
    assert len(const_modes) == 2
    np.testing.assert_allclose(m.sigma_m[const_modes, 2], ref["sigma_3_const_m"], atol=1e-4)
    np.testing.assert_allclose(m.sigma_ss_m[const_modes, 2], ref["sigma_ss_3_const_m"],
                               atol=1e-4)
    np.testing.assert_allclose(m.bias_m[const_modes, 2], ref["b_3_const_m"], atol=1e-4)
    ml = determine_modes(CONS[:0].tolist() + [0] * 5 + [1] * 5, np.full(10, 1e-4),
                         np.full(2, 1e-4), rules=B2012)
    assert ml.n_max == (ref["n_sat_max"], ref["n_const_max"])


def test_b2012_default_tolerance_and_maast_cap_bracket_the_root():
    """The published PLs lie in [root, root + TOL_PL] at the default tolerance; MAAST's
    10-step cap never goes below the root."""
    tight = mhss(*b2012_args(), rules=B2012, tol_pl_m=1e-6)
    for kw in ({}, {"pl_max_iter": 10}):
        res = mhss(*b2012_args(), rules=B2012, **kw)
        for name in ("vpl_m", "hpl1_m", "hpl2_m"):
            root = getattr(tight, name)
            assert root - 1e-6 <= getattr(res, name) <= root + 5e-2 + 1e-9


# --------------------------------------------------------------------- section 12 checks


@pytest.mark.parametrize("rules", [ADD, B2012])
def test_fault_free_only_is_k_sigma_plus_b(rules):
    """All priors 0: VPL = Q^-1(PHMI_V'/2) sigma_3 + b_3, HPL_q likewise (section 12)."""
    res = call(sky(p_sat=np.zeros(13), p_const=np.zeros(2)), rules=rules)
    assert res.n_modes == 0 and res.p_not_monitored == 0.0
    pv, ph = defaults(rules)["phmi_vert"], defaults(rules)["phmi_hor"]
    assert res.phmi_vert_alloc == pytest.approx(pv)
    assert res.phmi_hor_alloc == pytest.approx(ph / 2)
    want = q_inv(np.array([ph / 4, ph / 4, pv / 2])) * res.sigma_m + res.bias_m
    got = np.array([res.hpl1_m, res.hpl2_m, res.vpl_m])
    assert np.all(got >= want - 1e-9) and np.all(got <= want + 5e-2 + 1e-9)
    assert res.emt_m == 0.0


@pytest.mark.parametrize("rules", [ADD, B2012])
@pytest.mark.parametrize("c", [0.3, 7.0])
def test_scaling_sigmas_and_biases_scales_pls_and_emt(rules, c):
    base = sky()
    scaled = dict(base, **{k: c * base[k] for k in
                           ("sigma_int_m", "sigma_acc_m", "b_int_m", "b_acc_m")})
    r0 = call(base, rules=rules)
    r1 = call(scaled, rules=rules, tol_pl_m=c * 5e-2)
    for name in ("vpl_m", "hpl_m", "hpl1_m", "hpl2_m", "emt_m", "sigma_acc_v_m"):
        assert getattr(r1, name) == pytest.approx(c * getattr(r0, name), rel=1e-9), name
    assert r1.n_modes == r0.n_modes


def pl_lhs(res, axis, a_cap):
    """The section 7 equation written out from the mode table (independent of the
    bisection): 2 Qm((L - b0)/s0) + sum_k p_k min(Qm((L - T_k - b_k)/s_k), a_k)."""
    m = res.modes
    mon = m.monitored.copy()
    mon[0] = False
    s0, b0 = res.sigma_m[axis], res.bias_m[axis]
    t, b, s, p = (m.threshold_m[mon, axis], m.bias_m[mon, axis], m.sigma_m[mon, axis],
                  m.p_inst[mon])
    a = a_cap[mon]

    def lhs(x):
        return 2 * qm((x - b0) / s0) + np.sum(p * np.minimum(qm((x - t - b) / s), a))
    return lhs


@pytest.mark.parametrize("rules,kw", [
    (ADD, {}),
    (ADD, {"max_pmd": True, "n_es_int": 25.0, "n_es_cont": 25.0,
           "t_exp_over_mfd": 150 / 3600, "p_thres": 6e-8, "tol_pl_m": 1e-2}),
    (B2012, {}),
])
def test_each_pl_is_the_root_of_its_equation(rules, kw):
    res = call(sky(), rules=rules, **kw)
    prm = res.params
    m = res.modes
    if prm["max_pmd"]:
        a_cap = np.minimum(m.p_exp / (m.p_inst * prm["n_es_int"]), 1.0)
    else:
        a_cap = np.ones_like(m.p_inst)
    targets = [res.phmi_hor_alloc, res.phmi_hor_alloc, res.phmi_vert_alloc]
    pls = [res.hpl1_m, res.hpl2_m, res.vpl_m]
    for axis in range(3):
        lhs = pl_lhs(res, axis, a_cap)
        root = optimize.brentq(lambda x, f=lhs, t=targets[axis]: f(x) - t, 0.0, 1e4,
                               xtol=1e-10)
        assert root - 1e-7 <= pls[axis] <= root + prm["tol_pl_m"] + 1e-9
    assert res.hpl_m == pytest.approx(np.hypot(res.hpl1_m, res.hpl2_m))
    # PHMI allocations of section 7
    pv, ph, pnm = prm["phmi_vert"], prm["phmi_hor"], res.p_not_monitored
    assert res.phmi_vert_alloc == pytest.approx((pv - pv * pnm / (pv + ph)) / prm["n_es_int"])
    assert res.phmi_hor_alloc == pytest.approx(
        (ph / 2 - ph / 2 * pnm / (pv + ph)) / prm["n_es_int"])


@pytest.mark.parametrize("case", ["add", "b2012", "three-out", "lone-gal"])
def test_subset_statistics_equal_a_pseudo_inverse(case):
    """sigma, b, sigma_ss, b_ss and (S^(k) - S^(0)) y of every monitored mode equal those of
    pinv(W_k^1/2 G_k) W_k^1/2 (section 5), for down-dated and directly solved modes."""
    rng = np.random.default_rng(3)
    args = sky(y=rng.normal(0.0, 2.0, 13))
    kw = {}
    if case == "b2012":
        kw = {"rules": B2012}
    elif case == "three-out":  # high priors: N_max = 3, some 3-satellite modes taken
        args.update(p_sat=np.full(13, 2e-3), p_const=np.array([1e-3, 1e-3]))
        kw = {"p_thres": 1e-9}
    elif case == "lone-gal":  # one Galileo satellite: its single mode drops a clock
        keep = np.r_[np.arange(7), 7]
        args = {k: (v[keep] if np.ndim(v) and np.shape(v)[0] == 13 else v)
                for k, v in args.items()}
    res = call(args, **kw)
    m = res.modes
    g = args["G"]
    cint, cacc = args["sigma_int_m"] ** 2, args["sigma_acc_m"] ** 2
    s0 = subset_matrix(g, cint, np.zeros(len(cint), bool))
    sizes = set()
    for k in np.flatnonzero(m.monitored):
        s = subset_matrix(g, cint, m.sats[k])
        ds = s - s0
        np.testing.assert_allclose(m.sigma_m[k], np.sqrt((s**2) @ cint), rtol=1e-9)
        np.testing.assert_allclose(m.bias_m[k], np.abs(s) @ args["b_int_m"], rtol=1e-9)
        np.testing.assert_allclose(m.sigma_ss_m[k], np.sqrt((ds**2) @ cacc),
                                   rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(m.bias_ss_m[k], np.abs(ds) @ args["b_acc_m"],
                                   rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(m.separation_m[k], ds @ args["y"], rtol=1e-7,
                                   atol=1e-9)
        sizes.add(int(m.sats[k].sum()))
    np.testing.assert_allclose(res.dx_enu_m, s0 @ args["y"], rtol=1e-9)
    np.testing.assert_allclose(res.sigma_acc_v_m, np.sqrt((s0[2] ** 2) @ cacc), rtol=1e-9)
    if case == "three-out":
        assert 3 in sizes
    if case == "lone-gal":  # the Galileo satellite's mode is monitorable, sigma_ss = 0
        k = np.flatnonzero(m.sats[:, 7] & (m.sats.sum(-1) == 1))[0]
        assert m.monitored[k] and np.all(m.sigma_ss_m[k] < 1e-9)


def test_thresholds_follow_section_6():
    res = call(sky())
    m, prm = res.modes, res.params
    n = res.n_modes
    assert n == m.monitored.sum() - 1
    k_h = q_inv(prm["p_fa_hor"] / (4 * prm["n_es_cont"] * n))
    k_v = q_inv(prm["p_fa_vert"] / (2 * prm["n_es_cont"] * n))
    np.testing.assert_allclose(res.k_fa, [k_h, k_h, k_v])
    mon = m.monitored.copy()
    mon[0] = False
    np.testing.assert_allclose(m.threshold_m[mon],
                               res.k_fa * m.sigma_ss_m[mon] + m.bias_ss_m[mon])
    np.testing.assert_array_equal(m.threshold_m[0], 0.0)
    sel = mon & (m.p_inst >= prm["p_emt"])
    assert res.emt_m == pytest.approx(np.max(m.threshold_m[sel, 2]))


# ----------------------------------------------------------------- hand-built mode lists


def test_hand_built_mode_list_add():
    """7 GPS + 6 GAL, MAAST's ISM priors (GPS 1e-5 / 1e-8, GAL 3e-5 / 2e-4): N_max = 2;
    every same-constellation pair and {sat, own constellation} consolidates (GPS: 1e-10 x
    P0 < 0.01 x 1e-8; GAL: < 0.01 x 2e-4); the 13 singles and the GAL constellation are
    above PHMI; what is left (GPS constellation with its consolidated pairs 1.2e-8, 42
    cross pairs 1.26e-8, 7 GPS sat + GAL constellation 1.4e-8) sums to 3.9e-8 < P_THRES =
    8e-8, so nothing else is taken: 14 modes."""
    res = call(sky())
    m = res.modes
    assert m.valid.sum() == 15  # fault-free + 13 singles + GAL constellation
    assert res.n_modes == 14
    singles = m.sats.sum(-1) == 1
    assert singles.sum() == 13
    gal = np.flatnonzero(m.consts[:, 1])
    assert len(gal) == 1 and np.array_equal(m.sats[gal[0]], CONS == 1)
    np.testing.assert_allclose(res.k_fa, q_inv(np.array([9e-8 / 56, 9e-8 / 56,
                                                         3.9e-6 / 28])))
    # P_nm: what the determination leaves out, exactly
    p = np.r_[sky()["p_sat"], sky()["p_const"]]
    q, p0 = p / (1 - p), np.prod(1 - p)
    monitored = p0 * (1 + q[:13].sum()) + m.p_inst[gal[0]]
    assert res.p_not_monitored == pytest.approx(1 - monitored, rel=1e-6)
    assert 3.8e-8 < res.p_not_monitored < 3.95e-8


def test_consolidation_into_the_constellation_mode():
    """The GAL constellation mode holds its own exact prior plus every consolidated
    same-constellation set; with FC_THRES = 0 nothing consolidates (section 4 step 3)."""
    args = sky()
    p = np.r_[args["p_sat"], args["p_const"]]
    q, p0 = p / (1 - p), np.prod(1 - p)
    gal = np.flatnonzero(CONS == 1)
    qc = q[13 + 1]
    pairs = sum(q[i] * q[j] for i in gal for j in gal if i < j)
    with_own = sum(q[i] * qc for i in gal)
    want = p0 * (qc + pairs + with_own)
    res = call(args)
    k = np.flatnonzero(res.modes.consts[:, 1])[0]
    assert res.modes.p_inst[k] == pytest.approx(want, rel=1e-12)
    raw = call(args, fc_thres=0.0)
    k = np.flatnonzero(raw.modes.consts[:, 1] & (raw.modes.sats.sum(-1) == 6))[0]
    assert raw.modes.p_inst[k] == pytest.approx(p0 * qc, rel=1e-12)
    # Without consolidation the same-constellation pairs stay in P_nm, which then exceeds
    # P_THRES: the walk takes pairs until it is below.
    assert raw.n_modes > res.n_modes
    assert raw.p_not_monitored <= 8e-8


def test_hand_built_mode_list_b2012():
    """B2012 with P_sat = P_const = 1e-4 on 13 satellites: N_sat,max = 2 (P(>= 3) ~ 3e-10),
    N_const,max = 1 (P(>= 2) = 1e-8): 13 + 78 + 2 = 93 modes, no consolidation."""
    args = sky(p_sat=np.full(13, 1e-4), p_const=np.full(2, 1e-4))
    res = call(args, rules=B2012)
    assert res.n_modes == 93
    np.testing.assert_allclose(res.k_fa[2], q_inv(3.9e-6 / (2 * 93)))
    want_pnm = p_at_least(np.full(13, 1e-4), 3) + p_at_least(np.full(2, 1e-4), 2)
    assert res.p_not_monitored == pytest.approx(want_pnm, rel=1e-9)
    assert 1e-8 < res.p_not_monitored < 1.1e-8


def test_p_at_least_matches_enumeration():
    rng = np.random.default_rng(1)
    p = rng.uniform(1e-4, 0.2, 7)
    import itertools
    for r in (1, 2, 3):
        exact = sum(np.prod([p[i] if i in s else 1 - p[i] for i in range(7)])
                    for k in range(r, 8) for s in itertools.combinations(range(7), k))
        assert p_at_least(p, r) == pytest.approx(exact, rel=1e-9)
    assert p_at_least(p, 4) == pytest.approx(p.sum() ** 4 / 24)


def test_emt_excludes_modes_just_below_p_emt():
    """GPS only with P_sat = P_EMT: each single-satellite mode's exact prior is P0 q < P_EMT,
    so no mode enters the EMT (MAAST: EMT = eps; ARAIM.md section 8)."""
    keep = CONS == 0
    args = {k: (v[keep] if np.ndim(v) and np.shape(v)[0] == 13 else v)
            for k, v in sky().items()}
    args["G"] = args["G"][:, :4]
    args.update(p_sat=np.full(7, 1e-5), p_const=np.array([1e-8]))
    res = call(args)
    assert res.status == "ok" and res.n_modes >= 7
    assert res.emt_m == 0.0
    assert call(args, p_emt=0.99e-5).emt_m > 0.0


# ----------------------------------------------------------- batching, NaN rows, status


def random_batch(rng, shape, n_sat=13):
    az = rng.uniform(0, 360, shape + (n_sat,))
    el = rng.uniform(-10, 85, shape + (n_sat,))
    g = geometry(az, el, CONS[:n_sat], 2)
    g[el < 5] = np.nan
    s = rng.uniform(0.8, 3.0, shape + (n_sat,))
    return dict(G=g, sigma_int_m=s, sigma_acc_m=0.8 * s, b_int_m=np.full(n_sat, 0.5),
                b_acc_m=np.full(n_sat, 0.1), p_sat=np.where(CONS[:n_sat] == 0, 1e-5, 3e-5),
                p_const=np.array([1e-8, 2e-4]), y=rng.normal(0, 2, shape + (n_sat,)))


FIELDS = ("hpl_m", "vpl_m", "emt_m", "sigma_acc_v_m", "hpl1_m", "hpl2_m", "status",
          "reason", "n_sats", "n_modes", "p_not_monitored", "k_fa", "phmi_vert_alloc",
          "sigma_m", "bias_m", "dx_enu_m", "alarm", "alarm_mode", "test_ratio")


@pytest.mark.parametrize("kw", [{}, {"rules": B2012}, {"fde": True}])
def test_batched_equals_per_epoch_loop(kw):
    rng = np.random.default_rng(7)
    args = random_batch(rng, (3, 5))
    args["G"][0, 1, 3:] = np.nan  # epochs with few satellites
    args["G"][2, 2, :] = np.nan
    res = call(args, **kw)
    assert res.vpl_m.shape == (3, 5) and res.k_fa.shape == (3, 5, 3)
    assert res.modes.sats.shape[:2] == (3, 5) and res.modes.sats.shape[-1] == 13
    assert res.status[2, 2] == "unavailable" and res.reason[2, 2] == "too_few_satellites"
    for i in range(3):
        for j in range(5):
            one = call({k: (v[i, j] if np.ndim(v) == 2 + (k == "G") + 1 else v)
                        for k, v in args.items()}, **kw)
            for f in FIELDS + (("excluded_sat", "excluded_const") if kw.get("fde") else ()):
                a, b = getattr(one, f), getattr(res, f)[i, j]
                if a.dtype.kind in "fc":
                    np.testing.assert_allclose(a, b, rtol=1e-12, atol=0, err_msg=f)
                else:
                    np.testing.assert_array_equal(a, b, err_msg=f)
            k = one.modes.valid.sum()
            np.testing.assert_array_equal(one.modes.sats[:k], res.modes.sats[i, j, :k])
            np.testing.assert_allclose(one.modes.threshold_m[:k],
                                       res.modes.threshold_m[i, j, :k], rtol=1e-12)


def test_nan_rows_equal_removed_rows_and_do_not_poison_neighbours():
    args = sky(y=np.random.default_rng(0).normal(0, 1, 13))
    drop = np.array([2, 9])
    nan_args = {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in args.items()}
    nan_args["G"][drop] = np.nan
    for k in ("sigma_int_m", "sigma_acc_m", "b_int_m", "y"):
        nan_args[k][drop] = np.nan  # values of satellites not in view are ignored
    keep = np.setdiff1d(np.arange(13), drop)
    small = {k: (v[keep] if np.ndim(v) and np.shape(v)[0] == 13 else v)
             for k, v in args.items()}
    a, b = call(nan_args), call(small)
    for f in ("hpl_m", "vpl_m", "emt_m", "sigma_acc_v_m", "n_modes", "test_ratio"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-12)
    assert not a.modes.sats[:, drop].any()
    # the `used` mask and p_sat = 1 do the same
    used = np.ones(13, bool)
    used[drop] = False
    assert call(args, used=used).vpl_m == pytest.approx(b.vpl_m, rel=1e-12)
    p1 = args["p_sat"].copy()
    p1[drop] = 1.0
    assert call(dict(args, p_sat=p1)).vpl_m == pytest.approx(b.vpl_m, rel=1e-12)
    # a batch where one epoch is all NaN: its neighbours are untouched
    g2 = np.stack([args["G"], np.full_like(args["G"], np.nan), args["G"]])
    r2 = call(dict(args, G=g2))
    assert list(r2.status) == ["ok", "unavailable", "ok"]
    assert r2.vpl_m[0] == r2.vpl_m[2] == call(args).vpl_m
    assert np.isinf(r2.vpl_m[1]) and r2.n_sats[1] == 0


def test_a_constellation_out_of_view_drops_its_clock():
    keep = CONS == 0
    args = sky()
    g = args["G"].copy()
    g[~keep] = np.nan
    res = call(dict(args, G=g))
    small = {k: (v[keep] if np.ndim(v) and np.shape(v)[0] == 13 else v)
             for k, v in args.items()}
    small["G"] = small["G"][:, :4]
    small["p_const"] = args["p_const"][:1]
    ref = call(small)
    assert res.vpl_m == pytest.approx(ref.vpl_m, rel=1e-12)
    assert res.n_modes == ref.n_modes


@pytest.mark.parametrize("n_gps,n_gal,reason", [
    (3, 0, "too_few_satellites"),
    (2, 2, "too_few_satellites"),  # 4 satellites, 5 unknowns
    (0, 0, "too_few_satellites"),
])
def test_too_few_satellites_is_a_status(n_gps, n_gal, reason):
    keep = np.r_[np.arange(n_gps), 7 + np.arange(n_gal)].astype(int)
    args = sky()
    g = args["G"].copy()
    g[np.setdiff1d(np.arange(13), keep)] = np.nan
    res = call(dict(args, G=g, y=np.zeros(13)), fde=True)
    assert res.status == "unavailable" and res.reason == reason
    for f in ("hpl_m", "vpl_m", "emt_m", "sigma_acc_v_m"):
        assert np.isinf(getattr(res, f))
    assert res.n_modes == 0 and not res.alarm and res.alarm_mode == -1


def test_singular_geometry_is_a_status():
    """Every satellite at the same elevation: the up column is a multiple of the clock."""
    args = sky()
    args["G"] = geometry(AZ, np.full(13, 30.0), CONS, 2)
    res = call(args)
    assert res.status == "unavailable" and res.reason == "singular_geometry"
    assert np.isinf(res.vpl_m) and np.isinf(res.hpl_m)


def test_unbatched_outputs_are_scalars_and_attributes_are_complete():
    res = call(sky())
    assert res.vpl_m.shape == () and res.k_fa.shape == (3,)
    assert res.available and res.rho == 1.0
    assert res.dx_enu_m is None and res.alarm is None and res.excluded_sat is None
    assert res.modes.separation_m is None
    assert res.acc95_v_m == pytest.approx(1.96 * res.sigma_acc_v_m)
    assert res.ff_v_m == pytest.approx(5.33 * res.sigma_acc_v_m)
    assert call(sky(), return_modes=False).modes is None
    assert res.rules == ADD and res.params["p_thres"] == 8e-8


# -------------------------------------------------------------------- errors, keywords


def test_unknown_keyword_names_itself_and_the_allowed_ones():
    with pytest.raises(ValueError, match=r"unknown keyword 'p_fa'.*allowed: .*p_fa_vert"):
        call(sky(), p_fa=1e-6)
    with pytest.raises(ValueError, match=r"'fc_thres' for rules='blanch-2012'"):
        call(sky(), rules=B2012, fc_thres=0.01)
    with pytest.raises(ValueError, match=r"'p_thres_sat' for rules='add-v4.2'"):
        call(sky(), p_thres_sat=1e-8)
    with pytest.raises(ValueError, match="rules must be one of"):
        call(sky(), rules="maast")
    with pytest.raises(ValueError, match="phmi_vert must be a probability"):
        call(sky(), phmi_vert=2.0)


def test_every_param_has_a_default_per_rule_set_and_a_help():
    for p in PARAMS:
        assert p.help and p.default and set(p.default) <= {ADD, B2012}
    assert defaults(ADD)["p_thres"] == 8e-8 and "p_thres" not in defaults(B2012)
    assert defaults(B2012)["p_thres_sat"] == 4e-8


@pytest.mark.parametrize("change,match", [
    ({"sigma_int_m": -np.ones(13)}, "sigma_int_m must be finite and > 0"),
    ({"p_sat": np.full(13, 1.5)}, r"p_sat must be a probability in \[0, 1\]"),
    ({"p_const": np.array([1e-8, 1.0])}, "p_const must be a probability"),
    ({"b_int_m": np.full(13, np.nan)}, "b_int_m must be finite"),
    ({"p_const": np.zeros(3)}, r"p_const must have shape \(\.\.\., 2\)"),
])
def test_bad_inputs_raise_value_errors(change, match):
    with pytest.raises(ValueError, match=match):
        call(sky(**change))


def test_clock_columns_must_be_one_hot():
    g = sky()["G"].copy()
    g[0, 3:] = [1.0, 1.0]
    with pytest.raises(ValueError, match="one-hot"):
        call(sky(G=g))


# ----------------------------------------------------------------- statistics and faults


def test_fault_free_vertical_error_within_vpl_as_the_budget_allows():
    """Seeded fault-free Monte Carlo (y ~ N(0, C_int), the integrity model): at the LPV-200
    budget no exceedance is expected; with a large budget (PHMI_V = 2e-2) the exceedance
    rate of |VPE| > VPL is binomial with p <= PHMI_V' (two-sided test, p-value > 1e-3)."""
    rng = np.random.default_rng(20240614)
    n = 20000
    args = sky(b_int_m=np.zeros(13), b_acc_m=np.zeros(13))
    y = rng.normal(size=(n, 13)) * args["sigma_int_m"]
    res = call(dict(args, y=y), return_modes=False)
    vpe = np.abs(res.dx_enu_m[:, 2])
    k = int(np.sum(vpe > res.vpl_m))
    assert stats.binomtest(k, n, res.phmi_vert_alloc[0], alternative="greater").pvalue > 1e-3
    big = call(dict(args, y=y), return_modes=False, phmi_vert=2e-2, phmi_hor=1e-2)
    k = int(np.sum(np.abs(big.dx_enu_m[:, 2]) > big.vpl_m))
    p = big.phmi_vert_alloc[0]
    assert stats.binomtest(k, n, p).pvalue > 1e-3, (k, n * p)
    # horizontal: each axis bounded at PHMI_H' (two-sided), so radial <= 2 PHMI_H'
    kh = int(np.sum(np.hypot(big.dx_enu_m[:, 0], big.dx_enu_m[:, 1]) > big.hpl_m))
    assert stats.binomtest(kh, n, 2 * big.phmi_hor_alloc[0],
                           alternative="greater").pvalue > 1e-3
    # continuity: y ~ N(0, C_acc) (the model of the thresholds) raises no more alarms
    # than P_FA_VERT + P_FA_HOR allow
    y_acc = rng.normal(size=(n, 13)) * args["sigma_acc_m"]
    fa = call(dict(args, y=y_acc), return_modes=False)
    assert stats.binomtest(int(fa.alarm.sum()), n, 3.9e-6 + 9e-8,
                           alternative="greater").pvalue > 1e-3


def test_constellation_fault_is_explained_by_the_constellation_mode_and_excluded():
    """A Galileo ephemeris-like fault (every GAL range off by u_i . delta, delta = 25 m up
    and 15 m east) is explained by the GAL constellation mode and excluded with fde."""
    rng = np.random.default_rng(5)
    args = sky()
    u = -args["G"][:, :3]
    y = rng.normal(size=13) * args["sigma_acc_m"]
    y = y + np.where(CONS == 1, u @ np.array([15.0, 0.0, 25.0]), 0.0)
    res = call(dict(args, y=y), fde=True)
    assert res.alarm
    k = res.alarm_mode
    assert res.modes.consts[k, 1] and np.array_equal(res.modes.sats[k], CONS == 1)
    assert res.excluded_const == 1 and res.excluded_sat == -1
    gps_only = subset_matrix(args["G"], args["sigma_int_m"] ** 2, CONS == 1)
    np.testing.assert_allclose(res.dx_excluded_enu_m, gps_only @ y, rtol=1e-9)
    # the same fault without Galileo constellation modes cannot be explained: no candidate
    # passes (the satellite candidates leave 5 faulty Galileo ranges)
    res2 = call(dict(args, y=y), fde=True, fde_const=False)
    assert res2.alarm and res2.excluded_sat == -1 and res2.excluded_const == -1


def test_single_satellite_fault_is_excluded():
    rng = np.random.default_rng(11)
    args = sky()
    y = rng.normal(size=13) * args["sigma_acc_m"]
    y[4] += 60.0
    res = call(dict(args, y=y), fde=True)
    assert res.alarm and res.modes.sats[res.alarm_mode, 4]
    assert res.excluded_sat == 4 and res.excluded_const == -1
    quiet = call(dict(args, y=y - np.eye(13)[4] * 60.0), fde=True)
    assert not quiet.alarm and quiet.excluded_sat == -1


def test_fde_protection_levels_bound_the_fd_ones():
    """With exclusion the budget is shared (rho = 1/(N_exc + 1)) and the outputs are the
    maximum over the candidates: never below the detection-only ones (section 9)."""
    fd = call(sky())
    fde = call(sky(), fde=True)
    n_exc = 13 + 1  # satellites + the GAL constellation (P_const 2e-4 > 1e-7)
    assert fde.rho == pytest.approx(1 / (n_exc + 1))
    for f in ("vpl_m", "hpl_m", "emt_m", "sigma_acc_v_m"):
        assert getattr(fde, f) >= getattr(fd, f)
    assert fde.phmi_vert_alloc == pytest.approx(fd.phmi_vert_alloc / (n_exc + 1))


def test_fde_candidate_leaving_three_satellites_makes_pls_infinite():
    """MAAST: a candidate that leaves 3 satellites or fewer counts with infinite PLs.
    7 GPS + 3 GAL, P_const,GPS = 2e-7 (a candidate); PHMI_V = 1e-6 and P_THRES = 5e-7 keep
    the unmonitorable GPS constellation mode out of the all-in-view budget."""
    keep = np.r_[np.arange(7), 7, 8, 9]
    args = {k: (v[keep] if np.ndim(v) and np.shape(v)[0] == 13 else v)
            for k, v in sky(p_const=np.array([2e-7, 2e-4])).items()}
    kw = dict(fde=True, phmi_vert=1e-6, p_thres=5e-7)
    res = call(args, **kw)  # the GPS-constellation candidate leaves the 3 GAL
    assert res.status == "ok" and np.isinf(res.vpl_m) and np.isinf(res.hpl_m)
    assert np.isfinite(call(args, **kw, fde_const=False).vpl_m)
    assert np.isfinite(call(args, phmi_vert=1e-6, p_thres=5e-7).vpl_m)


def test_exclusion_options_keep_modes_out_of_the_walk():
    """Section 4 step 6 with exclusion: a mode sharing no satellite with an exclusion option
    (p_inst > P_EXC_THRES) is not taken. With P_THRES = 1e-9 the walk reaches the GPS
    constellation mode; under the GAL-constellation candidate it removes every satellite
    left, so with FDE its whole prior is spent at rho PHMI_V' and the VPL is infinite;
    P_EXC_THRES = 9e-7 leaves it in P_nm instead."""
    gps_mode = CONS == 0

    def has_gps_mode(res):
        return bool(np.any(np.all(res.modes.sats == gps_mode, axis=1) & res.modes.valid))

    fd = call(sky(), p_thres=1e-9)
    assert has_gps_mode(fd) and np.isfinite(fd.vpl_m)
    fde = call(sky(), p_thres=1e-9, fde=True)
    assert has_gps_mode(fde) and np.isinf(fde.vpl_m)
    opt = call(sky(), p_thres=1e-9, fde=True, p_exc_thres=9e-7)
    assert not has_gps_mode(opt) and np.isfinite(opt.vpl_m)
    assert opt.p_not_monitored > 1e-8 > fd.p_not_monitored


# ------------------------------------------------------------------- error model, hypothesis


def test_error_models():
    el = np.radians([5.0, 7.5, 90.0])
    gal = sigma_user_add_m(el, "GAL")
    assert gal[0] == pytest.approx(0.4529) and gal[2] == pytest.approx(0.2277)
    assert gal[1] == pytest.approx((0.4529 + 0.3553) / 2)
    theta = 30.0
    want = np.sqrt(0.16 + (0.34 + 0.4 * np.exp(-theta / 14)) ** 2
                   + (40 / (261 + theta**2) + 0.018) ** 2)
    assert sigma_user_ed259a_m(np.radians(theta)) == pytest.approx(want)
    assert sigma_tropo_m(np.pi / 2) == pytest.approx(0.12 * 1.001 / np.sqrt(1.002001))
    with pytest.raises(ValueError, match="GPS or GAL"):
        sigma_user_add_m(el, "GLO")


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=hs.integers(0, 2**31 - 1), c=hs.floats(0.1, 10.0))
def test_property_scaling_and_fault_free_bound(seed, c):
    """Random skies: scaling every sigma and bias by c scales PLs and EMT by c, and the
    VPL is never below the fault-free-only value K sigma_3 + b_3."""
    rng = np.random.default_rng(seed)
    args = random_batch(rng, ())
    args.pop("y")
    r0 = call(args)
    if r0.status != "ok":
        assert np.isinf(r0.vpl_m)
        return
    scaled = dict(args, **{k: c * args[k] for k in
                           ("sigma_int_m", "sigma_acc_m", "b_int_m", "b_acc_m")})
    r1 = call(scaled, tol_pl_m=c * 5e-2)
    for f in ("vpl_m", "hpl_m", "emt_m"):
        np.testing.assert_allclose(getattr(r1, f), c * getattr(r0, f), rtol=1e-8)
    floor = q_inv(r0.phmi_vert_alloc / 2) * r0.sigma_m[2] + r0.bias_m[2]
    assert r0.vpl_m >= floor - 1e-9


# ------------------------------------------------- fast kernel vs the reference path
# ``raimcore.araim.mhss._mhss(..., reference=True)`` is the plain numpy path as first
# written (``raimcore.araim._kernel_reference``: every exclusion candidate evaluated on its
# own, every protection level searched, fault-mode lists merged row by row). The fast
# path must give the same statuses, alarms, exclusions, availability decisions and
# ``*_set_by``, and the same numbers to rounding (well inside one micrometre).
one_um = 1e-6

_mhss_module = importlib.import_module("raimcore.araim.mhss")


def random_four_systems(rng, shape, n_sat=20):
    """Random skies of 4 constellations with priors high enough for three-satellite
    modes and constellation-plus-satellite modes (every kernel path)."""
    cons = np.arange(n_sat) % 4
    az = rng.uniform(0, 360, shape + (n_sat,))
    el = rng.uniform(-10, 85, shape + (n_sat,))
    g = geometry(az, el, cons, 4)
    g[el < 5] = np.nan
    s = rng.uniform(0.8, 3.0, shape + (n_sat,))
    return dict(G=g, sigma_int_m=s, sigma_acc_m=0.8 * s, b_int_m=np.full(n_sat, 0.5),
                b_acc_m=np.full(n_sat, 0.1), p_sat=np.full(n_sat, 1e-4),
                p_const=np.array([1e-8, 2e-4, 1e-4, 3e-4]),
                y=rng.normal(0, 2, shape + (n_sat,)))


def random_four_systems_high_priors(rng, shape):
    """:func:`random_four_systems` with priors high enough for modes of a constellation
    plus two satellites (the two-satellite down-date of a constellation's solution)."""
    args = random_four_systems(rng, shape)
    return dict(args, p_sat=np.full(20, 3e-4), p_const=np.array([1e-3, 2e-3, 1e-3, 3e-3]))


def assert_same_result(fast, ref, atol=one_um):
    """Every field of two MhssResults: floats to ``atol`` (same infinities and NaNs),
    everything else equal."""
    for f in fast.__dataclass_fields__:
        a, b = getattr(fast, f), getattr(ref, f)
        if f == "modes" and a is not None:
            assert_same_result(a, b, atol)
        elif isinstance(a, np.ndarray) and a.dtype.kind == "f":
            np.testing.assert_allclose(a, b, rtol=0, atol=atol, err_msg=f)
        elif isinstance(a, np.ndarray):
            np.testing.assert_array_equal(a, b, err_msg=f)
        else:
            assert (a is None) == (b is None) and (a is None or a == b), f


def call_ref(args, **kw):
    a = dict(args)
    return _mhss_module._mhss(a.pop("G"), a.pop("sigma_int_m"), a.pop("sigma_acc_m"),
                              a.pop("b_int_m"), a.pop("b_acc_m"), a.pop("p_sat"),
                              a.pop("p_const"), reference=True, **a, **kw)


@pytest.mark.parametrize("make, kw", [
    (random_batch, {"fde": True}),
    (random_four_systems, {"fde": True}),
    (random_four_systems, {"fde": True, "max_pmd": True, "n_es_int": 25.0,
                           "t_exp_over_mfd": 150.0 / 3600.0}),
    (random_four_systems_high_priors, {"fde": True}),
    (random_four_systems, {"fde": True, "rules": B2012}),
    (random_four_systems, {"fde": True, "fde_const": False, "return_modes": False}),
    (random_four_systems, {}),
])
def test_fast_path_equals_reference_path(make, kw):
    rng = np.random.default_rng(17)
    args = make(rng, (3, 4))
    args["G"][0, 1, 5:] = np.nan  # an epoch whose candidates leave 3 satellites or fewer
    vis = np.all(np.isfinite(args["G"]), axis=-1)
    first = np.argmax(vis, axis=-1)  # a 60 m fault on the first satellite in view, rows 1-2
    b, e = np.meshgrid(np.arange(1, 3), np.arange(4), indexing="ij")
    args["y"][b, e, first[1:]] += 60.0
    fast, ref = call(args, **kw), call_ref(args, **kw)
    assert_same_result(fast, ref)
    assert np.any(fast.alarm)
    if kw.get("fde"):
        assert np.any(fast.vpl_set_by >= 0) and np.any(fast.excluded_sat >= 0)
    no_y = {k: v for k, v in args.items() if k != "y"}
    assert_same_result(call(no_y, **kw), call_ref(no_y, **kw))


def test_fast_mode_merge_equals_row_merge():
    cons = np.arange(20) % 4
    p_sat, p_const = np.full(20, 1e-4), np.array([1e-8, 2e-4, 1e-4, 3e-4])
    for kw in ({}, {"rules": B2012}, {"fde": True, "p_exc_thres": 9e-7}):
        fast = determine_modes(cons, p_sat, p_const, **kw)
        ref = determine_modes(cons, p_sat, p_const, reference=True, **kw)
        for f in ("removed", "consts", "p_inst", "p_exp"):
            np.testing.assert_array_equal(getattr(fast, f), getattr(ref, f), err_msg=f)
        assert len(fast) > 40
        for i in (0, 7, 19):
            keep = np.arange(20) != i
            a, b = restrict_modes(fast, keep), restrict_modes(fast, keep, reference=True)
            c = restrict_modes(fast, keep, keys=mode_keys(fast.removed))  # keys cut by mask
            for f in ("removed", "consts", "p_inst", "p_exp"):
                np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)
                np.testing.assert_array_equal(getattr(c, f), getattr(b, f), err_msg=f)
            assert len(a) < len(fast)  # modes of satellite i merged


def recording_mhss_call(shared_data, monkeypatch):
    """``(mhss, args, kwargs)``: the kernel and its inputs as the ``araim`` algorithm builds
    them (exclusion on) for 10 minutes of the real GPS + GAL + BDS + GLO recording
    (ESBC00DNK, 2020-06-25, 30 s)."""
    from raimcore import araim as kernel_pkg
    from raimcore.algorithms import araim as algo
    from raimcore.pipeline import run_scenario
    from raimcore.scenario import load_scenario

    captured = []
    real = kernel_pkg.mhss

    def spy(*a, **k):
        captured.append((a, k))
        return real(*a, **k)

    monkeypatch.setattr(algo.kernel, "mhss", spy)
    s = load_scenario("default").replace(
        source="rinex", obs=str(shared_data / "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"),
        nav=[str(shared_data / "ESBC00DNK_R_20201770000_01D_MN.rnx")],
        systems=["GPS", "GAL", "BDS", "GLO"], faults=[], duration_s=600.0, step_s=30.0,
        algorithm="araim")
    run_scenario(s)
    (a, k), = captured
    return real, a, k


def test_fast_path_equals_reference_on_the_four_system_recording(shared_data, monkeypatch):
    """The real GPS + GAL + BDS + GLO recording (ESBC00DNK, 2020-06-25), 10 min at 30 s:
    the kernel's inputs as the ``araim`` algorithm builds them (with exclusion), fast and
    reference paths."""
    real, a, k = recording_mhss_call(shared_data, monkeypatch)
    assert a[0].shape[-2] >= 30 and a[0].shape[-1] == 7 and k["fde"]
    fast = real(*a, **k)
    ref = _mhss_module._mhss(*a, reference=True, **k)
    assert_same_result(fast, ref)
    assert np.all(fast.status == "ok") and fast.modes.valid.sum(axis=1).min() > 300


# ------------------------------------------- compiled kernels (numba) vs the numpy path
# ``raimcore.araim._numba`` computes the down-dated subset statistics and the PL equations
# with their bracket; ``RAIM_STUDIO_NUMBA=0`` (read at each call) runs the numpy path.
# Same statuses, alarms, exclusions, ``*_set_by`` and mode counts; numbers to rounding.
_kernel_module = importlib.import_module("raimcore.araim.kernel")
needs_numba = pytest.mark.skipif(_kernel_module.numba_kernels() is None,
                                 reason="numba not installed (the fast extra) or disabled")


def numba_and_numpy(monkeypatch, fn):
    """``fn()`` with the compiled kernels, then with the numpy path; checks that each ran."""
    calls = []
    nb = _kernel_module.numba_kernels()
    names = ("downdate_modes", "pl_equations", "bisect_rows")
    for name in names:
        real = getattr(nb, name)

        def counted(*a, _real=real, _name=name):
            calls.append(_name)
            return _real(*a)

        monkeypatch.setattr(nb, name, counted)
    compiled = fn()
    assert {"downdate_modes", "pl_equations"} <= set(calls)
    assert "bisect_rows" in calls or nb.scipy_ndtr() is None
    calls.clear()
    monkeypatch.setenv(_kernel_module.NUMBA_ENV, "0")
    plain = fn()
    assert not calls
    monkeypatch.delenv(_kernel_module.NUMBA_ENV)
    return compiled, plain


@needs_numba
@pytest.mark.parametrize("make, kw", [
    (random_batch, {"fde": True}),
    (random_four_systems, {"fde": True}),
    (random_four_systems, {"fde": True, "max_pmd": True, "n_es_int": 25.0,
                           "t_exp_over_mfd": 150.0 / 3600.0}),
    (random_four_systems_high_priors, {"fde": True}),
    (random_four_systems, {"fde": True, "rules": B2012}),
    (random_four_systems, {}),
])
def test_numba_equals_numpy(make, kw, monkeypatch):
    rng = np.random.default_rng(1717)
    args = make(rng, (3, 5))
    # C_acc not proportional to C_int (else M C_acc is symmetric and cross terms vanish)
    args["sigma_acc_m"] = args["sigma_int_m"] * rng.uniform(0.4, 0.95, args["y"].shape)
    args["G"][0, 1, 5:] = np.nan  # candidates leaving 3 satellites or fewer
    args["G"][0, 2, 3:] = np.nan  # too few satellites
    vis = np.all(np.isfinite(args["G"]), axis=-1)
    first = np.argmax(vis, axis=-1)
    b, e = np.meshgrid(np.arange(1, 3), np.arange(5), indexing="ij")
    args["y"][b, e, first[1:]] += 60.0
    for a in (args, {k: v for k, v in args.items() if k != "y"}):
        fast, plain = numba_and_numpy(monkeypatch, lambda a=a: call(a, **kw))
        assert_same_result(fast, plain)
        assert np.any(fast.status == "ok") and np.any(fast.status != "ok")
    assert np.any(fast.modes.monitored.sum(axis=-1) > 10)


@needs_numba
def test_numba_equals_numpy_on_the_four_system_recording(shared_data, monkeypatch):
    """10 minutes of the real GPS + GAL + BDS + GLO recording through the kernel as the
    ``araim`` algorithm calls it (exclusion on), compiled and numpy paths."""
    real, a, k = recording_mhss_call(shared_data, monkeypatch)
    fast, plain = numba_and_numpy(monkeypatch, lambda: real(*a, **k))
    assert_same_result(fast, plain)
    assert np.all(fast.status == "ok") and fast.modes.valid.sum(axis=1).min() > 300
    seen = np.all(np.isfinite(a[0][..., 0]), axis=0)  # a 40 m step on a satellite always
    sat = int(np.argmax(seen))                         # in view, on fault-free residuals
    y = np.zeros(a[0].shape[:2])
    y[:, sat] = 40.0
    kw = dict(k, y=y)
    fast, plain = numba_and_numpy(monkeypatch, lambda: real(*a, **kw))
    assert_same_result(fast, plain)
    assert np.all(fast.alarm) and np.all(fast.excluded_sat == sat)


@needs_numba
@pytest.mark.parametrize("capped", [False, True])
def test_compiled_bisection_gives_numpys_bits(capped, monkeypatch):
    """The compiled search (scipy's ndtr, numpy's summation order, tail terms bounded) is
    bit for bit the numpy search, at MAAST's tolerance and at 1e-9 m (steps close to the
    root, where the bound cannot decide and the full sum is formed), for term counts
    around numpy's summation blocks (8, 128) and with NaN terms."""
    nb = _kernel_module.numba_kernels()
    if nb.scipy_ndtr() is None:
        pytest.skip("this scipy does not export ndtr to compiled code")
    rng = np.random.default_rng(88)
    for j in (1, 7, 8, 9, 127, 128, 129, 300, 1100):
        r = 120
        c = rng.normal(5.0, 3.0, (r, j))
        sig = rng.uniform(0.5, 4.0, (r, j))
        p = np.where(rng.random((r, j)) < 0.9, 10.0 ** rng.uniform(-12, -4, (r, j)), 0.0)
        a = rng.uniform(0.01, 1.0, (r, j)) if capped else np.ones((r, j))
        c[0, 0] = np.nan
        br = _kernel_module.pl_bracket(c, sig, p, a, 10.0 ** rng.uniform(-9, -6, r))
        for tol in (5e-2, 1e-9):
            rows = rng.random(r) < 0.8
            fast = _kernel_module.pl_bisect(br, tol, rows=rows)
            monkeypatch.setenv(_kernel_module.NUMBA_ENV, "0")
            with np.errstate(invalid="ignore"):  # the NaN row's bracket, in numpy
                plain = _kernel_module.pl_bisect(br, tol, rows=rows)
            monkeypatch.delenv(_kernel_module.NUMBA_ENV)
            np.testing.assert_array_equal(fast, plain)
            assert np.isfinite(plain).sum() > 10  # rows really searched


@pytest.mark.parametrize("compiled", ["1", "0"])
def test_a_lone_satellites_mode_separates_by_exactly_zero(compiled, monkeypatch):
    """A satellite alone in its constellation only fixes its own clock: removing it leaves
    the position as it is (S^(k) = S^(0) on the position rows), so its mode has sigma_ss,
    b_ss, threshold and separation exactly 0 and the all-in-view's sigma and bias.
    Computed, those were rounding noise (~1e-14 m) and |sep| / T of that noise decided
    alarms and exclusions at random: with noise-only residuals the lone satellite's mode
    must never be the alarm's, and the result must not depend on the compiled path."""
    monkeypatch.setenv(_kernel_module.NUMBA_ENV, compiled)
    rng = np.random.default_rng(5)
    cons = np.array([0] * 9 + [1, 2, 2, 2, 2, 2])  # constellation 1: one satellite
    az = rng.uniform(0, 360, (40, 15))
    el = rng.uniform(10, 85, (40, 15))
    g = geometry(az, el, cons, 3)
    s = rng.uniform(0.8, 3.0, (40, 15))
    res = mhss(g, s, 0.8 * s, np.full(15, 0.5), np.full(15, 0.1), np.full(15, 1e-4),
               np.array([1e-8, 1e-4, 1e-4]), y=rng.normal(0, 1e-3, (40, 15)), fde=True,
               return_modes=True)
    m = res.modes
    lone = np.flatnonzero(m.valid[0] & (m.sats[0, :, 9]) & (m.sats[0].sum(-1) == 1))
    assert lone.size == 1
    k = lone[0]
    assert np.all(m.monitored[:, k])
    for f in ("sigma_ss_m", "bias_ss_m", "threshold_m", "separation_m"):
        assert np.all(getattr(m, f)[:, k] == 0.0), f
    np.testing.assert_array_equal(m.sigma_m[:, k], m.sigma_m[:, 0])
    np.testing.assert_array_equal(m.bias_m[:, k], m.bias_m[:, 0])
    assert not np.any(res.alarm) and np.all(res.alarm_mode != k)
    assert np.all(res.test_ratio < 0.1)


def test_numba_is_not_imported_by_the_package():
    import subprocess
    import sys

    code = "import raimcore, raimcore.araim, sys; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
