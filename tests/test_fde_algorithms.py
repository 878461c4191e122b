"""raimcore.fde with the registry's other snapshot algorithms: mss, gf, rs, qv, araim.

One conformance suite over the five: each must make the scenario engine's decisions
(every status, alarm, exclusion and named satellite, positions to a micrometre) on the
arrays of built-in scenarios, find and remove an injected fault, call too few satellites
"unavailable" with NaN, cap its exclusion at ``max_exclusions`` and refuse, in one line,
an option that is not its own. Parity's own suite is ``tests/test_fde.py``.
"""

import dataclasses

import numpy as np
import pytest
from test_fde import sky  # the random sky of the parity tests

import raimcore
from raimcore.algorithms import get as get_algorithm
from raimcore.measure.error_models import MAAST_ISM, araim_sigmas
from raimcore.pipeline import run_algorithm, run_scenario
from raimcore.scenario import load_scenario
from raimcore.snapshot import FDE_ALGORITHM_OUTPUTS

ONE_UM = 1e-6  # positions agree with the engine's to a micrometre
ALGORITHMS = ("mss", "gf", "rs", "qv", "araim")
ENGINE_NAME = {"sigma_acc_v_m": "sigma_acc_m"}  # araim's engine column of that output


def engine_call(data, algorithm):
    """The arguments of ``raimcore.fde`` that reproduce the engine's run on ``data``:
    (pos_sv_ecef_m, pr_m, sigma_m) and keywords. araim: the ISM's sigmas and values as
    arrays (the engine derives them from the elevations); rs: the scenario's seed; mss:
    its p_md."""
    pr = np.where(data.used, data.pr_m, np.nan)
    kw = {"sys_idx": data.sys_idx, "max_exclusions": data.n_sats}
    if algorithm == "araim":
        ism = MAAST_ISM if data.ism is None else data.ism
        sig_int, sig_acc = araim_sigmas(data.el_rad, data.systems, data.sys_idx, ism,
                                        data.user_model)
        per_sat = ism.per_sat(data.systems, data.sys_idx)
        kw.update(sigma_acc_m=np.where(data.used, sig_acc, np.nan), b_nom_m=per_sat["b_nom_m"],
                  b_cont_m=per_sat["b_cont_m"], p_sat=per_sat["p_sat"],
                  p_const=ism.per_system(data.systems)["p_const"])
        sigma = np.where(data.used, sig_int, np.nan)
    else:
        kw["p_fa"] = data.p_fa
        sigma = np.where(data.used, data.sigma_m, np.nan)
        if algorithm == "rs":
            kw["seed"] = data.seed
        if algorithm == "mss":
            kw["p_md"] = data.p_md
    return (data.pos_sv_ecef_m, pr, sigma), kw


def assert_engine_decisions(out, r):
    """An FdeResult ``r`` makes the decisions of the engine's AlgorithmOutput ``out``."""
    np.testing.assert_array_equal(np.asarray(out.status, dtype=str), r.status)
    np.testing.assert_array_equal(out.alarm, r.alarm)
    np.testing.assert_array_equal(out.excluded, r.excluded)
    np.testing.assert_array_equal(np.where(out.alarm, out.isolated, -1), r.isolated)
    np.testing.assert_allclose(r.statistic, out.statistic, rtol=1e-12, atol=0)
    np.testing.assert_allclose(r.pos_before_ecef_m, out.pos_before_ecef_m, rtol=0, atol=ONE_UM)
    np.testing.assert_allclose(r.pos_ecef_m, out.pos_after_ecef_m, rtol=0, atol=ONE_UM)


# ---------------------------------------------------------------- agreement with the engine

