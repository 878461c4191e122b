"""Android GnssLogger raw logs (raimcore.sky.android).

Expected pseudoranges are computed by hand in integer nanoseconds from the records, as the
GSA white paper (2017, section 2.4) and gps-measurement-tools ``ProcessGnssMeas.m`` do:
``pr = c (TimeNanos + TimeOffsetNanos - FullBiasNanos_0 - BiasNanos_0 - week (or day)
start - ReceivedSvTimeNanos)``.
"""

from __future__ import annotations

import doctest
import gzip
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from raimcore.constants import C_MPS
from raimcore.geometry import ecef_to_enu, geodetic_to_ecef
from raimcore.sky import android
from raimcore.sky.android import (
    AndroidLogError,
    pseudorange_m,
    read_android,
    read_android_log,
)
from raimcore.sky.rinex import ObsFile, RinexError

SNIPPET = Path(__file__).parent / "data" / "android" / "gnsslogger_v1.4.txt"
PHONE_LOG = "pseudoranges_log_2016_06_30_21_26_07.txt"
WEEK_NS = 604_800 * 10**9
DAY_NS = 86_400 * 10**9
one_mm = 1e-3
one_um = 1e-6


def ns_to_m(ns: float) -> float:
    return ns * C_MPS / 1e9


# -- the v1.4 snippet (records of Google's demo log) -------------------------------------

def test_snippet_pseudoranges_by_hand():
    log = read_android_log(SNIPPET)
    obs = log.obs
    assert isinstance(obs, ObsFile)
    assert obs.sat_names == ("G02",)  # G03 (uncertainty 667 ns) and G06 (State 1) rejected
    assert obs.obs_types == {"G": ("C1C",)}
    # Epoch 1, G02: TimeNanos 72076939000000, FullBiasNanos -1151285108458178048, BiasNanos 0
    # -> GPS ns 1151357185397178048 = week 1903 + 422785397178048 ns of week;
    # ReceivedSvTimeNanos 422785326362991 -> 70815057 ns.
    # Epoch 2 (same clock segment, same reference): TimeNanos 72077939000000 ->
    # 422786397178048 - 422786326364257 = 70813791 ns.
    want = np.array([[ns_to_m(70_815_057)], [ns_to_m(70_813_791)]])
    np.testing.assert_allclose(obs.codes["C1C"], want, rtol=0, atol=one_um)
    np.testing.assert_allclose(obs.t_gps_s, [1151357185.397178048, 1151357186.397178048],
                               rtol=0, atol=1e-6)
    assert 1151357185.397178048 // 604800 == 1903
    np.testing.assert_array_equal(obs.approx_pos_ecef_m, np.zeros(3))
    assert obs.version == 1.4 and obs.time_system == "GPS"
    np.testing.assert_array_equal(obs.epoch_flag, [0, 0])


def test_snippet_counts_notes_and_extras():
    log = read_android_log(SNIPPET)
    assert log.counts["Raw"] == 4 and log.counts["used"] == 2
    assert log.counts["rejected sv time uncertainty"] == 1
    assert log.counts["rejected GPS: time of week neither decoded nor known (State)"] == 1
    assert (log.counts["Fix"], log.counts["Nav"], log.counts["Status"]) == (2, 1, 1)
    assert any("ReceivedSvTimeUncertaintyNanos above 500 ns" in n for n in log.notes)
    assert any("Nav 1" in n and "Status 1" in n for n in log.notes)
    # Weights: c * ReceivedSvTimeUncertaintyNanos (13 ns, then 12 ns), C/N0, rates.
    np.testing.assert_allclose(log.sigma_m["C1C"][:, 0], [ns_to_m(13), ns_to_m(12)])
    np.testing.assert_allclose(log.cn0_dbhz["C1C"][:, 0], [31.6, 32.0])
    np.testing.assert_allclose(log.prr_mps["C1C"][:, 0], [-384.09503173828125,
                                                          -385.185791015625])
    np.testing.assert_array_equal(log.clock_count, [188, 188])
    np.testing.assert_array_equal(log.clock_reset, [True, False])
    # The phone's own fix: median of its two GPS Fix records.
    assert log.n_fix == 2
    want = geodetic_to_ecef(np.radians(37.422541), np.radians(-122.081659), -33.0)
    np.testing.assert_allclose(log.fix_ecef_m, want, atol=one_mm)


