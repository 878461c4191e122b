"""Broadcast ephemerides: satellite position and clock of GPS (LNAV), BeiDou (D1/D2),
Galileo (I/NAV, F/NAV) and GLONASS (FDMA L1/L2 state vectors).

Everything is vectorised over any batch shape: pass arrays of ephemeris parameters (one
record per element, e.g. ``(E, S)`` after :meth:`Ephemerides.select`) and transmission
times of the same (or a broadcastable) shape.

Time scales. All times are absolute GPS seconds. BeiDou records are converted from BDT
(BDT = GPST - 14 s). Galileo System Time starts aligned with GPS time (its week 0 is GPS
week 1024 and RINEX 3 writes the Galileo week on the GPS week count), so GST is used as
GPST; the GST-GPST offset (GGTO, a few ns: ``GAGP`` in the navigation header) is absorbed
by the receiver clock of the Galileo system. GLONASS records are stamped in UTC(SU): the
navigation reader converts their ``toc`` to GPS seconds with the leap seconds, and this
module takes that ``toc`` as given; tau_c (GLONASS time - UTC(SU), ns) is likewise left to
the GLONASS receiver clock.

Frames. GPS positions are in WGS-84, BeiDou in CGCS2000, Galileo in GTRF and GLONASS in
PZ-90.11 (broadcast since 2014); all are aligned to the ITRF at the centimetre level, far
below the metres of single-point positioning, so no transformation is applied (the
PZ-90.02 -> PZ-90.11 and PZ-90.11 -> ITRF offsets are centimetres).

References
----------
IS-GPS-200N, 20.3.3.4.3 (table 20-IV: user algorithm for ephemeris determination) and
20.3.3.3.3.1 (satellite clock correction, relativistic term, TGD).
BDS-SIS-ICD-B1I 3.0, 5.2.4.12 (table 5-11: MEO/IGSO, and the GEO rotation) and 5.2.4.10
(constants: CGCS2000 GM and Earth rotation rate); BDT = GPST - 14 s.
Galileo OS SIS ICD 2.0 (2021): 5.1.1 (ephemeris algorithm and constants), 5.1.4 (clock
correction), 5.1.5 (broadcast group delay for single-frequency users), 5.1.12 (SISA index).
GLONASS ICD ed. 5.1 (2008): 3.3.1.4 (FDMA carriers), 4.4 (immediate data: t_b, tau_n,
gamma_n; table 4.4: F_T),
appendix A.3.1.2 (4th-order Runge-Kutta propagation of the state vector).
RINEX 3.05 (IGS/RTCM 2020), appendix: the GPS, Galileo, GLONASS and BeiDou navigation
message record tables.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

from ..constants import (
    A_E_GLO_M,
    C_MPS,
    GM_BDS_M3PS2,
    GM_GAL_M3PS2,
    GM_GLO_M3PS2,
    GM_GPS_M3PS2,
    J2_GLO,
    OMEGA_E_BDS_RADPS,
    OMEGA_E_GAL_RADPS,
    OMEGA_E_GLO_RADPS,
    OMEGA_E_RADPS,
    SECONDS_PER_WEEK,
)
from .rinex import BDS_WEEK0_GPS_WEEK, BDT_MINUS_GPST_S

__all__ = ["Ephemerides", "from_nav", "ephemeris_notes", "sat_pos_clock", "is_bds_geo",
           "sisa_index_to_m", "MAX_AGE_S"]

#: Largest |t - toe| at which a record is used (s), by system letter:
#: GPS records are valid 4 h around toe (fit interval), used within 2 h;
#: BeiDou records are broadcast hourly (1-h updates), used within 65 min;
#: Galileo I/NAV batches are refreshed every 10 min and fitted for 4 h, used within 3 h
#: (RTKLIB 2.4.2 ``MAXDTOE_GAL``);
#: GLONASS state vectors come every 30 min (tb at 15 and 45 min past the hour, GLONASS
#: ICD 5.1, 4.4) and are meant for the 30-min interval around tb; used within 20 min, so the
#: nominal +-15 min plus some slack for a late record (RTKLIB allows 30 min, but then a
#: missing record silently doubles the propagation span and its error).
MAX_AGE_S = {"G": 7200.0, "C": 3900.0, "E": 10800.0, "R": 1200.0}

# Column of each parameter in the RINEX record values (af0 af1 af2, then 4 per line) of the
# Keplerian systems (RINEX 3.05 GPS, Galileo and BeiDou record tables): the first 20 are
# common; col 20 is GPS "codes on L2", Galileo "data sources", BeiDou spare; col 23
# is the SV accuracy / SISA (m); col 24 the health; col 25 TGD (GPS), TGD1 B1I (BDS) or
# BGD E5a/E1 (Galileo); col 26 BGD E5b/E1 (Galileo).
_COL = {"af0": 0, "af1": 1, "af2": 2, "iode": 3, "crs": 4, "dn": 5, "m0": 6, "cuc": 7,
        "e": 8, "cus": 9, "sqrt_a": 10, "toe": 11, "cic": 12, "omega0": 13, "cis": 14,
        "i0": 15, "crc": 16, "omega": 17, "omega_dot": 18, "idot": 19, "data_sources": 20,
        "week": 21, "accuracy": 23, "health": 24, "tgd": 25, "bgd_e5b": 26}
# What the orbit and clock of a Keplerian record need (absent -> the record is rejected).
_KEPLER_NEEDS = ("af0", "af1", "af2", "crs", "dn", "m0", "cuc", "e", "cus", "sqrt_a", "toe",
                 "cic", "omega0", "cis", "i0", "crc", "omega", "omega_dot", "idot", "week",
                 "health", "tgd")
# GLONASS (RINEX 3.05 GLONASS record table; RINEX 2.11 has the same first four lines):
# -tau_n, +gamma_n, t_k; X, Xdot, Xacc, health; Y, ..., frequency number; Z, ..., age;
# (3.05 only) status flags, delta tau L1/L2, URAI F_T, health flags. Positions in km.
_GCOL = {"af0": 0, "af1": 1, "x": 3, "vx": 4, "ax": 5, "health": 6, "y": 7, "vy": 8,
         "ay": 9, "fcn": 10, "z": 11, "vz": 12, "az": 13, "urai": 17}
_GLO_NEEDS = ("af0", "af1", "x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az", "health",
              "fcn")
# GLONASS ICD ed. 5.1, table 4.4: accuracy F_T (m) by index 0..14 (15: not given).
_GLO_FT_M = np.array([1.0, 2.0, 2.5, 4.0, 5.0, 7.0, 10.0, 12.0, 14.0, 16.0, 32.0, 64.0, 128.0,
                      256.0, 512.0])
_GLO_STEP_S = 60.0  # largest Runge-Kutta step (GLONASS ICD A.3.1.2 uses steps of minutes)
_GLO_MAX_SPAN_S = 7200.0  # a state vector is not propagated further (NaN beyond)


def is_bds_geo(prn) -> np.ndarray:
    """BeiDou GEO satellites: C01-C05 and C59-C63 (BDS-2 and BDS-3 GEO slots)."""
    prn = np.asarray(prn)
    return (prn <= 5) | (prn >= 59)


def sisa_index_to_m(index) -> np.ndarray:
    """Galileo SISA index (0..255) to metres, Galileo OS SIS ICD 2.0, 5.1.12: 0-49 by 1 cm
    from 0, 50-74 by 2 cm from 0.5 m, 75-99 by 4 cm from 1 m, 100-125 by 16 cm from 2 m;
    126-254 (spare) and 255 (NAPA, no accuracy prediction available) give NaN.

    RINEX 3 navigation files already hold SISA in metres (e.g. index 107 written as 3.12);
    this decodes the raw index of a message or a RINEX 4 reader.

    >>> sisa_index_to_m([0, 49, 50, 75, 107, 125, 255]).round(2).tolist()
    [0.0, 0.49, 0.5, 1.0, 3.12, 6.0, nan]
    """
    n = np.asarray(index, dtype=float)
    return np.select([n < 0, n < 50, n < 75, n < 100, n < 126],
                     [np.nan, 0.01 * n, 0.5 + 0.02 * (n - 50), 1.0 + 0.04 * (n - 75),
                      2.0 + 0.16 * (n - 100)], np.nan)


@dataclass(frozen=True)
class Ephemerides:
    """Struct of arrays, one element per broadcast record (any shape ``B``).

    ``system`` is "G", "C", "E" or "R"; times ``toc_gps_s`` and ``toe_gps_s`` are absolute
    GPS seconds (BeiDou records converted from BDT; for GLONASS both are t_b);
    ``toe_sow`` is the time of ephemeris in seconds of the system's own week (the
    Earth-rotation term uses it; NaN for GLONASS). ``af0 af1 af2`` are the clock
    polynomial: for GLONASS ``af0 = -tau_n`` and ``af1 = +gamma_n`` as RINEX stores them,
    ``af2 = 0``. The Keplerian elements are NaN for GLONASS.

    ``tgd_s`` is the group delay of the signal used: the L1 C/A (GPS TGD), B1I (BDS TGD1)
    or E1 (Galileo BGD(E1, E5b) for an I/NAV record, BGD(E1, E5a) for an F/NAV one); 0 for
    GLONASS (tau_n refers to L1). ``tgd2_s`` is the record's second group delay field:
    BDS TGD2 (B2I), Galileo BGD(E1, E5b); NaN for GPS (that field is the IODC) and
    GLONASS (see :func:`raimcore.sky.spp.group_delay_s` for other signals).
    ``healthy`` is bool: the fields the orbit and clock need
    are present and the health flags of the signal are 0 (see :func:`from_nav`).

    ``ura_m`` (B,) is the broadcast accuracy (m): the GPS URA and BeiDou URA as RINEX
    writes them (metres), the Galileo SISA (metres; NaN for NAPA), the GLONASS F_T of
    table 4.4 when the record carries it (RINEX 3.05), else NaN. ``fcn`` (B,) int is the
    GLONASS frequency channel k (0 for the other systems). ``pos_glo_m``,
    ``vel_glo_mps``, ``acc_glo_mps2`` (B, 3) are the GLONASS state vector at t_b and its
    lunisolar acceleration (PZ-90.11, Earth-fixed; NaN for the other systems).
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
    tgd2_s: np.ndarray
    healthy: np.ndarray
    ura_m: np.ndarray
    fcn: np.ndarray
    pos_glo_m: np.ndarray
    vel_glo_mps: np.ndarray
    acc_glo_mps2: np.ndarray

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
    """The GPS, BeiDou, Galileo and GLONASS records of a
    :class:`~raimcore.sky.rinex.NavFile`, one array each.

    A record is ``healthy`` when the fields its orbit and clock need are present (blank
    optional fields, e.g. a BeiDou spare, do not matter) and its health flags are 0: the
    GPS health field, the BeiDou SatH1, the GLONASS health flag (MSB of B_n), and for
    Galileo the SV health bits of the signal the E1 user follows (E1-B DVS and HS of an
    I/NAV record; E5a DVS and HS of an F/NAV record). For a Galileo satellite with I/NAV
    records, its F/NAV records are left out: their clock refers to E5a/E1, not to E1
    alone (OS SIS ICD 5.1.5). :func:`ephemeris_notes` names every record not used.

    Raises
    ------
    ValueError when the file has no record of these systems.
    """
    return _parse(nav)[0]


