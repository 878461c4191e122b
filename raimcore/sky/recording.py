"""The recording sky source: RINEX observation + navigation -> :class:`~raimcore.sky.Sky`.

A scenario with ``source = "rinex"`` names an observation and a navigation file. The
pseudoranges of the chosen signals are corrected for the satellite clock (relativity, TGD),
the Klobuchar ionosphere and the troposphere (:mod:`raimcore.sky.spp`), so that every registered
algorithm sees the same kind of data as from a simulation: satellite positions and
pseudoranges whose only unknowns are the receiver position and one clock per system. Faults
are added to the real pseudoranges by the measure stage; the truth for the error columns is
the header position of the (static) station, or ``truth_ecef_m``.

Satellites with no usable ephemeris are left out and said so in the sky's notes.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..geometry import az_el, ecef_to_geodetic
from . import Sky
from .rinex import ObsFile, read_nav, read_obs
from .spp import SYSTEM_LETTER, Corrected, correct, solve

__all__ = ["recording_sky", "recording_keys", "load_recording", "receiver_ecef_m"]

#: Defaults for real data (scenario keys): code noise of a geodetic receiver at the zenith,
#: a 10-degree mask against multipath.
REAL_DATA_DEFAULTS = {"sigma_m": 1.0, "mask_deg": 10.0}


def _stamp(path, key: str) -> tuple[str, int, int]:
    """The cache key of a file (resolved path, time, size); ``key`` names it in errors."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{key}: RINEX file {str(path)!r} does not exist or is not a file")
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
    return _corrected(_stamp(obs, "obs"), _stamp(nav, "nav"), tuple(systems), tuple(signals))


def recording_keys(obs) -> dict:
    """Scenario keys that fit the recording ``obs`` (see
    :func:`raimcore.scenario.recording_scenario`): its name, GPS and BDS (those present),
    the whole recording at its own interval, and the real-data defaults."""
    from ..scenario import SYSTEMS  # the systems a scenario takes

    o = _read_obs(_stamp(obs, "obs"))
    systems = [s for s, letter in SYSTEM_LETTER.items() if s in SYSTEMS
               and any(n[0] == letter for n in o.sat_names)] or ["GPS"]
    t = o.t_gps_s - o.t_gps_s[0] if len(o.t_gps_s) else np.zeros(1)
    step = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    return {"name": Path(obs).name.split(".")[0],
            "description": f"recording {Path(obs).name}", "source": "rinex", "obs": str(obs),
            "systems": systems, "duration_s": float(t[-1]), "step_s": step,
            **REAL_DATA_DEFAULTS}


def receiver_ecef_m(s) -> np.ndarray:
    """(3,) the receiver position of a recording scenario: ``truth_ecef_m``, else the
    header position (zeros when the file has none)."""
    if s.truth_ecef_m:
        return np.array(s.truth_ecef_m, dtype=float)
    return np.array(_read_obs(_stamp(s.obs, "obs")).approx_pos_ecef_m, dtype=float)


def _window(t_rel, t0, duration, step) -> np.ndarray:
    """Indices of the epochs in [t0, t0 + duration], thinned to at least ``step`` apart."""
    keep = []
    last = -math.inf
    for k, tk in enumerate(t_rel):
        if t0 - 1e-6 <= tk <= t0 + duration + 1e-6 and tk >= last + step - 1e-6:
            keep.append(k)
            last = tk
    return np.array(keep, dtype=int)


def recording_sky(s) -> Sky:
    """The :class:`~raimcore.sky.Sky` of a ``source = "rinex"`` scenario ``s``: the epochs
    in its window, the satellites of its systems with a usable ephemeris (``s.sats`` when
    given), their positions and corrected pseudoranges, the station as the truth."""
    obs_file = _read_obs(_stamp(s.obs, "obs"))
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
    for f in s.faults:
        if f.sat not in names:
            raise ValueError(f"faults: satellite {f.sat!r} is not in this recording (with "
                             f"a usable ephemeris); choose from {', '.join(names)}")
    ix = np.ix_(rows, cols)
    t = t_rel[rows] - s.t_start_s
    if s.truth_ecef_m:
        truth = np.array(s.truth_ecef_m, dtype=float)
    elif np.any(obs_file.approx_pos_ecef_m):
        truth = obs_file.approx_pos_ecef_m
    else:
        sol = solve(corr, mask_deg=s.mask_deg).pos_ecef_m
        ok = np.isfinite(sol).all(-1)
        if not ok.any():
            raise ValueError(f"{s.obs}: no header position, no truth_ecef_m and no epoch "
                             "with a single-point solution: give truth_ecef_m")
        truth = np.median(sol[ok], axis=0)
        notes.append("no header position and no truth_ecef_m: truth is the median "
                     "single-point solution")
    sv = corr.pos_sv_ecef_m[ix]
    truth_e = np.broadcast_to(truth, (len(rows), 3)).copy()
    az, el = az_el(sv, truth_e)
    return Sky(t_s=t, sat_names=tuple(names), sys_idx=corr.sys_idx[cols],
               systems=tuple(corr.systems), pos_sv_ecef_m=sv, pos_rx_ecef_m=truth_e,
               vel_rx_ecef_mps=np.zeros_like(truth_e),
               h_rx_m=ecef_to_geodetic(truth_e)[2],
               range_m=np.linalg.norm(sv - truth_e[:, None, :], axis=-1), az_rad=az,
               el_rad=el, trackable=corr.tracked[ix] & corr.usable[ix], pr_m=corr.pr_m[ix],
               notes=tuple(notes))
