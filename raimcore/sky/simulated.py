"""The simulated sky source: a constellation seen from a trajectory (static, straight line,
flight profile).

The constellation is the nominal one of each of the scenario's systems (GPS, BeiDou,
Galileo, GLONASS: :func:`~raimcore.sky.constellations.builtin`) or a YUMA or SEM almanac
(:func:`almanac_constellation`). Each system keeps its own receiver clock (``Sky.sys_idx``).
"""

from __future__ import annotations

import math

import numpy as np

from ..constants import BDS_GEO_RADIUS_M, BDS_MEO_ALT_M, GPS_SQRT_A, WGS84_A_M
from ..lsq import clock_columns, geometry_rows
from . import Sky
from .constellations import GAL_A_M, Constellation, builtin, read_almanac_cached
from .trajectories import flight_profile, static, straight_line

__all__ = ["simulated_sky", "epoch_times", "almanac_system", "almanac_constellation",
           "ALMANAC_ORBITS_M"]

#: Nominal semi-major axes (m) of the systems whose almanacs are YUMA or SEM files. Those
#: formats do not say which system they describe; the orbits do: GPS 26,560 km (SPS PS 5th
#: ed., table 3.1-1), BeiDou MEO 27,906 km and GEO/IGSO 42,164 km (BDS ICD B1I 3.0, 3.1),
#: Galileo 29,600 km (OS SDD 1.1, 2.1). GLONASS almanacs are not of this form.
ALMANAC_ORBITS_M = (("GPS", GPS_SQRT_A**2), ("BDS", WGS84_A_M + BDS_MEO_ALT_M),
                    ("BDS", BDS_GEO_RADIUS_M), ("GAL", GAL_A_M))
#: An almanac belongs to a system when its median semi-major axis is within this share of
#: the system's (the nearest two, GPS and BeiDou MEO, are 5 % apart).
ALMANAC_ORBIT_TOL = 0.02
_SYSTEM_NAME = {"GPS": "GPS", "BDS": "BeiDou", "GAL": "Galileo", "GLO": "GLONASS"}


def almanac_system(const: Constellation) -> str | None:
    """The system (``"GPS"``, ``"BDS"`` or ``"GAL"``) whose orbits an almanac describes,
    from its median semi-major axis (:data:`ALMANAC_ORBITS_M`), or None when it is none of
    them."""
    a_m = float(np.median(np.asarray(const.sqrt_a, dtype=float) ** 2))
    for system, nominal_m in ALMANAC_ORBITS_M:
        if abs(a_m / nominal_m - 1.0) <= ALMANAC_ORBIT_TOL:
            return system
    return None


def almanac_constellation(path, systems) -> Constellation:
    """The YUMA or SEM almanac ``path`` as a constellation of its own system (satellite
    names and propagation constants of GPS, BeiDou or Galileo, told by its orbits: see
    :func:`almanac_system`), read once per file version
    (:func:`~raimcore.sky.constellations.read_almanac_cached`).

    Raises
    ------
    ValueError naming the file: unreadable or malformed (the reader's message), orbits of
    no system with YUMA/SEM almanacs, or an almanac of a system not in ``systems``.
    """
    const = read_almanac_cached(path)  # read as GPS's: the format's own system
    system = almanac_system(const)
    a_km = float(np.median(const.sqrt_a**2)) / 1e3
    if system is None:
        known = ", ".join(f"{_SYSTEM_NAME[s]} {a / 1e3:,.0f} km" for s, a in ALMANAC_ORBITS_M)
        raise ValueError(f"{path}: cannot tell which system this almanac describes: its "
                         f"median semi-major axis {a_km:,.0f} km is within "
                         f"{ALMANAC_ORBIT_TOL:.0%} of none of {known}")
    if system not in systems:
        raise ValueError(f"{path} is a {_SYSTEM_NAME[system]} almanac (median semi-major "
                         f"axis {a_km:,.0f} km): it has no satellite of systems "
                         f"{', '.join(systems)} (add \"{system}\")")
    return const if system == "GPS" else read_almanac_cached(path, system)


def epoch_times(duration_s: float, step_s: float) -> np.ndarray:
    """(E,) epoch times ``0, step_s, ...`` up to ``duration_s`` inclusive."""
    n_ep = int(math.floor(duration_s / step_s + 1e-9)) + 1
    return np.arange(n_ep, dtype=float) * step_s


def simulated_sky(s) -> Sky:
    """Satellites of ``s.systems`` (``s.sats``, renamed by ``s.rename``) seen from the
    scenario's trajectory at every epoch: the nominal constellations, or the almanac
    ``s.constellation`` (one system; the sky's notes name the systems it leaves empty)."""
    notes = []
    if s.constellation == "nominal":
        const = builtin(s.systems)
    else:
        const = almanac_constellation(s.constellation, s.systems)
        empty = [x for x in s.systems if x not in const.systems]
        if empty:
            notes.append(f"constellation {s.constellation} is a {_SYSTEM_NAME[const.systems[0]]}"
                         f" almanac: no satellite of {', '.join(empty)} in this run")
    if s.sats:
        const = const.subset(list(s.sats))
    if s.rename:
        const = const.renamed(dict(s.rename))
    t = epoch_times(s.duration_s, s.step_s)
    if s.trajectory == "static":
        traj = static(t, s.lat_deg, s.lon_deg, s.height_m)
    elif s.trajectory == "line":
        traj = straight_line(t, s.lat_deg, s.lon_deg, s.height_m, s.speed_mps, s.heading_deg,
                             s.climb_mps)
    else:
        traj = flight_profile(t, s.lat_deg, s.lon_deg, s.height_m, s.heading_deg,
                              s.cruise_speed_mps, s.cruise_alt_m, s.climb_s, s.turn_start_s,
                              s.turn_rate_dps, s.turn_deg)
    sv = const.positions_ecef_m(s.t_start_s + t)
    systems = const.sys_names
    sys_idx = np.array([systems.index(x) for x in const.systems], dtype=int)
    cc = clock_columns(sys_idx, len(systems))
    h_enu, rng_m = geometry_rows(sv, traj.pos_ecef_m, cc, frame="enu")
    el = np.arcsin(np.clip(-h_enu[..., 2], -1.0, 1.0))
    az = np.mod(np.arctan2(-h_enu[..., 0], -h_enu[..., 1]), 2 * np.pi)
    healthy = np.broadcast_to(np.asarray(const.healthy, dtype=bool)[None, :], el.shape)
    return Sky(t_s=t, sat_names=tuple(const.names), sys_idx=sys_idx, systems=systems,
               pos_sv_ecef_m=sv, pos_rx_ecef_m=traj.pos_ecef_m,
               vel_rx_ecef_mps=traj.vel_ecef_mps, h_rx_m=np.asarray(traj.h_m, dtype=float),
               range_m=rng_m, az_rad=az, el_rad=el, trackable=healthy.copy(),
               notes=tuple(notes))