def ephemeris_notes(nav, systems: str = "GCER") -> tuple[str, ...]:
    """One note per satellite and reason for the records :func:`from_nav` does not use,
    e.g. ``"E14: 4 records unhealthy (E1-B HS 3)"``, ``"C05: 2 records missing
    sqrt_a"``, and one for the Galileo F/NAV records left for I/NAV ones; only for the
    system letters in ``systems``. Records that are used give no note."""
    return tuple(text for letter, text in _parse(nav)[1] if letter in systems)


def _parse(nav) -> tuple[Ephemerides, list[tuple[str, str]]]:
    """Records and ``(system letter, note)`` pairs."""
    parts = []
    notes: list[tuple[str, str]] = []
    for letter, (sats, toc, vals) in nav.records.items():
        if letter in "GCE":
            part, why, extra = _kepler_part(letter, np.asarray(sats), np.asarray(toc, float),
                                            np.asarray(vals, float))
        elif letter == "R":
            part, why, extra = _glonass_part(np.asarray(sats), np.asarray(toc, float),
                                             np.asarray(vals, float))
        else:
            continue
        parts.append(part)
        notes += [(letter, n) for n in _count_notes(part["sat"], why)]
        notes += [(letter, n) for n in extra]
    if not parts:
        raise ValueError(f"{nav.path}: no GPS, BeiDou, Galileo or GLONASS navigation records")
    eph = Ephemerides(**{k: np.concatenate([p[k] for p in parts])
                         for k in Ephemerides.__dataclass_fields__})
    return eph, notes


