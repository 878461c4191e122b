"""Particle-filter kernels and the PF-LLR algorithm (seed 002, spec section 3)."""

import math
import warnings

import numpy as np
import pytest
from scipy import stats

from raimcore.algorithms import pf, pf_llr
from raimcore.lsq import wls
from raimcore.measure.noise import Gaussian, StudentT
from raimcore.pipeline import run_scenario, simulate
from raimcore.scenario import load_scenario

ONE_CM = 0.01
ONE_NM = 1e-9


@pytest.fixture(autouse=True, scope="module")
def _private_tau_cache(tmp_path_factory):
    """PF-LLR's thresholds go to a disk cache by default: keep this module's out of the
    user's cache directory."""
    mp = pytest.MonkeyPatch()
    mp.setenv("RAIM_STUDIO_CACHE_DIR", str(tmp_path_factory.mktemp("tau-cache")))
    yield
    mp.undo()


def test_systematic_resample_keeps_expected_counts():
    """Particle i is copied floor(N w_i) or ceil(N w_i) times, ceil with probability
    frac(N w_i): checked per particle with a binomial test over many draws."""
    rng = np.random.default_rng(5)
    n, draws = 40, 4000
    w = rng.dirichlet(np.full(n, 0.7))
    idx = pf.systematic_resample(np.broadcast_to(w, (draws, n)), np.random.default_rng(6))
    assert idx.shape == (draws, n) and idx.min() >= 0 and idx.max() < n
    counts = np.stack([np.bincount(row, minlength=n) for row in idx])
    nw = n * w
    assert np.all((counts == np.floor(nw)) | (counts == np.ceil(nw)))
    frac = nw - np.floor(nw)
    for i in np.flatnonzero((frac > 0.05) & (frac < 0.95)):
        k = int(np.sum(counts[:, i] == np.ceil(nw[i])))
        assert stats.binomtest(k, draws, frac[i]).pvalue > 1e-4
    # Mean count equals N w_i (unbiased resampling) within a few standard errors.
    se = np.sqrt(frac * (1 - frac) / draws)
    assert np.all(np.abs(counts.mean(0) - nw) <= 5 * se + 1e-12)


def test_systematic_resample_degenerate_and_unbatched():
    w = np.zeros(10)
    w[3] = 1.0
    assert np.all(pf.systematic_resample(w, np.random.default_rng(0)) == 3)
    idx = pf.systematic_resample(np.full(7, 1 / 7), np.random.default_rng(1))
    np.testing.assert_array_equal(idx, np.arange(7))


def test_log_weights_are_normalised_and_neff_bounds():
    rng = np.random.default_rng(2)
    log_w = rng.normal(0, 30, (5, 3, 200)) - 1e4  # far from exp's range
    w, log_norm = pf.normalise_log_weights(log_w)
    np.testing.assert_allclose(w.sum(-1), 1.0, rtol=1e-12)
    assert np.all(np.isfinite(log_norm))
    n_eff = pf.effective_sample_size(w)
    assert np.all((n_eff >= 1 - 1e-9) & (n_eff <= 200 + 1e-9))
    assert pf.effective_sample_size(np.full(50, 0.02)) == pytest.approx(50)


def test_bank_step_weights_normalised_and_resampling_rule():
    d, _ = simulate(load_scenario("seed002", noise="gaussian", faults=[]))
    model = pf.ProcessModel("static", 1)
    fix = pf.robust_fix(d.pos_sv_ecef_m[0], d.pr_m[:1], d.used[0], d.sys_idx, 1, d.noise)
    cloud = pf.initial_cloud(fix.pos_ecef_m, fix.clock_m, fix.cov_enu, 300, model,
                             np.random.default_rng(0), batch=(4,), inflate=3.0)
    assert cloud.shape == (1, 4, 300, 4)
    bank = pf.ParticleBank(cloud, model)
    res = bank.step(1.0, d.pos_sv_ecef_m[1][None, None], d.pr_m[1][None, None],
                    np.broadcast_to(d.used[1], (1, 4, 6)), d.sys_idx, d.noise,
                    np.random.default_rng(1))
    np.testing.assert_allclose(np.exp(bank.log_w).sum(-1), 1.0, rtol=1e-9)
    np.testing.assert_array_equal(res.resampled, res.n_eff < 200)
    resampled_rows = np.exp(bank.log_w)[res.resampled]
    np.testing.assert_allclose(resampled_rows, 1 / 300)


def test_pf_update_agrees_with_least_squares_under_gaussian_noise():
    """One update of a Gaussian prior N(x_ls + d, c C_ls) by Gaussian pseudoranges has the
    posterior mean x_ls + d / (1 + c) (linear-Gaussian Bayes: the LSQ fix is the
    likelihood's mean, C_ls its covariance); many particles reproduce it."""
    d, _ = simulate(load_scenario("seed002", noise="gaussian", faults=[], seed=4))
    noise = Gaussian(3.0)
    sv, pr, used = d.pos_sv_ecef_m[0], d.pr_m[0], d.used[0]
    ls = wls(sv[None], pr[None], np.where(used, 1 / 9.0, 0.0)[None], d.sys_idx, 1)
    model = pf.ProcessModel("static", 1, q_pos_mps=0.0, q_clk_mps=0.0)
    c, n = 4.0, 200_000
    offset = np.array([6.0, -4.0, 9.0])
    cloud = pf.initial_cloud(ls.pos_ecef_m + offset, ls.clock_m, ls.cov_enu * c, n, model,
                             np.random.default_rng(3))
    bank = pf.ParticleBank(cloud, model, n_threshold=0)
    res = bank.step(0.0, sv[None], pr[None], used[None], d.sys_idx, noise,
                    np.random.default_rng(4))
    want = ls.pos_ecef_m[0] + offset / (1 + c)
    post_sd = np.sqrt(np.diag(ls.cov_enu[0])[:3].max() * c / (1 + c))
    tol = 6 * post_sd / np.sqrt(res.n_eff[0]) + ONE_CM
    assert np.linalg.norm(res.estimate[0, :3] - want) < tol


def test_pf_filter_tracks_a_static_receiver_like_batch_least_squares():
    """Gaussian noise, many particles: after 60 s the main filter sits within a metre of
    the least-squares fix of all epochs so far (both average the same data)."""
    d, _ = simulate(load_scenario("seed002", noise="gaussian", faults=[], seed=7,
                                  duration_s=60))
    model = pf.ProcessModel("static", 1, q_pos_mps=0.01, q_clk_mps=0.01)
    run = pf.run_llr_bank(d.pos_sv_ecef_m, d.pr_m[None], d.used, d.t_s, d.sys_idx, 1,
                          d.noise, model, n_particles=3000, window=10, burn_in=10,
                          rng=np.random.default_rng(1))
    # Batch LSQ of a static receiver: one position and one clock from all 61 x 6 ranges.
    sv = d.pos_sv_ecef_m.reshape(1, -1, 3)
    batch = wls(sv, d.pr_m.reshape(1, -1), np.full((1, sv.shape[1]), 1 / 9.0),
                np.zeros(sv.shape[1], int), 1)
    err_pf = np.linalg.norm(run.estimate[0, -1, 0, :3] - batch.pos_ecef_m[0])
    err_snap = np.linalg.norm(run.estimate[0, 0, 0, :3] - batch.pos_ecef_m[0])
    assert err_pf < 1.0 < err_snap + 1.0


def test_bank_vectorised_over_runs_gives_one_llr_per_satellite():
    d, _ = simulate(load_scenario("seed002", duration_s=80))
    run = pf.run_llr_bank(d.pos_sv_ecef_m, np.stack([d.pr_m, d.pr_m]), d.used, d.t_s,
                          d.sys_idx, 1, d.noise, pf.ProcessModel(), n_particles=50,
                          window=10, burn_in=5, rng=np.random.default_rng(0))
    assert run.llr.shape == (2, 81, 6) and run.estimate.shape == (2, 81, 7, 4)
    armed = np.flatnonzero(run.armed)
    assert armed[0] == 1 + 5 + 10 - 1
    np.testing.assert_allclose(run.beta[:, armed], np.nanmax(run.cum_llr[:, armed], -1))
    # The window sum is the sum of the last W per-epoch LLRs.
    k = armed[-1]
    np.testing.assert_allclose(run.cum_llr[:, k], run.llr[:, k - 9:k + 1].sum(1))