def test_rejects_above_a_lower_uncertainty_threshold_and_validates_it():
    log = read_android_log(SNIPPET, max_sv_time_unc_ns=12.5)  # epoch 1 G02 has 13 ns
    assert len(log.obs.t_gps_s) == 1  # epoch 1 has no measurement left
    assert log.obs.codes["C1C"][0, 0] == pytest.approx(ns_to_m(70_813_791), abs=one_um)
    assert log.counts["rejected sv time uncertainty"] == 2
    with pytest.raises(ValueError, match="max_sv_time_unc_ns"):
        read_android(SNIPPET, max_sv_time_unc_ns=0.0)
    with pytest.raises(ValueError, match="max_prr_unc_mps"):
        read_android(SNIPPET, max_prr_unc_mps=-1.0)


def test_gzip_log_opens(tmp_path):
    gz = tmp_path / "log.txt.gz"
    gz.write_bytes(gzip.compress(SNIPPET.read_bytes()))
    a, b = read_android(SNIPPET), read_android(gz)
    np.testing.assert_array_equal(a.codes["C1C"], b.codes["C1C"])


def test_doctests():
    assert doctest.testmod(android).failed == 0


# -- hand-made multi-constellation logs (columns in another order: read by name) ---------

HEADER = ("# Raw,ConstellationType,Svid,State,ReceivedSvTimeNanos,TimeNanos,FullBiasNanos,"
          "BiasNanos,TimeOffsetNanos,HardwareClockDiscontinuityCount,"
          "ReceivedSvTimeUncertaintyNanos,CarrierFrequencyHz,CodeType,LeapSecond")
TIME_NANOS = 5_000 * 10**9
WEEK = 2000
TOW_NS = 100_000 * 10**9  # receiver GPS time: week 2000, 100000 s (Tuesday 03:46:40)
FULL_BIAS = TIME_NANOS - (WEEK * WEEK_NS + TOW_NS)
BIAS = 0.25  # ns


def raw(ctype, svid, state, sv_ns, *, time_ns=TIME_NANOS, full_bias=FULL_BIAS, bias=BIAS,
        offset=0.0, count=7, unc=10, freq="", code="", leap=18):
    return (f"Raw,{ctype},{svid},{state},{sv_ns},{time_ns},{full_bias},{bias},{offset},"
            f"{count},{unc},{freq},{code},{leap}")


def write_log(tmp_path, rows, header=HEADER, version="# Version: v3.0.6.3 Platform: 13 "
              "Manufacturer: Google Model: Pixel 7"):
    p = tmp_path / "gnss_log.txt"
    p.write_text("\n".join(["# ", "# Header Description:", version, header, *rows]) + "\n")
    return p


