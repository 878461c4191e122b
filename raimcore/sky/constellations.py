"""GNSS constellations: nominal GPS, BeiDou-3, Galileo and GLONASS, YUMA and SEM almanacs,
Keplerian propagation.

Positions are Earth-centred Earth-fixed (WGS-84, CGCS2000, GTRF and PZ-90 treated as
identical here, which is well below the metre level for a simulator). Time ``t_s`` is
seconds from the constellation's reference epoch (for an almanac: seconds of the almanac
week in the system's own time scale). Each satellite carries its system's gravitational
constant and Earth rotation rate, so a mixed constellation propagates every satellite with
the constants of its own ICD.
"""

from __future__ import annotations

import functools
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import constants as k

__all__ = ["Constellation", "gps_nominal", "beidou_nominal", "galileo_nominal",
           "glonass_nominal", "read_yuma", "read_yuma_cached", "read_sem", "read_almanac",
           "read_almanac_cached", "combine", "SYSTEM_PREFIX", "builtin"]

#: Satellite-name prefix of each system (RINEX 3 convention), in the fixed order systems
#: are listed in (:attr:`Constellation.sys_names`).
SYSTEM_PREFIX = {"GPS": "G", "BDS": "C", "GAL": "E", "GLO": "R"}

# Galileo and GLONASS constants (kept here until raimcore.constants carries them).
GM_GAL_M3PS2 = 3.986004418e14  # Galileo OS SIS ICD Issue 2.0 (2021), 5.1.1 (GTRF GM)
OMEGA_E_GAL_RADPS = 7.2921151467e-5  # Galileo OS SIS ICD Issue 2.0, 5.1.1 (Earth rotation)
GM_GLO_M3PS2 = 3.986004418e14  # GLONASS ICD L1/L2 ed. 5.1 (2008), table 3.2 (PZ-90 fM)
OMEGA_E_GLO_RADPS = 7.292115e-5  # GLONASS ICD ed. 5.1 (2008), table 3.2 (PZ-90)
# Galileo OS Service Definition Document (OS SDD) Issue 1.1 (2019), section 2.1 (reference
# constellation): Walker 24/3/1, semi-major axis 29,599.8 km, inclination 56 deg.
GAL_A_M = 29_599.8e3
GAL_INC_RAD = math.radians(56.0)
# GLONASS ICD ed. 5.1 (2008), section 3.1 (constellation): 24 satellites in 3 planes 120 deg
# apart, 8 per plane 45 deg apart in argument of latitude, planes displaced 15 deg; altitude
# 19,100 km, inclination 64.8 deg, draconic period 11 h 15 min 44 s +- 5 s. a = 25,510 km
# gives a Keplerian period of 11 h 15 min 48.7 s (inside that tolerance), within 1 s of the
# 8 sidereal days / 17 revolutions of the real ground-track repeat (which the real orbit
# reaches with the shorter draconic period because its node regresses; no J2 here).
GLO_A_M = 25_510.0e3
GLO_INC_RAD = math.radians(64.8)
# SEM almanacs give the inclination as an offset from i0 = 0.30 semicircles (54 deg):
# IS-GPS-200, table 20-VI (almanac parameters) and the SEM description (CelesTrak,
# "Definition of a SEM almanac"; NAVCEN current.al3).
SEM_I0_SEMICIRCLES = 0.30

#: (GM, Earth rotation rate) of each system's ICD, used to propagate its satellites.
_EARTH = {
    "GPS": (k.GM_GPS_M3PS2, k.OMEGA_E_RADPS),
    "BDS": (k.GM_BDS_M3PS2, k.OMEGA_E_BDS_RADPS),
    "GAL": (GM_GAL_M3PS2, OMEGA_E_GAL_RADPS),
    "GLO": (GM_GLO_M3PS2, OMEGA_E_GLO_RADPS),
}

#: Systems whose almanacs are Keplerian (IS-GPS-200 table 20-IV form), i.e. readable from a
#: YUMA or SEM file. GLONASS almanacs are not (GLONASS ICD 5.1 almanac: longitude of the
#: first node crossing, draconic period and its rate, correction to the inclination, ...).
_KEPLERIAN_SYSTEMS = ("GPS", "BDS", "GAL")


