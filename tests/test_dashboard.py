"""Dashboard tests, all headless and in-process: pure pieces (land mask, orbits, figures,
panel registry, verdict, scheduler) and a live viser server whose GUI handles are set from
Python while the tests assert on the figures and the scene."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from app import figures, page, panels, scene, teaching  # noqa: E402
from app.scheduler import CoalescingScheduler  # noqa: E402
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 60.0


# -- pure pieces ---------------------------------------------------------------------------

@pytest.mark.parametrize(("lat", "lon", "is_land"), [
    (48.5, 2.5, True),  # France
    (40.5, -100.5, True),  # USA
    (-25.5, 134.5, True),  # Australia
    (-10.5, -55.5, True),  # Brazil
    (30.5, 104.5, True),  # Chengdu
    (0.5, -30.5, False),  # Atlantic
    (0.5, -150.5, False),  # Pacific
    (-30.5, 80.5, False),  # Indian Ocean
])
def test_land_mask_has_the_continents(lat, lon, is_land):
    land = scene.land_mask()
    assert land.shape == (180, 360)
    i, j = int(90 - lat), int(lon + 180)
    assert land[i, j] == is_land
    assert 0.25 < land.mean() < 0.40  # Earth: ~29% land (cells partly land count)


def test_land_mesh_faces_outward_on_the_ellipsoid():
    verts, faces = scene.land_mesh()
    tri = verts[faces].astype(float)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroid = tri.mean(axis=1)
    outward = np.einsum("ij,ij->i", normal, centroid)
    degenerate = np.linalg.norm(normal, axis=1) < 1e-12  # pole cells collapse to a point
    assert np.all(outward[~degenerate] > 0)
    r = np.linalg.norm(verts, axis=1) / scene.SCALE_PER_M
    assert r.min() > 6356e3 and r.max() < 6379e3 + 30e3


def test_orbit_rings_contain_the_satellites_as_the_earth_turns():
    res = run_scenario(load_scenario("default", duration_s=600.0, step_s=60.0))
    pos, t = res.measurements.pos_sv_ecef_m, res.measurements.t_s
    rings = scene.orbit_rings(pos, t, n_points=2048)
    from viser.transforms import SO3

    for k in (3, 10):
        rot = SO3(scene.earth_rotation_wxyz(float(t[k] - t[0]))).as_matrix()
        ring_now = rings @ rot.T  # (S, P, 3) in ECEF at t_k
        sat = pos[k] * scene.SCALE_PER_M
        dist = np.linalg.norm(ring_now - sat[:, None, :], axis=-1).min(axis=1)
        # ring sampling step is 2*pi*26.6/2048 = 0.08 scene units; circular orbits
        assert np.all(dist < 0.1), dist.max()


def test_mask_cone_opens_at_the_mask_elevation():
    verts, _ = scene.mask_cone(15.0)
    rim = verts[1:]
    el = np.degrees(np.arcsin(rim[:, 2] / np.linalg.norm(rim, axis=1)))
    np.testing.assert_allclose(el, 15.0, atol=1e-4)


def test_scheduler_never_overlaps_and_ends_on_the_last_value():
    sched = CoalescingScheduler()
    seen = []
    gate = threading.Event()

    def job(v):
        def run():
            gate.wait(5)
            time.sleep(0.002)
            seen.append(v)
        return run

    for v in range(200):
        sched.submit("recompute", job(v))
    gate.set()
    assert sched.wait_idle(10)
    assert seen[-1] == 199  # a burst ends showing the last value
    assert len(seen) <= 3  # coalesced: first + last (+ one caught in between)
    assert sched.n_running_max == 1
    # Slots: a pending recompute runs before a pending time step.
    order = []
    gate2 = threading.Event()
    sched.submit("time", lambda: (gate2.wait(5), order.append("t0")))
    sched.submit("time", lambda: order.append("t1"))
    sched.submit("recompute", lambda: order.append("r"))
    gate2.set()
    assert sched.wait_idle(10)
    assert order == ["t0", "r", "t1"]
    with pytest.raises(ValueError, match="slot"):
        sched.submit("nope", lambda: None)


def test_scheduler_survives_a_failing_job():
    errors = []
    sched = CoalescingScheduler(on_error=errors.append)
    sched.submit("recompute", lambda: 1 / 0)
    assert sched.wait_idle(5)
    done = []
    sched.submit("recompute", lambda: done.append(1))
    assert sched.wait_idle(5)
    assert done == [1] and isinstance(errors[0], ZeroDivisionError)


@pytest.fixture(scope="module")
def default_result():
    return run_scenario(load_scenario("default"))


@pytest.fixture(scope="module")
def default_view(default_result):
    from app.session import run_view

    return run_view(default_result)


def _decode(arr):
    if isinstance(arr, dict) and "bdata" in arr:
        return np.frombuffer(base64.b64decode(arr["bdata"]), dtype="<" + arr["dtype"])
    return np.asarray(arr, dtype=float)


def test_detection_figure_carries_the_table(default_view, default_result):
    fig = figures.detection_figure(default_view)
    doc = json.loads(fig.to_json(42))
    names = [tr["name"] for tr in doc["data"]]
    assert {"statistic", "threshold", "statistic / threshold",
            "P_d theory (snapshot χ² test)"} <= set(names)
    stat = _decode(doc["data"][names.index("statistic")]["y"])
    np.testing.assert_array_equal(stat, default_result.table["statistic"])
    norm = _decode(doc["data"][names.index("statistic / threshold")]["y"])
    np.testing.assert_allclose(norm, default_result.table["normalised"])
    marker = [s for s in doc["layout"]["shapes"] if s.get("name") == "now"]
    assert marker and marker[0]["x0"] == default_result.table["t_s"][42]
    go_fig = fig.to_plotly(42)  # plotly's own validation accepts the figure
    assert len(go_fig.data) == len(doc["data"])


def test_sky_figure_moves_with_time_and_colours_states(default_view):
    fig = figures.sky_figure(default_view)
    early = json.loads(fig.to_json(0))
    late = json.loads(fig.to_json(599))
    used0 = next(tr for tr in early["data"] if tr["name"] == "used")
    used1 = next(tr for tr in late["data"] if tr["name"] == "used")
    assert used0["marker"]["color"] == figures.rgb("used")
    assert not np.allclose(_decode(used0["theta"])[:3], _decode(used1["theta"])[:3])
    # At t = 300 s the ramp on G10 is excluded by the parity FDE: G10 in "excluded".
    mid = json.loads(fig.to_json(300))
    excl = next(tr for tr in mid["data"] if tr["name"] == "excluded")
    assert "G10" in excl["text"]


def test_panel_registry_shows_new_algorithm_outputs_without_dashboard_changes(default_view):
    e, s = default_view.used.shape
    rng = np.random.default_rng(0)
    table = dict(default_view.table)
    table.update(hpl_m=rng.uniform(10, 20, e), vpl_m=rng.uniform(10, 30, e),
                 n_eff=rng.uniform(20, 80, e), beta=rng.uniform(0, 5, e))
    per_sat = dict(default_view.per_sat, llr=rng.normal(size=(e, s)),
                   mf=rng.normal(size=(e, s)))
    view = figures.RunView(**{**default_view.__dict__, "table": table, "per_sat": per_sat})
    keys = [k for k, _ in panels.panels_for(view)]
    assert keys == ["detection", "isolation", "errors", "sky", "stanford", "per_sat", "columns"]
    assert panels.per_sat_keys(view) == ["fault_size_m", "isolability", "llr", "mf"]
    built = dict((k, b(view)) for k, b in panels.panels_for(view, "mf"))
    assert built["per_sat"].key == "per_sat:mf"
    assert len(built["per_sat"].data) >= int(view.used.any(axis=0).sum())
    err_names = [tr["name"] for tr in built["errors"].data]
    assert "HPL" in err_names and "VPL" in err_names
    col_names = [tr["name"] for tr in built["columns"].data]
    assert "n_eff" in col_names and "beta" in col_names
    assert "hpl_m" not in col_names  # claimed by the error panel, not repeated


def test_verdict_names_detection_exclusion_and_error(default_view, default_result):
    text = teaching.verdict(default_view, default_result.summary, 1e-3)
    assert text.startswith("Fault on G10 detected at t = ")
    assert "G10 excluded" in text and "HPE back to" in text
    t_det = float(text.split("t = ")[1].split(" s")[0])
    assert 121 <= t_det <= 200  # ramp 2 m/s from 120 s, sigma 3 m


def test_verdict_without_fault_counts_false_alarms():
    from app.session import run_view

    res = run_scenario(load_scenario("default", faults=[]))
    text = teaching.verdict(run_view(res), res.summary, 1e-3)
    assert text.startswith("No fault injected:") and "600 epochs" in text


def test_verdict_does_not_call_alarms_in_the_window_after_a_fault_false():
    from app.session import run_view
    from raimcore.scoring import summarize

    res = run_scenario(load_scenario("seed002", seed=3))
    view = run_view(res)
    text = teaching.verdict(view, res.summary, 1e-3)
    assert text.startswith("Fault on G19 detected at t = ")
    # pf-llr's window (W = 30) still holds the step for a while after t = 152 s: those
    # alarms are reported as such, not as alarms "while no fault was on".
    assert "just after the fault ended" in text
    assert "while no fault was on" not in text
    # Without the window column the summary counts those alarms as false ones, and the
    # verdict says so with the summary's counts.
    table = type(res.table)({k: v for k, v in res.table.columns.items()
                             if k != "memory_epochs"}, res.table.per_sat, res.table.sat_names)
    plain = summarize(table)
    assert plain.false_alarm.k > 0
    view_no_memory = type(view)(**{**view.__dict__, "table": table.columns})
    text = teaching.verdict(view_no_memory, plain, 1e-3)
    assert (f"{plain.false_alarm.k} alarms while no fault was on ({plain.false_alarm.k} of "
            f"{plain.false_alarm.n} fault-free epochs)") in text
    assert "just after the fault ended" not in text


def test_verdict_reads_its_counts_from_the_summary():
    """Unavailable and detect-only epochs and faults that never act are named, with the
    summary's numbers (not recounted)."""
    import dataclasses

    from app.session import run_view
    from raimcore.measure.faults import Fault

    res = run_scenario(load_scenario("default", faults=[Fault("G10", "step", t0_s=2000.0,
                                                              bias_m=50.0)]))
    view = run_view(res)
    text = teaching.verdict(view, res.summary, 1e-3)
    assert text.startswith("No fault acts: 0 alarms in 600 epochs")
    assert "Fault G10 step from t = 2000 s never acts: its window" in text
    # The counts are the summary's: a summary saying otherwise changes the verdict.
    fake = dataclasses.replace(res.summary, unavailable_epochs=7, detect_only_epochs=3,
                               false_alarm=type(res.summary.false_alarm)(2, 593))
    text = teaching.verdict(view, fake, 1e-3)
    assert "2 alarms in 593 epochs" in text
    assert "7 epochs of 600 unavailable" in text and "3 epochs detect-only" in text


