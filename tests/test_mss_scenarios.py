"""The solution-separation algorithm on the seed 001 scenarios (spec section 2, issue 4)."""

from __future__ import annotations

import numpy as np
import pytest

from raimcore import algorithms
from raimcore.geometry import ecef_to_enu
from raimcore.pipeline import run_scenario, simulate
from raimcore.scenario import load_scenario

PAPER_SATS = ("G04", "G08", "G10", "G13", "G14")  # seed 001 fault case


@pytest.fixture(scope="module")
def flight():
    return run_scenario("seed001-flight")


@pytest.fixture(scope="module")
def fault():
    return run_scenario("seed001-fault")


@pytest.fixture(scope="module")
def fault_rank():
    return run_scenario("seed001-fault", mss_ident_rule="rank")


def faulted(result):
    return result.table["faulty_truth"] != ""


def test_registered_with_option():
    spec = algorithms.get("mss")
    assert spec.defaults == {"mss_ident_rule": "unique"}
    assert spec.option_keys["mss_ident_rule"].choices == ("unique", "rank")
    with pytest.raises(ValueError, match="mss_ident_rule"):
        run_scenario("seed001-fault", duration_s=5, mss_ident_rule="best")


def test_paper_satellites_visible_through_the_fault_window():
    data, _ = simulate(load_scenario("seed001-flight"))
    window = (data.t_s >= 2000) & (data.t_s <= 3000)
    idx = [data.sat_names.index(s) for s in PAPER_SATS]
    assert np.all(data.used[np.ix_(window, idx)])
    assert np.degrees(data.el_rad[np.ix_(window, idx)]).min() > 7.5


def test_flight_vpl_with_baro_never_above_without(flight):
    t = flight.table
    assert np.all(t["status"] == "ok")
    vpl, vpl0 = t["vpl_m"].astype(float), t["vpl_nobaro_m"].astype(float)
    hpl, hpl0 = t["hpl_m"].astype(float), t["hpl_nobaro_m"].astype(float)
    assert np.all(np.isfinite(vpl)) and np.all(np.isfinite(vpl0))
    assert np.all(vpl < vpl0)  # spec section 2: VPL with baro <= without, at every epoch
    share_hpl = np.mean(hpl < hpl0)
    print(f"\nseed001-flight: baro lowers VPL at {np.mean(vpl < vpl0):.1%} of epochs "
          f"(mean {np.mean(vpl0 - vpl):.0f} m), HPL at {share_hpl:.1%} "
          f"(largest HPL increase {np.max(hpl - hpl0):.2f} m)")
    # HPL need not improve everywhere (a separation covariance can grow when a measurement
    # is added); here it improves mostly and never gets more than 1% worse.
    assert share_hpl > 0.5
    assert np.all(hpl <= 1.01 * hpl0)
    assert flight.summary["baro_vpl_not_higher_share"] == 1.0
    assert not t["alarm"].any()  # p_fa 1e-5 over 3600 epochs
    assert np.all(t["available"])


def test_flight_pl_families_share_slopes(flight):
    """Classic slope PLs and MSS PLs without baro: same slopes, different margins."""
    t = flight.table
    ratio = t["hpl_nobaro_m"].astype(float) / t["hpl_classic_m"].astype(float)
    assert np.all((ratio > 0.8) & (ratio < 1.5))
    assert np.all(t["vpl_classic_m"].astype(float) > t["vpl_m"].astype(float))


def test_fault_classic_raim_detects_but_cannot_identify(fault):
    t, f = fault.table, faulted(fault)
    assert f.sum() == 1001 and np.all(t["n_sat"][f] == 5)
    assert np.mean(t["classic_alarm"][f]) > 0.99
    assert np.all(t["classic_status"][f] == "detect-only")
    assert np.all(t["nobaro_status"][f] == "detect-only")  # MSS without baro too
    parity = run_scenario("seed001-fault", algorithm="parity", p_fa=1e-5)
    assert np.mean(parity.table["alarm"][f]) > 0.99
    assert np.all(parity.table["status"][f] == "detect-only")
    assert np.all(parity.table["excluded"][f] == "")