def test_process_models_and_bad_options():
    rng = np.random.default_rng(0)
    cv = pf.ProcessModel("cv", 2, q_pos_mps=0.0, q_vel_mps2=0.0, q_clk_mps=0.0)
    x = np.zeros((3, cv.dim))
    x[:, 3:6] = [1.0, 2.0, 3.0]
    np.testing.assert_allclose(pf.predict(x, 2.0, cv, rng)[:, :3], [[2.0, 4.0, 6.0]] * 3)
    with pytest.raises(ValueError, match="model must be one of"):
        pf.ProcessModel("brownian")
    with pytest.raises(ValueError, match="n_particles"):
        run_scenario(load_scenario("seed002", algorithm="pf-llr", n_particles=1))
    with pytest.raises(ValueError, match="tau must be"):
        run_scenario(load_scenario("seed002", algorithm="pf-llr", tau="high"))
    with pytest.raises(ValueError, match="tau_cache must be one of"):
        run_scenario(load_scenario("seed002", algorithm="pf-llr", tau_cache="cloud"))


def test_moving_receiver_with_constant_velocity_model():
    s = load_scenario("seed000-step", algorithm="pf-llr", model="cv", noise="student-t",
                      sigma_m=3.0, faults=[], duration_s=90, tau=1e6)
    r = run_scenario(s)
    late = r.table["t_s"] > 60
    assert np.nanmax(r.table["hpe_before_m"][late]) < 15.0
    assert not r.table["alarm"].any()
    # The paper-era noise (33 m): the filter stays locked (the EKF: about 40 m RMSE).
    r33 = run_scenario(s.replace(sigma_m=33.0, noise="gaussian"))
    assert r33.summary["rmse_before_m"] < 150.0


