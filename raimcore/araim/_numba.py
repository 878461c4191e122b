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

import ctypes
import functools
import math

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

__all__ = ["downdate_modes", "nested_bases", "solve_subsets", "pl_equations",
           "thresholds_and_test", "bisect_rows", "scipy_ndtr", "warm_up"]

#: Normalised offsets above which a PL term is "small" in :func:`bisect_rows`:
#: ``Q(x) <= Q(X_SMALL)``, about 6e-16, so its share of the sum is bounded, not computed.
X_SMALL = 8.0
#: ``Q(X_SMALL)`` rounded up (scipy: ``ndtr(-8) = 6.22e-16``).
Q_SMALL = 6.23e-16
_U = 2.0 ** -53  # unit roundoff of a double



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
    a = np.zeros((3, 2))
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
                # The three axes in one pass over the satellites: six independent sums
                # (each in the satellites' order, as one axis at a time would take it).
                b1 = idx[j, 1] if r == 2 else b0
                a00, a10, a20 = a[0, 0], a[1, 0], a[2, 0]
                a01, a11, a21 = a[0, 1], a[1, 1], a[2, 1]
                sb0 = sb1 = sb2 = 0.0
                ss0 = ss1 = ss2 = 0.0
                for i in range(n):
                    u = mb[e, base, b0, i]
                    d0, d1, d2_ = a00 * u, a10 * u, a20 * u
                    if r == 2:
                        v = mb[e, base, b1, i]
                        d0 += a01 * v
                        d1 += a11 * v
                        d2_ += a21 * v
                    s0_ = pb[e, base, 0, i] - d0
                    s1_ = pb[e, base, 1, i] - d1
                    s2_ = pb[e, base, 2, i] - d2_
                    if any_bnom:
                        w = bnom[e, i]
                        sb0 += abs(s0_) * w
                        sb1 += abs(s1_) * w
                        sb2 += abs(s2_) * w
                    if any_bcont:
                        w = bcont[e, i]
                        ss0 += abs(s0_ - p0[e, 0, i]) * w
                        ss1 += abs(s1_ - p0[e, 1, i]) * w
                        ss2 += abs(s2_ - p0[e, 2, i]) * w
                bias[e, k, 0], bias[e, k, 1], bias[e, k, 2] = sb0, sb1, sb2
                bias_ss[e, k, 0], bias_ss[e, k, 1], bias_ss[e, k, 2] = ss0, ss1, ss2
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


@functools.lru_cache(maxsize=1)
def scipy_ndtr():
    """The address of scipy's own ``ndtr`` (the C function behind ``scipy.special.ndtr``,
    exported by ``scipy.special.cython_special`` as ``double f(double, int)``) for
    :func:`_ndtr_at`, or None where this scipy does not export it with that signature or
    it does not return what ``scipy.special.ndtr`` returns (the caller then stays in
    numpy). An address passed at run time, not a ctypes object (which numba would bake
    into the cached machine code, wrong in the next process)."""
    try:
        import scipy.special
        import scipy.special.cython_special as cs
        from numba.extending import get_cython_function_address

        get_name = ctypes.pythonapi.PyCapsule_GetName
        get_name.restype, get_name.argtypes = ctypes.c_char_p, [ctypes.py_object]
        want = b"double (double, int __pyx_skip_dispatch)"
        names = [k for k, cap in cs.__pyx_capi__.items()
                 if (k == "ndtr" or (k.startswith("__pyx_fuse_") and k.endswith("ndtr")
                                     and k[11:-4].isdigit())) and get_name(cap) == want]
        if len(names) != 1:
            return None
        addr = get_cython_function_address("scipy.special.cython_special", names[0])
        fn = ctypes.CFUNCTYPE(ctypes.c_double, ctypes.c_double, ctypes.c_int)(addr)
        probe = np.array([-40.0, -8.5, -3.0, -0.5, 0.0, 0.7, 9.0])
        if not np.array_equal([fn(float(v), 1) for v in probe], scipy.special.ndtr(probe)):
            return None
        return int(addr)
    except Exception:  # noqa: BLE001 - any failure: the numpy search runs instead
        return None


@intrinsic
def _ndtr_at(typingctx, addr, x):
    """``f(x, 1)`` for the C function ``double f(double, int)`` at the address ``addr``
    (an integer known at run time only, so the compiled caller can be cached)."""
    sig = types.float64(types.intp, types.float64)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType(), ir.IntType(32)])
        fptr = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(fptr, [args[1], ir.Constant(ir.IntType(32), 1)])

    return sig, codegen


