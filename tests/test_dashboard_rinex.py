"""The dashboard on a real recording (../shared/data, skipped when absent): opened from the
command line, from server paths and by upload; real sky, faults, algorithm switch."""

from __future__ import annotations

import time

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from raimcore.scenario import recording_scenario  # noqa: E402

ESBC_OBS = "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx"
WAIT_S = 60.0


@pytest.fixture(scope="module")
def rec_dash():
    from conftest import SHARED_DATA

    from app.server import Dashboard

    if not (SHARED_DATA / ESBC_OBS).is_file():
        pytest.skip("../shared/data is not present")
    s = recording_scenario(str(SHARED_DATA / ESBC_OBS), str(SHARED_DATA / ESBC_NAV))
    d = Dashboard(port=0, scenario=s, verbose=False)
    yield d
    d.stop()


@pytest.fixture()
def session(rec_dash):
    from app.session import Session

    s = Session(rec_dash.server, rec_dash.start_scenario, rec_dash.presets)
    assert s.scheduler.wait_idle(WAIT_S)
    yield s
    s.close()


def _settle(s):
    assert s.scheduler.wait_idle(WAIT_S)


def test_recording_opens_with_its_real_sky(session):
    res = session.result
    assert res.scenario.source == "rinex" and len(res.measurements.t_s) == 240
    names = res.measurements.sat_names
    assert any(n.startswith("G") for n in names) and any(n.startswith("C") for n in names)
    assert session.time.max == 7170.0 and session.sigma.value == 1.0
    assert ESBC_OBS[:9] in session.status.content
    # Real satellites sit on their orbits, and the scene shows them.
    r = np.linalg.norm(res.measurements.pos_sv_ecef_m, axis=-1)
    assert (r > 2.5e7).all()
    assert all(f.visible for f in session.scene._sat_frames)
    # Fault-free: no alarm, positions within 10 m.
    t = res.table
    assert not t["alarm"].any()
    assert np.nanmax(np.hypot(t["hpe_before_m"], t["vpe_before_m"])) < 10.0


def test_faults_and_algorithms_on_the_recording(session):
    s = session
    s.add_fault()
    _settle(s)
    (f,) = s.result.scenario.faults
    assert f.kind == "step" and f.bias_m == 50.0
    t = s.result.table
    faulted = t["faulty_truth"] == f.sat
    assert faulted.any() and t["alarm"][faulted].mean() > 0.9
    assert "detected" in s.verdict_md.content
    s.algorithm.value = "mss"
    _settle(s)
    assert s.result.scenario.algorithm == "mss"
    assert s.result.table["alarm"][faulted].mean() > 0.9


def test_open_recording_from_server_paths_and_bad_path(session, tmp_path):
    from conftest import SHARED_DATA

    session.rec_obs.value = str(tmp_path / "missing.rnx")
    session.rec_nav.value = str(SHARED_DATA / ESBC_NAV)
    session.rec_open.value = True
    deadline = time.time() + WAIT_S
    while "Error" not in session.status.content and time.time() < deadline:
        time.sleep(0.05)
    assert "does not exist" in session.status.content
    session.open_recording(str(SHARED_DATA / "slac1180.21o"), str(SHARED_DATA / "brdc1180.21n"))
    _settle(session)
    assert session.result.scenario.name == "slac1180"
    assert session.preset.value == "slac1180" and "slac1180" in session.presets
    assert all(n.startswith("G") for n in session.result.measurements.sat_names)
    # Back to a built-in simulated preset and to the recording again.
    session.preset.value = "default"
    _settle(session)
    assert session.result.scenario.source == "sim"
    session.preset.value = "slac1180"
    _settle(session)
    assert session.result.scenario.source == "rinex"


def test_upload_both_files_opens_the_recording(session):
    from conftest import SHARED_DATA
    from viser._gui_handles import UploadedFile

    session.rec_obs.value = ""
    session.rec_nav.value = ""
    # What viser does on an upload: set the handle's value, then call on_upload.
    for button, field, name in ((session.rec_upload_obs, session.rec_obs, "slac1180.21o"),
                                (session.rec_upload_nav, session.rec_nav, "brdc1180.21n")):
        button._impl.value = UploadedFile(name, (SHARED_DATA / name).read_bytes())
        session._on_upload(button, field)
    _settle(session)
    assert session.result.scenario.obs.startswith(session._upload_dir)
    assert len(session.result.measurements.t_s) == 241
    upload_dir = session._upload_dir
    session.close()
    import os

    assert not os.path.exists(upload_dir)  # uploads go to a temp dir, removed on close


def test_parked_satellites_are_hidden():
    from app.scene import SceneRun, SkyScene

    class Handle:
        def __init__(self):
            self.visible, self.position, self.color, self.text, self.wxyz = True, 0, 0, "", 0

        def remove(self):
            pass

    class FakeScene:
        def __getattr__(self, name):
            return lambda *a, **k: Handle()

    sc = SkyScene(FakeScene())
    pos = np.zeros((2, 2, 3))
    pos[:, 0] = [2.6e7, 0.0, 0.0]  # a real satellite; the second is parked at the centre
    run = SceneRun(t_s=np.array([0.0, 30.0]), sat_names=("G01", "G02"), pos_sv_ecef_m=pos,
                   pos_rx_ecef_m=np.array([[6.4e6, 0.0, 0.0]] * 2),
                   state=np.zeros((2, 2), dtype=np.int8), mask_deg=10.0)
    sc.set_run(run)
    assert [f.visible for f in sc._sat_frames] == [True, False]


def test_cli_dashboard_takes_a_recording():
    from raimcore.cli import build_parser

    args = build_parser().parse_args(["dashboard", "--obs", "a.rnx", "--nav", "b.rnx"])
    assert (args.obs, args.nav) == ("a.rnx", ["b.rnx"])


def test_measured_noise_correlation_is_one_click_away(session):
    """The Recording folder offers the fitted Gauss-Markov time of the real errors; one
    click sets the noise-correlation control and the next run uses it."""
    assert session.rec_use_corr.visible
    assert "measured pseudorange errors" in session.rec_notes.content
    session.rec_use_corr.value = True  # a click
    _settle(session)
    corr = session.result.scenario.noise_corr_s
    assert 100.0 < corr < 3600.0  # ESBC: about 370 s (four systems), 1283 s (GPS + BDS)
    assert session.noise_corr.value == corr


def test_touching_every_control_leaves_the_recording_identical(session):
    from test_dashboard_roundtrip import touch_every_control

    from raimcore.measure.faults import Fault

    sat = session._visible_sats()[0]
    session.add_fault(Fault(sat, "ramp", t0_s=600.0, t1_s=1800.0, rate_mps=-0.75))
    _settle(session)
    expected = session.scenario
    assert expected.source == "rinex" and len(expected.faults) == 1
    assert not session.status.content.startswith("**Error")
    touch_every_control(session, expected)