# -- the live server, driven in-process -------------------------------------------------------

@pytest.fixture()
def session(dash):
    from app.session import Session

    s = Session(dash.server, dash.start_scenario, dash.presets)
    assert s.scheduler.wait_idle(WAIT_S)
    yield s
    s.close()


def _settle(s):
    assert s.scheduler.wait_idle(WAIT_S)


def test_server_listens_on_localhost_and_serves_its_client_offline(dash):
    import urllib.request

    assert dash.server.get_host() == "127.0.0.1"
    page = urllib.request.urlopen(dash.url, timeout=10).read().decode()
    assert "<div id=\"root\">" in page
    # The client is one self-contained page: no script or stylesheet from elsewhere.
    assert "src=\"http" not in page and "href=\"http" not in page
    assert dash.server.request_share_url() is None  # share tunnel refused


def test_session_controls_drive_figures_and_scene(session):
    s = session
    assert list(s.figures)[:4] == ["detection", "isolation", "errors", "sky"]
    stat0 = np.array(s.figures["detection"].data[0]["y"])
    s.sigma.value = 20.0
    _settle(s)
    stat1 = np.array(s.figures["detection"].data[0]["y"])
    assert s.result.scenario.sigma_m == 20.0
    assert not np.allclose(stat0, stat1, equal_nan=True)
    assert "update" in s.status.content
    # plotly handle carries the new figure
    doc = json.loads(s.plot_handles["detection"]._plotly_json_str)
    np.testing.assert_array_equal(_decode(doc["data"][0]["y"]), stat1)
    s.noise_corr.value = 120.0  # time-correlated noise: same sigma, new draws
    _settle(s)
    assert s.result.scenario.noise_corr_s == 120.0
    assert not s.rec_use_corr.visible and s.use_measured_correlation() is None  # simulated
    assert not np.allclose(stat1, np.array(s.figures["detection"].data[0]["y"]),
                           equal_nan=True)


