"""Small self-contained RINEX 2.11 / 3.0x / 4.00 files written by the tests themselves.

The navigation values are real broadcast records (GPS PRN 6 of 2021-04-28 from the IGS
``brdc1180.21n``; BeiDou C05 (GEO) and C23 (MEO), Galileo E01 (its F/NAV and I/NAV records
of the same toc) and GLONASS R01 of 2020-06-24/25 from ESBC's 3.05 mixed file,
``../shared/data/ESBC00DNK_R_20201770000_01D_MN.rnx``), so positions computed from them can
be checked against their known orbits. The RINEX 4 file is written by hand from the RINEX
4.00 format (IGS/RTCM 2021) and the layout of a DLR ``BRD400DLR`` merged file: the same
records as ``> EPH`` records, plus ``> STO``, ``> EOP``, ``> ION`` records and message types
the reader skips.
"""

from __future__ import annotations

from pathlib import Path


def _hdr(text: str, label: str) -> str:
    return f"{text:<60}{label}"


def _obs3_sat(sat: str, values) -> str:
    return sat + "".join("                " if v is None else f"{v:14.3f}  " for v in values)


def obs_v3(path: Path, *, version: str = "3.05", time_system: str = "GPS",
           truncate: bool = False, bad_number: bool = False, events: bool = True) -> Path:
    """Two GPS + one BDS satellites, three data epochs (flags 0, 1, 0), an event record
    (flag 4, two header lines) and a cycle-slip record (flag 6) in between."""
    lines = [
        _hdr(f"{version:>9}           OBSERVATION DATA    M (MIXED)", "RINEX VERSION / TYPE"),
        _hdr("snippet", "PGM / RUN BY / DATE"),
        _hdr("TEST", "MARKER NAME"),
        _hdr("  3582105.2910   532589.7313  5232754.8054", "APPROX POSITION XYZ"),
        _hdr("G    3 C1C L1C S1C", "SYS / # / OBS TYPES"),
        _hdr("C    2 C2I L2I", "SYS / # / OBS TYPES"),
        _hdr(f"  2020     6    25     0     0    0.0000000     {time_system}",
             "TIME OF FIRST OBS"),
        _hdr("", "END OF HEADER"),
        "> 2020 06 25 00 00  0.0000000  0  3",
        _obs3_sat("G05", [20000000.125, 105000000.5, 45.0]),
        _obs3_sat("G12", [21000000.250, None, 40.0]),
        _obs3_sat("C21", [22000000.500, 115000000.25]),
    ]
    if events:
        lines += ["> 2020 06 25 00 00 15.0000000  4  2",
                  _hdr("an event comment", "COMMENT"),
                  _hdr("another one", "COMMENT")]
    lines += [
        "> 2020 06 25 00 00 30.0000000  1  2",
        _obs3_sat("G05", [20000030.125, 105000001.5, 45.0]),
        _obs3_sat("C21", [22000030.500, 115000001.25]),
    ]
    if events:
        lines += ["> 2020 06 25 00 00 30.0000000  6  1",
                  _obs3_sat("G05", [None, 105000001.5])]
    lines += [
        "> 2020 06 25 00 01  0.0000000  0  2",
        _obs3_sat("G05", [20000060.125, 105000002.5, 45.0]),
        _obs3_sat("G12", [21000060.250, 106000002.5, 40.0]),
    ]
    if bad_number:
        lines[-1] = lines[-1][:3] + "  2100x060.250" + lines[-1][17:]
    if truncate:
        lines = lines[:-1]
    path.write_text("\n".join(lines) + "\n")
    return path


def _obs2_sat(values) -> list[str]:
    """One satellite record of the 6 types L1 L2 C1 P2 P1 S1 (two 80-column lines)."""
    cells = ["                " if v is None else f"{v:14.3f}  " for v in values]
    return ["".join(cells[:5]).rstrip(), "".join(cells[5:]).rstrip()]