def test_four_constellations_by_hand(tmp_path):
    glo_tod_ns = (100_000 - 18 + 3 * 3600) % 86_400 * 10**9  # GLONASS time of day: 24382 s
    rows = [
        raw(1, 5, 15, TOW_NS - 72_000_000, offset=10.5),  # GPS L1, 72 ms
        raw(1, 5, 15, TOW_NS - 72_000_010, freq="1176450000.0", code="Q"),  # GPS L5
        raw(6, 7, 1024 | 8, TOW_NS - 80_000_000, freq="1575420000.0", code="C"),  # E1C
        raw(6, 11, 1024 | 2048, 30_000_000),  # E1C secondary code only: 100 ms ambiguous
        raw(5, 21, 1 | 8, TOW_NS - 14 * 10**9 - 75_000_000, freq="1561098000.0", code="I"),
        raw(3, 12, 1 | 128, glo_tod_ns - 68_000_000, freq="1602562500.0"),  # GLONASS slot 12
        raw(3, 95, 1 | 128, glo_tod_ns - 68_000_000),  # FCN-only Svid: no slot
        raw(4, 193, 15, TOW_NS - 70_000_000),  # QZSS: skipped
        raw(2, 131, 1 | 8192, 1_000_000),  # SBAS: skipped
        raw(1, 9, 1, 4_000_000),  # code lock only: no TOW
        raw(1, 10, 15, TOW_NS - 70_000_000, unc=600),  # uncertainty above 500 ns
        raw(1, 11, 15 | 16, TOW_NS - 70_000_000),  # millisecond ambiguous
        raw(1, 5, 15, TOW_NS - 72_000_000),  # duplicate of the first row's signal
    ]
    log = read_android_log(write_log(tmp_path, rows))
    obs = log.obs
    assert obs.sat_names == ("C21", "E07", "G05", "R12")
    assert obs.obs_types == {"G": ("C1C", "C5Q"), "E": ("C1C",), "C": ("C2I",),
                             "R": ("C1C",)}
    assert obs.marker == "Pixel 7" and obs.version == 3.0
    col = {n: k for k, n in enumerate(obs.sat_names)}
    pr = {code: a[0] for code, a in obs.codes.items()}
    expect = {("C1C", "G05"): 72_000_000 - BIAS + 10.5, ("C5Q", "G05"): 72_000_010 - BIAS,
              ("C1C", "E07"): 80_000_000 - BIAS, ("C2I", "C21"): 75_000_000 - BIAS,
              ("C1C", "R12"): 68_000_000 - BIAS}
    for (code, sat), ns in expect.items():
        assert pr[code][col[sat]] == pytest.approx(ns_to_m(ns), abs=one_um), (code, sat)
    # L1 and L5 stay apart; nothing else was filled.
    assert np.isfinite(np.stack(list(pr.values()))).sum() == len(expect)
    np.testing.assert_allclose(obs.t_gps_s, [WEEK * 604_800 + 100_000 - BIAS * 1e-9],
                               rtol=0, atol=1e-6)
    c = log.counts
    assert c["rejected Galileo 100 ms ambiguous"] == 1
    assert c["skipped GLONASS FCN-only Svid"] == 1
    assert c["skipped QZSS"] == 1 and c["skipped SBAS"] == 1
    assert c["rejected GPS: time of week neither decoded nor known (State)"] == 1
    assert c["rejected sv time uncertainty"] == 1
    assert c["rejected GPS: millisecond ambiguous (State)"] == 1
    assert c["rejected duplicate"] == 1
    assert c["used"] == 5 and c["Raw"] == len(rows)
    assert any("QZSS" in n for n in log.notes) and any("100 ms" in n for n in log.notes)


def test_glonass_leap_seconds_from_the_table_when_blank(tmp_path):
    glo_tod_ns = (100_000 - 18 + 3 * 3600) % 86_400 * 10**9  # 2018: GPS - UTC = 18 s
    log = read_android_log(write_log(tmp_path, [
        raw(3, 12, 1 | 128, glo_tod_ns - 68_000_000, leap="")]))
    assert log.obs.codes["C1C"][0, 0] == pytest.approx(ns_to_m(68_000_000 - BIAS), abs=one_um)


@pytest.mark.parametrize("letter, ctype, tow_s, sv_ns", [
    # GPS: reception 30 ms into week 2000, transmission 40 ms before the end of week 1999.
    ("G", 1, 0.030, WEEK_NS - 40_000_000),
    # BeiDou: BDT = GPST - 14 s, so its week starts at GPS tow 14 s.
    ("C", 5, 14.030, WEEK_NS - 40_000_000),
    # GLONASS: day rollover of GLONASS time (UTC(SU) + 3 h) at GPS tow 18 s - 3 h + 1 day.
    ("R", 3, 86_400 + 18 - 3 * 3600 + 0.030, DAY_NS - 40_000_000),
])
def test_week_and_day_rollover(tmp_path, letter, ctype, tow_s, sv_ns):
    tow_ns = round(tow_s * 1e9)
    full_bias = TIME_NANOS - (WEEK * WEEK_NS + tow_ns)
    state = 1 | 128 if letter == "R" else 15
    log = read_android_log(write_log(tmp_path, [
        raw(ctype, 12, state, sv_ns, full_bias=full_bias, bias=0.0)]))
    code = "C2I" if letter == "C" else "C1C"
    assert log.obs.codes[code][0, 0] == pytest.approx(ns_to_m(70_000_000), abs=one_um)


