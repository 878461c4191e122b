"""The registered ``araim`` algorithm (issue 16, item 2): the ISM and user-model keys, the
``araim`` error model that draws the simulated noise, the adapter's columns, LPV-200
availability, the fault-free budget (statistically), a Galileo constellation fault detected
and excluded, and the command line."""

import json
import math

import numpy as np
import pytest
from scipy import stats

from raimcore import algorithms
from raimcore import araim as kernel
from raimcore.cli import main
from raimcore.measure.error_models import (
    ERROR_MODELS,
    GAL_USER_SIGMA_M,
    MAAST_ISM,
    araim_sigmas,
    araim_user_sigma,
    resolve_model,
    tropo_sigma,
)
from raimcore.pipeline import run_scenario, simulate
from raimcore.scenario import from_dict, load_scenario
from raimcore.schema import SchemaError

# Load the registry in its own order (_MODULES) before importing the adapter module: a
# direct import first would register araim first and reorder the README's key table.
algorithms.names()
from raimcore.algorithms.araim import AraimConstants, parse_constants  # noqa: E402

one_um = 1e-6
one_cm = 1e-2
DEG = math.radians
GPS_GAL = ["GPS", "GAL"]


def _araim(**kw):
    """A GPS + Galileo static user under ``araim`` (the default scenario's place)."""
    base = {"algorithm": "araim", "systems": GPS_GAL, "duration_s": 299.0, "seed": 5}
    return from_dict({**base, **kw})


# -- the ISM key -------------------------------------------------------------------------

def test_default_ism_is_maasts_example_and_agrees_with_the_kernel_table():
    """ARAIM.md section 10 (MAAST main_maast_araim.m): GPS / GAL sigma_URA 2.4 / 6 m,
    sigma_URE 2.4 / 4 m, b 0, P_sat 1e-5 / 3e-5, P_const 1e-8 / 2e-4; the kernel package
    keeps the same example (raimcore.araim.MAAST_EXAMPLE_ISM): both must agree."""
    s = from_dict({})
    assert s.ism == MAAST_ISM and str(s.ism) == "maast"
    for system, ref in kernel.MAAST_EXAMPLE_ISM.items():
        entry = MAAST_ISM[system]
        for field, value in ref.items():
            assert getattr(entry, field) == value, (system, field)
        assert entry.b_cont_m == 0.0


def test_ism_table_overrides_the_example_and_round_trips():
    s = from_dict({"ism": {"GAL": {"sigma_ura_m": 4.0, "p_const": 1e-4}}})
    assert s.ism["GAL"].sigma_ura_m == 4.0 and s.ism["GAL"].p_const == 1e-4
    assert s.ism["GAL"].sigma_ure_m == 4.0 and s.ism["GPS"] == MAAST_ISM["GPS"]  # kept
    assert str(s.ism) == "{GAL = {sigma_ura_m = 4.0, p_const = 0.0001}}"
    assert from_dict(s.to_dict()) == s
    assert load_scenario("default", ism="maast").ism == MAAST_ISM


@pytest.mark.parametrize("value, message", [
    ({"GAL": {"sigma_ura_m": -1.0}}, r"^ism\.GAL\.sigma_ura_m must be in \[0, 1000\] m, got -1"),
    ({"GAL": {"p_sat": 0.5}}, r"^ism\.GAL\.p_sat must be in \[0, 0\.001\], got 0\.5"),
    ({"GPS": {"p_const": True}}, r"^ism\.GPS\.p_const must be a number"),
    ({"GPS": {"b_nom_m": math.nan}}, r"^ism\.GPS\.b_nom_m must be a finite number"),
    ({"Galileo": {}}, r"^ism: unknown system 'Galileo'.*did you mean 'GAL'"),
    ({"GAL": {"sigma_ura": 1.0}}, r"^ism\.GAL: unknown field 'sigma_ura'.*did you mean "
                                    r"'sigma_ura_m'"),
    ({"GAL": 4.0}, r"^ism\.GAL must be a table"),
    ("maastt", r"^ism must be \"maast\" or a table"),
    (3, r"^ism must be \"maast\" or a table"),
])
def test_ism_refuses_bad_values_in_one_line(value, message):
    with pytest.raises(SchemaError, match=message) as exc:
        from_dict({"ism": value})
    assert "\n" not in str(exc.value)


