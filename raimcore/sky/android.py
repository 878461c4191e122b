"""Android GnssLogger raw logs -> the RINEX observation structure (code pseudoranges).

Google's GnssLogger app writes a comma-separated text log: ``#`` comment lines (among them
``# Version: ...`` and one header per record type, ``# Raw,ElapsedRealtimeMillis,
TimeNanos,...``) and records ``Raw,...`` (one per satellite signal per measurement epoch,
the ``GnssClock`` and ``GnssMeasurement`` fields of the Android API), ``Fix,...`` (the
phone's own position), ``Nav``, ``Status``, ``Accel``, ... :func:`read_android` turns the
``Raw`` records into a :class:`~raimcore.sky.rinex.ObsFile`, so the correction and
positioning chain of :mod:`raimcore.sky.spp` takes a phone exactly like a RINEX recording;
:func:`read_android_log` returns the same with what an ``ObsFile`` has no room for (the
measurement uncertainties as weights, C/N0, clock discontinuities, the phone's own fix,
what was rejected and why) in an :class:`AndroidLog`.

Formats. Columns are found by name from the ``# Raw,`` header line (their order and number
differ between logger versions), so logger format 1.4 (``# Version: 1.4.0.0, Platform:
N``, Android 7) and every later one (``# Version: v2.0.0.1 ...``, ``v3.0.x`` with
``CodeType`` and ``FullInterSignalBiasNanos``) are read. Logs older than 1.4 are refused
(their header was different; gps-measurement-tools ``ReadGnssLogger.m`` refuses them too);
a log without a ``# Version`` line is read when it has a ``# Raw,`` header. The file may be
gzip, zip, bzip2 or ``.Z`` compressed (:func:`raimcore.sky.compressed.read_bytes`).

Pseudoranges (GSA white paper "Using GNSS Raw Measurements on Android Devices", 2017,
section 2.4; Google gps-measurement-tools ``ProcessGnssMeas.m``), in integer nanoseconds
where the numbers exceed a double's 53 bits (``FullBiasNanos`` ~ 1.2e18):

- receiver time, GPS scale: ``t_rx = TimeNanos + TimeOffsetNanos - (FullBiasNanos_0 +
  BiasNanos_0)``, with ``FullBiasNanos_0``, ``BiasNanos_0`` those of the first usable
  measurement of the current hardware-clock segment: the receiver clock then runs freely
  and continuously (its drift goes into the receiver clock bias, solved with the position)
  instead of jumping each time the phone re-estimates its bias. A change of
  ``HardwareClockDiscontinuityCount`` (the hardware clock restarted, e.g. duty cycling)
  starts a new segment with a new reference; :attr:`AndroidLog.clock_reset` marks where.
  The sign of ``TimeOffsetNanos`` is the Android API's ("measurement time = TimeNanos +
  TimeOffsetNanos"); ``ProcessGnssMeas.m`` subtracts it (it is zero in most logs);
- the receiver time in the satellite's system time, modulo that time's period: GPS and
  Galileo time of week; BeiDou time of week with BDT = GPST - 14 s (BDS-SIS-ICD-B1I 3.0,
  4.2); GLONASS time of day, GLONASS time = UTC(SU) + 3 h = GPST - leap + 3 h (GLONASS
  ICD ed. 5.1, 3.3.3), the leap seconds from the record's ``LeapSecond`` field when given,
  else :func:`~raimcore.sky.rinex.gps_minus_utc_s`;
- ``pr = c (t_rx_sys - ReceivedSvTimeNanos)``, the difference wrapped into half a period
  either side of zero: the week (or day) rollover between transmission and reception.

The epoch time tag (``ObsFile.t_gps_s``) is the receiver time of the epoch
(``TimeNanos - FullBiasNanos_0 - BiasNanos_0``), the same clock as the pseudoranges, as in
RINEX; epochs are the distinct ``(clock segment, TimeNanos)`` pairs, in time order.

Measurements kept (Android ``GnssMeasurement.getState``): code lock and a time of week
(GPS, BeiDou, Galileo) or of day (GLONASS) decoded or known, not millisecond-ambiguous,
``ReceivedSvTimeUncertaintyNanos <= max_sv_time_unc_ns`` (500 ns in gps-measurement-tools'
``GnssThresholds.MAXTOWUNCNS``) and ``PseudorangeRateUncertaintyMetersPerSecond <=
max_prr_unc_mps`` (``MAXPRRUNCMPS``, 10 m/s). Galileo E1 measurements with only the E1C
secondary-code lock (time known modulo 100 ms) are not resolved: rejected and counted.
QZSS, SBAS, IRNSS and unknown constellations are skipped and counted, as are GLONASS
satellites known only by their frequency channel (Svid 93-106 = FCN + 100: no slot number).
Every rejection is counted in :attr:`AndroidLog.counts` and explained in its notes.

Names. Satellites ``G05``, ``E07``, ``C21``, ``R12`` (GLONASS Svid 1-24 is the orbital
slot). Observation codes as in RINEX 3, band from ``CarrierFrequencyHz`` (blank: L1 / B1I,
what Android 7 phones tracked) and attribute from ``CodeType`` when the log has it, else
the usual phone signal: GPS ``C1C`` / ``C5Q``, Galileo ``C1C`` / ``C5Q``, BeiDou ``C2I``
(B1I) / ``C1P`` (B1C) / ``C5P`` (B2a), GLONASS ``C1C``. L1 and L5 of one satellite are
different codes, never mixed.

Errors in the input raise :class:`AndroidLogError` (a :class:`~raimcore.sky.rinex.RinexError`,
so a ``ValueError``) naming the file, the line and what was expected.

References
----------
European GNSS Agency (2017), Using GNSS Raw Measurements on Android Devices, white paper,
section 2.4 (pseudorange generation). Google, gps-measurement-tools, ``ReadGnssLogger.m``,
``ProcessGnssMeas.m``, ``GnssThresholds.m`` (github.com/google/gps-measurement-tools).
Android API reference, ``android.location.GnssMeasurement`` (``getState``,
``getReceivedSvTimeNanos``, ``getTimeOffsetNanos``, ``getCodeType``) and ``GnssClock``.
"""

