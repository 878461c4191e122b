import math

import numpy as np
import pytest

from raimcore import constants as k
from raimcore.geometry import ecef_to_geodetic
from raimcore.sky.constellations import beidou_nominal, builtin, gps_nominal, read_yuma


def test_gps_nominal_radius_period_and_names():
    g = gps_nominal()
    assert g.names[:2] == ("G01", "G02") and len(g) == 24
    r = np.linalg.norm(g.positions_ecef_m(np.array([0.0, 5000.0])), axis=-1)
    assert np.allclose(r, k.GPS_SQRT_A**2)
    # Half a sidereal day later a GPS satellite is back in inertial space: in ECEF it has
    # rotated by omega_e * T around the z axis only, so z is unchanged.
    t_orbit = 2 * math.pi * math.sqrt(k.GPS_SQRT_A**6 / k.GM_GPS_M3PS2)
    p0, p1 = g.positions_ecef_m(np.array([0.0, t_orbit]))
    assert np.allclose(p0[:, 2], p1[:, 2], atol=1e-3)
    # Slot A1: RAAN 272.847, argument of latitude 268.126 (SPS PS table 3.1-1).
    u, raan, inc = math.radians(268.126), math.radians(272.847), k.GPS_INC_RAD
    a = k.GPS_SQRT_A**2
    want = a * np.array([math.cos(u) * math.cos(raan) - math.sin(u) * math.cos(inc)
                         * math.sin(raan), math.cos(u) * math.sin(raan) + math.sin(u)
                         * math.cos(inc) * math.cos(raan), math.sin(u) * math.sin(inc)])
    assert np.allclose(p0[0], want, atol=1e-3)


def test_beidou_geo_stays_put_and_igso_crosses_118e():
    b = beidou_nominal()
    assert len(b) == 30 and set(b.systems) == {"BDS"}
    pos = b.positions_ecef_m(np.linspace(0, 86164.0, 9))
    lat, lon, h = ecef_to_geodetic(pos)
    geo = [b.names.index(n) for n in ("C01", "C02", "C03")]
    assert np.allclose(np.degrees(lon[:, geo]), [80.0, 110.5, 140.0], atol=1e-6)
    assert np.allclose(lat[:, geo], 0.0, atol=1e-9)
    c06 = b.names.index("C06")
    assert math.isclose(math.degrees(lon[0, c06]), 118.0, abs_tol=1e-6)
    assert np.max(np.abs(np.degrees(lat[:, c06]))) > 50.0  # 55 deg figure-eight
    meo = [i for i, n in enumerate(b.names) if int(n[1:]) >= 19]
    assert np.allclose(h[:, meo], k.BDS_MEO_ALT_M, rtol=1e-3)


def test_builtin_rejects_unknown_system():
    with pytest.raises(ValueError, match="GPS or BDS"):
        builtin(["GAL"])


def test_read_yuma(shared_data):
    alm = read_yuma(shared_data / "yuma_week819.alm")
    assert len(alm) == 31 and alm.names[0] == "G01"
    assert math.isclose(alm.sqrt_a[0], 5153.605957)
    assert math.isclose(alm.ecc[0], 0.4164695740e-2)
    r = np.linalg.norm(alm.positions_ecef_m(np.array([319488.0])), axis=-1)
    assert np.all(np.abs(r - alm.sqrt_a**2) <= alm.ecc * alm.sqrt_a**2 + 1.0)


def test_read_yuma_errors_name_file_and_line(tmp_path):
    p = tmp_path / "bad.alm"
    p.write_text("******** Week 819 almanac for PRN-01 ********\nID: 01\nHealth: 000\n"
                 "Eccentricity: zero\n")
    with pytest.raises(ValueError, match=r"bad.alm:4: field 'eccentricity' is not a number"):
        read_yuma(p)
    p.write_text("******** Week 819 almanac for PRN-01 ********\nID: 01\nHealth: 000\n")
    with pytest.raises(ValueError, match=r"bad.alm:1: YUMA record is missing"):
        read_yuma(p)
