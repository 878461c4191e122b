"""How well an error model fits a recording: the scale and time correlation of its real
pseudorange errors against the surveyed station position."""

from __future__ import annotations

import numpy as np

from ..sky.spp import elevation_sigma
from .data import Measurements, Truth
from .noise import GaussMarkovFit, fit_gauss_markov

__all__ = ["error_statistics"]


def error_statistics(meas: Measurements, truth: Truth) -> GaussMarkovFit:
    """Scale and time correlation of a recording's real pseudorange errors.

    The errors are the pseudoranges minus the ranges from the true (station) position,
    with each epoch's receiver clock (one per system) removed as the weighted mean over
    that system's satellites; faulted measurements (``truth.faulted``) are left out. Each
    error is divided by its elevation model (:func:`raimcore.sky.spp.elevation_sigma` at
    ``sigma_m = 1``) and by ``sqrt(1 - w_i / sum w)`` (the share the clock estimate takes),
    so ``sigma_m`` of the fit is directly comparable to the scenario's ``sigma_m`` and
    ``corr_s`` to its ``noise_corr_s`` (:func:`raimcore.measure.noise.fit_gauss_markov`).

    Raises
    ------
    ValueError
        Too few error samples for an estimate.
    """
    rng = np.linalg.norm(meas.pos_sv_ecef_m - truth.pos_rx_ecef_m[:, None, :], axis=-1)
    d = meas.pr_m - rng
    valid = meas.used & np.isfinite(d) & ~truth.faulted
    sig1 = elevation_sigma(meas.el_rad, 1.0)
    w = np.where(valid, 1.0 / sig1**2, 0.0)
    z = np.full(d.shape, np.nan)
    for j in range(len(meas.systems)):
        col = meas.sys_idx == j
        wj, dj = w[:, col], np.where(valid[:, col], d[:, col], 0.0)
        w_sum = wj.sum(-1, keepdims=True)
        enough = (valid[:, col].sum(-1, keepdims=True) >= 2) & valid[:, col]
        with np.errstate(invalid="ignore", divide="ignore"):
            clk = (wj * dj).sum(-1, keepdims=True) / w_sum
            zj = (dj - clk) / (sig1[:, col] * np.sqrt(1.0 - wj / w_sum))
        z[:, col] = np.where(enough, zj, np.nan)
    return fit_gauss_markov(z, meas.t_s)
