"""Batched iterative weighted least squares for position and per-system receiver clocks.

One call solves every epoch (and every Monte Carlo run) at once. Satellites are switched
off with a zero weight, so epochs with different visible sets share one array shape and a
satellite is excluded by zeroing its weight. State: ECEF position (3) and one clock (m) per
system; covariance and geometry rows are returned in the local ENU frame of the solution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._validate import (
    check_array,
    check_batch,
    check_choice,
    check_indices,
    check_int,
    check_positive,
    check_weights,
    shape_str,
)
from .geometry import ecef_to_geodetic, enu_rotation

__all__ = ["LsqResult", "wls", "geometry_rows", "clock_columns", "normal_solve", "RCOND_MIN"]

#: Singular-geometry test (relative to scale): a normal matrix N = A^T W A is "singular"
#: when its diagonally scaled form D^-1/2 N D^-1/2 (unit diagonal, so units and weights
#: drop out) has a reciprocal condition number lambda_min / lambda_max below this, i.e. the
#: column-equilibrated whitened geometry has a condition number above 1e6. Used by every
#: kernel (wls, parity, MSS) so they agree on which epochs are unavailable.
RCOND_MIN = 1e-12


def _scaled(n):
    """``D^-1/2 N D^-1/2`` and ``outer = d d^T`` (``d = sqrt(diag N)``, diagonal > 0)."""
    d = np.sqrt(np.diagonal(n, axis1=-2, axis2=-1))
    outer = d[..., :, None] * d[..., None, :]
    return n / outer, outer


def _well_conditioned(ns, strict: bool = True):
    """Conditioning test of a unit-diagonal symmetric matrix (see :data:`RCOND_MIN`).

    The eigenvalues of a unit-diagonal n x n positive semi-definite matrix sum to n, so
    the product of all but the smallest is below e and ``det > t`` implies
    ``lambda_min > t / e`` and ``lambda_min / lambda_max > t / (e n)``.

    ``strict``: the eigenvalue ratio ``lambda_min / lambda_max > RCOND_MIN``. It is decided
    by the determinant where ``det > 1e-6`` (which guarantees the ratio, for any n below
    1e5) and by ``eigvalsh`` only for the remaining few, so the result is exact at the cost
    of a determinant. Not strict: ``det > RCOND_MIN`` (cheaper still; may call a merely
    ill-conditioned matrix singular, and accepts a ratio down to ``RCOND_MIN / (e n)``).
    """
    finite = np.all(np.isfinite(ns), axis=(-2, -1))
    ns = np.where(finite[..., None, None], ns, np.eye(ns.shape[-1]))
    det = np.linalg.det(ns)
    if not strict:
        return finite & (det > RCOND_MIN)
    ok = np.array(finite & (det > 1e-6))
    unsure = finite & ~ok
    if np.any(unsure):
        eig = np.linalg.eigvalsh(ns[unsure])
        ok[unsure] = eig[..., 0] > RCOND_MIN * eig[..., -1]
    return ok


@dataclass(frozen=True)
class LsqResult:
    """Batched least-squares solution; leading shape ``B`` (epochs, runs, ...).

    Attributes
    ----------
    pos_ecef_m : (B, 3) position, NaN where unavailable.
    clock_m : (B, q) receiver clock per system (m), NaN for a system with no satellite used.
    h_enu : (B, S, 3 + q) geometry rows [-u_enu, clock one-hot] at the solution (all
        satellites, used or not; NaN for a satellite whose position is not finite).
    resid_m : (B, S) post-fit residuals pr - predicted (NaN where weight is 0).
    cov_enu : (B, 3 + q, 3 + q) state covariance (H^T W H)^-1 in ENU + clocks (m^2).
    n_used : (B,) satellites with non-zero weight.
    n_states : (B,) 3 + number of systems with at least one used satellite.
    available : (B,) bool, enough satellites, non-singular geometry (:data:`RCOND_MIN`)
        and converged.
    converged : (B,) bool, the Gauss-Newton step fell below tolerance (False where the
        normal matrix was singular at an iterate, or after ``max_iter`` steps).
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
    """One-hot clock columns ``(S, n_sys)`` from per-satellite system indices in [0, n_sys)."""
    n_sys = check_int("n_sys", n_sys, 1)
    sys_idx = check_indices("sys_idx", sys_idx, length=None, hi=n_sys)
    return _clock_columns(sys_idx, n_sys)


def _clock_columns(sys_idx, n_sys: int) -> np.ndarray:
    return (sys_idx[:, None] == np.arange(n_sys)[None, :]).astype(float)


