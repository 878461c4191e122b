"""Constellation faults (issue 16, item 3): one fault on every satellite of a system.

The forms (``--fault GAL,step,20,300``, ``{sat = "GAL", ...}``, ``{kind = "constellation",
system = "GAL", shape = "step", ...}``) give one fault; its bias, ``bias x sin(el)``, acts
on every satellite of the system and no other, between t0_s and t1_s, on a simulated sky
and on a recording; the common part of that bias is the one a constellation's receiver
clock absorbs (checked: a common bias is invisible to parity), the rest is detected;
scoring and the verdict understand the fault.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import json
import math

import numpy as np
import pytest

from raimcore import algorithms
from raimcore.cli import main
from raimcore.measure import measure
from raimcore.measure.faults import Fault, fault_bias, fault_biases, parse_fault
from raimcore.pipeline import run_algorithm, run_scenario, simulate
from raimcore.scenario import load_scenario, recording_scenario
from raimcore.scoring import make_table, summarize
from raimcore.sky import build_sky

ESBC_OBS = "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx"
one_um = 1e-6  # m: biases are computed, not measured


def _gps_gal(faults, **kw):
    """The dashboard default on GPS + Galileo (1 m noise, 600 s)."""
    return load_scenario("default", systems=["GPS", "GAL"], faults=list(faults),
                         sigma_m=kw.pop("sigma_m", 1.0), **kw)


def _cli(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


# -- the forms ----------------------------------------------------------------------------

@pytest.mark.parametrize("cli, canonical, issue", [
    ("GAL,step,20,300", {"sat": "GAL", "kind": "step", "bias_m": 20, "t0_s": 300},
     {"kind": "constellation", "system": "GAL", "shape": "step", "bias_m": 20, "t0_s": 300}),
    ("GAL,step,20,300,450",
     {"sat": "GAL", "kind": "step", "bias_m": 20, "t0_s": 300, "t1_s": 450},
     {"kind": "constellation", "system": "GAL", "bias_m": 20, "t0_s": 300, "t1_s": 450}),
    ("BDS,ramp,0.5,60", {"sat": "BDS", "kind": "ramp", "rate_mps": 0.5, "t0_s": 60},
     {"kind": "constellation", "system": "BDS", "shape": "ramp", "rate_mps": 0.5,
      "t0_s": 60}),
], ids=["step", "step-with-end", "ramp"])
def test_cli_and_toml_forms_are_one_fault(tmp_path, cli, canonical, issue):
    f = parse_fault(cli)
    assert f == Fault.from_dict(canonical) == Fault.from_dict(issue)
    assert f.system == f.sat and f.target == f"{f.sat} (constellation)"
    assert Fault.from_dict(f.to_dict()) == f and f.to_dict()["sat"] == f.sat  # canonical
    # In scenario files, both spellings side by side.
    path = tmp_path / "two.toml"
    rows = "\n".join(f"{k} = {json.dumps(v)}" for k, v in canonical.items())
    rows2 = "\n".join(f"{k} = {json.dumps(v)}" for k, v in issue.items())
    path.write_text(f'systems = ["GPS", "{f.sat}"]\n[[faults]]\n{rows}\n[[faults]]\n{rows2}\n')
    s = load_scenario(path)
    assert s.faults == (f, f)
    # And the command line builds the same scenario.
    rc, out, _ = _cli(["run", path, "--fault", cli, "--quiet", "--set", "duration_s=2"])
    assert rc == 0 and json.loads(out)["epochs"] == 3


def test_a_satellite_fault_is_not_a_constellation_fault():
    f = parse_fault("G10,step,20,300")
    assert f.system is None and f.target == "G10"


# -- the biases ---------------------------------------------------------------------------

@pytest.mark.parametrize("fault", [
    Fault("GAL", "step", t0_s=200.0, t1_s=400.0, bias_m=20.0),
    Fault("GAL", "ramp", t0_s=200.0, t1_s=400.0, rate_mps=0.5),
], ids=["step", "ramp"])
def test_every_satellite_of_the_constellation_and_no_other_between_t0_and_t1(fault):
    data, truth = simulate(_gps_gal([fault], duration_s=599))
    t, el = data.t_s, data.el_rad
    gal = np.array([n.startswith("E") for n in data.sat_names])
    on = (t >= 200.0) & (t < 400.0)
    size = 20.0 * np.ones_like(t) if fault.kind == "step" else 0.5 * (t - 200.0)
    want = np.where(on[:, None] & gal[None, :], size[:, None] * np.sin(el), 0.0)
    np.testing.assert_allclose(truth.fault_bias_m, want, atol=one_um)
    # Truth: every used Galileo satellite is faulted while the bias is not zero (a ramp's
    # is zero at t0_s), no GPS satellite ever.
    acting = on & (size != 0)
    assert np.array_equal(truth.faulted, acting[:, None] & gal[None, :] & data.used)
    assert truth.faulted[:, gal].any(axis=0)[data.used[:, gal].any(axis=0)].all()
    assert data.used[acting][:, gal].sum(-1).min() >= 5  # the test sees several at once


def test_biases_add_up_over_faults_and_match_the_per_fault_form():
    """fault_biases is the sum of fault_bias, unbatched (one epoch) and batched."""
    names = ("G01", "E01", "E02", "G02")
    systems = np.array(["GPS", "GAL", "GAL", "GPS"])
    t = np.array([0.0, 10.0, 20.0])
    el = np.radians([[10.0, 30.0, 90.0, 45.0]] * 3)
    faults = [Fault("GAL", "step", t0_s=5.0, bias_m=10.0), Fault("E01", "step", bias_m=1.0)]
    b = fault_biases(faults, t, names, systems, el)
    np.testing.assert_allclose(b, [[0, 1, 0, 0], [0, 6, 10, 0], [0, 6, 10, 0]], atol=one_um)
    assert np.array_equal(b, sum(fault_bias(f, t, names, systems, el) for f in faults))
    one = fault_biases(faults, t[1:2], names, systems, el[1:2])
    assert np.array_equal(one, b[1:2])
    # A constellation with no satellite here adds nothing; its inputs are required.
    assert not fault_biases([Fault("GLO", bias_m=5.0)], t, names, systems, el).any()
    with pytest.raises(ValueError, match="sat_systems"):
        fault_biases(faults[:1], t, names)
    with pytest.raises(ValueError, match="el_rad"):
        fault_biases(faults[:1], t, names, systems)


def test_on_a_recording_every_galileo_satellite_gets_the_bias(shared_data):
    s = recording_scenario(str(shared_data / ESBC_OBS), str(shared_data / ESBC_NAV),
                           duration_s=1200.0)
    sky = build_sky(s)
    clean, _ = measure(sky, s)
    data, truth = measure(sky, s.replace(faults=[Fault("GAL", "step", t0_s=300.0,
                                                       t1_s=900.0, bias_m=20.0)]))
    gal = np.array([n.startswith("E") for n in data.sat_names])
    on = (data.t_s >= 300.0) & (data.t_s < 900.0)
    used = data.used
    delta = np.where(used, data.pr_m - clean.pr_m, 0.0)
    want = np.where(on[:, None] & gal[None, :] & used, 20.0 * np.sin(data.el_rad), 0.0)
    np.testing.assert_allclose(delta, want, atol=one_um)
    assert np.array_equal(truth.faulted, on[:, None] & gal[None, :] & used)
    assert used[on][:, gal].sum(-1).min() >= 5
    assert not [n for n in data.notes if n.startswith("warning: fault")]


def test_a_constellation_fault_runs_on_a_recording(shared_data):
    s = recording_scenario(str(shared_data / ESBC_OBS), str(shared_data / ESBC_NAV),
                           duration_s=1200.0, faults=[parse_fault("GAL,step,20,300,900")])
    r = run_scenario(s)
    assert r.summary.faulted_epochs == 20


# -- detection, and why not a common bias -------------------------------------------------

def test_parity_detects_a_20_m_galileo_step_on_gps_plus_galileo():
    r = run_scenario(_gps_gal([parse_fault("GAL,step,20,300")]))
    sm = r.summary
    assert sm.faulted_epochs == 300 and sm.detection.n == 300
    assert sm.detection.value >= 0.95 and sm.false_alarm.value <= 0.01
    assert sm.first_alarm_t_s <= 305.0
    # The same through the command line.
    rc, out, _ = _cli(["run", "default", "--set", 'systems=["GPS","GAL"]', "--set",
                       "sigma_m=1", "--fault", "GAL,step,20,300", "--quiet"])
    assert rc == 0 and json.loads(out)["detection_rate"] >= 0.95


def test_a_bias_common_to_a_constellation_is_absorbed_by_its_clock():
    """Why the bias goes with sin(el): the same bias on every Galileo satellite changes
    neither the parity statistic nor the position (Galileo has its own receiver clock)."""
    s = _gps_gal([], duration_s=60)
    data, _ = simulate(s)
    gal = np.array([n.startswith("E") for n in data.sat_names])
    common = dataclasses.replace(data, pr_m=data.pr_m + 20.0 * gal[None, :])
    spec = algorithms.get("parity")
    a = run_algorithm(spec, data, s.algorithm_options())
    b = run_algorithm(spec, common, s.algorithm_options())
    np.testing.assert_allclose(b.statistic, a.statistic, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b.pos_before_ecef_m, a.pos_before_ecef_m, atol=1e-6)


# -- scoring -------------------------------------------------------------------------------

def test_correct_isolation_of_a_constellation_fault_is_the_whole_constellation_excluded():
    s = _gps_gal([parse_fault("GAL,step,20,300")], duration_s=599)
    data, truth = simulate(s)
    out = run_algorithm(algorithms.get("parity"), data, s.algorithm_options())
    gal = np.array([n.startswith("E") for n in data.sat_names])
    whole = truth.faulted.any(-1)[:, None] & gal[None, :] & data.used
    one = whole & (np.cumsum(whole, axis=1) == 1)  # only the first faulted one
    for excluded, right in ((whole, 300), (one, 0)):
        o = dataclasses.replace(out, excluded=excluded)
        sm = summarize(make_table(data, truth, o))
        assert sm.correct_isolation.k == right and sm.correct_isolation.n == 300
        assert sm.detection.k == int(o.alarm[truth.faulted_epochs].sum())


# -- a fault that never acts ----------------------------------------------------------------

@pytest.mark.parametrize("case, why", [
    ("masked", "no GAL satellite is ever used"),
    ("after-the-run", "lies outside the run"),
    ("no-galileo-satellite", "this run has no GAL satellite"),
])
def test_a_constellation_fault_that_never_acts_is_a_warning(case, why):
    fault = {"sat": "GAL", "bias_m": 20.0, "t0_s": 500.0 if case == "after-the-run" else 0.0}
    kw = {"duration_s": 20}
    if case == "masked":
        kw["mask_deg"] = 89.0
    if case == "no-galileo-satellite":
        kw["sats"] = ["G01", "G02", "G03", "G04", "G05", "G06"]
    r = run_scenario(_gps_gal([fault], **kw))
    notes = [n for n in r.summary.notes if n.startswith("warning: fault GAL (constellation)")]
    assert len(notes) == 1 and "never acts" in notes[0] and why in notes[0], r.summary.notes
    assert r.summary.faulted_epochs == 0


# -- the verdict -----------------------------------------------------------------------------

def test_the_verdict_tells_a_constellation_fault():
    pytest.importorskip("plotly")
    from app import teaching
    from app.session import run_view

    s = _gps_gal([parse_fault("GAL,step,20,300")])
    r = run_scenario(s)
    text = teaching.verdict(run_view(r), r.summary, s.p_fa, faults=s.faults)
    assert text.startswith("Constellation fault on GAL (all its satellites) detected at t = ")
    # Parity excludes one satellite at a time: never the whole constellation.
    assert "of GAL excluded (its other satellites stay faulty)" in text
    assert "every one of its satellites" not in text
    # An algorithm that excludes the constellation gets it said.
    gal = np.array([n.startswith("E") for n in r.measurements.sat_names])
    excl = r.truth.faulted_epochs[:, None] & gal[None, :] & r.measurements.used
    out = dataclasses.replace(r.output, excluded=excl,
                              isolated=np.where(excl.any(-1), np.argmax(excl, -1), -1))
    r2 = dataclasses.replace(r, output=out, table=make_table(r.measurements, r.truth, out))
    text = teaching.verdict(run_view(r2), r2.summary, s.p_fa, faults=s.faults)
    assert "GAL excluded (every one of its satellites in view)" in text
    assert "HPE back to" in text and not math.isnan(r.summary.detection.value)
