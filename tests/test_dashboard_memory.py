"""A closed tab releases its session: 50 websocket clients open and close a session each
(some of them playing, one moving the time slider); afterwards every session is gone, the
process's resident memory (``VmRSS`` in ``/proc/self/status``) and its thread count are
back near where they were after the first few sessions.

Before sessions were released, memory grew by ~6-16 MB per closed tab and threads piled
up; the margin (:data:`RSS_MARGIN_MB` for 50 sessions) fails on a tenth of that."""

from __future__ import annotations

import gc
import sys
import threading
import time
import weakref
from pathlib import Path

import pytest

pytest.importorskip("viser")
pytest.importorskip("websockets")

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not Path("/proc/self/status").exists(),
                                 reason="reads VmRSS from /proc (Linux)")]

N_SESSIONS = 50
WARMUP_SESSIONS = 10  # the same mix as measured: caches and arenas warm
#: Resident memory allowed above the baseline after 50 closed sessions (MB): a session's
#: run, figures and scene are several MB, so a leak of even one in ten shows, and so does
#: a leak of 0.5 MB per session.
RSS_MARGIN_MB = 25.0
THREAD_MARGIN = 2
WAIT_S = 60.0


def rss_mb() -> float:
    """Resident set size of this process (MB), from ``/proc/self/status``."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


def _wait(pred, timeout_s: float = WAIT_S) -> bool:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(0.02)
    return pred()


def test_closed_sessions_release_memory_and_threads():
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_dashboard_ws import ViserWsClient

    from app.server import Dashboard, release_memory

    dash = Dashboard(port=0, verbose=False)
    refs: list[weakref.ref] = []

    def one_session(k: int) -> None:
        client = ViserWsClient(dash.url)
        try:
            assert _wait(lambda: len(dash.sessions) == 1)
            (session,) = dash.sessions.values()
            assert session.scheduler.wait_idle(WAIT_S)
            if k % 10 == 3:  # closed while playing
                session.speed.value = "60x"
                session.play.value = True
                time.sleep(0.3)
            elif k % 10 == 7:  # after a few time steps and a recompute
                for t in (10.0, 20.0, 30.0):
                    session.time.value = t
                session.sigma.value = 3.5
                assert session.scheduler.wait_idle(WAIT_S)
            refs.append(weakref.ref(session))
            del session
        finally:
            client.close()
        assert _wait(lambda: not dash.sessions), "the session outlived its tab"

    try:
        for k in range(WARMUP_SESSIONS):
            one_session(k)
        assert _wait(lambda: threading.active_count() <= 4)
        release_memory()
        rss0, threads0 = rss_mb(), threading.active_count()

        for k in range(N_SESSIONS):
            one_session(WARMUP_SESSIONS + k)

        # Probe and worker threads end once their client is gone.
        assert _wait(lambda: threading.active_count() <= threads0 + THREAD_MARGIN), \
            [t.name for t in threading.enumerate()]
        assert _wait(lambda: gc.collect() >= 0 and all(r() is None for r in refs), 10.0), \
            f"{sum(r() is not None for r in refs)} closed sessions still referenced"
        release_memory()
        rss1 = rss_mb()
        assert rss1 - rss0 < RSS_MARGIN_MB, (
            f"resident memory {rss0:.0f} -> {rss1:.0f} MB after {N_SESSIONS} closed tabs")
    finally:
        dash.stop()