@pytest.mark.parametrize("rule", ["unique", "rank"])
def test_fault_mss_with_baro_identifies_g10(rule, fault, fault_rank):
    res = fault if rule == "unique" else fault_rank
    t, f = res.table, faulted(res)
    share = np.mean(t["excluded"][f] == "G10")
    ident = {s: int(np.sum(t["ident_status"][f] == s)) for s in np.unique(t["ident_status"][f])}
    print(f"\nseed001-fault, rule {rule}: G10 identified and excluded at {share:.1%} of the "
          f"{f.sum()} faulted epochs; ident status {ident}")
    assert share >= 0.95
    assert np.all(np.isin(t["excluded"][f], ["G10", ""]))  # never a wrong exclusion
    assert np.all(t["excluded"][~f] == "")
    assert np.all(t["hpe_after_m"][f] < 250.0)


def test_fault_errors_against_paper_table_1(fault):
    """Error statistics in the fault window, beside the paper's Table 1 (see README)."""
    classic = run_scenario("seed001-fault", baro=False)
    f = faulted(fault)
    truth = fault.truth.pos_rx_ecef_m[f]
    err_baro = ecef_to_enu(fault.output.pos_after_ecef_m[f], truth)
    err_classic = ecef_to_enu(classic.output.pos_before_ecef_m[f], truth)
    std_baro, std_classic = err_baro.std(axis=0), err_classic.std(axis=0)
    rms_baro = np.sqrt(np.mean(err_baro**2, axis=0))
    rms_classic = np.sqrt(np.mean(err_classic**2, axis=0))
    print("\nseed001-fault error std E/N/U (m): with baro + exclusion "
          f"{np.round(std_baro, 1)}, classic {np.round(std_classic, 1)}, ratio "
          f"{np.round(100 * std_baro / std_classic, 1)} %; RMS ratio "
          f"{np.round(100 * rms_baro / rms_classic, 1)} % "
          "(paper: 21.49, 27.45, 73.83 m; 30.3, 68.5, 0.12 %)")
    # After excluding G10 the errors are noise-like (std near their RMS, no bias left) ...
    assert np.all(np.abs(err_baro.mean(axis=0)) < 0.3 * std_baro)
    assert np.all(std_baro < 80.0)
    # ... while classic RAIM keeps the 1000 m fault in its solution.
    assert np.all(rms_classic > 4 * rms_baro)


def test_baro_off_uses_the_same_pl_for_both_columns():
    res = run_scenario("seed001-flight", baro=False, duration_s=20)
    t = res.table
    np.testing.assert_array_equal(t["hpl_m"], t["hpl_nobaro_m"])
    assert not t["baro_used"].any()
    assert "baro_vpl_lower_share" not in res.summary


def test_parity_reports_classic_pls(fault):
    res = run_scenario("seed001-flight", algorithm="parity", baro=False, duration_s=20)
    np.testing.assert_allclose(res.table["hpl_m"], fault.table["hpl_classic_m"][:21])
    np.testing.assert_allclose(res.table["vpl_m"], fault.table["vpl_classic_m"][:21])


@pytest.mark.slow
@pytest.mark.parametrize("sat", ["G04", "G08", "G13", "G14"])
def test_fault_on_other_paper_satellites_both_rules(sat):
    """The same window with the fault moved: identification depends on the geometry.

    The unique rule never excludes a wrong satellite (it abstains: "ambiguous"); the
    ranking extension always names a candidate, right at least as often as the unique rule.
    """
    fault = {"sat": sat, "kind": "step", "bias_m": 1000.0, "t0_s": 2000.0, "t1_s": 3001.0}
    shares = {}
    for rule in ("unique", "rank"):
        res = run_scenario("seed001-fault", faults=[fault], mss_ident_rule=rule)
        t, f = res.table, faulted(res)
        assert np.mean(t["alarm"][f]) > 0.99
        shares[rule] = np.mean(t["excluded"][f] == sat)
        if rule == "unique":
            assert np.all(np.isin(t["excluded"][f], [sat, ""]))
    print(f"\nseed001-fault with the fault on {sat}: identified at {shares['unique']:.1%} "
          f"(unique rule), {shares['rank']:.1%} (ranking)")
    assert shares["rank"] >= shares["unique"]