@dataclass(frozen=True)
class Constellation:
    """Keplerian elements of a set of satellites, all arrays of shape ``(S,)``.

    Propagation follows IS-GPS-200 table 20-IV (almanac form, no harmonic corrections):
    ``Omega_k = Omega0 + (Omega_dot - omega_e) t_k - omega_e toa``, with each satellite's
    own ``gm_m3ps2`` (mean motion ``sqrt(gm / a^3)``) and ``omega_e_radps`` (the Earth
    rotation rate of its system's ICD: Galileo OS SIS ICD 5.1.1 and BDS ICD 5.2.4.10 use the
    same equation). ``omega_e_radps`` defaults to the GPS value for every satellite.
    """

    names: tuple[str, ...]
    systems: tuple[str, ...]  # per satellite: a key of SYSTEM_PREFIX ("GPS", "BDS", ...)
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
    omega_e_radps: np.ndarray | None = None  # Earth rotation rate per satellite

    def __post_init__(self):
        if len(set(self.names)) != len(self.names):
            raise ValueError("constellation satellite names must be unique")
        if self.omega_e_radps is None:
            object.__setattr__(self, "omega_e_radps",
                               np.full(len(self.names), k.OMEGA_E_RADPS))

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
        we = self.omega_e_radps
        om = self.omega0_rad + (self.omega_dot_radps - we) * tk - we * self.toa_s
        xp, yp = r * np.cos(u), r * np.sin(u)
        ci, si = np.cos(self.inc_rad), np.sin(self.inc_rad)
        co, so = np.cos(om), np.sin(om)
        return np.stack([xp * co - yp * ci * so, xp * so + yp * ci * co, yp * si], axis=-1)

    @property
    def sys_names(self) -> tuple[str, ...]:
        """Systems present, in a fixed order (GPS, BDS, GAL, GLO)."""
        return tuple(s for s in SYSTEM_PREFIX if s in self.systems)


_FIELDS = ("names", "systems", "sqrt_a", "ecc", "inc_rad", "omega0_rad", "omega_dot_radps",
           "argp_rad", "m0_rad", "toa_s", "gm_m3ps2", "healthy", "omega_e_radps")


def _circular(names, system, a_m, inc_rad, omega0_rad, u0_rad) -> Constellation:
    """Circular orbits of ``system`` (its GM and Earth rotation rate, see ``_EARTH``) with
    the longitude of the node ``omega0_rad`` and argument of latitude ``u0_rad`` at t = 0."""
    s = len(names)
    full = lambda v: np.broadcast_to(np.asarray(v, dtype=float), (s,)).copy()  # noqa: E731
    gm, we = _EARTH[system]
    return Constellation(tuple(names), (system,) * s, full(math.sqrt(a_m)), full(0.0),
                         full(inc_rad), full(omega0_rad), full(0.0), full(0.0), full(u0_rad),
                         full(0.0), full(gm), np.ones(s, dtype=bool), full(we))


def _walker(names, system, a_m, inc_rad, raan0_rad, slot_step_deg, plane_phase_deg):
    """A Walker 24/3/1 constellation: 3 planes 120 deg apart from ``raan0_rad``, 8 slots per
    plane ``slot_step_deg`` apart in argument of latitude (+-45 deg), and the equivalent slot
    of each next plane ``plane_phase_deg`` further (15 deg = F * 360 / T with F = 1)."""
    plane = np.repeat(np.arange(3), 8)
    slot = np.tile(np.arange(8), 3)
    return _circular(names, system, a_m, inc_rad, raan0_rad + np.radians(120.0 * plane),
                     np.radians(slot_step_deg * slot + plane_phase_deg * plane))


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
                     np.radians(u0))


def beidou_nominal() -> Constellation:
    """Nominal BeiDou-3: 24 MEO (Walker 24/3/1, 21,528 km, 55 deg), 3 IGSO, 3 GEO.

    Names follow the BDS convention loosely: GEO C01-C03 at 80, 110.5, 140 E; IGSO
    C06-C08 at 55 deg inclination sharing one ground track crossing the equator at 118 E;
    MEO C19-C42 (plane 1 first). Walker 24/3/1: planes 120 deg apart, 45 deg between slots,
    15 deg phase step between adjacent planes. Propagated with the CGCS2000 GM and Earth
    rotation rate (BDS-SIS-ICD-B1I 3.0, 5.2.4.10).
    """
    gm, we = _EARTH["BDS"]
    geo_lon = np.radians([80.0, 110.5, 140.0])
    geo_a = (gm / we**2) ** (1.0 / 3.0)  # geosynchronous: n = omega_e
    geo = _circular(["C01", "C02", "C03"], "BDS", geo_a, 0.0, geo_lon, 0.0)
    phase = np.radians([0.0, 120.0, 240.0])
    # Node crossing longitude = Omega0 + u0 for a geosynchronous orbit (see module doc).
    igso = _circular(["C06", "C07", "C08"], "BDS", geo_a, k.BDS_INC_RAD,
                     np.radians(118.0) - phase, phase)
    meo = _walker([f"C{19 + i:02d}" for i in range(24)], "BDS", k.WGS84_A_M + k.BDS_MEO_ALT_M,
                  k.BDS_INC_RAD, 0.0, 45.0, 15.0)
    return combine(geo, igso, meo)


