"""Four constellations everywhere (issue 15 item 3): GPS, BeiDou, Galileo and GLONASS in
simulated scenarios (every registered algorithm, each system alone), almanacs of another
system, Monte Carlo geometries and ``raim compare``; one receiver clock per system."""

from __future__ import annotations

import numpy as np
import pytest
from test_constellations import NAVCEN_862_SEM, NAVCEN_862_YUMA

from raimcore import algorithms
from raimcore.cli import main
from raimcore.measure.faults import Fault
from raimcore.pipeline import run_scenario
from raimcore.scenario import SYSTEMS, load_scenario
from raimcore.schema import SchemaError
from raimcore.sky import build_sky
from raimcore.sky.simulated import almanac_system
from raimcore.studies import montecarlo as mc

ALL_FOUR = ["GPS", "GAL", "GLO", "BDS"]
# Each system's receiver clock starts at its own random offset (up to 300 km, the measure
# stage); a satellite given the clock of another system would be off by hundreds of km.
# With sigma 3 m, a fault-free position is within tens of metres.
FAULT_FREE_HPE_M = 30.0
STEP_M = 500.0  # a step fault no algorithm can miss at sigma 3 m


def _short(systems, **over):
    """The default scenario's site, 20 s every 2 s, sigma 3 m, no fault unless given."""
    return load_scenario("default", **{"systems": systems, "duration_s": 20.0, "step_s": 2.0,
                                       "sigma_m": 3.0, "faults": [], **over})


def test_every_system_has_a_key_and_a_letter():
    assert SYSTEMS == {"GPS": "G", "BDS": "C", "GAL": "E", "GLO": "R"}


@pytest.fixture(scope="module")
def four_systems_faulted():
    """A short four-system scenario with a step on a Galileo satellite from t = 10 s."""
    return _short(ALL_FOUR, faults=[Fault("E02", "step", t0_s=10.0, bias_m=STEP_M)])


@pytest.mark.parametrize("name", algorithms.names())
def test_every_algorithm_runs_on_four_systems(four_systems_faulted, name):
    r = run_scenario(four_systems_faulted.replace(algorithm=name))
    m, t = r.measurements, r.table
    assert set(m.systems) == set(ALL_FOUR)
    # sys_idx gives every satellite the clock of its own system.
    assert all(n[0] == SYSTEMS[m.systems[k]] for n, k in zip(m.sat_names, m.sys_idx,
                                                              strict=True))
    used = m.used[0]
    assert {SYSTEMS[m.systems[k]] for k in m.sys_idx[used]} == set("GECR")
    assert not np.any(t["status"] == "unavailable")
    clean = (t["faulty_truth"] == "") & (t["status"] == "ok")
    assert np.nanmax(t["hpe_before_m"][clean], initial=0.0) < FAULT_FREE_HPE_M, name
    faulted = (t["faulty_truth"] == "E02") & (t["status"] == "ok")
    if faulted.any():  # filters still arming after 20 s have no "ok" epoch to judge
        assert t["alarm"][faulted].all(), name


@pytest.mark.parametrize("system", ["GAL", "GLO", "GPS", "BDS"])
def test_one_system_alone(system):
    s = _short([system])
    r = run_scenario(s)
    m, t = r.measurements, r.table
    assert m.systems == (system,)
    assert all(n.startswith(SYSTEMS[system]) for n in m.sat_names)
    assert not np.any(t["status"] == "unavailable")
    assert not t["alarm"].any()
    assert np.nanmax(t["hpe_before_m"]) < FAULT_FREE_HPE_M
    sat = next(n for n, u in zip(m.sat_names, m.used[0], strict=True) if u)
    faulted = run_scenario(s.with_faults(Fault(sat, "step", t0_s=10.0, bias_m=STEP_M)))
    ft = faulted.table
    assert ft["alarm"][ft["faulty_truth"] == sat].all()


def test_a_satellite_of_a_system_not_chosen_is_refused():
    with pytest.raises(SchemaError, match="'E02' is not of the chosen systems"):
        _short(["GPS", "GLO"], faults=[Fault("E02", bias_m=50.0)])
    s = _short(["GPS", "GLO"], faults=[Fault("R03", bias_m=50.0)])
    assert s.faults[0].sat == "R03"


# -- almanacs -------------------------------------------------------------------------------

def _galileo_yuma(text: str) -> str:
    """The NAVCEN YUMA records moved to Galileo's orbit (sqrt(A) 5440.6 m^1/2)."""
    import re

    return re.sub(r"(SQRT\(A\)  \(m 1/2\): +)\S+", r"\g<1>5440.600000", text)


def test_sem_almanac_as_the_constellation(tmp_path):
    p = tmp_path / "current.al3"
    p.write_text(NAVCEN_862_SEM)
    s = load_scenario("default", constellation=str(p), faults=[], t_start_s=319488.0,
                      duration_s=10.0)
    sky = build_sky(s)
    assert sky.sat_names == ("G01", "G02", "G13", "G32")
    # PRNs 13 and 32 have health 63 in the almanac: never trackable.
    assert sky.trackable[:, :2].any() and not sky.trackable[:, 2:].any()