@pytest.mark.parametrize("algorithm,scenario", [
    *((a, "default") for a in ALGORITHMS),
    *((a, "seed004-multi") for a in ("mss", "gf", "rs", "qv")),
    ("araim", "araim"),
])
def test_fde_makes_the_scenario_engines_decisions(algorithm, scenario):
    # baro = false: fde has no altimeter (only mss would use one).
    res = run_scenario(load_scenario(scenario, baro=False).replace(algorithm=algorithm))
    args, kw = engine_call(res.measurements, algorithm)
    outs = tuple(FDE_ALGORITHM_OUTPUTS[algorithm])
    r = raimcore.fde(*args, algorithm=algorithm, outputs=outs, **kw)
    assert r.algorithm == algorithm
    assert_engine_decisions(res.output, r)
    engine = {**res.output.per_sat, **res.output.columns}
    for k in outs:  # the optional outputs are the engine's columns of the same name
        np.testing.assert_allclose(r.outputs[k], engine[ENGINE_NAME.get(k, k)], rtol=1e-12,
                                   atol=0)
    # Not vacuous: every scenario has a fault that is detected and excluded.
    assert r.alarm.mean() > 0.3 and r.excluded.any(axis=-1).mean() > 0.3


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_agreement_with_missing_satellites(algorithm):
    """Satellites dropped at random (two systems): ok, detect-only and, for some
    algorithms, unavailable epochs, all as the engine decides them."""
    data = run_scenario(load_scenario("default", systems=["GPS", "BDS"])).measurements
    keep = np.random.default_rng(7).random(data.used.shape) > 0.45
    data = dataclasses.replace(data, used=data.used & keep,
                               pr_m=np.where(data.used & keep, data.pr_m, np.nan))
    spec = get_algorithm(algorithm)
    out = run_algorithm(spec, data, spec.resolve_options({}))
    args, kw = engine_call(data, algorithm)
    r = raimcore.fde(*args, algorithm=algorithm, **kw)
    if algorithm == "araim":  # epochs without redundancy: unavailable, as for all
        none = r.dof == 0
        assert none.sum() >= 3
        assert (np.asarray(out.status)[none] == "unavailable").all()
        assert np.isnan(out.statistic[none]).all() and not out.alarm[none].any()
    assert_engine_decisions(out, r)
    assert {"ok", "detect-only"} <= set(r.status.tolist()) and r.alarm.any()
    assert np.isnan(r.pos_ecef_m[r.status == "unavailable"]).all()


# ---------------------------------------------------------------- behaviour

@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_a_bias_is_detected_and_excluded(algorithm):
    sv, pr, sys_idx, rx = sky(np.random.default_rng(3), 4, 10, n_sys=2)
    pr = pr + np.random.default_rng(4).normal(0.0, 1.0, pr.shape)
    pr[:, 4] += 100.0
    r = raimcore.fde(sv, pr, 1.0, sys_idx=sys_idx, algorithm=algorithm)
    assert (r.status == "ok").all() and r.alarm.all() and (r.isolated == 4).all()
    np.testing.assert_array_equal(r.excluded, np.broadcast_to(np.arange(10) == 4, (4, 10)))
    err_after = np.linalg.norm(r.pos_ecef_m - rx, axis=-1)
    err_before = np.linalg.norm(r.pos_before_ecef_m - rx, axis=-1)
    assert (err_after < 10.0).all() and (err_before > err_after).all()
    assert (r.dof == 10 - 5).all()
    clean = raimcore.fde(sv, pr - 100.0 * (np.arange(10) == 4), 1.0, sys_idx=sys_idx,
                         algorithm=algorithm)
    assert not clean.alarm.any() and not clean.excluded.any()
    np.testing.assert_array_equal(clean.pos_ecef_m, clean.pos_before_ecef_m)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
@pytest.mark.parametrize("n_sats,status", [(3, "unavailable"), (4, "unavailable"),
                                           (5, "detect-only"), (7, "ok")])
