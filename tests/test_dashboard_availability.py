"""The dashboard's availability map (:mod:`app.availability_view`), driven headless: a
session of the in-process server whose controls are set from Python, as a user would."""

from __future__ import annotations

import gc
import html
import json
import sys
import threading
import time
import weakref
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from app import page  # noqa: E402
from app.availability_view import (  # noqa: E402
    MAX_USER_EPOCHS,
    THREAD_NAME,
    n_user_epochs,
    panel_figure,
    study_kwargs,
)
from raimcore.studies.availability import availability  # noqa: E402

WAIT_S = 60.0
#: A grid of 8 users x 4 epochs: finishes in well under a second.
TINY = {"grid_step_deg": 90.0, "duration_h": 2.0, "t_step_s": 1800.0}
#: A grid that runs for tens of seconds (648 users x 288 epochs): long enough to act on
#: while it runs; every test stops it.
LONG = {"grid_step_deg": 10.0, "duration_h": 24.0, "t_step_s": 300.0}


@pytest.fixture()
def session(dash):
    from app.session import Session

    s = Session(dash.server, dash.start_scenario, dash.presets)
    assert s.scheduler.wait_idle(WAIT_S)
    yield s
    s.close()


def _set(view, values: dict) -> None:
    """Enter ``values`` in the view's controls, as a user would."""
    for name, value in values.items():
        view.controls[name].handle.value = value
        assert view.controls[name].value == value, view.message_md.content


def _wait(pred, timeout_s: float = WAIT_S) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def _map_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == THREAD_NAME]


def test_a_tiny_grid_runs_to_completion_and_equals_the_study(session):
    view = session.availability_view
    _set(view, TINY)
    assert view.run()
    assert view.wait(WAIT_S)
    res = view.result
    direct = availability(("GPS", "GAL"), lat_step_deg=90.0, lon_step_deg=90.0,
                          t_step_s=1800.0, duration_s=7200.0, ism="b2012",
                          user_model="ed259a")
    assert res is not None and res.n_user_epochs == direct.n_user_epochs == 8 * 4
    for name in ("availability", "vpl_median_m", "vpl_p99_m", "hpl_median_m"):
        np.testing.assert_array_equal(getattr(res, name), getattr(direct, name))
    assert res.coverage_pct == direct.coverage_pct
    # The map on the page is the study's map, fitted to the panel.
    assert view.figure == panel_figure(direct)
    sent = json.loads(view.plot_handle._plotly_json_str)
    assert sent["data"][0]["z"] == panel_figure(direct)["data"][0]["z"]
    # Sized like the other panels: drawn at its declared height in the plot panel.
    assert view.plot_handle.aspect == page.plot_aspect(view.figure["layout"]["height"],
                                                       session.plots_px)
    # Summary: coverage (cos-lat weighted) and the VPL statistics of the direct call.
    for line in direct.summary_lines()[1:]:
        assert html.escape(line) in view.summary_md.content
    assert view.progress == (32, 32)
    assert view.progress_md.content.startswith("32 of 32 user-epochs, ")
    assert view.progress_bar.value == 100.0
    assert not view.run_button.disabled and view.cancel_button.disabled
    assert not _map_threads()


def test_cancel_stops_a_run_and_the_session_stays_responsive(session):
    view = session.availability_view
    _set(view, LONG)
    assert view.run()
    assert _wait(lambda: view.progress[0] > 0)  # the study reports between batches
    assert not view.cancel_button.disabled
    assert view.run_button.disabled
    # A second Run while one runs is refused, and the first goes on.
    first = view._thread
    assert not view.run()
    assert "already running" in view.message_md.content and view._thread is first
    # The session's own controls still recompute while the map runs.
    session.sigma.value = 6.5
    assert session.scheduler.wait_idle(WAIT_S)
    assert session.result.scenario.sigma_m == 6.5
    assert view.running, "the long map ended before the test could cancel it"
    done_at_cancel = view.progress[0]
    assert view.cancel()
    assert view.wait(10.0), "Cancel did not stop the map"
    total = n_user_epochs(study_kwargs(view.values))
    assert view.progress[0] < total and view.progress[1] == total
    assert view.progress[0] >= done_at_cancel
    assert view.result is None and view.figure is None  # no map from a cancelled run
    assert "Cancelled after" in view.message_md.content
    assert not view.run_button.disabled and view.cancel_button.disabled
    assert not view.cancel()  # nothing to cancel any more
    assert not _map_threads()


