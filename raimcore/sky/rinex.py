"""RINEX 2.11 / 3.0x observation and navigation readers (code pseudoranges, GPS + BeiDou).

Only what single-point positioning needs is kept: epochs (time, flag), the header position,
code pseudoranges (observation types starting with ``C`` or ``P``) per satellite, the
broadcast ephemerides of GPS and BeiDou, and the Klobuchar coefficients. Other systems'
navigation records are skipped by their line counts (GLONASS: 4 lines, 5 in RINEX 3.05;
SBAS: 4; Galileo, QZSS, IRNSS: 8).

The satellite-record blocks are parsed with fixed-width slicing of a ``(lines, columns)``
byte array, so a 2-hour 30-s mixed file (10,000 satellite records) loads in well under a
second. No third-party reader is used: the format is simple and a reader dependency
(georust, georinex) would not earn its place.

Times are GPS seconds since 1980-01-06 00:00:00 GPST (float). BeiDou times (BDT) are
converted with BDT = GPST - 14 s (BDS-SIS-ICD-B1I 3.0, 4.2).

Errors in the input raise :class:`RinexError` (a ``ValueError``) naming the file, the line
and what was expected.

References
----------
RINEX 2.11 (Gurtner & Estey 2007), RINEX 3.05 (IGS/RTCM 2020).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np

__all__ = ["RinexError", "ObsFile", "NavFile", "read_obs", "read_nav", "gps_seconds",
           "BDT_MINUS_GPST_S", "BDS_WEEK0_GPS_WEEK"]

_GPS_EPOCH = datetime(1980, 1, 6)
BDT_MINUS_GPST_S = -14.0  # BDS-SIS-ICD-B1I 3.0, 4.2: BDT = GPST - 14 s
BDS_WEEK0_GPS_WEEK = 1356  # BDT week 0 starts 2006-01-01 00:00:00 BDT (ICD 4.2)

#: Lines per navigation record (all lines, including the first) by system letter.
_NAV_LINES = {"G": 8, "C": 8, "E": 8, "J": 8, "I": 8, "R": 4, "S": 4}


class RinexError(ValueError):
    """A malformed or truncated RINEX file: names the file, the line (1-based) and what
    was expected."""

    def __init__(self, path, line: int | None, message: str):
        self.path = str(path)
        self.line = line
        where = f"{self.path}, line {line}" if line is not None else self.path
        super().__init__(f"{where}: {message}")


def gps_seconds(year, month, day, hour, minute, second) -> float:
    """Calendar date (in the file's time scale) to seconds since the GPS epoch."""
    whole = math.floor(second)
    dt = datetime(int(year), int(month), int(day), int(hour), int(minute), int(whole))
    return (dt - _GPS_EPOCH).total_seconds() + (second - whole)


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
    """GPS and BeiDou broadcast ephemerides of a RINEX navigation file.

    Attributes
    ----------
    path, version : file name and RINEX version.
    iono : Klobuchar coefficients, "GPSA"/"GPSB" (and "BDSA"/"BDSB" when present), (4,).
    records : system letter ("G", "C") -> ``(sats (N,), toc_gps_s (N,), values (N, 29))``;
        ``values`` holds the record's numbers in file order (af0, af1, af2, then four per
        broadcast-orbit line; missing trailing fields NaN).
    skipped : system letter -> number of records of other systems skipped.
    """

    path: str
    version: float
    iono: dict[str, np.ndarray]
    records: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]
    skipped: dict[str, int] = field(default_factory=dict)


# -- low-level helpers -----------------------------------------------------------------

def _read_lines(path) -> list[bytes]:
    p = Path(path)
    if not p.is_file():
        raise RinexError(path, None, "file does not exist")
    return p.read_bytes().splitlines()


def _label(line: bytes) -> str:
    return line[60:80].decode("ascii", "replace").strip()