def test_going_back_to_a_setting_reuses_the_cached_run(session, monkeypatch):
    import app.session as app_session

    calls = []
    real = app_session._run_scenario
    monkeypatch.setattr(app_session, "_run_scenario", lambda sc: calls.append(sc) or real(sc))
    session.sigma.value = 7.0
    _settle(session)
    first = session.result
    session.sigma.value = 8.0
    _settle(session)
    session.sigma.value = 7.0
    _settle(session)
    assert session.result is first
    assert [c.sigma_m for c in calls] == [7.0, 8.0]


def test_fault_controls_edit_add_and_remove_faults(session):
    s = session
    assert s.fault_sat.value == "G10" and s.fault_kind.value == "ramp"
    s.fault_kind.value = "step"
    s.fault_bias.value = 200.0
    s.fault_t0.value = 100.0
    s.fault_t1.value = 300.0
    _settle(s)
    (f,) = s.result.scenario.faults
    assert (f.sat, f.kind, f.bias_m, f.t0_s, f.t1_s) == ("G10", "step", 200.0, 100.0, 300.0)
    bias = s.result.truth.fault_bias_m[:, s.result.measurements.sat_names.index("G10")]
    t = s.result.measurements.t_s
    assert np.all(bias[(t >= 100) & (t < 300)] == 200.0)
    assert "G10 detected at t = 100 s" in s.verdict_md.content
    # Only visible satellites are offered, and the scenario's systems (constellation faults).
    used = s.result.measurements.used.any(axis=0)
    offered = set(s.fault_sat.options) - {"GPS"}
    assert offered == {n for n, u in zip(s.result.measurements.sat_names, used, strict=True) if u}
    assert s.fault_sat.options[-1] == "GPS"
    # Add a second fault, then remove the first.
    s.fault_add.value = True  # buttons: setting value fires on_click like a real click
    _settle(s)
    assert len(s.result.scenario.faults) == 2
    assert len(s.fault_pick.options) == 2
    second = s.result.scenario.faults[1].sat
    assert second != "G10" and second in offered
    s.fault_pick.value = s.fault_pick.options[0]
    s.fault_remove.value = True
    _settle(s)
    assert [f.sat for f in s.result.scenario.faults] == [second]


