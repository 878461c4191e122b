"""The seed 002 reference scenario: PF-LLR isolates G19 and beats the EKF under heavy tails."""

import numpy as np
import pytest

from raimcore.geometry import ecef_to_enu
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario
from raimcore.scoring import in_fault_memory

SEEDS = (0, 1, 2, 3, 4)


@pytest.fixture(scope="module")
def runs():
    out = {}
    for seed in SEEDS:
        for alg in ("pf-llr", "ekf"):
            out[alg, seed] = run_scenario(load_scenario("seed002", algorithm=alg, seed=seed))
    return out


@pytest.mark.parametrize("seed", SEEDS)
def test_pf_llr_names_g19_at_every_alarm_and_detects_fast(runs, seed):
    t = runs["pf-llr", seed].table
    alarm = t["alarm"]
    assert alarm.any()
    assert np.all(t["isolated"][alarm] == "G19")
    assert np.all(t["excluded"][alarm] == "G19")
    first = t["t_s"][alarm][0]
    assert 90 <= first <= 100  # detection delay under 10 s (W = 30)
    # No alarm before the fault.
    assert not alarm[t["t_s"] < 90].any()


@pytest.mark.parametrize("seed", SEEDS)
def test_pf_rmse_below_ekf_rmse_under_heavy_tails(runs, seed):
    pf_rmse = runs["pf-llr", seed].summary["rmse_before_m"]
    ekf_rmse = runs["ekf", seed].summary["rmse_before_m"]
    assert pf_rmse < 0.5 * ekf_rmse, (pf_rmse, ekf_rmse)


def test_pf_llr_output_columns(runs):
    t = runs["pf-llr", 0].table
    armed = t["status"] == "ok"
    np.testing.assert_allclose(t["beta"][armed], t["statistic"][armed])
    # First fix at t = 0, burn-in 30 epochs, then the window fills: armed from t = 60 s.
    assert np.all(t["status"][:60] == "not-armed") and t["status"][60] == "ok"
    # Cumulative LLR per satellite: G19's dominates during the fault.
    fault = (t["t_s"] >= 100) & (t["t_s"] < 153)
    llr = t.per_sat["llr"][fault]
    assert np.all(np.argmax(llr, axis=1) == t.sat_names.index("G19"))
    np.testing.assert_allclose(np.nanmax(t.per_sat["llr"][armed], axis=1), t["beta"][armed])
    n_eff = t["n_eff"][1:].astype(float)
    assert np.all((n_eff >= 1) & (n_eff <= 100))


def test_summary_leaves_the_window_after_a_fault_out_of_false_alarms(runs):
    """The W - 1 epochs after the fault ends still hold faulted epochs in their window:
    neither fault-free nor faulted."""
    sm = runs["pf-llr", 0].summary
    assert sm["fault_memory_epochs"] == 29
    assert sm["false_alarm_rate"] == 0.0
    # A memoryless algorithm (EKF) counts every epoch after the fault as fault-free.
    ekf = runs["ekf", 0].summary
    assert ekf["fault_memory_epochs"] == 0
    n = ekf["epochs"] - ekf["faulted_epochs"]
    assert ekf["false_alarm_n"] == n and sm["false_alarm_n"] == n - 29
    # Alarms inside the window are counted apart, not as false alarms.
    t = runs["pf-llr", 0].table
    memory = in_fault_memory(t["faulty_truth"] != "", t["memory_epochs"])
    assert sm.fault_memory_alarms == int(np.sum(t["alarm"] & memory)) > 0


def test_in_fault_memory():
    faulted = np.array([0, 0, 1, 1, 0, 0, 0, 0, 1, 0], dtype=bool)
    np.testing.assert_array_equal(in_fault_memory(faulted, np.full(10, 3)),
                                  [0, 0, 0, 0, 1, 1, 0, 0, 0, 1])
    assert not in_fault_memory(faulted, np.ones(10)).any()
    assert not in_fault_memory(faulted, None).any()


def test_dashboard_panels_show_beta_tau_llr_and_neff(runs):
    pytest.importorskip("plotly")
    from app import panels
    from app.session import run_view

    view = run_view(runs["pf-llr", 0])
    built = {k: b(view) for k, b in panels.panels_for(view, "llr")}
    names = [tr["name"] for tr in built["detection"].data]
    assert {"statistic", "threshold", "alarm"} <= set(names)
    assert built["per_sat"].key == "per_sat:llr"
    g19 = next(tr for tr in built["per_sat"].data if tr["name"] == "G19")
    assert g19["line"]["width"] > 2  # the faulty satellite is drawn thick
    cols = [tr["name"] for tr in built["columns"].data]
    assert "n_eff" in cols and "memory_epochs" not in cols


def test_particle_cloud_panel_follows_the_time_slider(runs):
    """pf-llr hands the main filter's cloud to the dashboard: a panel whose particles
    move with the time index; the weighted mean of the kept particles is the filter's
    estimate (its horizontal error is the table's HPE)."""
    pytest.importorskip("plotly")
    from app import panels
    from app.session import run_view

    r = runs["pf-llr", 0]
    cloud = r.output.extras["particles_ecef_m"]
    w = r.output.extras["particle_weight"]
    assert cloud.shape == (len(r.table), 100, 3)  # N = 100 <= 200 kept
    enu = ecef_to_enu(cloud, r.truth.pos_rx_ecef_m[:, None, :])
    np.testing.assert_allclose(np.nansum(w, axis=1)[1:], 1.0)
    mean = np.einsum("ek,eki->ei", w[60:], enu[60:])
    hpe = np.asarray(r.table["hpe_before_m"], float)[60:]
    # Equal where the filter did not resample; after a resampling the kept (equal-weight)
    # sample's mean differs from the pre-resampling weighted mean by resampling noise.
    np.testing.assert_allclose(np.hypot(mean[:, 0], mean[:, 1]), hpe, atol=0.2)
    assert np.mean(np.isclose(np.hypot(mean[:, 0], mean[:, 1]), hpe, atol=1e-6)) > 0.3
    view = run_view(r)
    built = dict(panels.panels_for(view))
    assert "particles" in built
    fig = built["particles"](view)
    a, _ = fig.dynamic(50)
    b, _ = fig.dynamic(300)
    assert len(a[0]["x"]) == 100 and not np.allclose(a[0]["x"], b[0]["x"])
    assert fig.layout["xaxis"]["range"][1] < 50  # metres around the truth, fixed axes
    ekf_view = run_view(runs["ekf", 0])
    assert "particles" not in dict(panels.panels_for(ekf_view))


def test_gaussian_mixture_noise_too():
    """The same with the other heavy-tailed model (10 % outliers at 5 sigma)."""
    pf_run = run_scenario(load_scenario("seed002", algorithm="pf-llr", noise="mixture"))
    ekf_run = run_scenario(load_scenario("seed002", algorithm="ekf", noise="mixture"))
    t = pf_run.table
    assert t["alarm"].any() and np.all(t["isolated"][t["alarm"]] == "G19")
    assert pf_run.summary["rmse_before_m"] < 0.5 * ekf_run.summary["rmse_before_m"]