def galileo_nominal() -> Constellation:
    """The Galileo reference constellation: Walker 56:24/3/1 at a = 29,599.8 km.

    Galileo OS SDD Issue 1.1 (2019), section 2.1: 24 slots in 3 planes (A, B, C) 120 deg
    apart, 8 slots per plane 45 deg apart, 15 deg phase step between adjacent planes,
    inclination 56 deg; the period is 14 h 04 min 41 s (17 revolutions in about 10
    sidereal days). Propagated with the GTRF GM and Earth rotation rate (OS SIS ICD 5.1.1).

    Named E01..E24 (E01-E08 plane A, E09-E16 plane B, E17-E24 plane C, in the direction of
    motion): this numbering is nominal, not the real SVID allocation, and the in-orbit
    spares are left out. The planes' RAAN at t = 0 (60, 180, 300 deg) is a free choice,
    made so that they lie between the BeiDou MEO planes (0, 120, 240 deg) rather than on
    them (the two inclinations differ by one degree only), and no slot starts within 2 deg
    of a GPS or BeiDou satellite.
    """
    return _walker([f"E{i:02d}" for i in range(1, 25)], "GAL", GAL_A_M, GAL_INC_RAD,
                   math.radians(60.0), 45.0, 15.0)


def glonass_nominal() -> Constellation:
    """The nominal 24-slot GLONASS constellation, named R01..R24 by slot number.

    GLONASS ICD ed. 5.1 (2008), section 3.1: 3 planes 120 deg apart, slots 1-8 in plane 1,
    9-16 in plane 2, 17-24 in plane 3; 45 deg of argument of latitude between adjacent slots
    of a plane, the equivalent slots of adjacent planes 15 deg apart; inclination 64.8 deg,
    altitude 19,100 km (``GLO_A_M`` = 25,510 km), period 11 h 15 min 44 s. The slot number
    grows against the direction of motion (slot N+1 trails slot N by 45 deg) and plane
    p+1's node lies 120 deg east of plane p's with its slots 15 deg ahead: the arrangement
    of the broadcast orbits in ``ESBC00DNK_R_20201770000_01D_MN.rnx`` (2020-06-25).
    Plane 1's RAAN at t = 0 (90 deg) is a free choice, made so that no slot starts within
    2 deg (seen from the Earth's centre) of a GPS, BeiDou or Galileo satellite. Propagated
    with the PZ-90 GM and Earth rotation rate (ICD table 3.2); no J2, so the node does not
    regress.
    """
    return _walker([f"R{i:02d}" for i in range(1, 25)], "GLO", GLO_A_M, GLO_INC_RAD,
                   math.radians(90.0), -45.0, 15.0)


def combine(*parts: Constellation) -> Constellation:
    """Concatenate constellations (names must stay unique)."""
    vals = []
    for f in _FIELDS:
        if f in ("names", "systems"):
            vals.append(tuple(x for p in parts for x in getattr(p, f)))
        else:
            vals.append(np.concatenate([np.asarray(getattr(p, f)) for p in parts]))
    return Constellation(*vals)


def _check_system(system, fmt: str) -> str:
    """``system`` for a Keplerian almanac reader, or a one-line ValueError."""
    if system not in _KEPLERIAN_SYSTEMS:
        raise ValueError(f"system must be one of {', '.join(_KEPLERIAN_SYSTEMS)} for a {fmt} "
                         f"almanac, got {system!r} (GLONASS almanacs are not Keplerian "
                         f"elements of this form)")
    return system