def test_fault_editor_creates_and_edits_a_constellation_fault(session):
    """Satellite = a system key: a fault on every satellite of that constellation."""
    s = session
    s.open_scenario(load_scenario("default", systems=["GPS", "GAL"], sigma_m=1.0,
                                  faults=[]))
    _settle(s)
    assert tuple(s.fault_sat.options[-2:]) == ("GPS", "GAL")
    s.fault_add.value = True  # a new satellite fault, made a constellation fault
    _settle(s)
    s.fault_sat.value = "GAL"
    _settle(s)
    s.fault_kind.value = "step"
    s.fault_bias.value = 20.0
    s.fault_t0.value = 300.0
    _settle(s)
    f = s.result.scenario.faults[0]
    assert (f.sat, f.system, f.kind, f.bias_m, f.t0_s) == ("GAL", "GAL", "step", 20.0, 300.0)
    assert s.fault_pick.value == "#1 GAL (constellation) step 20 m, 300 s..end"
    assert s.fault_sat.value == "GAL"
    data, truth = s.result.measurements, s.result.truth
    gal = np.array([n.startswith("E") for n in data.sat_names])
    on = data.t_s >= 300.0
    assert np.array_equal(truth.faulted[:, gal], on[:, None] & data.used[:, gal])
    assert "Constellation fault on GAL (all its satellites) detected" in s.verdict_md.content
    # The 3D view cues every faulted Galileo satellite.
    i = int(np.argmax(on)) + 10
    s.time.value = float(data.t_s[i])
    _settle(s)
    assert s.scene.i_epoch == i
    cued = set(s.scene.fault_cue_shown())
    assert cued == {n for n, x in zip(data.sat_names, truth.faulted[i], strict=True) if x}
    assert len(cued) >= 5 and all(n.startswith("E") for n in cued)
    # Edit it: a ramp that ends, then back to one satellite.
    s.fault_kind.value = "ramp"
    s.fault_t1.value = 450.0
    _settle(s)
    f = s.result.scenario.faults[0]
    assert (f.sat, f.kind, f.t1_s) == ("GAL", "ramp", 450.0)
    assert s.fault_pick.value.startswith("#1 GAL (constellation) ramp ")
    t, faulted = s.result.measurements.t_s, s.result.truth.faulted
    assert faulted[(t > 300.0) & (t < 450.0)][:, gal].any(-1).all()
    assert not faulted[t >= 450.0][:, gal].any()
    s.fault_sat.value = "E01"
    _settle(s)
    assert s.result.scenario.faults[0].sat == "E01"
    assert s.fault_pick.value.startswith("#1 E01 ramp ")


