"""Receiver trajectories: static, straight line, and an aircraft flight profile.

Moving trajectories are integrated on the ellipsoid from a speed / heading / climb-rate
profile (north and east velocity change latitude and longitude through the meridian and
prime-vertical radii), so a long flight keeps its altitude instead of leaving a tangent
plane.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .. import constants as k
from .._validate import check_positive, check_range
from ..geometry import enu_rotation, geodetic_to_ecef

__all__ = ["Trajectory", "static", "straight_line", "flight_profile", "TRAJECTORY_KINDS"]

TRAJECTORY_KINDS = ("static", "line", "flight")


@dataclass(frozen=True)
class Trajectory:
    """Receiver truth: times ``(E,)``, positions ``(E, 3)`` and velocities ``(E, 3)`` (ECEF)."""

    t_s: np.ndarray
    pos_ecef_m: np.ndarray
    vel_ecef_mps: np.ndarray
    lat_rad: np.ndarray
    lon_rad: np.ndarray
    h_m: np.ndarray


def _check_start(lat_deg, lon_deg, h_m):
    return (math.radians(check_range("lat_deg", lat_deg, -90.0, 90.0)),
            math.radians(check_range("lon_deg", lon_deg, -180.0, 360.0)),
            check_range("height_m", h_m, -1000.0, 1.0e6))


def _integrate(t_s, lat0, lon0, h0, speed_mps, heading_rad, climb_mps, sub=10) -> Trajectory:
    """Integrate a horizontal-speed / heading / climb-rate profile on the ellipsoid.

    The profile functions are sampled ``sub`` times per epoch step and integrated with the
    trapezoidal rule.
    """
    t = np.asarray(t_s, dtype=float)
    if t.size < 2:
        tf = t
    else:
        tf = np.linspace(t[0], t[-1], (t.size - 1) * sub + 1)
    v, psi, vu = speed_mps(tf), heading_rad(tf), climb_mps(tf)
    ve, vn = v * np.sin(psi), v * np.cos(psi)
    lat = np.empty_like(tf)
    lon = np.empty_like(tf)
    h = np.empty_like(tf)
    lat[0], lon[0], h[0] = lat0, lon0, h0
    dt = np.diff(tf)
    # Explicit trapezoid with radii at the previous point: errors are centimetres over hours.
    for i in range(tf.size - 1):
        s = math.sin(lat[i])
        rn = k.WGS84_A_M / math.sqrt(1.0 - k.WGS84_E2 * s * s)
        rm = rn * (1.0 - k.WGS84_E2) / (1.0 - k.WGS84_E2 * s * s)
        h[i + 1] = h[i] + 0.5 * (vu[i] + vu[i + 1]) * dt[i]
        lat[i + 1] = lat[i] + 0.5 * (vn[i] + vn[i + 1]) * dt[i] / (rm + h[i])
        lon[i + 1] = lon[i] + 0.5 * (ve[i] + ve[i + 1]) * dt[i] / ((rn + h[i]) * math.cos(lat[i]))
    idx = np.arange(t.size) * (sub if t.size >= 2 else 1)
    lat, lon, h = lat[idx], lon[idx], h[idx]
    pos = geodetic_to_ecef(lat, lon, h)
    enu_vel = np.stack([ve[idx], vn[idx], vu[idx]], axis=-1)
    rot = enu_rotation(lat, lon)
    vel = np.einsum("eji,ej->ei", rot, enu_vel)
    return Trajectory(t, pos, vel, lat, lon, h)


def static(t_s, lat_deg: float, lon_deg: float, height_m: float = 0.0) -> Trajectory:
    """A receiver at rest."""
    lat, lon, h = _check_start(lat_deg, lon_deg, height_m)
    t = np.asarray(t_s, dtype=float)
    pos = np.broadcast_to(geodetic_to_ecef(lat, lon, h), (t.size, 3)).copy()
    full = lambda v: np.full(t.size, v)  # noqa: E731
    return Trajectory(t, pos, np.zeros((t.size, 3)), full(lat), full(lon), full(h))


def straight_line(t_s, lat_deg: float, lon_deg: float, height_m: float = 0.0,
                  speed_mps: float = 100.0, heading_deg: float = 90.0,
                  climb_mps: float = 0.0) -> Trajectory:
    """Constant speed, heading and climb rate from a start point."""
    lat, lon, h = _check_start(lat_deg, lon_deg, height_m)
    v = check_range("speed_mps", speed_mps, 0.0, 1.0e4)
    psi = math.radians(check_range("heading_deg", heading_deg, -360.0, 360.0))
    vu = check_range("climb_mps", climb_mps, -1.0e3, 1.0e3)
    const = lambda c: (lambda tt: np.full_like(tt, c))  # noqa: E731
    return _integrate(t_s, lat, lon, h, const(v), const(psi), const(vu))


def flight_profile(t_s, lat_deg: float, lon_deg: float, height_m: float = 100.0,
                   heading_deg: float = 45.0, cruise_speed_mps: float = 230.0,
                   cruise_alt_m: float = 10000.0, climb_s: float = 900.0,
                   turn_start_s: float = 2400.0, turn_rate_dps: float = 1.5,
                   turn_deg: float = 180.0) -> Trajectory:
    """An aircraft flight: accelerating climb, cruise, a banked turn, cruise again.

    Phases (seed 001's profile, parameters documented here): from ``t = 0`` the speed rises
    linearly from 80 m/s to ``cruise_speed_mps`` while climbing at a constant rate to
    ``cruise_alt_m`` over ``climb_s`` seconds; cruise; from ``turn_start_s`` a
    coordinated turn at ``turn_rate_dps`` (bank angle atan(v * rate / g), about 31 deg for
    the defaults) through ``turn_deg``; then straight cruise on the new heading.
    """
    lat, lon, h = _check_start(lat_deg, lon_deg, height_m)
    climb_s = check_positive("climb_s", climb_s)
    v1 = check_positive("cruise_speed_mps", cruise_speed_mps)
    rate = math.radians(check_positive("turn_rate_dps", turn_rate_dps))
    turn = math.radians(check_range("turn_deg", turn_deg, 0.0, 3600.0))
    psi0 = math.radians(heading_deg)
    t0 = float(np.asarray(t_s, dtype=float)[0]) if np.size(t_s) else 0.0
    v0 = min(80.0, v1)
    climb = (cruise_alt_m - h) / climb_s

    def speed(tt):
        f = np.clip((tt - t0) / climb_s, 0.0, 1.0)
        return v0 + (v1 - v0) * f

    def heading(tt):
        dt = np.clip(tt - t0 - turn_start_s, 0.0, turn / rate)
        return psi0 + rate * dt

    def climb_rate(tt):
        return np.where(tt - t0 < climb_s, climb, 0.0)

    return _integrate(t_s, lat, lon, h, speed, heading, climb_rate)
