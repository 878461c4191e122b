"""How well an error model fits a recording: the scale and time correlation of its real
pseudorange errors against the surveyed station position."""

from __future__ import annotations

import numpy as np

from ..sky.spp import elevation_sigma
from .data import Measurements, Truth
from .noise import GaussMarkovFit, fit_gauss_markov

__all__ = ["error_statistics", "clock_free_errors"]


def clock_free_errors(err_m, valid, sigma_m, sys_idx, n_sys: int) -> np.ndarray:
    """Pseudorange errors with each epoch's receiver clock (one per system) removed.

    Parameters
    ----------
    err_m : (E, S) pseudorange minus true range (m): error plus receiver clock.
    valid : (E, S) bool, the errors to use (used, finite, not faulted).
    sigma_m : (E, S) the assumed 1-sigma of each error (m): the clock of an epoch and
        system is the mean of its errors weighted by ``w = 1 / sigma^2``.
    sys_idx : (S,) system index of each satellite; ``n_sys`` the number of systems.

    Returns
    -------
    (E, S) ``(d_i - clock) / sqrt(1 - w_i / sum w)``, NaN where not valid or where the
    system has fewer than 2 valid errors at that epoch. Removing a weighted mean shrinks
    error ``i``'s variance by the factor ``1 - w_i / sum w`` when the weights are the
    inverse variances; the division undoes it, so each value has the variance of the
    error itself.
    """
    d = np.asarray(err_m, dtype=float)
    w = np.where(valid, 1.0 / np.asarray(sigma_m, dtype=float) ** 2, 0.0)
    out = np.full(d.shape, np.nan)
    for j in range(n_sys):
        col = np.asarray(sys_idx) == j
        wj, dj = w[:, col], np.where(valid[:, col], d[:, col], 0.0)
        w_sum = wj.sum(-1, keepdims=True)
        enough = (valid[:, col].sum(-1, keepdims=True) >= 2) & valid[:, col]
        with np.errstate(invalid="ignore", divide="ignore"):
            clk = (wj * dj).sum(-1, keepdims=True) / w_sum
            rj = (dj - clk) / np.sqrt(1.0 - wj / w_sum)
        out[:, col] = np.where(enough, rj, np.nan)
    return out


def error_statistics(meas: Measurements, truth: Truth) -> GaussMarkovFit:
    """Scale and time correlation of a recording's real pseudorange errors.

    The errors are the pseudoranges minus the ranges from the true (station) position,
    with each epoch's receiver clock (one per system) removed as the weighted mean over
    that system's satellites (:func:`clock_free_errors`); faulted measurements
    (``truth.faulted``) are left out. Each error is divided by its elevation model
    (:func:`raimcore.sky.spp.elevation_sigma` at ``sigma_m = 1``), so ``sigma_m`` of the
    fit is directly comparable to the scenario's ``sigma_m`` and ``corr_s`` to its
    ``noise_corr_s`` (:func:`raimcore.measure.noise.fit_gauss_markov`).

    Raises
    ------
    ValueError
        Too few error samples for an estimate.
    """
    rng = np.linalg.norm(meas.pos_sv_ecef_m - truth.pos_rx_ecef_m[:, None, :], axis=-1)
    d = meas.pr_m - rng
    valid = meas.used & np.isfinite(d) & ~truth.faulted
    sig1 = elevation_sigma(meas.el_rad, 1.0)
    z = clock_free_errors(d, valid, sig1, meas.sys_idx, len(meas.systems)) / sig1
    return fit_gauss_markov(z, meas.t_s)
