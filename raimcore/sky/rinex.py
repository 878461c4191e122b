"""RINEX observation and navigation readers (code pseudoranges, broadcast ephemerides).

Formats read:

- observations: RINEX 2.11 and 3.0x (``.yyo``, ``.rnx``);
- navigation: RINEX 2 GPS (``.yyn``) and GLONASS (``.yyg``), RINEX 3.0x mixed or one file
  per system (IGS ``..._MN.rnx``, ``_GN``, ``_RN``, ``_EN``, ``_CN``), and RINEX 4.0x
  (``> EPH`` records of types LNAV, D1, D2, INAV, FNAV, FDMA, SBAS; ``> ION`` Klobuchar and
  NeQuick-G records); several navigation files are merged into one;
- any of these compressed: gzip ``.gz``, Unix compress ``.Z``, ``.zip``, ``.bz2``, and
  Hatanaka ``.crx`` / ``.yyd`` alone or inside those (:mod:`raimcore.sky.compressed`).

Only what single-point positioning needs is kept: epochs (time, flag), the header position,
code pseudoranges (observation types starting with ``C`` or ``P``) per satellite, the
broadcast ephemerides of GPS, GLONASS, Galileo and BeiDou (QZSS, NavIC and SBAS on request)
as the numbers of each record in file order, and the ionosphere coefficients.

The satellite-record blocks are parsed with fixed-width slicing of a ``(lines, columns)``
byte array, so a 2-hour 30-s mixed file (10,000 satellite records) loads in well under a
second. No third-party reader is used: the format is simple and a reader dependency
(georust, georinex) would not earn its place.

Time scales. Times are GPS seconds since 1980-01-06 00:00:00 GPST (float). BeiDou times
(BDT) are converted with BDT = GPST - 14 s (BDS-SIS-ICD-B1I 3.0, 4.2). Galileo System Time
(GST) is steered to GPST: both count seconds from the same epoch without leap seconds, and
their difference (GGTO, nanoseconds, broadcast as ``GAGP``) is far below the toc's one-second
resolution, so a Galileo toc is taken as GPST. GLONASS tocs are UTC(SU) in every RINEX
version: GPST = UTC + (GPS - UTC), the leap seconds from the file's ``LEAP SECONDS`` header
when present (a BeiDou-referenced value, ``BDS`` in columns 25-27, gets the 14 s added),
else from :func:`gps_minus_utc_s` (a table of the leap seconds, 18 s since 2017-01-01).
QZSS, NavIC and SBAS tocs are in GPST-aligned scales and kept as they are.

Errors in the input raise :class:`RinexError` (a ``ValueError``) naming the file, the line
and what was expected.

References
----------
RINEX 2.11 (Gurtner & Estey 2007), RINEX 3.05 (IGS/RTCM 2020), RINEX 4.00 (IGS/RTCM 2021),
IERS Bulletin C (leap seconds), Galileo OS SIS ICD issue 2.0 (GST), GLONASS ICD edition 5.1
(GLONASS time is UTC(SU) + 3 h).
"""

from __future__ import annotations

import math
import os
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime

import numpy as np

from .compressed import RinexError, read_bytes

__all__ = ["RinexError", "ObsFile", "NavFile", "read_obs", "read_nav", "gps_seconds",
           "gps_minus_utc_s", "BDT_MINUS_GPST_S", "BDS_WEEK0_GPS_WEEK", "NAV_SYSTEMS"]

_GPS_EPOCH = datetime(1980, 1, 6)
BDT_MINUS_GPST_S = -14.0  # BDS-SIS-ICD-B1I 3.0, 4.2: BDT = GPST - 14 s
BDS_WEEK0_GPS_WEEK = 1356  # BDT week 0 starts 2006-01-01 00:00:00 BDT (ICD 4.2)

#: Satellite system identifiers of RINEX 3/4 and their names in notes.
NAV_SYSTEMS = {"G": "GPS", "R": "GLONASS", "E": "Galileo", "C": "BeiDou", "J": "QZSS",
               "I": "NavIC", "S": "SBAS"}
#: Lines per navigation record (all lines, including the first) in RINEX 2 and 3, by
#: system letter; GLONASS has a 5th line from RINEX 3.05 on.
_NAV_LINES = {"G": 8, "C": 8, "E": 8, "J": 8, "I": 8, "R": 4, "S": 4}
#: Numbers kept per record (3 on the first line, 4 on each further one, of the longest
#: layout of that system); shorter records are padded with NaN.
_NAV_WIDTH = {"G": 31, "C": 31, "E": 31, "J": 31, "I": 31, "R": 19, "S": 15}
#: RINEX 4 ``> EPH`` message types read, with their line counts after the ``>`` line
#: (these keep the RINEX 3.05 layouts); every other type (CNAV, CNV1-3, L1NV, L1OC, ...)
#: is skipped up to the next ``>`` line and counted.
_V4_EPH_LINES = {("G", "LNAV"): 8, ("J", "LNAV"): 8, ("I", "LNAV"): 8, ("E", "INAV"): 8,
                 ("E", "FNAV"): 8, ("C", "D1"): 8, ("C", "D2"): 8, ("R", "FDMA"): 5,
                 ("S", "SBAS"): 4}
#: Klobuchar ``> ION`` records of RINEX 4 (by system letter) -> ``iono`` key prefix, the
#: RINEX 3 ``IONOSPHERIC CORR`` names. BeiDou's Klobuchar is its D1D2 message; its CNVX
#: ION record is BDGIM, not read.
_KLOBUCHAR = {"G": "GPS", "J": "QZS", "I": "IRN", "C": "BDS"}