def test_user_model_key_refuses_other_models():
    assert from_dict({"user_model": "ed259a"}).user_model == "ed259a"
    with pytest.raises(SchemaError, match="user_model must be one of add, ed259a; got 'mops'"):
        from_dict({"user_model": "mops"})


# -- the nominal error model (ARAIM.md section 2) ------------------------------------------

def test_user_models_hand_values():
    # add, GPS at 90 deg: 2.588331 x sqrt(0.130065^2 + 0.150001^2) = 0.513882
    # add, GAL: the table's ends (0.4529 at 5 deg, 0.2277 at 90) and 12.5 deg halfway
    #   between 0.3553 and 0.3063 = 0.3308
    # ed259a at 5 deg: sqrt(0.16 + 0.619869^2 + 0.157860^2) = 0.754425; 90 deg 0.525889
    np.testing.assert_allclose(araim_user_sigma(DEG(90.0), "GPS"), 0.513882, atol=one_um)
    np.testing.assert_allclose(araim_user_sigma(np.radians([5.0, 12.5, 90.0]), "GAL"),
                               [0.4529, 0.3308, 0.2277], atol=one_um)
    np.testing.assert_allclose(araim_user_sigma(np.radians([5.0, 90.0]), "BDS", "ed259a"),
                               [0.754425, 0.525889], atol=one_um)
    assert len(GAL_USER_SIGMA_M) == 18  # 5, 10, ..., 90 deg


@pytest.mark.parametrize("system", ["GPS", "GAL"])
def test_user_models_agree_with_the_kernel_package(system):
    """One formula, two homes (raimcore.araim.error_model and the measure stage): they
    must agree wherever both are defined (elevations above the 2-degree floor)."""
    el = np.radians(np.linspace(5.0, 90.0, 35))
    np.testing.assert_allclose(araim_user_sigma(el, system),
                               kernel.sigma_user_add_m(el, system), atol=one_um)
    np.testing.assert_allclose(araim_user_sigma(el, system, "ed259a"),
                               kernel.sigma_user_ed259a_m(el), atol=one_um)
    np.testing.assert_allclose(tropo_sigma(el), kernel.sigma_tropo_m(el), atol=one_um)


def test_integrity_and_accuracy_sigmas_hand_values():
    # zenith, add: GPS sqrt(2.4^2 + 0.12^2 + 0.513882^2) = 2.457331 (int = acc: URE = URA);
    # GAL int sqrt(36 + 0.0144 + 0.2277^2) = 6.005518, acc with URE 4 m: 4.008272
    el = np.full((2, 2), DEG(90.0))
    s_int, s_acc = araim_sigmas(el, ("GPS", "GAL"), [0, 1])
    np.testing.assert_allclose(s_int, [[2.457331, 6.005518]] * 2, atol=one_um)
    np.testing.assert_allclose(s_acc, [[2.457331, 4.008272]] * 2, atol=one_um)


def test_auto_is_araim_under_the_araim_algorithm():
    assert "araim" in ERROR_MODELS
    assert resolve_model("auto", False, "araim") == "araim"
    assert resolve_model("auto", True, "araim") == "araim"
    assert resolve_model("auto", False, "parity") == "uniform"
    data, _ = simulate(_araim(duration_s=10.0))
    assert data.error_model == "araim" and data.ism == MAAST_ISM
    # Measurements.sigma_m is the accuracy model (URE), what the noise is drawn with
    _, acc = araim_sigmas(data.el_rad, data.systems, data.sys_idx)
    np.testing.assert_allclose(data.sigma_m[data.used], acc[data.used])
    assert any(n.startswith("error model araim") for n in data.notes)


