"""Subset solutions, thresholds, protection levels and EMT (ARAIM.md sections 5-8).

Batched kernels over the epochs of one visibility pattern: every array has a leading
epoch axis ``E``, the satellites in view ``n`` (compacted, same order in every epoch), the
states ``m = 3 + c`` (E, N, U and one clock per constellation in view). The fault modes
(``removed``, ``(K, n)`` bool, row 0 fault-free) are the same for every epoch. Inputs are
trusted (validated by :func:`raimcore.araim.mhss`).

Subset solutions. With ``S0`` the all-in-view weighted least-squares matrix and
``M = I - G S0`` (residuals ``r = M y``), removing the satellites ``b`` gives exactly
(leave-out formula of weighted least squares)::

    S^(k) = S0 - S0[:, b] (M_bb)^-1 M[b, :],     det(N_k) / det(N_0) = det(M_bb)

so the one- and two-satellite modes (nearly all of them) cost a 1x1 or 2x2 inverse, and
their statistics need no ``(3, n)`` matrix per mode: ``sigma_q^(k)2 = sigma_q^(0)2 +
a_q M_bb C_int,b a_q^T`` (the cross term vanishes because ``M C_int`` is symmetric),
``sigma_ss,q^(k)2 = a_q (M diag(C_acc) M^T)_bb a_q^T`` with ``a = S0[:3, b] M_bb^-1``, and
the separations are ``-a r_b``. A mode removing a whole constellation plus one or two
other satellites is the same down-date applied to that constellation's own subset solution
(solved once per constellation, :func:`_nested`). The other modes (three or more single
satellites, several constellations, a constellation alone) are solved from their normal
equations. ``tests/test_araim.py`` checks every ``S^(k)`` against ``numpy.linalg.pinv`` of
the weighted kept rows.

Protection levels are searched by MAAST's half-interval search from MAAST's bracket
(:func:`pl_bracket`, :func:`pl_bisect`); the bracket alone bounds the result, which lets
:func:`raimcore.araim.mhss` skip the searches of exclusion candidates that cannot give the
largest PL. ``raimcore.araim._kernel_reference`` keeps this module as first written (the
reference path of the agreement tests); both give the same decisions and the same numbers
to rounding.

Compiled kernels. Where numba imports and ``RAIM_STUDIO_NUMBA`` is not ``0`` (read at each
call, :func:`numba_kernels`), these run compiled (:mod:`raimcore.araim._numba`, the same
formulas): the subset solutions from normal equations (:func:`_solve_subsets`, Cholesky
instead of LU for the determinant ratio and the inverse), the bases of :func:`_nested`,
the one- and two-satellite down-dates of the all-in-view and of those bases
(:func:`_compiled_downdates`), the thresholds with the separation test, and the PL
equations with their bracket (:func:`_compiled_bracket`), and the half-interval search
(:func:`pl_bisect`: scipy's own ``ndtr`` called from the compiled loop, numpy's summation
order, so the same bits; the terms far in the tail, about two thirds on a four-system
sky, are bounded instead of evaluated wherever the bound decides the step).
Everything else, and everything without numba, is the numpy code below;
``tests/test_araim.py`` checks that both paths agree (decisions identical, numbers to
rounding).
"""

from __future__ import annotations

import functools
import importlib.util
import os
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr, ndtri

__all__ = ["COND_MAX", "RATIO_MIN", "allinview", "subset_stats", "solve_pl", "pl_bracket",
           "pl_bisect", "PlBracket", "evaluate"]

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


#: Environment variable that keeps numba out when set to ``0`` (as for the particle bank,
#: :data:`raimcore.algorithms.pf.NUMBA_ENV`); read at each call.
NUMBA_ENV = "RAIM_STUDIO_NUMBA"


@functools.lru_cache(maxsize=1)
def _numba_module():
    """:mod:`raimcore.araim._numba`, or None where numba does not import."""
    try:
        from . import _numba
    except ImportError:
        return None
    return _numba


def numba_kernels():
    """The compiled kernels (:mod:`raimcore.araim._numba`) if numba is installed and
    ``RAIM_STUDIO_NUMBA`` is not ``0``, else None (the numpy path runs). Numba is looked up
    and imported only here, at the first evaluation: ``import raimcore`` stays light."""
    if os.environ.get(NUMBA_ENV, "1").strip() == "0":
        return None
    if importlib.util.find_spec("numba") is None:
        return None
    return _numba_module()


def _wsum(a, w):
    """``sum_n a[e, k, q, n] w[e, n]`` for ``a`` (E, K, 3, n), ``w`` (E, n)."""
    return np.einsum("ekqn,en->ekq", a, w)


#: Elements of one block of the ``|S^(k)|`` temporaries of :func:`_abs_wsum` (about 0.5 MB:
#: they stay in cache; a speed setting, not a result).
_BLOCK_ELEMENTS = 65536