#: GPS - UTC (s) from each UTC date on: IERS Bulletin C (TAI - UTC) minus 19 s. Extend the
#: table when IERS announces a leap second (none since 2017-01-01).
_LEAP_SECONDS = ((1981, 7, 1, 1), (1982, 7, 1, 2), (1983, 7, 1, 3), (1985, 7, 1, 4),
                 (1988, 1, 1, 5), (1990, 1, 1, 6), (1991, 1, 1, 7), (1992, 7, 1, 8),
                 (1993, 7, 1, 9), (1994, 7, 1, 10), (1996, 1, 1, 11), (1997, 7, 1, 12),
                 (1999, 1, 1, 13), (2006, 1, 1, 14), (2009, 1, 1, 15), (2012, 7, 1, 16),
                 (2015, 7, 1, 17), (2017, 1, 1, 18))


def gps_seconds(year, month, day, hour, minute, second) -> float:
    """Calendar date (in the file's time scale) to seconds since the GPS epoch."""
    whole = math.floor(second)
    dt = datetime(int(year), int(month), int(day), int(hour), int(minute), int(whole))
    return (dt - _GPS_EPOCH).total_seconds() + (second - whole)


_LEAP_AT_UTC_S = np.array([gps_seconds(y, m, d, 0, 0, 0) for y, m, d, _ in _LEAP_SECONDS])
_LEAP_S = np.array([0.0] + [float(s) for *_, s in _LEAP_SECONDS])


def gps_minus_utc_s(t_gps_s):
    """GPS - UTC in seconds (the leap seconds since 1980) at GPS time ``t_gps_s``.

    Parameters
    ----------
    t_gps_s : float or array, GPS seconds since 1980-01-06.

    Returns
    -------
    float or array of the same shape: 0 before 1981-07-01, 18 from 2017-01-01 00:00:00 UTC
    (GPS 00:00:18) on. From the IERS Bulletin C table; dates after the table's last leap
    second get its value, so the table must be extended when a new one is announced.

    Examples
    --------
    >>> gps_minus_utc_s(gps_seconds(2020, 6, 25, 0, 0, 0))
    18.0
    >>> gps_minus_utc_s(gps_seconds(2017, 1, 1, 0, 0, 17))  # 2016-12-31 23:59:60 UTC
    17.0
    """
    # A leap second takes effect at 00:00:00 UTC, which is (new value) s later in GPST.
    out = _LEAP_S[np.searchsorted(_LEAP_AT_UTC_S + _LEAP_S[1:], t_gps_s, side="right")]
    return float(out) if np.ndim(out) == 0 else out


def _utc_to_gps(t_utc_s: np.ndarray, leap_s: float | None) -> np.ndarray:
    """UTC dates written as seconds since 1980-01-06 -> GPS seconds (table unless given)."""
    if leap_s is not None:
        return t_utc_s + leap_s
    return t_utc_s + _LEAP_S[np.searchsorted(_LEAP_AT_UTC_S, t_utc_s, side="right")]


@dataclass(frozen=True)
class ObsFile:
    """A RINEX observation file, code pseudoranges only.

    Attributes
    ----------
    path, version : file name and RINEX version (2.11, 3.05, ...).
    marker : marker name (may be empty).
    approx_pos_ecef_m : (3,) header ``APPROX POSITION XYZ`` (zeros when absent).
    time_system : "GPS" or "BDT" (times below are GPST in both cases).
    obs_types : system letter -> observation types of that system (RINEX 2: the same list
        for every system).
    t_gps_s : (E,) epoch times, GPS seconds since 1980-01-06.
    epoch_flag : (E,) 0 (ok) or 1 (power failure before the epoch); event records
        (flags 2-5) and cycle-slip records (6) are skipped and counted in ``events``.
    sat_names : (S,) satellites seen in the file ("G05", "C21", ...), sorted.
    codes : observation type -> (E, S) pseudoranges (m), NaN where not observed.
    events : (line, flag) of each skipped event record.
    """

    path: str
    version: float
    marker: str
    approx_pos_ecef_m: np.ndarray
    time_system: str
    obs_types: dict[str, tuple[str, ...]]
    t_gps_s: np.ndarray
    epoch_flag: np.ndarray
    sat_names: tuple[str, ...]
    codes: dict[str, np.ndarray]
    events: tuple[tuple[int, int], ...] = ()

    def pseudorange(self, system: str, code: str) -> np.ndarray:
        """(E, S) pseudoranges of ``code`` for the satellites of system letter ``system``
        (NaN elsewhere)."""
        out = np.full((len(self.t_gps_s), len(self.sat_names)), np.nan)
        if code in self.codes:
            cols = [k for k, s in enumerate(self.sat_names) if s[0] == system]
            out[:, cols] = self.codes[code][:, cols]
        return out


