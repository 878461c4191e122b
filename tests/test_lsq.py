import numpy as np

from raimcore.geometry import az_el, geodetic_to_ecef
from raimcore.lsq import wls
from raimcore.sky.constellations import builtin

one_mm = 1e-3


def _sky(systems=("GPS",), t=(0.0, 600.0)):
    const = builtin(systems)
    sv = const.positions_ecef_m(np.asarray(t))
    rx = geodetic_to_ecef(np.radians(30.0), np.radians(110.0), 100.0)
    _, el = az_el(sv, rx)
    sys_idx = np.array([0 if s == "GPS" else 1 for s in const.systems])
    return sv, rx, el > np.radians(5.0), sys_idx


def test_noise_free_solution_is_exact_with_two_clocks():
    sv, rx, vis, sys_idx = _sky(("GPS", "BDS"))
    clocks = np.array([1234.5, -987.0])
    pr = np.linalg.norm(sv - rx, axis=-1) + clocks[sys_idx]
    res = wls(sv, pr, vis.astype(float), sys_idx)
    assert res.available.all() and res.converged.all()
    assert np.abs(res.pos_ecef_m - rx).max() < one_mm
    assert np.allclose(res.clock_m, clocks, atol=one_mm)
    assert np.all(res.n_states == 5)


def test_missing_system_clock_is_not_a_state():
    sv, rx, vis, sys_idx = _sky(("GPS", "BDS"))
    w = (vis & (sys_idx == 0)).astype(float)
    pr = np.linalg.norm(sv - rx, axis=-1) + 50.0
    res = wls(sv, pr, w, sys_idx)
    assert res.available.all() and np.all(res.n_states == 4)
    assert np.all(np.isnan(res.clock_m[:, 1]))


def test_too_few_satellites_is_unavailable_not_an_error():
    sv, rx, vis, sys_idx = _sky()
    w = np.zeros(vis.shape)
    for e in range(w.shape[0]):
        w[e, np.flatnonzero(vis[e])[:3]] = 1.0
    pr = np.linalg.norm(sv - rx, axis=-1)
    res = wls(sv, pr, w, sys_idx)
    assert not res.available.any()
    assert np.all(np.isnan(res.pos_ecef_m))


def test_singular_geometry_is_unavailable():
    rx = geodetic_to_ecef(0.0, 0.0, 0.0)
    sv = np.tile(rx * 4.0, (1, 6, 1))  # every satellite in the same direction
    sv[0, :, 1] += np.arange(6) * 1e-3
    pr = np.linalg.norm(sv - rx, axis=-1)
    res = wls(sv, pr, np.ones((1, 6)), np.zeros(6, int))
    assert not res.available[0]


def test_zero_weight_excludes_a_biased_satellite():
    sv, rx, vis, sys_idx = _sky()
    pr = np.linalg.norm(sv - rx, axis=-1)
    j = np.flatnonzero(vis[0])[0]
    pr[:, j] += 500.0
    w = vis.astype(float)
    w[:, j] = 0.0
    res = wls(sv, pr, w, sys_idx)
    assert np.abs(res.pos_ecef_m[0] - rx).max() < one_mm
    assert np.isnan(res.resid_m[0, j])
