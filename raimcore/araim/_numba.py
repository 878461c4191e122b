"""Compiled ARAIM kernels (numba): subset solutions and statistics, tests, PL brackets.

Used by :mod:`raimcore.araim.kernel` where numba imports and ``RAIM_STUDIO_NUMBA`` is not
``0`` (:func:`raimcore.araim.kernel.numba_kernels`); never imported by ``import raimcore``.

:func:`downdate_modes` computes, in one pass over (epoch, mode) with no temporaries, the
statistics of every mode that is a one- or two-satellite down-date of a base solution
(the all-in-view, or a constellation's own subset solution for a constellation plus one
or two satellites), the same formulas term for term as ``kernel._downdate`` and
``kernel._nested`` (see the module docstring of :mod:`raimcore.araim.kernel`), so the
numbers differ by rounding only. :func:`pl_equations` builds the protection-level
equations of ``kernel.evaluate`` and MAAST's starting bracket (``kernel.pl_bracket``) in
one pass without the (rows, modes) temporaries; the bracket multipliers (``Q^-1``) are
computed by the caller in numpy (the same numbers as ``pl_bracket`` from the same
inputs). :func:`thresholds_and_test` fuses section 6 (thresholds and the separation
test); :func:`solve_subsets` solves the modes' normal equations (Cholesky of the
diagonally scaled matrix: determinant ratio and inverse) and :func:`nested_bases` forms
the ``I - G Sb`` products of ``kernel._nested`` without (E, J, n, n) temporaries.

Kernels trust their inputs: C-contiguous float64 / int64 arrays shaped as documented.
Compiled once per machine with an on-disk cache (``cache=True``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["downdate_modes", "nested_bases", "solve_subsets", "pl_equations",
           "thresholds_and_test", "warm_up"]



@njit(cache=True, fastmath=False, error_model="numpy")
def downdate_modes(pb, mb, sigb2, ratio_b, d2, xb, dy, rb, p0, cint, cacc, bnom, bcont,
                   jb, idx, r, ks, ratio_min, any_bnom, any_bcont, need_acc, has_y,
                   sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep):
    """Statistics of modes removing the ``r`` (1 or 2) satellites ``idx[j]`` from the base
    ``jb[j]``, written in place at column ``ks[j]`` of the outputs.

    Bases (``J``): ``pb`` (E, J, 3, n) position rows ``Sb[:3]``; ``mb`` (E, J, n, n)
    ``I - G Sb``; ``sigb2`` (E, J, 3) ``sigma_q^(b)2``; ``ratio_b`` (E, J)
    ``det(Nb)/det(N0)``; ``d2`` (E, J, 3) ``|Sb_q - S0_q|^2_Cacc``; ``xb`` (E, J, n, 3)
    ``Mb C_acc (Sb[:3] - S0[:3])^T``; ``dy`` (E, J, 3) ``(Sb - S0)[:3] y``; ``rb`` (E, J, n)
    ``Mb y`` (unused without ``has_y``). ``p0`` (E, 3, n); ``cint``, ``cacc``, ``bnom``,
    ``bcont`` (E, n). ``jb``, ``ks`` (Kr,), ``idx`` (Kr, 2) int64.
    Outputs (E, K, 3): ``sigma``, ``bias``, ``sigma_ss``, ``bias_ss``, ``sep``; (E, K):
    ``ratio``, ``sacc`` (written only with ``need_acc`` / ``has_y``).
    """
    e_n = pb.shape[0]
    n = pb.shape[3]
    kr = idx.shape[0]
    a = np.empty((3, 2))
    for e in range(e_n):
        for j in range(kr):
            base = jb[j]
            k = ks[j]
            b0 = idx[j, 0]
            m00 = mb[e, base, b0, b0]
            if r == 1:
                det = m00
                good = det > ratio_min
                inv00 = 1.0 / (det if good else 1.0)
                for q in range(3):
                    a[q, 0] = pb[e, base, q, b0] * inv00
                q00 = m00 * cint[e, b0]
                qa00 = 0.0
                for i in range(n):
                    mi = mb[e, base, b0, i]
                    qa00 += mi * mi * cacc[e, i]
                for q in range(3):
                    a0 = a[q, 0]
                    sigma[e, k, q] = math.sqrt(sigb2[e, base, q] + max(a0 * a0 * q00, 0.0))
                    var = d2[e, base, q] - 2.0 * (a0 * xb[e, base, b0, q]) + a0 * a0 * qa00
                    sigma_ss[e, k, q] = math.sqrt(max(var, 0.0))
                    if has_y:
                        sep[e, k, q] = dy[e, base, q] - a0 * rb[e, base, b0]
            else:
                b1 = idx[j, 1]
                m01 = mb[e, base, b0, b1]
                m10 = mb[e, base, b1, b0]
                m11 = mb[e, base, b1, b1]
                det = m00 * m11 - m01 * m10
                good = det > ratio_min
                sc = 1.0 / (det if good else 1.0)
                i00, i01, i10, i11 = m11 * sc, -m01 * sc, -m10 * sc, m00 * sc
                for q in range(3):
                    x0 = pb[e, base, q, b0]
                    x1 = pb[e, base, q, b1]
                    a[q, 0] = x0 * i00 + x1 * i10
                    a[q, 1] = x0 * i01 + x1 * i11
                c0, c1 = cint[e, b0], cint[e, b1]
                q00, q01, q10, q11 = m00 * c0, m01 * c1, m10 * c0, m11 * c1
                qa00 = qa01 = qa11 = 0.0
                for i in range(n):
                    u = mb[e, base, b0, i]
                    v = mb[e, base, b1, i]
                    w = cacc[e, i]
                    qa00 += u * u * w
                    qa01 += u * v * w
                    qa11 += v * v * w
                for q in range(3):
                    a0, a1 = a[q, 0], a[q, 1]
                    vi = a0 * a0 * q00 + a0 * a1 * (q01 + q10) + a1 * a1 * q11
                    sigma[e, k, q] = math.sqrt(sigb2[e, base, q] + max(vi, 0.0))
                    quad = a0 * a0 * qa00 + a0 * a1 * (qa01 + qa01) + a1 * a1 * qa11
                    cross = a0 * xb[e, base, b0, q] + a1 * xb[e, base, b1, q]
                    sigma_ss[e, k, q] = math.sqrt(max(d2[e, base, q] - 2.0 * cross + quad,
                                                      0.0))
                    if has_y:
                        sep[e, k, q] = dy[e, base, q] - (a0 * rb[e, base, b0]
                                                         + a1 * rb[e, base, b1])
            ratio[e, k] = ratio_b[e, base] * det if good else 0.0
            if any_bnom or any_bcont or need_acc:
                for q in range(3):
                    sb_ = 0.0
                    sbs = 0.0
                    for i in range(n):
                        ds = a[q, 0] * mb[e, base, b0, i]
                        if r == 2:
                            ds += a[q, 1] * mb[e, base, idx[j, 1], i]
                        s_k = pb[e, base, q, i] - ds
                        if any_bnom:
                            sb_ += abs(s_k) * bnom[e, i]
                        if any_bcont:
                            sbs += abs(s_k - p0[e, q, i]) * bcont[e, i]
                    bias[e, k, q] = sb_
                    bias_ss[e, k, q] = sbs
                if need_acc:
                    v = 0.0
                    for i in range(n):
                        ds = a[2, 0] * mb[e, base, b0, i]
                        if r == 2:
                            ds += a[2, 1] * mb[e, base, idx[j, 1], i]
                        s_k = pb[e, base, 2, i] - ds
                        v += s_k * s_k * cacc[e, i]
                    sacc[e, k] = math.sqrt(v)
            else:
                for q in range(3):
                    bias[e, k, q] = 0.0
                    bias_ss[e, k, q] = 0.0


@njit(cache=True, fastmath=False, error_model="numpy")
def _chol_logdet_inv(a, inv, work):
    """Cholesky of the symmetric ``a`` (m, m) in ``work``; returns ``ln det a`` (``-inf``
    if not positive definite, ``inv`` then untouched), else writes ``inv = a^-1``."""
    m = a.shape[0]
    logdet = 0.0
    for j in range(m):
        d = a[j, j]
        for k in range(j):
            d -= work[j, k] * work[j, k]
        if not d > 0.0:
            return -np.inf
        d = math.sqrt(d)
        work[j, j] = d
        logdet += 2.0 * math.log(d)
        for i in range(j + 1, m):
            v = a[i, j]
            for k in range(j):
                v -= work[i, k] * work[j, k]
            work[i, j] = v / d
    for c in range(m):  # columns of a^-1: L L^T x = e_c
        for i in range(m):
            v = 1.0 if i == c else 0.0
            for k in range(i):
                v -= work[i, k] * inv[k, c]
            inv[i, c] = v / work[i, i]
        for i in range(m - 1, -1, -1):
            v = inv[i, c]
            for k in range(i + 1, m):
                v -= work[k, i] * inv[k, c]
            inv[i, c] = v / work[i, i]
    return logdet


@njit(cache=True, fastmath=False, error_model="numpy")
def solve_subsets(g, cint, n0, removed, absent, ratio_min, s_out, ratio_out):
    """``kernel._solve_subsets`` per (epoch, mode): the normal matrix of the kept
    satellites (clock columns of emptied constellations given the all-in-view diagonal),
    ``det(N_k)/det(N_0)`` of the diagonally scaled matrices (Cholesky), and the first
    rows of ``S^(k) = N_k^-1 G^T W_k`` (``N_k = I`` where the ratio is not above
    ``ratio_min``, as there). ``g`` (E, n, m); ``cint`` (E, n); ``n0`` (E, m, m);
    ``removed`` (Kd, n), ``absent`` (Kd, m) bool; outputs (E, Kd, rows, n), (E, Kd)."""
    e_n, n, m = g.shape
    kd = removed.shape[0]
    rows = s_out.shape[2]
    a = np.empty((m, m))
    inv = np.empty((m, m))
    work = np.zeros((m, m))
    sc = np.empty(m)
    for e in range(e_n):
        for c in range(m):
            sc[c] = math.sqrt(n0[e, c, c])
        for r_ in range(m):
            for c in range(m):
                a[r_, c] = n0[e, r_, c] / (sc[r_] * sc[c])
        ld0 = _chol_logdet_inv(a, inv, work)
        for k in range(kd):
            for r_ in range(m):
                for c in range(m):
                    a[r_, c] = 0.0
            for i in range(n):
                if removed[k, i]:
                    continue
                w = 1.0 / cint[e, i]
                for r_ in range(m):
                    gr = g[e, i, r_] * w
                    if gr == 0.0:
                        continue
                    for c in range(m):
                        a[r_, c] += gr * g[e, i, c]
            for c in range(m):
                if absent[k, c]:
                    a[c, c] = n0[e, c, c]
            for r_ in range(m):
                for c in range(m):
                    a[r_, c] /= sc[r_] * sc[c]
            ld = _chol_logdet_inv(a, inv, work)
            ratio = math.exp(ld - ld0) if ld > -np.inf else 0.0
            good = ratio > ratio_min
            ratio_out[e, k] = ratio if good else 0.0
            for q in range(rows):
                for i in range(n):
                    if removed[k, i]:
                        s_out[e, k, q, i] = 0.0
                        continue
                    v = 0.0
                    if good:
                        for c in range(m):  # N^-1 = D^-1 (A^-1) D^-1, D = diag(sc)
                            v += inv[q, c] / (sc[q] * sc[c]) * g[e, i, c]
                    else:
                        v = g[e, i, q]
                    s_out[e, k, q, i] = v / cint[e, i]


@njit(cache=True, fastmath=False, error_model="numpy")
def nested_bases(g, sb, p0, cint, cacc, y, has_y, mb, sigb2, d2, xb, dy, rb):
    """The bases of ``kernel._nested`` from their subset solutions ``sb`` (E, J, m, n):
    ``mb = I - G Sb`` (E, J, n, n), ``sigb2`` ``|Sb_q|^2_Cint`` and ``d2``
    ``|Sb_q - S0_q|^2_Cacc`` (E, J, 3), ``xb = Mb C_acc (Sb[:3] - S0[:3])^T`` (E, J, n, 3),
    with ``has_y`` ``dy = (Sb - S0)[:3] y`` (E, J, 3) and ``rb = Mb y`` (E, J, n). ``g``
    (E, n, m): three direction columns and one-hot clock columns, as validated by ``mhss``
    (each row's non-zero clock column is the one read)."""
    e_n, j_n, m, n = sb.shape
    w = np.empty((3, n))
    for e in range(e_n):
        for jj in range(j_n):
            for a in range(n):  # G rows: three direction cosines and a one-hot clock
                clk = 3
                for c in range(3, m):
                    if g[e, a, c] != 0.0:
                        clk = c
                g0, g1, g2, gc = g[e, a, 0], g[e, a, 1], g[e, a, 2], g[e, a, clk]
                for b in range(n):
                    v = (g0 * sb[e, jj, 0, b] + g1 * sb[e, jj, 1, b] + g2 * sb[e, jj, 2, b]
                         + gc * sb[e, jj, clk, b])
                    mb[e, jj, a, b] = (1.0 if a == b else 0.0) - v
            for q in range(3):
                for i in range(n):
                    w[q, i] = cacc[e, i] * (sb[e, jj, q, i] - p0[e, q, i])
            for q in range(3):
                s2 = 0.0
                t2 = 0.0
                ty = 0.0
                for i in range(n):
                    sv = sb[e, jj, q, i]
                    dv = sv - p0[e, q, i]
                    s2 += sv * sv * cint[e, i]
                    t2 += dv * dv * cacc[e, i]
                    if has_y:
                        ty += dv * y[e, i]
                sigb2[e, jj, q] = s2
                d2[e, jj, q] = t2
                dy[e, jj, q] = ty
            for a in range(n):
                ry = 0.0
                for q in range(3):
                    v = 0.0
                    for i in range(n):
                        v += mb[e, jj, a, i] * w[q, i]
                    xb[e, jj, a, q] = v
                if has_y:
                    for i in range(n):
                        ry += mb[e, jj, a, i] * y[e, i]
                rb[e, jj, a] = ry


@njit(cache=True, fastmath=False, error_model="numpy")
def pl_equations(thr, bias, sigma, pk, cap, ok, u_of, k_low, k_high, c, sig, p, a, low, up):
    """The protection-level equations of ``kernel.evaluate`` and their bracket
    (``kernel.pl_bracket``) in one pass, rows ``(axis, epoch)``.

    ``thr``, ``bias``, ``sigma`` (E, K, 3); ``pk`` (E, K) priors (0: inactive); ``cap``
    (K,); ``ok`` (3E,) bool; ``u_of`` (3E,) the row of ``k_low``, ``k_high`` (U, K) (the
    bracket multipliers of the row's budget and term count). Writes ``c``, ``sig``,
    ``p``, ``a`` (3E, K) and ``low``, ``up`` (3E,).
    """
    e_n, k_n = pk.shape
    for ax in range(3):
        for e in range(e_n):
            row = ax * e_n + e
            u = u_of[row]
            lo = -np.inf
            hi = -np.inf
            for j in range(k_n):
                pv = pk[e, j]
                if pv > 0.0:
                    cv = thr[e, j, ax] + bias[e, j, ax]
                    sv = sigma[e, j, ax]
                    c[row, j] = cv
                    sig[row, j] = sv
                    p[row, j] = pv
                    a[row, j] = cap[j]
                    vl = cv + k_low[u, j] * sv
                    vh = cv + k_high[u, j] * sv
                    if lo == lo and (vl > lo or vl != vl):  # np.max: NaN propagates
                        lo = vl
                    if hi == hi and (vh > hi or vh != vh):
                        hi = vh
                else:
                    c[row, j] = 0.0
                    sig[row, j] = 1.0
                    p[row, j] = 0.0
                    a[row, j] = 1.0
            low[row] = lo if ok[row] else 0.0
            up[row] = hi if ok[row] else 0.0


@njit(cache=True, fastmath=False, error_model="numpy")
def thresholds_and_test(sigma_ss, bias_ss, mon, k_fa, sep, has_y, thr, worst_mode, worst):
    """Thresholds ``T_k,q`` (section 6) and the solution-separation test of
    ``kernel.evaluate`` in one pass: ``thr`` (E, K, 3) (inf where not ``mon``, 0 for the
    fault-free mode); with ``has_y`` the largest ``|sep| / T`` of each epoch over the
    monitored faulted modes and axes (0/0 counts 0, x/0 inf), ``worst`` (E,), and its
    first mode, ``worst_mode`` (E,) (``-inf`` and 0 when there is none), as ``argmax``.
    ``k_fa`` (E, 3) with NaN replaced by 0.
    """
    e_n, k_n = mon.shape
    for e in range(e_n):
        best = -np.inf
        bi = 0
        for q in range(3):
            thr[e, 0, q] = 0.0
        for k in range(1, k_n):
            if not mon[e, k]:
                for q in range(3):
                    thr[e, k, q] = np.inf
                continue
            w = -np.inf
            for q in range(3):
                t = k_fa[e, q] * sigma_ss[e, k, q] + bias_ss[e, k, q]
                thr[e, k, q] = t
                if has_y:
                    d = abs(sep[e, k, q])
                    v = d / t
                    if v != v:
                        v = np.inf if d > 0.0 else 0.0
                    if v > w:
                        w = v
            if w > best:
                best = w
                bi = k
        worst[e] = best
        worst_mode[e] = bi


def warm_up() -> None:
    """Compile (or load from the on-disk cache) both kernels on a tiny problem."""
    e, j, n, kk = 1, 1, 5, 2
    pb = np.zeros((e, j, 3, n))
    mb = np.tile(np.eye(n), (e, j, 1, 1))
    z3 = np.zeros((e, j, 3))
    ones = np.ones((e, n))
    out3 = np.zeros((e, kk, 3))
    out1 = np.zeros((e, kk))
    idx = np.array([[0, -1], [1, -1]], dtype=np.int64)
    for r in (1, 2):
        downdate_modes(pb, mb, z3, np.ones((e, j)), z3, np.zeros((e, j, n, 3)), z3,
                       np.zeros((e, j, n)), np.zeros((e, 3, n)), ones, ones, ones, ones,
                       np.zeros(kk, np.int64), np.abs(idx) if r == 2 else idx, r,
                       np.arange(kk, dtype=np.int64), 1e-10, True, True, True, True,
                       out3, out3.copy(), out3.copy(), out3.copy(), out1, out1.copy(),
                       out3.copy())
    r3 = np.zeros((3 * e, kk))
    pl_equations(out3, out3, out3 + 1.0, np.ones((e, kk)), np.ones(kk), np.ones(3 * e, bool),
                 np.zeros(3 * e, np.int64), np.ones((1, kk)), np.ones((1, kk)), r3, r3.copy(),
                 r3.copy(), r3.copy(), np.zeros(3 * e), np.zeros(3 * e))
    nested_bases(np.zeros((e, n, 4)), np.zeros((e, j, 4, n)), np.zeros((e, 3, n)), ones, ones,
                 ones, True, mb.copy(), z3.copy(), z3.copy(), np.zeros((e, j, n, 3)),
                 z3.copy(), np.zeros((e, j, n)))
    solve_subsets(np.ones((e, n, 4)), ones, np.tile(np.eye(4), (e, 1, 1)),
                  np.zeros((kk, n), bool), np.zeros((kk, 4), bool), 1e-10,
                  np.zeros((e, kk, 3, n)), np.zeros((e, kk)))
    thresholds_and_test(out3, out3, np.ones((e, kk), bool), np.ones((e, 3)), out3, True,
                        out3.copy(), np.zeros(e, np.int64), np.zeros(e))
