"""Real recordings through the engine: RINEX observation + navigation -> :class:`EpochData`.

A scenario with ``source = "rinex"`` names an observation and a navigation file. The
pseudoranges of the chosen signals are corrected for the satellite clock (relativity, TGD),
the Klobuchar ionosphere and the troposphere (:mod:`raimcore.sky.spp`), so that every registered
algorithm sees the same kind of data as from a simulation: satellite positions and
pseudoranges whose only unknowns are the receiver position and one clock per system. Faults
are added to the real pseudoranges; the truth for the error columns is the header position
of the (static) station, or ``truth_ecef_m``.

Satellites with no usable ephemeris are left out and said so in ``EpochData.notes``.
"""

from __future__ import annotations

import dataclasses
import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..algorithms.base import EpochData
from ..geometry import az_el, ecef_to_geodetic
from ..measure.faults import fault_biases
from ..measure.noise import GaussMarkovFit, fit_gauss_markov, make_noise
from .rinex import ObsFile, read_nav, read_obs
from .spp import SYSTEM_LETTER, Corrected, correct, elevation_sigma, solve

__all__ = ["recording_epoch_data", "recording_scenario", "load_recording", "receiver_ecef_m",
           "error_statistics"]

#: Defaults for real data (scenario keys): code noise of a geodetic receiver at the zenith,
#: a 10-degree mask against multipath.
REAL_DATA_DEFAULTS = {"sigma_m": 1.0, "mask_deg": 10.0}


def _stamp(path) -> tuple[str, int, int]:
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"RINEX file {str(path)!r} does not exist")
    st = p.stat()
    return str(p.resolve()), st.st_mtime_ns, st.st_size


@lru_cache(maxsize=4)
def _read_obs(stamp) -> ObsFile:
    return read_obs(stamp[0])


@lru_cache(maxsize=4)
def _corrected(obs_stamp, nav_stamp, systems, signals) -> Corrected:
    return correct(_read_obs(obs_stamp), read_nav(nav_stamp[0]), systems, signals)


def load_recording(obs, nav, systems=("GPS", "BDS"), signals=()) -> Corrected:
    """Read and correct a recording (cached on the files' paths, sizes and times)."""
    return _corrected(_stamp(obs), _stamp(nav), tuple(systems), tuple(signals))


def recording_scenario(obs, nav, **overrides):
    """A :class:`~raimcore.scenario.Scenario` for a recording with real-data defaults:
    GPS and BDS (those present), the whole recording at its own interval, ``sigma_m`` 1 m,
    a 10-degree mask; ``overrides`` are scenario keys."""
    from ..scenario import from_dict

    o = _read_obs(_stamp(obs))
    systems = [s for s, letter in SYSTEM_LETTER.items()
               if any(n[0] == letter for n in o.sat_names)] or ["GPS"]
    t = o.t_gps_s - o.t_gps_s[0] if len(o.t_gps_s) else np.zeros(1)
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    d = {"name": Path(obs).name.split(".")[0], "description": f"recording {Path(obs).name}",
         "source": "rinex", "obs": str(obs), "nav": str(nav), "systems": systems,
         "duration_s": float(t[-1]), "step_s": step, **REAL_DATA_DEFAULTS}
    d.update(overrides)
    return from_dict(d)


def receiver_ecef_m(s) -> np.ndarray:
    """(3,) the receiver position of a recording scenario: ``truth_ecef_m``, else the
    header position (zeros when the file has none)."""
    if s.truth_ecef_m:
        return np.array(s.truth_ecef_m, dtype=float)
    return np.array(_read_obs(_stamp(s.obs)).approx_pos_ecef_m, dtype=float)


def _window(t_rel, t0, duration, step) -> np.ndarray:
    """Indices of the epochs in [t0, t0 + duration], thinned to at least ``step`` apart."""
    keep = []
    last = -math.inf
    for k, tk in enumerate(t_rel):
        if t0 - 1e-6 <= tk <= t0 + duration + 1e-6 and tk >= last + step - 1e-6:
            keep.append(k)
            last = tk
    return np.array(keep, dtype=int)