def _header(path, lines: list[bytes], kind: str) -> tuple[float, int]:
    """Version and the index of the first line after ``END OF HEADER``."""
    if not lines or _label(lines[0]) != "RINEX VERSION / TYPE":
        raise RinexError(path, 1, "expected the 'RINEX VERSION / TYPE' header line")
    try:
        version = float(lines[0][:9])
    except ValueError:
        raise RinexError(path, 1, "expected a RINEX version number in columns 1-9") from None
    ftype = lines[0][20:21].decode("ascii", "replace")
    if ftype != kind:
        what = {"O": "an observation", "N": "a navigation"}[kind]
        raise RinexError(path, 1, f"expected {what} file (type '{kind}' in column 21), "
                         f"got '{ftype}'")
    if int(version) not in (2, 3):
        raise RinexError(path, 1, f"expected RINEX version 2.xx or 3.xx, got {version}")
    for i, line in enumerate(lines):
        if _label(line) == "END OF HEADER":
            return version, i + 1
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
    blank fields are NaN. A bad number raises naming its line."""
    sub = np.ascontiguousarray(block[:, start:start + width]).view(f"S{width}").ravel()
    sub = np.char.strip(sub)
    blank = sub == b""
    try:
        vals = np.where(blank, b"nan", sub).astype(float)
        bad = ~blank & ~np.isfinite(vals)  # "nan" or "inf" written in the file
    except ValueError:
        bad = ~blank
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
    """Read a RINEX 2.11 or 3.0x observation file (code pseudoranges).

    Raises
    ------
    RinexError (a ValueError) for a missing file, a malformed header, epoch line or
    number, or a file that ends inside an epoch.
    """
    lines = _read_lines(path)
    version, body = _header(path, lines, "O")
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

def read_nav(path, systems: str = "GC") -> NavFile:
    """Read the GPS (``G``) and BeiDou (``C``) records of a RINEX 2 or 3 navigation file.

    RINEX 2 ``N`` files are GPS only; RINEX 3 mixed files hold every system, and records of
    the systems not in ``systems`` are skipped by their line counts.

    Raises
    ------
    RinexError (a ValueError) for a malformed header or record, an unknown system letter,
    or a file that ends inside a record.
    """
    lines = _read_lines(path)
    version, body = _header(path, lines, "N")
    iono: dict[str, np.ndarray] = {}
    for i, line in enumerate(lines[:body]):
        lab = _label(line)
        if lab == "IONOSPHERIC CORR":
            key = line[:4].decode("ascii", "replace").strip()
            iono[key] = np.array([_float(path, i + 1, line[5 + 12 * k:17 + 12 * k],
                                         "a Klobuchar coefficient") for k in range(4)])
        elif lab in ("ION ALPHA", "ION BETA"):
            key = "GPSA" if lab == "ION ALPHA" else "GPSB"
            iono[key] = np.array([_float(path, i + 1, line[2 + 12 * k:14 + 12 * k],
                                         "a Klobuchar coefficient") for k in range(4)])
    v3 = version >= 3
    glo_lines = 5 if v3 and version >= 3.05 else 4  # RINEX 3.05 added a 5th GLONASS line
    first_w, cont_w = (23, 4) if v3 else (22, 3)
    rec: dict[str, list] = {s: [] for s in systems}
    skipped: dict[str, int] = {}
    i, n = body, len(lines)
    while i < n:
        line = lines[i]
        if not line.strip():
            i += 1
            continue
        letter = line[:1].decode("ascii", "replace") if v3 else "G"
        if v3 and letter not in _NAV_LINES:
            raise RinexError(path, i + 1, "expected a navigation record starting with a "
                             f"satellite number such as 'G05' or 'C21', got {line[:3]!r}")
        count = glo_lines if letter == "R" else _NAV_LINES[letter]
        if i + count > n:
            raise RinexError(path, n, f"expected {count} lines for the record of "
                             f"{line[:3].decode('ascii', 'replace').strip()} starting at line "
                             f"{i + 1}, file ends")
        if letter not in rec:
            skipped[letter] = skipped.get(letter, 0) + 1
            i += count
            continue
        if v3:
            sat = line[:3].decode("ascii", "replace").replace(" ", "0")
            date = line[3:23].split()
        else:
            sat = f"G{_int(path, i + 1, line[:2], 'a PRN number in columns 1-2'):02d}"
            date = line[2:22].split()
        if len(date) != 6:
            raise RinexError(path, i + 1, "expected the time of clock 'yyyy mm dd hh mm ss'")
        try:
            yy = int(date[0])
            yy = yy + (2000 if yy < 80 else 1900) if yy < 100 else yy
            toc = gps_seconds(yy, *(int(x) for x in date[1:5]), float(date[5]))
        except ValueError:
            raise RinexError(path, i + 1, "expected a valid time of clock") from None
        if letter == "C":
            toc -= BDT_MINUS_GPST_S
        vals = []
        for k in range(3):
            vals.append(_nav_num(path, i + 1, line, first_w + 19 * k))
        for j in range(1, count):
            nxt = lines[i + j]
            if nxt[:1].strip():
                raise RinexError(path, i + j + 1, f"expected {count - 1} broadcast-orbit lines "
                                 f"after line {i + 1}, got a new record")
            for k in range(4):
                vals.append(_nav_num(path, i + j + 1, nxt, cont_w + 19 * k))
        rec[letter].append((sat, toc, vals))
        i += count
    records = {}
    for s, lst in rec.items():
        if lst:
            records[s] = (np.array([r[0] for r in lst]), np.array([r[1] for r in lst]),
                          np.array([r[2] for r in lst], dtype=float))
    return NavFile(str(path), version, iono, records, skipped)


def _nav_num(path, lineno, line: bytes, start: int) -> float:
    text = line[start:start + 19].strip()
    if not text:
        return math.nan
    return _float(path, lineno, text, f"a number in columns {start + 1}-{start + 19}")