def geometry_rows(pos_sv_ecef_m, pos_rx_ecef_m, clock_cols, *, frame: str = "enu"):
    """Linearised pseudorange rows ``[-u, c]`` and ranges at a receiver position.

    Parameters
    ----------
    pos_sv_ecef_m : (..., S, 3); pos_rx_ecef_m : (..., 3); clock_cols : (S, q) (see
        :func:`clock_columns`).
    frame : ``"enu"`` (rows in the receiver's local frame) or ``"ecef"``.

    Returns ``h (..., S, 3 + q)`` and ``range_m (..., S)``.
    """
    check_choice("frame", frame, ("enu", "ecef"))
    sv = check_array("pos_sv_ecef_m", pos_sv_ecef_m, last=("S", 3), finite=False)
    rx = check_array("pos_rx_ecef_m", pos_rx_ecef_m, last=(3,), finite=False)
    s_n = sv.shape[-2]
    cc = check_array("clock_cols", clock_cols, last=(s_n, "q"),
                     match=f"pos_sv_ecef_m {shape_str((s_n, 3))}")
    if cc.ndim != 2:
        raise ValueError(f"clock_cols must have shape ({s_n}, q), got {cc.shape}")
    check_batch({"pos_sv_ecef_m": sv.shape[:-2], "pos_rx_ecef_m": rx.shape[:-1]})
    return _geometry_rows(sv, rx, cc, frame)