def recording_epoch_data(s) -> EpochData:
    """The :class:`EpochData` of a ``source = "rinex"`` scenario ``s``."""
    from ..scenario import apply_restrict

    obs_file = _read_obs(_stamp(s.obs))
    corr = load_recording(s.obs, s.nav, s.systems, s.signals)
    notes = list(corr.notes)
    t_rel = corr.t_gps_s - corr.t_gps_s[0] if len(corr.t_gps_s) else corr.t_gps_s
    rows = _window(t_rel, s.t_start_s, s.duration_s, s.step_s)
    if rows.size == 0:
        raise ValueError(f"t_start_s {s.t_start_s:g} / duration_s {s.duration_s:g} select no "
                         f"epoch of {s.obs} (it spans 0 to {t_rel[-1] if len(t_rel) else 0:g} s)")
    names = list(corr.sat_names)
    cols = np.arange(len(names))
    if s.sats:
        unknown = [x for x in s.sats if x not in names]
        if unknown:
            raise ValueError(f"sats: {', '.join(unknown)} not in this recording; choose from "
                             f"{', '.join(names)}")
        cols = np.array([names.index(x) for x in s.sats], dtype=int)
    names = [names[c] for c in cols]
    ix = np.ix_(rows, cols)
    t = t_rel[rows] - s.t_start_s
    if s.truth_ecef_m:
        truth = np.array(s.truth_ecef_m, dtype=float)
    elif np.any(obs_file.approx_pos_ecef_m):
        truth = obs_file.approx_pos_ecef_m
    else:
        sol = solve(corr, mask_deg=s.mask_deg).pos_ecef_m
        ok = np.isfinite(sol).all(-1)
        truth = np.median(sol[ok], axis=0) if ok.any() else np.zeros(3)
        notes.append("no header position and no truth_ecef_m: truth is the median "
                     "single-point solution")
    sv = corr.pos_sv_ecef_m[ix]
    truth_e = np.broadcast_to(truth, (len(rows), 3)).copy()
    az, el = az_el(sv, truth_e)
    used = corr.tracked[ix] & corr.usable[ix] & (el >= math.radians(s.mask_deg))
    apply_restrict(used, t, names, s.restrict)
    bias = fault_biases(s.faults, t, names)
    pr = np.where(used, corr.pr_m[ix] + bias, np.nan)
    sys_idx = corr.sys_idx[cols]
    systems = corr.systems
    baro_alt = None
    if s.baro:  # a simulated altimeter beside the real pseudoranges
        rng = np.random.default_rng(np.random.SeedSequence(int(s.seed)).spawn(3)[2])
        baro_alt = ecef_to_geodetic(truth_e)[2] + s.sigma_baro_m * rng.standard_normal(len(t))
    noise = make_noise(s.noise, s.sigma_m, mixture_eps=s.mixture_eps,
                       mixture_scale=s.mixture_scale, student_nu=s.student_nu,
                       corr_s=s.noise_corr_s)  # the assumed model of the real errors
    data = EpochData(
        t_s=t, sat_names=tuple(names), sys_idx=sys_idx, systems=systems, pos_sv_ecef_m=sv,
        pr_m=pr, used=used, az_rad=az, el_rad=el, sigma_m=elevation_sigma(el, s.sigma_m),
        noise=noise, pos_rx_true_ecef_m=truth_e, vel_rx_true_ecef_mps=np.zeros_like(truth_e),
        fault_bias_m=bias, p_fa=s.p_fa, p_md=s.p_md, seed=int(s.seed), baro_alt_m=baro_alt,
        sigma_baro_m=s.sigma_baro_m if s.baro else None, hal_m=s.hal_m, val_m=s.val_m,
        notes=tuple(notes))
    try:
        fit = error_statistics(data)
    except ValueError:  # too few satellites for an estimate: nothing to say
        return data
    note = (f"measured pseudorange errors against the station position: sigma "
            f"{fit.sigma_m:.2f} m at the zenith (robust; scenario sigma_m {s.sigma_m:g}), "
            f"correlation {fit.rho:.2f} over {fit.dt_s:g} s")
    if 0 < fit.corr_s < math.inf:
        note += (f" (Gauss-Markov time {fit.corr_s:.0f} s; scenario noise_corr_s "
                 f"{s.noise_corr_s:g}: PF-LLR calibrates its threshold on these two keys)")
    return dataclasses.replace(data, notes=data.notes + (note,))


def error_statistics(data: EpochData) -> GaussMarkovFit:
    """Scale and time correlation of a recording's real pseudorange errors.

    The errors are the corrected pseudoranges minus the ranges from the true (station)
    position, with each epoch's receiver clock (one per system) removed as the weighted
    mean over that system's satellites; faulted measurements (``fault_bias_m != 0``) are
    left out. Each error is divided by its elevation model (:func:`raimcore.sky.spp.
    elevation_sigma` at ``sigma_m = 1``) and by ``sqrt(1 - w_i / sum w)`` (the share the
    clock estimate takes), so ``sigma_m`` of the fit is directly comparable to the
    scenario's ``sigma_m`` and ``corr_s`` to its ``noise_corr_s``
    (:func:`raimcore.measure.noise.fit_gauss_markov`).
    """
    rng = np.linalg.norm(data.pos_sv_ecef_m - data.pos_rx_true_ecef_m[:, None, :], axis=-1)
    d = data.pr_m - rng
    valid = data.used & np.isfinite(d) & (data.fault_bias_m == 0)
    sig1 = elevation_sigma(data.el_rad, 1.0)
    w = np.where(valid, 1.0 / sig1**2, 0.0)
    z = np.full(d.shape, np.nan)
    for j in range(len(data.systems)):
        col = data.sys_idx == j
        wj, dj = w[:, col], np.where(valid[:, col], d[:, col], 0.0)
        w_sum = wj.sum(-1, keepdims=True)
        enough = (valid[:, col].sum(-1, keepdims=True) >= 2) & valid[:, col]
        with np.errstate(invalid="ignore", divide="ignore"):
            clk = (wj * dj).sum(-1, keepdims=True) / w_sum
            zj = (dj - clk) / (sig1[:, col] * np.sqrt(1.0 - wj / w_sum))
        z[:, col] = np.where(enough, zj, np.nan)
    return fit_gauss_markov(z, data.t_s)