def test_status_by_number_of_satellites(algorithm, n_sats, status):
    sv, pr, _, rx = sky(np.random.default_rng(n_sats), 2, n_sats)
    r = raimcore.fde(sv, pr, 2.0, algorithm=algorithm)
    assert (r.status == status).all()
    if status == "unavailable":
        for a in (r.statistic, r.threshold, r.pos_ecef_m, r.pos_before_ecef_m):
            assert np.isnan(a).all()
        assert not r.alarm.any() and (r.isolated == -1).all() and not r.excluded.any()
    else:
        np.testing.assert_allclose(r.pos_ecef_m, np.broadcast_to(rx, (2, 3)), atol=1e-3)
        assert not r.alarm.any()


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_singular_and_empty_epochs_do_not_poison_neighbours(algorithm):
    sv, pr, _, _ = sky(np.random.default_rng(5), 4, 8)
    sv, pr = sv.copy(), pr.copy()
    sv[1] = sv[1, :1] + np.linspace(0.0, 1.0, 8)[:, None] * 1e-3  # all in one spot
    pr[1] = np.linalg.norm(sv[1, 0] - 6.4e6)
    pr[2] = np.nan  # nothing tracked
    r = raimcore.fde(sv, pr, 1.0, algorithm=algorithm)
    assert r.status.tolist() == ["ok", "unavailable", "unavailable", "ok"]
    alone = raimcore.fde(sv[[0, 3]], pr[[0, 3]], 1.0, algorithm=algorithm)
    np.testing.assert_allclose(r.pos_ecef_m[[0, 3]], alone.pos_ecef_m, atol=1e-9)


@pytest.mark.parametrize("algorithm", ("gf", "rs", "qv"))
def test_max_exclusions_caps_a_multi_fault_exclusion(algorithm):
    sv, pr, _, rx = sky(np.random.default_rng(8), 3, 12)
    pr = pr + np.random.default_rng(9).normal(0.0, 1.0, pr.shape)
    pr[:, 2] += 150.0
    pr[:, 7] -= 120.0
    two = raimcore.fde(sv, pr, 1.0, algorithm=algorithm, max_exclusions=2)
    np.testing.assert_array_equal(two.excluded,
                                  np.broadcast_to(np.isin(np.arange(12), [2, 7]), (3, 12)))
    assert (np.linalg.norm(two.pos_ecef_m - rx, axis=-1) < 10.0).all()
    one = raimcore.fde(sv, pr, 1.0, algorithm=algorithm, max_exclusions=1)
    assert one.alarm.all() and not one.excluded.any()  # would take two: none taken
    np.testing.assert_array_equal(one.pos_ecef_m, one.pos_before_ecef_m)
    np.testing.assert_array_equal(one.isolated, two.isolated)


@pytest.mark.parametrize("algorithm", ALGORITHMS)
def test_max_exclusions_zero_detects_only(algorithm):
    sv, pr, _, _ = sky(np.random.default_rng(3), 3, 9)
    pr = pr + np.random.default_rng(4).normal(0.0, 1.0, pr.shape)
    pr[:, 1] += 100.0
    full = raimcore.fde(sv, pr, 1.0, algorithm=algorithm)
    none = raimcore.fde(sv, pr, 1.0, algorithm=algorithm, max_exclusions=0)
    assert full.excluded.any() and not none.excluded.any()
    np.testing.assert_array_equal(none.alarm, full.alarm)
    np.testing.assert_array_equal(none.pos_ecef_m, none.pos_before_ecef_m)


def test_araim_constellation_exclusion_is_capped():
    """The araim scenario's Galileo constellation fault: the engine excludes every
    Galileo satellite; with max_exclusions = 1 nothing is excluded, the alarm stands."""
    res = run_scenario("araim")
    args, kw = engine_call(res.measurements, "araim")
    kw["max_exclusions"] = 1
    r = raimcore.fde(*args, algorithm="araim", **kw)
    gal = res.measurements.sys_idx == list(res.measurements.systems).index("GAL")
    many = res.output.excluded[:, gal].sum(axis=-1) > 1
    assert many.sum() > 100
    assert r.alarm[many].all() and not r.excluded[many].any()
    np.testing.assert_array_equal(r.pos_ecef_m[many], r.pos_before_ecef_m[many])


def test_araim_sigma_acc_and_ism_defaults_are_documented_values():
    sv, pr, sys_idx, _ = sky(np.random.default_rng(6), 3, 10, n_sys=2)
    pr = pr + np.random.default_rng(7).normal(0.0, 1.5, pr.shape)
    sig = np.full(pr.shape, 1.5)
    a = raimcore.fde(sv, pr, sig, algorithm="araim", sys_idx=sys_idx, outputs=("vpl_m",))
    b = raimcore.fde(sv, pr, sig, algorithm="araim", sys_idx=sys_idx, outputs=("vpl_m",),
                     sigma_acc_m=sig, b_nom_m=0.0, b_cont_m=np.zeros(10), p_sat=1e-5,
                     p_const=[1e-8, 1e-8])
    np.testing.assert_array_equal(a.outputs["vpl_m"], b.outputs["vpl_m"])
    worse = raimcore.fde(sv, pr, sig, algorithm="araim", sys_idx=sys_idx, outputs=("vpl_m",),
                         b_nom_m=1.0)
    assert (worse.outputs["vpl_m"] > a.outputs["vpl_m"]).all()