def obs_v2(path: Path, *, truncate: bool = False) -> Path:
    """RINEX 2.11: a 14-satellite epoch (the list continues on a second line, blank system
    letters mean GPS), an event record (flag 3, one header line), a second epoch."""
    sats = ["G01", "  2", "G03", "G04", "G05", "G06", "G07", "G08", "G09", "G10", "G11",
            "G12", "R13", "G14"]
    lines = [
        _hdr("     2.11           OBSERVATION DATA    M (MIXED)", "RINEX VERSION / TYPE"),
        _hdr("SNIP", "MARKER NAME"),
        _hdr(" -2703115.2660 -4291768.3440  3854247.9550", "APPROX POSITION XYZ"),
        _hdr("     6    L1    L2    C1    P2    P1    S1", "# / TYPES OF OBSERV"),
        _hdr("  2021     4    28    19     0    0.0000000     GPS", "TIME OF FIRST OBS"),
        _hdr("", "END OF HEADER"),
        " 21  4 28 19  0  0.0000000  0 14" + "".join(sats[:12]),
        " " * 32 + "".join(sats[12:]),
    ]
    for k in range(len(sats)):
        c1 = 20000000.0 + 1000.0 * k
        lines += _obs2_sat([1.0e8 + k, None, c1, c1 + 5.0, None, 45.0])
    lines += [" 21  4 28 19  0 15.0000000  3  1", _hdr("NEWSITE", "MARKER NAME"),
              " 21  4 28 19  0 30.0000000  0  2G01G03"]
    lines += _obs2_sat([1.0e8, None, 20000030.0, None, None, 45.0])
    lines += ["", ""]  # a satellite with no observation at all: two blank lines
    if truncate:
        lines = lines[:-3]
    path.write_text("\n".join(lines) + "\n")
    return path


_GPS6_V2 = """\
 6 21  4 28 17 59 44.0 0.109337270260D-04 0.329691829393D-11 0.000000000000D+00
    0.310000000000D+02-0.968750000000D+02 0.369765402213D-08 0.256518534901D+00
   -0.510737299919D-05 0.225707876962D-02 0.122226774692D-04 0.515375527000D+04
    0.323984000000D+06 0.167638063431D-07-0.294507412083D+01-0.298023223877D-07
    0.983895632254D+00 0.158375000000D+03-0.983603167134D+00-0.758853037846D-08
   -0.732173355102D-10 0.100000000000D+01 0.215500000000D+04 0.000000000000D+00
    0.200000000000D+01 0.000000000000D+00 0.419095158577D-08 0.310000000000D+02
    0.322932000000D+06 0.400000000000D+01 0.000000000000D+00 0.000000000000D+00"""


def nav_v2(path: Path, *, truncate: bool = False, bad_number: bool = False) -> Path:
    head = [
        _hdr("     2              NAVIGATION DATA", "RINEX VERSION / TYPE"),
        _hdr("    0.9313D-08  0.1490D-07 -0.5960D-07 -0.1192D-06", "ION ALPHA"),
        _hdr("    0.8806D+05  0.4915D+05 -0.1311D+06 -0.3277D+06", "ION BETA"),
        _hdr("", "END OF HEADER"),
    ]
    body = _GPS6_V2.splitlines()
    if bad_number:
        body[2] = body[2][:3] + "   0.51073729991xD-05" + body[2][23:]
    if truncate:
        body = body[:5]
    path.write_text("\n".join(head + body) + "\n")
    return path


def _v3_record(sat: str, date: str, values) -> list[str]:
    def num(v):
        return " " * 19 if v is None else f"{v: .12e}"
    out = [f"{sat} {date}" + "".join(num(v) for v in values[:3])]
    for k in range(3, len(values), 4):
        out.append("    " + "".join(num(v) for v in values[k:k + 4]))
    return out


# Real values (see the module docstring); the GPS record is PRN 6 of brdc1180.21n.
GPS6 = [float(line[c:c + 19].replace("D", "E")) for k, line in enumerate(_GPS6_V2.splitlines())
        for c in ((22, 41, 60) if k == 0 else (3, 22, 41, 60))]