def test_the_ism_and_user_model_reach_the_noise_draw():
    """sigma_URE of Galileo doubled: the Galileo sigmas grow, GPS's stay."""
    d0, _ = simulate(_araim(duration_s=5.0))
    d1, _ = simulate(_araim(duration_s=5.0, ism={"GAL": {"sigma_ure_m": 8.0}},
                            user_model="ed259a"))
    gal = (np.asarray(d0.sys_idx) == d0.systems.index("GAL"))[None, :] & d0.used
    gps = ~gal & d0.used
    assert np.all(d1.sigma_m[gal] > 1.8 * d0.sigma_m[gal])
    assert np.all(np.abs(d1.sigma_m[gps] - d0.sigma_m[gps]) < 0.5)  # only the user model
    assert d1.ism["GAL"].sigma_ure_m == 8.0 and d1.user_model == "ed259a"


# -- the algorithm ------------------------------------------------------------------------

def test_options_are_declared_and_listed_by_raim_keys(capsys):
    spec = algorithms.get("araim")
    assert set(spec.option_keys) == {"araim_rules", "araim_fde", "emt_max_m",
                                     "sigma_acc_max_m", "t_exp_s", "araim_constants"}
    assert spec.defaults["emt_max_m"] == 15.0 and spec.defaults["sigma_acc_max_m"] == 1.87
    assert main(["keys", "araim"]) == 0
    out = capsys.readouterr().out
    for name in spec.option_keys:
        assert f"  {name}" in out
    assert main(["keys", "scenario"]) == 0
    out = capsys.readouterr().out
    assert '  ism = maast  ("maast" or a table of systems)' in out
    assert "  user_model = \"add\"  (add | ed259a)" in out


def test_constants_option_parses_checks_and_prints_toml():
    c = parse_constants("araim_constants", {"phmi_vert": 1e-9, "n_es_int": 25})
    assert c == AraimConstants((("n_es_int", 25.0), ("phmi_vert", 1e-9)))
    assert parse_constants("araim_constants", str(c)) == c  # a text box's round trip
    odd = parse_constants("araim_constants", {"phmi_vert": 1.2345678912345e-9,
                                              "pl_max_iter": 10, "max_pmd": True})
    assert parse_constants("araim_constants", str(odd)) == odd
    assert str(AraimConstants()) == "{}" and parse_constants("x", "") == AraimConstants()
    with pytest.raises(SchemaError, match=r"araim_constants\.phmi_vert must be in \(0, 1\)"):
        parse_constants("araim_constants", {"phmi_vert": 2.0})
    with pytest.raises(SchemaError, match="unknown constant 'phmi_v'.*did you mean"):
        parse_constants("araim_constants", {"phmi_v": 1e-9})
    # a constant of the other rule set is refused when the run starts, before the kernel
    with pytest.raises(SchemaError, match="p_thres is a constant of add-v4.2"):
        run_scenario(_araim(duration_s=2.0, araim_rules="blanch-2012",
                            araim_constants={"p_thres": 1e-7}))


def test_columns_pls_emt_and_lpv200_availability():
    r = run_scenario(_araim(hal_m=40.0, val_m=35.0))
    t = r.table
    for col in ("hpl_m", "vpl_m", "emt_m", "sigma_acc_m", "n_modes", "available",
                "p_not_monitored", "k_fa_v", "alarm_mode", "excluded_mode"):
        assert col in t, col
    ok = t["status"] != "unavailable"
    assert ok.all()
    hpl, vpl = t["hpl_m"].astype(float), t["vpl_m"].astype(float)
    emt, sacc = t["emt_m"].astype(float), t["sigma_acc_m"].astype(float)
    assert np.all(np.isfinite(hpl) & np.isfinite(vpl) & (vpl > sacc) & (emt > 0))
    # MAAST's example ISM is H-ARAIM grade: the vertical LPV-200 criteria fail (section 11)
    assert np.all(vpl > 35.0) and np.all(sacc > 1.87) and not t["available"].any()
    # Availability is exactly the four criteria with the scenario's limits and the options
    r2 = run_scenario(_araim(hal_m=1e3, val_m=1e3, sigma_acc_max_m=10.0, emt_max_m=50.0))
    t2 = r2.table
    want = ((t2["vpl_m"] <= 1e3) & (t2["hpl_m"] <= 1e3) & (t2["emt_m"] <= 50.0)
            & (t2["sigma_acc_m"] <= 10.0))
    np.testing.assert_array_equal(t2["available"], want)
    assert t2["available"].all()
    # n_modes: every single satellite plus the Galileo constellation (GPS's P_const 1e-8
    # is below PHMI, ARAIM.md section 4 step 5)
    np.testing.assert_array_equal(t["n_modes"], t["n_sat"] + 1)


