"""The simulated sky source: a constellation (nominal or a YUMA almanac) seen from a
trajectory (static, straight line, flight profile)."""

from __future__ import annotations

import math

import numpy as np

from ..lsq import clock_columns, geometry_rows
from . import Sky
from .constellations import builtin, read_yuma_cached
from .trajectories import flight_profile, static, straight_line

__all__ = ["simulated_sky", "epoch_times"]


def epoch_times(duration_s: float, step_s: float) -> np.ndarray:
    """(E,) epoch times ``0, step_s, ...`` up to ``duration_s`` inclusive."""
    n_ep = int(math.floor(duration_s / step_s + 1e-9)) + 1
    return np.arange(n_ep, dtype=float) * step_s


def simulated_sky(s) -> Sky:
    """Satellites of ``s.systems`` (``s.sats``, renamed by ``s.rename``) seen from the
    scenario's trajectory at every epoch."""
    const = (builtin(s.systems) if s.constellation == "nominal"
             else read_yuma_cached(s.constellation))
    const = const if set(const.systems) <= set(s.systems) else const.subset(
        [n for n, sy in zip(const.names, const.systems, strict=True) if sy in s.systems])
    if not const.names:
        raise ValueError(f"constellation {s.constellation!r} has no satellite of "
                         f"{', '.join(s.systems)}")
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
               range_m=rng_m, az_rad=az, el_rad=el, trackable=healthy.copy())