def test_mask_change_refreshes_the_offered_satellites(session):
    before = set(session.fault_sat.options)
    session.mask.value = 35.0
    _settle(session)
    after = set(session.fault_sat.options)
    assert after < before and "G10" in after | {session.fault_sat.value}
    assert session.fault_sat.value == "G10"  # the edited fault keeps its satellite


def test_a_bad_value_shows_an_error_and_the_session_recovers(session):
    session.p_fa.value = 0.0  # a typed 0: the engine rejects it (p_fa in (0, 1))
    _settle(session)
    assert session.status.content.startswith("**Error:**") and "p_fa" in session.status.content
    session.p_fa.value = 1e-4
    _settle(session)
    assert session.result.scenario.p_fa == 1e-4 and "update" in session.status.content


def test_time_slider_moves_satellites_and_marks_panels(session):
    s = session
    pos0 = s.scene.sat_positions().copy()
    s.time.value = 400.0
    _settle(s)
    assert s.i_epoch == 400
    pos1 = s.scene.sat_positions()
    moved = np.linalg.norm(pos1 - pos0, axis=1)
    assert np.all(moved > 0.5)  # GPS satellites move ~1.4 Mm in 400 s
    # The panels are not sent again: the page gets one small time update (cursor time
    # and the sky plot's "now" markers) through the hidden carrier element.
    doc = json.loads(s.plot_handles["detection"]._plotly_json_str)
    assert [sh["x0"] for sh in doc["layout"]["shapes"] if sh.get("name") == "now"] == [0.0]
    sent = page.carried_state(s.page.carrier.content)
    assert sent == s.page.last_state and sent["t"] == 400.0
    assert sent["seq"] > doc["layout"]["meta"]["seq"]
    sky = sent["dyn"]["sky"]
    assert sky["rev"] == s.figures["sky"].rev
    excluded = next(tr for tr in sky["traces"] if tr["name"] == "excluded")
    assert "G10" in excluded["text"]
    assert len(s.page.carrier.content) < 5000
    # States in the scene: G10 excluded at t = 400 s in the default ramp scenario.
    assert s.scene.sat_colors()["G10"] == figures.STATE_COLORS["excluded"]
    # Raising the mask puts more satellites below it.
    n_grey = sum(c == figures.STATE_COLORS["below mask"] for c in s.scene.sat_colors().values())
    s.mask.value = 30.0
    _settle(s)
    n_grey2 = sum(c == figures.STATE_COLORS["below mask"]
                  for c in s.scene.sat_colors().values())
    assert n_grey2 > n_grey


def test_play_advances_time_and_pause_stops_it(session):
    session.speed.value = "60x"
    session.play.value = True
    t_end = time.monotonic() + WAIT_S
    while session.i_epoch < 30 and time.monotonic() < t_end:
        time.sleep(0.05)
    session.play.value = False
    time.sleep(0.5)
    _settle(session)
    i_paused = session.i_epoch
    assert i_paused >= 30
    time.sleep(0.6)
    assert session.i_epoch == i_paused == session.scene.i_epoch


def test_every_registered_algorithm_is_offered_with_its_options(session):
    from raimcore import algorithms

    assert list(session.algorithm.options) == algorithms.names()
    for name in algorithms.names():
        session.algorithm.value = name
        _settle(session)
        spec = algorithms.get(name)
        assert session.result.scenario.algorithm == name
        assert not session.status.content.startswith("**Error")
        assert set(session._option_handles) == set(spec.option_keys)
        assert spec.label in session.teach_md.content
        assert "detection" in session.figures and "errors" in session.figures
        # every per-epoch output column of the algorithm is drawn in some panel (a trace
        # named after it, or one whose meta names it: ARAIM's "EMT" draws emt_m)
        drawn = {tr.get("name") for f in session.figures.values() for tr in f.data}
        drawn |= {(tr.get("meta") or {}).get("column") for f in session.figures.values()
                  for tr in f.data if isinstance(tr.get("meta"), dict)}
        for col in session.result.output.columns:
            arr = np.asarray(session.result.output.columns[col])
            if arr.dtype.kind == "f" and np.isfinite(arr).any() and col != "dof":
                assert col in drawn or col in ("hpl_m", "vpl_m"), col
        # the generic per-satellite panel can show each unclaimed per-satellite output
        for key in session.per_sat_pick.options:
            if key == "(none)":
                continue
            session.per_sat_pick.value = key
            _settle(session)
            assert session.figures["per_sat"].key == f"per_sat:{key}"