def test_a_better_ism_makes_lpv200_available():
    """An ISM of the LPV-200 studies' grade (sigma_URA 1 m, sigma_URE 2/3 m: the
    0.66 x URA option commented in main_maast_araim.m) meets LPV-200 at this place and
    time; the PLs shrink with the sigmas."""
    good = {s: {"sigma_ura_m": 1.0, "sigma_ure_m": 0.66} for s in GPS_GAL}
    base = run_scenario(_araim(hal_m=40.0, val_m=35.0)).table
    t = run_scenario(_araim(hal_m=40.0, val_m=35.0, ism=good)).table
    assert np.all(t["vpl_m"] < base["vpl_m"])
    assert t["available"].all()


def test_fault_free_run_stays_inside_its_protection_levels_as_the_budget_says():
    """The noise is drawn from the accuracy model (URE); PLs bound it with URA. Over 2,000
    fault-free epochs VPE > VPL and HPE > HPL may happen no more often than PHMI allows
    (one-sided binomial test), alarms no more often than P_FA; the vertical errors have
    the kernel's sigma_acc as their scale (so the noise is what the model says). Detection
    only (araim_fde false): its PLs and sigma_acc are those of the all-in-view solution
    (with exclusion they are the worst over the exclusion candidates, ARAIM.md section 9:
    larger)."""
    s = _araim(duration_s=19990.0, step_s=10.0, seed=21, faults=[], araim_fde=False)
    t = run_scenario(s).table
    ok = t["status"] != "unavailable"
    n = int(ok.sum())
    assert n == 2000
    prm = kernel.defaults()
    for err, pl, budget in (("vpe_before_m", "vpl_m", prm["phmi_vert"]),
                            ("hpe_before_m", "hpl_m", prm["phmi_hor"])):
        k = int(np.sum(t[err][ok] > t[pl][ok]))
        assert stats.binomtest(k, n, budget, alternative="greater").pvalue > 0.01, (err, k)
    k_fa = int(t["alarm"][ok].sum())
    p_fa = prm["p_fa_vert"] + prm["p_fa_hor"]
    assert stats.binomtest(k_fa, n, p_fa, alternative="greater").pvalue > 0.01
    z2 = (t["vpe_before_m"][ok] / t["sigma_acc_m"][ok].astype(float)) ** 2
    assert np.mean(z2) == pytest.approx(1.0, abs=4 * math.sqrt(2.0 / n))


def test_exclusion_pls_are_the_worst_over_the_candidates():
    """ARAIM.md section 9: with araim_fde the PLs, EMT and sigma_acc are the largest over
    the all-in-view and every exclusion candidate, so never below those without."""
    fd = run_scenario(_araim(duration_s=30.0, araim_fde=False)).table
    fde = run_scenario(_araim(duration_s=30.0)).table
    for col in ("hpl_m", "vpl_m", "emt_m", "sigma_acc_m"):
        assert np.all(fde[col] >= fd[col] - one_cm), col
    assert np.all(fde["vpl_m"] > fd["vpl_m"])


def test_the_budget_check_fails_when_the_noise_exceeds_the_model():
    """The same check has power: noise drawn at 30 m (error_model uniform) against the ISM
    model puts VPE above VPL far more often than PHMI allows."""
    s = _araim(duration_s=1990.0, step_s=10.0, seed=21, error_model="uniform", sigma_m=30.0)
    t = run_scenario(s).table
    ok = t["status"] != "unavailable"
    k, n = int(np.sum(t["vpe_before_m"][ok] > t["vpl_m"][ok])), int(ok.sum())
    assert stats.binomtest(k, n, kernel.defaults()["phmi_vert"],
                           alternative="greater").pvalue < 1e-6


