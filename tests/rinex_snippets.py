"""Small self-contained RINEX 2.11 / 3.0x files written by the tests themselves.

The navigation values are real broadcast records (GPS PRN 6 of 2021-04-28 from the IGS
``brdc1180.21n``; BeiDou C05 (GEO) and C21 (MEO) of 2020-06-24 from ESBC's 3.05 mixed file),
so positions computed from them can be checked against their known orbits.
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
