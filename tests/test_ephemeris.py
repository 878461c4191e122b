"""Broadcast ephemerides of Galileo and GLONASS (and what changed for GPS and BeiDou), and
single-point positioning with each system on real data.

Reference values: the navigation file's own next record. A broadcast record is a fit to
the precise orbit around its toe, so the orbit of record k evaluated at the toe of record
k+1 must land on record k+1's orbit there, to the fit and propagation error: decimetres for
Galileo 10 min apart, metres for a GLONASS state vector integrated over 30 min. The
records below are verbatim lines of ``ESBC00DNK_R_20201770000_01D_MN.rnx`` (../shared/data,
from georust/rinex test resources, MPL-2.0): C05 (lines 208-215), E01 (3064-3095: F/NAV and
I/NAV at 23:30 and 23:40), E14 (9048-9063: F/NAV and I/NAV, flagged unhealthy) and R01
(18061-18070: 23:45 and 00:15 UTC), trailing blanks stripped. Tests on the whole file and
its observation file skip without ../shared/data.
"""

import dataclasses
import doctest

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from raimcore.constants import (
    A_E_GLO_M,
    F_B1I_HZ,
    F_L1_HZ,
    GM_GLO_M3PS2,
    J2_GLO,
    OMEGA_E_GLO_RADPS,
)
from raimcore.geometry import ecef_to_enu
from raimcore.sky import ephemeris as ephemeris_module
from raimcore.sky import spp as spp_module
from raimcore.sky.ephemeris import (
    MAX_AGE_S,
    ephemeris_notes,
    from_nav,
    sat_pos_clock,
    sisa_index_to_m,
)
from raimcore.sky.rinex import read_nav, read_obs
from raimcore.sky.spp import carrier_hz, correct, solve, spp, with_atmosphere

ESBC_OBS = "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx"
GPS_MINUS_UTC_2020_S = 18.0  # the file's LEAP SECONDS header (IERS Bulletin C)
one_cm = 0.01
one_m = 1.0
one_ns = 1e-9

