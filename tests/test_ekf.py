"""EKF baseline with the innovation chi-square test (seed 002 baseline)."""

import numpy as np
import pytest
from scipy import stats

from raimcore.algorithms.ekf import run_ekf
from raimcore.algorithms.pf import ProcessModel
from raimcore.pipeline import run_scenario, simulate
from raimcore.scenario import load_scenario


def _runs(noise, n_runs, seed, duration_s=300):
    d, truth = simulate(load_scenario("seed002", noise=noise, faults=[],
                                      duration_s=duration_s))
    rng = np.random.default_rng(seed)
    rng_m = np.linalg.norm(d.pos_sv_ecef_m - truth.pos_rx_ecef_m[:, None], axis=-1)
    clean = rng_m + 1234.5  # a constant receiver clock (m)
    pr = clean[None] + d.noise.sample(rng, (n_runs,) + clean.shape)
    return d, truth, pr


def test_nis_false_alarm_rate_matches_p_fa_under_gaussian_noise():
    """Gaussian noise, the filter's own model: innovations are white, NIS ~ chi2(m)."""
    d, _, pr = _runs("gaussian", 20, 1)
    # Truly static receiver and clock: no process noise in the data nor in the filter.
    model = ProcessModel("static", 1, q_pos_mps=0.0, q_clk_mps=0.0)
    p_fa = 0.01
    r = run_ekf(d.pos_sv_ecef_m, pr, d.used, d.t_s, d.sys_idx, 1,
                d.noise.std_m, model, p_fa, exclude=False)
    nis = r.nis[:, 1:]
    k, n = int(np.sum(nis > r.threshold[1:])), nis.size
    assert stats.binomtest(k, n, p_fa).pvalue > 1e-3, (k, n)
    # And the NIS itself follows chi2(6): Kolmogorov-Smirnov on a thinned sample.
    assert stats.kstest(nis[:, ::5].ravel(), stats.chi2(6).cdf).pvalue > 1e-3


def test_heavy_tails_raise_the_ekf_false_alarm_rate():
    """Student-t noise (nu = 3): the nominal 1e-3 test false-alarms several times more
    often (spec: 2.6-5.2 % per epoch)."""
    d, _, pr = _runs("student-t", 10, 2)
    r = run_ekf(d.pos_sv_ecef_m, pr, d.used, d.t_s, d.sys_idx, 1, d.noise.std_m,
                ProcessModel(), 1e-3, exclude=False)
    rate = np.mean(r.alarm[:, 1:])
    assert 0.01 < rate < 0.1


def test_ekf_excludes_the_faulty_satellite_in_seed002():
    r = run_scenario(load_scenario("seed002", algorithm="ekf"))
    t = r.table
    faulted = t["faulty_truth"] != ""
    assert t["alarm"][faulted].all()
    assert np.all(t["excluded"][faulted] == "G19")
    # The protected filter resists the fault; the plain EKF is dragged by it.
    assert r.summary["rmse_after_m"] < 0.5 * r.summary["rmse_before_m"]


def test_ekf_constant_velocity_tracks_a_moving_receiver():
    s = load_scenario("seed000-step", algorithm="ekf", model="cv", sigma_m=3.0, faults=[],
                      duration_s=90)
    t = run_scenario(s).table
    assert np.nanmax(t["hpe_after_m"][t["t_s"] > 30]) < 15.0


def test_ekf_rejects_bad_model():
    with pytest.raises(ValueError, match="model must be one of"):
        run_scenario(load_scenario("seed002", algorithm="ekf", model="jerk"))


def test_per_satellite_sigma_equals_scalar_when_uniform_and_holds_p_fa_when_not():
    """R = diag(sigma_i^2): a uniform array gives the scalar filter exactly; with unequal
    noise levels (as a recording's elevation model), the per-satellite R keeps NIS at its
    chi-square false-alarm rate where one common sigma does not."""
    d, truth, pr = _runs("gaussian", 20, 3)
    model = ProcessModel("static", 1, q_pos_mps=0.0, q_clk_mps=0.0)
    sig = d.noise.std_m
    args = (d.pos_sv_ecef_m, None, d.used, d.t_s, d.sys_idx, 1)
    a = run_ekf(*args[:1], pr, *args[2:], sig, model, 0.01, exclude=False)
    b = run_ekf(*args[:1], pr, *args[2:], np.full(d.pr_m.shape, sig), model, 0.01,
                exclude=False)
    np.testing.assert_allclose(a.nis, b.nis, rtol=1e-12)
    k_sat = np.array([1.0, 1.0, 2.0, 2.0, 4.0, 4.0])
    rng = np.random.default_rng(4)
    rng_m = np.linalg.norm(d.pos_sv_ecef_m - truth.pos_rx_ecef_m[:, None], axis=-1)
    pr_h = rng_m[None] + 1234.5 + sig * k_sat * rng.standard_normal((20,) + rng_m.shape)
    per_sat = run_ekf(*args[:1], pr_h, *args[2:], sig * np.broadcast_to(k_sat, d.pr_m.shape),
                      model, 0.01, exclude=False)
    common = run_ekf(*args[:1], pr_h, *args[2:], sig, model, 0.01, exclude=False)
    nis_ok, nis_bad = per_sat.nis[:, 1:], common.nis[:, 1:]
    k_ok = int(np.sum(nis_ok > per_sat.threshold[1:]))
    assert stats.binomtest(k_ok, nis_ok.size, 0.01).pvalue > 1e-3, k_ok
    k_bad = int(np.sum(nis_bad > common.threshold[1:]))
    assert k_bad > 10 * k_ok + 50


def test_protected_run_resumed_from_the_plain_run_equals_a_run_from_the_start():
    """``resume``: a protected run takes the plain run's outputs and state up to its first
    exclusion and goes on from there; every output equals a protected run from the
    start, and a ``resume`` of other inputs is ignored."""
    d, _, pr = _runs("student-t", 3, 4)
    pr[:, 150:, 0] += 60.0  # a step on one satellite: exclusions from t = 150 s
    args = (d.pos_sv_ecef_m, pr, d.used, d.t_s, d.sys_idx, 1, d.noise.std_m, ProcessModel(),
            1e-3)
    plain = run_ekf(*args, exclude=False)
    assert plain.resume is not None and 0 < plain.resume.k_div < d.n_epochs
    alone = run_ekf(*args, exclude=True)
    resumed = run_ekf(*args, exclude=True, resume=plain.resume)
    other = run_ekf(*args, exclude=True, resume=run_ekf(args[0], pr + 1.0, *args[2:],
                                                          exclude=False).resume)
    assert alone.excluded.any()
    for run in (resumed, other):
        for f in ("estimate", "nis", "norm_innov", "alarm", "worst", "excluded",
                  "clock_jump_m"):
            np.testing.assert_array_equal(getattr(run, f), getattr(alone, f), err_msg=f)
