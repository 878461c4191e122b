"""Broadcast ephemerides: satellite position and clock of GPS (LNAV) and BeiDou (D1/D2).

Everything is vectorised over any batch shape: pass arrays of ephemeris parameters (one
record per element, e.g. ``(E, S)`` after :meth:`Ephemerides.select`) and transmission
times of the same shape.

References
----------
IS-GPS-200N, 20.3.3.4.3 (table 20-IV: user algorithm for ephemeris determination) and
20.3.3.3.3.1 (satellite clock correction, relativistic term, TGD).
BDS-SIS-ICD-B1I 3.0, 5.2.4.12 (table 5-11: MEO/IGSO, and the GEO rotation) and 5.2.4.10
(constants: CGCS2000 GM and Earth rotation rate); BDT = GPST - 14 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import (
    C_MPS,
    GM_BDS_M3PS2,
    GM_GPS_M3PS2,
    OMEGA_E_BDS_RADPS,
    OMEGA_E_RADPS,
    SECONDS_PER_WEEK,
)
from .rinex import BDS_WEEK0_GPS_WEEK, BDT_MINUS_GPST_S

__all__ = ["Ephemerides", "from_nav", "sat_pos_clock", "is_bds_geo", "MAX_AGE_S"]

#: Largest |t - toe| at which a record is used (s): GPS records are valid 4 h around toe
#: (fit interval), BeiDou records are broadcast hourly (1-h updates, use within 2 h).
MAX_AGE_S = {"G": 7200.0, "C": 3900.0}

# Column of each parameter in the RINEX record values (af0 af1 af2, then 4 per line).
_COL = {"af0": 0, "af1": 1, "af2": 2, "iode": 3, "crs": 4, "dn": 5, "m0": 6, "cuc": 7,
        "e": 8, "cus": 9, "sqrt_a": 10, "toe": 11, "cic": 12, "omega0": 13, "cis": 14,
        "i0": 15, "crc": 16, "omega": 17, "omega_dot": 18, "idot": 19, "week": 21,
        "health": 24, "tgd": 25}


def is_bds_geo(prn) -> np.ndarray:
    """BeiDou GEO satellites: C01-C05 and C59-C63 (BDS-2 and BDS-3 GEO slots)."""
    prn = np.asarray(prn)
    return (prn <= 5) | (prn >= 59)


@dataclass(frozen=True)
class Ephemerides:
    """Struct of arrays, one element per broadcast record (any shape ``B``).

    ``system`` is "G" or "C"; times ``toc_gps_s`` and ``toe_gps_s`` are absolute GPS
    seconds (BeiDou records converted from BDT); ``toe_sow`` is the time of ephemeris in
    seconds of the system's own week (the Earth-rotation term uses it). ``tgd_s`` is the
    group delay of the L1 C/A (GPS TGD) or B1I (BDS TGD1) signal; ``healthy`` is bool.
    """

    sat: np.ndarray
    system: np.ndarray
    prn: np.ndarray
    toc_gps_s: np.ndarray
    toe_gps_s: np.ndarray
    toe_sow: np.ndarray
    af0: np.ndarray
    af1: np.ndarray
    af2: np.ndarray
    crs: np.ndarray
    dn: np.ndarray
    m0: np.ndarray
    cuc: np.ndarray
    e: np.ndarray
    cus: np.ndarray
    sqrt_a: np.ndarray
    cic: np.ndarray
    omega0: np.ndarray
    cis: np.ndarray
    i0: np.ndarray
    crc: np.ndarray
    omega: np.ndarray
    omega_dot: np.ndarray
    idot: np.ndarray
    tgd_s: np.ndarray
    healthy: np.ndarray

    def take(self, idx) -> Ephemerides:
        """Records at (fancy) index ``idx``; the result has ``idx``'s shape."""
        return Ephemerides(**{k: getattr(self, k)[idx] for k in self.__dataclass_fields__})

    def __len__(self) -> int:
        return len(self.sat)

    def select(self, sat_names, t_gps_s) -> tuple[Ephemerides, np.ndarray]:
        """For each epoch and satellite, the healthy record with the nearest toe.

        Parameters
        ----------
        sat_names : (S,) names; t_gps_s : (E,) times (GPS s).

        Returns
        -------
        eph : Ephemerides of shape (E, S) (arbitrary records where none is usable).
        usable : (E, S) bool, a healthy record within ``MAX_AGE_S`` of the epoch exists.
        """
        t = np.asarray(t_gps_s, dtype=float)
        s_n = len(sat_names)
        idx = np.zeros((t.size, s_n), dtype=int)
        usable = np.zeros((t.size, s_n), dtype=bool)
        for k, name in enumerate(sat_names):
            rec = np.flatnonzero((self.sat == name) & self.healthy)
            if rec.size == 0:
                continue
            age = np.abs(t[:, None] - self.toe_gps_s[rec][None, :])
            best = np.argmin(age, axis=1)
            idx[:, k] = rec[best]
            usable[:, k] = age[np.arange(t.size), best] <= MAX_AGE_S.get(name[0], 7200.0)
        return self.take(idx), usable


