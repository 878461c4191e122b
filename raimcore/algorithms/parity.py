"""Parity-vector fault detection, isolation and reconstruction (seed 000, Liao & Huang 1996).

Two layers:

* the paper's dense form, for one fixed measurement set: :func:`parity_matrix` (Potter's
  triangular V or a QR basis) and :func:`parity_test`;
* a masked form used by the scenario engine, :func:`parity_statistics`, where satellites
  are switched off by zero weights so that epochs with different visible sets share one
  batch. It works with the residual projector S = I - A (A^T A)^-1 A^T (A the whitened
  geometry), using V^T V = S: the statistics are identical (tested).

Statistics (spec section 1): p = V z / sigma, DF_D = p^T p ~ chi2(m - n) without fault,
T_D = chi2.isf(p_fa, m - n); DF_I_j = (p^T v_j)^2 / (v_j^T v_j) (seed 000 eq. 23; eq. 25 as
printed drops the square); f_hat_j = p^T v_j / (v_j^T v_j) sigma.

Unavailable is never a number: an epoch whose geometry is singular or nearly so (the
diagonally scaled normal matrix has a reciprocal condition number below
:data:`raimcore.lsq.RCOND_MIN`, the same test as the least-squares solver) gets NaN
statistics, no alarm and ``available = False``, and its neighbours in the batch are
computed exactly as without it. A satellite whose parity column has (almost) no length,
v_j^T v_j = S_jj <= 1e-9 (leverage 1: no redundancy for it), gets a NaN isolation statistic
and is never isolated. Inputs are validated once at the public edge (``ValueError`` naming
the argument and the expected shape).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .._validate import (
    check_array,
    check_batch,
    check_choice,
    check_int_array,
    check_probability,
    check_weights,
    shape_str,
)
from ..lsq import _normal_solve, _scaled, _well_conditioned

__all__ = ["parity_matrix", "parity_test", "ParityResult", "sse_test", "parity_statistics",
           "ParityStatistics", "detection_probability"]

#: A parity column shorter than this (v_j^T v_j = S_jj = 1 - leverage, scale-free) belongs
#: to a satellite with no redundancy: its isolation statistic is undefined (NaN).
_SJJ_MIN = 1e-9
#: Potter's pivot d_i^2 below this: the triangular V does not exist for the order.
_POTTER_PIVOT_MIN = 1e-12


def _projector(h):
    """W = I - H (H^T H)^-1 H^T, batched (seed 000 eq. 5)."""
    m = h.shape[-1 - 1]
    ht = np.swapaxes(h, -1, -2)
    return np.eye(m) - h @ np.linalg.solve(ht @ h, ht)


def _full_rank(h):
    """``(...,)`` bool: H^T H is well conditioned relative to scale (no zero column)."""
    n = np.swapaxes(h, -1, -2) @ h
    pos = np.all(np.diagonal(n, axis1=-2, axis2=-1) > 0.0, axis=-1)
    ns, _ = _scaled(np.where(pos[..., None, None], n, np.eye(n.shape[-1])))
    return pos & _well_conditioned(ns)


def _check_redundant(h):
    m, n = h.shape[-2:]
    if m <= n:
        raise ValueError(f"h must have shape (..., m, n) with more rows (measurements) than "
                         f"columns (states), m > n; got {h.shape} (m = {m}, n = {n})")


def _parity_matrix(h, method):
    """Unchecked :func:`parity_matrix`: ``v (..., m - n, m)`` (NaN where not ok), ``ok``."""
    m, n = h.shape[-2:]
    ok = _full_rank(h)
    # A stand-in geometry for rows that fail, so the batch stays one computation: its
    # W = diag(1, ..., 1, 0, ..., 0) has Potter pivots 1.
    h = np.where(ok[..., None, None], h, np.eye(m)[:, m - n:])
    if method == "qr":
        q, _ = np.linalg.qr(h, mode="complete")
        v = np.swapaxes(q[..., :, n:], -1, -2)
    else:
        w = _projector(h)
        v = np.zeros(h.shape[:-2] + (m - n, m))
        for i in range(m - n):  # Potter & Suman, row by row
            d2 = w[..., i, i] - np.sum(v[..., :i, i] ** 2, axis=-1)
            piv = d2 > _POTTER_PIVOT_MIN
            ok = ok & piv
            d = np.sqrt(np.where(piv, d2, 1.0))
            v[..., i, i] = d
            v[..., i, i + 1:] = (w[..., i, i + 1:] - np.einsum(
                "...k,...kj->...j", v[..., :i, i], v[..., :i, i + 1:])) / d[..., None]
    return np.where(ok[..., None, None], v, np.nan), ok


def parity_matrix(h, method: str = "potter") -> np.ndarray:
    """Parity matrix V (m - n, m) of a geometry matrix H (m, n), with leading batch axes.

    V H = 0, V V^T = I and V^T V = W = I - H (H^T H)^-1 H^T.

    Parameters
    ----------
    h : array (..., m, n), m > n, finite.
    method : ``"potter"`` (the paper's upper-triangular V with positive diagonal, built
        row by row as in the step list below seed 000 eq. 23; it is the first m - n rows of
        the pivot-free Cholesky factor of W) or ``"qr"`` (last m - n columns of the full Q
        of H, transposed). Both give the same statistics.

    Returns
    -------
    (..., m - n, m) V; all NaN for a batch entry whose H is rank-deficient (see
    :data:`raimcore.lsq.RCOND_MIN`) or, for ``"potter"``, whose triangular form does not
    exist for that satellite order (a pivot d_i^2 <= 1e-12; ``"qr"`` always exists).

    Raises
    ------
    ValueError if ``method`` is unknown, ``h`` is not ``(..., m, n)`` with m > n or has
    non-finite entries.
    """
    check_choice("method", method, ("potter", "qr"))
    h = check_array("h", h, last=("m", "n"))
    _check_redundant(h)
    return _parity_matrix(h, method)[0]


@dataclass(frozen=True)
class ParityResult:
    """Result of :func:`parity_test`; every field has the input's batch shape ``B``.

    Attributes
    ----------
    statistic : (B,) DF_D = p^T p (NaN where unavailable).
    threshold : (B,) T_D = chi2.isf(p_fa, m - n).
    alarm : (B,) bool, DF_D >= T_D (normalised statistic >= 1); False where unavailable.
    normalised : (B,) DF_D / T_D.
    isolation : (B, m) DF_I_j per measurement (NaN when m - n < 2, where unavailable and
        for a measurement with v_j^T v_j <= 1e-9).
    faulty : (B,) int, argmax_j DF_I_j where an alarm is raised and m - n >= 2, else -1.
    fault_size_m : (B, m) ML estimate of a bias on each measurement (m).
    parity : (B, m - n) the normalised parity vector p.
    dof : int, m - n.
    available : (B,) bool, False where H is rank-deficient (or Potter's V does not exist).
    """

    statistic: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    normalised: np.ndarray
    isolation: np.ndarray
    faulty: np.ndarray
    fault_size_m: np.ndarray
    parity: np.ndarray
    dof: int
    available: np.ndarray


def _check_dense(h, z, sigma_m):
    """Validate the dense form's ``h (..., m, n)``, ``z (..., m)``, ``sigma_m``.

    Returns ``h, z, sigma`` broadcast to one batch shape (sigma to ``(..., m)``).
    """
    h = check_array("h", h, last=("m", "n"))
    _check_redundant(h)
    m, n = h.shape[-2:]
    hdesc = f"h {shape_str((m, n))}"
    z = check_array("z", z, last=(m,), match=hdesc)
    sigma = check_array("sigma_m", sigma_m, ndim_min=0, finite=False)
    if sigma.ndim and sigma.shape[-1] not in (1, m):
        raise ValueError(f"sigma_m must be a scalar or have shape {shape_str((m,))} to "
                         f"match {hdesc}, got {sigma.shape}")
    if not np.all(np.isfinite(sigma) & (sigma > 0.0)):
        raise ValueError("sigma_m must be finite and > 0")
    batch = check_batch({"h": h.shape[:-2], "z": z.shape[:-1],
                         "sigma_m": sigma.shape[:-1]})
    return (np.broadcast_to(h, batch + (m, n)), np.broadcast_to(z, batch + (m,)),
            np.broadcast_to(sigma, batch + (m,)))


def parity_test(h, z, sigma_m, p_fa: float, method: str = "qr") -> ParityResult:
    """Parity-vector detection and isolation for one measurement set (seed 000 eqs. 1-25).

    Parameters
    ----------
    h : (..., m, n) geometry (linearised pseudorange rows), m > n, finite.
    z : (..., m) measurement residuals (pseudorange minus prediction at any linearisation
        point: V H = 0 removes the state error), finite (for missing measurements use
        :func:`parity_statistics` with zero weights).
    sigma_m : scalar or (..., m) measurement 1-sigma (m); unequal sigmas are whitened.
    p_fa : false-alarm probability per test, in (0, 1).
    method : parity matrix construction, ``"qr"`` or ``"potter"``.

    The batch shapes of ``h``, ``z`` and ``sigma_m`` broadcast together. A batch entry with
    rank-deficient geometry is unavailable: NaN statistics, no alarm, ``faulty = -1``.

    Raises
    ------
    ValueError naming the argument for bad shapes, values or probabilities.
    """
    p_fa = check_probability("p_fa", p_fa)
    check_choice("method", method, ("potter", "qr"))
    h, z, sig = _check_dense(h, z, sigma_m)
    m, n = h.shape[-2:]
    v, ok = _parity_matrix(h / sig[..., None], method)
    p = np.einsum("...ij,...j->...i", v, z / sig)  # seed 000 eq. 7 (normalised)
    stat = np.sum(p * p, axis=-1)  # eq. 8
    dof = m - n
    thr = np.broadcast_to(stats.chi2.isf(p_fa, dof), stat.shape)
    pv = np.einsum("...i,...ij->...j", p, v)  # p^T v_j
    vv = np.sum(v * v, axis=-2)  # v_j^T v_j
    with np.errstate(invalid="ignore", divide="ignore"):
        iso = np.where(vv > _SJJ_MIN, pv**2 / vv, np.nan)  # eq. 23 (with the square)
        size = np.where(vv > _SJJ_MIN, pv / vv * sig, np.nan)
    alarm = ok & (stat >= thr)
    if dof >= 2:
        pick = np.argmax(np.where(np.isnan(iso), -np.inf, iso), axis=-1)
        faulty = np.where(alarm & np.any(np.isfinite(iso), axis=-1), pick, -1)
    else:
        iso = np.full_like(iso, np.nan)
        faulty = np.full(stat.shape, -1)
    return ParityResult(statistic=stat, threshold=thr, alarm=alarm, normalised=stat / thr,
                        isolation=iso, faulty=faulty, fault_size_m=size, parity=p, dof=dof,
                        available=ok)


def sse_test(h, z, sigma_m, p_fa: float):
    """Least-squares residual (SSE) test: returns (SSE / sigma^2, threshold, alarm).

    The same detector as the parity test: SSE / sigma^2 == DF_D (spec section 1).

    Parameters
    ----------
    h, z, sigma_m, p_fa : as in :func:`parity_test` (m > n).

    Returns
    -------
    sse : (B,) SSE / sigma^2, NaN where H is rank-deficient (unavailable).
    threshold : float, chi2.isf(p_fa, m - n).
    alarm : (B,) bool, sse >= threshold (False where unavailable).

    Raises
    ------
    ValueError naming the argument for bad shapes (including m <= n: no redundancy),
    sigma_m <= 0 or non-finite, or p_fa outside (0, 1).
    """
    p_fa = check_probability("p_fa", p_fa)
    h, z, sig = _check_dense(h, z, sigma_m)
    hw, zw = h / sig[..., None], z / sig
    ok = _full_rank(hw)
    nmat = np.swapaxes(hw, -1, -2) @ hw
    nmat = np.where(ok[..., None, None], nmat, np.eye(nmat.shape[-1]))
    x = np.linalg.solve(nmat, np.einsum("...mi,...m->...i", hw, zw)[..., None])[..., 0]
    r = zw - np.einsum("...mi,...i->...m", hw, x)
    sse = np.where(ok, np.sum(r * r, axis=-1), np.nan)
    thr = stats.chi2.isf(p_fa, h.shape[-2] - h.shape[-1])
    return sse[()], thr, (ok & (sse >= thr))[()]


@dataclass(frozen=True)
class ParityStatistics:
    """Masked parity statistics (see :func:`parity_statistics`), batch shape ``B``.

    statistic, threshold : (B,), NaN where unavailable; dof : (B,); alarm : (B,) bool;
    isolation, fault_size_m, isolability : (B, S) with NaN for unused satellites;
    best : (B,) argmax of isolation over used satellites (-1 where dof < 2 or
    unavailable); projector : (B, S, S) (NaN where the geometry is singular);
    available : (B,) bool, geometry well conditioned, every used residual finite and
    dof >= 1.
    """

    statistic: np.ndarray
    threshold: np.ndarray
    dof: np.ndarray
    alarm: np.ndarray
    isolation: np.ndarray
    fault_size_m: np.ndarray
    isolability: np.ndarray
    best: np.ndarray
    projector: np.ndarray
    available: np.ndarray


def _whitened_projector(h, w):
    """S = I - A N^-1 A^T with A = sqrt(w) H; rows with zero weight give S_jj = 1.

    Unchecked (internal; the scenario engine calls it too). Weights that are not finite
    and > 0 count as 0; rows with zero weight may be non-finite. Returns ``s (..., S, S)``,
    NaN where the geometry is singular, and ``ok (...,)``.
    """
    w = np.where(np.isfinite(w) & (w > 0.0), w, 0.0)
    h = np.where(w[..., None] > 0.0, h, 0.0)
    n_inv, _, ok = _normal_solve(h, w, strict=True)
    a = np.sqrt(w)[..., None] * h
    return np.eye(h.shape[-2]) - a @ n_inv @ np.swapaxes(a, -1, -2), ok


def _check_masked(h, resid_m, weights, dof, *, h_name="h", resid_name="resid_m"):
    """Validate the masked form's arguments; returns them broadcast to one batch shape."""
    h = check_array(h_name, h, last=("S", "n"), finite=False)
    s_n, n = h.shape[-2:]
    hdesc = f"{h_name} {shape_str((s_n, n))}"
    r = check_array(resid_name, resid_m, last=(s_n,), finite=False, match=hdesc)
    w = check_weights("weights", weights, last=(s_n,), match=hdesc)
    dof = check_int_array("dof", dof)
    batch = check_batch({h_name: h.shape[:-2], resid_name: r.shape[:-1],
                         "weights": w.shape[:-1], "dof": dof.shape})
    return (np.broadcast_to(h, batch + h.shape[-2:]), np.broadcast_to(r, batch + (s_n,)),
            np.broadcast_to(w, batch + (s_n,)), np.broadcast_to(dof, batch))


def parity_statistics(h, resid_m, weights, p_fa: float, dof) -> ParityStatistics:
    """Parity detection/isolation statistics with satellites switched off by zero weights.

    Parameters
    ----------
    h : (B, S, n) geometry rows (any frame); rows with zero weight may be non-finite.
    resid_m : (B, S) residuals; ignored where the weight is 0 (may be NaN there).
    weights : (B, S) 1 / sigma^2, >= 0; 0 (or NaN) for unused satellites.
    p_fa : false-alarm probability, in (0, 1).
    dof : (B,) int, redundancy m - n of each epoch (from :class:`raimcore.lsq.LsqResult`);
        trusted, not recomputed.

    The batch shapes of the four arrays broadcast together. An epoch is unavailable (NaN
    statistic and threshold, no alarm, ``best = -1``) where its weighted geometry is
    singular (:data:`raimcore.lsq.RCOND_MIN`), a used satellite has a non-finite residual
    or row, or dof < 1.

    Raises
    ------
    ValueError naming the argument for bad shapes, negative or infinite weights,
    non-integer dof or p_fa outside (0, 1).

    Notes
    -----
    With V^T V = S: p^T p = r^T S r, V^T p = S r and v_j^T v_j = S_jj (r the whitened
    residual), so DF_D and DF_I_j need no explicit V. The isolability of satellite j is
    the largest |cos| between its parity column and another used one,
    max_k |S_jk| / sqrt(S_jj S_kk) (spec section 1): near 1 means a fault on j cannot be
    told apart from one on k.
    """
    p_fa = check_probability("p_fa", p_fa)
    h, r_m, w, dof = _check_masked(h, resid_m, weights, dof)
    return _parity_statistics(h, r_m, w, p_fa, dof)


def _parity_statistics(h, resid_m, w, p_fa, dof):
    used = w > 0
    finite = np.isfinite(resid_m) & np.all(np.isfinite(h), axis=-1)
    inputs_ok = ~np.any(used & ~finite, axis=-1)
    r = np.where(used & finite, resid_m, 0.0) * np.sqrt(w)
    s, ok = _whitened_projector(np.where(finite[..., None], h, 0.0), w)
    s_ok = np.where(ok[..., None, None], s, 0.0)
    sr = (s_ok @ r[..., None])[..., 0]
    stat = np.sum(r * sr, axis=-1)
    valid = ok & inputs_ok & (dof >= 1)
    thr = np.where(valid, stats.chi2.isf(p_fa, np.maximum(dof, 1)), np.nan)
    stat = np.where(valid, stat, np.nan)
    sjj = np.diagonal(s_ok, axis1=-2, axis2=-1)
    can_iso = valid & (dof >= 2)
    use_iso = used & can_iso[..., None] & (sjj > _SJJ_MIN)
    with np.errstate(invalid="ignore", divide="ignore"):
        iso = np.where(use_iso, sr**2 / sjj, np.nan)
        size = np.where(use_iso, sr / sjj / np.sqrt(np.where(used, w, 1.0)), np.nan)
        cos = np.abs(s_ok) / np.sqrt(sjj[..., :, None] * sjj[..., None, :])
    pair = used[..., :, None] & used[..., None, :] & ~np.eye(s.shape[-1], dtype=bool)
    isolability = np.where(use_iso, np.max(np.where(pair, cos, 0.0), axis=-1), np.nan)
    best = np.where(can_iso & np.any(use_iso, axis=-1),
                    np.argmax(np.where(use_iso, iso, -np.inf), axis=-1), -1)
    alarm = valid & (stat >= thr)
    return ParityStatistics(statistic=stat, threshold=thr, dof=np.array(dof), alarm=alarm,
                            isolation=iso, fault_size_m=size, isolability=isolability,
                            best=best, projector=s, available=valid)


def detection_probability(projector, bias_m, weights, dof, p_fa: float) -> np.ndarray:
    """Theoretical detection probability of the chi-square test for a known bias vector.

    lam = b_w^T S b_w (b_w = sqrt(w) b, the whitened bias) = ||V b||^2 / sigma^2 and
    P_D = ncx2.sf(T_D, m - n, lam) (spec section 1).

    Parameters
    ----------
    projector : (B, S, S) whitened residual projector S (``ParityStatistics.projector``;
        NaN rows, as it has for singular geometry, give NaN).
    bias_m : (B, S) bias on each satellite (m); ignored where the weight is 0.
    weights : (B, S) 1 / sigma^2, >= 0; 0 (or NaN) for unused satellites.
    dof : (B,) int, m - n.
    p_fa : false-alarm probability, in (0, 1).

    Returns
    -------
    (B,) P_D; NaN where there is no bias on a used satellite, dof < 1, or the projector or a
    used bias is not finite.

    Raises
    ------
    ValueError naming the argument for bad shapes, weights, dof or p_fa.
    """
    p_fa = check_probability("p_fa", p_fa)
    proj = check_array("projector", projector, last=("S", "S"), finite=False)
    s_n = proj.shape[-1]
    if proj.shape[-2] != s_n:
        raise ValueError(f"projector must have shape (..., S, S), got {proj.shape}")
    pdesc = f"projector {shape_str((s_n, s_n))}"
    bias = check_array("bias_m", bias_m, last=(s_n,), finite=False, match=pdesc)
    w = check_weights("weights", weights, last=(s_n,), match=pdesc)
    dof = check_int_array("dof", dof)
    check_batch({"projector": proj.shape[:-2], "bias_m": bias.shape[:-1],
                 "weights": w.shape[:-1], "dof": dof.shape})
    used = w > 0
    b = np.where(used, bias, 0.0) * np.sqrt(w)
    proj = np.where(used[..., :, None] & used[..., None, :], proj, 0.0)
    lam = np.einsum("...s,...st,...t->...", b, proj, b)
    good = (dof >= 1) & np.any(b != 0, axis=-1) & np.isfinite(lam)
    d = np.maximum(dof, 1)
    pd = stats.ncx2.sf(stats.chi2.isf(p_fa, d), d, np.where(good, np.maximum(lam, 0), 1.0))
    return np.where(good, pd, np.nan)