from __future__ import annotations

import math
import re
from collections import Counter
from dataclasses import dataclass, field
from decimal import Decimal, InvalidOperation
from typing import NamedTuple

import numpy as np

from .._validate import check_positive
from ..constants import C_MPS
from ..geometry import geodetic_to_ecef
from .compressed import RinexError, read_bytes
from .rinex import BDT_MINUS_GPST_S, ObsFile, gps_minus_utc_s

__all__ = ["AndroidLog", "AndroidLogError", "read_android", "read_android_log",
           "pseudorange_m", "MAX_SV_TIME_UNC_NS", "MAX_PRR_UNC_MPS"]

NS_PER_S = 1_000_000_000
WEEK_NS = 604_800 * NS_PER_S  # IS-GPS-200 20.3.3.3.3.1 (seconds in a GPS week)
DAY_NS = 86_400 * NS_PER_S
BDT_OFFSET_NS = int(BDT_MINUS_GPST_S) * NS_PER_S  # BDS-SIS-ICD-B1I 3.0, 4.2: BDT = GPST - 14 s
GLO_UTC_OFFSET_NS = 3 * 3600 * NS_PER_S  # GLONASS ICD ed. 5.1, 3.3.3: UTC(SU) + 3 h
#: Largest travel time accepted after the rollover wrap (s): gps-measurement-tools'
#: ``CheckGpsWeekRollover`` refuses a larger common bias (``maxBiasSeconds = 10``).
MAX_TRAVEL_S = 10.0
#: gps-measurement-tools ``GnssThresholds.MAXTOWUNCNS``: 500 ns.
MAX_SV_TIME_UNC_NS = 500.0
#: gps-measurement-tools ``GnssThresholds.MAXPRRUNCMPS``: 10 m/s.
MAX_PRR_UNC_MPS = 10.0

# android.location.GnssMeasurement state bits (Android API reference, getState()).
STATE_CODE_LOCK = 1
STATE_TOW_DECODED = 8
STATE_MSEC_AMBIGUOUS = 16
STATE_GLO_TOD_DECODED = 128
STATE_GAL_E1BC_CODE_LOCK = 1024
STATE_GAL_E1C_2ND_CODE_LOCK = 2048
STATE_TOW_KNOWN = 16384
STATE_GLO_TOD_KNOWN = 32768

#: android.location.GnssStatus constellation types -> system letter (None: skipped).
CONSTELLATIONS = {1: "G", 2: None, 3: "R", 4: None, 5: "C", 6: "E", 7: None, 0: None}
_SKIPPED_NAMES = {2: "SBAS", 4: "QZSS", 7: "IRNSS", 0: "unknown constellation"}
_SYSTEM_NAMES = {"G": "GPS", "R": "GLONASS", "C": "BeiDou", "E": "Galileo"}
#: Largest satellite number per system (GPS PRN, GLONASS slot, BeiDou and Galileo PRN).
_MAX_SVID = {"G": 32, "R": 24, "C": 63, "E": 36}

