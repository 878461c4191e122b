"""GF / RS / QV as registered algorithms on a scenario with several simultaneous faults."""

import numpy as np
import pytest

from raimcore import algorithms
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario


@pytest.fixture(scope="module")
def gf_run():
    return run_scenario(load_scenario("seed004-multi", algorithm="gf"))


def test_gf_isolates_up_to_three_simultaneous_faults(gf_run):
    out, data = gf_run.output, gf_run.measurements
    faulty = gf_run.truth.faulted
    exact = np.all(out.excluded == faulty, axis=-1)
    t = data.t_s
    assert exact[t < 60].all()  # no fault: nothing excluded
    for lo, hi in ((60, 120), (120, 180), (180, 270)):  # one, two, three faults
        assert exact[(t >= lo) & (t < hi)].mean() >= 0.9
    # Every excluded satellite stands above the adaptive threshold mean + M.
    mf, thr = out.per_sat["mf"], out.columns["mf_threshold"]
    assert np.all(mf[out.excluded] > np.repeat(thr, out.excluded.sum(axis=1)))
    assert np.allclose(np.nanmean(mf, axis=1) + 0.1, thr, equal_nan=True)
    # After exclusion the position is back near the truth.
    err = np.linalg.norm(out.pos_after_ecef_m - gf_run.truth.pos_rx_ecef_m, axis=-1)
    assert np.median(err[t >= 180]) < 150.0


@pytest.mark.parametrize("name", ["rs", "qv"])
def test_baselines_run_on_the_multi_fault_scenario(name):
    r = run_scenario(load_scenario("seed004-multi", algorithm=name, duration_s=130))
    exact = np.all(r.output.excluded == r.truth.faulted, axis=-1)
    t = r.measurements.t_s
    assert exact[t < 60].all()
    assert exact[(t >= 60) & (t < 120)].mean() > 0.5


def test_options_are_validated():
    with pytest.raises(ValueError, match="gf_weights must be one of pdop, uniform"):
        run_scenario(load_scenario("seed004-multi", algorithm="gf", duration_s=2,
                                   gf_weights="x"))
    with pytest.raises(ValueError, match="gf_margin"):
        run_scenario(load_scenario("seed004-multi", algorithm="gf", duration_s=2,
                                   gf_margin=3))


def test_uniform_weights_and_fewer_groups_still_work():
    r = run_scenario(load_scenario("seed004-multi", algorithm="gf", duration_s=100,
                                   gf_weights="uniform", gf_groups=200))
    assert np.all(r.output.excluded == r.truth.faulted, axis=-1)[60:].mean() > 0.8
    assert algorithms.get("gf").defaults["gf_groups"] == 0
