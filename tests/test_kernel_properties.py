"""Properties every array kernel keeps (issue 13, "never silently wrong").

One suite over the public kernels (``wls``, ``normal_solve``, ``parity_matrix``,
``parity_test``, ``sse_test``, ``parity_statistics``, ``detection_probability``, ``mss``,
``classic_raim``):

* output shapes for unbatched and batched inputs;
* singular or nearly singular geometry (duplicate satellites, all lines of sight on one
  line, all satellites at one elevation, fewer satellites than states) is unavailable: NaN
  statistics and positions, never finite numbers;
* a singular or NaN epoch never changes its neighbours (bit for bit);
* permuting the satellites permutes the per-satellite outputs and leaves the statistic and
  the position unchanged;
* V H = 0 and V V^T = I for full-rank H;
* bad inputs raise ``ValueError`` naming the argument (table below).
"""

from __future__ import annotations

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from raimcore import _validate as v
from raimcore.algorithms import mss
from raimcore.algorithms.parity import (
    _whitened_projector,
    detection_probability,
    parity_matrix,
    parity_statistics,
    parity_test,
    sse_test,
)
from raimcore.geometry import enu_rotation, geodetic_to_ecef
from raimcore.lsq import RCOND_MIN, _scaled, _well_conditioned, normal_solve, wls

P_FA, P_MD = 1e-3, 1e-3
SIGMA_M = 3.0
one_mm = 1e-3
LAT, LON = np.radians(30.0), np.radians(110.0)
RX = geodetic_to_ecef(LAT, LON, 100.0)
SV_RANGE_M = 2.2e7

seeds = st.integers(0, 2**32 - 1)
batch_shapes = st.lists(st.integers(1, 3), min_size=0, max_size=2).map(tuple)


# --- geometry builders --------------------------------------------------------------------

def los(rng, shape, el=None):
    """Unit lines of sight (ENU), shape ``shape + (3,)``, above 10 deg (or at ``el``)."""
    az = rng.uniform(0.0, 2.0 * np.pi, shape)
    e = rng.uniform(np.radians(10.0), np.radians(85.0), shape) if el is None else np.full(
        shape, el)
    return np.stack([np.cos(e) * np.sin(az), np.cos(e) * np.cos(az), np.sin(e)], axis=-1)


def rows(u):
    """Geometry rows ``[-u, 1]`` (one clock)."""
    return np.concatenate([-u, np.ones(u.shape[:-1] + (1,))], axis=-1)


def satellites(u):
    """ECEF satellite positions along the ENU lines of sight ``u`` from RX."""
    return RX + SV_RANGE_M * (u @ enu_rotation(LAT, LON))


SINGULAR = ["duplicate", "colinear", "cone", "near_cone"]


def singular_los(rng, m, kind):
    """Lines of sight ``(m, 3)`` whose geometry ``[-u, 1]`` is rank-deficient."""
    if kind == "duplicate":  # every satellite in one direction
        return np.broadcast_to(los(rng, (1,)), (m, 3)).copy()
    if kind == "colinear":  # all on one line through the receiver (both directions)
        u = np.broadcast_to(los(rng, (1,)), (m, 3)).copy()
        u[1::2] *= -1.0
        return u
    # All at one elevation: the Up and clock columns are proportional (a classic RAIM
    # singularity); "near_cone" spreads the elevations by 1e-9 rad only.
    el = np.radians(35.0) + (1e-9 * rng.uniform(-1, 1, m) if kind == "near_cone" else 0.0)
    return los(rng, (m,), el)


# --- kernels behind one interface ---------------------------------------------------------
# Each runner takes h (B, m, 4) ENU rows [-u, 1], z (B, m) and returns
# (per-epoch statistic (B,), per-epoch available (B,), per-satellite output (B, m), all
# outputs as a dict for bit-for-bit comparison).

def _fields(res):
    return {f: np.asarray(getattr(res, f)) for f in res.__dataclass_fields__}


def run_parity_test(h, z):
    r = parity_test(h, z, SIGMA_M, P_FA)
    return r.statistic, r.available, r.isolation, _fields(r)


def run_parity_potter(h, z):
    r = parity_test(h, z, SIGMA_M, P_FA, method="potter")
    return r.statistic, r.available, r.isolation, _fields(r)


def run_sse(h, z):
    sse, thr, alarm = sse_test(h, z, SIGMA_M, P_FA)
    sse = np.asarray(sse)
    return sse, np.isfinite(sse), np.broadcast_to(sse[..., None], z.shape), {
        "sse": sse, "alarm": np.asarray(alarm)}