C05 = [-5.159442080185e-04, -6.710987321412e-11, 0.0, 1.0, -5.662656250000e+02,
       -1.811504027843e-09, -5.810297336492e-01, -1.882389187813e-05, 3.793594660237e-04,
       5.378387868404e-07, 6.493369304657e+03, 3.456000000000e+05, -3.911554813385e-08,
       3.102197701912e+00, 6.286427378654e-08, 1.114144101831e-01, -1.862500000000e+01,
       -1.428005199908e+00, 2.799759478363e-09, 4.578762152394e-10, 0.0, 7.55e+02, 0.0, 2.0,
       0.0, 1.0e-10, -9.3e-09, 3.456276e+05, 0.0]
C05_DATE = "2020 06 25 00 00 00"


def nav_v3(path: Path, *, version: str = "3.05", truncate: bool = False,
           bad_letter: bool = False) -> Path:
    """GPS 6, a GLONASS record (5 lines in 3.05, 4 before), Galileo, SBAS and BDS C05 (GEO)."""
    glo = _v3_record("R01", "2020 06 25 00 15 00", [6.3e-05, 0.0, 3.456e5] + [1.0] * 12
                     + ([0.0, 0.0, 0.0, 0.0] if version >= "3.05" else []))
    lines = [
        _hdr(f"{version:>9}           NAVIGATION DATA     MIXED", "RINEX VERSION / TYPE"),
        _hdr("GPSA   9.3132e-09  1.4901e-08 -5.9605e-08 -1.1921E-07", "IONOSPHERIC CORR"),
        _hdr("GPSB   8.8064e+04  4.9152e+04 -1.3107e+05 -3.2768E+05", "IONOSPHERIC CORR"),
        _hdr("BDSA   1.0245e-08  2.9802e-08 -2.9802e-07  4.7684E-07", "IONOSPHERIC CORR"),
        _hdr("", "END OF HEADER"),
        *_v3_record("G06", "2021 04 28 17 59 44", GPS6),
        *glo,
        *_v3_record("E01", "2020 06 25 00 10 00", [1.0] * 31),
        *_v3_record("S23", "2020 06 25 00 01 04", [0.0] * 15),
        *_v3_record("C05", C05_DATE, C05),
    ]
    if bad_letter:
        lines[5 + 8] = "X" + lines[5 + 8][1:]
    if truncate:
        lines = lines[:-2]
    path.write_text("\n".join(lines) + "\n")
    return path


# -- real records of the ESBC 3.05 mixed file (see the module docstring) --------------------
# ``None`` is a blank field, as in the file.

GPS6_DATE = "2021 04 28 17 59 44"
C23 = [-8.494175272062e-04, 4.416911281169e-12, 0.0, 1.0, -14.515625, 4.083384375064e-09,
       -2.567442602347, -6.849877536297e-07, 3.092981642112e-04, 7.189810276031e-06,
       5.282613891602e+03, 3.456e+05, -4.889443516731e-08, -2.225624712603e-01,
       -5.355104804039e-08, 9.525541865053e-01, 2.141875e+02, -2.130393007123,
       -6.825998615956e-09, -5.525230148013e-10, 0.0, 755.0, None, 2.0, 0.0, 2.53e-08,
       2.53e-08, 3.45618e+05, 1.0]
C23_DATE = "2020 06 25 00 00 00"
# E01 at 2020-06-24 23:30:00: the F/NAV record (data sources 258 = F/NAV E5a, clock for
# E5a,E1) and the I/NAV record (517 = I/NAV E1-B + E5b, clock for E5b,E1) of the same toc.
_E01_COMMON = [61.0, 18.65625, 2.65653922695e-09, -1.832282909549, 8.568167686462e-07,
               9.650341235101e-05, 1.049041748047e-05, 5.44060203743e+03, 3.438e+05,
               1.862645149231e-09, 2.123282284601e-01, -1.4528632164e-07, 9.82829647737e-01,
               1.29875e+02, -2.778709093141, -5.216288707934e-09, -6.996720012901e-10]
E01_FNAV = ([-8.846927667037e-04, -7.972289495228e-12, 0.0] + _E01_COMMON
            + [258.0, 2111.0, None, 3.12, 0.0, -1.862645149231e-09, 0.0, 3.4454e+05])
E01_INAV = ([-8.846933487803e-04, -7.972289495228e-12, 0.0] + _E01_COMMON
            + [517.0, 2111.0, None, 3.12, 0.0, -1.862645149231e-09, -2.095475792885e-09,
               3.44465e+05])