@dataclass(frozen=True)
class NavFile:
    """Broadcast ephemerides of one or more RINEX navigation files, merged.

    Attributes
    ----------
    path : the file name, or the names joined by ", " when several files were merged.
    version : RINEX version of the first file.
    iono : ionosphere coefficients, (4,) each: Klobuchar "GPSA"/"GPSB", "BDSA"/"BDSB"
        (also "QZSA"/"QZSB", "IRNA"/"IRNB") and NeQuick-G "GAL" (ai0, ai1, ai2, then the
        header's 4th field in RINEX 3, NaN in RINEX 4), from RINEX 2/3 headers or the first
        RINEX 4 ``> ION`` record of each; the first file that has a key gives it.
    records : system letter ("G", "R", "E", "C") -> ``(sats (N,), toc_gps_s (N,),
        values (N, W))``, records in file order (files in the order given). ``values``
        holds the record's numbers in file order, NaN where a field is blank or absent:
        af0, af1, af2 (GLONASS: -tauN, +gammaN, message frame time), then four per
        broadcast-orbit line (GLONASS: X, Xdot, Xacc, health; Y, Ydot, Yacc, frequency
        number; Z, Zdot, Zacc, age; and in RINEX 3.05 / 4 status flags, L1/L2 group delay
        difference, URAI, health flags). ``W`` is 31 (GPS, Galileo, BeiDou, QZSS, NavIC),
        19 (GLONASS) or 15 (SBAS). ``toc_gps_s`` is GPST (see the module docstring).
    kinds : system letter -> (N,) navigation message of each record: the RINEX 4 message
        type ("LNAV", "D1", "D2", "INAV", "FNAV", "FDMA", "SBAS"), and in RINEX 2/3 "LNAV"
        (GPS, QZSS, NavIC), "FDMA" (GLONASS), "SBAS", "D1"/"D2" (BeiDou: D2 for the GEO
        satellites C01-C05 and C59-C63, which broadcast it) and for Galileo "INAV" or
        "FNAV" from the data-source field (bit 0 or 2: I/NAV; bit 1: F/NAV), "" when that
        field is blank or says neither or both.
    skipped : what was not read, with counts: system letter -> records of a system not
        asked for; "<letter> <type>" -> RINEX 4 ephemeris records of a message type not
        read (e.g. "G CNAV"); "STO", "EOP" and "ION <letter> <type>" -> RINEX 4 records
        not needed.
    notes : one line each about what was dropped or skipped that could matter: systems
        and message types skipped, duplicate records with different values (the first
        is kept), files disagreeing on the leap seconds. Identical duplicates (the same
        record in two files) are dropped without a note.
    leap_s : GPS - UTC (s) used for the GLONASS tocs: the ``LEAP SECONDS`` header of the
        first file that has one, else :func:`gps_minus_utc_s` at the first record; NaN
        without either. For another time, call :func:`gps_minus_utc_s`.
    paths : every file read, in order.
    """

    path: str
    version: float
    iono: dict[str, np.ndarray]
    records: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    skipped: dict[str, int] = field(default_factory=dict)
    kinds: dict[str, np.ndarray] = field(default_factory=dict)
    notes: tuple[str, ...] = ()
    leap_s: float = math.nan
    paths: tuple[str, ...] = ()


# -- low-level helpers -----------------------------------------------------------------

def _read_lines(path) -> list[bytes]:
    """The lines of a RINEX file, plain or compressed (:func:`compressed.read_bytes`)."""
    return read_bytes(path).splitlines()


def _label(line: bytes) -> str:
    return line[60:80].decode("ascii", "replace").strip()


_FILE_TYPES = {"O": "an observation", "N": "a navigation"}


def _header(path, lines: list[bytes], types: str, versions: tuple[int, ...] = (2, 3)
            ) -> tuple[float, str, int]:
    """Version, file type (column 21) and the index of the first line after
    ``END OF HEADER``; ``types`` are the accepted file types, the first names the kind."""
    if not lines or _label(lines[0]) != "RINEX VERSION / TYPE":
        raise RinexError(path, 1, "expected the 'RINEX VERSION / TYPE' header line")
    try:
        version = float(lines[0][:9])
    except ValueError:
        raise RinexError(path, 1, "expected a RINEX version number in columns 1-9") from None
    ftype = lines[0][20:21].decode("ascii", "replace")
    if ftype not in types:
        allowed = " or ".join(f"'{t}'" for t in types)
        raise RinexError(path, 1, f"expected {_FILE_TYPES[types[0]]} file (type {allowed} in "
                         f"column 21), got '{ftype}'")
    if int(version) not in versions:
        allowed = ", ".join(f"{v}.xx" for v in versions)
        raise RinexError(path, 1, f"expected RINEX version {allowed}, got {version}")
    for i, line in enumerate(lines):
        if _label(line) == "END OF HEADER":
            return version, ftype, i + 1
    raise RinexError(path, len(lines), "expected an 'END OF HEADER' line, file ends")


def _float(path, lineno: int, text: bytes, what: str) -> float:
    """A finite number (``nan`` and ``inf``, which Python would parse, are refused)."""
    try:
        x = float(text.replace(b"D", b"E").replace(b"d", b"e"))
    except ValueError:
        x = math.nan
    if not math.isfinite(x):
        raise RinexError(path, lineno, f"expected {what}, got "
                         f"{text.decode('ascii', 'replace').strip()!r}")
    return x