def run_parity_statistics(h, z):
    w = np.full(z.shape, SIGMA_M**-2)
    r = parity_statistics(h, z, w, P_FA, np.full(z.shape[:-1], z.shape[-1] - 4))
    return r.statistic, r.available, r.isolation, _fields(r)


def run_mss(h, z):
    m = z.shape[-1]
    r = mss.mss(h, z, np.full(z.shape, SIGMA_M**-2), np.ones(m, bool), P_FA, P_MD)
    return r.hpl_m, r.status != mss.STATUS_UNAVAILABLE, r.ratio, _fields(r)


def run_classic(h, z):
    m = z.shape[-1]
    r = mss.classic_raim(h, z, np.full(z.shape, SIGMA_M**-2), np.ones(m, bool), P_FA, P_MD)
    return r.sse, r.status != mss.STATUS_UNAVAILABLE, r.hslope_m, _fields(r)


def run_normal_solve(h, z):
    n_inv, present, ok = normal_solve(h, np.full(z.shape, SIGMA_M**-2))
    return n_inv[..., 2, 2], ok, np.broadcast_to(n_inv[..., 2, 2][..., None], z.shape), {
        "n_inv": n_inv, "present": present, "ok": ok}


def run_detection_probability(h, z):
    w = np.full(z.shape, SIGMA_M**-2)
    proj, _ = _whitened_projector(h, w)
    bias = np.zeros(z.shape)
    bias[..., 0] = 8.0 * SIGMA_M
    pd = detection_probability(proj, bias, w, np.full(z.shape[:-1], z.shape[-1] - 4), P_FA)
    return pd, np.isfinite(pd), np.broadcast_to(pd[..., None], z.shape), {"pd": pd}


def run_wls(h, z):
    """wls on satellites along the rows' lines of sight (z: pseudorange noise)."""
    sv = satellites(-h[..., :3])
    pr = np.linalg.norm(sv - RX, axis=-1) + z
    r = wls(sv, pr, np.full(z.shape, SIGMA_M**-2), np.zeros(z.shape[-1], int))
    return r.pos_ecef_m[..., 0], r.available, r.resid_m, _fields(r)


RUNNERS = {
    "parity_test": run_parity_test,
    "parity_test_potter": run_parity_potter,
    "sse_test": run_sse,
    "parity_statistics": run_parity_statistics,
    "detection_probability": run_detection_probability,
    "normal_solve": run_normal_solve,
    "mss": run_mss,
    "classic_raim": run_classic,
    "wls": run_wls,
}


def good_batch(rng, n_epochs, m):
    h = rows(los(rng, (n_epochs, m)))
    z = rng.normal(size=(n_epochs, m)) * SIGMA_M
    return h, z


def assert_same(a: dict, b: dict, keep=None):
    """Every output equal bit for bit (on the epochs ``keep`` if given; NaN equals NaN)."""
    for k in a:
        x, y = np.asarray(a[k]), np.asarray(b[k])
        if keep is not None and x.ndim and x.shape[0] == len(keep):
            x, y = x[keep], y[keep]
        assert np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"), k


# --- output shapes ------------------------------------------------------------------------

@settings(max_examples=15, deadline=None)
@given(seed=seeds, batch=batch_shapes, m=st.integers(6, 9))
def test_output_shapes_unbatched_and_batched(seed, batch, m):
    rng = np.random.default_rng(seed)
    h = rows(los(rng, batch + (m,)))
    z = rng.normal(size=batch + (m,))
    w = np.full(batch + (m,), SIGMA_M**-2)
    dof = np.full(batch, m - 4)
    r = parity_test(h, z, SIGMA_M, P_FA)
    assert r.statistic.shape == batch and r.available.shape == batch
    assert r.isolation.shape == batch + (m,) and r.parity.shape == batch + (m - 4,)
    assert parity_matrix(h, "qr").shape == batch + (m - 4, m)
    assert np.shape(sse_test(h, z, SIGMA_M, P_FA)[0]) == batch
    s = parity_statistics(h, z, w, P_FA, dof)
    assert s.statistic.shape == batch and s.projector.shape == batch + (m, m)
    assert detection_probability(s.projector, z, w, dof, P_FA).shape == batch
    n_inv, present, ok = normal_solve(h, w)
    assert n_inv.shape == batch + (4, 4) and present.shape == batch + (4,)
    assert ok.shape == batch
    res = mss.mss(h, z, w, np.ones(m, bool), P_FA, P_MD)
    assert res.hpl_m.shape == batch and res.dx_sep_m.shape == batch + (m, 4)
    c = mss.classic_raim(h, z, w, np.ones(m, bool), P_FA, P_MD)
    assert c.sse.shape == batch and c.hslope_m.shape == batch + (m,)
    sv = satellites(-h[..., :3])
    fix = wls(sv, np.linalg.norm(sv - RX, axis=-1), w, np.zeros(m, int))
    assert fix.pos_ecef_m.shape == batch + (3,) and fix.cov_enu.shape == batch + (4, 4)
    assert fix.available.shape == batch and np.all(fix.available)
    assert np.abs(fix.pos_ecef_m - RX).max() < one_mm


