"""RINEX readers and broadcast ephemerides on small snippets written by the tests."""

import math

import numpy as np
import pytest
import rinex_snippets as snip

from raimcore.geometry import ecef_to_geodetic
from raimcore.sky.ephemeris import from_nav, sat_pos_clock
from raimcore.sky.rinex import RinexError, gps_seconds, read_nav, read_obs

T0 = gps_seconds(2020, 6, 25, 0, 0, 0)


def test_obs_v3_epochs_flags_events_and_codes(tmp_path):
    o = read_obs(snip.obs_v3(tmp_path / "a.rnx"))
    assert o.version == 3.05 and o.marker == "TEST"
    np.testing.assert_allclose(o.approx_pos_ecef_m, [3582105.2910, 532589.7313, 5232754.8054])
    # The event (flag 4) and cycle-slip (flag 6) records are skipped, not epochs.
    np.testing.assert_allclose(o.t_gps_s - T0, [0.0, 30.0, 60.0])
    assert o.epoch_flag.tolist() == [0, 1, 0]
    assert [f for _, f in o.events] == [4, 6]
    assert o.sat_names == ("C21", "G05", "G12")
    assert sorted(o.codes) == ["C1C", "C2I"]
    g = o.pseudorange("G", "C1C")
    np.testing.assert_allclose(g[:, 1], [20000000.125, 20000030.125, 20000060.125])
    assert np.isnan(g[1, 2]) and np.isnan(g[:, 0]).all()  # G12 absent at epoch 2; C21 not GPS
    np.testing.assert_allclose(o.pseudorange("C", "C2I")[:2, 0], [22000000.5, 22000030.5])


def test_obs_v3_bdt_time_system_is_converted_to_gpst(tmp_path):
    o = read_obs(snip.obs_v3(tmp_path / "b.rnx", time_system="BDT"))
    assert o.t_gps_s[0] - T0 == pytest.approx(14.0)


def test_obs_v2_continuation_lines_blank_system_event_and_blank_records(tmp_path):
    o = read_obs(snip.obs_v2(tmp_path / "a.21o"))
    assert o.version == 2.11
    assert len(o.t_gps_s) == 2 and o.events[0][1] == 3
    assert "G02" in o.sat_names and "R13" in o.sat_names and "G14" in o.sat_names
    assert sorted(o.codes) == ["C1", "P1", "P2"]
    c1 = o.pseudorange("G", "C1")
    col = {n: k for k, n in enumerate(o.sat_names)}
    assert c1[0, col["G14"]] == 20000000.0 + 13000.0  # from the continuation of the list
    assert c1[1, col["G01"]] == 20000030.0
    assert np.isnan(c1[1, col["G03"]])  # blank record lines
    assert np.isnan(o.codes["P1"]).all()


@pytest.mark.parametrize("writer,kwargs,line", [
    (snip.obs_v3, {"truncate": True}, None),
    (snip.obs_v3, {"bad_number": True}, 23),
    (snip.obs_v2, {"truncate": True}, None),
])
def test_bad_obs_files_name_file_and_line(tmp_path, writer, kwargs, line):
    path = writer(tmp_path / "bad.rnx", **kwargs)
    with pytest.raises(RinexError) as exc:
        read_obs(path)
    msg = str(exc.value)
    assert "bad.rnx" in msg and "line" in msg and "expected" in msg
    if line is not None:
        assert exc.value.line == line


def test_obs_header_errors(tmp_path):
    p = tmp_path / "h.rnx"
    p.write_text("not a rinex file\n")
    with pytest.raises(RinexError, match=r"h\.rnx, line 1: expected the 'RINEX VERSION"):
        read_obs(p)
    text = snip.obs_v3(tmp_path / "x.rnx").read_text().replace("END OF HEADER", "COMMENT")
    p.write_text(text)
    with pytest.raises(RinexError, match="END OF HEADER"):
        read_obs(p)
    with pytest.raises(RinexError, match="navigation file"):
        read_nav(snip.obs_v3(tmp_path / "o.rnx"))
    with pytest.raises(ValueError, match="does not exist"):
        read_obs(tmp_path / "missing.rnx")


