"""Batched iterative weighted least squares for position and per-system receiver clocks.

One call solves every epoch (and every Monte Carlo run) at once. Satellites are switched
off with a zero weight, so epochs with different visible sets share one array shape and a
satellite is excluded by zeroing its weight. State: ECEF position (3) and one clock (m) per
system; covariance and geometry rows are returned in the local ENU frame of the solution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import ecef_to_geodetic, enu_rotation

__all__ = ["LsqResult", "wls", "geometry_rows", "clock_columns", "normal_solve"]

#: Normal matrices with a reciprocal condition number below this are "singular geometry".
RCOND_MIN = 1e-12


@dataclass(frozen=True)
class LsqResult:
    """Batched least-squares solution; leading shape ``B`` (epochs, runs, ...).

    Attributes
    ----------
    pos_ecef_m : (B, 3) position, NaN where unavailable.
    clock_m : (B, q) receiver clock per system (m), NaN for a system with no satellite used.
    h_enu : (B, S, 3 + q) geometry rows [-u_enu, clock one-hot] at the solution (all
        satellites, used or not).
    resid_m : (B, S) post-fit residuals pr - predicted (NaN where weight is 0).
    cov_enu : (B, 3 + q, 3 + q) state covariance (H^T W H)^-1 in ENU + clocks (m^2).
    n_used : (B,) satellites with non-zero weight.
    n_states : (B,) 3 + number of systems with at least one used satellite.
    available : (B,) bool, enough satellites and non-singular geometry.
    converged : (B,) bool, the Gauss-Newton step fell below tolerance.
    """

    pos_ecef_m: np.ndarray
    clock_m: np.ndarray
    h_enu: np.ndarray
    resid_m: np.ndarray
    cov_enu: np.ndarray
    n_used: np.ndarray
    n_states: np.ndarray
    available: np.ndarray
    converged: np.ndarray

    @property
    def dof(self) -> np.ndarray:
        """Redundancy m - n (negative values mean under-determined)."""
        return self.n_used - self.n_states


def clock_columns(sys_idx, n_sys: int) -> np.ndarray:
    """One-hot clock columns ``(S, n_sys)`` from per-satellite system indices."""
    sys_idx = np.asarray(sys_idx, dtype=int)
    return (sys_idx[:, None] == np.arange(n_sys)[None, :]).astype(float)


def geometry_rows(pos_sv_ecef_m, pos_rx_ecef_m, clock_cols, *, frame: str = "enu"):
    """Linearised pseudorange rows ``[-u, c]`` and ranges at a receiver position.

    Returns ``h (..., S, 3 + q)`` and ``range_m (..., S)``. ``frame`` is ``"enu"`` (rows in
    the receiver's local frame) or ``"ecef"``.
    """
    rx = np.asarray(pos_rx_ecef_m, dtype=float)
    d = np.asarray(pos_sv_ecef_m, dtype=float) - rx[..., None, :]
    rng = np.linalg.norm(d, axis=-1)
    u = d / rng[..., None]
    if frame == "enu":
        lat, lon, _ = ecef_to_geodetic(rx)
        u = np.einsum("...ij,...sj->...si", enu_rotation(lat, lon), u)
    c = np.broadcast_to(clock_cols, u.shape[:-1] + clock_cols.shape[-1:])
    return np.concatenate([-u, c], axis=-1), rng


def normal_solve(a, w, *, strict: bool = True):
    """Inverse of the regularised normal matrix N = A^T W A and its availability.

    States whose column has no weight at all (a clock of a system with no satellite used)
    get a unit diagonal so they stay at zero instead of making N singular; they are not
    counted in ``n_states``.

    Parameters
    ----------
    a : (..., S, n) rows; w : (..., S) weights.
    strict : judge the conditioning by eigenvalues (reciprocal condition number of the
        diagonally scaled N above ``RCOND_MIN``); otherwise by its determinant, which is
        cheaper and used inside iterations.

    Returns ``n_inv (..., n, n)``, ``present (..., n)`` (bool, state observed),
    ``ok (...,)`` (bool, well conditioned).
    """
    aw = a * w[..., None]
    n = np.swapaxes(aw, -1, -2) @ a
    finite = np.all(np.isfinite(n), axis=(-2, -1))
    n = np.where(finite[..., None, None], n, np.eye(n.shape[-1]))
    diag = np.diagonal(n, axis1=-2, axis2=-1)
    present = diag > 0.0
    n = n + (~present)[..., None, :] * np.eye(n.shape[-1])
    # Scale to unit diagonal before judging the conditioning (units differ by state).
    d = np.sqrt(np.diagonal(n, axis1=-2, axis2=-1))
    outer = d[..., :, None] * d[..., None, :]
    ns = n / outer
    if strict:
        eig = np.linalg.eigvalsh(ns)
        ok = finite & (eig[..., 0] > RCOND_MIN * eig[..., -1])
    else:
        ok = finite & (np.linalg.det(ns) > RCOND_MIN)
    ns_safe = np.where(ok[..., None, None], ns, np.eye(n.shape[-1]))
    return np.linalg.inv(ns_safe) / outer, present, ok


def wls(pos_sv_ecef_m, pr_m, weights, sys_idx, n_sys: int | None = None, *,
        x0_ecef_m=None, max_iter: int = 12, tol_m: float = 1e-4) -> LsqResult:
    """Iterative (Gauss-Newton) weighted least squares, batched over leading axes.

    Parameters
    ----------
    pos_sv_ecef_m : (B, S, 3) satellite positions.
    pr_m : (B, S) pseudoranges; entries with zero weight may be NaN.
    weights : (B, S) weights 1/sigma^2 (1/m^2); 0 excludes a satellite.
    sys_idx : (S,) system index of each satellite.
    n_sys : number of clock states (default ``max(sys_idx) + 1``).
    x0_ecef_m : (B, 3) start point (default: the Earth's centre, from which Gauss-Newton
        converges for GNSS geometry).
    max_iter, tol_m : iteration limit and step tolerance (m).

    Returns
    -------
    LsqResult ; epochs with fewer used satellites than states, or singular geometry, are
    ``available = False`` with NaN values (no exception).
    """
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    w = np.asarray(weights, dtype=float)
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    pr = np.where(w > 0, np.nan_to_num(np.asarray(pr_m, dtype=float)), 0.0)
    w = np.where(np.isfinite(np.asarray(pr_m, dtype=float)) | (w == 0), w, 0.0)
    sys_idx = np.asarray(sys_idx, dtype=int)
    q = int(n_sys if n_sys is not None else sys_idx.max() + 1)
    cc = clock_columns(sys_idx, q)
    batch = sv.shape[:-2]
    x = (np.zeros(batch + (3,)) if x0_ecef_m is None
         else np.array(np.broadcast_to(x0_ecef_m, batch + (3,)), dtype=float))
    clk = np.zeros(batch + (q,))
    n_used = np.sum(w > 0, axis=-1)
    converged = np.zeros(batch, dtype=bool)
    ok = np.ones(batch, dtype=bool)
    for _ in range(max_iter):
        h, rng = geometry_rows(sv, x, cc, frame="ecef")
        dz = pr - rng - clk @ cc.T
        n_inv, present, ok = normal_solve(h, w, strict=False)
        g = (np.swapaxes(h, -1, -2) @ (w * dz)[..., None])
        dx = (n_inv @ g)[..., 0]
        dx = np.where(ok[..., None], dx, 0.0)
        x = x + dx[..., :3]
        clk = clk + dx[..., 3:]
        converged = np.linalg.norm(dx[..., :3], axis=-1) < tol_m
        if np.all(converged | ~ok):
            break
    h_enu, rng = geometry_rows(sv, x, cc, frame="enu")
    resid = np.where(w > 0, pr - rng - clk @ cc.T, np.nan)
    cov, present, ok = normal_solve(h_enu, w)
    n_states = 3 + np.sum(present[..., 3:], axis=-1)
    available = ok & (n_used >= n_states) & converged
    nan = lambda a, extra: np.where(available.reshape(available.shape + (1,) * extra), a,  # noqa: E731
                                    np.nan)
    clk = np.where(present[..., 3:], clk, np.nan)
    return LsqResult(nan(x, 1), nan(clk, 1), h_enu, nan(resid, 1), nan(cov, 2), n_used,
                     n_states, available, converged)