def _almanac_lines(path, fmt: str) -> tuple[Path, list[str]]:
    """The lines of an almanac file, or a ValueError naming it."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{fmt} almanac {str(path)!r} does not exist or is not a file")
    try:
        return path, path.read_text(encoding="ascii", errors="replace").splitlines()
    except OSError as exc:
        raise ValueError(f"{fmt} almanac {str(path)!r} cannot be read: "
                         f"{exc.strerror or exc}") from None


_YUMA_KEYS = {
    "id": "prn", "health": "health", "eccentricity": "ecc",
    "time of applicability(s)": "toa", "orbital inclination(rad)": "inc",
    "rate of right ascen(r/s)": "omega_dot", "sqrt(a)  (m 1/2)": "sqrt_a",
    "right ascen at week(rad)": "omega0", "argument of perigee(rad)": "argp",
    "mean anom(rad)": "m0", "af0(s)": "af0", "af1(s/s)": "af1", "week": "week",
}

#: What each almanac field allows: (lo, hi, lo_open, hi_open, integer, in words). Every
#: field must be a finite number besides. PRNs 1-63 (IS-GPS-200, tables 3-Ia and 3-Ib;
#: Galileo SVIDs are 1-36); eccentricity: an ellipse; toa: seconds of the week; inclination:
#: radians. The SEM-only fields: IS-GPS-200 URA index 0-15, health a 6-bit code stored as
#: an integer, inclination offset from 0.30 semicircles such that i is in [0, 1] semicircle.
_YUMA_RANGE = {
    "prn": (1, 63, False, False, True, "an integer PRN in [1, 63]"),
    "health": (0, 255, False, False, True, "an integer in [0, 255]"),
    "ecc": (0.0, 1.0, False, True, False, "a number in [0, 1) (an ellipse)"),
    "toa": (0.0, k.SECONDS_PER_WEEK, False, True, False, "a number of seconds in [0, 604800)"),
    "inc": (0.0, math.pi, False, False, False, "a number of radians in [0, pi]"),
    "sqrt_a": (0.0, None, True, False, False, "a finite number > 0 (m^1/2)"),
    "week": (0, None, False, False, True, "an integer >= 0"),
    "count": (1, None, False, False, True, "an integer number of records >= 1"),
    "svn": (0, None, False, False, True, "an integer >= 0"),
    "ura": (0, 15, False, False, True, "an integer URA index in [0, 15]"),
    "config": (0, None, False, False, True, "an integer >= 0"),
    "di_sc": (-SEM_I0_SEMICIRCLES, 1.0 - SEM_I0_SEMICIRCLES, False, False, False,
              "a number of semicircles in [-0.3, 0.7] (inclination 0.30 + offset in [0, 1] "
              "semicircle)"),
}


def _yuma_value(path, lineno: int, label: str, name: str, text: str) -> float:
    """One almanac field as a float, checked: finite, and within ``_YUMA_RANGE``."""
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


def _check_records(path, recs: list[dict], fmt: str) -> None:
    """PRNs unique and every orbit above the Earth's surface (records carry ``_line``)."""
    seen: dict[int, int] = {}
    for r in recs:
        prn = int(r["prn"])
        if prn in seen:
            raise ValueError(f"{path}:{r['_line']}: PRN {prn} appears twice (first at line "
                             f"{seen[prn]}); a {fmt} almanac has one record per satellite")
        seen[prn] = r["_line"]
        perigee_m = r["sqrt_a"] ** 2 * (1.0 - r["ecc"])
        if perigee_m <= k.WGS84_A_M:
            raise ValueError(f"{path}:{r['_line']}: PRN {prn}: sqrt(A) {r['sqrt_a']:g} m^1/2 "
                             f"with eccentricity {r['ecc']:g} puts the perigee "
                             f"{perigee_m / 1e3:,.0f} km from the Earth's centre, inside the "
                             f"Earth ({k.WGS84_A_M / 1e3:,.0f} km): not an orbit")


def _from_records(recs: list[dict], system: str) -> Constellation:
    """A Constellation of almanac records in radians (keys as in ``_YUMA_KEYS``)."""
    col = lambda key: np.array([r[key] for r in recs], dtype=float)  # noqa: E731
    gm, we = _EARTH[system]
    s = len(recs)
    names = tuple(f"{SYSTEM_PREFIX[system]}{int(r['prn']):02d}" for r in recs)
    return Constellation(names, (system,) * s, col("sqrt_a"), col("ecc"), col("inc"),
                         col("omega0"), col("omega_dot"), col("argp"), col("m0"), col("toa"),
                         np.full(s, gm), col("health") == 0, np.full(s, we))


