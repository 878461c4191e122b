"""raimcore.fde, the array-level snapshot FDE, and its fast parity kernel.

One conformance suite runs over both paths of the same call (``path="fast"``, the kernel
the scenario engine uses, and ``path="reference"``, the plain numpy path it replaced):
behaviour tests run on each, and agreement tests require the same decisions (every
status, alarm, isolated satellite and exclusion) and positions to a micrometre on
simulated scenarios (fault-free, half faulted, satellites missing, fewer than 5
satellites, a moving receiver, two exclusions) and on the real recordings in
``../shared/data`` (skipped when absent).
"""

import numpy as np
import pytest
from scipy import stats

import raimcore
from raimcore.algorithms import get as get_algorithm
from raimcore.measure.faults import Fault
from raimcore.pipeline import simulate
from raimcore.scenario import load_scenario, recording_scenario

ONE_UM = 1e-6  # positions of the two paths agree to a micrometre (the issue: 1e-6 m)
STAT_RTOL = 1e-6  # detection statistics, relative (Gauss-Newton stops at a 0.1 mm step)
PATHS = ("fast", "reference")
SATS = ["G02", "G05", "G06", "G09", "G10", "G15", "G20", "C02", "C21", "C28"]
ESBC = ("ESBC00DNK_R_20201770000_02H_30S_MO.rnx", "ESBC00DNK_R_20201770000_01D_MN.rnx")
SLAC = ("slac1180.21o", "brdc1180.21n")


def arrays(data):
    """(pos_sv_ecef_m, pr_m, sigma_m, sys_idx) of a Measurements: NaN = not used."""
    pr = np.where(data.used, data.pr_m, np.nan)
    return data.pos_sv_ecef_m, pr, np.where(data.used, data.sigma_m, np.nan), data.sys_idx