def test_inputs_broadcast_over_batch_axes():
    """One geometry against many measurement vectors (batch axes broadcast)."""
    rng = np.random.default_rng(1)
    h = rows(los(rng, (7,)))
    z = rng.normal(size=(5, 7))
    w = np.full(7, SIGMA_M**-2)
    a = parity_test(h, z, SIGMA_M, P_FA)
    b = parity_test(np.broadcast_to(h, (5, 7, 4)), z, SIGMA_M, P_FA)
    np.testing.assert_array_equal(a.statistic, b.statistic)
    m1 = mss.mss(h, z, w, np.ones(7, bool), P_FA, P_MD)
    m2 = mss.mss(np.broadcast_to(h, (5, 7, 4)), z, np.broadcast_to(w, (5, 7)),
                 np.ones(7, bool), P_FA, P_MD)
    np.testing.assert_array_equal(m1.hpl_m, m2.hpl_m)
    assert m1.hpl_m.shape == (5,)


# --- singular geometry is unavailable, and never touches its neighbours -------------------

@pytest.mark.parametrize("kernel", list(RUNNERS))
@pytest.mark.parametrize("kind", SINGULAR)
def test_singular_epoch_is_nan_and_neighbours_are_bit_identical(kernel, kind):
    rng = np.random.default_rng(zlib.crc32(f"{kernel}/{kind}".encode()))
    n_epochs, m, bad = 5, 8, 2
    h, z = good_batch(rng, n_epochs, m)
    run = RUNNERS[kernel]
    stat0, avail0, _, out0 = run(h, z)
    assert np.all(avail0) and np.all(np.isfinite(stat0))
    h_bad = h.copy()
    h_bad[bad] = rows(singular_los(rng, m, kind))
    stat1, avail1, per_sat1, out1 = run(h_bad, z)
    assert not avail1[bad]
    assert np.isnan(stat1[bad])
    assert np.all(np.isnan(per_sat1[bad]))
    keep = np.arange(n_epochs) != bad
    assert np.all(avail1[keep])
    assert_same(out0, out1, keep)


@pytest.mark.parametrize("kernel", ["parity_statistics", "mss", "classic_raim",
                                    "normal_solve", "detection_probability", "wls"])
def test_nan_epoch_never_poisons_neighbours(kernel):
    """Masked kernels take NaN measurements (unused); an all-NaN epoch is unavailable."""
    rng = np.random.default_rng(5)
    h, z = good_batch(rng, 4, 8)
    run = RUNNERS[kernel]
    _, _, _, out0 = run(h, z)
    z_nan, h_nan = z.copy(), h.copy()
    z_nan[1] = np.nan
    if kernel in ("normal_solve", "detection_probability"):  # these see only geometry
        h_nan[1] = np.nan
    stat1, avail1, _, out1 = run(h_nan, z_nan)
    assert not avail1[1] and np.isnan(stat1[1])
    assert_same(out0, out1, np.array([True, False, True, True]))


def test_dense_parity_rejects_nan_but_masked_form_marks_it():
    """The dense form has no mask: NaN is an input error there, a status in the masked."""
    rng = np.random.default_rng(6)
    h, z = good_batch(rng, 3, 7)
    z[1, 2] = np.nan
    with pytest.raises(ValueError, match="z must contain only finite"):
        parity_test(h, z, SIGMA_M, P_FA)
    w = np.full(z.shape, SIGMA_M**-2)
    s = parity_statistics(h, z, w, P_FA, np.full(3, 3))
    assert list(s.available) == [True, False, True]
    assert np.isnan(s.statistic[1]) and not s.alarm[1] and s.best[1] == -1
    w[1, 2] = 0.0  # the same satellite switched off: available with one dof less
    s = parity_statistics(h, z, w, P_FA, np.array([3, 2, 3]))
    assert np.all(s.available)


