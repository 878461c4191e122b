"""The dashboard's controls are made from the schema, never clip, never rewrite.

Headless and in-process: a live viser server; GUI handles are set, or their update
callbacks fired, from Python as a user's edit would, and the session's scenario is
compared with the preset it came from.
"""

from __future__ import annotations

import logging
import math

import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from viser import GuiEvent  # noqa: E402

from app.controls import FAULT_KEYS, KeyControl, control_kind  # noqa: E402
from raimcore import algorithms  # noqa: E402
from raimcore.scenario import list_scenarios, load_scenario, scenario_keys  # noqa: E402

WAIT_S = 120.0


@pytest.fixture()
def session(dash):
    from app.session import Session

    s = Session(dash.server, dash.start_scenario, dash.presets)
    _settle(s)
    yield s
    s.close()


def _settle(s):
    assert s.scheduler.wait_idle(WAIT_S)


def _touch(handle) -> None:
    """Fire ``handle``'s update callbacks with its value unchanged: what a user's edit
    that ends on the same value does (viser calls them on every message from the page)."""
    for cb in list(handle._impl.update_cb):
        cb(GuiEvent(client=None, client_id=None, target=handle))


def _open(session, name):
    session.preset.value = name
    _settle(session)
    assert session.scenario.name == name


def _assert_identical(session, preset, what):
    for got in (session.scenario, session.current_scenario()):
        assert got == preset, what
        assert got.to_dict() == preset.to_dict(), what


def _assert_shows(ctl: KeyControl, value, what):
    """The control shows ``value`` itself, inside its range (never clipped)."""
    h = ctl.handle
    assert ctl.value == value, what
    if ctl.kind in ("slider", "number") and ctl._encode is None:
        assert h.value == value, what
    if ctl.kind == "slider":
        assert h.min <= h.value <= h.max, what
    if ctl.kind in ("text", "dropdown", "checkbox"):
        assert ctl.shows_exactly, what


# -- 7a: touching every control without changing it leaves the scenario identical ----------

def touch_every_control(session, preset) -> None:
    """Fire every control's update callback with its own value (scenario controls, the
    algorithm and preset dropdowns, every option of the algorithm, every fault-editor
    control for every fault); after each, the session's scenario must still be ``preset``
    (== and ``to_dict()``), each keyed control must show its value unclipped, and nothing
    is re-run."""
    _assert_identical(session, preset, "before")
    n_runs = session.timing.n_recomputes

    # Scenario controls, the algorithm and the preset.
    for key, ctl in session.controls.items():
        _assert_shows(ctl, getattr(preset, key), key)
        _touch(ctl.handle)
        _assert_identical(session, preset, key)
    for handle in (session.algorithm, session.preset):
        _touch(handle)
        _settle(session)
        _assert_identical(session, preset, handle.label)

    # Every option of the preset's algorithm.
    options = preset.algorithm_options()
    assert set(session.option_controls) == set(algorithms.get(preset.algorithm).option_keys)
    for key, ctl in session.option_controls.items():
        _assert_shows(ctl, options[key], key)
        _touch(ctl.handle)
        _assert_identical(session, preset, key)

    # Every fault-editor control, for every fault.
    for k, fault in enumerate(preset.faults):
        session.fault_pick.value = session.fault_pick.options[k]
        assert session._fault_index == k
        fc = session.fault_controls
        assert session.fault_sat.value == fault.sat
        _assert_shows(fc["kind"], fault.kind, f"fault {k} kind")
        size = "bias_m" if fault.kind == "step" else "rate_mps"
        _assert_shows(fc[size], getattr(fault, size), f"fault {k} {size}")
        _assert_shows(fc["t0_s"], fault.t0_s, f"fault {k} t0_s")
        t1 = session.fault_t1
        assert fc["t1_s"].value == fault.t1_s
        assert t1.value == (t1.max if fault.t1_s == math.inf else fault.t1_s)
        for handle in (session.fault_pick, session.fault_sat,
                       *(c.handle for c in fc.values())):
            _touch(handle)
            _assert_identical(session, preset, f"fault {k} {handle.label}")
    _settle(session)
    assert session.timing.n_recomputes == n_runs  # nothing changed: nothing re-run
    assert not session.status.content.startswith("**Error")


@pytest.mark.parametrize("name", list_scenarios())
def test_touching_every_control_leaves_the_preset_identical(session, name):
    preset = load_scenario(name)
    _open(session, name)
    touch_every_control(session, preset)


# -- the bugs of issue 13 -------------------------------------------------------------------

def test_nudging_fault_start_keeps_the_660_m_faults(session):
    _open(session, "seed004-multi")
    assert session.fault_bias.value == 660.0 and session.fault_bias.max >= 660.0
    session.fault_t0.value = 61.0  # fault #1 starts at 60 s
    _settle(session)
    faults = session.result.scenario.faults
    assert [f.bias_m for f in faults] == [660.0, 660.0, 660.0]
    assert faults[0].t0_s == 61.0
    expect = load_scenario("seed004-multi").faults
    assert faults[1:] == expect[1:]