def _count_notes(sats, why) -> list[str]:
    """``"SAT: n records REASON"`` for every (satellite, reason) of the rejected records."""
    bad = np.flatnonzero(why != "")
    counts = Counter(zip(sats[bad].tolist(), why[bad].tolist(), strict=True))
    return [f"{sat}: {n} record{'s' if n != 1 else ''} {reason}"
            for (sat, reason), n in sorted(counts.items())]


def _missing(names, cols: dict) -> np.ndarray:
    """Per record: "missing a, b" naming the absent fields of ``names``, or ""."""
    miss = np.stack([~np.isfinite(cols[k]) for k in names], axis=-1)
    why = np.full(miss.shape[0], "", dtype=object)
    for r in np.flatnonzero(miss.any(axis=1)):  # only the incomplete records
        why[r] = "missing " + ", ".join(k for k, m in zip(names, miss[r], strict=True) if m)
    return why


def _kepler_part(letter, sats, toc, vals):
    col = {k: vals[:, j] if j < vals.shape[1] else np.full(len(sats), np.nan)
           for k, j in _COL.items()}
    n = len(sats)
    extra: list[str] = []
    keep = np.ones(n, dtype=bool)
    health = np.nan_to_num(col["health"]).astype(np.int64)
    tgd = col["tgd"]
    if letter == "E":
        # Data sources (RINEX 3.05 Galileo record table): bit 0 I/NAV E1-B, bit 1 F/NAV E5a-I, bit 2
        # I/NAV E5b-I; bit 8 clock for E5a/E1, bit 9 for E5b/E1. Absent: I/NAV assumed.
        ds = np.nan_to_num(col["data_sources"]).astype(np.int64)
        fnav = ((ds & 0b010) != 0) & ((ds & 0b101) == 0)
        e5a_clock = ((ds & 0x100) != 0) | (((ds & 0x300) == 0) & fnav)
        # OS SIS ICD 5.1.5: an E1-only user subtracts BGD(E1, E5b) from the I/NAV clock
        # (E5b/E1 combination) or BGD(E1, E5a) from the F/NAV one.
        tgd = np.where(e5a_clock, col["tgd"], col["bgd_e5b"])
        # SV health (same table): bit 0 E1-B DVS, 1-2 E1-B HS, 3 E5a DVS, 4-5 E5a HS, ...
        sig_bits = np.where(fnav, health >> 3, health) & 0b111
        has_inav = np.isin(sats, sats[~fnav])
        keep = ~(fnav & has_inav)
        if (~keep).any():
            extra.append(f"GAL: {int((~keep).sum())} F/NAV records of "
                         f"{len(set(sats[~keep].tolist()))} satellites not used: their I/NAV "
                         "records give the E1 clock (OS SIS ICD 5.1.5)")
        unhealthy = sig_bits != 0
        why_health = np.full(n, "", dtype=object)
        for r in np.flatnonzero(unhealthy):  # only the unhealthy records
            sig = "E5a" if fnav[r] else "E1-B"
            flags = [f"{sig} HS {sig_bits[r] >> 1}"] * bool(sig_bits[r] >> 1)
            flags += [f"{sig} DVS 1"] * bool(sig_bits[r] & 1)
            why_health[r] = f"unhealthy ({', '.join(flags)})"
    else:
        unhealthy = health != 0
        label = "health" if letter == "G" else "SatH1"
        why_health = np.full(n, "", dtype=object)
        why_health[unhealthy] = [f"unhealthy ({label} {h})" for h in health[unhealthy]]
    cols = {**col, "tgd": tgd}
    why = _missing(_KEPLER_NEEDS, cols)
    why = np.where((why == "") & unhealthy, why_health, why)
    week = col["week"]
    if letter == "C":
        # BDT week -> GPS seconds: BDT 0 is GPS week 1356 + 14 s (ICD 4.2).
        toe = (week + BDS_WEEK0_GPS_WEEK) * SECONDS_PER_WEEK + col["toe"] - BDT_MINUS_GPST_S
    else:
        # GPS, and Galileo whose week RINEX writes on the GPS week count (GST = GPST).
        toe = week * SECONDS_PER_WEEK + col["toe"]
    # The toc is exact; fix a week roll-over between toc and toe (toe within 1/2 week).
    toe = toe + SECONDS_PER_WEEK * np.round((toc - toe) / SECONDS_PER_WEEK)
    acc = col["accuracy"]
    nan3 = np.full((n, 3), np.nan)
    part = dict(
        sat=sats, system=np.full(n, letter), prn=np.array([int(s[1:]) for s in sats]),
        toc_gps_s=toc, toe_gps_s=toe, toe_sow=col["toe"], af0=col["af0"], af1=col["af1"],
        af2=col["af2"], crs=col["crs"], dn=col["dn"], m0=col["m0"], cuc=col["cuc"],
        e=col["e"], cus=col["cus"], sqrt_a=col["sqrt_a"], cic=col["cic"],
        omega0=col["omega0"], cis=col["cis"], i0=col["i0"], crc=col["crc"],
        omega=col["omega"], omega_dot=col["omega_dot"], idot=col["idot"],
        tgd_s=np.nan_to_num(tgd),
        tgd2_s=col["bgd_e5b"] if letter in "CE" else np.full(n, np.nan), healthy=why == "",
        ura_m=np.where(np.isfinite(acc) & (acc > 0), acc, np.nan), fcn=np.zeros(n, int),
        pos_glo_m=nan3, vel_glo_mps=nan3, acc_glo_mps2=nan3)
    return {k: v[keep] for k, v in part.items()}, why[keep], extra