@pytest.mark.parametrize("kind", SINGULAR)
def test_singular_parity_matrix_is_nan(kind):
    h = rows(singular_los(np.random.default_rng(7), 7, kind))
    for method in ("qr", "potter"):
        assert np.all(np.isnan(parity_matrix(h, method)))
    sse, thr, alarm = sse_test(h, np.ones(7), SIGMA_M, P_FA)
    assert np.isnan(sse) and np.isfinite(thr) and not alarm


@pytest.mark.parametrize("kind", ["duplicate", "cone"])
def test_wls_singular_sky_is_unavailable(kind):
    """Satellites on one point / on a circle of equal elevation and range: no fix."""
    u = singular_los(np.random.default_rng(8), 8, kind)
    sv = satellites(u)[None]
    res = wls(sv, np.linalg.norm(sv - RX, axis=-1), np.ones((1, 8)), np.zeros(8, int))
    assert not res.available[0] and not res.converged[0]
    assert np.all(np.isnan(res.pos_ecef_m)) and np.all(np.isnan(res.cov_enu))


def test_fewer_satellites_than_states_is_unavailable():
    """m < n: a status in the masked kernels, a ValueError naming the shapes in the dense."""
    rng = np.random.default_rng(9)
    h, z = good_batch(rng, 2, 7)
    w = np.full(z.shape, SIGMA_M**-2)
    w[0, 3:] = 0.0  # three satellites used, four states
    s = parity_statistics(h, z, w, P_FA, np.array([-1, 3]))
    assert list(s.available) == [False, True] and np.isnan(s.statistic[0])
    for f in (mss.mss, mss.classic_raim):
        res = f(h, z, w, np.ones(7, bool), P_FA, P_MD)
        assert list(res.status) == [mss.STATUS_UNAVAILABLE, mss.STATUS_OK]
        assert np.isnan(res.hpl_m[0]) and np.isfinite(res.hpl_m[1])
    sv = satellites(-h[..., :3])
    fix = wls(sv, np.linalg.norm(sv - RX, axis=-1), w, np.zeros(7, int))
    assert list(fix.available) == [False, True] and np.all(np.isnan(fix.pos_ecef_m[0]))
    for f in (parity_test, sse_test):
        with pytest.raises(ValueError, match=r"h must have shape \(\.\.\., m, n\).*\(3, 4\)"):
            f(h[0, :3], z[0, :3], SIGMA_M, P_FA)


def test_absent_clock_is_not_singular_in_the_masked_kernels():
    """A system with no satellite used pins its clock instead of making N singular."""
    rng = np.random.default_rng(10)
    h = np.concatenate([rows(los(rng, (7,))), np.zeros((7, 1))], axis=-1)
    h[6, 3:] = [0.0, 1.0]  # satellite 6 is the only one of system 1
    w = np.full(7, SIGMA_M**-2)
    w[6] = 0.0
    z = rng.normal(size=7)
    s = parity_statistics(h, z, w, P_FA, 2)
    assert s.available and np.isfinite(s.statistic)
    _, present, ok = normal_solve(h, w)
    assert ok and list(present) == [True, True, True, True, False]


def test_satellite_without_redundancy_is_never_isolated():
    """The only satellite of a system has leverage 1 (S_jj = 0): no isolation number."""
    rng = np.random.default_rng(12)
    h = np.concatenate([rows(los(rng, (7,))), np.zeros((7, 1))], axis=-1)
    h[6, 3:] = [0.0, 1.0]
    z = rng.normal(size=7)
    z[6] += 1e4  # invisible to the parity test: absorbed by its own clock
    z[0] += 100.0
    s = parity_statistics(h, z, np.ones(7), P_FA, 2)
    assert s.alarm and s.best == 0
    assert np.isnan(s.isolation[6]) and np.isnan(s.fault_size_m[6])
    assert np.isnan(s.isolability[6]) and np.all(np.isfinite(s.isolation[:6]))
    d = parity_test(h, z, 1.0, P_FA)
    assert d.faulty == 0 and np.isnan(d.isolation[6])


