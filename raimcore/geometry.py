"""WGS-84 coordinate conversions, line-of-sight geometry and dilution of precision.

All functions are vectorised: batch axes first, components last, e.g. ``(..., 3)`` for a
position and ``(..., n_sat, 3)`` for satellite positions. Angles are radians inside.
"""

from __future__ import annotations

import numpy as np

from .constants import WGS84_A_M, WGS84_B_M, WGS84_E2

__all__ = [
    "geodetic_to_ecef",
    "ecef_to_geodetic",
    "enu_rotation",
    "ecef_to_enu",
    "enu_to_ecef",
    "los_enu",
    "az_el",
    "dops",
]


def geodetic_to_ecef(lat_rad, lon_rad, h_m) -> np.ndarray:
    """Geodetic latitude, longitude (rad) and ellipsoidal height (m) to ECEF (m).

    Returns an array of shape ``broadcast(lat, lon, h).shape + (3,)``.

    References
    ----------
    NIMA TR8350.2, eq. 4-14.
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    h = np.asarray(h_m, dtype=float)
    sin_lat = np.sin(lat)
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * sin_lat**2)  # prime vertical radius
    x = (n + h) * np.cos(lat) * np.cos(lon)
    y = (n + h) * np.cos(lat) * np.sin(lon)
    z = (n * (1.0 - WGS84_E2) + h) * sin_lat
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(pos_ecef_m) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ECEF (m), shape ``(..., 3)``, to geodetic latitude, longitude (rad) and height (m).

    Bowring's closed form followed by two fixed-point refinements: sub-millimetre from the
    Earth's surface to geostationary altitude.

    References
    ----------
    Bowring, B. R. (1976), Survey Review 23(181), 323-327.
    """
    p_ecef = np.asarray(pos_ecef_m, dtype=float)
    x, y, z = p_ecef[..., 0], p_ecef[..., 1], p_ecef[..., 2]
    lon = np.arctan2(y, x)
    p = np.hypot(x, y)
    ep2 = (WGS84_A_M**2 - WGS84_B_M**2) / WGS84_B_M**2
    theta = np.arctan2(z * WGS84_A_M, p * WGS84_B_M)
    lat = np.arctan2(z + ep2 * WGS84_B_M * np.sin(theta) ** 3,
                     p - WGS84_E2 * WGS84_A_M * np.cos(theta) ** 3)
    with np.errstate(divide="ignore", invalid="ignore"):  # the Earth's centre has no latitude
        lat, h = _refine(lat, p, z)
    return lat, lon, h


def _refine(lat, p, z):
    for _ in range(2):
        n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
        h = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.cos(lat) - n,
                     np.abs(z) - WGS84_B_M)
        lat = np.arctan2(z, p * (1.0 - WGS84_E2 * n / (n + h)))
    n = WGS84_A_M / np.sqrt(1.0 - WGS84_E2 * np.sin(lat) ** 2)
    h = np.where(np.abs(np.cos(lat)) > 1e-9, p / np.cos(lat) - n, np.abs(z) - WGS84_B_M)
    return lat, h


def enu_rotation(lat_rad, lon_rad) -> np.ndarray:
    """Rotation matrix from ECEF to local East-North-Up, shape ``(..., 3, 3)``.

    ``enu = R @ (ecef - ecef_ref)``; rows are the E, N, U unit vectors in ECEF.
    """
    lat = np.asarray(lat_rad, dtype=float)
    lon = np.asarray(lon_rad, dtype=float)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    zero = np.zeros_like(sl * so)
    e = np.stack(np.broadcast_arrays(-so, co, zero), axis=-1)
    nrt = np.stack(np.broadcast_arrays(-sl * co, -sl * so, cl), axis=-1)
    u = np.stack(np.broadcast_arrays(cl * co, cl * so, sl), axis=-1)
    return np.stack([e, nrt, u], axis=-2)


def ecef_to_enu(pos_ecef_m, ref_ecef_m) -> np.ndarray:
    """ECEF points ``(..., 3)`` to ENU (m) about reference point(s) ``ref_ecef_m``."""
    ref = np.asarray(ref_ecef_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(ref)
    rot = enu_rotation(lat, lon)
    d = np.asarray(pos_ecef_m, dtype=float) - ref
    return np.einsum("...ij,...j->...i", rot, d)


def enu_to_ecef(enu_m, ref_ecef_m) -> np.ndarray:
    """ENU offsets ``(..., 3)`` about ``ref_ecef_m`` back to ECEF (m)."""
    ref = np.asarray(ref_ecef_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(ref)
    rot = enu_rotation(lat, lon)
    return ref + np.einsum("...ji,...j->...i", rot, np.asarray(enu_m, dtype=float))


def los_enu(pos_sv_ecef_m, pos_rx_ecef_m) -> tuple[np.ndarray, np.ndarray]:
    """Unit lines of sight receiver -> satellite in ENU, and geometric ranges.

    Parameters
    ----------
    pos_sv_ecef_m : array, shape ``(..., n_sat, 3)``
    pos_rx_ecef_m : array, shape ``(..., 3)``

    Returns
    -------
    u_enu : array ``(..., n_sat, 3)``; range_m : array ``(..., n_sat)``
    """
    rx = np.asarray(pos_rx_ecef_m, dtype=float)
    d = np.asarray(pos_sv_ecef_m, dtype=float) - rx[..., None, :]
    rng = np.linalg.norm(d, axis=-1)
    lat, lon, _ = ecef_to_geodetic(rx)
    rot = enu_rotation(lat, lon)
    u = np.einsum("...ij,...sj->...si", rot, d) / rng[..., None]
    return u, rng


def az_el(pos_sv_ecef_m, pos_rx_ecef_m) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (from north, clockwise) and elevation (rad), each ``(..., n_sat)``."""
    u, _ = los_enu(pos_sv_ecef_m, pos_rx_ecef_m)
    az = np.mod(np.arctan2(u[..., 0], u[..., 1]), 2.0 * np.pi)
    el = np.arcsin(np.clip(u[..., 2], -1.0, 1.0))
    return az, el


def dops(h_enu) -> dict[str, np.ndarray]:
    """Dilution of precision from ENU geometry rows ``(..., m, n)`` (n >= 4).

    Columns 0..2 are E, N, U, the rest are clock terms. Returns ``gdop``, ``pdop``,
    ``hdop``, ``vdop`` and ``tdop`` (first clock), each of shape ``(...)``; NaN where the
    geometry is singular.
    """
    h = np.asarray(h_enu, dtype=float)
    ntn = np.einsum("...mi,...mj->...ij", h, h)
    with np.errstate(invalid="ignore"):
        try:
            q = np.linalg.inv(ntn)
        except np.linalg.LinAlgError:
            q = np.full_like(ntn, np.nan)
            flat = ntn.reshape(-1, *ntn.shape[-2:])
            out = q.reshape(flat.shape)
            for k, a in enumerate(flat):
                if np.linalg.matrix_rank(a) == a.shape[-1]:
                    out[k] = np.linalg.inv(a)
    d = np.diagonal(q, axis1=-2, axis2=-1)
    return {
        "gdop": np.sqrt(np.sum(d, axis=-1)),
        "pdop": np.sqrt(d[..., 0] + d[..., 1] + d[..., 2]),
        "hdop": np.sqrt(d[..., 0] + d[..., 1]),
        "vdop": np.sqrt(d[..., 2]),
        "tdop": np.sqrt(d[..., 3]),
    }