def read_yuma(path, system: str = "GPS") -> Constellation:
    """Read a YUMA almanac; satellites are named ``<prefix><ID>`` (``G01`` for GPS).

    Parameters
    ----------
    path : the YUMA file (NAVCEN ``current.alm``, CelesTrak ``*.alm``).
    system : ``"GPS"`` (default), ``"GAL"`` or ``"BDS"``. A YUMA record's ``ID:`` is a plain
        number, so the file cannot say which system it describes: the caller does. The
        system sets the names (``E01`` for ``"GAL"``) and the GM and Earth rotation rate
        used to propagate; ``toa``/``week`` are then in that system's time scale (GST week,
        BDT week). The European GNSS Service Centre publishes Galileo almanacs as XML, not
        YUMA (www.gsc-europa.eu/gsc-products/almanac); a Galileo YUMA file is one exported
        by a receiver or planning tool. GLONASS almanacs are not Keplerian in this form and
        are refused.

    Every field is checked where it is read: a finite number, eccentricity in [0, 1),
    sqrt(A) > 0 with the whole orbit above the Earth's surface, PRN 1-63 and unique,
    toa within the week, inclination in [0, pi].

    Raises
    ------
    ValueError naming the file, the line, the field and what it allows, for a missing or
    unreadable file, a malformed, truncated or out-of-range record; or naming ``system``.
    """
    system = _check_system(system, "YUMA")
    path, text = _almanac_lines(path, "YUMA")
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
    _check_records(path, recs, "YUMA")
    return _from_records(recs, system)


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


#: The eight lines of each SEM record (after the 2-line file header), in file order: what
#: the line holds (for messages) and its fields (semicircle quantities end in ``_sc``). SEM
#: description: CelesTrak "Definition of a SEM almanac"; NAVCEN ``current.al3``;
#: IS-GPS-200 table 20-VI.
_SEM_LINES = (
    ("the PRN number", (("PRN", "prn"),)),
    ("the SVN number", (("SVN", "svn"),)),
    ("the average URA number", (("URA", "ura"),)),
    ("eccentricity, inclination offset (semicircles) and rate of right ascension "
     "(semicircles/s)", (("eccentricity", "ecc"), ("inclination offset", "di_sc"),
                         ("rate of right ascension", "omega_dot_sc"))),
    ("sqrt(A) (m^1/2), right ascension at week and argument of perigee (semicircles)",
     (("sqrt(A)", "sqrt_a"), ("right ascension at week", "omega0_sc"),
      ("argument of perigee", "argp_sc"))),
    ("mean anomaly (semicircles), af0 (s) and af1 (s/s)",
     (("mean anomaly", "m0_sc"), ("af0", "af0"), ("af1", "af1"))),
    ("the satellite health", (("health", "health"),)),
    ("the satellite configuration", (("configuration", "config"),)),
)