def test_closing_the_tab_during_a_run_leaves_no_thread(dash):
    from app.session import Session

    s = Session(dash.server, dash.start_scenario, dash.presets)
    view = s.availability_view
    _set(view, LONG)
    assert view.run()
    assert _wait(lambda: view.progress[0] > 0)
    thread = view._thread
    t0 = time.monotonic()
    s.close()
    assert not thread.is_alive() and not _map_threads()
    assert time.monotonic() - t0 < 10.0
    assert view.result is None and view._session is None
    assert not view.run()  # a late click on a closed tab starts nothing
    assert not _map_threads()


def test_bad_inputs_are_refused_in_one_line_and_the_controls_keep_their_values(session):
    view = session.availability_view
    _set(view, {"grid_step_deg": 45.0})
    # A bad entry: the control shows the last valid value again, one line says why.
    sys_ctl = view.controls["systems"]
    for text, why in (("GPS, XYZ", "XYZ"), ("GPS GPS", "each once"), ("", "none")):
        view.message_md.content = ""
        sys_ctl.handle.value = text
        assert sys_ctl.value == ("GPS", "GAL") and sys_ctl.handle.value == "GPS, GAL"
        msg = view.message_md.content
        assert "systems" in msg and why in msg and "\n" not in msg
    for name, bad, allowed in (("grid_step_deg", 0.0, "[1, 90] deg"),
                               ("duration_h", 0.0, "(0, 240] h"),
                               ("t_step_s", -60.0, "[1, 86400] s")):
        ctl = view.controls[name]
        kept = ctl.value
        ctl.handle.value = bad
        assert ctl.value == kept and ctl.handle.value == kept
        assert f"{name} must be in {allowed}" in view.message_md.content
    assert view.controls["grid_step_deg"].value == 45.0
    # Valid entries that together make too large a map: Run is refused, nothing starts,
    # and every control keeps what the user set.
    big = {"grid_step_deg": 1.0, "duration_h": 24.0, "t_step_s": 60.0}
    _set(view, big)
    assert n_user_epochs(study_kwargs(view.values)) > MAX_USER_EPOCHS
    assert not view.run()
    assert "user-epochs" in view.message_md.content and "\n" not in view.message_md.content
    assert not view.running and view._thread is None and not _map_threads()
    for name, value in big.items():
        assert view.controls[name].value == value
        assert view.controls[name].handle.value == value


def _run_in_a_tab(dash, client, known) -> weakref.ref:
    """In the tab of ``client``: a tiny map typed and clicked in the page, then a long
    one left running. Returns a weak reference to the tab's session."""
    (s,) = [x for x in dash.wait_for_sessions(len(known) + 1) if x not in known]
    assert s.scheduler.wait_idle(WAIT_S)
    view = s.availability_view
    for name, value in TINY.items():
        client.set_value(view.controls[name].handle._impl.uuid, value)
    assert _wait(lambda: all(view.controls[n].value == v for n, v in TINY.items()))
    client.set_value(view.run_button._impl.uuid, True)  # a click
    assert _wait(lambda: view.figure is not None) and view.wait(WAIT_S)
    uuid = view.plot_handle._impl.uuid
    sent = client.wait_for(lambda m: m.get("uuid") == uuid
                           and m.get("updates", {}).get("_plotly_json_str"))
    assert json.loads(sent["updates"]["_plotly_json_str"]) == view.figure
    _set(view, LONG)
    assert view.run()
    assert _wait(lambda: view.progress[0] > 0)
    return weakref.ref(s)


def test_a_real_tab_draws_its_map_and_closing_it_frees_the_session(dash):
    """Through a websocket client (a browser tab): the map reaches the page; closing the
    tab during a second run ends the thread and lets the session go."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_dashboard_ws import ViserWsClient

    known = set(dash.sessions.values())
    client = ViserWsClient(dash.url)
    try:
        ref = _run_in_a_tab(dash, client, known)
        assert _map_threads()
    finally:
        client.close()
    assert _wait(lambda: set(dash.sessions.values()) <= known), "the session outlived its tab"
    assert _wait(lambda: not _map_threads(), 10.0)
    assert _wait(lambda: gc.collect() >= 0 and ref() is None, 10.0)