def _glonass_part(sats, toc, vals):
    n = len(sats)
    col = {k: vals[:, j] if j < vals.shape[1] else np.full(n, np.nan) for k, j in _GCOL.items()}
    health = np.nan_to_num(col["health"]).astype(np.int64)
    why = _missing(_GLO_NEEDS, col)
    unhealthy = (why == "") & (health != 0)
    why[unhealthy] = [f"unhealthy (health flag {h})" for h in health[unhealthy].tolist()]
    urai = col["urai"]
    ft = np.isfinite(urai) & (urai >= 0) & (urai <= 14)
    ura = np.where(ft, _GLO_FT_M[np.where(ft, urai, 0).astype(int)], np.nan)
    km = 1e3
    nan = np.full(n, np.nan)
    part = dict(
        sat=sats, system=np.full(n, "R"), prn=np.array([int(s[1:]) for s in sats]),
        toc_gps_s=toc, toe_gps_s=toc, toe_sow=nan, af0=col["af0"], af1=col["af1"],
        af2=np.zeros(n), crs=nan, dn=nan, m0=nan, cuc=nan, e=nan, cus=nan, sqrt_a=nan,
        cic=nan, omega0=nan, cis=nan, i0=nan, crc=nan, omega=nan, omega_dot=nan, idot=nan,
        tgd_s=np.zeros(n), tgd2_s=np.full(n, np.nan), healthy=why == "", ura_m=ura,
        fcn=np.nan_to_num(col["fcn"]).astype(int),
        pos_glo_m=km * np.stack([col["x"], col["y"], col["z"]], axis=-1),
        vel_glo_mps=km * np.stack([col["vx"], col["vy"], col["vz"]], axis=-1),
        acc_glo_mps2=km * np.stack([col["ax"], col["ay"], col["az"]], axis=-1))
    return part, why, []