def test_large_and_negative_biases_are_shown_and_kept(session):
    _open(session, "seed001-fault")
    assert session.fault_bias.value == 1000.0  # the slider widened, not clipped
    assert session.fault_bias.min <= 1000.0 <= session.fault_bias.max
    session.fault_bias.value = -70.0  # typed in the slider's box
    _settle(session)
    assert session.scenario.faults[0].bias_m == -70.0
    assert session.fault_bias.min <= -70.0
    session.fault_t0.value = 2001.0  # another edit keeps the bias
    _settle(session)
    (f,) = session.result.scenario.faults
    assert (f.bias_m, f.t0_s) == (-70.0, 2001.0)
    # A negative ramp rate, too.
    session.fault_kind.value = "ramp"
    session.fault_rate.value = -3.5
    _settle(session)
    (f,) = session.result.scenario.faults
    assert (f.kind, f.rate_mps) == ("ramp", -3.5)


@pytest.mark.parametrize(("control", "bad", "key"), [
    ("sigma", 0.0, "sigma_m"), ("seed", -3, "seed"), ("p_fa", "0", "p_fa"),
    ("p_fa", "abc", "p_fa"), ("mask", 95.0, "mask_deg"), ("noise_corr", -5.0, "noise_corr_s"),
    ("fault_bias", 2e7, "bias_m"), ("fault_rate", -2e5, "rate_mps"),
])
def test_an_invalid_entry_is_refused_in_one_line_and_changes_nothing(session, caplog,
                                                                      control, bad, key):
    before = session.scenario
    handle = getattr(session, control)
    shown = handle.value
    n_runs = session.timing.n_recomputes
    with caplog.at_level(logging.DEBUG):
        handle.value = bad
        _settle(session)
    status = session.status.content
    assert status.startswith("**Error:**") and key in status and "\n" not in status
    assert session.scenario is before
    assert handle.value == shown  # the control is back at the last valid value
    assert session.timing.n_recomputes == n_runs
    assert not any(r.exc_info for r in caplog.records), "a traceback was logged"
    # And the session goes on: a valid entry is taken.
    session.sigma.value = 4.0
    _settle(session)
    assert session.result.scenario.sigma_m == 4.0 and "update" in session.status.content


def test_a_fault_start_after_its_end_is_refused(session):
    _open(session, "seed000-step")  # G03 step 20 s..80 s
    session.fault_t0.value = 90.0
    _settle(session)
    assert "fault G03 t1_s must be after t0_s" in session.status.content
    assert session.scenario.faults == load_scenario("seed000-step").faults
    assert session.fault_t0.value == 20.0
    session.fault_t1.value = session.fault_t1.max  # the right end: until the end
    _settle(session)
    assert session.result.scenario.faults[0].t1_s == math.inf
    session.fault_t0.value = 90.0
    _settle(session)
    assert session.result.scenario.faults[0].t0_s == 90.0


def test_a_value_beyond_the_usual_range_widens_the_slider(session):
    session.sigma.value = 80.0  # usual range 0.1-50 m (the key's ui range)
    _settle(session)
    assert session.result.scenario.sigma_m == 80.0
    assert session.sigma.max == 80.0 and session.sigma.value == 80.0
    session.sigma.value = 5.0
    _settle(session)
    assert session.sigma.max == 80.0  # the user's slider keeps its range while in use
    _open(session, "seed000-step")  # a new scenario: the usual range again
    assert session.sigma.max == scenario_keys()["sigma_m"].ui_hi


# -- controls made from the schema ---------------------------------------------------------

def _every_key():
    keys = scenario_keys()
    out = [keys[n] for n in ("sigma_m", "noise_corr_s", "p_fa", "mask_deg", "seed")]
    out += [k for name in algorithms.names() for k in algorithms.get(name).options]
    return out + list(FAULT_KEYS.values())


@pytest.mark.parametrize("key", _every_key(), ids=lambda k: k.name)
def test_each_control_takes_range_step_help_and_choices_from_its_key(dash, key):
    ctl = KeyControl(dash.server.gui, key, key.default)
    try:
        h = ctl.handle
        assert key.help in h.hint
        kind = control_kind(key)
        assert kind == {"bool": "checkbox", "choice": "dropdown"}.get(key.kind, kind)
        if kind == "dropdown":
            assert tuple(h.options) == key.choices
        if kind == "slider":
            lo = key.ui_lo if key.ui_lo is not None else key.lo
            hi = key.ui_hi if key.ui_hi is not None else key.hi
            assert (h.min, h.max) == (min(lo, key.default), max(hi, key.default))
            if key.ui_step is not None:
                assert h.step == key.ui_step
        if kind == "number":
            if key.lo is not None and not key.lo_open:
                assert h.min == key.lo
            if key.hi is not None and not key.hi_open:
                assert h.max == key.hi
        if key.kind not in ("custom",):
            assert ctl.read() == key.default  # shown and read back unchanged
        if kind == "text" and key.kind == "float":
            h.value = "1e-5"  # a probability typed as a user would
            assert ctl.read() == 1e-5
    finally:
        ctl.remove()


def test_option_controls_follow_the_algorithm_and_refuse_bad_entries(session):
    session.algorithm.value = "pf-llr"
    _settle(session)
    oc = session.option_controls
    assert control_kind(oc["tau"].key) == "text" and oc["tau"].handle.value == "auto"
    assert tuple(oc["model"].handle.options) == ("static", "cv")
    oc["window"].handle.value = 0  # window >= 1
    _settle(session)
    assert "window" in session.status.content and session.scenario.option("window") is None
    assert oc["window"].handle.value == 30
    oc["tau"].handle.value = "12.5"
    _settle(session)
    assert session.scenario.option("tau") == 12.5
    oc["tau"].handle.value = "soon"
    _settle(session)
    assert "tau" in session.status.content and session.scenario.option("tau") == 12.5
    assert oc["tau"].handle.value == "12.5"
