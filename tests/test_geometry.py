import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from raimcore.constants import WGS84_A_M, WGS84_B_M
from raimcore.geometry import (
    az_el,
    dops,
    ecef_to_enu,
    ecef_to_geodetic,
    enu_rotation,
    enu_to_ecef,
    geodetic_to_ecef,
)

one_mm = 1e-3


@given(st.floats(-89.9, 89.9), st.floats(-180, 180), st.floats(-500, 4.0e7))
def test_geodetic_round_trip(lat_deg, lon_deg, h_m):
    xyz = geodetic_to_ecef(math.radians(lat_deg), math.radians(lon_deg), h_m)
    lat, lon, h = ecef_to_geodetic(xyz)
    back = geodetic_to_ecef(lat, lon, h)
    assert np.linalg.norm(back - xyz) < one_mm
    assert abs(h - h_m) < one_mm


def test_known_points():
    assert np.allclose(geodetic_to_ecef(0.0, 0.0, 0.0), [WGS84_A_M, 0, 0])
    assert np.allclose(geodetic_to_ecef(math.pi / 2, 0.0, 0.0), [0, 0, WGS84_B_M], atol=1e-6)
    lat, lon, h = ecef_to_geodetic(np.array([[0.0, 0.0, WGS84_B_M + 10.0]]))
    assert np.isclose(lat[0], math.pi / 2) and np.isclose(h[0], 10.0, atol=one_mm)


def test_enu_rotation_is_orthonormal_and_batched():
    lat = np.radians([[10.0, -45.0], [60.0, 89.0]])
    lon = np.radians([[20.0, 170.0], [-60.0, 0.0]])
    r = enu_rotation(lat, lon)
    assert r.shape == (2, 2, 3, 3)
    assert np.allclose(r @ np.swapaxes(r, -1, -2), np.eye(3))
    assert np.allclose(np.linalg.det(r), 1.0)


def test_enu_round_trip_and_up_direction():
    ref = geodetic_to_ecef(math.radians(30), math.radians(104), 500.0)
    up = geodetic_to_ecef(math.radians(30), math.radians(104), 1500.0)
    enu = ecef_to_enu(up, ref)
    assert np.allclose(enu, [0, 0, 1000.0], atol=one_mm)
    assert np.allclose(enu_to_ecef(enu, ref), up, atol=one_mm)


def test_az_el_of_a_satellite_due_north_at_45_deg():
    ref = geodetic_to_ecef(0.0, 0.0, 0.0)
    sv = enu_to_ecef(np.array([[0.0, 1.0e6, 1.0e6]]), ref)
    az, el = az_el(sv, ref)
    assert np.isclose(az[0], 0.0, atol=1e-9) or np.isclose(az[0], 2 * np.pi, atol=1e-9)
    assert np.isclose(el[0], math.radians(45.0))


def test_dops_match_direct_inverse():
    rng = np.random.default_rng(1)
    u = rng.normal(size=(8, 3))
    u[:, 2] = np.abs(u[:, 2])
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    h = np.hstack([-u, np.ones((8, 1))])
    q = np.linalg.inv(h.T @ h)
    d = dops(h)
    assert np.isclose(d["gdop"], math.sqrt(np.trace(q)))
    assert np.isclose(d["hdop"], math.sqrt(q[0, 0] + q[1, 1]))
    assert np.isclose(d["vdop"], math.sqrt(q[2, 2]))