def sat_pos_clock(eph: Ephemerides, t_gps_s) -> tuple[np.ndarray, np.ndarray]:
    """Satellite position (ECEF at time ``t``) and clock offset at GPS time ``t``.

    Parameters
    ----------
    eph : records, shape ``B``; t_gps_s : times, shape ``B`` or broadcastable to it (GPS
        s; the transmission time).

    Returns
    -------
    pos_ecef_m : (B, 3) in the Earth-fixed frame at ``t`` (WGS-84 / CGCS2000 / GTRF /
        PZ-90.11, see the module notes).
    clock_s : (B,) satellite clock offset (satellite time minus system time) incl. the
        relativistic term, minus the group delay ``tgd_s`` (s): a pseudorange is corrected
        by ``+ c * clock_s``. GLONASS: ``-tau_n + gamma_n (t - t_b)`` (GLONASS ICD: t_sys =
        t_sv + tau_n - gamma_n (t_sv - t_b)), whose relativistic part is in tau_n already.
        GLONASS state vectors are not propagated more than 2 h from t_b (NaN position
        beyond).
    """
    t = np.asarray(t_gps_s, dtype=float)
    rec_shape = np.shape(eph.sat)
    shape = np.broadcast_shapes(rec_shape, t.shape)
    def records_first(a):  # (B, ...) -> (N, ...): the records along one axis
        a = np.asarray(a)
        return a.reshape(-1, *a.shape[len(rec_shape):])

    flat = Ephemerides(**{k: records_first(getattr(eph, k))
                          for k in Ephemerides.__dataclass_fields__})
    idx = np.broadcast_to(np.arange(flat.sat.size).reshape(rec_shape), shape).ravel()
    e = flat.take(idx)
    t = np.broadcast_to(t, shape).ravel()
    pos = np.full((t.size, 3), np.nan)
    clk = np.full(t.size, np.nan)
    glo = e.system == "R"
    if (~glo).any():
        pos[~glo], clk[~glo] = _kepler_pos_clock(e.take(~glo), t[~glo])
    if glo.any():
        pos[glo], clk[glo] = _glonass_pos_clock(e.take(glo), t[glo])
    return pos.reshape((*shape, 3)), clk.reshape(shape)


