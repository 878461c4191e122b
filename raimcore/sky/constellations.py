"""GNSS constellations: nominal GPS and BeiDou-3, YUMA almanacs, Keplerian propagation.

Positions are Earth-centred Earth-fixed (WGS-84 / CGCS2000 treated as identical here, which
is well below the metre level for a simulator). Time ``t_s`` is seconds from the
constellation's reference epoch (for an almanac: GPS seconds of the almanac week).
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import constants as k

__all__ = ["Constellation", "gps_nominal", "beidou_nominal", "read_yuma", "read_yuma_cached",
           "combine", "SYSTEM_PREFIX", "builtin"]

#: Satellite-name prefix of each system (RINEX 3 convention).
SYSTEM_PREFIX = {"GPS": "G", "BDS": "C"}


@dataclass(frozen=True)
class Constellation:
    """Keplerian elements of a set of satellites, all arrays of shape ``(S,)``.

    Propagation follows IS-GPS-200 table 20-IV (almanac form, no harmonic corrections):
    ``Omega_k = Omega0 + (Omega_dot - omega_e) t_k - omega_e toa``.
    """

    names: tuple[str, ...]
    systems: tuple[str, ...]  # per satellite: "GPS" or "BDS"
    sqrt_a: np.ndarray  # m^0.5
    ecc: np.ndarray
    inc_rad: np.ndarray
    omega0_rad: np.ndarray  # longitude of ascending node at the weekly epoch
    omega_dot_radps: np.ndarray
    argp_rad: np.ndarray  # argument of perigee
    m0_rad: np.ndarray  # mean anomaly at toa
    toa_s: np.ndarray
    gm_m3ps2: np.ndarray
    healthy: np.ndarray

    def __post_init__(self):
        if len(set(self.names)) != len(self.names):
            raise ValueError("constellation satellite names must be unique")

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, names) -> Constellation:
        """The satellites called ``names`` (in that order); unknown names raise."""
        index = {n: i for i, n in enumerate(self.names)}
        missing = [n for n in names if n not in index]
        if missing:
            raise ValueError(f"sats: unknown satellite(s) {', '.join(missing)}; this "
                             f"constellation has {', '.join(self.names)}")
        return self._take(np.array([index[n] for n in names], dtype=int))

    def renamed(self, mapping: dict[str, str]) -> Constellation:
        """A copy with satellites renamed (``{"G05": "G19"}``)."""
        unknown = [n for n in mapping if n not in self.names]
        if unknown:
            raise ValueError(f"rename: unknown satellite(s) {', '.join(unknown)}")
        names = tuple(mapping.get(n, n) for n in self.names)
        return Constellation(names, *(getattr(self, f) for f in _FIELDS[1:]))

    def _take(self, idx: np.ndarray) -> Constellation:
        vals = [tuple(np.asarray(getattr(self, f), dtype=object)[idx]) if f in ("names", "systems")
                else np.asarray(getattr(self, f))[idx] for f in _FIELDS]
        return Constellation(*vals)

    def positions_ecef_m(self, t_s) -> np.ndarray:
        """Satellite ECEF positions at times ``t_s`` (shape ``(E,)``) -> ``(E, S, 3)``."""
        t = np.asarray(t_s, dtype=float)[..., None]
        a = self.sqrt_a**2
        n0 = np.sqrt(self.gm_m3ps2 / a**3)
        tk = t - self.toa_s
        mk = self.m0_rad + n0 * tk
        # Newton on Kepler's equation M = E - e sin E. From E0 = M it converges within 10
        # steps for GNSS orbits (e < 0.1); a more eccentric almanac orbit starts from
        # E0 = pi, which converges for every e < 1, with more steps (Charles & Tatum 1998).
        if np.any(self.ecc >= 0.1):
            turns = mk - np.mod(mk, 2.0 * np.pi)  # solve for M in [0, 2 pi), add them back
            mw = mk - turns
            ek = np.where(self.ecc >= 0.1, np.pi, mw)
            for _ in range(50):
                ek = ek - (ek - self.ecc * np.sin(ek) - mw) / (1.0 - self.ecc * np.cos(ek))
            ek = ek + turns
        else:
            ek = mk.copy()
            for _ in range(10):
                ek = ek - (ek - self.ecc * np.sin(ek) - mk) / (1.0 - self.ecc * np.cos(ek))
        nu = np.arctan2(np.sqrt(1.0 - self.ecc**2) * np.sin(ek), np.cos(ek) - self.ecc)
        u = nu + self.argp_rad
        r = a * (1.0 - self.ecc * np.cos(ek))
        om = (self.omega0_rad + (self.omega_dot_radps - k.OMEGA_E_RADPS) * tk
              - k.OMEGA_E_RADPS * self.toa_s)
        xp, yp = r * np.cos(u), r * np.sin(u)
        ci, si = np.cos(self.inc_rad), np.sin(self.inc_rad)
        co, so = np.cos(om), np.sin(om)
        return np.stack([xp * co - yp * ci * so, xp * so + yp * ci * co, yp * si], axis=-1)

    @property
    def sys_names(self) -> tuple[str, ...]:
        """Systems present, in a fixed order (GPS first)."""
        return tuple(s for s in ("GPS", "BDS") if s in self.systems)


_FIELDS = ("names", "systems", "sqrt_a", "ecc", "inc_rad", "omega0_rad", "omega_dot_radps",
           "argp_rad", "m0_rad", "toa_s", "gm_m3ps2", "healthy")


def _circular(names, system, a_m, inc_rad, omega0_rad, u0_rad, gm) -> Constellation:
    s = len(names)
    full = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (s,)).copy()  # noqa: E731
    return Constellation(tuple(names), (system,) * s, full(math.sqrt(a_m)), full(0.0),
                         full(inc_rad), full(omega0_rad), full(0.0), full(0.0), full(u0_rad),
                         full(0.0), full(gm), np.ones(s, dtype=bool))


# GPS SPS Performance Standard, 5th ed. (2020), table 3.1-1: plane RAAN and the arguments of
# latitude of slots 1-4 (degrees), as quoted in issue 2.
_GPS_PLANES = {
    "A": (272.847, (268.126, 161.786, 11.676, 41.806)),
    "B": (332.847, (80.956, 173.336, 309.976, 204.376)),
    "C": (32.847, (111.876, 11.796, 339.666, 241.556)),
    "D": (92.847, (135.226, 265.446, 35.156, 167.356)),
    "E": (152.847, (197.046, 302.596, 66.066, 333.686)),
    "F": (212.847, (238.886, 345.226, 105.206, 135.346)),
}


def gps_nominal() -> Constellation:
    """The nominal 24-slot GPS constellation (SPS PS table 3.1-1), named G01..G24.

    G01..G04 are slots A1..A4, G05..G08 B1..B4, ..., G21..G24 F1..F4. The tabulated RAAN
    is used as the longitude of the ascending node at t = 0; nodal regression is ignored
    (about 0.04 deg/day, irrelevant over a scenario).
    """
    raan, u0 = [], []
    for plane_raan, slots in _GPS_PLANES.values():
        raan += [plane_raan] * 4
        u0 += list(slots)
    names = [f"G{i:02d}" for i in range(1, 25)]
    return _circular(names, "GPS", k.GPS_SQRT_A**2, k.GPS_INC_RAD, np.radians(raan),
                     np.radians(u0), k.GM_GPS_M3PS2)


def beidou_nominal() -> Constellation:
    """Nominal BeiDou-3: 24 MEO (Walker 24/3/1, 21,528 km, 55 deg), 3 IGSO, 3 GEO.

    Names follow the BDS convention loosely: GEO C01-C03 at 80, 110.5, 140 E; IGSO
    C06-C08 at 55 deg inclination sharing one ground track crossing the equator at 118 E;
    MEO C19-C42 (plane 1 first). Walker 24/3/1: planes 120 deg apart, 45 deg between slots,
    15 deg phase step between adjacent planes.
    """
    gm = k.GM_BDS_M3PS2
    geo_lon = np.radians([80.0, 110.5, 140.0])
    geo_a = (gm / k.OMEGA_E_RADPS**2) ** (1.0 / 3.0)  # geosynchronous: n = omega_e
    geo = _circular(["C01", "C02", "C03"], "BDS", geo_a, 0.0, geo_lon, 0.0, gm)
    phase = np.radians([0.0, 120.0, 240.0])
    # Node crossing longitude = Omega0 + u0 for a geosynchronous orbit (see module doc).
    igso = _circular(["C06", "C07", "C08"], "BDS", geo_a, k.BDS_INC_RAD,
                     np.radians(118.0) - phase, phase, gm)
    plane = np.repeat(np.arange(3), 8)
    slot = np.tile(np.arange(8), 3)
    meo = _circular([f"C{19 + i:02d}" for i in range(24)], "BDS",
                    k.WGS84_A_M + k.BDS_MEO_ALT_M, k.BDS_INC_RAD,
                    np.radians(120.0 * plane), np.radians(45.0 * slot + 15.0 * plane), gm)
    return combine(geo, igso, meo)


def combine(*parts: Constellation) -> Constellation:
    """Concatenate constellations (names must stay unique)."""
    vals = []
    for f in _FIELDS:
        if f in ("names", "systems"):
            vals.append(tuple(x for p in parts for x in getattr(p, f)))
        else:
            vals.append(np.concatenate([np.asarray(getattr(p, f)) for p in parts]))
    return Constellation(*vals)


_YUMA_KEYS = {
    "id": "prn", "health": "health", "eccentricity": "ecc",
    "time of applicability(s)": "toa", "orbital inclination(rad)": "inc",
    "rate of right ascen(r/s)": "omega_dot", "sqrt(a)  (m 1/2)": "sqrt_a",
    "right ascen at week(rad)": "omega0", "argument of perigee(rad)": "argp",
    "mean anom(rad)": "m0", "af0(s)": "af0", "af1(s/s)": "af1", "week": "week",
}

#: What each YUMA field allows: (lo, hi, lo_open, hi_open, integer, in words). Every field
#: must be a finite number besides. PRNs 1-63 (IS-GPS-200, tables 3-Ia and 3-Ib);
#: eccentricity: an ellipse; toa: seconds of the week; inclination: radians.
_YUMA_RANGE = {
    "prn": (1, 63, False, False, True, "an integer PRN in [1, 63]"),
    "health": (0, 255, False, False, True, "an integer in [0, 255]"),
    "ecc": (0.0, 1.0, False, True, False, "a number in [0, 1) (an ellipse)"),
    "toa": (0.0, k.SECONDS_PER_WEEK, False, True, False, "a number of seconds in [0, 604800)"),
    "inc": (0.0, math.pi, False, False, False, "a number of radians in [0, pi]"),
    "sqrt_a": (0.0, None, True, False, False, "a finite number > 0 (m^1/2)"),
    "week": (0, None, False, False, True, "an integer >= 0"),
}


def _yuma_value(path, lineno: int, label: str, name: str, text: str) -> float:
    """One YUMA field as a float, checked: finite, and within ``_YUMA_RANGE``."""
    try:
        x = float(text)
    except ValueError:
        raise ValueError(f"{path}:{lineno}: field {label!r} is not a number: "
                         f"{text.strip()!r}") from None
    lo, hi, lo_open, hi_open, integer, words = _YUMA_RANGE.get(
        name, (None, None, False, False, False, "a finite number"))
    bad = not math.isfinite(x) or (integer and not x.is_integer())
    bad = bad or (lo is not None and (x < lo or (lo_open and x == lo)))
    bad = bad or (hi is not None and (x > hi or (hi_open and x == hi)))
    if bad:
        raise ValueError(f"{path}:{lineno}: field {label!r} must be {words}, got "
                         f"{text.strip()!r}")
    return x


def read_yuma(path) -> Constellation:
    """Read a GPS YUMA almanac; satellites are named ``G<PRN>``.

    Every field is checked where it is read: a finite number, eccentricity in [0, 1),
    sqrt(A) > 0 with the whole orbit above the Earth's surface, PRN 1-63 and unique,
    toa within the week, inclination in [0, pi].

    Raises
    ------
    ValueError naming the file, the line, the field and what it allows, for a missing or
    unreadable file, a malformed, truncated or out-of-range record.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"YUMA almanac {str(path)!r} does not exist or is not a file")
    try:
        text = path.read_text(encoding="ascii", errors="replace").splitlines()
    except OSError as exc:
        raise ValueError(f"YUMA almanac {str(path)!r} cannot be read: "
                         f"{exc.strerror or exc}") from None
    recs, cur = [], None
    for lineno, line in enumerate(text, 1):
        if line.startswith("****"):
            if cur is not None:
                recs.append(cur)
            cur = {"_line": lineno}
            continue
        if not line.strip():
            continue
        if cur is None or ":" not in line:
            raise ValueError(f"{path}:{lineno}: expected a YUMA record line 'Key: value', "
                             f"got {line.strip()[:60]!r}")
        key, val = line.split(":", 1)
        key = re.sub(r"\s+$", "", key.lower())
        name = _YUMA_KEYS.get(key)
        if name is None:
            raise ValueError(f"{path}:{lineno}: unknown YUMA field {key!r}")
        cur[name] = _yuma_value(path, lineno, key, name, val)
    if cur is not None:
        recs.append(cur)
    need = set(_YUMA_KEYS.values())
    for r in recs:
        missing = need - set(r)
        if missing:
            raise ValueError(f"{path}:{r['_line']}: YUMA record is missing "
                             f"{', '.join(sorted(missing))} (truncated file?)")
    if not recs:
        raise ValueError(f"{path}: no YUMA records found")
    seen: dict[int, int] = {}
    for r in recs:
        prn = int(r["prn"])
        if prn in seen:
            raise ValueError(f"{path}:{r['_line']}: PRN {prn} appears twice (first at line "
                             f"{seen[prn]}); a YUMA almanac has one record per satellite")
        seen[prn] = r["_line"]
        perigee_m = r["sqrt_a"] ** 2 * (1.0 - r["ecc"])
        if perigee_m <= k.WGS84_A_M:
            raise ValueError(f"{path}:{r['_line']}: PRN {prn}: sqrt(A) {r['sqrt_a']:g} m^1/2 "
                             f"with eccentricity {r['ecc']:g} puts the perigee "
                             f"{perigee_m / 1e3:,.0f} km from the Earth's centre, inside the "
                             f"Earth ({k.WGS84_A_M / 1e3:,.0f} km): not an orbit")
    col = lambda key: np.array([r[key] for r in recs])  # noqa: E731
    names = tuple(f"G{int(r['prn']):02d}" for r in recs)
    return Constellation(names, ("GPS",) * len(recs), col("sqrt_a"), col("ecc"), col("inc"),
                         col("omega0"), col("omega_dot"), col("argp"), col("m0"), col("toa"),
                         np.full(len(recs), k.GM_GPS_M3PS2), col("health") == 0)


def read_yuma_cached(path) -> Constellation:
    """:func:`read_yuma`, cached on the file's resolved path, size and modification time
    (a scenario reads its almanac when it is checked and again when it is run)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return read_yuma(p)  # raises, naming the file
    return _read_yuma_stamped(str(p.resolve()), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=8)
def _read_yuma_stamped(path: str, mtime_ns: int, size: int) -> Constellation:
    return read_yuma(path)


def builtin(systems) -> Constellation:
    """The nominal constellation(s) for ``systems`` (a subset of ``("GPS", "BDS")``)."""
    parts = []
    for s in systems:
        if s == "GPS":
            parts.append(gps_nominal())
        elif s == "BDS":
            parts.append(beidou_nominal())
        else:
            raise ValueError(f"systems entries must be GPS or BDS, got {s!r}")
    if not parts:
        raise ValueError("systems must name at least one of GPS, BDS")
    return combine(*parts)