def test_batched_run_equals_single_epoch_runs(fault):
    """The algorithm compacts the used satellites per batch: per-epoch runs must agree."""
    data, spec = fault.measurements, algorithms.get("mss")
    options = spec.resolve_options({"mss_ident_rule": "unique"})
    for e in (0, 1999, 2000, 2500, 2875, 3001):
        one = data.take_epochs([e])
        assert one.n_epochs == 1 and one.baro_alt_m.shape == (1,)
        out = spec.run(one, options)
        for key in ("hpl_m", "vpl_m", "hpl_classic_m", "vpl_nobaro_m"):
            np.testing.assert_allclose(out.columns[key][0], fault.output.columns[key][e],
                                       rtol=1e-9)
        # A ratio of a separation (a difference of two solutions) to its threshold: the
        # batched and one-epoch products round differently, ~1e-11 of it.
        np.testing.assert_allclose(out.per_sat["sep_ratio"][0], fault.output.per_sat[
            "sep_ratio"][e], rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(out.excluded[0], fault.output.excluded[e])
        np.testing.assert_allclose(out.pos_after_ecef_m[0], fault.output.pos_after_ecef_m[e],
                                   atol=1e-6)
        assert out.columns["ident_status"][0] == fault.output.columns["ident_status"][e]


@pytest.mark.parametrize("rule", ["unique", "rank"])
def test_two_faults_on_the_flight_exclude_the_pair(rule):
    """Two simultaneous 1000 m faults with 7 satellites + baro: level one says
    multiple-fault, level two names and excludes the pair."""
    faults = [{"sat": sat, "kind": "step", "bias_m": 1000.0, "t0_s": 50.0, "t1_s": 250.0}
              for sat in ("G08", "G15")]
    res = run_scenario("seed001-flight", duration_s=299, faults=faults, mss_ident_rule=rule)
    t, f = res.table, faulted(res)
    assert np.mean(t["ident_status"][f] == "multiple-fault") > 0.95
    pair = t[f"ident_pair_{rule}"][f]
    share = np.mean(t["excluded"][f] == "G08+G15")
    print(f"\nseed001-flight, G08 + G15 faulted, rule {rule}: pair excluded at {share:.1%}")
    assert share > (0.8 if rule == "unique" else 0.95)
    assert np.all(np.isin(pair, ["G08+G15", ""]))  # never a wrong pair named
    ok = t["excluded"][f] == "G08+G15"
    assert np.all(t["hpe_after_m"][f][ok] < 250.0)


@pytest.mark.parametrize("rule", ["unique", "rank"])
def test_fast_kernels_agree_with_reference_on_the_fault_scenario(rule, fault, monkeypatch):
    """Issue 17: the algorithm with the reference kernels swapped in makes exactly the same
    decisions, with PLs to 1e-6 relative and positions to 1 um, on the paper's fault case
    (with baro, 5 satellites in the window, classic RAIM beside it)."""
    from raimcore.algorithms import mss as kernel

    data, spec = fault.measurements, algorithms.get("mss")
    options = spec.resolve_options({"mss_ident_rule": rule})
    fast = spec.run(data, options)
    monkeypatch.setattr(kernel, "mss", kernel.mss_reference)
    monkeypatch.setattr(kernel, "classic_raim", kernel.classic_raim_reference)
    ref = spec.run(data, options)
    for name in ("alarm", "status", "excluded", "isolated"):
        np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name), err_msg=name)
    for name in ("pos_before_ecef_m", "pos_after_ecef_m"):
        np.testing.assert_allclose(getattr(fast, name), getattr(ref, name), atol=1e-6,
                                   err_msg=name)
    for key, col in fast.columns.items():
        if np.asarray(col).dtype.kind == "f":
            np.testing.assert_allclose(col, ref.columns[key], rtol=1e-6, equal_nan=True,
                                       err_msg=key)
        else:
            np.testing.assert_array_equal(col, ref.columns[key], err_msg=key)
    for key, val in fast.per_sat.items():
        np.testing.assert_allclose(val, ref.per_sat[key], rtol=1e-6, equal_nan=True,
                                   err_msg=key)
    assert np.any(ref.excluded) and np.any(ref.columns["classic_alarm"])  # the case has power