def _kepler_pos_clock(eph: Ephemerides, t) -> tuple[np.ndarray, np.ndarray]:
    """GPS, BeiDou and Galileo: IS-GPS-200 table 20-IV, BDS ICD 5.2.4.12, Galileo OS SIS
    ICD 5.1.1 (the same algorithm with each system's GM and Earth rotation rate)."""
    bds = eph.system == "C"
    gal = eph.system == "E"
    gm = np.select([bds, gal], [GM_BDS_M3PS2, GM_GAL_M3PS2], GM_GPS_M3PS2)
    we = np.select([bds, gal], [OMEGA_E_BDS_RADPS, OMEGA_E_GAL_RADPS], OMEGA_E_RADPS)
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
    # MEO/IGSO (and GPS, Galileo): Omega = Omega0 + (Omega_dot - we) tk - we toe; GEO (BDS
    # ICD 5.2.4.12): Omega = Omega0 + Omega_dot tk - we toe, then R_Z(we tk) R_X(-5 deg).
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
    # 20.3.3.3.3.1; BDS ICD 5.2.4.10 and Galileo OS SIS ICD 5.1.4 with their GM).
    rel = -2.0 * np.sqrt(gm) / C_MPS**2 * eph.e * eph.sqrt_a * np.sin(ecc_anom)
    clock = eph.af0 + eph.af1 * dt + eph.af2 * dt**2 + rel - eph.tgd_s
    return np.stack([x, y, z], axis=-1), clock