_ESBC_RECORDS = """\
C05 2020 06 24 22 00 00-5.154609680176e-04-6.708145150469e-11 0.000000000000e+00
     1.000000000000e+00-4.142968750000e+02-3.141559429989e-09-1.101749161212e+00
    -1.366203650832e-05 3.830116475001e-04-1.177610829473e-05 6.493378950119e+03
     3.384000000000e+05-6.146728992462e-08 2.697580724014e+00 6.146728992462e-08
     1.136268367853e-01 3.549843750000e+02-1.027125663175e+00 4.100527946305e-09
     3.321566928024e-10 0.000000000000e+00 7.550000000000e+02
     2.000000000000e+00 0.000000000000e+00 1.000000000000e-10-9.300000000000e-09
     3.384276000000e+05 0.000000000000e+00
E01 2020 06 24 23 30 00-8.846927667037e-04-7.972289495228e-12 0.000000000000e+00
     6.100000000000e+01 1.865625000000e+01 2.656539226950e-09-1.832282909549e+00
     8.568167686462e-07 9.650341235101e-05 1.049041748047e-05 5.440602037430e+03
     3.438000000000e+05 1.862645149231e-09 2.123282284601e-01-1.452863216400e-07
     9.828296477370e-01 1.298750000000e+02-2.778709093141e+00-5.216288707934e-09
    -6.996720012901e-10 2.580000000000e+02 2.111000000000e+03
     3.120000000000e+00 0.000000000000e+00-1.862645149231e-09 0.000000000000e+00
     3.445400000000e+05
E01 2020 06 24 23 30 00-8.846933487803e-04-7.972289495228e-12 0.000000000000e+00
     6.100000000000e+01 1.865625000000e+01 2.656539226950e-09-1.832282909549e+00
     8.568167686462e-07 9.650341235101e-05 1.049041748047e-05 5.440602037430e+03
     3.438000000000e+05 1.862645149231e-09 2.123282284601e-01-1.452863216400e-07
     9.828296477370e-01 1.298750000000e+02-2.778709093141e+00-5.216288707934e-09
    -6.996720012901e-10 5.170000000000e+02 2.111000000000e+03
     3.120000000000e+00 0.000000000000e+00-1.862645149231e-09-2.095475792885e-09
     3.444650000000e+05
E01 2020 06 24 23 40 00-8.846975979395e-04-7.986500349944e-12 0.000000000000e+00
     6.200000000000e+01 1.912500000000e+01 2.676540060065e-09-1.758424687366e+00
     8.530914783478e-07 9.648420382291e-05 1.049041748047e-05 5.440601928711e+03
     3.444000000000e+05 4.470348358154e-08 2.123253801586e-01-1.173466444016e-07
     9.828292351941e-01 1.299062500000e+02-2.778181983277e+00-5.240575433859e-09
    -7.232444117471e-10 2.580000000000e+02 2.111000000000e+03
     3.120000000000e+00 0.000000000000e+00-1.862645149231e-09 0.000000000000e+00
     3.451400000000e+05
E01 2020 06 24 23 40 00-8.846981800161e-04-7.986500349944e-12 0.000000000000e+00
     6.200000000000e+01 1.912500000000e+01 2.676540060065e-09-1.758424687366e+00
     8.530914783478e-07 9.648420382291e-05 1.049041748047e-05 5.440601928711e+03
     3.444000000000e+05 4.470348358154e-08 2.123253801586e-01-1.173466444016e-07
     9.828292351941e-01 1.299062500000e+02-2.778181983277e+00-5.240575433859e-09
    -7.232444117471e-10 5.170000000000e+02 2.111000000000e+03
     3.120000000000e+00 0.000000000000e+00-1.862645149231e-09-2.095475792885e-09
     3.450650000000e+05
E14 2020 06 24 19 50 00-1.061151910108e-03-1.340083599644e-11 0.000000000000e+00
     3.900000000000e+01 4.862500000000e+01 4.026596295327e-09 3.838393308945e-01
     1.143664121628e-06 1.668391372077e-01 6.243586540222e-06 5.289346492767e+03
     3.306000000000e+05 2.225860953331e-06 1.580074080108e+00-5.831941962242e-06
     8.830099927048e-01 2.172500000000e+02 1.751929312076e+00-5.873101781120e-09
     1.402558422188e-09 2.580000000000e+02 2.111000000000e+03
     3.120000000000e+00 4.800000000000e+01-5.122274160385e-09 0.000000000000e+00
     3.313400000000e+05
E14 2020 06 24 19 50 00-1.061153016053e-03-1.340083599644e-11 0.000000000000e+00
     3.900000000000e+01 4.862500000000e+01 4.026596295327e-09 3.838393308945e-01
     1.143664121628e-06 1.668391372077e-01 6.243586540222e-06 5.289346492767e+03
     3.306000000000e+05 2.225860953331e-06 1.580074080108e+00-5.831941962242e-06
     8.830099927048e-01 2.172500000000e+02 1.751929312076e+00-5.873101781120e-09
     1.402558422188e-09 5.170000000000e+02 2.111000000000e+03
     3.120000000000e+00 3.900000000000e+02-5.122274160385e-09-6.053596735001e-09
     3.312650000000e+05
R01 2020 06 24 23 45 00 6.355997174978e-05 0.000000000000e+00 3.438000000000e+05
     1.372008105469e+04 1.682619094849e+00-0.000000000000e+00 0.000000000000e+00
     1.826717285156e+03 2.401678085327e+00 0.000000000000e+00 1.000000000000e+00
     2.143656884766e+04-1.280283927917e+00-2.793967723846e-09 0.000000000000e+00
                         .999999999999e+09 1.500000000000e+01
R01 2020 06 25 00 15 00 6.356183439493e-05 0.000000000000e+00 3.456000000000e+05
     1.682726318359e+04 1.726848602295e+00 0.000000000000e+00 0.000000000000e+00
     5.647285644531e+03 1.820017814636e+00 9.313225746155e-10 1.000000000000e+00
     1.833408203125e+04-2.144553184509e+00-2.793967723846e-09 0.000000000000e+00
                         .999999999999e+09 1.500000000000e+01
"""