def _abs_wsum(base, a, mrow, w):
    """``sum_n w[e, n] |base[e, q, n] - a[e, k, q] mrow[e, k, n]|`` (E, K, 3), for the bias
    of one-satellite down-dates (``base`` = ``S0[:3]`` (E, 3, n)), built in blocks of
    epochs so that the (block, K, 3, n) temporary stays in cache."""
    e, k, _ = a.shape
    n = mrow.shape[-1]
    out = np.empty((e, k, 3))
    step = max(1, _BLOCK_ELEMENTS // max(1, k * 3 * n))
    for i in range(0, e, step):
        sl = slice(i, i + step)
        t = a[sl, :, :, None] * mrow[sl, :, None, :]
        np.subtract(base[sl, None], t, out=t)
        out[sl] = np.einsum("ekqn,en->ekq", np.abs(t, out=t), w[sl])
    return out


def _small_matmul(x, inv):
    """``x @ inv`` for ``x`` (..., 3, r), ``inv`` (..., r, r), r in (1, 2), written out
    (numpy's matmul loops slowly over millions of tiny matrices)."""
    if x.shape[-1] == 1:
        return x * inv
    out = np.empty(x.shape)
    x0, x1 = x[..., 0], x[..., 1]
    out[..., 0] = x0 * inv[..., None, 0, 0] + x1 * inv[..., None, 1, 0]
    out[..., 1] = x0 * inv[..., None, 0, 1] + x1 * inv[..., None, 1, 1]
    return out


def _quad(amat, q):
    """``a_q Q a_q^T`` for ``amat`` (..., 3, r) and ``q`` (..., r, r), r in (1, 2),
    written out (the einsum ``ekqa,ekab,ekqb->ekq``)."""
    if amat.shape[-1] == 1:
        return amat[..., 0] ** 2 * q[..., None, 0, 0]
    a0, a1 = amat[..., 0], amat[..., 1]
    return (a0 * a0 * q[..., None, 0, 0] + a0 * a1 * (q[..., None, 0, 1] + q[..., None, 1, 0])
            + a1 * a1 * q[..., None, 1, 1])


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


#: Normal matrices with ``tr(N) tr(N^-1)`` below ``COND_MAX / _COND_MARGIN`` are regular
#: without an eigen-decomposition (``cond(N) <= tr(N) tr(N^-1)`` for a positive definite N).
_COND_MARGIN = 16.0


def _regular(n0):
    """``cond(N) < COND_MAX`` and ``N`` positive definite, per matrix (section 5), and the
    inverses if they could all be formed (else None). Matrices that the trace bound
    ``cond(N) <= tr(N) tr(N^-1)`` clears with a wide margin skip ``eigvalsh``; the rest
    get the eigenvalue test as before, so the decisions are the same."""
    n_inv = None
    try:
        with np.errstate(all="ignore"):
            n_inv = np.linalg.inv(n0)
    except np.linalg.LinAlgError:
        n_inv = None
    sure = np.zeros(n0.shape[0], bool)
    if n_inv is not None:
        tr = np.trace(n0, axis1=-2, axis2=-1)
        tri = np.trace(n_inv, axis1=-2, axis2=-1)
        with np.errstate(invalid="ignore", over="ignore"):
            sure = (np.isfinite(tri) & (tri > 0.0) & (tr > 0.0)
                    & (tr * tri < COND_MAX / _COND_MARGIN))
    regular = sure.copy()
    rest = np.flatnonzero(~sure)
    if rest.size:
        lam = np.linalg.eigvalsh(n0[rest])
        with np.errstate(divide="ignore", invalid="ignore"):
            cond = lam[..., -1] / lam[..., 0]
        regular[rest] = (lam[..., 0] > 0.0) & (cond < COND_MAX)
    return regular, n_inv


def allinview(g, cint, cacc, bnom, y=None) -> AllInView:
    """Weighted least squares with ``W = C_int^-1`` over every satellite (section 5)."""
    e, n, m = g.shape
    gw = g / cint[..., None]
    n0 = np.swapaxes(gw, -1, -2) @ g
    enough = n >= max(m, 4)
    regular, n_inv = _regular(n0)
    ok = np.asarray(enough & regular)
    reason = np.where(ok, 0, np.where(enough, 2, 1))
    n0 = np.where(ok[:, None, None], n0, np.eye(m))
    if n_inv is None:
        n_inv = np.linalg.inv(n0)
    else:  # the inverse of each regular matrix is the same whatever the batch
        n_inv = np.where(ok[:, None, None], n_inv, np.eye(m))
    s0 = n_inv @ np.swapaxes(gw, -1, -2)
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
    outs = (sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep)
    nb = numba_kernels()
    if nb is not None:
        outs = (sigma, bias, sigma_ss, bias_ss, ratio,
                sacc if need_acc else np.empty((e, k_all)),  # the kernel writes every one
                sep if sep is not None else np.empty(shape))
        _compiled_downdates(nb, av, g, cint, cacc, bnom, bcont, cons, removed, size, emptied,
                            present, need_acc, y, any_bnom, any_bcont, outs)
        set_void_modes(av, void_modes(size, present), sigma, bias, sigma_ss, bias_ss, sacc,
                       sep)
        return _finish_stats(av, count_ok, ratio, sigma, bias, sigma_ss, bias_ss, sacc,
                             sep, need_acc)
    x_acc = None
    # M diag(C_acc) M^T, once per epoch: its 2 x 2 blocks give sigma_ss of two-satellite
    # modes (its diagonal, for one-satellite modes, from one matrix-vector product).
    down = (size >= 1) & (size <= 2) & ~emptied
    q_acc_full = ((av.m * cacc[:, None, :]) @ np.swapaxes(av.m, -1, -2)
                  if np.any(down & (size == 2)) else None)
    q_acc_diag = (av.m * av.m) @ cacc[..., None] if np.any(down & (size == 1)) else None
    if need_acc:  # M diag(C_acc) S0_3^T, for the accuracy sigma of down-dated subsets
        x_acc = np.einsum("eij,ej->ei", av.m, cacc * av.p0[:, 2, :])

    for r in (1, 2):
        ks = np.flatnonzero((size == r) & ~emptied)
        if ks.size == 0:
            continue
        idx = np.nonzero(removed[ks])[1].reshape(ks.size, r)  # (Kr, r), ascending
        st = _downdate(av, idx, cint, q_acc_full if r == 2 else q_acc_diag, bnom, bcont,
                       any_bnom, any_bcont, x_acc, y)
        _store(outs, ks, st)

    # A whole constellation plus one or two satellites: down-dates of the constellation's
    # subset solution (:func:`_nested`); the rest from their normal equations.
    ks, member, j_of, extra, r_extra, nest = _nest_plan(cons, m - 3, removed, size,
                                                        emptied, present)
    for r in (1, 2):
        kn = ks[nest & (r_extra == r)]
        if kn.size == 0:
            continue
        jn = j_of[nest & (r_extra == r)]
        bases, jb = np.unique(jn, return_inverse=True)
        base_present = np.ones((len(bases), m - 3), bool)
        base_present[np.arange(len(bases)), bases] = False
        idx = np.nonzero(extra[nest & (r_extra == r)])[1].reshape(kn.size, r)
        st = _nested(av, g, cint, cacc, bnom, bcont, member[bases], base_present,
                     jb.reshape(-1), idx, need_acc, y, any_bnom, any_bcont)
        _store(outs, kn, st)
    ks = ks[~nest]
    if ks.size:
        st = _direct(av, g, cint, cacc, bnom, bcont, removed[ks], present[ks], need_acc, y,
                     any_bnom, any_bcont)
        _store(outs, ks, st)

    set_void_modes(av, void_modes(size, present), sigma, bias, sigma_ss, bias_ss, sacc, sep)
    return _finish_stats(av, count_ok, ratio, sigma, bias, sigma_ss, bias_ss, sacc, sep,
                         need_acc)


def void_modes(size, present):
    """(K,) bool: modes whose every removed satellite is the only one of its constellation
    (``size`` and ``present`` of :func:`mode_classes`). Such a satellite fixes its own
    clock and nothing else, so ``S^(k) = S^(0)`` on the position rows exactly: the
    section 5 formulas give ``sigma_ss = b_ss = 0``, a zero separation and the
    all-in-view's ``sigma`` and ``b``. Computed, they come out as rounding noise
    (~1e-14 m), and the test ``|sep| / T`` would be noise over noise, an alarm or an
    exclusion at random; :func:`set_void_modes` writes the exact values."""
    return (size >= 1) & (size == np.sum(~present, axis=1))


def set_void_modes(av, void, sigma, bias, sigma_ss, bias_ss, sacc, sep) -> None:
    """Write the exact statistics of the ``void`` modes (:func:`void_modes`) in place
    (``sacc``, ``sep``: where not None)."""
    if not np.any(void):
        return
    sigma[:, void] = av.sigma[:, None, :]
    bias[:, void] = av.bias[:, None, :]
    sigma_ss[:, void] = 0.0
    bias_ss[:, void] = 0.0
    if sacc is not None:
        sacc[:, void] = av.sigma_acc[:, None, 2]
    if sep is not None:
        sep[:, void] = 0.0


def _nest_plan(cons, c: int, removed, size, emptied, present):
    """The modes that are not one- or two-satellite down-dates of the all-in-view
    (``ks``), and which of them remove one whole constellation plus one or two satellites
    (``nest``): those are down-dates of that constellation's subset solution.

    Returns ``ks`` (Kd,), ``member`` (c, n) satellites of each constellation, ``j_of``
    (Kd,) the emptied constellation, ``extra`` (Kd, n) the satellites removed besides it,
    ``r_extra`` (Kd,) their count, ``nest`` (Kd,) bool."""
    ks = np.flatnonzero((size >= 1) & ~(((size == 1) | (size == 2)) & ~emptied))
    member = cons[None, :] == np.arange(c)[:, None]
    gone = ~present[ks]  # (Kd, c) constellations emptied
    j_of = np.argmax(gone, axis=1)
    extra = removed[ks] & ~member[j_of]
    r_extra = extra.sum(axis=1)
    nest = (gone.sum(axis=1) == 1) & (r_extra >= 1) & (r_extra <= 2)
    return ks, member, j_of, extra, r_extra, nest


def _store(outs, ks, st) -> None:
    """Write the statistics ``st`` of modes ``ks`` (sigma, bias, sigma_ss, bias_ss, ratio,
    sacc, sep; None where not computed) into the arrays ``outs`` of the same order (None
    where not kept)."""
    for out, value in zip(outs, st, strict=True):
        if out is not None and value is not None:
            out[:, ks] = value


def _finish_stats(av, count_ok, ratio, sigma, bias, sigma_ss, bias_ss, sacc, sep, need_acc):
    """Monitorability (section 5) and infinite statistics of unmonitorable modes."""
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


def _compiled_downdates(nb, av, g, cint, cacc, bnom, bcont, cons, removed, size, emptied,
                        present, need_acc, y, any_bnom, any_bcont, outs):
    """:func:`subset_stats` with the one- and two-satellite down-dates of the all-in-view
    and of each constellation's subset solution (:func:`_nested`) in one compiled pass
    (:func:`raimcore.araim._numba.downdate_modes`, the same formulas); the other modes
    from their normal equations (:func:`_direct`) as on the numpy path. Writes ``outs``
    (sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep) in place."""
    e, n, m = g.shape
    sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep = outs
    has_y = y is not None
    flags = (RATIO_MIN, any_bnom, any_bcont, need_acc, has_y)
    f64 = np.ascontiguousarray

    def run(bases, jb, idx, r, ks):
        nb.downdate_modes(*bases, f64(av.p0), f64(cint), f64(cacc), f64(bnom), f64(bcont),
                          f64(jb, dtype=np.int64), f64(idx, dtype=np.int64), r,
                          f64(ks, dtype=np.int64), *flags, *outs)

    plain = None
    for r in (1, 2):
        ks = np.flatnonzero((size == r) & ~emptied)
        if ks.size == 0:
            continue
        if plain is None:
            z3 = np.zeros((e, 1, 3))
            rb = av.resid[:, None] if has_y else np.zeros((e, 1, n))
            plain = tuple(f64(a) for a in (
                av.p0[:, None], av.m[:, None], (av.sigma ** 2)[:, None], np.ones((e, 1)),
                z3, np.zeros((e, 1, n, 3)), z3, rb))
        idx = np.full((ks.size, 2), -1)
        idx[:, :r] = np.nonzero(removed[ks])[1].reshape(ks.size, r)
        run(plain, np.zeros(ks.size), idx, r, ks)

    ks, member, j_of, extra, r_extra, nest = _nest_plan(cons, m - 3, removed, size,
                                                        emptied, present)
    if ks.size == 0:
        return
    if np.any(nest):
        bases, jb = np.unique(j_of[nest], return_inverse=True)
        base_present = np.ones((len(bases), m - 3), bool)
        base_present[np.arange(len(bases)), bases] = False
        sb, ratio_b = _solve_subsets(av, g, cint, member[bases], base_present, m)
        j_n = len(bases)
        mb_full = np.empty((e, j_n, n, n))
        sigb2, d2, dy = (np.empty((e, j_n, 3)) for _ in range(3))
        xb, rb = np.empty((e, j_n, n, 3)), np.empty((e, j_n, n))
        nb.nested_bases(f64(g), f64(sb), f64(av.p0), f64(cint), f64(cacc),
                        f64(y) if has_y else np.empty((1, 1)), has_y, mb_full, sigb2, d2,
                        xb, dy, rb)
        base = (f64(sb[:, :, :3]), mb_full, sigb2, f64(ratio_b), d2, xb, dy, rb)
        jb = jb.reshape(-1)
        for r in (1, 2):
            sel = nest & (r_extra == r)
            if not np.any(sel):
                continue
            idx = np.full((int(sel.sum()), 2), -1)
            idx[:, :r] = np.nonzero(extra[sel])[1].reshape(-1, r)
            run(base, jb[sel[nest]], idx, r, ks[sel])
    ks = ks[~nest]
    if ks.size:
        st = _direct(av, g, cint, cacc, bnom, bcont, removed[ks], present[ks], need_acc, y,
                     any_bnom, any_bcont)
        _store(outs, ks, st)


def _downdate(av, idx, cint, q_acc, bnom, bcont, any_bnom, any_bcont, x_acc, y):
    """Modes removing the satellites ``idx`` (Kr, r), r in (1, 2), no clock lost;
    ``q_acc`` is ``M diag(C_acc) M^T``: (E, n, n) for r = 2, its diagonal (E, n, 1) for
    r = 1. Written out per column of ``a = S0[:3, b] M_bb^-1`` (each (E, 3, Kr)): numpy
    handles millions of 2 x 2 products faster as whole-array arithmetic."""
    kr, r = idx.shape
    mres, p0 = av.m, av.p0
    ii = [idx[:, c] for c in range(r)]
    mbb = [[mres[:, ia, ib] for ib in ii] for ia in ii]  # M_bb entries, each (E, Kr)
    if r == 1:
        det = mbb[0][0]
        good = det > RATIO_MIN
        inv = [[1.0 / np.where(good, det, 1.0)]]
        qa = [[q_acc[:, ii[0], 0]]]
    else:
        det = mbb[0][0] * mbb[1][1] - mbb[0][1] * mbb[1][0]
        good = det > RATIO_MIN
        sc = 1.0 / np.where(good, det, 1.0)
        inv = [[mbb[1][1] * sc, -mbb[0][1] * sc], [-mbb[1][0] * sc, mbb[0][0] * sc]]
        qa = [[q_acc[:, ia, ib] for ib in ii] for ia in ii]
    x = [p0[:, :, ia] for ia in ii]  # S0[:3, b] columns, (E, 3, Kr)
    if r == 1:
        a = [x[0] * inv[0][0][:, None, :]]
    else:
        a = [x[0] * inv[0][c][:, None, :] + x[1] * inv[1][c][:, None, :] for c in range(2)]
    # Q_int = M C_int (symmetric): (Q_int)_bb = M_bb * C_int,b (columns).
    qi = [[mbb[ia][ib] * cint[:, ii[ib]] for ib in range(r)] for ia in range(r)]

    def quad(cols, q, axis):  # sum_ab a_a q_ab a_b, as _quad
        if r == 1:
            return cols[0] * cols[0] * q[0][0][axis]
        return (cols[0] * cols[0] * q[0][0][axis] + cols[0] * cols[1]
                * (q[0][1][axis] + q[1][0][axis]) + cols[1] * cols[1] * q[1][1][axis])

    full = (slice(None), None, slice(None))  # (E, Kr) -> (E, 1, Kr)
    var_add = quad(a, qi, full)
    sigma = np.sqrt(av.sigma[:, :, None] ** 2 + np.maximum(var_add, 0.0))
    sigma_ss = np.sqrt(np.maximum(quad(a, qa, full), 0.0))
    sigma, sigma_ss = np.swapaxes(sigma, 1, 2), np.swapaxes(sigma_ss, 1, 2)  # (E, Kr, 3)
    if r == 1:
        a0 = np.swapaxes(a[0], 1, 2)  # (E, Kr, 3)
        mrow = mres[:, ii[0], :]  # (E, Kr, n)
        if any_bcont:
            bias_ss = np.abs(a0) * (np.abs(mrow) @ bcont[:, :, None])
        else:
            bias_ss = np.zeros(sigma.shape)
        if any_bnom:  # |S^(k)| = |S0 - a m_row|, the largest temporary: in blocks
            bias = _abs_wsum(p0, a0, mrow, bnom)
        else:
            bias = np.zeros(sigma.shape)
    else:
        if any_bnom or any_bcont:
            amat = np.swapaxes(np.stack(a, axis=-1), 1, 2)  # (E, Kr, 3, 2)
            ds = amat @ mres[:, idx, :]  # (E, Kr, 3, n) = S0 - S^(k)
        bias_ss = _wsum(np.abs(ds), bcont) if any_bcont else np.zeros(sigma.shape)
        bias = _wsum(np.abs(p0[:, None] - ds), bnom) if any_bnom else np.zeros(sigma.shape)
    sacc = None
    if x_acc is not None:
        a3 = [c[:, 2, :] for c in a]  # (E, Kr)
        cross = sum(c * x_acc[:, ia] for c, ia in zip(a3, ii, strict=True))
        var = av.sigma_acc[:, None, 2] ** 2 - 2.0 * cross + quad(a3, qa, ...)
        sacc = np.sqrt(np.maximum(var, 0.0))
    sep = None
    if y is not None:
        res = av.resid
        sep = -sum(c * res[:, None, ia] for c, ia in zip(a, ii, strict=True))
        sep = np.swapaxes(sep, 1, 2)
    ratio = np.where(good, det, 0.0)
    return sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep


def _solve_subsets(av, g, cint, removed, present, rows: int):
    """Subset solutions from their normal equations (clock columns of emptied
    constellations replaced by the all-in-view diagonal, so they decouple): the first
    ``rows`` rows of ``S^(k)`` (E, Kd, rows, n) and ``det(N_k)/det(N_0)`` (E, Kd), 0 where
    not above :data:`RATIO_MIN`."""
    e, n, m = g.shape
    nb = numba_kernels()
    if nb is not None:
        absent = np.concatenate([np.ones((len(removed), 3), bool), present], axis=1) == 0
        s_k, ratio = np.empty((e, len(removed), rows, n)), np.empty((e, len(removed)))
        f64 = np.ascontiguousarray
        nb.solve_subsets(f64(g), f64(cint), f64(av.n0), f64(removed), f64(absent),
                         RATIO_MIN, s_k, ratio)
        return s_k, ratio
    keep = (~removed).astype(float)  # (Kd, n)
    gw = g / cint[..., None]  # (E, n, m)
    gtw_k = np.swapaxes(gw, -1, -2)[:, None] * keep[None, :, None, :]  # (E, Kd, m, n)
    nk = gtw_k @ g[:, None]  # (E, Kd, m, m)
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
    return np.linalg.inv(nk)[..., :rows, :] @ gtw_k, np.where(good, ratio, 0.0)


def _direct(av, g, cint, cacc, bnom, bcont, removed, present, need_acc, y, any_bnom=True,
            any_bcont=True):
    """Modes solved from their normal equations (:func:`_solve_subsets`)."""
    s_k, ratio = _solve_subsets(av, g, cint, removed, present, 3)
    ds = s_k - av.p0[:, None]  # (E, Kd, 3, n)
    sigma = np.sqrt(_wsum(s_k * s_k, cint))
    bias = _wsum(np.abs(s_k), bnom) if any_bnom else np.zeros_like(sigma)
    sigma_ss = np.sqrt(_wsum(ds * ds, cacc))
    bias_ss = _wsum(np.abs(ds), bcont) if any_bcont else np.zeros_like(sigma)
    sacc = np.sqrt(np.einsum("ekn,en->ek", s_k[:, :, 2] ** 2, cacc)) if need_acc else None
    sep = np.einsum("ekqn,en->ekq", ds, y) if y is not None else None
    return sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep


def _nested(av, g, cint, cacc, bnom, bcont, base_removed, base_present, jb, idx, need_acc, y,
            any_bnom, any_bcont):
    """Modes removing a whole constellation plus ``r`` in (1, 2) other satellites that
    leave every other constellation a satellite: one- or two-satellite down-dates of the
    constellation's own subset solution (the base, solved once per constellation from its
    normal equations, :func:`_solve_subsets`).

    With the base ``Sb``, ``Mb = I - G Sb`` and the extra satellites ``b``, the leave-out
    formula of the module docstring gives ``S^(k) = Sb - a Mb[b, :]``, ``a = Sb[:3, b]
    (Mb_bb)^-1``, ``det(N_k)/det(N_0) = det(Nb)/det(N_0) det(Mb_bb)``;
    ``sigma_q^(k)2 = sigma_q^(b)2 + a_q Mb_bb C_int,b a_q^T``; with ``D = Sb[:3] - S0[:3]``,
    ``sigma_ss,q^(k)2 = |D_q|^2_Cacc - 2 a_q (Mb[b, :] C_acc D_q^T) + a_q (Mb C_acc
    Mb^T)_bb a_q^T``; the separations ``D y - a (Mb y)_b``.

    ``base_removed``, ``base_present`` (J, n), (J, c): the bases; ``jb`` (Kn,) each mode's
    base, ``idx`` (Kn, r) its extra satellites.
    """
    e, n, m = g.shape
    kn, r = idx.shape
    sb, ratio_b = _solve_subsets(av, g, cint, base_removed, base_present, m)  # (E, J, m, n)
    sb3 = sb[:, :, :3]  # (E, J, 3, n)
    mb_full = np.eye(n) - g[:, None] @ sb  # (E, J, n, n), once per base
    jk = jb[:, None]
    mrow = mb_full[:, jk, idx, :]  # rows b of each mode's base: (E, Kn, r, n)
    mbb = mb_full[:, jk[..., None], idx[:, :, None], idx[:, None, :]]  # (E, Kn, r, r)
    if r == 1:
        det = mbb[..., 0, 0]
        good = det > RATIO_MIN
        inv = (1.0 / np.where(good, det, 1.0))[..., None, None]
    else:
        a_, b_, c_, d_ = mbb[..., 0, 0], mbb[..., 0, 1], mbb[..., 1, 0], mbb[..., 1, 1]
        det = a_ * d_ - b_ * c_
        good = det > RATIO_MIN
        sc = 1.0 / np.where(good, det, 1.0)
        inv = np.stack([np.stack([d_ * sc, -b_ * sc], -1), np.stack([-c_ * sc, a_ * sc], -1)],
                       -2)
    sb_cols = np.swapaxes(np.swapaxes(sb3, 2, 3)[:, jk, idx, :], 2, 3)  # (E, Kn, 3, r)
    amat = _small_matmul(sb_cols, inv)  # (E, Kn, 3, r)
    sig_b2 = _wsum(sb3 ** 2, cint)  # (E, J, 3)
    q_int = mbb * cint[:, idx][:, :, None, :]
    sigma = np.sqrt(sig_b2[:, jb] + np.maximum(_quad(amat, q_int), 0.0))
    dmat = sb3 - av.p0[:, None]  # (E, J, 3, n)
    d2 = _wsum(dmat * dmat, cacc)[:, jb]  # (E, Kn, 3)
    xb = (mb_full * cacc[:, None, None, :]) @ np.swapaxes(dmat, -1, -2)  # (E, J, n, 3)
    x = xb[:, jk, idx, :]  # (E, Kn, r, 3)
    mc = mrow * cacc[:, None, None, :]  # (E, Kn, r, n)
    qa = mc @ np.swapaxes(mrow, -1, -2)  # (E, Kn, r, r)
    cross = np.sum(amat * np.swapaxes(x, -1, -2), axis=-1)  # (E, Kn, 3)
    sigma_ss = np.sqrt(np.maximum(d2 - 2.0 * cross + _quad(amat, qa), 0.0))
    p_b = sb3[:, jb] if (any_bnom or any_bcont or need_acc) else None  # (E, Kn, 3, n)
    s_k = None
    if any_bnom or any_bcont or need_acc:
        s_k = p_b - amat @ mrow  # (E, Kn, 3, n)
    bias = _wsum(np.abs(s_k), bnom) if any_bnom else np.zeros_like(sigma)
    bias_ss = (_wsum(np.abs(s_k - av.p0[:, None]), bcont) if any_bcont
               else np.zeros_like(sigma))
    sacc = np.sqrt(np.einsum("ekn,en->ek", s_k[:, :, 2] ** 2, cacc)) if need_acc else None
    sep = None
    if y is not None:
        dy = np.einsum("ejqn,en->ejq", dmat, y)[:, jb]
        my = (mrow @ y[:, None, :, None])[..., 0]  # (E, Kn, r)
        sep = dy - np.sum(amat * my[:, :, None, :], axis=-1)
    ratio = np.where(good, ratio_b[:, jb] * det, 0.0)
    return sigma, bias, sigma_ss, bias_ss, ratio, sacc, sep


@dataclass(frozen=True)
class PlBracket:
    """The protection-level equations of ``R`` rows, normalised, with MAAST's starting
    bracket (section 7); see :func:`pl_bracket`."""

    c: np.ndarray  # (R, J) offsets (0 for inactive terms)
    sig: np.ndarray  # (R, J) sigmas (1 for inactive terms)
    p: np.ndarray  # (R, J) priors (0: inactive)
    a: np.ndarray  # (R, J) caps (1 for inactive terms)
    tgt: np.ndarray  # (R,) budgets (1 where not ok)
    low: np.ndarray  # (R,) L_low, a lower bound of the root (0 where not ok)
    up: np.ndarray  # (R,) L_up, an upper bound of the output (0 where not ok)
    ok: np.ndarray  # (R,) bool: a finite PL (budget > 0 and some active term)


def pl_bracket(c, sig, p, a, target) -> PlBracket:
    """The starting bracket of :func:`solve_pl` (arguments as there). The output of the
    search always lies in ``[low, up]`` (the search only moves the ends inwards)."""
    active = p > 0.0
    c = np.where(active, c, 0.0)
    sig = np.where(active, sig, 1.0)
    p = np.where(active, p, 0.0)
    a = np.where(active, a, 1.0)
    ok = (target > 0.0) & np.any(active, axis=1)
    tgt = np.where(ok, target, 1.0)
    k_terms = np.maximum(active.sum(axis=1), 1)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        k_low, k_high = _bracket_multipliers(tgt, k_terms, p, a, active)
        low = np.max(np.where(active, c + k_low * sig, -np.inf), axis=1)
        up = np.max(np.where(active, c + k_high * sig, -np.inf), axis=1)
        low, up = np.where(ok, low, 0.0), np.where(ok, up, 0.0)
    return PlBracket(c, sig, p, a, tgt, low, up, ok)


def _bracket_multipliers(tgt, k_terms, p, a, active):
    """``Q^-1(min(1, tgt/(p a)))`` and ``max(0, Q^-1(min(1, tgt/(K' p))))`` of every term,
    (R, J) (inactive terms: anything, masked by the caller). Rows often share their
    budget, term count, priors and caps (one mode list, a few budgets): then ``Q^-1`` runs
    on the distinct rows only and is gathered (same numbers, far fewer ``ndtri`` calls)."""
    r, j = p.shape
    if r > 8:
        p_col = np.max(p, axis=0)
        a_col = np.max(np.where(active, a, -np.inf), axis=0)
        same = bool(np.all((p == p_col) | ~active)) and bool(np.all((a == a_col) | ~active))
        if same:
            t_u, t_inv = np.unique(tgt, return_inverse=True)
            code = t_inv.reshape(-1).astype(np.int64) * (j + 2) + k_terms
            uniq, inv = np.unique(code, return_inverse=True)
            if len(uniq) * 4 <= r:
                t_u, k_u = t_u[uniq // (j + 2)], (uniq % (j + 2)).astype(float)
                a_col = np.where(np.isfinite(a_col), a_col, 1.0)
                low_u = q_inv(np.minimum(1.0, t_u[:, None] / (p_col * a_col)))
                high_u = np.maximum(0.0, q_inv(np.minimum(1.0, t_u[:, None]
                                                          / (k_u[:, None] * p_col))))
                inv = inv.reshape(-1)
                return low_u[inv], high_u[inv]
    pa = p * a
    k_low = q_inv(np.minimum(1.0, np.where(active, tgt[:, None] / pa, 1.0)))
    k_high = np.maximum(0.0, q_inv(np.minimum(1.0, tgt[:, None] / (k_terms[:, None] * p))))
    return k_low, k_high


def _compiled_bracket(nb, thr, bias, sigma, pk, cap, target) -> PlBracket:
    """The bracket of :func:`evaluate`'s PL equations as :func:`pl_bracket` makes it, the
    (rows, modes) arrays filled in one compiled pass
    (:func:`raimcore.araim._numba.pl_equations`). Every row's priors are its epoch's
    ``pk`` and its caps ``cap`` where active, so the multipliers depend on the row only
    through its budget and term count (as in :func:`_bracket_multipliers`): ``Q^-1`` runs
    on the distinct (budget, count) pairs, the same numbers."""
    e, k = pk.shape
    k_terms = np.tile(np.maximum((pk > 0.0).sum(axis=1), 1), 3)
    ok = (target > 0.0) & np.tile(np.any(pk > 0.0, axis=1), 3)
    tgt = np.where(ok, target, 1.0)
    pairs = np.stack([tgt, k_terms.astype(float)], axis=1)
    uniq, u_of = np.unique(pairs, axis=0, return_inverse=True)
    p_col = np.where(pk.max(axis=0, initial=0.0) > 0.0, np.max(pk, axis=0, initial=0.0),
                     1.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        t_u, k_u = uniq[:, :1], uniq[:, 1:]
        k_low = q_inv(np.minimum(1.0, t_u / (p_col * cap)))
        k_high = np.maximum(0.0, q_inv(np.minimum(1.0, t_u / (k_u * p_col))))
    r = 3 * e
    c, sig, p, a = (np.empty((r, k)) for _ in range(4))
    low, up = np.empty(r), np.empty(r)
    f64 = np.ascontiguousarray
    nb.pl_equations(f64(thr), f64(bias), f64(sigma), f64(pk), f64(cap, dtype=float), ok,
                    u_of.reshape(-1).astype(np.int64), f64(k_low), f64(k_high), c, sig, p, a,
                    low, up)
    return PlBracket(c, sig, p, a, tgt, low, up, ok)


def pl_bisect(br: PlBracket, tol: float, max_iter: int = 0, rows=None):
    """MAAST's half-interval search from the bracket ``br`` on the rows ``rows`` (bool
    (R,), default all). Returns (R,): ``L_up`` of the searched rows, ``br.up`` of the
    others, ``inf`` where not ``br.ok``. A row's result does not depend on the others.
    With numba, compiled (:func:`raimcore.araim._numba.bisect_rows`: the same decisions
    with scipy's ``ndtr`` and numpy's summation order, terms far in the tail bounded
    instead of summed where that cannot change a decision): the same bits."""
    low, up = br.low.copy(), br.up.copy()
    sel = br.ok & (up - low > tol)
    if rows is not None:
        sel &= rows
    rows = np.flatnonzero(sel)
    steps = max_iter if max_iter > 0 else _MAX_STEPS
    # With every cap a_j >= 1 the min(Qm, a) is Qm itself (Qm <= 1).
    capped = not bool(np.all(br.a >= 1.0))
    nb = numba_kernels()
    ndtr_c = nb.scipy_ndtr() if nb is not None and rows.size else None
    if ndtr_c is not None:  # the same steps and decisions, compiled
        f64 = np.ascontiguousarray
        nb.bisect_rows(f64(br.c), f64(br.sig), f64(br.p), f64(br.a), f64(br.tgt), low, up,
                       rows.astype(np.int64), float(tol), int(steps), capped, ndtr_c)
        return np.where(br.ok, up, np.inf)
    # The rows still searching are gathered once and compacted only when some finish.
    lo, hi, tg = low[rows], up[rows], br.tgt[rows]
    cr, sr, pr = br.c[rows], br.sig[rows], br.p[rows]
    ar = br.a[rows] if capped else None
    for _ in range(steps):
        if rows.size == 0:
            break
        mid = 0.5 * (lo + hi)
        x = (mid[:, None] - cr) / sr
        qm = ndtr(-np.maximum(x, 0.0))
        qm[x < 0.0] = 1.0
        if capped:
            qm = np.minimum(qm, ar)
        lhs = np.sum(pr * qm, axis=1)
        high = lhs > tg
        lo = np.where(high, mid, lo)
        hi = np.where(high, hi, mid)
        live = hi - lo > tol
        if not live.all():
            done = ~live
            low[rows[done]], up[rows[done]] = lo[done], hi[done]
            rows, lo, hi, tg = rows[live], lo[live], hi[live], tg[live]
            cr, sr, pr = cr[live], sr[live], pr[live]
            ar = ar[live] if capped else None
    low[rows], up[rows] = lo, hi
    return np.where(br.ok, up, np.inf)


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
    return pl_bisect(pl_bracket(c, sig, p, a, target), tol, max_iter)


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
    #: with ``defer_pl``: the PL equations, rows (axis, epoch) (E, N, U), not yet searched
    #: (``hpl``, ``hpl1``, ``hpl2``, ``vpl`` are then NaN; ``ok`` False rows are infinite).
    pl: PlBracket | None = None


def evaluate(g, cint, cacc, bnom, bcont, cons, modes, prm: dict, *, rules: str,
             rho=1.0, drop: bool = True, p_nm=None, y=None, defer_pl: bool = False) -> Evaluation:
    """Sections 5-8 for the epochs of one pattern and its mode list.

    ``drop``: the all-in-view rule (unmonitorable modes leave the list and their ``p_exp``
    joins ``P_nm``); otherwise the exclusion-candidate rule of section 9 (they stay with
    ``sigma = inf``, consuming ``p_inst a`` of the budget, and one with ``p_inst >= P_EMT``
    makes the EMT infinite) with ``p_nm`` (E,), the all-in-view's final ``P_nm`` (what
    ``mhss_raim_baseline_v5.m`` returns to ``usr_vhpl_araim.m``).
    ``defer_pl``: return the protection-level equations and their brackets (``pl``)
    instead of solving them, so that the caller searches only the rows it needs.
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
    nb = numba_kernels()
    if nb is not None:  # thresholds and the separation test in one compiled pass
        thr = np.empty(st.sigma_ss.shape)
        worst_mode, worst = np.empty(e, np.int64), np.empty(e)
        f64 = np.ascontiguousarray
        nb.thresholds_and_test(f64(st.sigma_ss), f64(st.bias_ss), f64(mon),
                               f64(np.nan_to_num(k_fa)), f64(st.sep) if y is not None
                               else np.empty((1, 1, 3)), y is not None, thr, worst_mode, worst)
    else:
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
    tgt = np.concatenate([phmi_h - lost, phmi_h - lost, phmi_v - lost])
    if nb is not None:
        br = _compiled_bracket(nb, thr, st.bias, st.sigma, pk, cap, tgt)
    else:
        offs = thr + st.bias  # (E, K, 3)
        ax_c = np.moveaxis(offs, 2, 0).reshape(3 * e, -1)
        ax_s = np.moveaxis(st.sigma, 2, 0).reshape(3 * e, -1)
        ax_p = np.tile(pk, (3, 1))
        ax_a = np.broadcast_to(cap, ax_p.shape)
        ax_c = np.where(ax_p > 0, ax_c, 0.0)
        ax_s = np.where(ax_p > 0, ax_s, 1.0)
        br = pl_bracket(ax_c, ax_s, ax_p, ax_a, tgt)
    if defer_pl:
        hpl1, hpl2, vpl, hpl = (np.full(e, np.nan) for _ in range(4))
    else:
        pl = pl_bisect(br, prm["tol_pl_m"], prm["pl_max_iter"]).reshape(3, e)
        hpl1, hpl2, vpl = pl[0], pl[1], pl[2]
        hpl = np.hypot(hpl1, hpl2)
        br = None
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
    if y is not None and nb is not None:
        alarm_mode, ratio = worst_mode, worst
    elif y is not None:
        sep = st.sep
        with np.errstate(divide="ignore", invalid="ignore"):
            norm = np.abs(sep) / thr
        norm = np.where(np.isnan(norm), np.where(np.abs(sep) > 0, np.inf, 0.0), norm)
        norm = np.where(mon[..., None], norm, -np.inf)
        norm[:, 0] = -np.inf
        worst = np.max(norm, axis=2)  # (E, K)
        alarm_mode = np.argmax(worst, axis=1)
        ratio = worst[np.arange(e), alarm_mode]
    if y is not None:
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
                      alarm_mode, ratio, br)
