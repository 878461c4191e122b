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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .._validate import check_array, check_choice, check_probability

__all__ = ["parity_matrix", "parity_test", "ParityResult", "sse_test", "parity_statistics",
           "ParityStatistics", "detection_probability"]


def _projector(h):
    """W = I - H (H^T H)^-1 H^T, batched (seed 000 eq. 5)."""
    m = h.shape[-1 - 1]
    ht = np.swapaxes(h, -1, -2)
    return np.eye(m) - h @ np.linalg.solve(ht @ h, ht)


def parity_matrix(h, method: str = "potter") -> np.ndarray:
    """Parity matrix V (m - n, m) of a geometry matrix H (m, n), with leading batch axes.

    V H = 0, V V^T = I and V^T V = W = I - H (H^T H)^-1 H^T.

    Parameters
    ----------
    h : array (..., m, n), m > n, full column rank.
    method : ``"potter"`` (the paper's upper-triangular V with positive diagonal, built
        row by row as in the step list below seed 000 eq. 23; it is the first m - n rows of
        the pivot-free Cholesky factor of W) or ``"qr"`` (last m - n columns of the full Q
        of H, transposed). Both give the same statistics.

    Raises
    ------
    ValueError if m <= n or, for ``"potter"``, if a leading principal minor of W vanishes
    (the triangular form does not exist for that satellite order; use ``"qr"``).
    """
    check_choice("method", method, ("potter", "qr"))
    h = check_array("h", h, ndim_min=2)
    m, n = h.shape[-2:]
    if m <= n:
        raise ValueError(f"h must have more rows (measurements) than columns (states); "
                         f"got m = {m}, n = {n}")
    if method == "qr":
        q, _ = np.linalg.qr(h, mode="complete")
        return np.swapaxes(q[..., :, n:], -1, -2)
    w = _projector(h)
    v = np.zeros(h.shape[:-2] + (m - n, m))
    for i in range(m - n):  # Potter & Suman, row by row
        d2 = w[..., i, i] - np.sum(v[..., :i, i] ** 2, axis=-1)
        if np.any(d2 <= 1e-12):
            raise ValueError("potter parity matrix does not exist for this satellite order "
                             "(a leading minor of W vanishes); use method='qr'")
        d = np.sqrt(d2)
        v[..., i, i] = d
        v[..., i, i + 1:] = (w[..., i, i + 1:] - np.einsum(
            "...k,...kj->...j", v[..., :i, i], v[..., :i, i + 1:])) / d[..., None]
    return v


@dataclass(frozen=True)
class ParityResult:
    """Result of :func:`parity_test`; every field has the input's batch shape ``B``.

    Attributes
    ----------
    statistic : (B,) DF_D = p^T p.
    threshold : (B,) T_D = chi2.isf(p_fa, m - n).
    alarm : (B,) bool, DF_D >= T_D (normalised statistic >= 1).
    normalised : (B,) DF_D / T_D.
    isolation : (B, m) DF_I_j per measurement (NaN when m - n < 2).
    faulty : (B,) int, argmax_j DF_I_j where an alarm is raised and m - n >= 2, else -1.
    fault_size_m : (B, m) ML estimate of a bias on each measurement (m).
    parity : (B, m - n) the normalised parity vector p.
    dof : int, m - n.
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


def parity_test(h, z, sigma_m, p_fa: float, method: str = "qr") -> ParityResult:
    """Parity-vector detection and isolation for one measurement set (seed 000 eqs. 1-25).

    Parameters
    ----------
    h : (..., m, n) geometry (linearised pseudorange rows).
    z : (..., m) measurement residuals (pseudorange minus prediction at any linearisation
        point: V H = 0 removes the state error).
    sigma_m : scalar or (..., m) measurement 1-sigma (m); unequal sigmas are whitened.
    p_fa : false-alarm probability per test, in (0, 1).
    method : parity matrix construction, ``"qr"`` or ``"potter"``.

    Raises
    ------
    ValueError naming the argument for bad shapes, values or probabilities.
    """
    p_fa = check_probability("p_fa", p_fa)
    h = check_array("h", h, ndim_min=2)
    z = check_array("z", z)
    m, n = h.shape[-2:]
    if m <= n:
        raise ValueError(f"h must have more rows (measurements) than columns (states); "
                         f"got m = {m}, n = {n}")
    if z.shape[-1] != m:
        raise ValueError(f"z must have {m} measurements (rows of h), got shape {z.shape}")
    sigma = np.asarray(sigma_m, dtype=float)
    if np.any(~np.isfinite(sigma)) or np.any(sigma <= 0):
        raise ValueError("sigma_m must be finite and > 0")
    sig = np.broadcast_to(sigma, np.broadcast_shapes(sigma.shape, z.shape))
    hw = h / sig[..., None]
    v = parity_matrix(hw, method)
    p = np.einsum("...ij,...j->...i", v, z / sig)  # seed 000 eq. 7 (normalised)
    stat = np.sum(p * p, axis=-1)  # eq. 8
    dof = m - n
    thr = np.broadcast_to(stats.chi2.isf(p_fa, dof), stat.shape)
    pv = np.einsum("...i,...ij->...j", p, v)  # p^T v_j
    vv = np.sum(v * v, axis=-2)  # v_j^T v_j
    iso = pv**2 / vv  # eq. 23 (with the square)
    alarm = stat >= thr
    if dof >= 2:
        faulty = np.where(alarm, np.argmax(iso, axis=-1), -1)
    else:
        iso = np.full_like(iso, np.nan)
        faulty = np.full(stat.shape, -1)
    return ParityResult(stat, thr, alarm, stat / thr, iso, faulty, pv / vv * sig, p, dof)


def sse_test(h, z, sigma_m, p_fa: float):
    """Least-squares residual (SSE) test: returns (SSE / sigma^2, threshold, alarm).

    The same detector as the parity test: SSE / sigma^2 == DF_D (spec section 1).
    """
    p_fa = check_probability("p_fa", p_fa)
    h = check_array("h", h, ndim_min=2)
    z = check_array("z", z)
    sig = np.broadcast_to(np.asarray(sigma_m, dtype=float), z.shape)
    hw, zw = h / sig[..., None], z / sig
    x = np.linalg.solve(np.swapaxes(hw, -1, -2) @ hw,
                        np.einsum("...mi,...m->...i", hw, zw)[..., None])[..., 0]
    r = zw - np.einsum("...mi,...i->...m", hw, x)
    sse = np.sum(r * r, axis=-1)
    thr = stats.chi2.isf(p_fa, h.shape[-2] - h.shape[-1])
    return sse, thr, sse >= thr


@dataclass(frozen=True)
class ParityStatistics:
    """Masked parity statistics (see :func:`parity_statistics`), batch shape ``B``.

    statistic, threshold, dof : (B,); alarm : (B,) bool; isolation, fault_size_m,
    isolability : (B, S) with NaN for unused satellites; best : (B,) argmax of isolation
    over used satellites (-1 where dof < 2 or unavailable); projector : (B, S, S).
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