def test_clock_segments_keep_the_first_bias(tmp_path):
    """One continuous hardware clock: the first FullBiasNanos (+ BiasNanos) stays the
    reference when the phone re-estimates it; a discontinuity takes a new one."""
    rows = [raw(1, 5, 15, TOW_NS - 72_000_000, count=3),
            # 1 s later, the phone's bias estimate moved by 500 ns: ignored (same segment)
            raw(1, 5, 15, TOW_NS + 10**9 - 72_000_100, time_ns=TIME_NANOS + 10**9,
                full_bias=FULL_BIAS + 500, bias=0.75, count=3),
            # a hardware clock restart: TimeNanos jumps back, a new reference is taken
            raw(1, 5, 15, TOW_NS + 2 * 10**9 - 72_000_200, time_ns=10**9,
                full_bias=10**9 - (WEEK * WEEK_NS + TOW_NS + 2 * 10**9) - 300, bias=0.0,
                count=4)]
    log = read_android_log(write_log(tmp_path, rows))
    pr = log.obs.codes["C1C"][:, 0]
    np.testing.assert_allclose(pr, [ns_to_m(72_000_000 - BIAS), ns_to_m(72_000_100 - BIAS),
                                    ns_to_m(72_000_200 + 300)], rtol=0, atol=one_um)
    t0 = WEEK * 604_800 + 100_000
    np.testing.assert_allclose(log.obs.t_gps_s - t0, [-BIAS * 1e-9, 1 - BIAS * 1e-9,
                                                      2 + 300e-9], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(log.clock_reset, [True, False, True])
    np.testing.assert_array_equal(log.clock_count, [3, 3, 4])


def test_reference_skips_rejected_first_measurement(tmp_path):
    """The segment's reference is its first *usable* measurement: a bad first record
    (e.g. before the phone decoded the time of week) does not set it."""
    rows = [raw(1, 9, 1, 4_000_000, full_bias=FULL_BIAS + 10**6),
            raw(1, 5, 15, TOW_NS - 72_000_000)]
    log = read_android_log(write_log(tmp_path, rows))
    assert log.obs.codes["C1C"][0, 0] == pytest.approx(ns_to_m(72_000_000 - BIAS), abs=one_um)


@given(week=st.integers(1000, 3000), tow_ns=st.integers(0, WEEK_NS - 1),
       travel_ns=st.integers(-500_000_000, 500_000_000),
       letter=st.sampled_from("GECR"), frac=st.floats(-1e3, 1e3))
def test_kernel_recovers_any_travel_time(week, tow_ns, travel_ns, letter, frac):
    """For any reception time, including either side of a week / day boundary, the
    kernel returns c * (travel + frac) from the satellite time in its own system time."""
    t = week * WEEK_NS + tow_ns
    if letter == "R":
        sv = (t - travel_ns - 18 * 10**9 + 3 * 3600 * 10**9) % DAY_NS
    else:
        sv = (t - travel_ns - (14 * 10**9 if letter == "C" else 0)) % WEEK_NS
    pr = pseudorange_m([t], [frac], [sv], letter, [18.0] if letter == "R" else None)
    assert pr[0] == pytest.approx(ns_to_m(travel_ns + frac), abs=one_um)


# -- errors ------------------------------------------------------------------------------

def test_not_a_gnsslogger_log(tmp_path):
    p = tmp_path / "x.txt"
    p.write_text("     2.11           OBSERVATION DATA    G (GPS)             RINEX VERSION / "
                 "TYPE\n")
    with pytest.raises(AndroidLogError, match=r"x\.txt.*'# Raw,' header"):
        read_android(p)
    with pytest.raises(RinexError, match="does not exist"):
        read_android(tmp_path / "missing.txt")


@pytest.mark.parametrize("rows, line, match", [
    ([raw(1, 5, 15, "12a")], 5, "integer ReceivedSvTimeNanos, got '12a'"),
    ([raw(1, 5, 15, 1) + ",extra"], 5, "expected 13 comma-separated fields.*got 14"),
    ([raw(1, 5, 15, 1, unc="x")], 5, "number ReceivedSvTimeUncertaintyNanos"),
    ([raw(1, 5, 15, 1), raw(1, 5, 15, 1, full_bias=-FULL_BIAS)], 6, "negative FullBiasNanos"),
])
def test_malformed_records_name_the_line(tmp_path, rows, line, match):
    p = write_log(tmp_path, rows)
    with pytest.raises(AndroidLogError, match=match) as exc:
        read_android(p)
    assert exc.value.line == line and exc.value.path == str(p)
    assert isinstance(exc.value, ValueError)


def test_raw_record_before_its_header(tmp_path):
    p = tmp_path / "log.txt"
    p.write_text("# Version: v3.0.0.1\n" + raw(1, 5, 15, 1) + "\n" + HEADER + "\n")
    with pytest.raises(AndroidLogError, match="'# Raw,' header line before") as exc:
        read_android(p)
    assert exc.value.line == 2


def test_old_version_and_missing_columns_refused(tmp_path):
    p = write_log(tmp_path, [raw(1, 5, 15, 1)], version="# Version: 1.3.0.0, Platform: N")
    with pytest.raises(AndroidLogError, match="format 1.4 or later, got version 1.3"):
        read_android(p)
    p = write_log(tmp_path, [], header="# Raw,TimeNanos,Svid,State,ConstellationType")
    with pytest.raises(AndroidLogError, match="missing FullBiasNanos, ReceivedSvTimeNanos"):
        read_android(p)


def test_nothing_usable_is_an_error(tmp_path):
    p = write_log(tmp_path, [raw(1, 9, 1, 4_000_000)])
    with pytest.raises(AndroidLogError, match="no usable|none passed.*neither decoded"):
        read_android(p)
    p = write_log(tmp_path, [])
    with pytest.raises(AndroidLogError, match="found none"):
        read_android(p)


# -- the real phone log ------------------------------------------------------------------

#: Surveyed point of the log (gps-measurement-tools ProcessGnssMeasScript.m, via the data
#: README): Charleston Park test site, WGS-84.
TRUTH_LLH = (37.422578, -122.081678, -28.0)


def test_phone_log_single_point_positions(shared_data):
    from raimcore.sky.rinex import read_nav
    from raimcore.sky.spp import correct, solve

    log_path = shared_data / PHONE_LOG
    if not log_path.is_file():
        pytest.skip(f"{PHONE_LOG} is not in ../shared/data")
    log = read_android_log(log_path)
    obs = log.obs
    assert len(obs.t_gps_s) == 223 and log.counts["Raw"] == 1379
    assert log.counts["used"] == 1376 and log.counts["rejected sv time uncertainty"] == 3
    assert obs.sat_names == ("G02", "G03", "G06", "G12", "G17", "G19", "G24", "G25", "G28")
    # Duty cycling: the hardware clock restarts at almost every epoch.
    assert log.clock_reset.sum() == 215
    corr = correct(obs, read_nav(shared_data / "hour1820.16n"), systems=("GPS",))
    sol = solve(corr, mask_deg=10.0)
    assert sol.available.all()
    truth = geodetic_to_ecef(*np.radians(TRUTH_LLH[:2]), TRUTH_LLH[2])
    enu = ecef_to_enu(sol.pos_ecef_m, truth)
    horiz = np.hypot(enu[:, 0], enu[:, 1])
    # Measured: median 8.2 m, 95th percentile 17.6 m, 6 satellites at most epochs (a
    # duty-cycled 2016 phone, L1 only). A pseudorange off by one microsecond (300 m) or a
    # wrong week would put these far beyond the bounds.
    assert np.median(horiz) < 12.0
    assert np.percentile(horiz, 95) < 25.0
    assert abs(np.median(enu[:, 2])) < 10.0
    # The receiver clock stays within metres of GPS time (the phone's own bias is used).
    assert np.nanmax(np.abs(sol.clock_m)) < 1e3
    # The phone's own fix is a few metres from the surveyed point too.
    fix_enu = ecef_to_enu(log.fix_ecef_m, truth)
    assert math.hypot(fix_enu[0], fix_enu[1]) < 10.0