def test_preset_switch_loads_the_scenario(session):
    session.preset.value = "seed000-step"
    _settle(session)
    res = session.result
    assert res.scenario.name == "seed000-step" and len(res.measurements.sat_names) == 6
    assert session.sigma.value == 33.0 and session.time.max == 100.0
    assert session.fault_sat.value == "G03" and session.fault_kind.value == "step"


def test_exports_csv_and_standalone_html(session):
    csv_text = session.table_csv().decode()
    header = csv_text.splitlines()[0].split(",")
    assert header[:3] == ["t_s", "n_sat", "status"]
    assert len(csv_text.splitlines()) == 1 + len(session.result.measurements.t_s)
    page = session.figures_html().decode()
    assert "plotly.js v" in page  # plotly.js embedded, not loaded from a CDN
    assert "<script src=" not in page and "<script type=\"text/javascript\" src=" not in page
    assert page.count("Plotly.newPlot") == len(session.figures)
    session.export_csv.value = True  # the button sends the file through viser


def test_import_raimcore_does_not_import_the_dashboard():
    code = "import sys, raimcore, raimcore.cli, raimcore.scenario; " \
           "print(any(m.split('.')[0] in ('viser', 'plotly', 'app') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, check=True)
    assert out.stdout.strip() == "False"


def test_cli_has_a_dashboard_command_on_localhost():
    from raimcore.cli import build_parser

    args = build_parser().parse_args(["dashboard"])
    # No --port: the default one, or the next free one (said on its own line).
    assert (args.host, args.port, args.scenario) == ("127.0.0.1", None, "default")
    args = build_parser().parse_args(["dashboard", "--host", "192.0.2.1", "--port", "9000",
                                      "--scenario", "seed000-ramp"])
    assert (args.host, args.port, args.scenario) == ("192.0.2.1", 9000, "seed000-ramp")


def test_app_code_never_defaults_to_all_interfaces():

    from app.server import DEFAULT_HOST

    assert DEFAULT_HOST == "127.0.0.1"
    # All interfaces are never offered: not as a default, not in a message.
    for path in (ROOT / "app").rglob("*.py"):
        assert "0.0.0.0" not in path.read_text(), path


def test_learn_tab_shows_the_scenario_report(session):
    assert session.report_md.content.startswith("# default:")
    session.open_scenario(load_scenario("seed002"))
    assert session.scheduler.wait_idle(WAIT_S)
    assert session.report_md.content.startswith("# seed002:")
    session.open_scenario(load_scenario("default").replace(name="mine"))
    assert "No report for *mine*" in session.report_md.content


# -- sizes, lean time updates, shared runs --------------------------------------------------

def test_plots_are_drawn_at_their_declared_heights(session):
    """viser's client draws a plot ``width`` wide and ``width * aspect`` tall: with the
    width a plot has in the plot panel, every panel gets its declared height."""
    s = session
    for width_px in (1600, 1000, 1920):
        s.set_window(width_px, 800)
        width = page.plot_width(s.plots_px)  # the width the client gives the plot
        for key, handle in s.plot_handles.items():
            fig = s.figures[key]
            assert width * handle.aspect == pytest.approx(fig.height_px, abs=0.5), key
            assert 200 <= fig.height_px <= 480
    # The JSON carries its height too (what the HTML export draws).
    doc = json.loads(s.plot_handles["detection"]._plotly_json_str)
    assert doc["layout"]["height"] == s.figures["detection"].height_px


@pytest.mark.parametrize("width_px", [1000, 1100, 1280, 1440, 1600, 1920, 2560])
def test_side_panels_leave_the_3d_view_at_least_half_the_window(width_px):
    left, right = page.side_panel_widths(width_px)
    assert width_px - left - right >= width_px / 2
    assert page.CONTROLS_PX[0] <= left <= page.CONTROLS_PX[1]
    assert page.PLOTS_PX[0] <= right <= page.PLOTS_PX[1]
    assert page.plot_width(right) >= 229  # the titles are made to fit that (figures)