#: (letter, lo_hz, hi_hz, RINEX band digit) of each carrier a phone reports; a measured
#: ``CarrierFrequencyHz`` is matched within 2 MHz (GLONASS G1 over its 14 FDMA channels).
_BANDS = (
    ("G", 1573.42e6, 1577.42e6, "1"), ("G", 1174.45e6, 1178.45e6, "5"),
    ("G", 1225.60e6, 1229.60e6, "2"),
    ("E", 1573.42e6, 1577.42e6, "1"), ("E", 1174.45e6, 1178.45e6, "5"),
    ("E", 1205.14e6, 1209.14e6, "7"), ("E", 1276.75e6, 1280.75e6, "6"),
    ("C", 1559.098e6, 1563.098e6, "2"), ("C", 1573.42e6, 1577.42e6, "1"),
    ("C", 1174.45e6, 1178.45e6, "5"), ("C", 1205.14e6, 1209.14e6, "7"),
    ("C", 1266.52e6, 1270.52e6, "6"),
    ("R", 1596.0e6, 1608.0e6, "1"), ("R", 1240.0e6, 1252.0e6, "2"),
)
#: Band of a blank ``CarrierFrequencyHz`` (Android: "if not set, L1"; BeiDou B1I).
_BLANK_BAND = {"G": "1", "E": "1", "C": "2", "R": "1"}
#: RINEX attribute when the log has no ``CodeType``: the signal phones track.
_DEFAULT_ATTR = {("G", "1"): "C", ("G", "5"): "Q", ("G", "2"): "L", ("E", "1"): "C",
                 ("E", "5"): "Q", ("E", "7"): "Q", ("E", "6"): "C", ("C", "2"): "I",
                 ("C", "1"): "P", ("C", "5"): "P", ("C", "7"): "I", ("C", "6"): "I",
                 ("R", "1"): "C", ("R", "2"): "C"}

#: Raw columns read; the first group must be in the header.
_REQUIRED = ("TimeNanos", "FullBiasNanos", "Svid", "State", "ReceivedSvTimeNanos",
             "ConstellationType")
_OPTIONAL = ("BiasNanos", "TimeOffsetNanos", "HardwareClockDiscontinuityCount",
             "ReceivedSvTimeUncertaintyNanos", "Cn0DbHz", "PseudorangeRateMetersPerSecond",
             "PseudorangeRateUncertaintyMetersPerSecond", "CarrierFrequencyHz", "CodeType",
             "LeapSecond", "BiasUncertaintyNanos")


class _Raw(NamedTuple):
    """The fields of one ``Raw`` record that are used (NaN / None where blank)."""

    lineno: int
    time_ns: int
    full_bias_ns: int | None
    bias_ns: float
    time_offset_ns: float
    clock_count: int | None
    svid: int
    constellation: int
    state: int
    sv_time_ns: int
    sv_time_unc_ns: float
    cn0_dbhz: float
    prr_mps: float
    prr_unc_mps: float
    carrier_hz: float
    code_type: str
    leap_s: float
    bias_unc_ns: float


class AndroidLogError(RinexError):
    """A file that is not a GnssLogger log, or a malformed one: names the file, the line
    (1-based, when there is one) and what was expected."""


@dataclass(frozen=True)
class AndroidLog:
    """A GnssLogger log: the observations and what an :class:`ObsFile` has no room for.

    ``E`` epochs and ``S`` satellites are those of ``obs``; the per-measurement
    dictionaries have the keys of ``obs.codes`` and NaN where ``obs.codes`` is NaN.

    Attributes
    ----------
    obs : the pseudoranges as an :class:`~raimcore.sky.rinex.ObsFile`: ``version`` is the
        logger format (1.4, 3.0, ...; not a RINEX version), ``marker`` the phone model when
        the header names it, ``approx_pos_ecef_m`` zeros (a phone log has no surveyed
        position), ``time_system`` "GPS", ``epoch_flag`` zeros.
    sigma_m : code -> (E, S) pseudorange 1-sigma reported by the phone,
        ``c * ReceivedSvTimeUncertaintyNanos`` (m): weights ``1 / sigma_m**2`` for a
        least-squares solution (it describes tracking noise only, not multipath or the
        atmosphere). NaN where the log leaves the field blank.
    cn0_dbhz : code -> (E, S) carrier-to-noise density (dB-Hz).
    prr_mps, prr_sigma_mps : code -> (E, S) pseudorange rate and its 1-sigma (m/s).
    clock_count : (E,) ``HardwareClockDiscontinuityCount`` of each epoch.
    clock_reset : (E,) bool, True at the first epoch of each hardware-clock segment (the
        first epoch included): the receiver time reference is taken anew there, so the
        receiver clock bias may jump (a filter re-initialises its clock state there).
    clock_bias_sigma_m : (E,) ``c * BiasUncertaintyNanos`` of the epoch's reference
        measurement (m): how well the phone knew GPS time when the segment started.
    fix_ecef_m : (3,) the median of the phone's own ``Fix`` positions from the GPS
        provider (WGS-84, m), NaN without any: the phone's fix, not a truth.
    n_fix : number of GPS-provider ``Fix`` records in that median.
    counts : what was read and rejected, by reason (see :attr:`notes`): ``"Raw"`` and the
        other record types, ``"used"``, ``"skipped <constellation>"``, ``"rejected ..."``.
    notes : one sentence per reason a measurement was rejected or a record skipped, with
        its count.
    """

    obs: ObsFile
    sigma_m: dict[str, np.ndarray]
    cn0_dbhz: dict[str, np.ndarray]
    prr_mps: dict[str, np.ndarray]
    prr_sigma_mps: dict[str, np.ndarray]
    clock_count: np.ndarray
    clock_reset: np.ndarray
    clock_bias_sigma_m: np.ndarray
    fix_ecef_m: np.ndarray
    n_fix: int
    counts: dict[str, int] = field(default_factory=dict)
    notes: tuple[str, ...] = ()


