"""A websocket client speaking viser's protocol drives one dashboard session while another
session stays unchanged; a burst of slider messages ends on the last value."""

from __future__ import annotations

import threading
import time

import pytest

viser = pytest.importorskip("viser")
ws_sync = pytest.importorskip("websockets.sync.client")
msgspec = pytest.importorskip("msgspec")
zstandard = pytest.importorskip("zstandard")

WAIT_S = 60.0


class ViserWsClient:
    """Minimal viser client: decodes server windows, sends GUI updates."""

    def __init__(self, url: str) -> None:
        self.ws = ws_sync.connect(url.replace("http", "ws"),
                                  subprotocols=[f"viser-v{viser.__version__}"],
                                  max_size=None, open_timeout=30)
        self.messages: list[dict] = []
        self._lock = threading.Lock()
        self._dz = zstandard.ZstdDecompressor()
        self._thread = threading.Thread(target=self._recv_loop, daemon=True)
        self._thread.start()
        # viser registers a client (and runs on_client_connect) on its first camera message.
        self.ws.send(msgspec.msgpack.encode({
            "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0],
            "position": [0.0, 0.0, 60.0], "fov": 1.0, "near": 0.05, "far": 2000.0,
            "image_height": 800, "image_width": 1200, "look_at": [0.0, 0.0, 0.0],
            "up_direction": [0.0, 0.0, 1.0]}))

    def _recv_loop(self) -> None:
        try:
            while True:
                raw = self.ws.recv()
                inner_len = int.from_bytes(raw[:8], "little")
                comp_len = int.from_bytes(raw[8:16], "little")
                inner = self._dz.decompress(raw[16:16 + comp_len], max_output_size=inner_len)
                window = msgspec.msgpack.decode(inner)
                with self._lock:
                    self.messages.extend(window["messages"])
        except Exception:  # noqa: BLE001 - connection closed at teardown
            return

    def snapshot(self) -> list[dict]:
        with self._lock:
            return list(self.messages)

    def wait_for(self, pred, timeout_s: float = WAIT_S, start: int = 0) -> dict:
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            for m in self.snapshot()[start:]:
                if pred(m):
                    return m
            time.sleep(0.05)
        raise TimeoutError("message not received")

    def gui_uuid(self, label: str) -> str:
        m = self.wait_for(lambda m: m.get("type", "").startswith("Gui")
                          and isinstance(m.get("props"), dict)
                          and m["props"].get("label") == label)
        return m["uuid"]

    def set_value(self, uuid: str, value) -> None:
        self.ws.send(msgspec.msgpack.encode({"type": "GuiUpdateMessage", "uuid": uuid,
                                             "updates": {"value": value}}))

    def close(self) -> None:
        self.ws.close()


@pytest.fixture(scope="module")
def dash():
    from app.server import Dashboard

    d = Dashboard(port=0, verbose=False)
    yield d
    d.stop()


def test_one_session_changes_while_the_other_stays(dash):
    a = ViserWsClient(dash.url)
    (sess_a,) = dash.wait_for_sessions(1)
    b = ViserWsClient(dash.url)
    sessions = dash.wait_for_sessions(2)
    (sess_b,) = [s for s in sessions if s is not sess_a]
    try:
        for s in (sess_a, sess_b):
            assert s.scheduler.wait_idle(WAIT_S)
        result_b = sess_b.result
        n_b = sess_b.timing.n_recomputes
        sigma_uuid = a.gui_uuid("Noise sigma (m)")
        # Each tab has its own controls: B's slider is another GUI element.
        assert b.gui_uuid("Noise sigma (m)") != sigma_uuid
        det_uuid_a = sess_a.plot_handles["detection"]._impl.uuid
        det_uuid_b = sess_b.plot_handles["detection"]._impl.uuid
        time.sleep(0.5)  # let B's initial windows arrive
        n_msgs = len(a.snapshot())
        n_msgs_b = len(b.snapshot())

        a.set_value(sigma_uuid, 12.0)
        t_end = time.monotonic() + WAIT_S
        while sess_a.result.scenario.sigma_m != 12.0 and time.monotonic() < t_end:
            time.sleep(0.05)
        assert sess_a.scheduler.wait_idle(WAIT_S)
        assert sess_a.result.scenario.sigma_m == 12.0
        # A's browser receives the new detection figure.
        a.wait_for(lambda m: m.get("type") == "GuiUpdateMessage"
                   and m.get("uuid") == det_uuid_a
                   and "_plotly_json_str" in m.get("updates", {}), start=n_msgs)
        # B is untouched: same run, same controls, no recompute.
        assert sess_b.sigma.value == 3.0
        assert sess_b.result is result_b
        assert sess_b.timing.n_recomputes == n_b
        time.sleep(0.5)
        assert not any(m.get("uuid") == det_uuid_b for m in b.snapshot()[n_msgs_b:])

        # A burst of 40 slider messages: recomputes never overlap, the last value wins.
        n_a = sess_a.timing.n_recomputes
        values = [round(3.0 + 0.5 * k, 1) for k in range(40)]
        for v in values:
            a.set_value(sigma_uuid, v)
        t_end = time.monotonic() + WAIT_S
        while sess_a.sigma.value != values[-1] and time.monotonic() < t_end:
            time.sleep(0.05)
        time.sleep(0.2)
        assert sess_a.scheduler.wait_idle(WAIT_S)
        assert sess_a.result.scenario.sigma_m == values[-1]
        assert sess_a.scheduler.n_running_max == 1
        assert sess_a.timing.n_recomputes - n_a < len(values)  # coalesced
    finally:
        a.close()
        b.close()


@pytest.mark.parametrize(("label", "bad", "key"), [("Noise sigma (m)", 0.0, "sigma_m"),
                                                    ("Random seed", -3, "seed")])
def test_a_raw_invalid_value_from_the_page_is_refused_without_a_traceback(dash, capfd,
                                                                          caplog, label,
                                                                          bad, key):
    """The page's number field sends what is typed before it clamps: the server refuses
    it in one line naming the key, keeps the scenario and puts the control back."""
    import logging

    known = set(dash.sessions.values())
    a = ViserWsClient(dash.url)
    try:
        (sess,) = [s for s in dash.wait_for_sessions(len(known) + 1) if s not in known]
        assert sess.scheduler.wait_idle(WAIT_S)
        before = sess.scenario
        good = getattr(before, key)
        uuid = a.gui_uuid(label)
        n_msgs = len(a.snapshot())
        with caplog.at_level(logging.DEBUG):
            a.set_value(uuid, bad)
            t_end = time.monotonic() + WAIT_S
            while "Error" not in sess.status.content and time.monotonic() < t_end:
                time.sleep(0.05)
            assert sess.scheduler.wait_idle(WAIT_S)
        status = sess.status.content
        assert status.startswith("**Error:**") and key in status and "\n" not in status
        assert sess.scenario is before
        # The page is told the last valid value.
        a.wait_for(lambda m: m.get("type") == "GuiUpdateMessage" and m.get("uuid") == uuid
                   and m.get("updates", {}).get("value") == good, start=n_msgs)
        assert not any(r.exc_info for r in caplog.records)
        assert "Traceback" not in capfd.readouterr().err
    finally:
        a.close()