def test_titles_are_short_and_legends_sit_inside_the_figure(default_view):
    builders = [figures.detection_figure, figures.isolation_figure, figures.error_figure,
                figures.sky_figure, lambda v: figures.per_sat_figure(v, "fault_size_m"),
                lambda v: figures.columns_figure(v, ["statistic_after", "nis_plain",
                                                     "a_long_column_name_m"])]
    for build in builders:
        layout = build(default_view).layout
        title = layout["title"]
        assert len(title["text"]) <= figures.TITLE_MAX_CHARS
        sub = title.get("subtitle", {}).get("text", "")
        assert len(sub) <= figures.DETAIL_MAX_CHARS
        legend = layout["legend"]
        # Under the plot, in the figure (plotly widens the bottom margin to hold it).
        assert legend["yanchor"] == "top" and -0.3 < legend["y"] < 0
        assert layout.get("margin", {}).get("autoexpand", True)


def test_a_time_step_sends_no_figure(dash):
    """In a real page session: moving the time slider changes no figure handle; the
    page gets one small update (the carrier) whose sky markers are the run's."""
    from test_dashboard_ws import ViserWsClient

    known = set(dash.sessions.values())
    c = ViserWsClient(dash.url)
    try:
        (s,) = [x for x in dash.wait_for_sessions(len(known) + 1) if x not in known]
        _settle(s)
        assert s.page.live and s.scene is not None
        carrier = s.page.carrier._impl.uuid
        plots = {h._impl.uuid for h in s.plot_handles.values()}
        time.sleep(0.3)
        n0 = len(c.snapshot())
        s.time.value = 250.0
        _settle(s)
        update = c.wait_for(lambda m: m.get("uuid") == carrier, start=n0)
        time.sleep(0.3)
        new = c.snapshot()[n0:]
        assert not any(m.get("uuid") in plots for m in new)  # no figure re-sent
        state = page.carried_state(update["updates"]["content"])
        assert state["t"] == 250.0 and state == s.page.last_state
        i = s.i_epoch
        used = next(tr for tr in state["dyn"]["sky"]["traces"] if tr["name"] == "used")
        sel = (s.view.states()[i] == 0) & (s.view.el_rad[i] >= 0)
        assert sorted(used["text"]) == sorted(np.asarray(s.view.sat_names)[sel].tolist())
        assert len(update["updates"]["content"]) < 5000
    finally:
        c.close()


def test_a_recompute_resends_only_the_figures_that_changed(session):
    s = session
    sky_json = s.plot_handles["sky"]._plotly_json_str
    det_json = s.plot_handles["detection"]._plotly_json_str
    s.sigma.value = 4.5  # the noise changes every statistic, not the sky's tracks
    _settle(s)
    assert s.plot_handles["sky"]._plotly_json_str is sky_json
    assert s.plot_handles["detection"]._plotly_json_str != det_json
    # The sky's markers (states) still follow the run: in the time update.
    assert s.page.last_state["dyn"]["sky"]["rev"] == s.figures["sky"].rev


def test_runs_are_shared_between_sessions_and_bounded(dash):
    from app.session import RESULTS, ResultCache, Session

    a = Session(dash.server, dash.start_scenario, dash.presets)
    try:
        _settle(a)
        b = Session(dash.server, dash.start_scenario, dash.presets)
        try:
            _settle(b)
            assert b.result is a.result  # run once, shown twice
        finally:
            b.close()
    finally:
        a.close()
    assert RESULTS.get(dash.start_scenario) is not None
    small = ResultCache(max_items=2)
    scenarios = [dash.start_scenario.replace(seed=k) for k in range(3)]
    for sc in scenarios:
        small.put(sc, run_scenario(sc.replace(duration_s=20.0)))
    assert len(small) == 2 and small.get(scenarios[0]) is None
    tiny = ResultCache(max_bytes=1)  # the newest run is always kept
    tiny.put(scenarios[0], run_scenario(scenarios[0].replace(duration_s=20.0)))
    assert len(tiny) == 1


def test_a_closed_session_lets_go_of_its_run_and_threads(dash):
    from app.session import Session

    s = Session(dash.server, dash.start_scenario, dash.presets)
    _settle(s)
    s.speed.value = "60x"
    s.play.value = True
    time.sleep(0.3)
    play = s._play_thread
    assert play.is_alive()
    s.close()
    assert not play.is_alive()
    assert s.figures == {} and s.result is None and s.view is None and s.plot_handles == {}
    s.sigma.value = 9.0  # a late event on a closed session: ignored, nothing runs
    assert s.scheduler.wait_idle(1.0) and s.result is None


