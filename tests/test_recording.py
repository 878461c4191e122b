"""Real recordings (../shared/data, skipped when absent): SPP accuracy, false alarms of the
parity test on fault-free real data, faults injected into real pseudoranges."""

import numpy as np
import pytest
from scipy import stats

from raimcore import algorithms
from raimcore.cli import main
from raimcore.geometry import ecef_to_enu
from raimcore.measure.faults import Fault
from raimcore.pipeline import run_scenario
from raimcore.scenario import from_dict, load_scenario, recording_scenario
from raimcore.sky.rinex import read_nav, read_obs
from raimcore.sky.spp import spp

ESBC_OBS = "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx"
SLAC_OBS, SLAC_NAV = "slac1180.21o", "brdc1180.21n"


@pytest.fixture
def esbc(shared_data):
    return str(shared_data / ESBC_OBS), str(shared_data / ESBC_NAV)


@pytest.fixture
def slac(shared_data):
    return str(shared_data / SLAC_OBS), str(shared_data / SLAC_NAV)


@pytest.mark.parametrize("files,systems", [
    ((ESBC_OBS, ESBC_NAV), ("GPS",)), ((ESBC_OBS, ESBC_NAV), ("BDS",)),
    ((ESBC_OBS, ESBC_NAV), ("GPS", "BDS")), ((SLAC_OBS, SLAC_NAV), ("GPS",))])
def test_spp_within_10_m_of_the_header_position(shared_data, files, systems):
    obs = read_obs(shared_data / files[0])
    res, corr = spp(obs, read_nav(shared_data / files[1]), systems)
    err = np.linalg.norm(ecef_to_enu(res.pos_ecef_m, obs.approx_pos_ecef_m), axis=-1)
    assert res.available.all() and not corr.notes
    print(f"{files[0][:4]} {'+'.join(systems)}: worst 3D error {err.max():.2f} m, "
          f"RMS {np.sqrt(np.mean(err**2)):.2f} m")
    assert err.max() < 10.0


def test_corrections_are_needed_for_the_accuracy(esbc):
    from raimcore.sky.spp import solve

    obs = read_obs(esbc[0])
    _, corr = spp(obs, read_nav(esbc[1]), ("GPS",))
    bare = corr.__class__(**{**corr.__dict__, "iono_m": 0 * corr.iono_m,
                             "tropo_m": 0 * corr.tropo_m})
    err = np.linalg.norm(ecef_to_enu(solve(bare).pos_ecef_m, obs.approx_pos_ecef_m), axis=-1)
    assert err.max() > 10.0


@pytest.mark.parametrize("which", ["esbc", "slac"])
def test_parity_false_alarm_rate_on_fault_free_real_data(request, which):
    obs, nav = request.getfixturevalue(which)
    r = run_scenario(recording_scenario(obs, nav))
    t = r.table
    nominal = t["status"] != "unavailable"
    k, n = int(t["alarm"][nominal].sum()), int(nominal.sum())
    print(f"{which}: parity false alarms {k}/{n} at p_fa {r.scenario.p_fa:g}, sigma 1 m")
    assert n == len(t)
    # No more alarms than the test's p_fa allows (one-sided binomial test at 1e-3).
    assert stats.binom.sf(k - 1, n, r.scenario.p_fa) > 1e-3
    err = np.hypot(t["hpe_before_m"], t["vpe_before_m"])
    assert np.nanmax(err) < 10.0


def test_a_50_m_step_on_a_real_satellite_is_detected_and_excluded(esbc):
    s = recording_scenario(*esbc, faults=[Fault("G05", "step", t0_s=600.0, t1_s=1800.0,
                                                bias_m=50.0)])
    t = run_scenario(s).table
    faulted = t["faulty_truth"] == "G05"
    assert faulted.sum() == 40
    assert t["alarm"][faulted].mean() >= 0.95
    assert np.mean(t["excluded"][faulted] == "G05") >= 0.95
    err = np.hypot(t["hpe_after_m"], t["vpe_after_m"])[faulted]
    assert np.nanmax(err) < 10.0


def test_several_faulty_satellites_and_every_algorithm_runs_on_real_data(slac):
    s = recording_scenario(*slac, duration_s=900.0, faults=[
        Fault("G13", "ramp", t0_s=300.0, rate_mps=1.0), Fault("G15", "step", t0_s=600.0,
                                                              bias_m=80.0)])
    for name in algorithms.names():
        r = run_scenario(s.replace(algorithm=name))
        t = r.table
        assert len(t) == 31
        assert set(t["faulty_truth"][t["t_s"] >= 600.0]) == {"G13+G15"}
        ok = (t["faulty_truth"] == "") & (t["status"] != "unavailable")
        assert np.nanmax(np.hypot(t["hpe_before_m"], t["vpe_before_m"])[ok]) < 10.0, name


def test_window_step_truth_and_round_trip(esbc):
    s = recording_scenario(*esbc, t_start_s=600.0, duration_s=1200.0, step_s=60.0,
                           systems=["BDS"], truth_ecef_m=[3582105.0, 532589.0, 5232754.0])
    assert from_dict(s.to_dict()) == s
    r = run_scenario(s)
    m = r.measurements
    assert m.t_s[0] == 0.0 and m.t_s[-1] == 1200.0 and len(m.t_s) == 21
    assert all(n.startswith("C") for n in m.sat_names)
    np.testing.assert_allclose(r.truth.pos_rx_ecef_m[0], s.truth_ecef_m)
    with pytest.raises(ValueError, match="select no epoch"):
        run_scenario(s.replace(t_start_s=1e5))