@pytest.mark.parametrize("fde", [True, False])
def test_galileo_constellation_fault_is_detected_and_the_constellation_excluded(fde):
    """A 50 m step on every Galileo satellite (bias x sin(el), raimcore.measure.faults) from
    t = 100 s: the Galileo constellation mode explains the alarm; with exclusion Galileo is
    excluded and the vertical error returns to the fault-free level. (20 m moves this
    position by well under a metre: Galileo's URA of 6 m weighs it down; it is neither
    detected nor harmful, VPE stays far below VPL.)"""
    s = _araim(duration_s=399.0, araim_fde=fde, faults=[
        {"sat": "GAL", "kind": "step", "bias_m": 50.0, "t0_s": 100.0}])
    r = run_scenario(s)
    t = r.table
    f = t["t_s"] >= 100.0
    assert not t["alarm"][~f].any()
    assert np.mean(t["alarm"][f]) > 0.95
    assert np.all(t["alarm_mode"][f & t["alarm"]] == "GAL")
    assert np.all(t["vpe_before_m"] <= t["vpl_m"])
    gal = np.array([n.startswith("E") for n in r.measurements.sat_names])
    exc = r.output.excluded
    if fde:
        hit = f & t["alarm"]
        assert np.all(t["excluded_mode"][hit] == "GAL")
        np.testing.assert_array_equal(exc[hit], r.measurements.used[hit] & gal[None, :])
        assert r.summary.correct_isolation.value > 0.95
        assert np.mean(t["vpe_after_m"][hit]) < 0.5 * np.mean(t["vpe_before_m"][hit])
        assert np.mean(t["vpe_after_m"][hit]) < 2.0 * np.mean(t["vpe_before_m"][~f])
    else:
        assert not exc.any() and np.all(t["excluded_mode"] == "")
        np.testing.assert_array_equal(t["vpe_after_m"], t["vpe_before_m"])


def test_a_satellite_fault_is_named_and_excluded():
    s = _araim(duration_s=199.0, faults=[{"sat": "G10", "kind": "step", "bias_m": 80.0,
                                          "t0_s": 50.0}])
    t = run_scenario(s).table
    hit = (t["t_s"] >= 50.0) & t["alarm"]
    assert hit.sum() > 0.9 * 150
    assert np.all(t["alarm_mode"][hit] == "G10") and np.all(t["excluded"][hit] == "G10")
    assert np.all(t["isolated"][hit] == "G10")


def test_too_few_satellites_is_unavailable_with_infinite_pls():
    s = _araim(duration_s=20.0, restrict=[{"sats": ["G03", "G04", "G07"], "t0_s": 5.0,
                                           "t1_s": 10.0}])
    t = run_scenario(s).table
    w = (t["t_s"] >= 5.0) & (t["t_s"] < 10.0)
    assert np.all(t["status"][w] == "unavailable") and not t["available"][w].any()
    assert np.all(np.isinf(t["vpl_m"][w].astype(float)))
    assert np.all(t["status"][~w] != "unavailable")