@njit(cache=True, fastmath=False, error_model="numpy")
def _pairwise_leaf(a, lo, n):
    """numpy's pairwise summation of ``a[lo:lo + n]``, ``n <= 128``: one pass with eight
    partial sums (sequential below eight terms)."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    stop = n - n % 8
    while i < stop:
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True, fastmath=False, error_model="numpy")
def _pairwise_sum(a, lo, n):
    """``a[lo:lo + n].sum()`` in numpy's own order, so the result is the bit pattern
    ``np.sum(..., axis=1)`` gives for a C-contiguous row: runs above 128 split in two
    halves (the first a multiple of 8) summed separately and added, below that
    :func:`_pairwise_leaf`. numpy's recursion walked with an explicit stack (a cached
    recursive numba function crashes when loaded in the next process)."""
    if n <= 128:
        return _pairwise_leaf(a, lo, n)
    f_lo = np.empty(64, np.int64)
    f_n = np.empty(64, np.int64)
    f_left = np.empty(64)
    f_stage = np.zeros(64, np.int64)  # 0: new, 1: left half pending, 2: right pending
    top = 0
    f_lo[0], f_n[0] = lo, n
    while True:
        cl, cn = f_lo[top], f_n[top]
        if cn > 128:  # first visit of a split: its left half next
            n2 = cn // 2
            n2 -= n2 % 8
            f_stage[top] = 1
            top += 1
            f_lo[top], f_n[top], f_stage[top] = cl, n2, 0
            continue
        ret = _pairwise_leaf(a, cl, cn)
        top -= 1
        while top >= 0:  # hand the value up
            if f_stage[top] == 1:  # its left half: keep it, go to the right half
                f_left[top] = ret
                f_stage[top] = 2
                n2 = f_n[top] // 2
                n2 -= n2 % 8
                f_lo[top + 1], f_n[top + 1] = f_lo[top] + n2, f_n[top] - n2
                f_stage[top + 1] = 0
                top += 1
                break
            ret = f_left[top] + ret
            top -= 1
        if top < 0:
            return ret


@njit(cache=True, fastmath=False, error_model="numpy")
def _capped_qm(x, cap, capped, ndtr):
    """``min(Qm(x), cap)`` (the cap only if ``capped``) as ``pl_bisect`` computes it:
    ``Qm = 1`` below 0, scipy's ``ndtr(-x)`` otherwise, NaN kept as ``np.minimum``
    keeps it."""
    qm = 1.0 if x < 0.0 else _ndtr_at(ndtr, -x)
    if capped and (cap < qm or cap != cap):
        qm = cap
    return qm


@njit(cache=True, fastmath=False, error_model="numpy")
def bisect_rows(c, sig, p, a, tgt, low, up, rows, tol, steps, capped, ndtr):
    """``kernel.pl_bisect``'s half-interval search on the rows ``rows``, ``low`` and
    ``up`` (R,) moved in place; ``c``, ``sig``, ``p``, ``a`` (R, J), ``tgt`` (R,) as in
    ``kernel.PlBracket``; ``ndtr`` is the address :func:`scipy_ndtr` returns.

    Every step takes the decision numpy takes, ``sum_j p_j min(Qm(x_j), a_j) > tgt``
    (its products, its ``ndtr``, its pairwise sum), so the output is bit for bit
    ``pl_bisect``'s. Most terms sit far in the tail (``x_j > X_SMALL``: a share below
    ``6e-16`` each); a step first sums the others and bounds the tail by
    ``Q_SMALL sum p_j``: when that sum clears the budget by more than the tail bound plus
    the rounding of either sum (``4 J u`` relative), the full sum lies on the same side
    and is not formed; otherwise (rare: a root within ~1e-12 of the midpoint, or NaN) the
    step forms numpy's sum term by term.
    """
    k_n = c.shape[1]
    terms = np.empty(k_n)
    rel = 4.0 * k_n * _U
    for r in rows:
        lo = low[r]
        hi = up[r]
        tg = tgt[r]
        for _ in range(steps):
            if not hi - lo > tol:
                break
            mid = 0.5 * (lo + hi)
            major = 0.0
            p_small = 0.0
            for j in range(k_n):
                x = (mid - c[r, j]) / sig[r, j]
                if x > X_SMALL:
                    p_small += p[r, j]
                    continue
                major += p[r, j] * _capped_qm(x, a[r, j], capped, ndtr)
            err = rel * major + 1e-300
            if major - err > tg:
                high = True
            elif major + err + 2.0 * Q_SMALL * p_small < tg:
                high = False
            else:  # numpy's sum, term by term
                for j in range(k_n):
                    x = (mid - c[r, j]) / sig[r, j]
                    terms[j] = p[r, j] * _capped_qm(x, a[r, j], capped, ndtr)
                high = _pairwise_sum(terms, 0, k_n) > tg
            if high:
                lo = mid
            else:
                hi = mid
        low[r] = lo
        up[r] = hi


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
    addr = scipy_ndtr()
    if addr is not None:
        for capped in (False, True):
            bisect_rows(r3, r3 + 1.0, r3 + 1.0, r3 + 1.0, np.ones(3 * e), np.zeros(3 * e),
                        np.ones(3 * e), np.arange(3 * e, dtype=np.int64), 0.5, 2, capped, addr)
