"""Noise models, faults and trajectories."""

import math

import numpy as np
import pytest
from scipy import integrate, stats

from raimcore.measure.faults import Fault, fault_biases, parse_fault
from raimcore.measure.noise import Scaled, fit_gauss_markov, gauss_markov_unit, make_noise, scaled
from raimcore.sky.trajectories import flight_profile, static, straight_line


@pytest.mark.parametrize("kind", ["gaussian", "mixture", "student-t"])
def test_noise_density_integrates_to_one_and_matches_samples(kind):
    model = make_noise(kind, 2.0)
    total, _ = integrate.quad(lambda x: math.exp(model.logpdf(x)), -np.inf, np.inf)
    assert abs(total - 1.0) < 1e-6
    x = model.sample(np.random.default_rng(0), 200_000)
    # Kolmogorov-Smirnov against the model's own CDF (numerical integral of its density).
    grid = np.linspace(-60, 60, 24001)
    cdf = np.cumsum(np.exp(model.logpdf(grid))) * (grid[1] - grid[0])
    ks = stats.kstest(x, lambda q: np.interp(q, grid, cdf))
    assert ks.pvalue > 1e-3


def test_student_t_matches_scipy():
    model = make_noise("student-t", 1.5, student_nu=4.0)
    x = np.linspace(-10, 10, 11)
    assert np.allclose(model.logpdf(x), stats.t.logpdf(x, 4.0, scale=1.5))
    assert math.isclose(model.std_m, 1.5 * math.sqrt(2.0))


def test_noise_bad_parameters_named():
    with pytest.raises(ValueError, match="noise must be one of"):
        make_noise("laplace", 1.0)
    with pytest.raises(ValueError, match="sigma_m"):
        make_noise("gaussian", 0.0)
    with pytest.raises(ValueError, match="mixture_eps"):
        make_noise("mixture", 1.0, mixture_eps=1.5)


@pytest.mark.parametrize("kind", ["gaussian", "mixture", "student-t"])
def test_correlated_noise_keeps_the_marginal_and_has_the_gauss_markov_correlation(kind):
    corr_s, dt = 20.0, 5.0
    model = make_noise(kind, 2.0, corr_s=corr_s)
    t = np.arange(12) * dt
    x = model.sample(np.random.default_rng(1), (6000, 12, 4), t_s=t)
    # One epoch across independent sequences: the white model's own law (KS, as above).
    grid = np.linspace(-80, 80, 32001)
    cdf = np.cumsum(np.exp(model.logpdf(grid))) * (grid[1] - grid[0])
    for k in (0, 11):
        assert stats.kstest(x[:, k].ravel(), lambda q: np.interp(q, grid, cdf)).pvalue > 1e-3
    # The copula's normal scores have lag-k correlation exp(-k dt / corr_s): Fisher z test.
    z = stats.norm.ppf(np.clip(np.interp(x, grid, cdf), 1e-12, 1 - 1e-12))
    n = z[:, 0].size
    for lag in (1, 3):
        r = np.corrcoef(z[:, 5].ravel(), z[:, 5 + lag].ravel())[0, 1]
        expect = math.exp(-lag * dt / corr_s)
        assert abs(np.arctanh(r) - np.arctanh(expect)) * math.sqrt(n - 3) < 4.0


def test_gauss_markov_unequal_steps_and_white_default():
    rng_a, rng_b = np.random.default_rng(3), np.random.default_rng(3)
    t = np.array([0.0, 1.0, 2.0, 3.0])
    fast = gauss_markov_unit(rng_a, (2, 4, 3), t, 10.0)      # equal steps: filter path
    t_jitter = t + np.array([0.0, 0.0, 0.0, 1e-9])
    slow = gauss_markov_unit(rng_b, (2, 4, 3), t_jitter, 10.0)  # unequal: loop path
    assert np.allclose(fast, slow, atol=1e-8)
    # A gap of many correlation times makes the next epoch (almost) independent.
    u = gauss_markov_unit(np.random.default_rng(4), (20000, 2, 1), [0.0, 1000.0], 10.0)
    assert abs(np.corrcoef(u[:, 0, 0], u[:, 1, 0])[0, 1]) < 0.05
    # corr_s = 0 draws exactly the white noise of before (seeded scenarios unchanged).
    white = make_noise("student-t", 2.0).sample(np.random.default_rng(5), (7, 3))
    assert np.array_equal(white, 2.0 * np.random.default_rng(5).standard_t(3.0, (7, 3)))


def test_fit_gauss_markov_recovers_scale_and_correlation_time():
    t = np.arange(3000) * 30.0
    x = make_noise("gaussian", 1.5, corr_s=60.0).sample(np.random.default_rng(7), (3000, 12),
                                                          t_s=t)
    x[100:200, :4] = np.nan  # tracking gaps
    fit = fit_gauss_markov(x, t)
    assert fit.dt_s == 30.0 and fit.n_pairs < 2999 * 12
    assert abs(fit.sigma_m / 1.5 - 1) < 0.05 and abs(fit.std_m / 1.5 - 1) < 0.05
    assert abs(fit.rho - math.exp(-0.5)) < 0.02
    assert abs(fit.corr_s / 60.0 - 1) < 0.06
    white = fit_gauss_markov(np.random.default_rng(8).standard_normal((500, 8)),
                             np.arange(500.0))
    assert abs(white.rho) < 0.03 and white.corr_s < 0.5
    # A time gap (a missing epoch) breaks the pair instead of counting it as one step.
    t_gap = np.delete(np.arange(11.0), 5)
    assert fit_gauss_markov(np.ones((10, 2)), t_gap).n_pairs == 16
    # Jittered time tags (a phone's 29.999 / 30.001 s steps) still pair: the same fit.
    jitter = t + np.random.default_rng(9).uniform(-1e-3, 1e-3, t.shape)
    fit_j = fit_gauss_markov(x, jitter)
    assert fit_j.n_pairs == fit.n_pairs and fit_j.rho == fit.rho
    assert fit_j.corr_s == pytest.approx(fit.corr_s, rel=1e-4)
    with pytest.raises(ValueError, match="errors must be"):
        fit_gauss_markov(np.ones((5, 2)), np.arange(4.0))


