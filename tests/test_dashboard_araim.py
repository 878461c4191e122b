"""The ARAIM parts of the dashboard (issue 16, item 6): the ISM folder, the "Fault modes
now" panel, and why lesson 13's scenario under the B2012 rules has infinite protection
levels. Headless: sessions on an in-process viser server, handles set from Python."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from app import araim_modes, panels  # noqa: E402
from app.ism_controls import format_probability, uses_ism, with_ism_field  # noqa: E402
from app.lessons import load_lesson  # noqa: E402
from raimcore.pipeline import run_scenario  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402
from raimcore.schema import SchemaError  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LESSON_13 = ROOT / "app" / "lessons" / "13-araim-fault-modes.md"
WAIT_S = 60.0
#: Epochs of the built-in ``araim`` scenario before and during its 50 m Galileo
#: constellation fault (from t = 300 s).
BEFORE_FAULT, DURING_FAULT = 100, 350


def _settle(s):
    assert s.scheduler.wait_idle(WAIT_S)


@pytest.fixture(scope="module")
def lesson13():
    return load_lesson(LESSON_13).scenario()


@pytest.fixture(scope="module")
def araim_result():
    return run_scenario(load_scenario("araim"))


# -- item 3: the B2012 infinities of lesson 13 ---------------------------------------------

def test_lesson13_under_b2012_is_infinite_because_of_the_galileo_exclusion(lesson13):
    """B2012 monitors every constellation (N_const,max = 1), the GPS one too (P_const
    1e-8). With exclusion, the candidate "exclude GAL" leaves only GPS, where the GPS
    constellation mode removes every satellite left: unmonitorable, it spends its prior
    1e-8 of that candidate's budget rho PHMI_V' = (1/16) 9.8e-8 (1 - P_nm / 1e-7) =
    3.9e-9, so the VPL is infinite. Not P_nm: it is 3.6e-8, under the budget."""
    res = run_scenario(lesson13.replace(araim_rules="blanch-2012"))
    c = res.table.columns
    assert np.all(c["n_modes"] == 16)
    assert np.all(c["p_not_monitored"] < 1e-7)
    assert np.all(np.isinf(c["vpl_m"])) and np.all(np.isinf(c["hpl_m"]))
    assert set(c["pl_set_by"]) == {"GAL"}
    (note,) = set(c["pl_note"])
    assert "excluding GAL" in note and "3.9e-09" in note and "araim_fde = false" in note
    assert "," not in note  # a column of the CSV the dashboard writes unquoted
    # Detection only: no candidate, finite PLs and no note.
    fd = run_scenario(lesson13.replace(araim_rules="blanch-2012", araim_fde=False))
    assert np.all(np.isfinite(fd.table.columns["vpl_m"]))
    assert set(fd.table.columns["pl_note"]) == {""}
    # The threshold is the candidate's budget: a GPS P_const under 3.9e-9 gives a finite
    # VPL, over it an infinite one.
    ism = lesson13.ism.to_dict()
    for p_const, finite in ((3e-9, True), (5e-9, False)):
        ism["GPS"]["p_const"] = p_const
        r = run_scenario(lesson13.replace(araim_rules="blanch-2012", ism=ism))
        assert np.all(np.isfinite(r.table.columns["vpl_m"])) == finite, p_const


def test_add_rules_say_which_candidate_sets_the_pls_and_have_no_note(lesson13):
    c = run_scenario(lesson13).table.columns
    assert np.all(np.isfinite(c["vpl_m"]))
    assert set(c["pl_note"]) == {""}
    names = set(run_scenario(lesson13).measurements.sat_names)
    assert set(c["pl_set_by"]) <= names | {"GPS", "GAL", ""}


def test_kernel_names_the_candidate_that_gives_the_vpl():
    """vpl_set_by: the event index (original satellite order; constellations after the
    satellites) of the candidate that gave the VPL, -1 for the all-in-view."""
    from raimcore import araim

    rng = np.random.default_rng(3)
    n = 11
    el = rng.uniform(0.2, 1.4, n)
    az = rng.uniform(0, 2 * np.pi, n)
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    cons = np.array([0] * 6 + [1] * 5)  # in view: 5 GPS, 5 Galileo
    g = np.concatenate([-u, np.eye(2)[cons]], axis=1)
    g[0] = np.nan  # satellite 0 not in view: indices stay those of the input rows
    sig, zeros = np.full(n, 1.5), np.zeros(n)
    p_sat = np.full(n, 1e-5)
    fd = araim.mhss(g, sig, sig, zeros, zeros, p_sat, [1e-8, 1e-4])
    assert fd.vpl_set_by is None  # no exclusion, no candidates
    # Excluding Galileo (P_const 1e-4 > 1e-7) leaves the 5 GPS satellites, where the GPS
    # constellation mode is unmonitorable; with B2012 rules it is monitored (prior 1e-8
    # over that candidate's budget): the VPL is infinite and the candidate is GAL,
    # event n + 1. (Excluding one satellite leaves that mode 4 satellites: monitorable.)
    b12 = araim.mhss(g, sig, sig, zeros, zeros, p_sat, [1e-8, 1e-4], fde=True,
                     rules="blanch-2012")
    assert np.isinf(b12.vpl_m) and int(b12.vpl_set_by) == n + 1
    # A GPS constellation prior under the budget: finite, set by a candidate or not.
    ok = araim.mhss(g, sig, sig, zeros, zeros, p_sat, [1e-10, 1e-4], fde=True,
                    rules="blanch-2012")
    assert np.isfinite(ok.vpl_m) and int(ok.vpl_set_by) != n + 1
    # Four GPS satellites: every single-satellite mode is unmonitorable, P_nm (4e-5)
    # uses up the budget of the all-in-view itself, which is then the one named (-1).
    g4 = g.copy()
    g4[5:] = np.nan
    four = araim.mhss(g4[:, :4], sig, sig, zeros, zeros, p_sat, [1e-8], fde=True)
    assert four.p_not_monitored > 1e-7
    assert np.isinf(four.vpl_m) and int(four.vpl_set_by) == -1


# -- item 2: the fault-mode panel, pure ----------------------------------------------------

def test_fault_mode_panel_is_offered_for_araim_only(araim_result):
    from app.session import run_view

    assert "araim_modes" in [k for k, _ in panels.panels_for(run_view(araim_result))]
    parity = run_scenario(load_scenario("default", duration_s=30.0))
    assert "araim_modes" not in [k for k, _ in panels.panels_for(run_view(parity))]


def test_fault_mode_panel_shows_each_epochs_modes_and_alarms(araim_result):
    from app.session import run_view

    view = run_view(araim_result)
    fig = araim_modes.fault_modes_figure(view)
    assert fig.data == []  # everything is per epoch: sent with the time updates
    before, during = fig.time_state(BEFORE_FAULT), fig.time_state(DURING_FAULT)
    assert before["rev"] == during["rev"]  # same figure, only the time part differs
    n_modes = int(araim_result.table.columns["n_modes"][DURING_FAULT])
    assert during["layout"]["title"]["text"] == f"Fault modes now: {n_modes} monitored"
    assert "P_nm 4.1e-8" in during["layout"]["title"]["subtitle"]["text"]
    assert "0 alarms" in before["layout"]["title"]["subtitle"]["text"]
    assert "1 alarm" in during["layout"]["title"]["subtitle"]["text"]
    # The Galileo constellation mode (prior 2e-4) alarms during the fault, vertically.
    vert = during["traces"][0]
    gal = [k for k, y in enumerate(vert["y"]) if y.startswith("GAL ")]
    assert len(gal) == 1 and vert["y"][gal[0]] == "GAL · 2.0e-4"
    assert vert["marker"]["color"][gal[0]] == araim_modes.ALARM_COLOR
    assert vert["x"][gal[0]] > 1.0
    assert before["traces"][0]["marker"]["color"].count(araim_modes.ALARM_COLOR) == 0
    # The bars are the separations over the thresholds of the run's mode table.
    ex = view.extras
    k = np.flatnonzero(ex["mode_monitored"][BEFORE_FAULT])
    want = (np.abs(ex["mode_separation_m"][BEFORE_FAULT, k, 2])
            / ex["mode_threshold_m"][BEFORE_FAULT, k, 2])
    np.testing.assert_allclose(before["traces"][0]["x"], want, atol=1e-4)
    assert len(json.dumps(during)) < 4000  # a time step stays small
    fig.to_plotly(DURING_FAULT)  # a valid plotly figure


def test_fault_mode_panel_says_why_pls_are_infinite(lesson13):
    from app.session import run_view

    view = run_view(run_scenario(lesson13.replace(araim_rules="blanch-2012")))
    st = araim_modes.fault_modes_figure(view).time_state(10)
    (note,) = st["layout"]["annotations"]
    assert "infinite" in note["text"] and "GAL" in note["text"]


def test_mode_ratios_edge_cases():
    sep = np.array([[0.0, 3.0, 2.0], [1.0, 0.0, np.nan], [0.0, 0.0, 0.0]])
    thr = np.array([[1.0, 1.0, 4.0], [0.0, 2.0, 1.0], [0.0, 0.0, 0.0]])
    v, h = araim_modes.mode_ratios(sep, thr)
    np.testing.assert_array_equal(v[:1], [0.5])
    assert np.isnan(v[1]) and v[2] == 0.0
    np.testing.assert_array_equal(h, [3.0, np.inf, 0.0])


# -- item 1: the ISM helpers ---------------------------------------------------------------

def test_ism_field_edit_keeps_the_rest_and_refuses_in_one_line(lesson13):
    s = with_ism_field(lesson13, "GAL", "p_const", 1e-8)
    assert s.ism["GAL"].p_const == 1e-8
    assert s.ism["GPS"].sigma_ura_m == 1.0  # the lesson's custom GPS entry is kept
    with pytest.raises(SchemaError, match=r"ism\.GAL\.p_sat") as err:
        with_ism_field(lesson13, "GAL", "p_sat", 0.5)
    assert "\n" not in str(err.value)
    assert [format_probability(p) for p in (2e-4, 1.02e-4, 1e-8, 0.0)] == \
        ["2e-04", "1.02e-04", "1e-08", "0e+00"]
    assert float(format_probability(1.0 / 3e5)) == 1.0 / 3e5
    assert uses_ism(lesson13) and not uses_ism(load_scenario("default"))
    assert uses_ism(load_scenario("default", error_model="araim"))


# -- the live session ----------------------------------------------------------------------

@pytest.fixture()
def araim_session(dash):
    from app.session import Session

    s = Session(dash.server, load_scenario("araim"), dash.presets)
    _settle(s)
    yield s
    s.close()


def _gal(session):
    ism = session.ism_controls
    ism.system.value = "GAL"
    _settle(session)
    return ism


def test_ism_controls_edit_the_scenario_and_recompute(araim_session):
    s = araim_session
    ism = s.ism_controls
    assert ism.folder.visible
    assert list(ism.system.options) == ["GPS", "GAL"]
    assert ism.controls["p_sat"].handle.value == "1e-05"  # GPS, scientific notation
    _gal(s)
    assert ism.controls["p_const"].handle.value == "2e-04"
    assert ism.controls["sigma_ura_m"].handle.value == 6.0
    n_before = int(s.result.table.columns["n_modes"][0])
    # Galileo's constellation fault made as unlikely as GPS's: no longer monitored alone.
    ism.controls["p_const"].handle.value = "1e-8"
    _settle(s)
    assert s.scenario.ism["GAL"].p_const == 1e-8 == s.result.scenario.ism["GAL"].p_const
    assert s.scenario.ism["GPS"].p_const == 1e-8  # GPS untouched
    n_after = int(s.result.table.columns["n_modes"][0])
    assert n_after == n_before - 1
    title = s.page.last_state["dyn"]["araim_modes"]["layout"]["title"]["text"]
    assert title == f"Fault modes now: {n_after} monitored"
    vpl0 = s.result.table.columns["vpl_m"].copy()
    ism.controls["sigma_ura_m"].handle.value = 2.0  # a number box
    _settle(s)
    assert s.scenario.ism["GAL"].sigma_ura_m == 2.0
    assert not np.allclose(vpl0, s.result.table.columns["vpl_m"])


def test_a_refused_ism_value_reverts_and_says_why(araim_session):
    s = araim_session
    ism = _gal(s)
    before = s.scenario
    ism.controls["p_sat"].handle.value = "0.5"
    _settle(s)
    assert s.status.content.startswith("**Error:**") and "ism.GAL.p_sat" in s.status.content
    assert ism.controls["p_sat"].handle.value == "3e-05"
    assert s.scenario is before
    ism.controls["p_sat"].handle.value = "not a number"
    _settle(s)
    assert "ism.GAL.p_sat" in s.status.content and s.scenario is before


def test_picking_a_system_shows_it_and_edits_nothing(araim_session):
    s = araim_session
    ism = s.ism_controls
    before, n = s.scenario, s.timing.n_recomputes
    _gal(s)
    assert ism.controls["sigma_ure_m"].handle.value == 4.0
    ism.system.value = "GPS"
    _settle(s)
    assert ism.controls["sigma_ure_m"].handle.value == 2.4
    assert s.scenario is before and s.timing.n_recomputes == n


def test_a_scenario_with_a_custom_ism_shows_it_and_the_folder_follows_araim(araim_session,
                                                                             lesson13):
    s = araim_session
    ism = s.ism_controls
    ism.system.value = "GPS"
    _settle(s)
    s.open_scenario(lesson13)
    _settle(s)
    assert ism.controls["sigma_ura_m"].handle.value == 1.0
    assert ism.controls["sigma_ure_m"].handle.value == 0.66
    assert s.scenario is lesson13 or s.scenario == lesson13  # showing it changed nothing
    s.algorithm.value = "parity"
    _settle(s)
    assert not ism.folder.visible  # parity with a uniform error model: no ISM used
    s.controls["error_model"].handle.value = "araim"
    _settle(s)
    assert ism.folder.visible


def test_fault_mode_panel_follows_the_time_slider_without_resending(araim_session):
    s = araim_session
    assert "araim_modes" in s.figures
    sent = s.plot_handles["araim_modes"]._plotly_json_str
    s.time.value = float(BEFORE_FAULT)
    _settle(s)
    dyn = s.page.last_state["dyn"]["araim_modes"]
    assert "0 alarms" in dyn["layout"]["title"]["subtitle"]["text"]
    assert f"t {BEFORE_FAULT} s" in dyn["layout"]["title"]["subtitle"]["text"]
    s.time.value = float(DURING_FAULT)
    _settle(s)
    dyn = s.page.last_state["dyn"]["araim_modes"]
    assert "1 alarm" in dyn["layout"]["title"]["subtitle"]["text"]
    assert araim_modes.ALARM_COLOR in dyn["traces"][0]["marker"]["color"]
    assert s.plot_handles["araim_modes"]._plotly_json_str is sent  # no figure re-sent