@pytest.mark.parametrize("version", ["3.04", "3.05"])
def test_nav_v3_skips_other_systems_by_line_count(tmp_path, version):
    n = read_nav(snip.nav_v3(tmp_path / "n.rnx", version=version), systems="GC")
    assert n.skipped == {"R": 1, "E": 1, "S": 1}
    assert sorted(n.records) == ["C", "G"]
    assert list(n.records["G"][0]) == ["G06"] and list(n.records["C"][0]) == ["C05"]
    np.testing.assert_allclose(n.records["G"][2][0, :3], snip.GPS6[:3])
    # The BDS toc is in BDT: converted to GPST (+14 s).
    assert n.records["C"][1][0] - T0 == pytest.approx(14.0)
    assert n.iono["BDSA"][0] == pytest.approx(1.0245e-08)


def test_nav_v2_reads_d_exponents_and_iono(tmp_path):
    n = read_nav(snip.nav_v2(tmp_path / "b.21n"))
    vals = n.records["G"][2][0]
    np.testing.assert_allclose(vals, snip.GPS6)
    assert n.iono["GPSA"][0] == pytest.approx(0.9313e-08)


@pytest.mark.parametrize("writer,kwargs,line", [
    (snip.nav_v3, {"truncate": True}, None),
    (snip.nav_v3, {"bad_letter": True}, 14),
    (snip.nav_v2, {"truncate": True}, None),
    (snip.nav_v2, {"bad_number": True}, 7),
])
def test_bad_nav_files_name_file_and_line(tmp_path, writer, kwargs, line):
    path = writer(tmp_path / "badnav.rnx", **kwargs)
    with pytest.raises(RinexError) as exc:
        read_nav(path)
    assert "badnav.rnx" in str(exc.value) and "expected" in str(exc.value)
    if line is not None:
        assert exc.value.line == line


def test_ephemeris_gps_orbit_radius_and_bds_geo_longitude(tmp_path):
    eph = from_nav(read_nav(snip.nav_v3(tmp_path / "n.rnx")))
    g = eph.take(np.flatnonzero(eph.sat == "G06"))
    pos, clk = sat_pos_clock(g, g.toe_gps_s)
    r = np.linalg.norm(pos, axis=-1)
    assert 26.0e6 < r[0] < 27.2e6
    assert clk[0] == pytest.approx(snip.GPS6[0] - 4.190951586e-09, abs=5e-9)
    # C05 is the BeiDou GEO at 58.75 deg E: only right with the GEO rotation (ICD 5.2.4.12).
    c = eph.take(np.flatnonzero(eph.sat == "C05"))
    for dt in (0.0, 1800.0):
        pos, _ = sat_pos_clock(c, c.toe_gps_s + dt)
        lat, lon, h = ecef_to_geodetic(pos)
        assert abs(math.degrees(lon[0]) - 58.75) < 1.0
        assert abs(math.degrees(lat[0])) < 3.0
        assert 35.7e6 < h[0] < 35.9e6


def test_ephemeris_unbatched_equals_batched(tmp_path):
    eph = from_nav(read_nav(snip.nav_v3(tmp_path / "n.rnx")))
    t = eph.toe_gps_s[:, None] + np.array([[0.0, 600.0, 1800.0]])  # (records, 3 times)
    pos_b, clk_b = sat_pos_clock(eph.take(np.repeat(np.arange(len(eph))[:, None], 3, 1)), t)
    assert pos_b.shape == (len(eph), 3, 3) and clk_b.shape == (len(eph), 3)
    for k in range(len(eph)):
        for j in range(3):
            pos, clk = sat_pos_clock(eph.take(k), t[k, j])
            assert pos.shape == (3,)
            np.testing.assert_allclose(pos, pos_b[k, j], atol=1e-6)
            assert clk == clk_b[k, j]