def read_sem(path, system: str = "GPS") -> Constellation:
    """Read a SEM almanac (NAVCEN's ``current.al3``, CelesTrak's ``*.al3``; the format
    GNSSTk and Trimble's planning software read).

    The layout: a header line (number of records, a title), a line with the almanac week
    and time of applicability (s), then per satellite, records usually separated by a blank
    line: PRN; SVN; average URA; eccentricity, inclination offset, rate of right ascension;
    sqrt(A), right ascension at week, argument of perigee; mean anomaly, af0, af1; health;
    configuration. Angles are in semicircles (times pi -> radians) and the inclination is
    an offset from i0 = 0.30 semicircle (54 deg), so ``i = (0.30 + offset) * pi``.

    Returns the same :class:`Constellation` as :func:`read_yuma` would for the same
    almanac (radians, names ``G<PRN>``, healthy when health is 0). ``system`` is as in
    :func:`read_yuma` (the format is GPS's; the others only name and propagate).

    Raises
    ------
    ValueError naming the file, the line and what was expected there, for a missing or
    unreadable file, a malformed, truncated or out-of-range header or record, a record count
    that differs from the header's, a PRN twice, an orbit inside the Earth; or naming
    ``system``.
    """
    system = _check_system(system, "SEM")
    path, text = _almanac_lines(path, "SEM")
    lines = [(n, ln.split()) for n, ln in enumerate(text, 1) if ln.strip()]
    if not lines:
        raise ValueError(f"{path}: empty file, expected a SEM almanac")
    lineno, tok = lines[0]
    count = _yuma_value(path, lineno, "number of records", "count", tok[0])
    if len(lines) < 2:
        raise ValueError(f"{path}:{lineno}: SEM header ends here; expected a line with the "
                         f"week number and the time of applicability next")
    lineno, tok = lines[1]
    if len(tok) != 2:
        raise ValueError(f"{path}:{lineno}: expected the week number and the time of "
                         f"applicability (2 numbers), got {' '.join(tok)[:60]!r}")
    _yuma_value(path, lineno, "week", "week", tok[0])
    toa = _yuma_value(path, lineno, "time of applicability", "toa", tok[1])
    recs = []
    body = lines[2:]
    for start in range(0, len(body), len(_SEM_LINES)):
        chunk = body[start:start + len(_SEM_LINES)]
        rec = {"_line": chunk[0][0], "toa": toa}
        for i, (what, fields) in enumerate(_SEM_LINES):
            if i >= len(chunk):
                raise ValueError(f"{path}:{chunk[-1][0]}: SEM record {len(recs) + 1} (line "
                                 f"{rec['_line']}) ends here; expected {what} next "
                                 f"(truncated file?)")
            lineno, tok = chunk[i]
            if len(tok) != len(fields):
                n = len(fields)
                raise ValueError(f"{path}:{lineno}: expected {what} ({n} number"
                                 f"{'s' if n > 1 else ''}) in SEM record {len(recs) + 1}, "
                                 f"got {' '.join(tok)[:60]!r}")
            for (label, name), text_val in zip(fields, tok, strict=True):
                rec[name] = _yuma_value(path, lineno, label, name, text_val)
        recs.append(rec)
    if len(recs) != count:
        raise ValueError(f"{path}:{lines[0][0]}: the SEM header announces {int(count)} "
                         f"records, the file has {len(recs)}")
    for r in recs:  # semicircles -> radians (IS-GPS-200 table 20-VI)
        r["inc"] = (SEM_I0_SEMICIRCLES + r["di_sc"]) * math.pi
        for sc, rad in (("omega_dot_sc", "omega_dot"), ("omega0_sc", "omega0"),
                        ("argp_sc", "argp"), ("m0_sc", "m0")):
            r[rad] = r[sc] * math.pi
    _check_records(path, recs, "SEM")
    return _from_records(recs, system)


def _almanac_format(path) -> str:
    """``"YUMA"`` or ``"SEM"`` from the file's first non-blank line (not its name)."""
    path, text = _almanac_lines(path, "YUMA or SEM")
    for lineno, line in enumerate(text, 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("*") or s.lower().startswith("id:"):
            return "YUMA"
        if re.fullmatch(r"\d+", s.split()[0]):
            return "SEM"
        raise ValueError(f"{path}:{lineno}: neither a YUMA almanac (records start with "
                         f"'****') nor a SEM almanac (first line: number of records and a "
                         f"title); got {s[:60]!r}")
    raise ValueError(f"{path}: empty file, not a YUMA or SEM almanac")


def read_almanac(path, system: str = "GPS") -> Constellation:
    """Read a YUMA or a SEM almanac, told apart by content (a YUMA file starts with a
    ``****`` record header, a SEM file with its record count), whatever its suffix.

    ``system`` as in :func:`read_yuma`. Raises the ValueError of :func:`read_yuma` or
    :func:`read_sem`, or one naming the file and line when it is neither.
    """
    system = _check_system(system, "YUMA or SEM")
    fmt = _almanac_format(path)
    return read_yuma(path, system) if fmt == "YUMA" else read_sem(path, system)


def read_almanac_cached(path, system: str = "GPS") -> Constellation:
    """:func:`read_almanac`, cached like :func:`read_yuma_cached` (path, size, time)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return read_almanac(p, system)  # raises, naming the file
    return _read_almanac_stamped(str(p.resolve()), st.st_mtime_ns, st.st_size, system)


@functools.lru_cache(maxsize=8)
def _read_almanac_stamped(path: str, mtime_ns: int, size: int, system: str) -> Constellation:
    return read_almanac(path, system)


#: The nominal constellation of each system.
_NOMINAL = {"GPS": gps_nominal, "BDS": beidou_nominal, "GAL": galileo_nominal,
            "GLO": glonass_nominal}


def builtin(systems) -> Constellation:
    """The nominal constellation(s) for ``systems`` (a subset of ``("GPS", "BDS", "GAL",
    "GLO")``), combined in the order given."""
    parts = []
    for s in systems:
        if s not in _NOMINAL:
            raise ValueError(f"systems entries must be GPS, BDS, GAL or GLO, got {s!r}")
        parts.append(_NOMINAL[s]())
    if not parts:
        raise ValueError(f"systems must name at least one of {', '.join(_NOMINAL)}")
    return combine(*parts)