E01_DATE = "2020 06 24 23 30 00"
# R01 at 2020-06-25 00:15:00 UTC: -tauN, +gammaN, tk; X, Xdot, Xacc, health; Y, ...; Z,
# ..., age (km, km/s, km/s^2); 3.05 line 5: status flags (blank), L1/L2 delay difference
# (.999999999999e+09: unknown), URAI 15, health flags (blank).
R01 = [6.356183439493e-05, 0.0, 3.456e+05, 1.682726318359e+04, 1.726848602295, 0.0, 0.0,
       5.647285644531e+03, 1.820017814636, 9.313225746155e-10, 1.0, 1.833408203125e+04,
       -2.144553184509, -2.793967723846e-09, 0.0, None, 9.99999999999e+08, 15.0, None]
R01_DATE = "2020 06 25 00 15 00"

#: (satellite, date, values, RINEX 4 message type) by system, in file order.
REAL_RECORDS = {
    "G": [("G06", GPS6_DATE, GPS6, "LNAV")],
    "C": [("C05", C05_DATE, C05, "D2"), ("C23", C23_DATE, C23, "D1")],
    "E": [("E01", E01_DATE, E01_FNAV, "FNAV"), ("E01", E01_DATE, E01_INAV, "INAV")],
    "R": [("R01", R01_DATE, R01, "FDMA")],
}
_NAMES = {"G": "GPS", "C": "BDS", "E": "GALILEO", "R": "GLONASS"}
_IONO = {
    "G": [_hdr("GPSA   4.6566e-09  1.4901e-08 -5.9605e-08 -1.1921E-07", "IONOSPHERIC CORR"),
          _hdr("GPSB   8.1920e+04  9.8304e+04 -6.5536e+04 -5.2429E+05", "IONOSPHERIC CORR")],
    "C": [_hdr("BDSA   1.0245e-08  2.9802e-08 -2.9802e-07  4.7684E-07", "IONOSPHERIC CORR"),
          _hdr("BDSB   1.1469e+05  1.6384e+05 -1.3107e+05 -4.5875E+05", "IONOSPHERIC CORR")],
}


def nav_v3_system(path: Path, systems: str = "GCER", *, version: str = "3.05",
                  blank_spare: bool = False, leap: str | None = "    18") -> Path:
    """The real records of ``systems`` in one RINEX 3 file: one system as IGS publishes
    them per system (``_GN``, ``_CN``, ``_EN``, ``_RN``), several as a mixed file.
    ``blank_spare``: the BeiDou spare field (BROADCAST ORBIT - 5, 2nd) left blank, as some
    3.05 writers do. ``leap``: the ``LEAP SECONDS`` header field (None: no such line)."""
    kind = (f"{systems}: {_NAMES[systems]}" if len(systems) == 1 else "M: MIXED")
    lines = [_hdr(f"{version:>9}           N: GNSS NAV DATA    {kind}", "RINEX VERSION / TYPE"),
             _hdr("snippet", "PGM / RUN BY / DATE")]
    for letter in systems:
        lines += _IONO.get(letter, [])
    if leap is not None:
        lines.append(_hdr(leap, "LEAP SECONDS"))
    lines.append(_hdr("", "END OF HEADER"))
    for letter in systems:
        for sat, date, values, _ in REAL_RECORDS[letter]:
            if blank_spare and letter == "C":
                values = values[:20] + [None] + values[21:]
            lines += _v3_record(sat, date, values)
    path.write_text("\n".join(lines) + "\n")
    return path


def _v4_other(head: str, first: str, n_more: int) -> list[str]:
    """A RINEX 4 record the reader skips: its ``>`` line, a first line, ``n_more`` lines."""
    return [head, first] + ["    " + " 0.000000000000e+00" * 4] * n_more