def test_satellite_without_ephemeris_left_out_with_a_note(esbc, tmp_path):
    lines = open(esbc[1]).read().splitlines()
    out, skip = [], 0
    for line in lines:
        if line.startswith("G05 "):
            skip = 8
        if skip:
            skip -= 1
            continue
        out.append(line)
    nav = tmp_path / "nav_without_g05.rnx"
    nav.write_text("\n".join(out) + "\n")
    r = run_scenario(recording_scenario(esbc[0], str(nav)))
    assert "G05" not in r.measurements.sat_names
    assert any("G05" in n and "left out" in n for n in r.measurements.notes)
    with pytest.raises(ValueError, match="G05"):
        run_scenario(recording_scenario(esbc[0], str(nav), faults=[Fault("G05", "step",
                                                                         bias_m=50.0)]))


def test_rinex_source_needs_files_and_bad_files_are_value_errors(tmp_path):
    with pytest.raises(ValueError, match="needs obs and nav"):
        load_scenario("default", source="rinex")
    with pytest.raises(ValueError, match="source must be one of"):
        load_scenario("default", source="csv")
    with pytest.raises(ValueError, match="does not exist"):
        run_scenario(load_scenario("default", source="rinex", obs=str(tmp_path / "a"),
                                   nav=str(tmp_path / "b")))


@pytest.mark.parametrize("algorithm", ["parity", "mss"])
def test_no_satellite_ever_used_gives_all_unavailable(algorithm):
    r = run_scenario("default", mask_deg=89.0, duration_s=10.0, algorithm=algorithm)
    assert set(r.table["status"]) == {"unavailable"}
    assert not r.table["alarm"].any()


def test_cli_done_when_ramp_detected_and_excluded(esbc, capsys):
    obs, nav = esbc
    assert main(["run", "--obs", obs, "--nav", nav, "--fault", "G05,ramp,2,600"]) == 0
    out = capsys.readouterr().out
    assert "first alarm: t = 630 s" in out
    assert "correct isolation rate over faulted epochs: 100.0%" in out
    assert "mean HPE on fault-free epochs: " in out
    assert main(["run", "--obs", obs]) == 2
    assert "--obs and --nav go together" in capsys.readouterr().err


def test_batched_spp_equals_a_per_epoch_loop(esbc):
    import dataclasses

    from raimcore.sky.spp import correct, solve

    obs, nav = read_obs(esbc[0]), read_nav(esbc[1])
    batched = solve(correct(obs, nav)).pos_ecef_m
    for e in (0, 77, 239):
        one = dataclasses.replace(obs, t_gps_s=obs.t_gps_s[e:e + 1],
                                  epoch_flag=obs.epoch_flag[e:e + 1],
                                  codes={k: v[e:e + 1] for k, v in obs.codes.items()})
        np.testing.assert_allclose(solve(correct(one, nav)).pos_ecef_m[0], batched[e],
                                   atol=1e-6)


@pytest.mark.slow
def test_real_errors_are_time_correlated_and_pf_llr_needs_that_in_its_threshold(esbc):
    """ESBC's real pseudorange errors (against the station position) are strongly
    correlated over 30 s. PF-LLR calibrated on white noise false-alarms at most armed
    epochs; calibrated with the measured correlation time it holds, and a slow ramp is
    still caught and isolated."""
    from raimcore.measure import error_statistics, measure
    from raimcore.sky.recording import recording_sky

    s = recording_scenario(*esbc, algorithm="pf-llr")
    data, truth = measure(recording_sky(s), s)
    fit = error_statistics(data, truth)
    print(f"ESBC errors: sigma {fit.sigma_m:.2f} m, rho {fit.rho:.2f} over {fit.dt_s:g} s, "
          f"corr {fit.corr_s:.0f} s")
    assert 0.2 < fit.sigma_m < 2.0 and fit.rho > 0.5 and fit.dt_s == 30.0
    assert any(n.startswith("measured pseudorange errors") for n in data.notes)
    white = run_scenario(s)
    corr = run_scenario(s.replace(noise_corr_s=round(fit.corr_s)))
    assert corr.table["threshold"][-1] > white.table["threshold"][-1]
    assert white.summary["false_alarm_rate"] > 0.2
    assert corr.summary["false_alarm_rate"] <= 0.05
    ramp = run_scenario(s.replace(noise_corr_s=round(fit.corr_s)).with_faults(
        Fault("G05", "ramp", t0_s=3600.0, rate_mps=0.5)))
    assert ramp.summary["first_alarm_t_s"] <= 3600.0 + 120.0
    assert ramp.summary["correct_isolation_rate"] >= 0.9


def test_measured_error_note_is_computed_before_any_fault(esbc):
    """The recording's measured-error note describes its real errors: an injected fault
    (here 500 m on G05 for the whole recording) does not change it."""
    s = recording_scenario(*esbc, duration_s=1800.0)
    clean = run_scenario(s).summary.notes
    faulted = run_scenario(s.with_faults(Fault("G05", "step", t0_s=0.0, bias_m=500.0)))
    note = [n for n in clean if n.startswith("measured pseudorange errors")]
    assert note and note[0] in faulted.summary.notes