def test_user_tau_is_used_and_calibration_is_cached(monkeypatch, tmp_path):
    """tau is calibrated once per configuration: kept in memory, and on disk (the default)
    so that a new process (an empty memory cache) reads it back instead of recomputing;
    a change of what it depends on (the noise sigma) is another key."""
    calls = []
    real = pf.calibrate_tau

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(pf_llr, "calibrate_tau", counting)
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    monkeypatch.delenv("RAIM_STUDIO_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    s = load_scenario("seed002", algorithm="pf-llr", duration_s=100, n_particles=20)
    t1 = run_scenario(s).table
    t2 = run_scenario(s.replace(seed=9, faults=[])).table  # same geometry: cache hit
    assert len(calls) == 1
    assert np.nanmax(t1["threshold"]) == np.nanmax(t2["threshold"])
    t3 = run_scenario(s.replace(tau=123.5)).table
    assert len(calls) == 1 and np.nanmax(t3["threshold"]) == 123.5
    # The fault-free samples are kept, not tau: another p_fa is a new quantile of them.
    t5 = run_scenario(s.replace(p_fa_window=0.05)).table
    assert len(calls) == 1 and np.nanmax(t5["threshold"]) < np.nanmax(t1["threshold"])
    # On disk by default, under $XDG_CACHE_HOME/raim-studio: a fresh process reads it.
    stored = list((tmp_path / "raim-studio" / "pf_llr_tau").glob("*.json"))
    assert len(stored) == 1
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    t4 = run_scenario(s.replace(seed=4)).table
    assert len(calls) == 1 and np.nanmax(t4["threshold"]) == np.nanmax(t1["threshold"])
    # Another noise sigma is another calibration (and another file).
    run_scenario(s.replace(sigma_m=4.0))
    assert len(calls) == 2
    assert len(list(stored[0].parent.glob("*.json"))) == 2
    # "memory" never touches the disk; "off" always recomputes.
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    run_scenario(s.replace(tau_cache="memory", n_particles=21))
    assert len(list(stored[0].parent.glob("*.json"))) == 2 and len(calls) == 3
    run_scenario(s.replace(tau_cache="off"))
    run_scenario(s.replace(tau_cache="off"))
    assert len(calls) == 5


def test_threshold_changes_retest_the_same_bank_run(monkeypatch):
    """A change of the threshold options alone (tau, p_fa_window) re-tests the kept bank
    run, with the result of a fresh run; a change of what the run reads (the noise
    sigma, the seed, N) runs the bank again."""
    calls = []
    real = pf_llr.run_llr_bank

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(pf_llr, "run_llr_bank", counting)
    monkeypatch.setattr(pf_llr, "_BANK_RUNS", type(pf_llr._BANK_RUNS)())
    s = load_scenario("seed002", algorithm="pf-llr", duration_s=120, n_particles=30)
    first = run_scenario(s).table
    again = run_scenario(s.replace(p_fa_window=0.01)).table
    user = run_scenario(s.replace(tau=40.0)).table
    assert len(calls) == 1
    np.testing.assert_array_equal(again["beta"], first["beta"])
    assert np.nanmax(user["threshold"]) == 40.0
    assert np.array_equal(user["alarm"], np.nan_to_num(np.asarray(user["beta"], float)) > 40)
    monkeypatch.setattr(pf_llr, "_BANK_RUNS", type(pf_llr._BANK_RUNS)())
    fresh = run_scenario(s.replace(p_fa_window=0.01)).table
    np.testing.assert_array_equal(fresh["beta"], again["beta"])
    np.testing.assert_array_equal(fresh["alarm"], again["alarm"])
    for change in ({"sigma_m": 4.0}, {"seed": 3}, {"n_particles": 31}):
        run_scenario(s.replace(**change))
    assert len(calls) == 5 and len(pf_llr._BANK_RUNS) == pf_llr.BANK_RUN_CACHE_SIZE
    monkeypatch.setattr(pf_llr, "BANK_RUN_CACHE_BYTES", 0)  # too big to keep: rerun
    run_scenario(s.replace(seed=21))
    run_scenario(s.replace(seed=21, p_fa_window=0.01))
    assert len(calls) == 7


def test_disk_cache_is_keyed_safe_and_falls_back_to_memory(monkeypatch, tmp_path):
    """The disk cache: RAIM_STUDIO_CACHE_DIR overrides the location; an entry of another
    key or a damaged file is recomputed, never trusted; a directory that cannot be written
    keeps the threshold in memory (one warning) and still returns it."""
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    monkeypatch.setenv("RAIM_STUDIO_CACHE_DIR", str(tmp_path / "c"))
    assert pf.default_cache_path() == tmp_path / "c" / "pf_llr_tau"
    computed = []

    def compute(value):
        def f():
            computed.append(value)
            return value
        return f

    assert pf.cached_tau("k1", compute(1.5)) == 1.5
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    assert pf.cached_tau("k1", compute(9.0)) == 1.5 and computed == [1.5]
    (entry,) = (tmp_path / "c" / "pf_llr_tau").glob("*.json")
    entry.write_text('{"key": "k1", "tau": "')  # damaged
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    assert pf.cached_tau("k1", compute(2.5)) == 2.5
    entry.write_text('{"key": "another", "tau": 7.0}')  # a hash collision, in effect
    monkeypatch.setattr(pf, "_TAU_CACHE", {})
    assert pf.cached_tau("k1", compute(3.5)) == 3.5
    # Not writable (a file where the directory should be): memory only, one warning.
    blocker = tmp_path / "blocked"
    blocker.write_text("")
    monkeypatch.setattr(pf, "_DISK_WARNED", set())
    with pytest.warns(UserWarning, match="not writable"):
        assert pf.cached_tau("k2", compute(4.5), path=blocker / "sub") == 4.5
    assert pf.cached_tau("k2", compute(8.0), path=blocker / "sub") == 4.5  # memory hit
    # At most CACHE_MAX_FILES entries: the oldest go.
    monkeypatch.setattr(pf, "CACHE_MAX_FILES", 2)
    for k in range(4):
        pf.cached_tau(f"many {k}", compute(float(k)))
    assert len(list((tmp_path / "c" / "pf_llr_tau").glob("*.json"))) == 2
    # The key names the code version: a change of the filters' source is a new key.
    key = pf.calibration_key(np.array([[2e7, 0, 0], [0, 2e7, 0]]), np.array([6.4e6, 0, 0]),
                             [0, 0], Gaussian(3.0), pf.ProcessModel(), n_particles=10)
    assert key.endswith(f"code={pf.calibration_code_version()}")


def test_noise_models_give_the_likelihood():
    """The filter's likelihood is the noise model's logpdf summed over scored satellites."""
    noise = StudentT(3.0, 3.0)
    model = pf.ProcessModel("static", 1)
    x = np.array([[[0.0, 0.0, 0.0, 5.0]]])
    sv = np.array([[2e7, 0, 0], [0, 2e7, 0], [0, 0, 2e7]])
    pr = np.array([2e7 + 5.0 + 1.0, 2e7 + 5.0 - 2.0, np.nan])
    ll = pf.log_likelihood(x, sv, pr, np.array([True, True, False]), np.zeros(3, int), noise,
                           model)
    assert ll[0, 0] == pytest.approx(noise.logpdf(1.0) + noise.logpdf(-2.0))
    assert math.isfinite(ll[0, 0])


@pytest.mark.slow
def test_fault_free_alarm_rate_matches_calibrated_tau():
    """Calibrate tau for p_fa_window = 5 %, then count alarms in independent fault-free
    runs at non-overlapping windows (every W-th armed epoch): binomial test."""
    d, truth = simulate(load_scenario("seed002", faults=[]))
    u = d.used[0]
    sv, rx = d.pos_sv_ecef_m[0][u], truth.pos_rx_ecef_m[0]
    model = pf.ProcessModel()
    cfg = dict(n_particles=100, window=30, burn_in=30, p_fa_window=0.05)
    cal = pf.calibrate_tau(sv, rx, d.sys_idx[u], 1, d.noise, model, n_runs=64, n_armed=60,
                           rng=np.random.default_rng(100), **cfg)
    test = pf.calibrate_tau(sv, rx, d.sys_idx[u], 1, d.noise, model, n_runs=160,
                            n_armed=60, rng=np.random.default_rng(200), **cfg)
    windows = test.beta[:, ::30]  # 2 non-overlapping windows per run
    k, n = int(np.sum(windows > cal.tau)), windows.size
    assert stats.binomtest(k, n, 0.05).pvalue > 1e-3, (k, n)


@pytest.mark.slow
def test_time_correlated_noise_needs_a_threshold_calibrated_on_it():
    """seed002's Student-t noise with a 60 s correlation time: the window sums of LLRs
    spread much more than under white noise. tau calibrated on the correlated model holds
    p_fa_window = 5 % (binomial test, one window per independent run); the white-noise tau
    does not (the mismatch behind PF-LLR's false alarms on real recordings)."""
    d, truth = simulate(load_scenario("seed002", faults=[], noise_corr_s=60.0))
    white = simulate(load_scenario("seed002", faults=[]))[0].noise
    u = d.used[0]
    sv, rx, sys_idx = d.pos_sv_ecef_m[0][u], truth.pos_rx_ecef_m[0], d.sys_idx[u]
    model = pf.ProcessModel()
    cfg = dict(n_particles=100, window=30, burn_in=30, p_fa_window=0.05)
    tau_corr = pf.calibrate_tau(sv, rx, sys_idx, 1, d.noise, model, n_runs=64, n_armed=60,
                                rng=np.random.default_rng(100), **cfg).tau
    tau_white = pf.calibrate_tau(sv, rx, sys_idx, 1, white, model, n_runs=64, n_armed=60,
                                 rng=np.random.default_rng(100), **cfg).tau
    assert tau_corr > 1.5 * tau_white
    test = pf.calibrate_tau(sv, rx, sys_idx, 1, d.noise, model, n_runs=400, n_armed=1,
                            rng=np.random.default_rng(200), **cfg)
    last = test.beta[:, -1]  # one window per run: independent samples
    k = int(np.sum(last > tau_corr))
    assert stats.binomtest(k, last.size, 0.05).pvalue > 1e-3, k
    k_white = int(np.sum(last > tau_white))
    assert stats.binomtest(k_white, last.size, 0.05, alternative="greater").pvalue < 1e-6


def test_calibration_runs_at_the_scenario_epoch_interval():
    """The calibration filters its runs at the scenario's step (process noise and noise
    correlation depend on it), and the step is part of the cache key."""
    d, truth = simulate(load_scenario("seed002", faults=[], duration_s=3))
    u = d.used[0]
    args = (d.pos_sv_ecef_m[0][u], truth.pos_rx_ecef_m[0], d.sys_idx[u], 1, d.noise,
            pf.ProcessModel())
    cfg = dict(n_particles=50, window=5, burn_in=5, p_fa_window=0.05, n_runs=4, n_armed=5)
    b1 = pf.calibrate_tau(*args, rng=np.random.default_rng(1), dt_s=1.0, **cfg).beta
    b30 = pf.calibrate_tau(*args, rng=np.random.default_rng(1), dt_s=30.0, **cfg).beta
    assert not np.allclose(b1, b30)
    with pytest.raises(ValueError, match="dt_s"):
        pf.calibrate_tau(*args, rng=np.random.default_rng(1), dt_s=0.0, **cfg)


def test_per_satellite_noise_scale_in_the_likelihood():
    """A Scaled noise model weighs each satellite by its own sigma (a recording's elevation
    model): with a uniform factor 2 it is exactly the noise model with twice the sigma;
    simulated scenarios have no scale at all."""
    from raimcore.algorithms.pf_llr import noise_scale
    from raimcore.measure.noise import make_noise, scaled

    d, truth = simulate(load_scenario("seed002", duration_s=2))
    model = pf.ProcessModel("static", 1)
    x = np.random.default_rng(0).normal(size=(50, 4)) * 5.0
    x[:, :3] += truth.pos_rx_ecef_m[0]
    base = make_noise("gaussian", 3.0)
    a = pf.log_likelihood(x, d.pos_sv_ecef_m[0], d.pr_m[0], d.used[0], d.sys_idx,
                          scaled(base, np.full(6, 2.0)), model)
    b = pf.log_likelihood(x, d.pos_sv_ecef_m[0], d.pr_m[0], d.used[0], d.sys_idx,
                          make_noise("gaussian", 6.0), model)
    np.testing.assert_allclose(a, b, rtol=1e-12)
    assert noise_scale(d) is None


def test_chunked_likelihood_equals_one_batch(monkeypatch):
    """Agreement: the likelihood of a big bank computed in chunks of filters equals the
    one-batch computation and a per-filter loop."""
    rng = np.random.default_rng(8)
    d, truth = simulate(load_scenario("seed002", duration_s=2))
    model = pf.ProcessModel()
    x = np.zeros((3, 7, 50, 4))
    x[..., :3] = truth.pos_rx_ecef_m[0] + rng.normal(0, 20, (3, 7, 50, 3))
    x[..., 3] = rng.normal(0, 20, (3, 7, 50))
    masks = np.vstack([np.ones(6, bool), ~np.eye(6, dtype=bool)])
    args = (d.pos_sv_ecef_m[1][None, None], d.pr_m[1][None, None], masks[None], d.sys_idx,
            d.noise, model)
    whole = pf.log_likelihood(x, *args)
    loop = np.array([[pf.log_likelihood(x[r, q], d.pos_sv_ecef_m[1], d.pr_m[1], masks[q],
                                        d.sys_idx, d.noise, model) for q in range(7)]
                     for r in range(3)])
    monkeypatch.setattr(pf, "_CHUNK_ELEMENTS", 700)  # two filters per chunk
    chunked = pf.log_likelihood(x, *args)
    np.testing.assert_allclose(chunked, whole, rtol=1e-12)
    np.testing.assert_allclose(loop, whole, rtol=1e-12)


def test_tau_per_satellite_set_when_asked():
    """tau_sets = "each": one calibration per satellite set in view, each armed epoch
    against its own set's tau; "first" (default) keeps the first set's tau throughout."""
    sc = load_scenario("seed002", faults=[], duration_s=260.0, restrict=[
        {"sats": ["G03", "G15", "G18", "G21", "G26"], "t0_s": 150.0, "t1_s": 220.0}])
    first = run_scenario(sc).table
    each = run_scenario(sc.replace(tau_sets="each")).table
    t = np.asarray(first["t_s"])
    armed = np.isfinite(np.asarray(first["threshold"], dtype=float))
    thr_f = np.asarray(first["threshold"], dtype=float)[armed]
    thr_e = np.asarray(each["threshold"], dtype=float)
    assert np.ptp(thr_f) == 0.0
    six, five = armed & (t < 150), armed & (t >= 150) & (t < 220)
    assert six.any() and five.any()
    assert np.ptp(thr_e[six]) == 0.0 and np.ptp(thr_e[five]) == 0.0
    assert thr_e[six][0] == thr_f[0] and thr_e[five][0] != thr_e[six][0]
    with pytest.raises(ValueError, match="tau_sets"):
        run_scenario(sc.replace(tau_sets="sometimes"))


# -- the clock proposal (pf.propose) -------------------------------------------------------

def _clock_setup(n, sigma_m, dt=30.0):
    """seed002's geometry, two systems (G02..G09 | G15, G19 read as a second system), a
    common state with a drift; pseudoranges from a clock 25 m / 12 m off the prediction.
    The position does not move (q_pos 0): the clock alone is under test."""
    d, truth = simulate(load_scenario("seed002", duration_s=2, faults=[]))
    model = pf.ProcessModel("static", 2, q_pos_mps=0.0, q_clk_mps=0.3, q_drift_mps2=0.2)
    sys_idx = np.array([0, 0, 0, 1, 0, 1])
    x = np.zeros((n, model.dim))
    x[:, :3] = truth.pos_rx_ecef_m[0]
    x[:, model.clocks] = [100.0, -40.0]
    x[:, model.drift] = 2.0
    sv = d.pos_sv_ecef_m[1]
    clock = np.array([100.0 + 2.0 * dt + 25.0, -40.0 + 2.0 * dt + 12.0])
    pr = (np.linalg.norm(sv - truth.pos_rx_ecef_m[0], axis=-1) + clock[sys_idx]
          + Gaussian(sigma_m).sample(np.random.default_rng(5), (6,)))
    return model, sys_idx, x, sv, pr, Gaussian(sigma_m), dt


def test_clock_proposal_importance_ratios_give_back_the_prior():
    """propose draws the offsets near the measurements; weighted by its ratios
    p(x_k | x_k-1) / q, the draw is the state equation's: mean b + d dt, covariance
    a I + beta 1 1^T (the moments of predict), E_q[ratio] = 1; the drift's law of total
    variance holds as for predict; the ratios never exceed 1 / PROPOSAL_DEFENSIVE (the
    defensive mixture). A 30 m noise keeps the proposal near the prior, so the importance
    sample is large enough to check moments."""
    n, v0 = 400_000, 0.3
    model, sys_idx, x, sv, pr, noise, dt = _clock_setup(n, 30.0, dt=10.0)
    mask = np.array([True, True, True, True, True, False])
    y, log_ratio = pf.propose(x, dt, model, np.random.default_rng(2), sv, pr, mask, sys_idx,
                              noise, drift_var=v0)
    ratio = np.exp(log_ratio)
    assert ratio.mean() == pytest.approx(1.0, abs=0.02)
    assert log_ratio.max() <= -math.log(pf.PROPOSAL_DEFENSIVE) + 1e-12  # bounded weights
    w = ratio / ratio.sum()
    off = y[:, model.clocks]
    mean = w @ off
    np.testing.assert_allclose(mean, [100.0 + 2.0 * dt, -40.0 + 2.0 * dt], atol=0.15)
    cov = (off - mean).T @ (w[:, None] * (off - mean))
    a, beta = 0.3**2 * dt, v0 * dt**2 + 0.2**2 * dt**3 / 3
    np.testing.assert_allclose(cov, a * np.eye(2) + beta, rtol=0.03)
    assert off.mean(0)[0] - mean[0] > 1.0  # the unweighted draw looked at the data (+25 m)
    v1 = pf.drift_step_var(model, v0, dt)
    dm = w @ y[:, model.drift]
    assert dm == pytest.approx(2.0, abs=0.02)
    assert w @ (y[:, model.drift] - dm) ** 2 + v1 == pytest.approx(v0 + 0.2**2 * dt, rel=0.03)


def test_clock_proposal_changes_the_monte_carlo_not_the_filter():
    """Agreement: one update at a 30 s step (19 m of clock prediction spread, 1 m Gaussian
    noise, the position known) is linear-Gaussian in the offsets and the drift; with the
    clock proposal 20,000 particles give the Kalman posterior mean and the predictive
    likelihood N(y; H m, H P H^T + R), where the bootstrap filter degenerates to one or
    two particles even with 1,000,000."""
    model, sys_idx, x, sv, pr, noise, dt = _clock_setup(1, 1.0)
    v0 = 0.04
    # Closed form: state (b_0, b_1, d), known offsets and a drift N(2, v0) at k - 1.
    f = np.array([[1.0, 0.0, dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    mean = f @ x[0, 3:]
    cov = f @ np.diag([0.0, 0.0, v0]) @ f.T + model.clock_cov(dt)
    h = np.zeros((6, 3))
    h[np.arange(6), sys_idx] = 1.0
    innov = pr - np.linalg.norm(sv - x[0, :3], axis=-1) - h @ mean
    s_mat = h @ cov @ h.T + np.eye(6)
    want = mean + cov @ h.T @ np.linalg.solve(s_mat, innov)
    want_log_pred = stats.multivariate_normal(np.zeros(6), s_mat).logpdf(innov)
    res = {}
    for proposal, n in (("clock", 20_000), ("prior", 1_000_000)):
        bank = pf.ParticleBank(np.repeat(x, n, 0), model, n_threshold=0, drift_var=v0,
                               proposal=proposal)
        res[proposal] = bank.step(dt, sv, pr, np.ones(6, bool), sys_idx, noise,
                                  np.random.default_rng(3))
    clock = res["clock"]
    assert clock.n_eff > 0.25 * 20_000 and res["prior"].n_eff < 10
    np.testing.assert_allclose(clock.estimate[3:], want, atol=0.02)
    assert clock.log_pred == pytest.approx(want_log_pred, abs=0.02)
    with pytest.raises(ValueError, match="proposal must be one of"):
        pf.ParticleBank(x[None], model, proposal="optimal")


def test_chunked_proposal_equals_one_batch(monkeypatch):
    """Agreement: the proposal computed in chunks of filters draws the same particles with
    the same ratios (every random number is drawn for the whole batch first), and its
    likelihood is log_likelihood's. (States in m, ratios and likelihoods in nepers: the
    same micro-unit tolerance.)"""
    model, sys_idx, x, sv, pr, noise, dt = _clock_setup(50, 1.0)
    x = np.broadcast_to(x, (3, 7) + x.shape).copy()
    x[..., :3] += np.random.default_rng(1).normal(0, 2.0, x.shape[:-1] + (3,))
    masks = np.vstack([np.ones(6, bool), ~np.eye(6, dtype=bool)])
    args = (dt, model, None, sv, pr, masks, sys_idx, noise, 1.0, 1.0, 0.04)

    def draw():
        a = list(args)
        a[2] = np.random.default_rng(7)
        return pf._propose(x, *a)

    whole = draw()
    monkeypatch.setattr(pf, "_CHUNK_ELEMENTS", 700)  # two filters per chunk
    chunked = draw()
    one_um = 1e-6  # the ranges are computed about each chunk's first particle (1e-8 m)
    for p, q in zip(whole, chunked, strict=True):
        np.testing.assert_allclose(p, q, rtol=0, atol=one_um)
    np.testing.assert_allclose(
        whole[2], pf.log_likelihood(whole[0], sv, pr, masks, sys_idx, noise, model),
        rtol=0, atol=one_um)


# -- the fast kernel against the reference (ParticleBank(kernel=...)) ----------------------

def _bank_case(case: str):
    """A bank of 7 filters (seed002, 6 satellites) for the agreement tests: the process
    model, noise model, system index, masks and start cloud of each case."""
    from raimcore.measure.noise import GaussianMixture, scaled

    d, truth = simulate(load_scenario("seed002", duration_s=12))
    masks = np.vstack([np.ones(6, bool), ~np.eye(6, dtype=bool)])
    sys_idx, noise, n_clk = d.sys_idx, d.noise, 1
    model = pf.ProcessModel("static", 1, q_drift_mps2=0.2)
    if case == "two systems, gaussian":
        sys_idx, n_clk, noise = np.array([0, 0, 0, 1, 0, 1]), 2, Gaussian(3.0)
        model = pf.ProcessModel("static", 2, q_drift_mps2=0.2)
    elif case == "cv, mixture, a satellite unused":
        noise, model = GaussianMixture(3.0), pf.ProcessModel("cv", 1, q_drift_mps2=0.2)
        masks = masks & (np.arange(6) != 4)
    elif case == "no drift, scaled noise":
        noise, model = scaled(StudentT(3.0), np.linspace(0.8, 2.0, 6)), pf.ProcessModel()
    rng = np.random.default_rng(11)
    fix = pf.robust_fix(d.pos_sv_ecef_m[0], d.pr_m[:1], d.used[0], d.sys_idx, 1, d.noise)
    x = np.zeros((2, 7, 300, model.dim))
    x[..., :3] = truth.pos_rx_ecef_m[0] + rng.normal(0, 8.0, x.shape[:-1] + (3,))
    x[..., model.clocks] = fix.clock_m[0, 0] + rng.normal(0, 8.0, x.shape[:-1] + (n_clk,))
    if model.kind == "cv":
        x[..., 3:6] = rng.normal(0, 1.0, x.shape[:-1] + (3,))
    if model.has_drift:
        x[..., model.drift] = rng.normal(0, 0.5, x.shape[:-1])
    return d, model, noise, sys_idx, masks, x


def _bank_steps(case, kernels):
    """One bank per kernel from :func:`_bank_case`'s cloud, each with its own generator of
    the same seed; returns ``(banks, rngs, steps)``, ``steps`` yielding, for 10 steps (a
    5 s gap at the 4th, a clock restart at the 7th), ``{kernel: StepResult}``."""
    d, model, noise, sys_idx, masks, x = _bank_case(case)
    banks = {k: pf.ParticleBank(x, model, drift_var=0.3 if model.has_drift else 0.0,
                                kernel=k) for k in kernels}
    rngs = {k: np.random.default_rng(5) for k in kernels}

    def steps():
        for k in range(1, 11):
            dt = 5.0 if k == 4 else 1.0
            reset = pf.CLOCK_RESET_SD_M**2 if k == 7 else 0.0
            yield {name: bank.step(dt, d.pos_sv_ecef_m[k][None, None],
                                   d.pr_m[k][None, None], masks[None], sys_idx, noise,
                                   rngs[name], q_scale=2.0, reset_var=reset)
                   for name, bank in banks.items()}

    return banks, rngs, steps()


@pytest.mark.parametrize("case", ["one system, student-t", "two systems, gaussian",
                                  "cv, mixture, a satellite unused", "no drift, scaled noise"])
def test_fast_bank_step_agrees_with_the_reference(case):
    """Agreement: 10 steps of the fast kernel and of the reference from the same cloud and
    seed (two realisations x 7 filters x 300 particles, a 5 s gap and a clock restart on
    the way) give the same particles, weights, predictive likelihoods, N_eff, estimates
    and resampling decisions: the same random numbers in the same order, the same
    formulas; the differences are rounding (the squared ranges are summed in another
    order: nanometres)."""
    banks, rngs, steps = _bank_steps(case, pf.KERNELS)
    for out in steps:
        fast, ref = out["fast"], out["reference"]
        np.testing.assert_array_equal(fast.resampled, ref.resampled)
        np.testing.assert_allclose(fast.log_pred, ref.log_pred, rtol=0, atol=1e-6)
        np.testing.assert_allclose(fast.n_eff, ref.n_eff, rtol=1e-6)
        np.testing.assert_allclose(fast.estimate, ref.estimate, rtol=0, atol=1e-6)
        np.testing.assert_allclose(banks["fast"].particles, banks["reference"].particles,
                                   rtol=0, atol=1e-6)
        np.testing.assert_allclose(banks["fast"].log_w, banks["reference"].log_w, rtol=0,
                                   atol=1e-6)
        np.testing.assert_allclose(banks["fast"].drift_var, banks["reference"].drift_var,
                                   rtol=1e-12)
    assert np.any([ref.resampled])  # the resampling path was exercised
    assert np.ptp(banks["fast"].particles[..., 0]) > 1.0  # and the clouds did move


@pytest.mark.parametrize("budget", [700, 100, 1])
def test_fast_kernel_blocks_change_nothing(budget, monkeypatch):
    """Agreement: the fast kernel's per-particle work done in blocks of filters (700
    pairs: two filters), of particles within a filter (100: 16 particles) or one particle
    at a time gives the one-block result."""
    d, model, noise, sys_idx, masks, x = _bank_case("two systems, gaussian")

    def two_steps():  # the numpy fast kernel: the one that works in blocks
        bank = pf.ParticleBank(x[:, :, :50], model, drift_var=0.3, kernel="fast")
        rng = np.random.default_rng(2)
        out = [bank.step(1.0, d.pos_sv_ecef_m[k], d.pr_m[k], masks, sys_idx, noise, rng)
               for k in (1, 2)]
        return bank, out

    whole, res_whole = two_steps()
    monkeypatch.setattr(pf, "_FAST_CHUNK_ELEMENTS", budget)
    blocks, res_blocks = two_steps()
    # Rounding only: a one-particle block sums its likelihood by another BLAS path.
    tiny_neper = 1e-7
    np.testing.assert_allclose(blocks.particles, whole.particles, rtol=0, atol=ONE_NM)
    np.testing.assert_allclose(blocks.log_w, whole.log_w, rtol=0, atol=tiny_neper)
    for a, b in zip(res_blocks, res_whole, strict=True):
        np.testing.assert_allclose(a.log_pred, b.log_pred, rtol=0, atol=tiny_neper)


@pytest.mark.parametrize("kernel", pf.KERNELS)
def test_bank_step_leaves_the_start_cloud_alone(kernel):
    """Every kernel updates the bank's own copy (the fast and numba ones in place), never
    the caller's array."""
    d, model, noise, sys_idx, masks, x = _bank_case("one system, student-t")
    before = x.copy()
    bank = pf.ParticleBank(x, model, kernel=kernel)
    bank.step(1.0, d.pos_sv_ecef_m[1], d.pr_m[1], masks, sys_idx, noise,
              np.random.default_rng(0))
    np.testing.assert_array_equal(x, before)
    assert not np.array_equal(bank.particles, before)


def test_run_llr_bank_kernels_agree():
    """Agreement over a whole run (seed002 with its fault, 60 s, N = 100): the windowed
    LLRs, beta, argmax and estimates of the fast kernel are the reference's."""
    d, _ = simulate(load_scenario("seed002", duration_s=100, t_start_s=60.0))
    args = (d.pos_sv_ecef_m, d.pr_m[None], d.used, d.t_s, d.sys_idx, 1, d.noise,
            pf_llr.process_model(pf_llr.SPEC.resolve_options({}), 1))
    cfg = dict(n_particles=100, window=10, burn_in=5)
    runs = {k: pf.run_llr_bank(*args, **cfg, rng=np.random.default_rng(3), kernel=k)
            for k in pf.KERNELS}
    fast, ref = runs["fast"], runs["reference"]
    np.testing.assert_array_equal(fast.argmax, ref.argmax)
    np.testing.assert_allclose(fast.cum_llr, ref.cum_llr, rtol=0, atol=1e-5)
    np.testing.assert_allclose(fast.beta, ref.beta, rtol=0, atol=1e-5)
    np.testing.assert_allclose(fast.estimate, ref.estimate, rtol=0, atol=1e-5)
    assert np.nanmax(fast.beta) > 20.0  # the 50 m step on G19 was seen


# -- the compiled kernel against the numpy fast kernel (ParticleBank(kernel="numba")) -------

needs_numba = pytest.mark.skipif(pf.numba_kernels() is None,
                                 reason="numba not installed (the fast extra) or disabled")
#: Numba against the numpy fast kernel: the same formulas, sums in another order. States
#: in m, log weights and log-likelihoods in nepers (measured: 2e-8 at most).
NUMBA_ATOL = 1e-7


def _assert_steps_agree(a, b, bank_a, bank_b):
    np.testing.assert_array_equal(a.resampled, b.resampled)
    np.testing.assert_allclose(a.log_pred, b.log_pred, rtol=0, atol=NUMBA_ATOL)
    np.testing.assert_allclose(a.n_eff, b.n_eff, rtol=1e-8)
    np.testing.assert_allclose(a.estimate, b.estimate, rtol=0, atol=NUMBA_ATOL)
    np.testing.assert_allclose(bank_a.particles, bank_b.particles, rtol=0, atol=NUMBA_ATOL)
    np.testing.assert_allclose(bank_a.log_w, bank_b.log_w, rtol=0, atol=NUMBA_ATOL)
    np.testing.assert_array_equal(bank_a.drift_var, bank_b.drift_var)


@needs_numba
@pytest.mark.parametrize("case", ["one system, student-t", "two systems, gaussian",
                                  "cv, mixture, a satellite unused", "no drift, scaled noise"])
def test_numba_bank_step_agrees_with_the_fast_kernel(case):
    """Agreement: 10 steps of the compiled kernel and of the numpy fast kernel from the
    same cloud and seed (two realisations x 7 filters x 300 particles, a 5 s gap and a
    clock restart on the way): the same random numbers, the same particles, weights,
    predictive likelihoods, estimates and resampling decisions to rounding."""
    banks, rngs, steps = _bank_steps(case, ("numba", "fast"))
    assert banks["numba"].kernel == "numba"
    resampled = 0
    for out in steps:
        _assert_steps_agree(out["numba"], out["fast"], banks["numba"], banks["fast"])
        resampled += out["numba"].resampled.sum()
    assert 0 < resampled < 10 * 14  # resampling exercised, not on every step
    # Both generators consumed the same random numbers.
    assert rngs["numba"].random() == rngs["fast"].random()


@needs_numba
@pytest.mark.parametrize("noise", [StudentT(1.0), Gaussian(2.0)], ids=["student-t", "gaussian"])
def test_numba_kernel_edges(noise):
    """Edge table: 30 satellites of one system, huge residuals (a 1e9 m common error: the
    Student-t product of 1 + t^2 over the satellites passes 1e250 and is taken in parts),
    a NaN pseudorange on a satellite no filter uses, a filter that sees no satellite
    (predict only) and one that sees a single one; the compiled kernel agrees with the
    numpy fast kernel and no NaN reaches a neighbouring filter."""
    rng = np.random.default_rng(4)
    s_n, n = 30, 64
    rx = np.array([4.0e6, 3.0e5, 4.9e6])
    u = rng.normal(size=(s_n, 3))
    sv = rx + 2.2e7 * (u / np.linalg.norm(u, axis=-1, keepdims=True))
    pr = np.linalg.norm(sv - rx, axis=-1) + 1e9 + rng.normal(0, 2.0, s_n)
    pr[7] = np.nan
    masks = np.ones((5, s_n), bool)
    masks[:, 7] = False
    masks[1] = False  # no satellite: predict only
    masks[2] = False
    masks[2, 3] = True  # one satellite
    masks[3, ::2] = False
    model = pf.ProcessModel("static", 1, q_drift_mps2=0.2)
    x = np.zeros((5, n, model.dim))
    x[..., :3] = rx + rng.normal(0, 5.0, (5, n, 3))
    x[..., 3] = 1e9 + rng.normal(0, 5.0, (5, n))
    banks = {k: pf.ParticleBank(x, model, drift_var=0.1, kernel=k) for k in ("numba", "fast")}
    sys_idx = np.zeros(s_n, dtype=int)
    for k in range(3):
        out = {name: bank.step(1.0, sv, pr + 3e9 * (k == 2), masks, sys_idx, noise,
                               np.random.default_rng(k)) for name, bank in banks.items()}
        assert np.all(np.isfinite(out["numba"].log_pred[[0, 2, 3, 4]]))
        assert np.all(np.isfinite(banks["numba"].particles))
        np.testing.assert_array_equal(out["numba"].log_pred[1], 0.0)
        # Log-likelihoods of order 1e3 nepers: agreement relative to them.
        np.testing.assert_allclose(out["numba"].log_pred, out["fast"].log_pred, rtol=1e-12,
                                   atol=NUMBA_ATOL)
        np.testing.assert_allclose(banks["numba"].particles, banks["fast"].particles,
                                   rtol=1e-15, atol=NUMBA_ATOL)  # clocks of 1e9 m: ulps
        np.testing.assert_array_equal(out["numba"].resampled, out["fast"].resampled)


@needs_numba
def test_numba_bank_steps_an_unknown_noise_model_with_numpy():
    """A noise model the compiled loops do not know (here a subclass of Gaussian: its
    logpdf may be anything) is stepped by the numpy fast kernel: exactly its results."""

    class Wider(Gaussian):
        def logpdf(self, x_m):
            return super().logpdf(np.asarray(x_m) / 2.0)

    d, model, _, sys_idx, masks, x = _bank_case("two systems, gaussian")
    noise = Wider(3.0)
    banks = [pf.ParticleBank(x, model, drift_var=0.3, kernel=k) for k in ("numba", "fast")]
    res = [b.step(1.0, d.pos_sv_ecef_m[1], d.pr_m[1], masks, sys_idx, noise,
                  np.random.default_rng(1)) for b in banks]
    np.testing.assert_array_equal(res[0].log_pred, res[1].log_pred)
    np.testing.assert_array_equal(banks[0].particles, banks[1].particles)


@needs_numba
def test_run_llr_bank_numba_agrees_with_the_fast_kernel():
    """Agreement over a whole run (seed002 with its fault, 100 s, N = 100): the windowed
    LLRs, beta, argmax and estimates of the compiled kernel are the numpy fast kernel's."""
    d, _ = simulate(load_scenario("seed002", duration_s=100, t_start_s=60.0))
    args = (d.pos_sv_ecef_m, d.pr_m[None], d.used, d.t_s, d.sys_idx, 1, d.noise,
            pf_llr.process_model(pf_llr.SPEC.resolve_options({}), 1))
    cfg = dict(n_particles=100, window=10, burn_in=5)
    runs = {k: pf.run_llr_bank(*args, **cfg, rng=np.random.default_rng(3), kernel=k)
            for k in ("numba", "fast")}
    got, want = runs["numba"], runs["fast"]
    np.testing.assert_array_equal(got.argmax, want.argmax)
    np.testing.assert_allclose(got.cum_llr, want.cum_llr, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got.beta, want.beta, rtol=0, atol=1e-6)
    np.testing.assert_allclose(got.estimate, want.estimate, rtol=0, atol=1e-6)
    assert np.nanmax(got.beta) > 20.0


@needs_numba
def test_numba_is_the_default_and_warms_up():
    """With numba installed a bank runs the compiled kernel unless told otherwise, and the
    dashboard's warm-up (a tiny bank step) runs."""
    x = np.zeros((2, 8, 4))
    assert pf.DEFAULT_KERNEL == "numba"
    assert pf.ParticleBank(x, pf.ProcessModel()).kernel == "numba"
    assert pf.ParticleBank(x, pf.ProcessModel(), kernel="fast").kernel == "fast"
    pf.numba_kernels().warm_up()


def test_numpy_path_when_numba_is_switched_off(monkeypatch):
    """RAIM_STUDIO_NUMBA=0 keeps numba out: a bank asked for the compiled kernel (or made
    by default) runs the numpy fast kernel, says so, and gives the fast kernel's results
    exactly; the same bank step as with numba, to rounding, where it is installed."""
    d, model, noise, sys_idx, masks, x = _bank_case("one system, student-t")
    on = pf.numba_kernels() is not None
    with_numba = pf.ParticleBank(x, model, drift_var=0.3, kernel="numba")
    monkeypatch.setenv(pf.NUMBA_ENV, "0")
    assert not pf.numba_enabled() and pf.numba_kernels() is None
    banks = [pf.ParticleBank(x, model, drift_var=0.3, kernel=k) for k in ("numba", "fast")]
    banks.append(pf.ParticleBank(x, model, drift_var=0.3))
    assert [b.kernel for b in banks] == ["fast", "fast", "fast"]
    args = (1.0, d.pos_sv_ecef_m[1], d.pr_m[1], masks, sys_idx, noise)
    res = [b.step(*args, np.random.default_rng(9)) for b in banks]
    for r, b in zip(res[1:], banks[1:], strict=True):
        np.testing.assert_array_equal(r.log_pred, res[0].log_pred)
        np.testing.assert_array_equal(b.particles, banks[0].particles)
    if on:  # the bank made before the switch keeps its kernel: agreement to rounding
        assert with_numba.kernel == "numba"
        ref = with_numba.step(*args, np.random.default_rng(9))
        _assert_steps_agree(ref, res[0], with_numba, banks[0])


def test_switched_off_numba_is_never_imported():
    """A process started with RAIM_STUDIO_NUMBA=0 defaults to the numpy fast kernel and
    never imports numba, even after a bank step; without it, ``import raimcore`` and the
    pf module still leave numba unimported (it is paid at the first bank only)."""
    import importlib.util
    import os
    import subprocess
    import sys

    code = ("import sys, numpy as np; from raimcore.algorithms import pf; "
            "print(pf.DEFAULT_KERNEL, 'numba' in sys.modules); "
            "b = pf.ParticleBank(np.zeros((1, 4, 4)), pf.ProcessModel()); "
            "print(b.kernel, 'numba' in sys.modules)")
    env = dict(os.environ, RAIM_STUDIO_NUMBA="0")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    assert out == ["fast", "False", "fast", "False"]
    env.pop("RAIM_STUDIO_NUMBA")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout.split()
    installed = importlib.util.find_spec("numba") is not None
    works = installed and pf._numba_module() is not None
    assert out == ["numba" if installed else "fast", "False", "numba" if works else "fast",
                   str(works)]


@pytest.mark.parametrize("path", ["network", "sort"])
@pytest.mark.parametrize("n_sat", [1, 2, 3, 5, 6, 7, 9, 16, 24, 25, 40])
def test_selection_network_median_is_the_sorted_median(n_sat, path, monkeypatch):
    """The fast kernel's median (a pruned Batcher network; a sort for few values or above
    _NETWORK_MAX satellites) equals the reference's sort-based median exactly, for any
    mask, including a filter with no satellite of a system and rows with different
    counts."""
    monkeypatch.setattr(pf, "_NETWORK_MIN_VALUES", 0 if path == "network" else 10**9)
    rng = np.random.default_rng(n_sat)
    resid = rng.standard_t(3, (5, 40, n_sat)) * 10.0
    mask = rng.random((5, n_sat)) < 0.7
    mask[0] = True
    mask[1] = False
    sys_idx = rng.integers(0, 2, n_sat)
    want = pf._system_median(resid, mask, sys_idx, 2)
    got = pf._masked_median(np.ascontiguousarray(np.swapaxes(resid, -1, -2)), mask, sys_idx,
                            2)
    np.testing.assert_array_equal(np.swapaxes(got, -1, -2), want)
    for s in range(2):  # row 0 sees every satellite: numpy's median
        cols = sys_idx == s
        np.testing.assert_array_equal(
            got[0, s], np.median(resid[0][:, cols], axis=-1) if cols.any() else 0.0)
    assert np.all(got[1] == 0.0)  # row 1 sees none


def test_doctests():
    import doctest

    assert doctest.testmod(pf).failed == 0


def test_median_network_is_a_selection_network():
    """0-1 principle (Knuth TAOCP 5.3.4): a comparator network puts the right values on
    its outputs for every input iff it does so for every 0-1 input; checked exhaustively
    up to 12 wires for the median outputs the kernel asks for."""
    for n in range(1, 13):
        outs = tuple(sorted({(k - 1) // 2 for k in (n, n - 1) if k > 0}
                            | {k // 2 for k in (n, n - 1) if k > 0}))
        net = pf.median_network(n, outs)
        bits = (np.arange(2**n)[:, None] >> np.arange(n)) & 1
        v = bits.copy()
        for i, j in net:
            lo, hi = np.minimum(v[:, i], v[:, j]), np.maximum(v[:, i], v[:, j])
            v[:, i], v[:, j] = lo, hi
        want = np.sort(bits, axis=1)
        np.testing.assert_array_equal(v[:, list(outs)], want[:, list(outs)])


def test_counting_resampler_equals_systematic_resampling():
    """The fast kernel's resampler counts each particle's copies (ceil(N c - u)) instead of
    searching the cumulative weights: the same indices from the same uniform draw."""
    rng = np.random.default_rng(12)
    w = rng.dirichlet(np.full(50, 0.3), size=400)
    w[0] = 0.0
    w[0, 7] = 1.0
    want = pf.systematic_resample(w, np.random.default_rng(13))
    got = pf._resample_fast(w, np.random.default_rng(13)).reshape(w.shape)
    np.testing.assert_array_equal(got - 50 * np.arange(400)[:, None], want)


def test_clock_jump_median_matches_nanmedian():
    """clock_jump's masked median (a sort with +inf) is numpy's nanmedian of the masked
    residuals, NaN residuals ignored, a system without satellites 0."""
    rng = np.random.default_rng(3)
    for _ in range(200):
        r_n, s_n = rng.integers(1, 5), rng.integers(1, 9)
        resid = rng.normal(0, 3000.0, (r_n, s_n))
        resid[rng.random((r_n, s_n)) < 0.1] = np.nan
        mask = rng.random((r_n, s_n)) < 0.7
        sys_idx = rng.integers(0, 3, s_n)
        got = pf.clock_jump(resid, mask, sys_idx, 3, 1000.0)
        for s in range(3):
            v = np.where(mask & (sys_idx == s), resid, np.nan)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # a row with none: NaN
                med = np.nan_to_num(np.nanmedian(v, axis=-1))
            want = np.where(np.abs(med) > 1000.0, med, 0.0)
            np.testing.assert_array_equal(got[:, s], want)


# -- the per-epoch work around the kernels (issue 17: a PF-LLR control change <= 100 ms) ----

def _restarted(d, rng: np.random.Generator):
    """``d`` whose receiver clock restarts (flagged) at 30 % of its epochs, moving by
    20-300 m and its drift by 1-10 m/s (as ``tests/test_clock_reset.py``'s)."""
    import dataclasses

    e = d.n_epochs
    at = rng.random(e) < 0.3
    at[0] = False
    sign = rng.choice([-1.0, 1.0], (2, e))
    jump = np.where(at, sign[0] * rng.uniform(20.0, 300.0, e), 0.0)
    dd = np.where(at, sign[1] * rng.uniform(1.0, 10.0, e), 0.0)
    t = np.asarray(d.t_s, dtype=float)
    clock = np.cumsum(jump) + np.maximum(t[:, None] - t[None, :], 0.0) @ dd
    return dataclasses.replace(d, pr_m=d.pr_m + clock[:, None], clock_reset=at)


#: Recorded before the per-epoch work around the kernels was cut (issue 17), by this
#: module's ``_recorded_run`` with the numba, fast and reference kernels (all three gave
#: these to the digits kept): beta at armed epochs 60, 105, ..., 375, the argmax counts per
#: satellite and sum over armed epochs of epoch x argmax, the main filter's last position
#: (m), the number of nonzero clock jumps and their sum (m).
RECORDED_RUNS = {
    "seed002": ([93.474266, 212.551104, 335.245585, 88.02324, 89.850441, 94.534422,
                 91.266782, 97.580423], [88, 42, 48, 37, 35, 109], 186386,
                [-2178656.0549, 4388875.7827, 4069504.9778], 0, 0.0),
    "free clock, a 1 ms jump": (
        [96.44661, 211.671817, 323.499694, 91.93695, 94.160446, 92.721724, 92.674234,
         95.45212], [28, 64, 47, 49, 35, 136], 255198,
        [-2178657.903, 4388877.485, 4069506.7579], 1, -299790.5406),
    "flagged restarts": (
        [99.588371, 216.779244, 331.411002, 90.026489, 93.319791, 93.303209, 91.094,
         94.80647], [61, 74, 27, 28, 47, 122], 211649,
        [-2178655.8349, 4388875.2208, 4069504.6086], 225, -1225.7542),
}


def _recorded_run(case: str, kernel: str):
    """The seeded run behind :data:`RECORDED_RUNS` (seed002, N = 100, W = 30, 418 epochs)."""
    keys = {"free clock, a 1 ms jump": dict(clock_drift_mps=400.0, clock_jumps_s=[200.0],
                                            seed=3)}.get(case, {})
    d, _ = simulate(load_scenario("seed002", **keys))
    if case == "flagged restarts":
        d = _restarted(d, np.random.default_rng(5))
    model = pf_llr.process_model(pf_llr.SPEC.resolve_options({}), 1)
    return pf.run_llr_bank(d.pos_sv_ecef_m, d.pr_m[None], d.used, d.t_s, d.sys_idx, 1,
                           d.noise, model, n_particles=100, window=30, burn_in=30,
                           rng=np.random.default_rng(7), kernel=kernel,
                           clock_reset=d.clock_reset)


@pytest.mark.parametrize("case", list(RECORDED_RUNS))
@pytest.mark.parametrize("kernel", ["numba", "fast"])
def test_bank_runs_equal_the_runs_recorded_before_the_overhead_cut(case, kernel):
    """Regression: seeded whole runs (a fault, a free-running clock with a 1 ms jump, clock
    restarts flagged at 30 % of the epochs) give the windowed LLRs, decisions, positions
    and clock jumps recorded before the per-epoch work around the kernels was cut: the
    same random numbers, the same formulas (measured: every array bit for bit)."""
    run = _recorded_run(case, kernel)
    beta, counts, checksum, last, n_jumps, jump_sum = RECORDED_RUNS[case]
    armed = np.flatnonzero(run.armed)
    assert armed.size == 359
    one_micro = 1e-6  # the digits kept (nepers; the kernels agree to 1e-8)
    np.testing.assert_allclose(run.beta[0, armed[::45]], beta, rtol=0, atol=one_micro)
    arg = run.argmax[0, armed]
    assert np.bincount(arg, minlength=6).tolist() == counts
    assert int((arg * armed).sum()) == checksum
    np.testing.assert_allclose(run.estimate[0, -1, 0, :3], last, rtol=0, atol=1e-4)
    assert np.count_nonzero(run.clock_jump_m) == n_jumps
    np.testing.assert_allclose(run.clock_jump_m.sum(), jump_sum, rtol=0, atol=1e-4)


def test_reference_kernel_run_equals_the_recorded_run():
    """The plain numpy reference kernel over the same seeded run with flagged restarts:
    the recorded values too (the loop around the kernels is shared)."""
    run = _recorded_run("flagged restarts", "reference")
    beta, counts, checksum, *_ = RECORDED_RUNS["flagged restarts"]
    armed = np.flatnonzero(run.armed)
    np.testing.assert_allclose(run.beta[0, armed[::45]], beta, rtol=0, atol=1e-5)
    arg = run.argmax[0, armed]
    assert np.bincount(arg, minlength=6).tolist() == counts
    assert int((arg * armed).sum()) == checksum


def test_one_normal_draw_is_two_draws_one_after_the_other():
    """What the bank step relies on to draw the motion and clock noise at once: a
    Generator fills an array element by element, so one standard normal draw of a + b
    numbers is a draw of a then a draw of b (ziggurat rejections included), and the
    uniform draw after them is the same."""
    for seed in range(5):
        one, two = np.random.default_rng(seed), np.random.default_rng(seed)
        both = one.standard_normal(7 * 100 * 5 + 7 * 100)
        a = two.standard_normal((1, 7, 100, 5))
        b = two.standard_normal((1, 7, 100, 1))
        np.testing.assert_array_equal(both, np.concatenate([a.ravel(), b.ravel()]))
        assert one.random() == two.random()


@pytest.mark.parametrize("kernel", ["numba", "fast"])
def test_kept_per_filter_terms_change_nothing(kernel, monkeypatch):
    """Agreement: a bank keeping its per-filter terms across steps (masks, clock proposal,
    drift gain and variance, median plans) steps exactly as one that recomputes them at
    every step, with the masks changed in place in one array between steps (the terms are
    kept by content, never by identity), the drift variance changed in place (as a clock
    jump does) and a clock restart on the way."""
    d, model, noise, sys_idx, masks, x = _bank_case("one system, student-t")
    banks = [pf.ParticleBank(x, model, drift_var=0.3, kernel=kernel) for _ in range(2)]
    rngs = [np.random.default_rng(5) for _ in banks]
    mask = masks.copy()
    for k in range(1, 11):
        mask[...] = masks & (np.arange(6) != (k // 3))  # in place: another satellite out
        if k == 6:
            for bank in banks:
                bank.drift_var[0, 0] = 4.0
        reset = pf.CLOCK_RESET_SD_M**2 if k == 7 else 0.0
        out = []
        for i, (bank, rng) in enumerate(zip(banks, rngs, strict=True)):
            if i == 1:  # recompute everything
                bank._prep = pf._PrepCache()
                monkeypatch.setattr(pf, "_MEDIAN_PLANS", {})
                monkeypatch.setattr(pf, "_SYS_IDX", {})
            out.append(bank.step(1.0, d.pos_sv_ecef_m[k][None, None], d.pr_m[k][None, None],
                                 mask[None], sys_idx, noise, rng, q_scale=2.0,
                                 reset_var=reset))
        np.testing.assert_array_equal(out[0].log_pred, out[1].log_pred)
        np.testing.assert_array_equal(out[0].estimate, out[1].estimate)
        np.testing.assert_array_equal(banks[0].particles, banks[1].particles)
        np.testing.assert_array_equal(banks[0].log_w, banks[1].log_w)
        np.testing.assert_array_equal(banks[0].drift_var, banks[1].drift_var)
    assert banks[0].kernel == (kernel if pf.numba_kernels() is not None else "fast")


@pytest.mark.parametrize("kernel", ["numba", "fast"])
@pytest.mark.parametrize("model", [pf.ProcessModel("static", 2, q_drift_mps2=0.2),
                                   pf.ProcessModel("cv", 2)], ids=["static", "cv"])
def test_clock_jump_screen_never_hides_a_jump(kernel, model):
    """Property: the cheap screen before the jump detector (:func:`pf._may_jump`) says
    "no jump" only where the detector finds none (:func:`pf._common_mode`), over clouds
    whose common-mode innovation sits anywhere around the 1000 m threshold, within
    millimetres of it included, for two systems; and it says "maybe" at a real jump."""
    rng = np.random.default_rng(8)
    d, _ = simulate(load_scenario("seed002", duration_s=5))
    sys_idx = np.array([0, 1, 0, 1, 0, 0])
    used = np.array([True, True, True, True, False, True])
    sv, rx = d.pos_sv_ecef_m[1], np.array([-2178650.0, 4388870.0, 4069500.0])
    rng_m = np.linalg.norm(sv - rx, axis=-1)
    seen = {True: 0, False: 0}
    for offset in np.concatenate([rng.uniform(0.0, 2000.0, 60),
                                  pf.CLOCK_JUMP_M + rng.uniform(-2e-3, 2e-3, 40)]):
        x = np.zeros((2, 3, 50, model.dim))
        x[..., :3] = rx + rng.normal(0.0, 3.0, x.shape[:-1] + (3,))
        pr = rng_m + rng.normal(0.0, 0.5, (2, 6)) + np.where(sys_idx == 1, offset, 0.0)
        pr[1, 4] = np.nan  # an unused satellite
        bank = pf.ParticleBank(x, model, kernel=kernel)
        bank.log_w = np.log(rng.dirichlet(np.ones(50), (2, 3)))
        exact = pf._common_mode(bank, 1.0, sv, pr, used, sys_idx, 2, pf.CLOCK_JUMP_M)
        maybe = pf._may_jump(bank, 1.0, sv, pr, used, sys_idx)
        assert maybe or not exact.any(), offset
        if offset > pf.CLOCK_JUMP_M + 50.0:
            assert maybe and exact.any()
        seen[bool(maybe)] += 1
    assert seen[True] and seen[False]