def test_almanac_system_is_told_by_its_orbits(tmp_path):
    gps, gal = tmp_path / "gps.alm", tmp_path / "gal.alm"
    gps.write_text(NAVCEN_862_YUMA)
    gal.write_text(_galileo_yuma(NAVCEN_862_YUMA))
    from raimcore.sky.constellations import read_almanac

    assert almanac_system(read_almanac(gps)) == "GPS"
    assert almanac_system(read_almanac(gal)) == "GAL"
    # A Galileo almanac in a GPS scenario: refused in one line, naming what to add.
    with pytest.raises(SchemaError) as exc:
        load_scenario("default", constellation=str(gal), faults=[])
    msg = str(exc.value)
    assert "\n" not in msg
    for word in ("constellation", str(gal), "Galileo almanac", "29,6", 'add "GAL"'):
        assert word in msg, msg
    # In a Galileo scenario its satellites are E01...
    s = load_scenario("default", systems=["GAL"], constellation=str(gal), faults=[],
                      duration_s=10.0)
    sky = build_sky(s)
    assert sky.sat_names == ("E01", "E02", "E13", "E32") and sky.systems == ("GAL",)
    # ... propagated on Galileo's orbit (a = 29,600 km).
    r = np.linalg.norm(sky.pos_sv_ecef_m, axis=-1)
    assert np.all(np.abs(r / 5440.6**2 - 1.0) < 0.02)
    # A GPS almanac in a GPS + GAL scenario: the run says Galileo has no satellite.
    mixed = load_scenario("default", systems=["GPS", "GAL"], constellation=str(gps),
                          faults=[], t_start_s=319488.0, duration_s=10.0)
    assert any("GPS almanac" in n and "GAL" in n for n in build_sky(mixed).notes)


def test_almanac_of_no_known_orbit_is_refused(tmp_path):
    import re

    p = tmp_path / "odd.alm"
    p.write_text(re.sub(r"(SQRT\(A\)  \(m 1/2\): +)\S+", r"\g<1>6000.000000",
                        NAVCEN_862_YUMA))
    with pytest.raises(SchemaError) as exc:
        load_scenario("default", constellation=str(p), faults=[])
    assert "cannot tell which system" in str(exc.value) and "36,000 km" in str(exc.value)


# -- Monte Carlo and compare ----------------------------------------------------------------

def test_random_geometry_of_four_systems():
    systems = ("GPS", "GAL", "GLO", "BDS")
    h, sys_idx = mc.random_geometry(np.random.default_rng(1), 200, 16, systems=systems)
    assert h.shape == (200, 16, 7)
    np.testing.assert_array_equal(h[..., 3:].argmax(-1), sys_idx)
    np.testing.assert_array_equal(h[..., 3:].sum(-1), 1.0)
    for j in range(4):
        assert np.all((sys_idx == j).sum(-1) >= 2)
    # The default is seed 004's GPS + BDS, draw for draw.
    a = mc.random_geometry(np.random.default_rng(2), 50, 14)
    b = mc.random_geometry(np.random.default_rng(2), 50, 14, systems=("GPS", "BDS"))
    np.testing.assert_array_equal(a[0], b[0])


def test_study_of_four_systems_uses_seven_states():
    st = mc.Study(n_visible=(14,), n_faults=(1,), bias=(1.5,), algorithms=("parity",),
                  runs=100, systems=("GPS", "GAL", "GLO", "BDS"))
    assert st.n_states == 7
    assert st.unit_m(14) == pytest.approx(mc.p_bias_m(14, 33.0, st.p_fa, st.p_md, 7))
    assert st.unit_m(14) < mc.Study().unit_m(14)  # fewer degrees of freedom: smaller P_bias
    res = mc.run_study(st, progress=False)
    assert res.rows[0]["rate"] > 0.5
    with pytest.raises(ValueError, match="systems must be"):
        mc.Study(systems=("GPS", "QZS"))


def test_compare_on_four_systems(tmp_path):
    out = tmp_path / "cmp.json"
    assert main(["compare", "default", "--set", 'systems=["GPS","GAL","GLO","BDS"]',
                 "--set", "duration_s=20", "--set", "step_s=2", "--set", "sigma_m=3",
                 "--algorithms", "parity,mss,ekf", "--fault", "E02,step,500,10",
                 "--out", str(out)]) == 0
    import json

    rows = {r["algorithm"]: r for r in json.loads(out.read_text())}
    assert set(rows) == {"parity", "mss", "ekf"}
    for r in rows.values():
        assert r["detection_rate"] == 1.0 and r["correct_isolation_rate"] == 1.0
        assert r["false_alarm_rate"] == 0.0