def nav_v4(path: Path, *, truncate: bool = False, version: str = "4.00") -> Path:
    """RINEX 4.00: the real records as ``> EPH`` records, between a time offset (STO), an
    Earth orientation (EOP), Klobuchar (GPS LNAV, BDS D1D2), NeQuick-G and BDGIM ION
    records, a GPS CNAV and a BDS CNV1 record (message types not read) and a QZSS LNAV
    record (system not read by default). ``truncate``: the GLONASS record lacks its
    5th line."""
    lines = [_hdr(f"{version:>9}           NAVIGATION DATA     M", "RINEX VERSION / TYPE"),
             _hdr("snippet             RAIM Studio         20240101 000000 UTC",
                  "PGM / RUN BY / DATE"),
             _hdr("    18    18  2185     7", "LEAP SECONDS"),
             _hdr("", "END OF HEADER"),
             "> STO G06 LNAV",
             "    2020 06 25 00 00 00 GPUT     UTC(USNO)",
             "     3.456000000000e+05 9.313225746155e-10 2.664535259100e-15 0.000000000000e+00",
             "> EOP G06 CNVX",
             "    2020 06 25 00 00 00 3.496837615967e-02-1.758575439453e-03 0.000000000000e+00",
             "                        2.492733001709e-01 1.537799835205e-03 0.000000000000e+00",
             "    -8.632800000000e+04-2.960562705994e-03-3.077089786530e-04 0.000000000000e+00",
             "> ION G06 LNAV",
             "    2020 06 24 23 59 44 4.656612873077e-09 1.490116119385e-08-5.960464477539e-08",
             "    -1.192092895508e-07 8.192000000000e+04 9.830400000000e+04-6.553600000000e+04",
             "    -5.242880000000e+05",
             "> ION C05 D1D2",
             "    2020 06 25 00 00 00 1.024454832077e-08 2.980232238770e-08-2.980232238770e-07",
             "     4.768371582031e-07 1.146880000000e+05 1.638400000000e+05-1.310720000000e+05",
             "    -4.587520000000e+05",
             "> ION E01 IFNV",
             "    2020 06 24 23 30 00 2.825000000000e+01 7.812500000000e-03 1.007080078125e-02",
             "     0.000000000000e+00",
             *_v4_other("> ION C23 CNVX", "    2020 06 25 00 00 00" + " 1.000000000000e+00"
                        * 3, 2)]  # BDGIM, not Klobuchar: skipped
    for letter in "GCER":
        for sat, date, values, msg in REAL_RECORDS[letter]:
            rec = _v3_record(sat, date, values)
            if truncate and letter == "R":
                rec = rec[:-1]  # a GLONASS record one line short
            lines += [f"> EPH {sat} {msg}", *rec]
        if letter == "G":
            lines += _v4_other("> EPH G06 CNAV", _v3_record("G06", GPS6_DATE, GPS6)[0], 8)
        if letter == "C":
            lines += _v4_other("> EPH C23 CNV1", _v3_record("C23", C23_DATE, C23)[0], 9)
    lines += _v4_other("> EPH J01 LNAV", "J01 2020 06 25 11 00 00-2.819551154971e-04"
                       " 5.684341886081e-12 0.000000000000e+00", 7)
    path.write_text("\n".join(lines) + "\n")
    return path


def _d19(v) -> str:
    """A RINEX 2 number (D19.12, FORTRAN ``D`` exponent); None is a blank field."""
    return " " * 19 if v is None else f"{v: .12e}".replace("e", "D")


def nav_v2_glonass(path: Path, *, leap: str | None = "    18") -> Path:
    """RINEX 2.11 GLONASS navigation (``.yyg``, type 'G'): R01 above in the 4-line layout
    (PRN, yy mm dd hh mm ss.s, 3 numbers; then 3 lines of 4), tocs in UTC."""
    v = R01[:15]
    lines = [_hdr("     2.11           G: GLONASS NAV DATA", "RINEX VERSION / TYPE"),
             _hdr("snippet", "PGM / RUN BY / DATE"),
             _hdr("  2020     6    25    -0.111758708954D-07", "CORR TO SYSTEM TIME")]
    if leap is not None:
        lines.append(_hdr(leap, "LEAP SECONDS"))
    lines += [_hdr("", "END OF HEADER"),
              " 1 20  6 25  0 15  0.0" + "".join(_d19(x) for x in v[:3])]
    lines += ["   " + "".join(_d19(x) for x in v[k:k + 4]) for k in (3, 7, 11)]
    path.write_text("\n".join(lines) + "\n")
    return path