def _geometry_rows(sv, rx, clock_cols, frame):
    d = sv - rx[..., None, :]
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
    a : (..., S, n) rows; rows with zero weight may be non-finite (they are ignored).
    w : (..., S) weights (>= 0; 0 or NaN: row unused).
    strict : judge the conditioning by eigenvalues (reciprocal condition number of the
        diagonally scaled N above :data:`RCOND_MIN`); otherwise by its determinant, which
        is cheaper (see :func:`_well_conditioned`).

    Returns
    -------
    n_inv : (..., n, n), NaN where not ``ok``.
    present : (..., n) bool, state observed by a used row.
    ok : (...,) bool, N finite and well conditioned (singular geometry: False).

    Raises
    ------
    ValueError naming ``a`` or ``w`` for a bad shape or a negative / infinite weight.
    """
    a = check_array("a", a, last=("S", "n"), finite=False)
    s_n, n = a.shape[-2:]
    w = check_weights("w", w, last=(s_n,), match=f"a {shape_str((s_n, n))}")
    batch = check_batch({"a": a.shape[:-2], "w": w.shape[:-1]})
    a = np.broadcast_to(a, batch + (s_n, n))
    w = np.broadcast_to(w, batch + (s_n,))
    return _normal_solve(np.where(w[..., None] > 0.0, a, 0.0), w, strict=strict)


def _normal_solve(a, w, *, strict: bool = True):
    """:func:`normal_solve` without checks: ``a`` finite or zero where ``w == 0``."""
    aw = a * w[..., None]
    n = np.swapaxes(aw, -1, -2) @ a
    finite = np.all(np.isfinite(n), axis=(-2, -1))
    n = np.where(finite[..., None, None], n, np.eye(n.shape[-1]))
    diag = np.diagonal(n, axis1=-2, axis2=-1)
    present = diag > 0.0
    n = n + (~present)[..., None, :] * np.eye(n.shape[-1])
    # Scale to unit diagonal before judging the conditioning (units differ by state).
    ns, outer = _scaled(n)
    ok = finite & _well_conditioned(ns, strict)
    ns_safe = np.where(ok[..., None, None], ns, np.eye(n.shape[-1]))
    n_inv = np.where(ok[..., None, None], np.linalg.inv(ns_safe) / outer, np.nan)
    return n_inv, present, ok


def wls(pos_sv_ecef_m, pr_m, weights, sys_idx, n_sys: int | None = None, *,
        x0_ecef_m=None, max_iter: int = 12, tol_m: float = 1e-4) -> LsqResult:
    """Iterative (Gauss-Newton) weighted least squares, batched over leading axes.

    Parameters
    ----------
    pos_sv_ecef_m : (B, S, 3) satellite positions; may be non-finite for unused satellites.
    pr_m : (B, S) pseudoranges; entries with zero weight may be NaN.
    weights : (B, S) weights 1/sigma^2 (1/m^2), >= 0; 0 (or NaN) excludes a satellite, as
        does a non-finite pseudorange or satellite position.
    sys_idx : (S,) system index of each satellite, in [0, n_sys).
    n_sys : number of clock states (default ``max(sys_idx) + 1``).
    x0_ecef_m : (B, 3) start point (default: the Earth's centre, from which Gauss-Newton
        converges for GNSS geometry); a non-finite row starts from the Earth's centre.
    max_iter, tol_m : iteration limit and step tolerance (m).

    The batch shapes of ``pos_sv_ecef_m``, ``pr_m``, ``weights`` and ``x0_ecef_m`` broadcast
    together. Each epoch iterates on its own: once its step falls below ``tol_m`` it is
    frozen, so an epoch's result does not depend on the rest of the batch.

    Returns
    -------
    LsqResult ; epochs with fewer used satellites than states, singular geometry (see
    :data:`RCOND_MIN`) or no convergence are ``available = False`` with NaN values (no
    exception).

    Raises
    ------
    ValueError naming the argument for bad shapes, negative or infinite weights, system
    indices outside [0, n_sys), ``max_iter < 1`` or ``tol_m <= 0``.
    """
    sv = check_array("pos_sv_ecef_m", pos_sv_ecef_m, last=("S", 3), finite=False)
    s_n = sv.shape[-2]
    desc = f"pos_sv_ecef_m {shape_str((s_n, 3))}"
    pr = check_array("pr_m", pr_m, last=(s_n,), finite=False, match=desc)
    w = check_weights("weights", weights, last=(s_n,), match=desc)
    if n_sys is None:
        sys_idx = check_indices("sys_idx", sys_idx, length=s_n, match=desc)
        q = int(sys_idx.max()) + 1 if s_n else 1
    else:
        q = check_int("n_sys", n_sys, 1)
        sys_idx = check_indices("sys_idx", sys_idx, length=s_n, hi=q, match=desc)
    shapes = {"pos_sv_ecef_m": sv.shape[:-2], "pr_m": pr.shape[:-1], "weights": w.shape[:-1]}
    if x0_ecef_m is not None:
        x0 = check_array("x0_ecef_m", x0_ecef_m, last=(3,), finite=False)
        shapes["x0_ecef_m"] = x0.shape[:-1]
    batch = check_batch(shapes)
    max_iter = check_int("max_iter", max_iter, 1)
    tol_m = check_positive("tol_m", tol_m)
    sv = np.broadcast_to(sv, batch + (s_n, 3))
    x = (np.zeros(batch + (3,)) if x0_ecef_m is None
         else np.array(np.broadcast_to(x0, batch + (3,)), dtype=float))
    x[~np.all(np.isfinite(x), axis=-1)] = 0.0
    pr = np.broadcast_to(pr, batch + (s_n,))
    usable = np.isfinite(pr) & np.all(np.isfinite(sv), axis=-1)
    w = np.where(usable, np.broadcast_to(w, batch + (s_n,)), 0.0)
    used = w > 0
    pr = np.where(used, pr, 0.0)
    cc = _clock_columns(sys_idx, q)
    clk = np.zeros(batch + (q,))
    n_used = np.sum(used, axis=-1)
    converged = np.zeros(batch, dtype=bool)
    done = np.zeros(batch, dtype=bool)
    # Rows of unused satellites are multiplied by a zero weight; only a non-finite one
    # (a satellite without a position) must be zeroed explicitly (0 * NaN = NaN).
    mask_rows = not np.all(np.isfinite(sv))
    for _ in range(max_iter):
        h, rng = _geometry_rows(sv, x, cc, "ecef")
        dz = pr - rng - clk @ cc.T
        if mask_rows:
            h = np.where(used[..., None], h, 0.0)
            dz = np.where(used, dz, 0.0)
        n_inv, present, ok = _normal_solve(h, w, strict=False)
        g = (np.swapaxes(h, -1, -2) @ (w * dz)[..., None])
        dx = (n_inv @ g)[..., 0]
        step = ok & ~done
        dx = np.where(step[..., None], dx, 0.0)
        x = x + dx[..., :3]
        clk = clk + dx[..., 3:]
        # Per-epoch convergence: a converged epoch is frozen; one whose normal matrix is
        # singular at the current iterate stops there, not converged (so unavailable).
        now = step & (np.linalg.norm(dx[..., :3], axis=-1) < tol_m)
        converged |= now
        done |= now | ~ok
        if np.all(done):
            break
    h_enu, rng = _geometry_rows(sv, x, cc, "enu")
    resid = np.where(used, pr - rng - clk @ cc.T, np.nan)
    cov, present, ok = _normal_solve(np.where(used[..., None], h_enu, 0.0) if mask_rows
                                     else h_enu, w)
    n_states = 3 + np.sum(present[..., 3:], axis=-1)
    available = ok & (n_used >= n_states) & converged
    nan = lambda a, extra: np.where(available.reshape(available.shape + (1,) * extra), a,  # noqa: E731
                                    np.nan)
    clk = np.where(present[..., 3:], clk, np.nan)
    return LsqResult(nan(x, 1), nan(clk, 1), h_enu, nan(resid, 1), nan(cov, 2), n_used,
                     n_states, available, converged)