def from_nav(nav) -> Ephemerides:
    """All GPS and BeiDou records of a :class:`~raimcore.sky.rinex.NavFile`, one array each."""
    parts = []
    for letter, (sats, toc, vals) in nav.records.items():
        if letter not in "GC":
            continue
        col = {k: vals[:, j] for k, j in _COL.items()}
        week = col["week"]
        if letter == "C":
            # BDT week -> GPS seconds: BDT 0 is GPS week 1356 + 14 s (ICD 4.2).
            toe = (week + BDS_WEEK0_GPS_WEEK) * SECONDS_PER_WEEK + col["toe"] - BDT_MINUS_GPST_S
        else:
            toe = week * SECONDS_PER_WEEK + col["toe"]
        # The toc is exact; fix a week roll-over between toc and toe (toe within 1/2 week).
        toe = toe + SECONDS_PER_WEEK * np.round((toc - toe) / SECONDS_PER_WEEK)
        ok = np.isfinite(vals[:, :22]).all(axis=1) & (col["health"] == 0)
        parts.append(dict(
            sat=sats, system=np.full(len(sats), letter), prn=np.array([int(s[1:]) for s in sats]),
            toc_gps_s=toc, toe_gps_s=toe, toe_sow=col["toe"], af0=col["af0"],
            af1=col["af1"], af2=col["af2"], crs=col["crs"], dn=col["dn"], m0=col["m0"],
            cuc=col["cuc"], e=col["e"], cus=col["cus"], sqrt_a=col["sqrt_a"],
            cic=col["cic"], omega0=col["omega0"], cis=col["cis"], i0=col["i0"],
            crc=col["crc"], omega=col["omega"], omega_dot=col["omega_dot"],
            idot=col["idot"], tgd_s=np.nan_to_num(col["tgd"]), healthy=ok))
    if not parts:
        raise ValueError(f"{nav.path}: no GPS or BeiDou navigation records")
    return Ephemerides(**{k: np.concatenate([p[k] for p in parts])
                          for k in Ephemerides.__dataclass_fields__})


def sat_pos_clock(eph: Ephemerides, t_gps_s) -> tuple[np.ndarray, np.ndarray]:
    """Satellite position (ECEF at time ``t``) and clock offset at GPS time ``t``.

    Parameters
    ----------
    eph : records, shape ``B``; t_gps_s : times, shape ``B`` (GPS s; the transmission time).

    Returns
    -------
    pos_ecef_m : (B, 3) in the Earth-fixed frame at ``t`` (WGS-84 / CGCS2000).
    clock_s : (B,) satellite clock offset incl. the relativistic term, minus TGD (s):
        a pseudorange is corrected by ``+ c * clock_s``.
    """
    t = np.asarray(t_gps_s, dtype=float)
    bds = eph.system == "C"
    gm = np.where(bds, GM_BDS_M3PS2, GM_GPS_M3PS2)
    we = np.where(bds, OMEGA_E_BDS_RADPS, OMEGA_E_RADPS)
    a = eph.sqrt_a**2
    tk = t - eph.toe_gps_s  # IS-GPS-200 table 20-IV: t_k = t - t_oe
    n = np.sqrt(gm / a**3) + eph.dn
    m = eph.m0 + n * tk
    ecc_anom = m.copy()
    for _ in range(10):  # Kepler's equation M = E - e sin E
        ecc_anom = m + eph.e * np.sin(ecc_anom)
    nu = np.arctan2(np.sqrt(1.0 - eph.e**2) * np.sin(ecc_anom), np.cos(ecc_anom) - eph.e)
    phi = nu + eph.omega
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    u = phi + eph.cus * s2 + eph.cuc * c2
    r = a * (1.0 - eph.e * np.cos(ecc_anom)) + eph.crs * s2 + eph.crc * c2
    inc = eph.i0 + eph.idot * tk + eph.cis * s2 + eph.cic * c2
    xp, yp = r * np.cos(u), r * np.sin(u)
    geo = bds & is_bds_geo(eph.prn)
    # MEO/IGSO (and GPS): Omega = Omega0 + (Omega_dot - we) tk - we toe; GEO (BDS ICD
    # 5.2.4.12): Omega = Omega0 + Omega_dot tk - we toe, then R_Z(we tk) R_X(-5 deg).
    big_omega = eph.omega0 + (eph.omega_dot - np.where(geo, 0.0, we)) * tk - we * eph.toe_sow
    co, so, ci, si = np.cos(big_omega), np.sin(big_omega), np.cos(inc), np.sin(inc)
    x = xp * co - yp * ci * so
    y = xp * so + yp * ci * co
    z = yp * si
    if np.any(geo):
        f = np.radians(-5.0)
        yg = y * np.cos(f) + z * np.sin(f)  # R_X(-5 deg)
        zg = -y * np.sin(f) + z * np.cos(f)
        ang = we * tk  # R_Z(we tk)
        xg = x * np.cos(ang) + yg * np.sin(ang)
        yg2 = -x * np.sin(ang) + yg * np.cos(ang)
        x, y, z = np.where(geo, xg, x), np.where(geo, yg2, y), np.where(geo, zg, z)
    dt = t - eph.toc_gps_s
    # Relativistic correction F e sqrt(A) sin E, F = -2 sqrt(GM) / c^2 (IS-GPS-200
    # 20.3.3.3.3.1; BDS ICD 5.2.4.10 with the CGCS2000 GM).
    rel = -2.0 * np.sqrt(gm) / C_MPS**2 * eph.e * eph.sqrt_a * np.sin(ecc_anom)
    clock = eph.af0 + eph.af1 * dt + eph.af2 * dt**2 + rel - eph.tgd_s
    return np.stack([x, y, z], axis=-1), clock