def test_session_has_lessons_legend_and_the_faults_onset(session):
    """The Lessons tab lists the built-in lessons, the 3D legend is filled by the scene,
    and the verdict dates the default ramp from its onset as set (120 s)."""
    assert len(session.lessons_tab.lessons) >= 10
    assert "mask" in session.legend_md.content and "excluded" in session.legend_md.content
    assert "onset at t = 120 s" in session.verdict_md.content


def test_dashboard_refuses_a_missing_lessons_folder(tmp_path, capsys):
    from raimcore.cli import main

    assert main(["dashboard", "--lessons", str(tmp_path / "nope"), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "--lessons" in err and "not a folder" in err and "Traceback" not in err


def test_sky_plot_marks_each_system_with_its_own_symbol_and_the_mask_like_the_3d_view():
    from app.session import run_view

    res = run_scenario(load_scenario("default", systems=["GPS", "GAL", "GLO"],
                                     duration_s=20.0, faults=[]))
    fig = figures.sky_figure(run_view(res))
    traces, _ = fig.dynamic(0)
    shown = {(n[:1], s) for tr in traces
             for n, s in zip(tr["text"], tr["marker"]["symbol"], strict=True)}
    assert {letter for letter, _ in shown} == {"G", "E", "R"}
    assert shown <= {("G", "circle"), ("E", "diamond"), ("R", "triangle-up")}
    assert "◆ GAL" in json.dumps(fig.layout["title"], ensure_ascii=False)
    mask = next(tr for tr in fig.data if tr["name"] == "mask")
    assert mask["line"]["color"].startswith("rgba(140,80,230")  # scene.MASK_RGB


@pytest.fixture(scope="module")
def araim_view():
    from app.session import run_view

    # The built-in ARAIM scenario cut to 360 s: 60 epochs of its GAL fault (t0 300 s).
    return run_view(run_scenario(load_scenario("araim", duration_s=359)))


def test_araim_panel_shows_pls_emt_and_accuracy_against_lpv200(araim_view, default_view):
    keys = [k for k, _ in panels.panels_for(araim_view)]
    assert "araim" in keys
    assert "araim" not in [k for k, _ in panels.panels_for(default_view)]  # parity
    fig = dict(panels.panels_for(araim_view))["araim"](araim_view)
    assert 200 <= fig.height_px <= 480
    title = fig.layout["title"]
    assert len(title["text"]) <= figures.TITLE_MAX_CHARS
    assert len(title.get("subtitle", {}).get("text", "")) <= figures.DETAIL_MAX_CHARS
    by_name = {tr["name"]: tr for tr in fig.data}
    assert set(by_name) == {"VPL", "HPL", "EMT", "σ_acc"}
    np.testing.assert_allclose(by_name["VPL"]["y"], araim_view.table["vpl_m"])
    assert by_name["EMT"]["yaxis"] == by_name["σ_acc"]["yaxis"] == "y2"
    # The limits: VAL/HAL on the PL axis, 15 m and 1.87 m on the EMT / sigma_acc axis.
    lines = {(s["yref"], s["y0"]) for s in fig.layout["shapes"] if s["type"] == "line"}
    assert {("y", 35.0), ("y", 40.0), ("y2", 15.0), ("y2", 1.87)} <= lines
    # MAAST's example ISM is H-ARAIM grade: no epoch is LPV-200 available, so one grey
    # band covers the run.
    shaded = [s for s in fig.layout["shapes"] if s.get("name") == "unavailable"]
    assert not araim_view.table["available"].any()
    assert len(shaded) == 1
    assert shaded[0]["x0"] == araim_view.t_s[0] and shaded[0]["x1"] == araim_view.t_s[-1]
    # A time cursor across both rows, moved by the time slider like the other panels.
    now = [s for s in fig.to_dict(10)["layout"]["shapes"] if s.get("name") == "now"]
    assert len(now) == 1 and now[0]["x0"] == araim_view.t_s[10] and now[0]["yref"] == "paper"
    fig.to_plotly(10)  # valid plotly


def test_araim_panel_shades_only_the_unavailable_epochs(araim_view):
    table = dict(araim_view.table)
    avail = np.ones(len(araim_view.t_s), bool)
    avail[5:9] = False
    avail[-3:] = False
    table["available"] = avail
    import dataclasses

    fig = figures.araim_figure(dataclasses.replace(araim_view, table=table))
    shaded = [(s["x0"], s["x1"]) for s in fig.layout["shapes"]
              if s.get("name") == "unavailable"]
    t = araim_view.t_s
    assert shaded == [(t[5], t[8]), (t[-3], t[-1])]