# -- pure kernel -----------------------------------------------------------------------

def pseudorange_m(t_rx_ns, t_rx_frac_ns, received_sv_time_ns, letter: str, leap_s=None):
    """Pseudoranges from receiver time and received satellite time (white paper 2.4).

    Parameters
    ----------
    t_rx_ns : (N,) int, receiver time in GPS nanoseconds since 1980-01-06
        (``TimeNanos - FullBiasNanos_0``), exact integers.
    t_rx_frac_ns : (N,) float, the fractional part to add (``TimeOffsetNanos -
        BiasNanos_0``, ns).
    received_sv_time_ns : (N,) int, ``ReceivedSvTimeNanos`` (time of week, or of day for
        GLONASS, in the satellite's system time).
    letter : system letter "G", "E", "C" or "R".
    leap_s : (N,) GPS - UTC seconds (GLONASS only; default from the leap-second table).

    Returns
    -------
    pr_m : (N,) float pseudoranges (m), the travel time wrapped into half a week (a day
        for GLONASS) either side of zero, so a week rollover between transmission and
        reception is undone.

    Examples
    --------
    Reception 50 ms into a week, transmission 70 ms before its end:

    >>> week = 604_800 * 10**9
    >>> float(pseudorange_m([2000 * week + 50_000_000], [0.0], [week - 20_000_000], "G")[0])
    20985472.06
    """
    t = np.asarray(t_rx_ns, dtype=np.int64)
    sv = np.asarray(received_sv_time_ns, dtype=np.int64)
    if letter == "R":
        if leap_s is None:
            leap_s = gps_minus_utc_s(t // NS_PER_S)
        leap_ns = np.asarray(np.round(np.asarray(leap_s, dtype=float)), dtype=np.int64) * NS_PER_S
        period = DAY_NS
        t_sys = np.mod(t - leap_ns + GLO_UTC_OFFSET_NS, period)  # GLONASS time of day
    else:
        period = WEEK_NS
        shift = BDT_OFFSET_NS if letter == "C" else 0  # BDT = GPST - 14 s
        t_sys = np.mod(t + shift, period)  # time of week
    d = np.mod(t_sys - sv + period // 2, period) - period // 2  # rollover wrap
    return (d + np.asarray(t_rx_frac_ns, dtype=float)) * (C_MPS / NS_PER_S)


# -- reader ----------------------------------------------------------------------------

def read_android(path, *, max_sv_time_unc_ns: float = MAX_SV_TIME_UNC_NS,
                 max_prr_unc_mps: float = MAX_PRR_UNC_MPS) -> ObsFile:
    """The code pseudoranges of a GnssLogger log as an :class:`ObsFile` (see the module
    docstring; :func:`read_android_log` also returns the uncertainties and the notes).

    >>> from raimcore.sky.spp import correct, solve  # doctest: +SKIP
    >>> obs = read_android("pseudoranges_log_2016_06_30_21_26_07.txt")  # doctest: +SKIP
    >>> fix = solve(correct(obs, read_nav("hour1820.16n"), systems=("GPS",)))  # doctest: +SKIP
    """
    return read_android_log(path, max_sv_time_unc_ns=max_sv_time_unc_ns,
                            max_prr_unc_mps=max_prr_unc_mps).obs


def read_android_log(path, *, max_sv_time_unc_ns: float = MAX_SV_TIME_UNC_NS,
                     max_prr_unc_mps: float = MAX_PRR_UNC_MPS) -> AndroidLog:
    """Read a GnssLogger raw log (format 1.4 or later, plain or compressed).

    Parameters
    ----------
    path : str or os.PathLike, the log (``.txt``, or ``.gz`` / ``.zip`` / ``.bz2`` of it).
    max_sv_time_unc_ns : largest ``ReceivedSvTimeUncertaintyNanos`` kept (ns, > 0).
    max_prr_unc_mps : largest ``PseudorangeRateUncertaintyMetersPerSecond`` kept (m/s, > 0;
        ``math.inf`` keeps all).

    Returns
    -------
    AndroidLog, whose ``obs`` holds the pseudoranges.

    Raises
    ------
    ValueError naming the argument for a threshold that is not > 0.
    AndroidLogError (a ValueError) naming the file and line for a missing or unreadable
    file, a file with no ``# Raw,`` header line (not a GnssLogger log), a ``Raw`` record
    before that header, a logger version older than 1.4, a header lacking a required
    column, a record with a different number of fields than its header, a malformed
    number, or no ``Raw`` record at all.
    """
    max_unc = check_positive("max_sv_time_unc_ns", max_sv_time_unc_ns)
    max_prr = check_positive("max_prr_unc_mps", max_prr_unc_mps)
    text = read_bytes(path).decode("utf-8", "replace").lstrip("\ufeff")
    p = _Parser(path)
    p.scan(text.splitlines())
    return p.build(max_unc, max_prr)


_VERSION = re.compile(r"version:\s*v?(\d+)\.(\d+)", re.IGNORECASE)
_MODEL = re.compile(r"model:\s*([^,]+?)\s*(?:$|,|\w+:)", re.IGNORECASE)


class _Parser:
    """One pass over the lines: headers, Raw columns by name, Fix positions, counts."""

    def __init__(self, path):
        self.path = path
        self.version = math.nan
        self.model = ""
        self.raw_cols: dict[str, int] | None = None
        self.raw_width = 0
        self.fix_cols: dict[str, int] | None = None
        self.fix_width = 0
        self.records: Counter = Counter()
        self.rows: list[_Raw] = []
        self.fixes: list[tuple[float, float, float]] = []

    def error(self, lineno, message):
        return AndroidLogError(self.path, lineno, message)

    def scan(self, lines: list[str]) -> None:
        for i, line in enumerate(lines):
            s = line.strip()
            if not s:
                continue
            if s.startswith("#"):
                self._comment(i + 1, s.lstrip("#").strip())
                continue
            kind = s.split(",", 1)[0].strip()
            self.records[kind] += 1
            if kind == "Raw":
                self._raw(i + 1, s)
            elif kind == "Fix" and self.fix_cols is not None:
                self._fix(i + 1, s)
        if self.raw_cols is None:
            raise self.error(None, "expected an Android GnssLogger log: no '# Raw,' header "
                             "line naming the measurement columns")
        if not self.rows:
            raise self.error(None, "expected 'Raw,' measurement records after the '# Raw,' "
                             "header, found none")

    def _comment(self, lineno: int, body: str) -> None:
        m = _VERSION.search(body)
        if m and math.isnan(self.version):
            major, minor = int(m.group(1)), int(m.group(2))
            if (major, minor) < (1, 4):
                raise self.error(lineno, f"expected GnssLogger format 1.4 or later, got "
                                 f"version {major}.{minor} (older headers are not read)")
            self.version = float(f"{major}.{minor}")
            mm = _MODEL.search(body)
            if mm:
                self.model = mm.group(1).strip()
            return
        names = [c.strip() for c in body.split(",")]
        if names[0] == "Raw":
            cols = {n: k for k, n in enumerate(names[1:]) if n}
            missing = [n for n in _REQUIRED if n not in cols]
            if missing:
                raise self.error(lineno, "expected the '# Raw,' header to name the columns "
                                 f"{', '.join(_REQUIRED)}; missing {', '.join(missing)}")
            self.raw_cols, self.raw_width = cols, len(names) - 1
        elif names[0] == "Fix":
            cols = {}
            for k, n in enumerate(names[1:]):
                for key in ("Provider", "Latitude", "Longitude", "Altitude"):
                    if n.startswith(key) and key not in cols:
                        cols[key] = k
            if len(cols) == 4:
                self.fix_cols, self.fix_width = cols, len(names) - 1

    def _fields(self, lineno: int, s: str, width: int, kind: str) -> list[str]:
        f = [x.strip() for x in s.split(",")[1:]]
        if len(f) != width:
            raise self.error(lineno, f"expected {width} comma-separated fields after '{kind},'"
                             f" as in the '# {kind},' header, got {len(f)}")
        return f

    def _raw(self, lineno: int, s: str) -> None:
        if self.raw_cols is None:
            raise self.error(lineno, "expected the '# Raw,' header line before the first "
                             "'Raw,' record")
        f = self._fields(lineno, s, self.raw_width, "Raw")
        c = self.raw_cols

        def get(name):
            k = c.get(name)
            return f[k] if k is not None else ""

        def integer(name, required=True):
            txt = get(name)
            if not txt:
                if required:
                    raise self.error(lineno, f"expected an integer {name}, the field is blank")
                return None
            try:
                return int(txt)
            except ValueError:
                pass
            try:
                d = Decimal(txt)
                if d.is_finite() and d == d.to_integral_value():
                    return int(d)
            except InvalidOperation:
                pass
            raise self.error(lineno, f"expected an integer {name}, got {txt!r}")

        def number(name):
            txt = get(name)
            if not txt:
                return math.nan
            try:
                x = float(txt)
            except ValueError:
                x = math.inf
            if math.isinf(x):
                raise self.error(lineno, f"expected a number {name}, got {txt!r}")
            return x

        self.rows.append(_Raw(
            lineno, integer("TimeNanos"), integer("FullBiasNanos", required=False),
            number("BiasNanos"), number("TimeOffsetNanos"),
            integer("HardwareClockDiscontinuityCount", required=False),
            integer("Svid"), integer("ConstellationType"), integer("State"),
            integer("ReceivedSvTimeNanos"), number("ReceivedSvTimeUncertaintyNanos"),
            number("Cn0DbHz"), number("PseudorangeRateMetersPerSecond"),
            number("PseudorangeRateUncertaintyMetersPerSecond"), number("CarrierFrequencyHz"),
            get("CodeType"), number("LeapSecond"), number("BiasUncertaintyNanos")))

    def _fix(self, lineno: int, s: str) -> None:
        f = self._fields(lineno, s, self.fix_width, "Fix")
        c = self.fix_cols
        if f[c["Provider"]].lower() != "gps":
            return
        vals = []
        for key in ("Latitude", "Longitude", "Altitude"):
            txt = f[c[key]]
            try:
                x = float(txt) if txt else math.nan
            except ValueError:
                raise self.error(lineno, f"expected a number for the Fix {key}, got {txt!r}"
                                 ) from None
            vals.append(x)
        self.fixes.append(tuple(vals))

    # -- measurements -> arrays ---------------------------------------------------------

    def build(self, max_unc: float, max_prr: float) -> AndroidLog:
        counts: Counter = Counter({k: v for k, v in self.records.items()})
        rows = self.rows
        fb_all = [r.full_bias_ns for r in rows if r.full_bias_ns is not None]
        flip = bool(fb_all) and all(x > 0 for x in fb_all)
        if not flip and any(x > 0 for x in fb_all):
            bad = next(r.lineno for r in rows if (r.full_bias_ns or 0) > 0)
            raise self.error(bad, "expected a negative FullBiasNanos (TimeNanos minus GPS "
                             "time), as on the other lines; the sign changes here")
        if flip:
            counts["flipped FullBiasNanos sign"] = len(fb_all)
        # Pass 1: the measurements that pass the checks; the hardware-clock segments and
        # the time reference of each (its first usable measurement).
        seg = -1
        last_count = object()
        keep: list[tuple[_Raw, str, str, str, int]] = []  # row, letter, sat, code, segment
        ref: dict[int, tuple[int, float, float]] = {}  # FullBias_0, Bias_0, BiasUnc_0
        first_count: dict[int, int] = {}
        for r in rows:
            if r.clock_count != last_count:
                seg += 1
                last_count = r.clock_count
                first_count[seg] = r.clock_count or 0
            why = self._check(r, max_unc, max_prr)
            if isinstance(why, str):
                counts[why] += 1
                continue
            if r.full_bias_ns is None:
                counts["rejected no FullBiasNanos"] += 1
                continue
            if seg not in ref:
                ref[seg] = (-r.full_bias_ns if flip else r.full_bias_ns,
                            0.0 if math.isnan(r.bias_ns) else r.bias_ns, r.bias_unc_ns)
            keep.append((r, *why, seg))
        # Pass 2: pseudoranges per system (vectorised kernel).
        n = len(keep)
        t_int = np.array([r.time_ns - ref[sg][0] for r, *_, sg in keep], dtype=np.int64)
        frac = np.array([(0.0 if math.isnan(r.time_offset_ns) else r.time_offset_ns)
                         - ref[sg][1] for r, *_, sg in keep], dtype=float)
        sv_ns = np.array([r.sv_time_ns for r, *_ in keep], dtype=np.int64)
        leap = np.array([r.leap_s for r, *_ in keep], dtype=float)
        letters = np.array([x[1] for x in keep], dtype="U1")
        pr = np.full(n, np.nan)
        for letter in "GECR":
            sel = letters == letter
            if not sel.any():
                continue
            lp = None
            if letter == "R":
                lp = np.where(np.isfinite(leap[sel]), leap[sel],
                              gps_minus_utc_s(t_int[sel] // NS_PER_S))
            pr[sel] = pseudorange_m(t_int[sel], frac[sel], sv_ns[sel], letter, lp)
        bad_tau = np.abs(pr) > MAX_TRAVEL_S * C_MPS
        if bad_tau.any():
            counts["rejected travel time"] += int(bad_tau.sum())
        keep = [x for x, bad in zip(keep, bad_tau, strict=True) if not bad]
        pr = pr[~bad_tau]
        # Epochs: distinct (segment, TimeNanos), ordered by their receiver time.
        ep_time = {}
        for r, *_, sg in keep:
            if (sg, r.time_ns) not in ep_time:
                ti = r.time_ns - ref[sg][0]
                ep_time[(sg, r.time_ns)] = ti // NS_PER_S + (ti % NS_PER_S - ref[sg][1]) / NS_PER_S
        ep_keys = sorted(ep_time, key=lambda k: (ep_time[k], k))
        ep_index = {k: i for i, k in enumerate(ep_keys)}
        sats = sorted({x[2] for x in keep})
        col = {name: i for i, name in enumerate(sats)}
        e_n, s_n = len(ep_keys), len(sats)
        if e_n == 0:
            raise self.error(None, "expected at least one usable Raw measurement, none "
                             "passed the checks: " + "; ".join(_notes(counts, max_unc,
                                                                       max_prr)))
        # Fill the (E, S) arrays of each code; the first of duplicate measurements is kept.
        e_idx = np.array([ep_index[(sg, r.time_ns)] for r, *_, sg in keep], dtype=int)
        s_idx = np.array([col[x[2]] for x in keep], dtype=int)
        code_of = np.array([x[3] for x in keep])
        seen: set[tuple[str, int, int]] = set()
        first = np.zeros(len(keep), dtype=bool)
        keys = zip(code_of.tolist(), e_idx.tolist(), s_idx.tolist(), strict=True)
        for k, key in enumerate(keys):
            first[k] = key not in seen
            seen.add(key)
        if not first.all():
            counts["rejected duplicate"] += int((~first).sum())
        values = {"pr": pr,
                  "sigma": np.array([r.sv_time_unc_ns for r, *_ in keep]) * C_MPS / NS_PER_S,
                  "cn0": np.array([r.cn0_dbhz for r, *_ in keep], dtype=float),
                  "prr": np.array([r.prr_mps for r, *_ in keep], dtype=float),
                  "prr_sigma": np.array([r.prr_unc_mps for r, *_ in keep], dtype=float)}
        per_code: dict[str, dict[str, np.ndarray]] = {name: {} for name in values}
        letter_of = np.array([x[1] for x in keep])
        obs_types = {ltr: tuple(sorted(set(code_of[first & (letter_of == ltr)].tolist())))
                     for ltr in dict.fromkeys(letter_of.tolist())}
        for code in sorted(set(code_of.tolist())):
            sel = first & (code_of == code)
            for name, v in values.items():
                arr = np.full((e_n, s_n), np.nan)
                arr[e_idx[sel], s_idx[sel]] = v[sel]
                per_code[name][code] = arr
        used = int(first.sum())
        counts["used"] = used
        t = np.array([ep_time[k] for k in ep_keys], dtype=float)
        seg_ep = np.array([k[0] for k in ep_keys], dtype=int)
        reset = np.ones(e_n, dtype=bool)
        reset[1:] = seg_ep[1:] != seg_ep[:-1]
        count_ep = np.array([first_count[sg] for sg in seg_ep], dtype=int)
        bias_sig = np.array([ref[sg][2] * C_MPS / NS_PER_S for sg in seg_ep], dtype=float)
        obs = ObsFile(str(self.path), self.version, self.model, np.zeros(3), "GPS", obs_types,
                      t, np.zeros(e_n, dtype=int), tuple(sats), per_code["pr"], ())
        if self.fixes:
            lat, lon, h = np.nanmedian(np.array(self.fixes), axis=0)
            fix = np.asarray(geodetic_to_ecef(np.radians(lat), np.radians(lon), h), dtype=float)
        else:
            fix = np.full(3, np.nan)
        return AndroidLog(obs, per_code["sigma"], per_code["cn0"], per_code["prr"],
                          per_code["prr_sigma"], count_ep, reset, bias_sig, fix,
                          len(self.fixes), dict(counts), tuple(_notes(counts, max_unc,
                                                                      max_prr)))

    @staticmethod
    def _check(r: _Raw, max_unc: float, max_prr: float):
        """``(letter, satellite, code)`` of a usable measurement, else the count key of
        the reason it is not used."""
        svid, ctype, state, freq = r.svid, r.constellation, r.state, r.carrier_hz
        letter = CONSTELLATIONS.get(ctype)
        if letter is None:
            return f"skipped {_SKIPPED_NAMES.get(ctype, f'constellation type {ctype}')}"
        if letter == "R" and 93 <= svid <= 106:
            return "skipped GLONASS FCN-only Svid"
        if not 1 <= svid <= _MAX_SVID[letter]:
            return f"rejected {_SYSTEM_NAMES[letter]}: Svid outside 1-{_MAX_SVID[letter]}"
        if math.isnan(freq):
            band = _BLANK_BAND[letter]
        else:
            band = next((b for ltr, lo, hi, b in _BANDS if ltr == letter and lo <= freq <= hi),
                        None)
            if band is None:
                return f"rejected {_SYSTEM_NAMES[letter]}: CarrierFrequencyHz in no known band"
        name = _SYSTEM_NAMES[letter]
        if state & STATE_MSEC_AMBIGUOUS:
            return f"rejected {name}: millisecond ambiguous (State)"
        if letter == "E" and band == "1":
            lock = state & (STATE_GAL_E1BC_CODE_LOCK | STATE_CODE_LOCK)
        else:
            lock = state & STATE_CODE_LOCK
        if letter == "R":
            timed = state & (STATE_GLO_TOD_DECODED | STATE_GLO_TOD_KNOWN)
        else:
            timed = state & (STATE_TOW_DECODED | STATE_TOW_KNOWN)
        if not lock:
            return f"rejected {name}: no code lock (State)"
        if not timed:
            if letter == "E" and state & STATE_GAL_E1C_2ND_CODE_LOCK:
                return "rejected Galileo 100 ms ambiguous"
            span = "day" if letter == "R" else "week"
            return f"rejected {name}: time of {span} neither decoded nor known (State)"
        if r.sv_time_unc_ns > max_unc:
            return "rejected sv time uncertainty"
        if r.prr_unc_mps > max_prr:
            return "rejected prr uncertainty"
        ct = r.code_type
        attr = ct if len(ct) == 1 and ct.isalpha() else _DEFAULT_ATTR[(letter, band)]
        return letter, f"{letter}{svid:02d}", f"C{band}{attr}"


_REASONS = {
    "rejected no FullBiasNanos": "no FullBiasNanos (the phone had no GPS time yet)",
    "rejected travel time": f"travel time beyond {MAX_TRAVEL_S:g} s after the week "
                            "rollover (a wrong time of week)",
    "rejected duplicate": "duplicate of an earlier measurement of the same satellite, "
                          "signal and epoch (the first kept)",
    "skipped GLONASS FCN-only Svid": "GLONASS satellites known only by their frequency "
                                     "channel (Svid 93-106), no slot number: skipped",
    "rejected Galileo 100 ms ambiguous": "Galileo E1C secondary-code lock only (time "
                                         "known modulo 100 ms, not resolved)",
    "flipped FullBiasNanos sign": "every FullBiasNanos positive: taken with the opposite "
                                  "sign (as gps-measurement-tools does)",
}


def _notes(counts: Counter, max_unc: float, max_prr: float) -> list[str]:
    out = []
    for key in sorted(counts):
        v = counts[key]
        if not v or not (key.startswith(("rejected", "skipped")) or key in _REASONS):
            continue
        if key in _REASONS:
            text = _REASONS[key]
        elif key == "rejected sv time uncertainty":
            text = f"ReceivedSvTimeUncertaintyNanos above {max_unc:g} ns"
        elif key == "rejected prr uncertainty":
            text = f"pseudorange-rate uncertainty above {max_prr:g} m/s"
        elif key.startswith("skipped "):
            text = f"{key[8:]} measurements: skipped (not positioned)"
        else:
            text = key.split(" ", 1)[1]
        out.append(f"{v} Raw measurement{'s' if v != 1 else ''}: {text}")
    other = {k: v for k, v in counts.items() if k[:1].isupper() and k != "Raw"}
    if other:
        out.append("records other than Raw (no measurements; Fix gives fix_ecef_m): "
                   + ", ".join(f"{k} {v}" for k, v in sorted(other.items())))
    return out