def _whitened_projector(h, w):
    """S = I - A N^-1 A^T with A = sqrt(w) H; rows with zero weight give S_jj = 1."""
    from ..lsq import normal_solve

    n_inv, _, ok = normal_solve(h, w, strict=False)
    a = np.sqrt(w)[..., None] * h
    return np.eye(h.shape[-2]) - a @ n_inv @ np.swapaxes(a, -1, -2), ok


def parity_statistics(h, resid_m, weights, p_fa: float, dof) -> ParityStatistics:
    """Parity detection/isolation statistics with satellites switched off by zero weights.

    Parameters
    ----------
    h : (B, S, n) geometry rows (any frame).
    resid_m : (B, S) residuals; ignored where the weight is 0 (may be NaN there).
    weights : (B, S) 1 / sigma^2, 0 for unused satellites.
    p_fa : false-alarm probability.
    dof : (B,) redundancy m - n of each epoch (from :class:`raimcore.lsq.LsqResult`).

    Notes
    -----
    With V^T V = S: p^T p = r^T S r, V^T p = S r and v_j^T v_j = S_jj (r the whitened
    residual), so DF_D and DF_I_j need no explicit V. The isolability of satellite j is
    the largest |cos| between its parity column and another used one,
    max_k |S_jk| / sqrt(S_jj S_kk) (spec section 1): near 1 means a fault on j cannot be
    told apart from one on k.
    """
    w = np.asarray(weights, dtype=float)
    used = w > 0
    r = np.where(used, np.nan_to_num(np.asarray(resid_m, dtype=float)), 0.0) * np.sqrt(w)
    s, ok = _whitened_projector(np.asarray(h, dtype=float), w)
    sr = (s @ r[..., None])[..., 0]
    stat = np.sum(r * sr, axis=-1)
    dof = np.asarray(dof)
    valid = ok & (dof >= 1)
    thr = np.where(valid, stats.chi2.isf(p_fa, np.maximum(dof, 1)), np.nan)
    stat = np.where(valid, stat, np.nan)
    sjj = np.diagonal(s, axis1=-2, axis2=-1)
    can_iso = valid & (dof >= 2)
    use_iso = used & can_iso[..., None]
    with np.errstate(invalid="ignore", divide="ignore"):
        iso = np.where(use_iso, sr**2 / sjj, np.nan)
        size = np.where(use_iso, sr / sjj / np.sqrt(np.where(used, w, 1.0)), np.nan)
        cos = np.abs(s) / np.sqrt(sjj[..., :, None] * sjj[..., None, :])
    pair = used[..., :, None] & used[..., None, :] & ~np.eye(s.shape[-1], dtype=bool)
    isolability = np.where(use_iso, np.max(np.where(pair, cos, 0.0), axis=-1), np.nan)
    best = np.where(can_iso, np.argmax(np.where(use_iso, iso, -np.inf), axis=-1), -1)
    alarm = valid & (stat >= thr)
    return ParityStatistics(stat, thr, dof, alarm, iso, size, isolability, best, s)


def detection_probability(projector, bias_m, weights, dof, p_fa: float) -> np.ndarray:
    """Theoretical detection probability of the chi-square test for a known bias vector.

    lam = b_w^T S b_w (b_w = sqrt(w) b, the whitened bias) = ||V b||^2 / sigma^2 and
    P_D = ncx2.sf(T_D, m - n, lam) (spec section 1). NaN where there is no bias on a used
    satellite or the test is unavailable.
    """
    w = np.asarray(weights, dtype=float)
    b = np.where(w > 0, np.asarray(bias_m, dtype=float), 0.0) * np.sqrt(w)
    lam = np.einsum("...s,...st,...t->...", b, projector, b)
    dof = np.asarray(dof)
    good = (dof >= 1) & np.any(b != 0, axis=-1) & np.isfinite(lam)
    d = np.maximum(dof, 1)
    pd = stats.ncx2.sf(stats.chi2.isf(p_fa, d), d, np.where(good, np.maximum(lam, 0), 1.0))
    return np.where(good, pd, np.nan)