# -- helpers ------------------------------------------------------------------------------

def _hdr(text: str, label: str) -> str:
    return f"{text:<60}{label}"


def _records() -> list[list[str]]:
    """The excerpt's records, each a list of its lines."""
    recs: list[list[str]] = []
    for line in _ESBC_RECORDS.splitlines():
        if line[:1].strip():
            recs.append([line])
        else:
            recs[-1].append(line)
    return recs


def _span(j: int) -> tuple[int, int]:
    """(line, first column) of field ``j`` of a RINEX 3 record (0-2 on the first line,
    then four per broadcast-orbit line)."""
    return (0, 23 + 19 * j) if j < 3 else (1 + (j - 3) // 4, 4 + 19 * ((j - 3) % 4))


def _field(rec: list[str], j: int) -> float:
    k, c = _span(j)
    return float(rec[k][c:c + 19])


def _set(rec: list[str], j: int, value) -> list[str]:
    """``rec`` with field ``j`` written as ``value`` (None: left blank)."""
    k, c = _span(j)
    line = rec[k].ljust(80)
    text = " " * 19 if value is None else f"{value:19.12e}"
    return [*rec[:k], line[:c] + text + line[c + 19:], *rec[k + 1:]]


def _nav(path, records=None):
    """A RINEX 3.05 mixed navigation file of ``records`` (default: the whole excerpt),
    read with the four systems."""
    head = [_hdr("     3.05           NAVIGATION DATA     MIXED", "RINEX VERSION / TYPE"),
            _hdr("GPSA   4.6566e-09  1.4901e-08 -5.9605e-08 -1.1921E-07", "IONOSPHERIC CORR"),
            _hdr("GPSB   8.1920e+04  9.8304e+04 -6.5536e+04 -5.2429E+05", "IONOSPHERIC CORR"),
            _hdr("    18", "LEAP SECONDS"), _hdr("", "END OF HEADER")]
    body = [line for rec in (_records() if records is None else records) for line in rec]
    path.write_text("\n".join(head + body) + "\n")
    return read_nav(path, systems="GCER")


def _esbc_nav(shared_data):
    """ESBC's navigation file with GLONASS tocs in GPS time: the reader converts them from
    UTC(SU) when it knows the leap seconds (a ``leap_s``-like attribute); otherwise the 18 s
    of 2020 are added here."""
    nav = read_nav(shared_data / ESBC_NAV, systems="GCER")
    if any("leap" in name for name in nav.__dataclass_fields__):
        return nav
    sats, toc, vals = nav.records["R"]
    return dataclasses.replace(nav, records={**nav.records,
                                             "R": (sats, toc + GPS_MINUS_UTC_2020_S, vals)})


def _horizontal_error_m(pos_ecef_m, ref_ecef_m) -> np.ndarray:
    enu = ecef_to_enu(pos_ecef_m, ref_ecef_m)
    return np.hypot(enu[..., 0], enu[..., 1])


# -- decoding tables ----------------------------------------------------------------------

@pytest.mark.parametrize("index,metres", [
    (0, 0.0), (1, 0.01), (49, 0.49), (50, 0.50), (74, 0.98), (75, 1.00), (99, 1.96),
    (100, 2.00), (107, 3.12), (125, 6.00), (126, np.nan), (254, np.nan), (255, np.nan),
    (-1, np.nan)])
def test_galileo_sisa_index_table(index, metres):
    """OS SIS ICD 5.1.12: four linear bands, spare 126-254 and NAPA 255 without a value.
    Index 107 is ESBC's 3.12 m as RINEX 3 writes it."""
    np.testing.assert_allclose(sisa_index_to_m(index), metres, atol=1e-12)


@pytest.mark.parametrize("letter,code,fcn,mhz", [
    ("G", "C1C", 0, 1575.42), ("G", "C1", 0, 1575.42), ("G", "C2W", 0, 1227.60),
    ("G", "C5Q", 0, 1176.45), ("E", "C1C", 0, 1575.42), ("E", "C1X", 0, 1575.42),
    ("E", "C7Q", 0, 1207.14), ("E", "C5Q", 0, 1176.45), ("C", "C2I", 0, 1561.098),
    ("C", "C1I", 0, 1561.098), ("C", "C6I", 0, 1268.52), ("R", "C1C", 0, 1602.0),
    ("R", "C1C", -7, 1598.0625), ("R", "C1P", 6, 1605.375), ("R", "C1", 1, 1602.5625),
    ("R", "C2C", -7, 1242.9375), ("E", "C9X", 0, np.nan)])
def test_carrier_frequencies(letter, code, fcn, mhz):
    """RINEX 3.05 table 4; GLONASS L1/L2 FDMA channels, ICD ed. 5.1 3.3.1.4."""
    np.testing.assert_allclose(carrier_hz(letter, code, fcn) / 1e6, mhz, rtol=1e-12)


@pytest.mark.parametrize("module", [ephemeris_module, spp_module])
def test_docstring_examples_run(module):
    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0


# -- records: what is used, what is rejected and said so ------------------------------------

def test_galileo_e1_takes_the_inav_records_their_bgd_and_sisa(tmp_path):
    nav = _nav(tmp_path / "n.rnx")
    eph = from_nav(nav)
    e01 = eph.take(np.flatnonzero(eph.sat == "E01"))
    # The two I/NAV records (23:30, 23:40); the F/NAV ones of the same tocs are left out.
    assert len(e01) == 2 and e01.healthy.all()
    np.testing.assert_array_equal(e01.af0, [-8.846933487803e-04, -8.846981800161e-04])
    np.testing.assert_array_equal(e01.tgd_s, -2.095475792885e-09)  # BGD(E1, E5b)
    np.testing.assert_array_equal(e01.ura_m, 3.12)  # SISA, metres in RINEX 3
    assert np.diff(e01.toe_gps_s).tolist() == [600.0]
    e14 = eph.take(np.flatnonzero(eph.sat == "E14"))
    assert len(e14) == 1 and not e14.healthy.any()  # SV health 390: E1-B HS 3, E5b HS 3
    notes = ephemeris_notes(nav)
    assert "E14: 1 record unhealthy (E1-B HS 3)" in notes
    assert any(n.startswith("GAL: 3 F/NAV records of 2 satellites not used") for n in notes)
    assert ephemeris_notes(nav, systems="GCR") == ()


def test_galileo_satellite_with_only_fnav_records_uses_e5a_bgd_and_e5a_health(tmp_path):
    fnav = [r for r in _records() if r[0][0] != "E" or _field(r, 20) == 258.0]
    nav = _nav(tmp_path / "n.rnx", fnav)
    eph = from_nav(nav)
    e01 = eph.take(np.flatnonzero(eph.sat == "E01"))
    assert len(e01) == 2 and e01.healthy.all()
    np.testing.assert_array_equal(e01.af0, [-8.846927667037e-04, -8.846975979395e-04])
    np.testing.assert_array_equal(e01.tgd_s, -1.862645149231e-09)  # BGD(E1, E5a)
    # E14's F/NAV health 48 is E5a HS 3 (bits 4-5).
    assert ephemeris_notes(nav) == ("E14: 1 record unhealthy (E5a HS 3)",)


@pytest.mark.parametrize("fields,note", [
    ((20,), None), ((22,), None), ((20, 22), None),  # the spares: blank is absent
    ((28,), None),  # AODC, not needed by the orbit or clock
    ((10,), "C05: 1 record missing sqrt_a"), ((25,), "C05: 1 record missing tgd"),
    ((4, 24), "C05: 1 record missing crs, health")])
def test_a_blank_beidou_field_rejects_the_record_only_when_needed(tmp_path, fields, note):
    def blank(rec):
        for j in fields:
            rec = _set(rec, j, None)
        return rec

    recs = [blank(r) if r[0].startswith("C05") else r for r in _records()]
    nav = _nav(tmp_path / "n.rnx", recs)
    eph = from_nav(nav)
    assert eph.healthy[eph.sat == "C05"].tolist() == [note is None]
    assert ephemeris_notes(nav, systems="C") == (() if note is None else (note,))
    if note is None:  # the same orbit and clock as the complete record
        full = from_nav(_nav(tmp_path / "full.rnx"))
        c, c_full = (e.take(np.flatnonzero(e.sat == "C05")) for e in (eph, full))
        t = c.toe_gps_s + 600.0
        for got, want in zip(sat_pos_clock(c, t), sat_pos_clock(c_full, t), strict=True):
            np.testing.assert_array_equal(got, want)


def test_glonass_record_state_vector_channel_health_and_accuracy(tmp_path):
    eph = from_nav(_nav(tmp_path / "n.rnx"))
    r = eph.take(np.flatnonzero(eph.sat == "R01"))
    assert r.healthy.all() and r.fcn.tolist() == [1, 1]
    assert r.toe_gps_s[1] - r.toe_gps_s[0] == 1800.0 and (r.toc_gps_s == r.toe_gps_s).all()
    np.testing.assert_array_equal(r.af0, [6.355997174978e-05, 6.356183439493e-05])  # -tau_n
    np.testing.assert_allclose(r.pos_glo_m[0], [13720081.05469, 1826717.285156,
                                                21436568.84766], rtol=0, atol=1e-6)
    np.testing.assert_allclose(r.acc_glo_mps2[1], [0.0, 9.313225746155e-07,
                                                   -2.793967723846e-06], atol=1e-18)
    assert np.isnan(r.ura_m).all()  # URAI 15: not given
    # Health flag 1 on the second record; F_T index 3 (4 m, ICD table 4.4) on the first.
    recs = [_set(r, 6, 1.0) if r[0].startswith("R01 2020 06 25") else
            _set(r, 17, 3.0) if r[0].startswith("R01") else r for r in _records()]
    nav = _nav(tmp_path / "edited.rnx", recs)
    r = (e := from_nav(nav)).take(np.flatnonzero(e.sat == "R01"))
    assert r.healthy.tolist() == [True, False] and r.ura_m[0] == 4.0
    assert ephemeris_notes(nav, systems="R") == ("R01: 1 record unhealthy (health flag 1)",)


# -- orbits and clocks ----------------------------------------------------------------------

@pytest.mark.parametrize("sat,span_s,pos_tol_m,clk_tol_m", [
    ("E01", 600.0, 0.5, 0.5), ("R01", 1800.0, 5.0, 3.0)])
def test_a_record_reaches_the_next_record(tmp_path, sat, span_s, pos_tol_m, clk_tol_m):
    """Record k at record k+1's toe against record k+1 (for GLONASS, its state vector
    itself: no integration at t_b)."""
    eph = from_nav(_nav(tmp_path / "n.rnx"))
    k = np.flatnonzero((eph.sat == sat) & eph.healthy)
    a, b = eph.take(k[0]), eph.take(k[1])
    assert b.toe_gps_s - a.toe_gps_s == span_s
    (pa, ca), (pb, cb) = sat_pos_clock(a, b.toe_gps_s), sat_pos_clock(b, b.toe_gps_s)
    if sat[0] == "R":
        np.testing.assert_array_equal(pb, b.pos_glo_m)
    d_pos, d_clk = np.linalg.norm(pa - pb), 299792458.0 * abs(ca - cb)
    print(f"{sat}: {span_s:g} s on, position {d_pos:.2f} m, clock {d_clk:.2f} m")
    assert d_pos < pos_tol_m and d_clk < clk_tol_m


def test_glonass_runge_kutta_matches_a_tight_reference_integration(tmp_path):
    """The ICD's equations of motion written out again here and integrated by scipy's
    DOP853 at 1e-12: the 60-s RK4 steps agree to a centimetre over +-30 min."""
    eph = from_nav(_nav(tmp_path / "n.rnx"))
    r = eph.take(np.flatnonzero(eph.sat == "R01")[0])
    ax, ay, az = r.acc_glo_mps2
    w = OMEGA_E_GLO_RADPS

    def rhs(_, s):  # GLONASS ICD ed. 5.1 A.3.1.2
        x, y, z, vx, vy, vz = s
        rho = np.sqrt(x * x + y * y + z * z)
        mu, c, q = GM_GLO_M3PS2 / rho**3, 1.5 * J2_GLO * GM_GLO_M3PS2 * A_E_GLO_M**2 / rho**5, \
            5.0 * z * z / rho**2
        return [vx, vy, vz, -mu * x - c * x * (1 - q) + w * w * x + 2 * w * vy + ax,
                -mu * y - c * y * (1 - q) + w * w * y - 2 * w * vx + ay,
                -mu * z - c * z * (3 - q) + az]

    y0 = np.concatenate([r.pos_glo_m, r.vel_glo_mps])
    for dt in (-1800.0, -900.0, 30.0, 450.0, 1799.0):
        ref = solve_ivp(rhs, (0.0, dt), y0, method="DOP853", rtol=1e-12, atol=1e-6).y[:3, -1]
        pos, _ = sat_pos_clock(r, r.toe_gps_s + dt)
        assert np.linalg.norm(pos - ref) < one_cm, dt


def test_batched_equals_one_by_one_and_a_nan_record_poisons_only_itself(tmp_path):
    eph = from_nav(_nav(tmp_path / "n.rnx"))
    k = np.flatnonzero(eph.healthy)
    assert set(eph.system[k]) == set("CER")
    recs = eph.take(np.r_[k, k[-1]])
    pos = recs.pos_glo_m.copy()
    pos[-1, 0] = np.nan  # a GLONASS record without X
    recs = dataclasses.replace(recs, pos_glo_m=pos)
    n = len(recs)
    t = recs.toe_gps_s[:, None] + np.array([[-900.0, 0.0, 300.0, 1200.0]])
    pos_b, clk_b = sat_pos_clock(recs.take(np.repeat(np.arange(n)[:, None], 4, axis=1)), t)
    assert pos_b.shape == (n, 4, 3) and clk_b.shape == (n, 4)
    assert np.isfinite(pos_b[:-1]).all() and np.isnan(pos_b[-1]).all()
    assert np.isfinite(clk_b).all()  # the clock does not need the state vector
    for i in range(n):
        for j in range(4):
            p, c = sat_pos_clock(recs.take(i), t[i, j])
            assert p.shape == (3,) and np.shape(c) == ()
            np.testing.assert_allclose(p, pos_b[i, j], rtol=0, atol=1e-6)
            np.testing.assert_allclose(c, clk_b[i, j], rtol=0, atol=1e-18)
    # A time broadcast against the records.
    p, c = sat_pos_clock(recs, recs.toe_gps_s[0] + 60.0)
    assert p.shape == (n, 3) and c.shape == (n,)


@pytest.mark.parametrize("sat,max_age_s", [("R01", 1200.0), ("E01", 3 * 3600.0)])
def test_a_record_is_used_only_within_its_system_max_age(tmp_path, sat, max_age_s):
    """A GLONASS state vector near its 30-min slot (+-20 min), a Galileo batch within 3 h."""
    assert MAX_AGE_S[sat[0]] == max_age_s
    eph = from_nav(_nav(tmp_path / "n.rnx"))
    last = eph.toe_gps_s[(eph.sat == sat) & eph.healthy].max()
    t = last + np.array([0.0, max_age_s - 1.0, max_age_s + 1.0])
    picked, usable = eph.select([sat, "C05"], t)
    assert usable[:, 0].tolist() == [True, True, False]
    assert (picked.sat[:, 0] == sat).all() and (picked.toe_gps_s[:, 0] == last).all()


# -- the whole ESBC file --------------------------------------------------------------------

@pytest.mark.parametrize("letter,span_s,median_m,max_m,clk_max_m", [
    ("E", 600.0, 0.2, 1.0, 1.0), ("R", 1800.0, 3.0, 6.0, 3.0), ("G", 7200.0, 1.0, 2.0, 1.0),
    ("C", 3600.0, 0.5, 5.0, 2.0)])
def test_every_record_reaches_the_next_one_on_esbc(shared_data, letter, span_s, median_m,
                                                   max_m, clk_max_m):
    eph = from_nav(_esbc_nav(shared_data))
    use = (eph.system == letter) & eph.healthy
    idx = np.flatnonzero(use)
    idx = idx[np.lexsort((eph.toe_gps_s[idx], eph.sat[idx]))]
    a, b = idx[:-1], idx[1:]
    pair = (eph.sat[a] == eph.sat[b]) & (np.abs(eph.toe_gps_s[b] - eph.toe_gps_s[a] - span_s)
                                          < 1.0)
    a, b = a[pair], b[pair]
    assert a.size > 50
    t = eph.toe_gps_s[b]
    (pa, ca), (pb, cb) = sat_pos_clock(eph.take(a), t), sat_pos_clock(eph.take(b), t)
    d = np.linalg.norm(pa - pb, axis=-1)
    dc = 299792458.0 * np.abs(ca - cb)
    print(f"{letter}: {a.size} pairs {span_s:g} s apart: position median {np.median(d):.2f} "
          f"m, 95% {np.percentile(d, 95):.2f} m, max {d.max():.2f} m; clock median "
          f"{np.median(dc):.2f} m, max {dc.max():.2f} m")
    assert np.median(d) < median_m and d.max() < max_m and dc.max() < clk_max_m


def test_esbc_records_not_used_are_named(shared_data):
    notes = ephemeris_notes(_esbc_nav(shared_data))
    assert notes == ("E14: 21 records unhealthy (E1-B HS 3)",
                     "E18: 19 records unhealthy (E1-B HS 3)",
                     "GAL: 781 F/NAV records of 24 satellites not used: their I/NAV records "
                     "give the E1 clock (OS SIS ICD 5.1.5)")


@pytest.fixture(scope="module")
def esbc_spp():
    """ESBC's four systems, each alone and together: (obs, {systems: (result, corr)})."""
    from conftest import SHARED_DATA

    if not SHARED_DATA.is_dir():
        pytest.skip("../shared/data is not present")
    obs = read_obs(SHARED_DATA / ESBC_OBS)
    nav = _esbc_nav(SHARED_DATA)
    runs = {s: spp(obs, nav, s) for s in
            [("GPS",), ("GAL",), ("GLO",), ("BDS",), ("GPS", "BDS", "GAL", "GLO")]}
    return obs, nav, runs


@pytest.mark.parametrize("systems,median_m,p95_m", [
    (("GPS",), 5.0, 10.0), (("GAL",), 5.0, 10.0), (("GLO",), 5.0, 10.0),
    (("BDS",), 5.0, 10.0), (("GPS", "BDS", "GAL", "GLO"), 3.0, 5.0)])
def test_spp_per_system_against_the_header_position(esbc_spp, systems, median_m, p95_m):
    obs, _, runs = esbc_spp
    res, corr = runs[systems]
    err = _horizontal_error_m(res.pos_ecef_m, obs.approx_pos_ecef_m)
    n_sat = (corr.tracked & corr.usable).sum(axis=1)
    print(f"ESBC {'+'.join(systems)} ({corr.signals}): horizontal median {np.median(err):.2f} "
          f"m, 95% {np.percentile(err, 95):.2f} m, {np.mean(n_sat):.1f} satellites per epoch")
    assert res.available.all()
    assert np.median(err) < median_m and np.percentile(err, 95) < p95_m
    assert corr.systems == systems
    assert all(n.startswith("GAL: ") and "F/NAV" in n for n in corr.notes)


def test_glonass_and_galileo_carry_frequency_and_accuracy(esbc_spp):
    _, nav, runs = esbc_spp
    _, corr = runs[("GPS", "BDS", "GAL", "GLO")]
    sys_of = np.array(corr.systems)[corr.sys_idx]
    glo = sys_of == "GLO"
    # Every GLONASS satellite on its own L1 channel, the others on L1 / B1I.
    k = np.round((corr.freq_hz[:, glo] - 1602e6) / 0.5625e6)
    assert ((k >= -7) & (k <= 6)).all() and len(np.unique(k)) > 5
    np.testing.assert_array_equal(corr.freq_hz[:, sys_of == "GAL"], F_L1_HZ)
    np.testing.assert_array_equal(corr.freq_hz[:, sys_of == "BDS"], F_B1I_HZ)
    # The Klobuchar delay scales with (f_L1 / f)^2.
    at_l1 = with_atmosphere(dataclasses.replace(corr, freq_hz=np.full_like(corr.freq_hz,
                                                                           F_L1_HZ)),
                            nav, corr.rx_ecef_m)
    np.testing.assert_allclose(corr.iono_m / at_l1.iono_m, (F_L1_HZ / corr.freq_hz) ** 2,
                               rtol=1e-12)
    ura = corr.ura_m[corr.usable]
    gal_ura = corr.ura_m[:, sys_of == "GAL"][corr.usable[:, sys_of == "GAL"]]
    assert np.all(gal_ura == 3.12) and np.isnan(corr.ura_m[:, glo]).all()
    assert np.nanmin(ura) >= 2.0


def test_glonass_toc_in_utc_would_be_tens_of_metres_off(esbc_spp, shared_data):
    """The GLONASS tocs must be GPS time: 18 s of UTC(SU) left in them move the satellites
    by ~70 km along track and the solution by far more than any bound above."""
    obs, nav, _ = esbc_spp
    sats, toc, vals = nav.records["R"]
    utc = dataclasses.replace(nav, records={**nav.records, "R": (sats, toc - 18.0, vals)})
    res, _ = spp(obs, utc, ("GLO",))
    err = _horizontal_error_m(res.pos_ecef_m, obs.approx_pos_ecef_m)
    assert np.nanmedian(err) > 20.0


def test_unhealthy_galileo_satellite_left_out_with_its_reason(esbc_spp):
    obs, nav, runs = esbc_spp
    used = runs[("GAL",)][1].sat_names
    sat = used[0]
    sats, toc, vals = nav.records["E"]
    vals = vals.copy()
    vals[sats == sat, 24] = 2.0  # E1-B HS 1 (E1-B signal out of service)
    bad = dataclasses.replace(nav, records={**nav.records, "E": (sats, toc, vals)})
    res, corr = spp(obs, bad, ("GAL",))
    n_inav = int(np.sum((sats == sat) & (vals[:, 20] == 517.0)))
    assert sat not in corr.sat_names and res.available.all()
    assert f"{sat}: {n_inav} records unhealthy (E1-B HS 1)" in corr.notes
    assert any(n.startswith(f"{sat}: no healthy GAL ephemeris") for n in corr.notes)


def test_a_system_without_navigation_records_is_left_out_with_a_note(shared_data):
    obs = read_obs(shared_data / ESBC_OBS)
    nav = read_nav(shared_data / ESBC_NAV, systems="GC")
    res, corr = spp(obs, nav, ("GPS", "GAL"))
    assert corr.systems == ("GPS",) and res.available.all()
    assert any(n.startswith("GAL: no navigation records") for n in corr.notes)
    with pytest.raises(ValueError, match="systems must be among GPS, BDS, GAL, GLO"):
        correct(obs, nav, ("GPS", "QZS"))


def test_batched_glonass_spp_equals_a_per_epoch_solution(esbc_spp):
    obs, nav, runs = esbc_spp
    batched = runs[("GLO",)][0].pos_ecef_m
    for e in (0, 131, 239):
        one = dataclasses.replace(obs, t_gps_s=obs.t_gps_s[e:e + 1],
                                  epoch_flag=obs.epoch_flag[e:e + 1],
                                  codes={k: v[e:e + 1] for k, v in obs.codes.items()})
        np.testing.assert_allclose(solve(correct(one, nav, ("GLO",))).pos_ecef_m[0],
                                   batched[e], atol=1e-6)