def sky(rng, t_n, s_n, *, n_sys=1, rx=(3.9e6, 3.0e5, 5.0e6)):
    """Random satellites above a receiver's horizon and exact pseudoranges plus clocks."""
    rx = np.asarray(rx, dtype=float)
    up = rx / np.linalg.norm(rx)
    u = rng.normal(size=(t_n, s_n, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    u -= 2.0 * np.minimum(u @ up, 0.0)[..., None] * up  # reflected above the horizon
    u += 0.2 * up  # and a little higher
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    sv = rx + 2.2e7 * u
    sys_idx = np.arange(s_n) % n_sys
    clocks = np.array([1.5e4, -6.0e4, 3.0e3, 9.0e2])[:n_sys]
    pr = np.linalg.norm(sv - rx, axis=-1) + clocks[sys_idx]
    return sv, pr, sys_idx, rx


def tied(r):
    """Epochs where the largest isolation statistics of ``r`` (which has the
    ``isolation`` output) tie: two satellites alone in their system have parallel parity
    columns (isolability 1), equal DF_I, and which one argmax names is rounding."""
    iso = np.sort(np.nan_to_num(r.outputs["isolation"], nan=-1.0), axis=-1)
    return r.alarm & (iso[:, -1] >= 0.0) & np.isclose(iso[:, -1], iso[:, -2], rtol=1e-9,
                                                      atol=0.0)


def assert_same_decisions(a, b, skip=None):
    """Two FdeResults make the same decisions, with positions within a micrometre.

    ``skip`` : epochs whose isolation is a tie (see :func:`tied`): there both paths must
    name one of the tied satellites, and what follows the exclusion is not compared.
    """
    if skip is not None and skip.any():
        iso = a.outputs["isolation"][skip]
        picked = np.take_along_axis(iso, b.isolated[skip, None], axis=-1)[:, 0]
        np.testing.assert_allclose(picked, np.nanmax(iso, axis=-1), rtol=1e-9)
        keep = ~skip
        a = FdeView(a, keep)
        b = FdeView(b, keep)
    np.testing.assert_array_equal(a.status, b.status)
    # dof where available (an unavailable epoch's dof is only a count: the reference
    # counted every system's clock there when its last iterate had no finite geometry).
    ok = a.status != "unavailable"
    np.testing.assert_array_equal(a.dof[ok], b.dof[ok])
    np.testing.assert_array_equal(a.alarm, b.alarm)
    np.testing.assert_array_equal(a.isolated, b.isolated)
    np.testing.assert_array_equal(a.excluded, b.excluded)
    np.testing.assert_array_equal(a.threshold, b.threshold)
    np.testing.assert_allclose(a.statistic, b.statistic, rtol=STAT_RTOL, atol=1e-9)
    np.testing.assert_allclose(a.statistic_after, b.statistic_after, rtol=STAT_RTOL,
                               atol=1e-9)
    np.testing.assert_allclose(a.pos_before_ecef_m, b.pos_before_ecef_m, rtol=0, atol=ONE_UM)
    np.testing.assert_allclose(a.pos_ecef_m, b.pos_ecef_m, rtol=0, atol=ONE_UM)
    np.testing.assert_allclose(a.clock_m, b.clock_m, rtol=0, atol=ONE_UM)


class FdeView:
    """The epochs ``keep`` of an FdeResult (the fields compared)."""

    def __init__(self, r, keep):
        for k in ("status", "dof", "alarm", "isolated", "excluded", "threshold",
                  "statistic", "statistic_after", "pos_before_ecef_m", "pos_ecef_m",
                  "clock_m"):
            setattr(self, k, getattr(r, k)[keep])


def both(*args, **kw):
    """The fast and the reference result of one call, and the epochs with a tie."""
    kw.setdefault("outputs", ("isolation",))
    fast, ref = (raimcore.fde(*args, path=p, **kw) for p in PATHS)
    return fast, ref, tied(ref)


# ---------------------------------------------------------------- agreement: simulated

def _bench(duration_s, faulted, step_s=1.0):
    s = load_scenario("default", systems=["GPS", "BDS"], duration_s=duration_s,
                      step_s=step_s, sigma_m=3.0, mask_deg=0.0).replace(sats=SATS)
    # No fault, or a 60 m step on G10 over the second half.
    s = s.with_faults(*([Fault("G10", "step", t0_s=duration_s / 2, bias_m=60.0)] if faulted
                        else []))
    return simulate(s)[0]


@pytest.fixture(scope="module")
def bench_faulted():
    return _bench(1999, True)


@pytest.mark.parametrize("faulted", [False, True], ids=["fault-free", "half-faulted"])
def test_agreement_on_the_benchmark_scenario(faulted, bench_faulted):
    data = bench_faulted if faulted else _bench(1999, False)
    fast, ref, ties = both(*arrays(data)[:3], sys_idx=data.sys_idx)
    assert_same_decisions(ref, fast, ties)
    assert (fast.status == "ok").all()
    if not faulted:
        assert fast.alarm.mean() < 0.01 and not fast.excluded[~fast.alarm].any()
    else:  # the fault is found and removed in (nearly) every faulted epoch
        half = len(fast.alarm) // 2 + 1
        assert fast.alarm[half:].mean() > 0.95 and fast.alarm[:half].mean() < 0.01
        assert (fast.excluded[half:, SATS.index("G10")].mean()) > 0.95


@pytest.mark.parametrize("max_exclusions", [0, 3])
def test_agreement_for_other_exclusion_limits(bench_faulted, max_exclusions):
    fast, ref, ties = both(*arrays(bench_faulted)[:3], sys_idx=bench_faulted.sys_idx,
                           max_exclusions=max_exclusions)
    assert_same_decisions(ref, fast, ties)
    assert (fast.excluded.sum(axis=-1).max() > 0) == (max_exclusions > 0)
    assert (fast.isolated[fast.alarm] >= 0).all()


def test_agreement_with_missing_satellites_and_fewer_than_five(bench_faulted):
    sv, pr, sig, sys_idx = arrays(bench_faulted)
    rng = np.random.default_rng(7)
    pr = pr.copy()
    sv = sv.copy()
    pr[rng.random(pr.shape) < 0.4] = np.nan  # many epochs with 3, 4 or 5 satellites
    sv[rng.random(pr.shape) < 0.02] = np.nan  # a satellite without a position
    pr[::97] = np.nan  # whole epochs with nothing tracked
    n = np.sum(np.isfinite(pr) & np.isfinite(sv).all(-1), axis=-1)
    assert {3, 4, 5, 6} <= set(n.tolist())
    fast, ref, ties = both(sv, pr, sig, sys_idx=sys_idx, max_exclusions=2)
    assert_same_decisions(ref, fast, ties)
    assert (fast.status[n < 5] != "ok").all()
    assert np.isnan(fast.statistic[fast.status == "unavailable"]).all()
    assert np.isnan(fast.pos_ecef_m[n < 4]).all()
    assert {"ok", "detect-only", "unavailable"} == set(fast.status.tolist())


def test_agreement_three_systems_and_a_moving_receiver():
    s = load_scenario("seed001-flight", duration_s=599, step_s=2.0, baro=False).replace(
        systems=["GPS", "GAL", "BDS"], sigma_m=5.0, p_fa=1e-3)
    s = s.with_faults(Fault("G10", "step", t0_s=300.0, bias_m=80.0),
                      Fault("E07", "step", t0_s=300.0, bias_m=-70.0))
    data = simulate(s)[0]
    fast, ref, ties = both(*arrays(data)[:3], sys_idx=data.sys_idx, max_exclusions=2)
    assert_same_decisions(ref, fast, ties)
    assert fast.alarm[150:].mean() > 0.9 and fast.excluded[150:].any(axis=-1).mean() > 0.9


def test_optional_outputs_agree_with_the_reference(bench_faulted):
    outs = tuple(raimcore.snapshot.FDE_OUTPUTS)
    fast, ref, ties = both(*arrays(bench_faulted)[:3], sys_idx=bench_faulted.sys_idx,
                     outputs=outs, p_md=1e-4)
    for k in outs:
        np.testing.assert_allclose(fast.outputs[k], ref.outputs[k], rtol=1e-6, atol=1e-8)
    assert raimcore.fde(*arrays(bench_faulted)[:3]).outputs == {}


# ---------------------------------------------------------------- agreement: recordings

@pytest.mark.parametrize("files,faults", [
    (ESBC, ()), (SLAC, ()),
    (ESBC, (Fault("G05", "step", t0_s=600.0, t1_s=1800.0, bias_m=50.0),
            Fault("C23", "step", t0_s=1200.0, t1_s=3000.0, bias_m=-40.0)))],
    ids=["esbc", "slac", "esbc-faulted"])
def test_agreement_on_real_recordings(shared_data, files, faults):
    s = recording_scenario(str(shared_data / files[0]), str(shared_data / files[1]),
                           faults=list(faults))
    data = simulate(s)[0]
    fast, ref, ties = both(*arrays(data)[:3], sys_idx=data.sys_idx, max_exclusions=2)
    assert_same_decisions(ref, fast, ties)
    assert (fast.status != "unavailable").mean() > 0.9
    if faults:  # both faults found; where they overlap (1200-1800 s), both excluded
        assert fast.alarm.sum() > 60 and fast.excluded.sum(axis=-1).max() == 2


# ---------------------------------------------------------------- behaviour, both paths

@pytest.mark.parametrize("path", PATHS)
def test_a_bias_is_detected_isolated_and_excluded(path):
    sv, pr, sys_idx, rx = sky(np.random.default_rng(3), 1, 9, n_sys=2)
    pr = pr + np.random.default_rng(4).normal(0.0, 1.0, pr.shape)
    pr[0, 4] += 100.0
    r = raimcore.fde(sv, pr, 1.0, sys_idx=sys_idx, path=path)
    assert r.alarm[0] and r.isolated[0] == 4 and r.excluded[0].tolist() == [
        j == 4 for j in range(9)]
    assert np.linalg.norm(r.pos_ecef_m[0] - rx) < 10.0
    assert np.linalg.norm(r.pos_before_ecef_m[0] - rx) > np.linalg.norm(r.pos_ecef_m[0] - rx)
    assert r.statistic_after[0] < r.threshold[0] < r.statistic[0]
    none = raimcore.fde(sv, pr, 1.0, sys_idx=sys_idx, path=path, max_exclusions=0)
    assert none.alarm[0] and none.isolated[0] == 4 and not none.excluded.any()
    np.testing.assert_array_equal(none.pos_ecef_m, none.pos_before_ecef_m)


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize("n_sats,status", [(3, "unavailable"), (4, "unavailable"),
                                           (5, "detect-only"), (6, "ok")])
def test_status_by_number_of_satellites(path, n_sats, status):
    sv, pr, _, rx = sky(np.random.default_rng(n_sats), 1, n_sats)
    r = raimcore.fde(sv, pr, 2.0, path=path)
    assert r.status[0] == status and r.dof[0] == n_sats - 4
    if status == "unavailable":
        assert np.isnan(r.statistic[0]) and np.isnan(r.pos_ecef_m[0]).all()
        assert not r.alarm[0] and r.isolated[0] == -1 and not r.excluded.any()
    else:
        np.testing.assert_allclose(r.pos_ecef_m[0], rx, atol=1e-3)
        assert r.statistic[0] < 1e-6


@pytest.mark.parametrize("path", PATHS)
def test_singular_geometry_is_unavailable_and_does_not_poison_neighbours(path):
    sv, pr, _, _ = sky(np.random.default_rng(5), 3, 8)
    sv = sv.copy()
    sv[1] = sv[1, :1] + np.linspace(0.0, 1.0, 8)[:, None] * 1e-3  # all satellites in one spot
    pr = pr.copy()
    pr[1] = np.linalg.norm(sv[1, 0] - 6.4e6)
    r = raimcore.fde(sv, pr, 1.0, path=path)
    assert r.status.tolist() == ["ok", "unavailable", "ok"]
    alone = raimcore.fde(sv[[0, 2]], pr[[0, 2]], 1.0, path=path)
    np.testing.assert_allclose(r.pos_ecef_m[[0, 2]], alone.pos_ecef_m, atol=1e-9)


@pytest.mark.parametrize("path", PATHS)
def test_batched_equals_per_epoch_and_chunks_do_not_matter(path, bench_faulted):
    sv, pr, sig, sys_idx = arrays(bench_faulted.take_epochs(np.arange(990, 1030)))
    batch = raimcore.fde(sv, pr, sig, sys_idx=sys_idx, path=path)
    one = [raimcore.fde(sv[[t]], pr[[t]], sig[[t]], sys_idx=sys_idx, path=path)
           for t in range(len(pr))]
    assert batch.alarm.any() and not batch.alarm.all()
    for t, r in enumerate(one):
        assert r.status[0] == batch.status[t] and r.alarm[0] == batch.alarm[t]
        np.testing.assert_array_equal(r.excluded[0], batch.excluded[t])
        np.testing.assert_allclose(r.pos_ecef_m[0], batch.pos_ecef_m[t], atol=1e-9)
    if path == "fast":
        small = raimcore.fde(sv, pr, sig, sys_idx=sys_idx, chunk_epochs=7)
        assert_same_decisions(small, batch)


@pytest.mark.parametrize("path", PATHS)
def test_satellite_order_does_not_matter(path):
    sv, pr, sys_idx, _ = sky(np.random.default_rng(11), 20, 12, n_sys=3)
    pr = pr + np.random.default_rng(12).normal(0.0, 1.0, pr.shape)
    pr[::2, 5] += 40.0
    perm = np.random.default_rng(13).permutation(12)
    a = raimcore.fde(sv, pr, 1.0, sys_idx=sys_idx, path=path)
    b = raimcore.fde(sv[:, perm], pr[:, perm], 1.0, sys_idx=sys_idx[perm], path=path)
    np.testing.assert_allclose(a.statistic, b.statistic, rtol=STAT_RTOL)
    np.testing.assert_array_equal(a.excluded[:, perm], b.excluded)
    np.testing.assert_allclose(a.pos_ecef_m, b.pos_ecef_m, atol=1e-6)


def test_false_alarm_rate_matches_p_fa():
    """Fault-free Gaussian noise: the alarm rate is p_fa (binomial test, seeded)."""
    rng = np.random.default_rng(21)
    sv, pr, sys_idx, _ = sky(rng, 20_000, 9, n_sys=2)
    pr = pr + rng.normal(0.0, 2.0, pr.shape)
    r = raimcore.fde(sv, pr, 2.0, sys_idx=sys_idx, p_fa=1e-2)
    k, n = int(r.alarm.sum()), len(r.alarm)
    assert stats.binomtest(k, n, 1e-2).pvalue > 1e-3, f"{k}/{n} alarms"


def test_the_scenario_engine_runs_the_same_kernel(bench_faulted):
    spec = get_algorithm("parity")
    out = spec.run(bench_faulted, spec.resolve_options({"max_exclusions": 1}))
    r = raimcore.fde(*arrays(bench_faulted)[:3], sys_idx=bench_faulted.sys_idx,
                     p_fa=bench_faulted.p_fa)
    np.testing.assert_array_equal(out.alarm, r.alarm)
    np.testing.assert_array_equal(out.excluded, r.excluded)
    np.testing.assert_array_equal(out.isolated, r.isolated)
    np.testing.assert_array_equal(out.pos_after_ecef_m, r.pos_ecef_m)  # bit for bit
    np.testing.assert_array_equal(np.asarray(out.status, dtype=str), r.status)


# ---------------------------------------------------------------- the public edge

@pytest.mark.parametrize("kwargs,message", [
    ({"algorithm": "nope"}, "algorithm must be one of parity, mss, gf, rs, qv, araim"),
    ({"seed": 3}, "option 'seed' does not apply to algorithm 'parity' (only to rs)"),
    ({"chunk": 5}, "unknown option 'chunk' for raimcore.fde; options: outputs"),
    ({"outputs": ("hpl",)}, "outputs must name some of isolation"),
    ({"p_fa": 1.5}, "p_fa must be a probability"),
    ({"max_exclusions": -1}, "max_exclusions"),
    ({"path": "slow"}, "path must be one of fast, reference"),
    ({"sys_idx": [0, 1]}, "sys_idx must be an integer array of shape (6,)"),
])
def test_bad_arguments_raise_one_line_errors(kwargs, message):
    sv, pr, _, _ = sky(np.random.default_rng(0), 2, 6)
    with pytest.raises(ValueError) as e:
        raimcore.fde(sv, pr, 1.0, **kwargs)
    assert message in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("sv_shape,pr_shape,sigma,message", [
    ((2, 6, 2), (2, 6), 1.0, "pos_sv_ecef_m"),
    ((6, 3), (6,), 1.0, "pos_sv_ecef_m must have shape (T, n, 3)"),
    ((2, 6, 3), (2, 5), 1.0, "pr_m"),
    ((2, 6, 3), (2, 6), 0.0, "sigma_m must be finite and > 0"),
    ((2, 6, 3), (2, 6), np.ones(6), "sigma_m must be a scalar or have shape (2, 6)"),
])
def test_bad_shapes_and_sigmas_are_named(sv_shape, pr_shape, sigma, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        raimcore.fde(np.full(sv_shape, 2e7), np.full(pr_shape, 2e7), sigma)


def test_nan_sigma_is_fine_where_not_tracked():
    sv, pr, _, _ = sky(np.random.default_rng(1), 2, 7)
    pr = pr.copy()
    pr[0, 2] = np.nan
    sig = np.ones(pr.shape)
    sig[0, 2] = np.nan
    r = raimcore.fde(sv, pr, sig)
    assert (r.status == "ok").all() and r.dof.tolist() == [2, 3]


def test_docstring_example_runs():
    import doctest

    from raimcore import snapshot

    res = doctest.testmod(snapshot)
    assert res.attempted > 0 and res.failed == 0
