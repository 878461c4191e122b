"""Start the RAIM Studio dashboard: a viser server with one :class:`~app.session.Session`
per connected browser tab.

Offline by design: viser serves its own client (one local ``index.html``) and plotly.js
from the installed ``plotly`` package over the websocket; no share tunnel (the share button
is hidden and share requests are refused), no environment map (plain lights), nothing
fetched at run time. The server listens on 127.0.0.1 unless another host is asked for
explicitly.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import gc
import logging
import threading

import numpy as np

from raimcore.scenario import Scenario, load_scenario

from .session import Session, preset_table

log = logging.getLogger(__name__)

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
DEFAULT_SCENARIO = "default"


class Dashboard:
    """The running dashboard: the viser server and its sessions (one per client).

    Parameters
    ----------
    host, port : where to listen (port 0 picks a free one).
    scenario : built-in scenario name, TOML path or :class:`Scenario` (e.g. a recording's)
        each new session starts from.
    """

    def __init__(self, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
                 scenario: str | Scenario = DEFAULT_SCENARIO, verbose: bool = True,
                 lesson_dirs=()) -> None:
        import viser

        self.lesson_dirs = tuple(lesson_dirs)

        self.start_scenario: Scenario = (scenario if isinstance(scenario, Scenario)
                                         else load_scenario(scenario))
        self.presets: dict[str, str | Scenario] = preset_table()
        if self.start_scenario.name not in self.presets:
            self.presets[self.start_scenario.name] = (
                scenario if isinstance(scenario, Scenario) else str(scenario))
        limit_malloc_arenas()
        self.sessions: dict[int, Session] = {}
        self._lock = threading.Lock()
        self._connected = threading.Condition(self._lock)
        self.server = viser.ViserServer(host=host, port=port, label="RAIM Studio",
                                        verbose=verbose)
        # No share tunnel: hide the button and refuse requests a client might still send.
        self.server.request_share_url = _refuse_share  # type: ignore[method-assign]
        self.server.gui.configure_theme(show_share_button=False, control_width="medium",
                                        brand_color=(31, 94, 234))
        self.server.scene.configure_environment_map(hdri=None)
        self._aim_camera()
        self.server.on_client_connect(self._on_connect)
        self.server.on_client_disconnect(self._on_disconnect)
        threading.Thread(target=self._prewarm, daemon=True, name="raim-prewarm").start()
        threading.Thread(target=warm_kernels, daemon=True, name="raim-warm-kernels").start()

    def _prewarm(self) -> None:
        """Run the start scenario once, in the background: the first tab finds it in the
        runs shared by all sessions (:data:`app.session.RESULTS`)."""
        from .session import RESULTS, _run_scenario

        s = self.start_scenario
        if RESULTS.get(s) is None:
            try:
                RESULTS.put(s, _run_scenario(s))
            except ValueError as exc:  # the first session says why, in its status line
                log.info("start scenario not run: %s", exc)

    def _aim_camera(self) -> None:
        """Start every client looking at the receiver's side of the Earth from far enough
        out to see the GNSS orbits (scene units: 1000 km)."""
        from raimcore.geometry import geodetic_to_ecef

        s = self.start_scenario
        if s.recorded:
            from raimcore.sky.recording import receiver_ecef_m

            rx = receiver_ecef_m(s)
        else:
            rx = geodetic_to_ecef(np.radians(s.lat_deg), np.radians(s.lon_deg), 0.0)
        from . import scene

        r_orbit_m = max(scene.ORBIT_RADIUS_M[sy] for sy in s.systems)
        scene.aim_camera(self.server.initial_camera, scene.camera_pose(rx, r_orbit_m))

    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.port}"

    def _on_connect(self, client) -> None:
        session = Session(client, self.start_scenario, self.presets,
                          lesson_dirs=self.lesson_dirs)
        with self._connected:
            self.sessions[client.client_id] = session
            self._connected.notify_all()

    def _on_disconnect(self, client) -> None:
        """A closed tab: its session lets go of everything, and the memory goes back to
        the system (:func:`release_memory`)."""
        with self._lock:
            session = self.sessions.pop(client.client_id, None)
        if session is not None:
            session.close()
            del session
            release_memory()

    def wait_for_sessions(self, n: int, timeout_s: float = 20.0) -> list[Session]:
        """Block until ``n`` sessions are connected (tests)."""
        with self._connected:
            self._connected.wait_for(lambda: len(self.sessions) >= n, timeout_s)
            return list(self.sessions.values())

    def stop(self) -> None:
        for s in list(self.sessions.values()):
            s.close()
        self.server.stop()


def warm_kernels() -> bool:
    """Compile, or load from numba's on-disk cache, the compiled kernels of the particle
    filters (:func:`raimcore.algorithms._pf_numba.warm_up`, a tiny bank step) and of ARAIM
    (:func:`raimcore.araim._numba.warm_up`) so that the first PF-LLR or ARAIM change of a
    session does not pay it (about 4 s and 3 s cold, 0.2 s and 0.5 s cached); False where
    they do not run here (numba missing or ``RAIM_STUDIO_NUMBA=0``)."""
    from raimcore.algorithms import pf
    from raimcore.araim import kernel

    nb_pf, nb_araim = pf.numba_kernels(), kernel.numba_kernels()
    if nb_pf is None or nb_araim is None:
        return False
    nb_pf.warm_up()
    nb_araim.warm_up()
    return True


#: glibc's ``mallopt`` parameter for the number of malloc arenas, and the count the
#: dashboard asks for.
M_ARENA_MAX = -8
MALLOC_ARENAS = 2


def limit_malloc_arenas(n: int = MALLOC_ARENAS) -> bool:
    """Ask glibc for at most ``n`` malloc arenas (True if it agreed; elsewhere than glibc
    there is nothing to ask).

    Every session runs its jobs, its Play loop and its window probe on threads of its
    own; glibc gives threads their own arenas (up to 8 per core), and the pages a closed
    session freed in them stay with the process: about 1 MB per closed tab until 16 arenas
    exist, and a resident size 70 MB higher from the start (measured: 50 tabs opened and
    closed, 2 arenas: flat; 4: +14 MB; the default: +26 MB). The same as starting the
    server with ``MALLOC_ARENA_MAX=2``."""
    if _LIBC is None or not hasattr(_LIBC, "mallopt"):
        return False
    return bool(_LIBC.mallopt(M_ARENA_MAX, int(n)))


def release_memory() -> None:
    """Collect the closed session's reference cycles (handles and callbacks refer to
    it) and hand freed heap pages back to the system.

    Without ``malloc_trim`` the resident size of the process grows by several MB per
    closed tab although nothing is referenced any more (glibc keeps freed pages of its
    per-thread arenas); elsewhere than glibc there is nothing to trim."""
    gc.collect()
    if _LIBC is not None:
        _LIBC.malloc_trim(0)


def _libc():
    name = ctypes.util.find_library("c")
    try:
        lib = ctypes.CDLL(name) if name else None
        return lib if lib is not None and hasattr(lib, "malloc_trim") else None
    except OSError:  # pragma: no cover - not glibc
        return None


_LIBC = _libc()


def _refuse_share(*_args, **_kwargs) -> None:
    log.warning("share URL requested: refused (RAIM Studio runs offline)")
    return None


def serve(host: str = DEFAULT_HOST, port: int = DEFAULT_PORT,
          scenario: str | Scenario = DEFAULT_SCENARIO, lesson_dirs=()) -> None:
    """Run the dashboard until interrupted (Ctrl-C); ``lesson_dirs`` add a teacher's
    lessons to the Lessons tab."""
    dash = Dashboard(host, port, scenario, lesson_dirs=lesson_dirs)
    print(f"RAIM Studio dashboard: open {dash.url} in a browser (Ctrl-C to stop)")
    try:
        threading.Event().wait()
    except KeyboardInterrupt:
        pass
    finally:
        dash.stop()