def test_per_satellite_scaled_noise():
    base = make_noise("gaussian", 1.5)
    k = np.array([1.0, 2.0, 4.0])
    m = scaled(base, k)
    assert isinstance(m, Scaled) and m.sigma_m == 1.5 and m.kind == "gaussian"
    x = np.linspace(-10, 10, 7)[:, None] * np.ones(3)
    np.testing.assert_allclose(m.logpdf(x), stats.norm.logpdf(x, scale=1.5 * k))
    np.testing.assert_allclose(m.std_m, 1.5 * k)
    draws = m.sample(np.random.default_rng(0), (200_000, 3))
    np.testing.assert_allclose(draws.std(0), 1.5 * k, rtol=0.01)
    assert scaled(base, None) is base and scaled(base, np.ones(3)) is base
    np.testing.assert_allclose(scaled(m, k).scale, k * k)  # scales compose, no nesting
    assert "scale=[1.00,2.00,4.00]" in repr(m)
    with pytest.raises(ValueError, match="noise scale"):
        scaled(base, [1.0, 0.0])


def test_correlated_noise_bad_input_named():
    with pytest.raises(ValueError, match="noise_corr_s"):
        make_noise("gaussian", 1.0, corr_s=-1.0)
    model = make_noise("gaussian", 1.0, corr_s=30.0)
    with pytest.raises(ValueError, match="needs the epoch times t_s"):
        model.sample(np.random.default_rng(0), (10, 3))
    with pytest.raises(ValueError, match="one time per epoch"):
        model.sample(np.random.default_rng(0), (10, 3), t_s=np.arange(9.0))


def test_step_and_ramp_biases():
    t = np.arange(0.0, 10.0)
    step = Fault("G01", "step", t0_s=2, t1_s=5, bias_m=10.0)
    ramp = Fault("G02", "ramp", t0_s=3, rate_mps=2.0)
    b = fault_biases([step, ramp, Fault("G01", "step", t0_s=4, bias_m=1.0)], t,
                     ("G01", "G02", "G03"))
    assert np.array_equal(b[:, 0], [0, 0, 10, 10, 11, 1, 1, 1, 1, 1])
    assert np.array_equal(b[:, 1], [0, 0, 0, 0, 2, 4, 6, 8, 10, 12])
    assert not b[:, 2].any()


def test_fault_parsing_and_errors():
    f = parse_fault("G10,ramp,5,20")
    assert (f.sat, f.kind, f.rate_mps, f.t0_s, f.t1_s) == ("G10", "ramp", 5.0, 20.0, math.inf)
    f = parse_fault("C21,step,100,20,80")
    assert (f.bias_m, f.t1_s) == (100.0, 80.0)
    for bad in ("G10,jump,5,20", "G10,step,5", "G10,step,x,1"):
        with pytest.raises(ValueError, match="--fault must be"):
            parse_fault(bad)
    with pytest.raises(ValueError, match="t1_s must be after t0_s"):
        Fault("G01", "step", t0_s=5, t1_s=5, bias_m=1.0)
    with pytest.raises(ValueError, match="not in this scenario"):
        fault_biases([Fault("G99", bias_m=1.0)], [0.0], ("G01",))


def test_trajectories():
    t = np.arange(0.0, 101.0)
    s = static(t, 30, 104, 500)
    assert np.ptp(s.pos_ecef_m, axis=0).max() == 0.0
    line = straight_line(t, 30, 104, 1000, speed_mps=100, heading_deg=90)
    step = np.linalg.norm(np.diff(line.pos_ecef_m, axis=0), axis=1)
    assert np.allclose(step, 100.0, rtol=1e-4)
    assert np.allclose(line.h_m, 1000.0, atol=0.01)
    tf = np.arange(0.0, 3601.0)
    fl = flight_profile(tf, 30, 104, 100, heading_deg=0, turn_start_s=2400, turn_deg=180)
    assert abs(fl.h_m[900] - 10000.0) < 1.0 and abs(fl.h_m[-1] - 10000.0) < 1.0
    speed = np.linalg.norm(fl.vel_ecef_mps, axis=1)
    assert speed[0] < 100 and abs(speed[-1] - 230.0) < 0.5
    # After the 180 deg turn the aircraft flies south: latitude decreases.
    assert fl.lat_rad[-1] < fl.lat_rad[-200]
    assert fl.lat_rad[2300] > fl.lat_rad[1000]
    with pytest.raises(ValueError, match="lat_deg"):
        static(t, 95, 0, 0)