def _int(path, lineno: int, text: bytes, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise RinexError(path, lineno, f"expected {what}, got {text.decode('ascii', 'replace')!r}"
                         ) from None


def _fields(path, block: np.ndarray, rows_lineno: np.ndarray, start: int, width: int
            ) -> np.ndarray:
    """Floats from columns ``start:start+width`` of a fixed-width byte block ``(N, W)``;
    blank fields are NaN, FORTRAN ``D`` exponents are read. A bad number raises naming its
    line."""
    sub = np.ascontiguousarray(block[:, start:start + width]).view(f"S{width}").ravel()
    sub = np.char.strip(sub)
    blank = sub == b""
    vals = None
    for attempt in range(2):
        try:
            vals = np.where(blank, b"nan", sub).astype(float)
            break
        except ValueError:
            if attempt == 0:  # RINEX 2 navigation files write 0.1D+01
                sub = np.char.replace(np.char.replace(sub, b"D", b"E"), b"d", b"e")
    bad = ~blank if vals is None else ~blank & ~np.isfinite(vals)  # also "nan", "inf"
    if bad.any():
        for k in np.flatnonzero(bad):
            _float(path, int(rows_lineno[k]), sub[k], f"a number in columns {start + 1}-"
                   f"{start + width}")
        raise AssertionError("unreachable: _float refuses the bad field")  # pragma: no cover
    return vals


def _block(lines: list[bytes], idx: np.ndarray, width: int) -> np.ndarray:
    """Rows ``idx`` of ``lines`` as a space-padded ``(N, width)`` byte array."""
    arr = np.array([lines[i] for i in idx], dtype=f"S{width}")
    out = arr.view("S1").reshape(len(idx), width)
    return np.where(out == b"", b" ", out)


# -- observation files -----------------------------------------------------------------

def read_obs(path) -> ObsFile:
    """Read a RINEX 2.11 or 3.0x observation file (code pseudoranges), plain or
    compressed (gzip, ``.Z``, zip, bzip2, Hatanaka ``.crx`` / ``.yyd``; see
    :mod:`raimcore.sky.compressed`).

    Raises
    ------
    RinexError (a ValueError) for a missing file, a corrupt archive, a malformed header,
    epoch line or number, or a file that ends inside an epoch.
    """
    lines = _read_lines(path)
    version, _, body = _header(path, lines, "O")
    head = lines[:body]
    pos = np.zeros(3)
    marker = ""
    time_system = "GPS"
    types: dict[str, list[str]] = {}
    r2_types: list[str] = []
    r2_count = 0
    last_sys = ""
    for i, line in enumerate(head):
        lab = _label(line)
        if lab == "APPROX POSITION XYZ":
            pos = np.array([_float(path, i + 1, line[14 * k:14 * k + 14],
                                   "an APPROX POSITION XYZ coordinate") for k in range(3)])
        elif lab == "MARKER NAME":
            marker = line[:60].decode("ascii", "replace").strip()
        elif lab == "SYS / # / OBS TYPES":
            sys_letter = line[0:1].decode()
            if sys_letter.strip():
                last_sys = sys_letter
                types[last_sys] = []
            elif not last_sys:
                raise RinexError(path, i + 1, "expected a system letter in column 1")
            types[last_sys] += line[7:58].decode("ascii", "replace").split()
        elif lab == "# / TYPES OF OBSERV":
            if line[:6].strip():
                r2_count = _int(path, i + 1, line[:6], "the number of observation types")
            r2_types += line[6:60].decode("ascii", "replace").split()
        elif lab == "TIME OF FIRST OBS":
            ts = line[48:51].decode("ascii", "replace").strip()
            time_system = ts or time_system
    if version < 3:
        if not r2_types or len(r2_types) != r2_count:
            raise RinexError(path, body, f"expected {r2_count} observation types in the "
                             f"'# / TYPES OF OBSERV' header lines, got {len(r2_types)}")
        obs_types = {s: tuple(r2_types) for s in "GRECJS"}
    else:
        if not types:
            raise RinexError(path, body, "expected 'SYS / # / OBS TYPES' header lines")
        obs_types = {s: tuple(v) for s, v in types.items()}
    t_shift = -BDT_MINUS_GPST_S if time_system == "BDT" else 0.0
    if version < 3:
        epochs, sat_rows = _epochs_v2(path, lines, body, len(r2_types))
    else:
        epochs, sat_rows = _epochs_v3(path, lines, body)
    t, flags, events = epochs
    sat_line, sat_epoch, sat_name = sat_rows
    names = tuple(sorted(set(sat_name)))
    col = {n: k for k, n in enumerate(names)}
    sat_col = np.array([col[n] for n in sat_name], dtype=int)
    codes: dict[str, np.ndarray] = {}
    for sys_letter, tl in obs_types.items():
        rows = np.flatnonzero(np.array([n[0] == sys_letter for n in sat_name], dtype=bool))
        if rows.size == 0:
            continue
        wanted = [(j, ty) for j, ty in enumerate(tl) if ty[0] in "CP"]
        if not wanted:
            continue
        if version < 3:
            per = (len(tl) + 4) // 5  # lines per satellite record (5 fields of 16 columns)
            idx = sat_line[rows][:, None] + np.arange(per)[None, :]
            blk = _block(lines, idx.ravel(), 80).reshape(rows.size, per * 80)
        else:
            blk = _block(lines, sat_line[rows], 3 + 16 * len(tl))
        lineno = sat_line[rows] + 1
        for j, ty in wanted:
            start = (j // 5) * 80 + (j % 5) * 16 if version < 3 else 3 + 16 * j
            vals = _fields(path, blk, lineno, start, 14)
            vals = np.where(vals == 0.0, np.nan, vals)  # 0.000 means "no observation"
            arr = codes.setdefault(ty, np.full((len(t), len(names)), np.nan))
            arr[sat_epoch[rows], sat_col[rows]] = vals
    return ObsFile(str(path), version, marker, pos, time_system, obs_types,
                   np.asarray(t, dtype=float) + t_shift, np.asarray(flags, dtype=int), names,
                   codes, tuple(events))


def _epochs_v3(path, lines, body):
    t: list[float] = []
    flags: list[int] = []
    events: list[tuple[int, int]] = []
    sat_line: list[int] = []
    sat_epoch: list[int] = []
    i, n = body, len(lines)
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        if line[:1] != b">":
            raise RinexError(path, i + 1, "expected an epoch line starting with '>' "
                             "('> yyyy mm dd hh mm ss.sssssss flag nsat')")
        flag = _int(path, i + 1, line[31:32], "an epoch flag in column 32")
        nrec = _int(path, i + 1, line[32:35], "a record count in columns 33-35")
        if i + nrec >= n:
            raise RinexError(path, n, f"expected {nrec} records after the epoch line {i + 1}, "
                             f"file ends after {n - i - 1}")
        if flag in (0, 1):
            f = line[2:29].split()
            if len(f) != 6:
                raise RinexError(path, i + 1, "expected 'yyyy mm dd hh mm ss.sssssss' in "
                                 "columns 3-29")
            try:
                t.append(gps_seconds(*(int(x) for x in f[:5]), float(f[5])))
            except ValueError:
                raise RinexError(path, i + 1, "expected a valid date and time in columns "
                                 "3-29") from None
            flags.append(flag)
            for k in range(i + 1, i + 1 + nrec):
                sat = lines[k][:3].decode("ascii", "replace")
                if len(sat) < 3 or sat[0] not in "GRECJSI" or not sat[1:].strip().isdigit():
                    raise RinexError(path, k + 1, f"expected a satellite record starting "
                                     f"with a satellite number such as 'G05', got {sat!r}")
                sat_line.append(k)
                sat_epoch.append(len(t) - 1)
        else:
            events.append((i + 1, flag))
        i += 1 + nrec
    names = [lines[k][:3].decode().replace(" ", "0") for k in sat_line]
    return (t, flags, events), (np.array(sat_line, dtype=int), np.array(sat_epoch, dtype=int),
                                names)


def _epochs_v2(path, lines, body, ntypes):
    per = (ntypes + 4) // 5
    t: list[float] = []
    flags: list[int] = []
    events: list[tuple[int, int]] = []
    sat_line: list[int] = []
    sat_epoch: list[int] = []
    names: list[str] = []
    i, n = body, len(lines)
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        flag = _int(path, i + 1, line[26:29], "an epoch line with the epoch flag in column 29")
        nrec = _int(path, i + 1, line[29:32], "a satellite count in columns 30-32")
        if flag > 1 and flag != 6:  # event: nrec header lines follow
            events.append((i + 1, flag))
            if i + nrec >= n:
                raise RinexError(path, n, f"expected {nrec} event lines after line {i + 1}, "
                                 "file ends")
            i += 1 + nrec
            continue
        nlist = (nrec + 11) // 12
        if i + nlist - 1 >= n:
            raise RinexError(path, n, f"expected {nlist} epoch lines listing {nrec} satellites "
                             f"from line {i + 1}, file ends")
        sats: list[str] = []
        for k in range(nlist):
            chunk = lines[i + k][32:68].decode("ascii", "replace").ljust(36)
            sats += [chunk[3 * m:3 * m + 3] for m in range(12)]
        sats = [s.replace(" ", "G", 1) if s[0] == " " else s for s in sats[:nrec]]
        sats = [s[0] + s[1:].replace(" ", "0") for s in sats]
        for k, s in enumerate(sats):
            if s[0] not in "GRECJSI" or not s[1:].isdigit():
                raise RinexError(path, i + 1 + k // 12, f"expected a satellite number such as "
                                 f"'G05' in the epoch's satellite list, got {s!r}")
        first = i + nlist
        if first + nrec * per > n:
            raise RinexError(path, n, f"expected {nrec * per} observation lines after the epoch "
                             f"at line {i + 1} ({nrec} satellites x {per}), file ends")
        if flag != 6:
            f = line[:26].split()
            if len(f) != 6:
                raise RinexError(path, i + 1, "expected 'yy mm dd hh mm ss.sssssss' in columns "
                                 "1-26")
            try:
                yy = int(f[0])
                t.append(gps_seconds(yy + (2000 if yy < 80 else 1900) if yy < 100 else yy,
                                     *(int(x) for x in f[1:5]), float(f[5])))
            except ValueError:
                raise RinexError(path, i + 1, "expected a valid date and time in columns "
                                 "1-26") from None
            flags.append(flag)
            sat_line += [first + k * per for k in range(nrec)]
            sat_epoch += [len(t) - 1] * nrec
            names += sats
        else:
            events.append((i + 1, flag))
        i = first + nrec * per
    return (t, flags, events), (np.array(sat_line, dtype=int), np.array(sat_epoch, dtype=int),
                                names)


# -- navigation files ------------------------------------------------------------------

def read_nav(paths, systems: str = "GCER") -> NavFile:
    """Read and merge the broadcast ephemerides of one or more RINEX navigation files.

    Parameters
    ----------
    paths : str, os.PathLike or a non-empty sequence of them
        RINEX 2 GPS (``.yyn``) or GLONASS (``.yyg``), RINEX 3.0x mixed or single-system,
        or RINEX 4.0x navigation files, plain or compressed, in any mix (e.g. an IGS
        station's ``_GN``, ``_EN``, ``_CN`` and ``_RN`` files).
    systems : str
        System letters to read, distinct, from "GRECJIS" (default "GCER": GPS, BeiDou,
        Galileo, GLONASS). Records of other systems are skipped by their line counts and
        counted in ``skipped`` and ``notes``.

    Returns
    -------
    NavFile
        The records of all files, files in the order given, duplicates dropped: a record
        with the same satellite, toc and message kind (``NavFile.kinds``) as an earlier one
        is dropped, silently when its values are the same, and counted in ``notes`` when
        they differ (the first is kept). Blank fields (a spare, an optional trailing
        field) read as NaN: they never reject a record.

    Raises
    ------
    ValueError
        ``paths`` or ``systems`` not of the form above.
    RinexError (a ValueError)
        A missing or unreadable file, a malformed header or record (a number that is not
        one, an unknown system letter or RINEX 4 record type), or a file that ends inside
        a record; it names the file and the line.
    """
    files = _check_paths(paths)
    systems = _check_systems(systems)
    return _merge([_read_nav_file(p, systems) for p in files], systems)


def _check_paths(paths) -> list:
    if isinstance(paths, str | os.PathLike):
        return [paths]
    if (isinstance(paths, Sequence) and len(paths) > 0
            and all(isinstance(p, str | os.PathLike) for p in paths)):
        return list(paths)
    raise ValueError("paths: expected a file path or a non-empty sequence of file paths, "
                     f"got {paths!r}")


def _check_systems(systems) -> str:
    if (not isinstance(systems, str) or not systems or len(set(systems)) != len(systems)
            or any(s not in NAV_SYSTEMS for s in systems)):
        raise ValueError(f"systems: expected distinct letters of {''.join(NAV_SYSTEMS)!r} "
                         f"(e.g. 'GCER'), got {systems!r}")
    return systems


@dataclass
class _Found:
    """Records of one system found in one file (before their numbers are parsed)."""

    count: int  # lines per record
    sats: list[str] = field(default_factory=list)
    starts: list[int] = field(default_factory=list)  # index of each record's first line
    tocs: list[float] = field(default_factory=list)  # in the file's time scale
    kinds: list[str] = field(default_factory=list)  # RINEX 4 message types


def _read_nav_file(path, systems: str) -> tuple[NavFile, float | None]:
    """One file, duplicates kept; with its ``LEAP SECONDS`` header value (or None)."""
    lines = _read_lines(path)
    version, ftype, body = _header(path, lines, "NG", versions=(2, 3, 4))
    iono, leap = _nav_header(path, lines[:body])
    if version >= 4:
        found, skipped = _scan_v4(path, lines, body, systems, iono)
    else:
        found, skipped = _scan_v2_v3(path, lines, body, systems, version,
                                     "R" if ftype == "G" else "G")
    first_w, cont_w = (22, 3) if version < 3 else (23, 4)  # columns of the numbers
    records, kinds = {}, {}
    for letter, f in found.items():
        sats = np.array(f.sats)
        vals = _nav_values(path, lines, np.array(f.starts), f.count, _NAV_WIDTH[letter],
                           first_w, cont_w)
        toc = np.array(f.tocs, dtype=float)
        if letter == "C":
            toc = toc - BDT_MINUS_GPST_S
        elif letter == "R":
            toc = _utc_to_gps(toc, leap)
        records[letter] = (sats, toc, vals)
        kinds[letter] = np.array(f.kinds) if version >= 4 else _kinds_v2_v3(letter, sats, vals)
    if leap is not None:
        leap_s = float(leap)
    elif records:
        leap_s = gps_minus_utc_s(min(r[1].min() for r in records.values()))
    else:
        leap_s = math.nan
    nav = NavFile(str(path), version, iono, records, dict(skipped), kinds, (), leap_s,
                  (str(path),))
    return nav, leap


def _nav_header(path, head: list[bytes]) -> tuple[dict[str, np.ndarray], int | None]:
    """Ionosphere coefficients and GPS - UTC (``LEAP SECONDS``, None when absent)."""
    iono: dict[str, np.ndarray] = {}
    leap = None
    for i, line in enumerate(head):
        lab = _label(line)
        if lab == "IONOSPHERIC CORR":
            key = line[:4].decode("ascii", "replace").strip()
            iono[key] = np.array([_nav_num(path, i + 1, line, 5 + 12 * k, 12)
                                  for k in range(4)])
        elif lab in ("ION ALPHA", "ION BETA"):
            key = "GPSA" if lab == "ION ALPHA" else "GPSB"
            iono[key] = np.array([_nav_num(path, i + 1, line, 2 + 12 * k, 12)
                                  for k in range(4)])
        elif lab == "LEAP SECONDS" and leap is None:
            leap = _int(path, i + 1, line[:6], "the number of leap seconds in columns 1-6")
            if line[24:27].strip() == b"BDS":  # RINEX 3.04: BDT - UTC; GPST = BDT + 14 s
                leap -= int(BDT_MINUS_GPST_S)
    return iono, leap


def _scan_v2_v3(path, lines, body, systems, version, file_letter):
    """Find the records of RINEX 2/3: system letter in column 1 (RINEX 2: one system per
    file, ``file_letter``), a fixed number of lines per system."""
    v3 = version >= 3
    glo_lines = 5 if version >= 3.05 else 4  # RINEX 3.05 added a 5th GLONASS line
    found: dict[str, _Found] = {}
    skipped: Counter = Counter()
    i, n = body, len(lines)
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        letter = line[:1].decode("ascii", "replace") if v3 else file_letter
        if letter not in _NAV_LINES:
            raise RinexError(path, i + 1, "expected a navigation record starting with a "
                             f"satellite number such as 'G05' or 'C21', got {line[:3]!r}")
        count = glo_lines if letter == "R" else _NAV_LINES[letter]
        if i + count > n:
            raise RinexError(path, n, f"expected {count} lines for the record of "
                             f"{line[:3].decode('ascii', 'replace').strip()} starting at line "
                             f"{i + 1}, file ends")
        if letter not in systems:
            skipped[letter] += 1
            i += count
            continue
        _check_continuation(path, lines, i, count)
        if v3:
            sat = line[:3].decode("ascii", "replace").replace(" ", "0")
            date = line[3:23]
        else:
            sat = f"{letter}{_int(path, i + 1, line[:2], 'a PRN number in columns 1-2'):02d}"
            date = line[2:22]
        f = found.setdefault(letter, _Found(count))
        f.sats.append(sat)
        f.starts.append(i)
        f.tocs.append(_toc(path, i + 1, date))
        i += count
    return found, skipped


def _scan_v4(path, lines, body, systems, iono):
    """Find the records of RINEX 4: each starts with a ``> TYPE SAT MESSAGE`` line (type in
    columns 3-5, satellite 7-9, message 11-14) and runs to the next ``>`` line. Klobuchar
    and NeQuick-G ``ION`` records go into ``iono`` (the first of each key is kept)."""
    found: dict[str, _Found] = {}
    skipped: Counter = Counter()
    i, n = body, len(lines)
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        if line[:1] != b">":
            raise RinexError(path, i + 1, "expected a RINEX 4 record line starting with '>' "
                             "such as '> EPH G05 LNAV'")
        rtype = line[2:5].decode("ascii", "replace")
        sat = line[6:9].decode("ascii", "replace").replace(" ", "0")
        msg = line[10:14].decode("ascii", "replace").strip()
        letter = sat[:1]
        end = i + 1
        while end < n and lines[end][:1] != b">":
            end += 1
        last = end
        while last > i + 1 and not lines[last - 1].strip():
            last -= 1
        nbody = last - i - 1  # lines of the record after its '>' line, blank tail dropped
        if rtype == "EPH":
            if letter not in _NAV_LINES:
                raise RinexError(path, i + 1, "expected a satellite number such as 'G05' in "
                                 f"columns 7-9, got {sat!r}")
            count = _V4_EPH_LINES.get((letter, msg))
            if letter not in systems:
                skipped[letter] += 1
            elif count is None:
                skipped[f"{letter} {msg}"] += 1
            else:
                if nbody != count:
                    raise RinexError(path, i + 1, f"expected {count} lines after "
                                     f"'> EPH {sat} {msg}', got {nbody}")
                first = lines[i + 1]
                if first[:3].decode("ascii", "replace").replace(" ", "0") != sat:
                    raise RinexError(path, i + 2, f"expected the record of {sat} (as on "
                                     f"line {i + 1}), got {first[:3]!r}")
                _check_continuation(path, lines, i + 1, count)
                # Every message type read of one system has the same line count.
                f = found.setdefault(letter, _Found(count))
                f.sats.append(sat)
                f.starts.append(i + 1)
                f.tocs.append(_toc(path, i + 2, first[3:23]))
                f.kinds.append(msg)
        elif rtype == "ION":
            klob = _KLOBUCHAR.get(letter) if letter != "C" or msg == "D1D2" else None
            if klob is not None:
                if nbody < 3:
                    raise RinexError(path, i + 1, "expected 3 lines after "
                                     f"'> ION {sat} {msg}' (Klobuchar), got {nbody}")
                a = [_nav_num(path, i + 2, lines[i + 1], 23 + 19 * k) for k in range(3)]
                b = [_nav_num(path, i + 3, lines[i + 2], 4 + 19 * k) for k in range(4)]
                b.append(_nav_num(path, i + 4, lines[i + 3], 4))
                iono.setdefault(klob + "A", np.array(a + b[:1]))  # alpha0-3
                iono.setdefault(klob + "B", np.array(b[1:]))  # beta0-3
            elif letter == "E" and msg == "IFNV" and nbody >= 1:  # NeQuick-G ai0-ai2
                ai = [_nav_num(path, i + 2, lines[i + 1], 23 + 19 * k) for k in range(3)]
                iono.setdefault("GAL", np.array(ai + [math.nan]))
            else:
                skipped[f"ION {letter} {msg}"] += 1
        elif rtype in ("STO", "EOP"):
            skipped[rtype] += 1
        else:
            raise RinexError(path, i + 1, "expected a record type EPH, STO, EOP or ION in "
                             f"columns 3-5, got {rtype!r}")
        i = end
    return found, skipped


def _check_continuation(path, lines, i: int, count: int) -> None:
    for j in range(1, count):
        if lines[i + j][:1].strip():
            raise RinexError(path, i + j + 1, f"expected {count - 1} broadcast-orbit lines "
                             f"after line {i + 1}, got a new record")


def _toc(path, lineno: int, text: bytes) -> float:
    """The time of clock 'yyyy mm dd hh mm ss' (RINEX 2: 'yy ...', seconds with decimals),
    as seconds since 1980-01-06 in the file's time scale."""
    date = text.split()
    if len(date) != 6:
        raise RinexError(path, lineno, "expected the time of clock 'yyyy mm dd hh mm ss'")
    try:
        yy = int(date[0])
        yy = yy + (2000 if yy < 80 else 1900) if yy < 100 else yy
        return gps_seconds(yy, *(int(x) for x in date[1:5]), float(date[5]))
    except ValueError:
        raise RinexError(path, lineno, "expected a valid time of clock") from None


def _nav_values(path, lines, starts: np.ndarray, count: int, width: int, first_w: int,
                cont_w: int) -> np.ndarray:
    """(N, width) numbers of the records starting at lines ``starts`` (``count`` lines
    each): 3 from column ``first_w`` of the first line, 4 from ``cont_w`` of the others,
    19 columns each; blank or absent fields NaN."""
    vals = np.full((starts.size, width), np.nan)
    for j in range(count):
        blk = _block(lines, starts + j, 80)
        lineno = starts + j + 1
        for k in range(3 if j == 0 else 4):
            start = (first_w if j == 0 else cont_w) + 19 * k
            vals[:, (0 if j == 0 else 4 * j - 1) + k] = _fields(path, blk, lineno, start, 19)
    return vals


def _kinds_v2_v3(letter: str, sats: np.ndarray, vals: np.ndarray) -> np.ndarray:
    """Message kind of RINEX 2/3 records (RINEX 4 writes it; see ``NavFile.kinds``)."""
    if letter == "E":
        # RINEX 3.05 A8, data sources: bit 0 I/NAV E1-B, bit 1 F/NAV E5a-I, bit 2 I/NAV E5b-I.
        src = np.nan_to_num(vals[:, 20]).astype(np.int64)
        inav, fnav = (src & 0b101) != 0, (src & 0b010) != 0
        return np.where(inav & ~fnav, "INAV", np.where(fnav & ~inav, "FNAV", ""))
    if letter == "C":
        prn = np.array([int(s[1:]) for s in sats])
        return np.where((prn <= 5) | (prn >= 59), "D2", "D1")
    return np.full(len(sats), {"R": "FDMA", "S": "SBAS"}.get(letter, "LNAV"))


def _merge(parts: list[tuple[NavFile, int | None]], systems: str) -> NavFile:
    """One NavFile from per-file ones: records concatenated in file order, then the
    duplicates (same satellite, toc and kind) dropped; notes written."""
    navs = [nav for nav, _ in parts]
    iono: dict[str, np.ndarray] = {}
    skipped: Counter = Counter()
    for nav in navs:
        for key, coef in nav.iono.items():
            iono.setdefault(key, coef)
        skipped.update(nav.skipped)
    notes = []
    for key, count in skipped.items():
        letter, _, msg = key.partition(" ")
        if key in NAV_SYSTEMS:
            used = ", ".join(NAV_SYSTEMS[x] for x in systems)
            notes.append(f"{_plural(count, 'record')} of {NAV_SYSTEMS[key]} skipped (systems "
                         f"read: {used})")
        elif letter in NAV_SYSTEMS:
            notes.append(f"{_plural(count, 'record')} of {NAV_SYSTEMS[letter]} {msg} skipped "
                         "(message type not read)")
    records, kinds = {}, {}
    conflicts: Counter = Counter()
    for letter in systems:
        got = [nav for nav in navs if letter in nav.records]
        if not got:
            continue
        sats = np.concatenate([nav.records[letter][0] for nav in got])
        toc = np.concatenate([nav.records[letter][1] for nav in got])
        vals = np.concatenate([nav.records[letter][2] for nav in got])
        kind = np.concatenate([nav.kinds[letter] for nav in got])
        first: dict[tuple, int] = {}
        keep = []
        for k, key in enumerate(zip(sats.tolist(), toc.tolist(), kind.tolist(), strict=True)):
            j = first.setdefault(key, k)
            if j == k:
                keep.append(k)
            elif not np.array_equal(vals[j], vals[k], equal_nan=True):
                conflicts[sats[k]] += 1
        keep = np.array(keep, dtype=int)
        records[letter] = (sats[keep], toc[keep], vals[keep])
        kinds[letter] = kind[keep]
    for sat, count in sorted(conflicts.items()):
        notes.append(f"{sat}: {_plural(count, 'duplicate record')} with different values "
                     "(same toc and message), kept the first")
    leaps = [leap for _, leap in parts if leap is not None]
    if len(set(leaps)) > 1:
        notes.append(f"the files' LEAP SECONDS disagree ({', '.join(map(str, leaps))} s): "
                     f"each file's GLONASS tocs use its own, leap_s is {leaps[0]} s")
    finite = [nav.leap_s for nav in navs if math.isfinite(nav.leap_s)]
    leap_s = float(leaps[0]) if leaps else (finite[0] if finite else math.nan)
    paths = tuple(nav.path for nav in navs)
    return NavFile(", ".join(paths), navs[0].version, iono, records, dict(skipped), kinds,
                   tuple(notes), leap_s, paths)


def _plural(count: int, what: str) -> str:
    return f"{count} {what}" + ("" if count == 1 else "s")


def _nav_num(path, lineno, line: bytes, start: int, width: int = 19) -> float:
    """The number in columns ``start:start+width`` of ``line``; NaN when blank."""
    text = line[start:start + width].strip()
    if not text:
        return math.nan
    return _float(path, lineno, text, f"a number in columns {start + 1}-{start + width}")