def test_unused_satellite_without_position_does_not_block_the_fix():
    """A NaN position (no ephemeris) of an unused satellite, and a NaN start point."""
    rng = np.random.default_rng(13)
    sv = satellites(los(rng, (2, 8)))
    pr = np.linalg.norm(sv - RX, axis=-1)
    w = np.ones((2, 8))
    ref = wls(sv[:, :7], pr[:, :7], w[:, :7], np.zeros(7, int))
    sv[:, 7] = np.nan
    w[:, 7] = 0.0
    x0 = np.array([[np.nan] * 3, [0.0, 0.0, 0.0]])
    res = wls(sv, pr, w, np.zeros(8, int), x0_ecef_m=x0)
    assert np.all(res.available)
    np.testing.assert_allclose(res.pos_ecef_m, ref.pos_ecef_m, rtol=0, atol=1e-6)
    assert np.all(np.isnan(res.resid_m[:, 7]))


@settings(max_examples=40, deadline=None)
@given(seed=seeds, log_rcond=st.floats(-16.0, -8.0), n=st.integers(2, 8))
def test_fast_conditioning_test_equals_eigenvalue_ratio(seed, log_rcond, n):
    """The determinant shortcut decides exactly as lambda_min / lambda_max > RCOND_MIN."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    a = (q * np.logspace(0.0, log_rcond, n)) @ q.T
    ns, _ = _scaled(a)
    eig = np.linalg.eigvalsh(ns)
    expect = eig[0] > RCOND_MIN * eig[-1]
    assert bool(_well_conditioned(ns)) == expect
    assert bool(_well_conditioned(np.stack([np.eye(n), ns]))[1]) == expect


# --- permutation invariance ---------------------------------------------------------------

@settings(max_examples=20, deadline=None)
@given(seed=seeds, m=st.integers(6, 10))
def test_permuting_satellites_permutes_outputs(seed, m):
    rng = np.random.default_rng(seed)
    h, z = good_batch(rng, 1, m)
    z[0, 0] += 40.0 * SIGMA_M  # an alarm, so isolation and identification have work
    perm = rng.permutation(m)
    for kernel in ("parity_test", "sse_test", "parity_statistics", "mss", "classic_raim",
                   "wls"):
        stat_a, avail_a, sat_a, _ = RUNNERS[kernel](h, z)
        stat_b, avail_b, sat_b, _ = RUNNERS[kernel](h[:, perm], z[:, perm])
        assert np.array_equal(avail_a, avail_b), kernel
        np.testing.assert_allclose(stat_b, stat_a, rtol=1e-9, atol=1e-9 if kernel != "wls"
                                   else one_mm, err_msg=kernel)
        np.testing.assert_allclose(sat_b, sat_a[:, perm], rtol=1e-6, atol=1e-6,
                                   err_msg=kernel)
    a = parity_test(h, z, SIGMA_M, P_FA)
    b = parity_test(h[:, perm], z[:, perm], SIGMA_M, P_FA)
    assert np.array_equal(a.alarm, b.alarm)
    assert np.array_equal(perm[b.faulty[b.faulty >= 0]], a.faulty[a.faulty >= 0])


# --- parity matrix identities -------------------------------------------------------------

@settings(max_examples=25, deadline=None)
@given(seed=seeds, m=st.integers(5, 12), n_epochs=st.integers(1, 4))
def test_parity_matrix_identities_batched(seed, m, n_epochs):
    h = rows(los(np.random.default_rng(seed), (n_epochs, m)))
    v = parity_matrix(h, "qr")
    eye = np.eye(m - 4)
    assert np.abs(v @ h).max() < 1e-9
    assert np.abs(v @ np.swapaxes(v, -1, -2) - eye).max() < 1e-9
    vp = parity_matrix(h, "potter")
    ok = np.all(np.isfinite(vp), axis=(-2, -1))
    # Potter's rounding grows as 1 / (smallest pivot)^2 (see test_parity.py).
    piv2 = np.min(np.diagonal(vp[ok], axis1=-2, axis2=-1) ** 2, axis=-1, initial=1.0)
    bound = np.maximum(1e-9, 50 * np.finfo(float).eps / piv2)
    assert np.all(np.abs(vp[ok] @ h[ok]).max(axis=(-2, -1)) < 1e-9)
    err = np.abs(vp[ok] @ np.swapaxes(vp[ok], -1, -2) - eye).max(axis=(-2, -1))
    assert np.all(err < bound)


# --- batched equals per epoch -------------------------------------------------------------

@pytest.mark.parametrize("kernel", list(RUNNERS))
def test_batched_equals_per_epoch(kernel):
    rng = np.random.default_rng(11)
    h, z = good_batch(rng, 4, 8)
    h[1] = rows(singular_los(rng, 8, "cone"))
    stat, avail, per_sat, _ = RUNNERS[kernel](h, z)
    for e in range(4):
        s1, a1, p1, _ = RUNNERS[kernel](h[e:e + 1], z[e:e + 1])
        assert a1[0] == avail[e]
        np.testing.assert_allclose(s1[0], stat[e], rtol=1e-12)
        np.testing.assert_allclose(p1[0], per_sat[e], rtol=1e-10, atol=1e-12)


# --- bad inputs: ValueError naming the argument -------------------------------------------

def _base():
    rng = np.random.default_rng(0)
    h = rows(los(rng, (6,)))
    w = np.full(6, SIGMA_M**-2)
    return {"h": h, "z": np.zeros(6), "w": w, "sv": satellites(-h[:, :3]),
            "proj": np.eye(6)}


def _call(name, **over):
    b = _base()
    if name == "parity_test":
        kw = dict(h=b["h"], z=b["z"], sigma_m=SIGMA_M, p_fa=P_FA) | over
        return parity_test(**kw)
    if name == "parity_matrix":
        kw = dict(h=b["h"], method="qr") | over
        return parity_matrix(**kw)
    if name == "sse_test":
        kw = dict(h=b["h"], z=b["z"], sigma_m=SIGMA_M, p_fa=P_FA) | over
        return sse_test(**kw)
    if name == "parity_statistics":
        kw = dict(h=b["h"], resid_m=b["z"], weights=b["w"], p_fa=P_FA, dof=2) | over
        return parity_statistics(**kw)
    if name == "detection_probability":
        kw = dict(projector=b["proj"], bias_m=b["z"], weights=b["w"], dof=2, p_fa=P_FA) | over
        return detection_probability(**kw)
    if name == "normal_solve":
        kw = dict(a=b["h"], w=b["w"]) | over
        return normal_solve(**kw)
    if name in ("mss", "classic_raim"):
        kw = dict(h=b["h"], z_m=b["z"], w=b["w"], is_sat=np.ones(6, bool), p_fa=P_FA,
                  p_md=P_MD) | over
        return getattr(mss, name)(**kw)
    if name == "wls":
        kw = dict(pos_sv_ecef_m=b["sv"], pr_m=np.linalg.norm(b["sv"] - RX, axis=-1),
                  weights=b["w"], sys_idx=np.zeros(6, int)) | over
        return wls(**kw)
    if name == "lambda_detect":
        kw = dict(dof=2, p_fa=P_FA, p_md=P_MD) | over
        return mss.lambda_detect(**kw)
    if name == "availability":
        kw = dict(hpl_m=[1.0], vpl_m=[1.0], hal_m=40.0, val_m=50.0) | over
        return mss.availability(**kw)
    if name == "geometry_rows":
        kw = dict(u_enu=los(np.random.default_rng(0), (6,)), sys_idx=np.zeros(6, int),
                  n_sys=1, baro=True) | over
        return mss.geometry_rows(**kw)
    raise AssertionError(name)


BAD_INPUTS = [
    # (kernel, overrides, expected message regex: always names the argument)
    ("parity_test", {"p_fa": 0.0}, "p_fa"),
    ("parity_test", {"p_fa": 1.0}, "p_fa"),
    ("parity_test", {"p_fa": np.nan}, "p_fa"),
    ("parity_test", {"p_fa": True}, "p_fa"),
    ("parity_test", {"p_fa": "0.001"}, "p_fa"),
    ("parity_test", {"sigma_m": 0.0}, "sigma_m"),
    ("parity_test", {"sigma_m": -3.0}, "sigma_m"),
    ("parity_test", {"sigma_m": np.inf}, "sigma_m"),
    ("parity_test", {"sigma_m": np.ones(4)}, r"sigma_m must be a scalar or have shape"),
    ("parity_test", {"z": np.zeros(5)},
     r"z must have shape \(\.\.\., 6\) to match h \(\.\.\., 6, 4\), got \(5,\)"),
    ("parity_test", {"z": np.zeros((2, 6)), "h": np.zeros((3, 6, 4))}, "z has batch shape"),
    ("parity_test", {"h": np.zeros(6)}, "h must have shape"),
    ("parity_test", {"h": np.ones((4, 4)), "z": np.zeros(4)}, r"h must have shape.*m > n"),
    ("parity_test", {"method": "svd"}, "method"),
    ("parity_matrix", {"h": np.ones((3, 4))}, "h must have shape"),
    ("parity_matrix", {"h": np.full((6, 4), np.nan)}, "h must contain only finite"),
    ("sse_test", {"sigma_m": 0.0}, "sigma_m"),
    ("sse_test", {"sigma_m": np.nan}, "sigma_m"),
    ("sse_test", {"p_fa": 2.0}, "p_fa"),
    ("sse_test", {"h": np.ones((4, 4)), "z": np.zeros(4)}, r"h must have shape.*\(4, 4\)"),
    ("sse_test", {"z": np.zeros(7)}, r"z must have shape \(\.\.\., 6\)"),
    ("parity_statistics", {"p_fa": 2}, "p_fa"),
    ("parity_statistics", {"p_fa": -0.1}, "p_fa"),
    ("parity_statistics", {"resid_m": np.zeros(5)}, r"resid_m must have shape \(\.\.\., 6\)"),
    ("parity_statistics", {"weights": np.ones(5)}, r"weights must have shape \(\.\.\., 6\)"),
    ("parity_statistics", {"weights": -np.ones(6)}, "weights must be finite and >= 0"),
    ("parity_statistics", {"weights": np.full(6, np.inf)}, "weights must be finite"),
    ("parity_statistics", {"dof": 2.5}, "dof must hold integers"),
    ("parity_statistics", {"dof": np.ones(3, int), "h": np.ones((2, 6, 4))},
     r"dof has batch shape \(3,\).*\(2,\) of h"),
    ("parity_statistics", {"h": np.ones(6)}, "h must have shape"),
    ("detection_probability", {"p_fa": 1.5}, "p_fa"),
    ("detection_probability", {"projector": np.eye(6)[:5]}, r"projector must have shape"),
    ("detection_probability", {"bias_m": np.zeros(5)}, r"bias_m must have shape \(\.\.\., 6\)"),
    ("detection_probability", {"weights": np.ones(7)}, "weights must have shape"),
    ("normal_solve", {"w": np.ones(5)}, r"w must have shape \(\.\.\., 6\) to match a"),
    ("normal_solve", {"w": -np.ones(6)}, "w must be finite and >= 0"),
    ("normal_solve", {"a": np.ones(6)}, "a must have"),
    ("mss", {"p_fa": 0.0}, "p_fa"),
    ("mss", {"p_md": 1.0}, "p_md"),
    ("mss", {"z_m": np.zeros(5)}, r"z_m must have shape \(\.\.\., 6\) to match h"),
    ("mss", {"w": np.ones(5)}, r"w must have shape \(\.\.\., 6\)"),
    ("mss", {"w": -np.ones(6)}, "w must be finite and >= 0"),
    ("mss", {"is_sat": np.ones(5, bool)}, r"is_sat must have shape \(6,\)"),
    ("mss", {"is_sat": np.full(6, 2)}, "is_sat must be a boolean"),
    ("mss", {"h": np.ones((6, 2))}, r"h must have shape .*n >= 3"),
    ("mss", {"z_m": np.zeros((2, 6)), "h": np.ones((3, 6, 4))}, "z_m has batch shape"),
    ("classic_raim", {"p_md": 1.5}, "p_md"),
    ("classic_raim", {"z_m": np.zeros(7)}, "z_m must have shape"),
    ("wls", {"pr_m": np.zeros(5)},
     r"pr_m must have shape \(\.\.\., 6\) to match pos_sv_ecef_m \(\.\.\., 6, 3\)"),
    ("wls", {"weights": np.ones(7)}, "weights must have shape"),
    ("wls", {"weights": -np.ones(6)}, "weights must be finite and >= 0"),
    ("wls", {"sys_idx": np.zeros(5, int)}, r"sys_idx must have shape \(6,\)"),
    ("wls", {"sys_idx": -np.ones(6, int)}, "sys_idx entries must be in"),
    ("wls", {"sys_idx": np.ones(6, int), "n_sys": 1}, r"sys_idx entries must be in \[0, 1\)"),
    ("wls", {"sys_idx": np.zeros(6, bool)}, "sys_idx must be an integer array"),
    ("wls", {"n_sys": 0}, "n_sys"),
    ("wls", {"pos_sv_ecef_m": np.ones((6, 2))}, "pos_sv_ecef_m must have shape"),
    ("wls", {"x0_ecef_m": np.zeros(2)}, "x0_ecef_m must have shape"),
    ("wls", {"max_iter": 0}, "max_iter"),
    ("wls", {"tol_m": 0.0}, "tol_m"),
    ("lambda_detect", {"dof": 0}, "dof"),
    ("lambda_detect", {"dof": True}, "dof"),
    ("lambda_detect", {"p_md": 0.0}, "p_md"),
    ("availability", {"hal_m": -1.0}, "hal_m"),
    ("availability", {"val_m": np.nan}, "val_m"),
    ("geometry_rows", {"sys_idx": np.ones(6, int)}, "sys_idx entries must be in"),
    ("geometry_rows", {"u_enu": np.ones((6, 2))}, "u_enu must have shape"),
]


@pytest.mark.parametrize("kernel, over, message", BAD_INPUTS,
                         ids=[f"{k}-{next(iter(o))}-{i}" for i, (k, o, _) in
                              enumerate(BAD_INPUTS)])
def test_bad_inputs_raise_value_error_naming_the_argument(kernel, over, message):
    with pytest.raises(ValueError, match=message):
        _call(kernel, **over)


@pytest.mark.parametrize("kernel", ["parity_test", "sse_test", "parity_statistics",
                                    "detection_probability", "mss", "classic_raim",
                                    "lambda_detect", "wls"])
def test_numpy_scalars_are_numbers(kernel):
    """np.float32 / np.int64 are accepted wherever Python numbers are, same results."""
    over = {"p_fa": np.float32(0.25)}
    if kernel in ("parity_test", "sse_test"):
        over["sigma_m"] = np.float32(SIGMA_M)
    if kernel in ("parity_statistics", "detection_probability", "lambda_detect"):
        over["dof"] = np.int64(2)
    if kernel == "wls":
        over = {"n_sys": np.int64(1), "max_iter": np.int32(12), "tol_m": np.float32(1e-4)}
    a = _call(kernel, **{k: x.item() for k, x in over.items()})
    b = _call(kernel, **over)
    if hasattr(a, "__dataclass_fields__"):
        assert_same(_fields(a), _fields(b))
    else:
        for x, y in zip(np.atleast_1d(a), np.atleast_1d(b), strict=True):
            assert np.array_equal(np.asarray(x), np.asarray(y), equal_nan=True)


# --- the validation helpers ---------------------------------------------------------------

@pytest.mark.parametrize("value", [0.5, 1, np.float32(0.5), np.float64(2.0), np.int64(5),
                                   np.int8(1), np.array(3.0)])
def test_numbers_accept_numpy_scalars(value):
    assert v.check_positive("x", value) == float(value)
    assert v.check_finite_number("x", value) == float(value)
    assert v.check_range("x", value, 0.0, 10.0) == float(value)


@pytest.mark.parametrize("value", [True, False, np.bool_(True), "1.0", None, 1 + 2j,
                                   np.array([1.0, 2.0]), [1.0]])
def test_non_numbers_are_rejected_naming_the_argument(value):
    for check in (v.check_positive, v.check_finite_number, v.check_probability):
        with pytest.raises(ValueError, match="sigma_m"):
            check("sigma_m", value)
    with pytest.raises(ValueError, match="sigma_m"):
        v.check_range("sigma_m", value, 0.0, 10.0)
    with pytest.raises(ValueError, match="n_sat"):
        v.check_int("n_sat", value)


def test_check_helpers_edges():
    assert v.check_int("n", np.int64(5), 1) == 5 and v.check_int("n", 5.0) == 5
    assert v.check_probability("p", np.float32(0.25)) == 0.25
    assert v.check_probability("p", 1, open_interval=False) == 1.0
    with pytest.raises(ValueError, match="p"):
        v.check_probability("p", True, open_interval=False)
    for bad in (np.inf, -np.inf, np.nan):
        with pytest.raises(ValueError, match="x must be a finite number"):
            v.check_finite_number("x", bad)
    with pytest.raises(ValueError, match="sigma_m must be a finite number > 0"):
        v.check_positive("sigma_m", 0.0)
    assert v.check_positive("sigma_m", 0.0, allow_zero=True) == 0.0
    with pytest.raises(ValueError, match="n must be an integer"):
        v.check_int("n", 2.5)
    assert v.check_batch({"a": (3, 1), "b": (4,), "c": ()}) == (3, 4)
    with pytest.raises(ValueError, match=r"b has batch shape \(2,\).*\(3,\) of a"):
        v.check_batch({"a": (3,), "b": (2,)})
    w = v.check_weights("w", [1.0, np.nan, 0.0], last=(3,))
    assert list(w) == [1.0, 0.0, 0.0]