def test_rs_draws_follow_the_seed():
    sv, pr, _, _ = sky(np.random.default_rng(10), 20, 12)
    pr = pr + np.random.default_rng(11).normal(0.0, 1.0, pr.shape)
    pr[:, 3] += 60.0
    a, b = (raimcore.fde(sv, pr, 1.0, algorithm="rs", seed=5, rs_draws=3,
                         outputs=("rs_isolated",)) for _ in range(2))
    np.testing.assert_array_equal(a.outputs["rs_isolated"], b.outputs["rs_isolated"])


def test_fields_the_other_algorithms_do_not_have_are_nan():
    sv, pr, sys_idx, _ = sky(np.random.default_rng(1), 2, 8, n_sys=2)
    r = raimcore.fde(sv, pr, 1.0, algorithm="gf", sys_idx=sys_idx)
    assert r.clock_m.shape == (2, 2) and np.isnan(r.clock_m).all()
    assert np.isnan(r.statistic_after).all() and r.outputs == {}


# ---------------------------------------------------------------- the public edge

@pytest.mark.parametrize("algorithm,kwargs,message", [
    ("nope", {}, "algorithm must be one of parity, mss, gf, rs, qv, araim; got 'nope'"),
    ("ekf", {}, "algorithm must be one of parity, mss, gf, rs, qv, araim; got 'ekf'"),
    ("mss", {"chunk": 5}, "unknown option 'chunk' for raimcore.fde; options: outputs, p_md, "
     "mss_ident_rule (algorithm 'mss')"),
    ("mss", {"path": "fast"}, "option 'path' does not apply to algorithm 'mss' (only to "
     "parity)"),
    ("gf", {"p_md": 1e-4}, "option 'p_md' does not apply to algorithm 'gf' (only to parity, "
     "mss)"),
    ("mss", {"gf_groups": 10}, "option 'gf_groups' does not apply to algorithm 'mss' (only to "
     "gf)"),
    ("araim", {"emt_max_m": 15.0}, "unknown option 'emt_max_m' for raimcore.fde"),
    ("parity", {"seed": 1}, "option 'seed' does not apply to algorithm 'parity' (only to rs)"),
    ("gf", {"gf_margin": 5.0}, "gf_margin"),
    ("mss", {"mss_ident_rule": "best"}, "mss_ident_rule"),
    ("mss", {"outputs": ("isolation",)}, "outputs must name some of hpl_m, vpl_m"),
    ("araim", {"p_fa": 1e-3}, "p_fa does not apply to algorithm 'araim'"),
    ("araim", {"p_sat": np.ones(5)}, "p_sat must be a scalar or have shape (6,) or (2, 6)"),
    ("araim", {"p_sat": 2.0}, "p_sat must be finite and >= 0 and <= 1"),
    ("araim", {"sigma_acc_m": 0.0}, "sigma_acc_m must be finite and > 0"),
    ("araim", {"p_const": [1e-8, 1e-8]}, "p_const must be a scalar or have shape (1,)"),
    ("araim", {"araim_constants": {"phmi_vertical": 1e-9}}, "araim_constants"),
    ("rs", {"seed": -1}, "seed"),
    ("gf", {"max_exclusions": -1}, "max_exclusions"),
    ("parity", {"max_exclusions": 11}, "max_exclusions"),
])
def test_bad_arguments_raise_one_line_errors(algorithm, kwargs, message):
    sv, pr, _, _ = sky(np.random.default_rng(0), 2, 6)
    with pytest.raises(ValueError) as e:
        raimcore.fde(sv, pr, 1.0, algorithm=algorithm, **kwargs)
    assert message in str(e.value) and "\n" not in str(e.value)