def test_raim_run_prints_pls_and_availability(capsys, tmp_path):
    out_csv = tmp_path / "araim.csv"
    assert main(["run", "default", "--algorithm", "araim", "--set", 'systems=["GPS","GAL"]',
                 "--set", "duration_s=60", "--out", str(out_csv)]) == 0
    out = capsys.readouterr().out
    assert "algorithm araim" in out and "GPS+GAL" in out
    assert "mean HPL" in out and "mean VPL" in out and "EMT median" in out
    assert "available by every LPV-200 criterion (VPL, HPL, EMT, sigma_acc)" in out
    assert "available (HPL <= HAL" not in out  # ARAIM's availability is all four criteria
    assert "error model araim" in out
    header = out_csv.read_text().splitlines()[0].split(",")
    for col in ("hpl_m", "vpl_m", "emt_m", "sigma_acc_m", "available", "n_modes"):
        assert col in header
    assert main(["run", "default", "--algorithm", "araim", "--set", 'systems=["GPS","GAL"]',
                 "--set", "duration_s=10", "--quiet"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["vpl_mean_m"] > 0 and summary["pl_availability"] is not None


def test_the_araim_scenario_report_holds():
    """The claims of raimcore/scenarios/araim.md (``raim show araim``)."""
    r = run_scenario("araim")
    t, sm = r.table, r.summary
    assert sm.detection.value >= 0.99 and sm.correct_isolation.value >= 0.99
    f = t["t_s"] >= 300.0
    assert np.all(t["alarm_mode"][f & t["alarm"]] == "GAL")
    assert sm.rmse_before_m > 1.5 * sm.rmse_after_m
    assert sm.false_alarm.k == 0 and sm.false_alarm_check == "within"
    assert 40.0 < sm.vpl_mean_m < 55.0 and sm.pl_availability.k == 0
    assert np.all(t["sigma_acc_m"] > 1.87)
    fd = run_scenario("araim", araim_fde=False).summary
    assert 20.0 < fd.vpl_mean_m < 30.0
    good = {s: {"sigma_ura_m": 1.0, "sigma_ure_m": 0.66} for s in GPS_GAL}
    lpv = run_scenario("araim", ism=good, faults=[]).summary
    assert lpv.vpl_mean_m < 25.0 and lpv.pl_availability.value == 1.0


def test_all_mode_names_equal_the_per_mode_names():
    """The fault-mode panel's labels (every mode of every epoch, named in packed blocks)
    equal :func:`_mode_names` called mode by mode, on a run whose GAL constellation mode
    and satellite modes all appear."""
    from types import SimpleNamespace

    from raimcore.algorithms import araim as adapter

    rng = np.random.default_rng(3)
    n_sat, cons = 13, np.array([0] * 7 + [1] * 6)
    el = rng.uniform(DEG(8), DEG(80), (70, n_sat))
    az = rng.uniform(0, 2 * np.pi, (70, n_sat))
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    g = np.concatenate([-u, np.broadcast_to(np.eye(2)[cons], (70, n_sat, 2))], -1)
    g[rng.random((70, n_sat)) < 0.15] = np.nan
    s = np.full(n_sat, 1.5)
    res = kernel.mhss(g, s, s, np.zeros(n_sat), np.zeros(n_sat), np.full(n_sat, 1e-5),
                      np.array([1e-8, 2e-4]))
    data = SimpleNamespace(systems=("GPS", "GAL"), sys_idx=cons,
                           sat_names=tuple(f"S{i:02d}" for i in range(n_sat)))
    old_block = adapter._NAME_BLOCK
    try:
        adapter._NAME_BLOCK = 5  # several blocks, names shared across them
        got = adapter._all_mode_names(res.modes, data)
    finally:
        adapter._NAME_BLOCK = old_block
    n_ep, k_all = res.modes.p_inst.shape
    want = np.stack([adapter._mode_names(res.modes, np.full(n_ep, k), data)
                     for k in range(1, k_all)], axis=1)
    np.testing.assert_array_equal(got, want)
    assert "GAL" in set(want.ravel()) and "S03" in set(want.ravel())


def test_summary_sets_false_alarms_against_araims_budget_not_the_scenario_p_fa(capsys):
    """ARAIM's separation tests share (P_FA_VERT + P_FA_HOR) / N_es,cont per epoch: the
    summary checks the fault-free alarm share against that, the scenario's p_fa (which
    ARAIM does not use) is said to have no effect, and araim_constants move the budget."""
    res = run_scenario(_araim(p_fa=1e-2, faults=[]))
    prm = kernel.defaults()
    budget = prm["p_fa_vert"] + prm["p_fa_hor"]
    assert res.output.p_fa == pytest.approx(budget)
    assert res.summary.p_fa == pytest.approx(budget)
    assert any("p_fa 0.01 has no effect on araim" in n for n in res.summary.notes)
    res2 = run_scenario(_araim(p_fa=1e-2, faults=[],
                               araim_constants={"p_fa_vert": 1e-4, "n_es_cont": 2.0}))
    assert res2.summary.p_fa == pytest.approx((1e-4 + prm["p_fa_hor"]) / 2.0)
    parity = run_scenario(_araim(p_fa=1e-2, faults=[], algorithm="parity"))
    assert parity.output.p_fa is None and parity.summary.p_fa == 1e-2
    assert not any("no effect on" in n for n in parity.summary.notes)