def _glonass_accel(r, v, acc_ls) -> np.ndarray:
    """GLONASS ICD ed. 5.1 A.3.1.2: acceleration in the rotating PZ-90 frame (central
    term, J2, centrifugal and Coriolis terms, lunisolar acceleration held constant)."""
    r2 = np.sum(r * r, axis=-1)
    rr = np.sqrt(r2)
    mu_r3 = GM_GLO_M3PS2 / (r2 * rr)
    j2 = 1.5 * J2_GLO * GM_GLO_M3PS2 * A_E_GLO_M**2 / (r2 * r2 * rr)  # 3/2 J2 mu a^2 / r^5
    z2 = r[:, 2] ** 2 / r2
    w2 = OMEGA_E_GLO_RADPS**2
    ax = (-mu_r3 - j2 * (1.0 - 5.0 * z2) + w2) * r[:, 0] + 2.0 * OMEGA_E_GLO_RADPS * v[:, 1]
    ay = (-mu_r3 - j2 * (1.0 - 5.0 * z2) + w2) * r[:, 1] - 2.0 * OMEGA_E_GLO_RADPS * v[:, 0]
    az = (-mu_r3 - j2 * (3.0 - 5.0 * z2)) * r[:, 2]
    return np.stack([ax, ay, az], axis=-1) + acc_ls


def _glonass_pos_clock(eph: Ephemerides, t) -> tuple[np.ndarray, np.ndarray]:
    """GLONASS: the state vector at t_b integrated to ``t`` with 4th-order Runge-Kutta
    (GLONASS ICD ed. 5.1 A.3.1.2) in ``ceil(|t - t_b| / 60 s)`` equal steps per element
    (so an element's result does not depend on the rest of the batch); clock
    ``-tau_n + gamma_n (t - t_b)``. A state vector that is not finite or lies
    below the Earth's surface, or a span beyond 2 h, gives a NaN position."""
    dt = t - eph.toe_gps_s
    r, v, a_ls = eph.pos_glo_m, eph.vel_glo_mps, eph.acc_glo_mps2
    ok = (np.isfinite(dt) & (np.abs(dt) <= _GLO_MAX_SPAN_S)
          & np.isfinite(np.concatenate([r, v, a_ls], axis=-1)).all(axis=-1)
          & (np.sum(np.where(np.isfinite(r), r, 0.0) ** 2, axis=-1) > A_E_GLO_M**2))
    # Elements not integrated get a harmless placeholder state (their output is NaN).
    dt = np.where(ok, dt, 0.0)
    r = np.where(ok[:, None], r, [4.0 * A_E_GLO_M, 0.0, 0.0])
    v = np.where(ok[:, None], v, 0.0)
    a_ls = np.where(ok[:, None], a_ls, 0.0)
    n_steps = np.ceil(np.abs(dt) / _GLO_STEP_S)
    h = (dt / np.maximum(n_steps, 1.0))[:, None]
    for k in range(int(n_steps.max(initial=0.0))):
        k1r, k1v = v, _glonass_accel(r, v, a_ls)
        k2r, k2v = v + 0.5 * h * k1v, _glonass_accel(r + 0.5 * h * k1r, v + 0.5 * h * k1v, a_ls)
        k3r, k3v = v + 0.5 * h * k2v, _glonass_accel(r + 0.5 * h * k2r, v + 0.5 * h * k2v, a_ls)
        k4r, k4v = v + h * k3v, _glonass_accel(r + h * k3r, v + h * k3v, a_ls)
        active = (k < n_steps)[:, None]  # an element stops after its own steps
        r = np.where(active, r + h / 6.0 * (k1r + 2.0 * k2r + 2.0 * k3r + k4r), r)
        v = np.where(active, v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v), v)
    clock = eph.af0 + eph.af1 * (t - eph.toc_gps_s) - eph.tgd_s
    return np.where(ok[:, None], r, np.nan), clock
