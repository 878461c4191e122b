"""Reference path of :mod:`raimcore.araim.kernel`: sections 5-8 as first written.

The plain numpy kernel kept verbatim for the agreement tests (``tests/test_araim.py``) and
the benchmark (``tests/benchmarks/bench_araim.py``): :func:`raimcore.araim.mhss._mhss` with
``reference=True`` runs it, one exclusion candidate at a time. The fast kernel must give the
same availability, alarms and exclusions and the same protection levels to rounding.
The formulas are those of :mod:`raimcore.araim.kernel` (see its docstring); both write
the exact statistics of the modes that remove only lone satellites of their constellations
(:func:`raimcore.araim.kernel.void_modes`), whose computed values are rounding noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

from .kernel import set_void_modes, void_modes

__all__ = ["evaluate"]

#: All-in-view geometry is singular when cond(G^T W G) >= 1e7 (``compute_subset_solutions.m``).
COND_MAX = 1e7
#: A subset is unmonitorable when its normal matrix keeps less than this share of the
#: all-in-view determinant, ``det(N_k)/det(N_0)`` (= ``det(M_bb)``; absent clock columns
#: counted with the all-in-view diagonal). MAAST's test is ``rcond(N_k) > 10 eps``; both
#: reject only numerically singular subsets.
RATIO_MIN = 1e-10
#: Bisection steps when ``pl_max_iter = 0`` (the interval halves each step: 200 steps
#: reach the resolution of a double from any bracket).
_MAX_STEPS = 200


def q_inv(p):
    """Q^-1(p), the upper normal tail inverse (``-ndtri(p)``, accurate for small p)."""
    return -ndtri(p)


@dataclass(frozen=True)
class AllInView:
    """All-in-view solution of a batch of epochs (see :func:`allinview`)."""

    ok: np.ndarray  # (E,) bool
    reason: np.ndarray  # (E,) int: 0 ok, 1 too few satellites, 2 singular
    n0: np.ndarray  # (E, m, m) normal matrix (identity where not ok)
    p0: np.ndarray  # (E, 3, n) position rows of S0
    s0: np.ndarray  # (E, m, n)
    m: np.ndarray  # (E, n, n) residual matrix I - G S0
    sigma: np.ndarray  # (E, 3)
    bias: np.ndarray  # (E, 3)
    sigma_acc: np.ndarray  # (E, 3) accuracy sigma per axis
    resid: np.ndarray | None  # (E, n) r = M y
    dx: np.ndarray | None  # (E, 3) S0 y


def allinview(g, cint, cacc, bnom, y=None) -> AllInView:
    """Weighted least squares with ``W = C_int^-1`` over every satellite (section 5)."""
    e, n, m = g.shape
    gw = g / cint[..., None]
    n0 = np.swapaxes(gw, -1, -2) @ g
    enough = n >= max(m, 4)
    lam = np.linalg.eigvalsh(n0)
    with np.errstate(divide="ignore", invalid="ignore"):
        cond = lam[..., -1] / lam[..., 0]
    regular = (lam[..., 0] > 0.0) & (cond < COND_MAX)
    ok = np.asarray(enough & regular)
    reason = np.where(ok, 0, np.where(enough, 2, 1))
    n0 = np.where(ok[:, None, None], n0, np.eye(m))
    s0 = np.linalg.inv(n0) @ np.swapaxes(gw, -1, -2)
    p0 = s0[:, :3, :]
    mres = np.eye(n) - g @ s0
    sigma = np.sqrt(np.einsum("eqn,en->eq", p0 * p0, cint))
    bias = np.einsum("eqn,en->eq", np.abs(p0), bnom)
    sigma_acc = np.sqrt(np.einsum("eqn,en->eq", p0 * p0, cacc))
    resid = dx = None
    if y is not None:
        resid = np.einsum("eij,ej->ei", mres, y)
        dx = np.einsum("eqn,en->eq", p0, y)
    return AllInView(ok, reason, n0, p0, s0, mres, sigma, bias, sigma_acc, resid, dx)


@dataclass(frozen=True)
class SubsetStats:
    """Per-mode statistics, shapes ``(E, K, 3)`` unless said; inf where unmonitorable."""

    sigma: np.ndarray
    bias: np.ndarray
    sigma_ss: np.ndarray
    bias_ss: np.ndarray
    sigma_acc_v: np.ndarray | None  # (E, K) sigma_acc,3^(k) (B2012 EMT only)
    monitorable: np.ndarray  # (E, K) bool
    sep: np.ndarray | None  # (E, K, 3) (S^(k) - S^(0)) y


def mode_classes(cons, c: int, removed):
    """Static facts of each mode: size, constellation emptied, count rule (section 5)."""
    n = len(cons)
    member = cons[None, :] == np.arange(c)[:, None]  # (c, n)
    left = (~removed).astype(int) @ member.T.astype(int)  # (K, c) satellites left
    size = removed.sum(axis=1)
    emptied = np.any(left == 0, axis=1)
    n_unknowns = 3 + np.sum(left > 0, axis=1)
    count_ok = (n - size) >= np.maximum(n_unknowns, 4)
    return size, emptied, count_ok, left > 0


def subset_stats(av: AllInView, g, cint, cacc, bnom, bcont, cons, removed, *,
                 need_acc: bool = False, y=None) -> SubsetStats:
    """Statistics of every subset solution (section 5) for every epoch.

    ``removed`` (K, n) bool, row 0 the fault-free mode. See the module docstring for the
    down-date formulas; modes that are not one/two-satellite down-dates are solved from
    their normal equations.
    """
    e, n, m = g.shape
    k_all = len(removed)
    size, emptied, count_ok, present = mode_classes(cons, m - 3, removed)
    shape = (e, k_all, 3)
    sigma = np.full(shape, np.inf)
    bias = np.full(shape, np.inf)
    sigma_ss = np.full(shape, np.inf)
    bias_ss = np.full(shape, np.inf)
    sacc = np.full((e, k_all), np.inf) if need_acc else None
    sep = np.full(shape, np.nan) if y is not None else None
    ratio = np.zeros((e, k_all))
    sigma[:, 0], bias[:, 0] = av.sigma, av.bias
    sigma_ss[:, 0] = bias_ss[:, 0] = 0.0
    ratio[:, 0] = 1.0
    if need_acc:
        sacc[:, 0] = av.sigma_acc[:, 2]
    if sep is not None:
        sep[:, 0] = 0.0
    any_bnom = bool(np.any(bnom > 0.0))
    any_bcont = bool(np.any(bcont > 0.0))
    x_acc = None
    if need_acc:  # M diag(C_acc) S0_3^T, for the accuracy sigma of down-dated subsets
        x_acc = np.einsum("eij,ej->ei", av.m, cacc * av.p0[:, 2, :])

    for r in (1, 2):
        ks = np.flatnonzero((size == r) & ~emptied)
        if ks.size == 0:
            continue
        idx = np.array([np.flatnonzero(removed[k]) for k in ks])  # (Kr, r)
        st = _downdate(av, idx, cint, cacc, bnom, bcont, any_bnom, any_bcont, x_acc, y)
        sigma[:, ks], bias[:, ks], sigma_ss[:, ks], bias_ss[:, ks] = st[:4]
        ratio[:, ks] = st[4]
        if need_acc:
            sacc[:, ks] = st[5]
        if sep is not None:
            sep[:, ks] = st[6]

    ks = np.flatnonzero((size >= 1) & ~(((size == 1) | (size == 2)) & ~emptied))
    if ks.size:
        st = _direct(av, g, cint, cacc, bnom, bcont, removed[ks], present[ks], need_acc, y)
        sigma[:, ks], bias[:, ks], sigma_ss[:, ks], bias_ss[:, ks] = st[:4]
        ratio[:, ks] = st[4]
        if need_acc:
            sacc[:, ks] = st[5]
        if sep is not None:
            sep[:, ks] = st[6]

    set_void_modes(av, void_modes(size, present), sigma, bias, sigma_ss, bias_ss, sacc, sep)
    mon = av.ok[:, None] & count_ok[None, :] & (ratio > RATIO_MIN)
    mon[:, 0] = av.ok
    bad = ~mon
    for a in (sigma, bias, sigma_ss, bias_ss):
        a[bad] = np.inf
    if need_acc:
        sacc[bad] = np.inf
    if sep is not None:
        sep[bad] = np.nan
    return SubsetStats(sigma, bias, sigma_ss, bias_ss, sacc, mon, sep)


def _downdate(av, idx, cint, cacc, bnom, bcont, any_bnom, any_bcont, x_acc, y):
    """Modes removing the satellites ``idx`` (Kr, r), r in (1, 2), no clock lost."""
    kr, r = idx.shape
    mres, p0 = av.m, av.p0
    mbb = mres[:, idx[:, :, None], idx[:, None, :]]  # (E, Kr, r, r)
    if r == 1:
        det = mbb[..., 0, 0]
        good = det > RATIO_MIN
        inv = (1.0 / np.where(good, det, 1.0))[..., None, None]
    else:
        a_, b_, c_, d_ = mbb[..., 0, 0], mbb[..., 0, 1], mbb[..., 1, 0], mbb[..., 1, 1]
        det = a_ * d_ - b_ * c_
        good = det > RATIO_MIN
        s = 1.0 / np.where(good, det, 1.0)
        inv = np.stack([np.stack([d_ * s, -b_ * s], -1), np.stack([-c_ * s, a_ * s], -1)], -2)
    p0b = np.moveaxis(p0[:, :, idx], 1, 2)  # (E, Kr, 3, r)
    amat = p0b @ inv  # (E, Kr, 3, r)
    # Q_int = M C_int (symmetric): (Q_int)_bb = M_bb * C_int,b (columns).
    q_int = mbb * cint[:, idx][:, :, None, :]
    if r == 1:  # (M diag(C_acc) M^T)_ii from one matrix-vector product per epoch
        q_acc = ((mres * mres) @ cacc[..., None])[:, idx[:, 0], 0][..., None, None]
    else:
        mb = mres[:, idx, :]  # (E, Kr, r, n)
        q_acc = np.einsum("ekal,ekbl,el->ekab", mb, mb, cacc)
    var_add = np.einsum("ekqa,ekab,ekqb->ekq", amat, q_int, amat)
    sigma = np.sqrt(av.sigma[:, None, :] ** 2 + np.maximum(var_add, 0.0))
    sigma_ss = np.sqrt(np.maximum(np.einsum("ekqa,ekab,ekqb->ekq", amat, q_acc, amat), 0.0))
    if r == 1:
        mrow = mres[:, idx[:, 0], :]  # (E, Kr, n)
        if any_bcont:
            bias_ss = np.abs(amat[..., 0]) * (np.abs(mrow) @ bcont[:, :, None])
        else:
            bias_ss = np.zeros_like(sigma)
        if any_bnom:
            s_k = p0[:, None, :, :] - amat[..., 0][..., None] * mrow[:, :, None, :]
            bias = np.einsum("ekqn,en->ekq", np.abs(s_k), bnom)
        else:
            bias = np.zeros_like(sigma)
    else:
        mb = mres[:, idx, :]
        ds = amat @ mb if (any_bnom or any_bcont) else None  # (E, Kr, 3, n) = S0 - S^(k)
        bias_ss = (np.einsum("ekqn,en->ekq", np.abs(ds), bcont) if any_bcont
                   else np.zeros_like(sigma))
        bias = (np.einsum("ekqn,en->ekq", np.abs(p0[:, None] - ds), bnom) if any_bnom
                else np.zeros_like(sigma))
    sacc = None
    if x_acc is not None:
        a3 = amat[:, :, 2, :]  # (E, Kr, r)
        var = (av.sigma_acc[:, None, 2] ** 2 - 2.0 * np.sum(a3 * x_acc[:, idx], axis=-1)
               + np.einsum("eka,ekab,ekb->ek", a3, q_acc, a3))
        sacc = np.sqrt(np.maximum(var, 0.0))
    sep = None
    if y is not None:
        sep = -np.einsum("ekqa,eka->ekq", amat, av.resid[:, idx])
    ratio = np.where(good, det, 0.0)
    return sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep


def _direct(av, g, cint, cacc, bnom, bcont, removed, present, need_acc, y):
    """Modes solved from their normal equations (clock columns of emptied
    constellations replaced by the all-in-view diagonal, so they decouple)."""
    e, n, m = g.shape
    keep = (~removed).astype(float)  # (Kd, n)
    gw = g / cint[..., None]  # (E, n, m)
    nk = np.einsum("eni,kn,enj->ekij", gw, keep, g)  # (E, Kd, m, m)
    diag0 = np.diagonal(av.n0, axis1=-2, axis2=-1)  # (E, m)
    absent = np.concatenate([np.ones((len(removed), 3), bool), present], axis=1) == 0
    for j in range(m):
        if np.any(absent[:, j]):
            nk[:, absent[:, j], j, j] = diag0[:, j, None]
    d = np.sqrt(diag0)
    outer = d[:, :, None] * d[:, None, :]
    det0 = np.linalg.det(av.n0 / outer)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.linalg.det(nk / outer[:, None]) / det0[:, None]
    ratio = np.where(np.isfinite(ratio), ratio, 0.0)
    good = ratio > RATIO_MIN
    nk = np.where(good[..., None, None], nk, np.eye(m))
    gtw_k = np.swapaxes(gw, -1, -2)[:, None] * keep[None, :, None, :]  # (E, Kd, m, n)
    s_k = np.linalg.inv(nk)[..., :3, :] @ gtw_k
    ds = s_k - av.p0[:, None]  # (E, Kd, 3, n)
    sigma = np.sqrt(np.einsum("ekqn,en->ekq", s_k * s_k, cint))
    bias = np.einsum("ekqn,en->ekq", np.abs(s_k), bnom)
    sigma_ss = np.sqrt(np.einsum("ekqn,en->ekq", ds * ds, cacc))
    bias_ss = np.einsum("ekqn,en->ekq", np.abs(ds), bcont)
    sacc = np.sqrt(np.einsum("ekn,en->ek", s_k[:, :, 2] ** 2, cacc)) if need_acc else None
    sep = np.einsum("ekqn,en->ekq", ds, y) if y is not None else None
    return sigma, bias, sigma_ss, bias_ss, np.where(good, ratio, 0.0), sacc, sep


def solve_pl(c, sig, p, a, target, tol: float, max_iter: int = 0):
    """Protection level: the root ``L`` of ``sum_j p_j min(Qm((L - c_j)/sig_j), a_j) =
    target`` by MAAST's half-interval search (section 7), row by row.

    Parameters
    ----------
    c, sig, p, a : (R, J) -- offsets (T + b), sigmas, priors (0: term ignored), caps.
    target : (R,) -- the allocated budget (<= 0: infinite PL).
    tol : stop when ``L_up - L_low <= tol``; ``max_iter`` caps the steps (0: no cap).

    Returns
    -------
    (R,) ``L_up``, within ``[root, root + tol]`` (``inf`` where ``target <= 0``).
    """
    active = p > 0.0
    c = np.where(active, c, 0.0)
    sig = np.where(active, sig, 1.0)
    p = np.where(active, p, 0.0)
    a = np.where(active, a, 1.0)
    ok = (target > 0.0) & np.any(active, axis=1)
    tgt = np.where(ok, target, 1.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        pa = p * a
        k_low = q_inv(np.minimum(1.0, np.where(active, tgt[:, None] / pa, 1.0)))
        low = np.max(np.where(active, c + k_low * sig, -np.inf), axis=1)
        k_terms = np.maximum(active.sum(axis=1), 1)
        k_high = np.maximum(0.0, q_inv(np.minimum(1.0, tgt[:, None] / (k_terms[:, None] * p))))
        up = np.max(np.where(active, c + k_high * sig, -np.inf), axis=1)
        low, up = np.where(ok, low, 0.0), np.where(ok, up, 0.0)
    steps = max_iter if max_iter > 0 else _MAX_STEPS
    rows = np.flatnonzero(ok & (up - low > tol))
    for _ in range(steps):
        if rows.size == 0:
            break
        mid = 0.5 * (low[rows] + up[rows])
        x = (mid[:, None] - c[rows]) / sig[rows]
        qm = np.where(x < 0.0, 1.0, ndtr(-np.maximum(x, 0.0)))
        lhs = np.sum(p[rows] * np.minimum(qm, a[rows]), axis=1)
        high = lhs > tgt[rows]
        low[rows] = np.where(high, mid, low[rows])
        up[rows] = np.where(high, up[rows], mid)
        rows = rows[up[rows] - low[rows] > tol]
    return np.where(ok, up, np.inf)


@dataclass(frozen=True)
class Evaluation:
    """Sections 5-8 for one batch of epochs and one mode list (arrays ``(E, ...)``)."""

    ok: np.ndarray
    reason: np.ndarray
    hpl: np.ndarray
    hpl1: np.ndarray
    hpl2: np.ndarray
    vpl: np.ndarray
    emt: np.ndarray
    sigma_acc_v: np.ndarray
    n_fm: np.ndarray
    p_nm: np.ndarray
    k_fa: np.ndarray  # (E, 3)
    phmi_v: np.ndarray
    phmi_h: np.ndarray
    sigma0: np.ndarray  # (E, 3)
    bias0: np.ndarray  # (E, 3)
    threshold: np.ndarray  # (E, K, 3)
    stats: SubsetStats
    dx: np.ndarray | None  # (E, 3)
    alarm: np.ndarray | None  # (E,)
    alarm_mode: np.ndarray | None  # (E,)
    test_ratio: np.ndarray | None  # (E,)


def evaluate(g, cint, cacc, bnom, bcont, cons, modes, prm: dict, *, rules: str,
             rho=1.0, drop: bool = True, p_nm=None, y=None) -> Evaluation:
    """Sections 5-8 for the epochs of one pattern and its mode list.

    ``drop``: the all-in-view rule (unmonitorable modes leave the list and their ``p_exp``
    joins ``P_nm``); otherwise the exclusion-candidate rule of section 9 (they stay with
    ``sigma = inf``, consuming ``p_inst a`` of the budget, and one with ``p_inst >= P_EMT``
    makes the EMT infinite) with ``p_nm`` (E,), the all-in-view's final ``P_nm`` (what
    ``mhss_raim_baseline_v5.m`` returns to ``usr_vhpl_araim.m``).
    """
    e = g.shape[0]
    b2012 = rules == "blanch-2012"
    av = allinview(g, cint, cacc, bnom, y)
    st = subset_stats(av, g, cint, cacc, bnom, bcont, cons, modes.removed,
                      need_acc=b2012, y=y)
    p_inst, p_exp = modes.p_inst, modes.p_exp
    mon = st.monitorable
    mon_f = mon[:, 1:]
    n_fm = mon_f.sum(axis=1)
    if drop:
        p_nm = modes.p_nm + np.sum(p_exp[1:] * ~mon_f, axis=1)
    else:
        p_nm = np.broadcast_to(modes.p_nm if p_nm is None else p_nm, (e,)).astype(float)
    # Section 6: false-alarm multipliers and thresholds.
    nf = np.where(n_fm > 0, n_fm, 1) * prm["n_es_cont"]
    k_h = q_inv(prm["p_fa_hor"] / (4.0 * nf))
    k_v = q_inv(prm["p_fa_vert"] / (2.0 * nf))
    k_fa = np.stack([k_h, k_h, k_v], axis=-1)
    k_fa = np.where((n_fm > 0)[:, None], k_fa, np.nan)
    with np.errstate(invalid="ignore"):  # inf sigma_ss of unmonitorable modes, masked
        thr = np.where(mon[..., None],
                       np.nan_to_num(k_fa)[:, None, :] * st.sigma_ss + st.bias_ss, np.inf)
    thr[:, 0] = 0.0
    # Section 7: budgets and protection levels.
    pv, ph, nes = prm["phmi_vert"], prm["phmi_hor"], prm["n_es_int"]
    phmi_v = rho * (pv - pv * p_nm / (pv + ph)) / nes
    phmi_h = rho * (0.5 * ph - 0.5 * ph * p_nm / (pv + ph)) / nes
    if prm["max_pmd"]:
        with np.errstate(divide="ignore", invalid="ignore"):
            cap = np.where(p_inst > 0, np.minimum(p_exp / (p_inst * nes), 1.0), 1.0)
    else:
        cap = np.ones_like(p_inst)
    cap = cap.copy()
    cap[0] = 1.0
    pk = np.where(mon, p_inst[None, :], 0.0)
    pk[:, 0] = 2.0
    pk = np.where(av.ok[:, None], pk, 0.0)
    if drop:
        lost = np.zeros(e)
    else:  # sigma = inf terms: their whole allocation p a is spent
        lost = np.sum(np.where(~mon, p_inst[None, :] * cap[None, :], 0.0)[:, 1:], axis=1)
    offs = thr + st.bias  # (E, K, 3)
    ax_c = np.moveaxis(offs, 2, 0).reshape(3 * e, -1)
    ax_s = np.moveaxis(st.sigma, 2, 0).reshape(3 * e, -1)
    ax_p = np.tile(pk, (3, 1))
    ax_a = np.broadcast_to(cap, ax_p.shape)
    tgt = np.concatenate([phmi_h - lost, phmi_h - lost, phmi_v - lost])
    ax_c = np.where(ax_p > 0, ax_c, 0.0)
    ax_s = np.where(ax_p > 0, ax_s, 1.0)
    pl = solve_pl(ax_c, ax_s, ax_p, ax_a, tgt, prm["tol_pl_m"], prm["pl_max_iter"])
    pl = pl.reshape(3, e)
    hpl1, hpl2, vpl = pl[0], pl[1], pl[2]
    hpl = np.hypot(hpl1, hpl2)
    # Section 8: EMT and accuracy.
    sel = mon_f & (p_inst[None, 1:] >= prm["p_emt"])
    t3 = thr[:, 1:, 2]
    if b2012:
        with np.errstate(divide="ignore", invalid="ignore"):
            extra = q_inv(prm["p_emt"] / (2.0 * p_inst[1:]))[None, :] * st.sigma_acc_v[:, 1:]
        cand = t3 + extra
    else:
        cand = t3
    emt = np.max(np.where(sel, cand, 0.0), axis=1, initial=0.0)
    if not drop:
        blind = ~mon_f & (p_inst[None, 1:] >= prm["p_emt"])
        emt = np.where(np.any(blind, axis=1), np.inf, emt)
    sigma_acc_v = av.sigma_acc[:, 2].copy()
    # Section 6: solution-separation test.
    alarm = alarm_mode = ratio = None
    if y is not None:
        sep = st.sep
        with np.errstate(divide="ignore", invalid="ignore"):
            norm = np.abs(sep) / thr
        norm = np.where(np.isnan(norm), np.where(np.abs(sep) > 0, np.inf, 0.0), norm)
        norm = np.where(mon[..., None], norm, -np.inf)
        norm[:, 0] = -np.inf
        worst = np.max(norm, axis=2)  # (E, K)
        alarm_mode = np.argmax(worst, axis=1)
        ratio = worst[np.arange(e), alarm_mode]
        alarm = ratio > 1.0
        none = ~np.isfinite(ratio) & (ratio < 0)
        alarm_mode = np.where(none, -1, alarm_mode)
        ratio = np.where(none, np.nan, ratio)
        alarm = alarm & ~none
    # Unavailable epochs: every output infinite (section 5).
    bad = ~av.ok
    for arr in (hpl, hpl1, hpl2, vpl, emt, sigma_acc_v):
        arr[bad] = np.inf
    n_fm = np.where(bad, 0, n_fm)
    p_nm = np.where(bad, np.nan, p_nm)
    k_fa[bad] = np.nan
    return Evaluation(av.ok, av.reason, hpl, hpl1, hpl2, vpl, emt, sigma_acc_v, n_fm, p_nm,
                      k_fa, phmi_v, phmi_h, av.sigma, av.bias, thr, st, av.dx, alarm,
                      alarm_mode, ratio)
