"""One browser tab = one :class:`Session`: its own controls, 3D scene, run and worker.

The session's :class:`~raimcore.scenario.Scenario` is the truth; the controls show it.
Every control is made from its key's declaration (:mod:`app.controls`), and a user's entry
edits exactly that key: checked by the schema (a refused entry leaves the scenario and the
control at the last valid value and says why in one line), then a recompute is submitted
to the session's :class:`~app.scheduler.CoalescingScheduler` (never two at once; a burst of
slider moves ends on the last value). A control the user did not move never rewrites its
value, so touching a control without changing it leaves the scenario identical.

A recompute runs the scenario through :func:`raimcore.pipeline.run_scenario`, rebuilds the
panels the run calls for (the panel registry, :mod:`app.panels`), the teaching text and
the verdict (from the run's :class:`~raimcore.scoring.Summary`), and updates the 3D scene.
A figure whose static part did not change is not sent again. Moving the time slider (or
Play) moves the scene and sends the page one small time update (the cursor's time and the
sky plot's "now" markers: :mod:`app.page`), never whole figures. Runs are kept in a cache
shared by all sessions (:class:`ResultCache`: a scenario run in one tab is instant in
another).

Sizes follow the browser window (:mod:`app.page`): the control and plot panels take
their widths from it, so that the 3D view keeps at least half of the window, and every
plot is drawn at its declared height.

A closed tab's session lets go of everything (:meth:`Session.close`): its worker and Play
threads end, its figures, runs and handles are dropped.
"""

from __future__ import annotations

import dataclasses
import html
import io
import logging
import math
import shutil
import tempfile
import threading
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from raimcore import algorithms
from raimcore.geometry import ecef_to_enu
from raimcore.measure.faults import Fault
from raimcore.pipeline import ScenarioResult
from raimcore.pipeline import run_scenario as _run_scenario
from raimcore.scenario import Scenario, list_scenarios, load_scenario, scenario_keys
from raimcore.schema import is_input_error as input_error

from . import page, panels, teaching
from .availability_view import AvailabilityView
from .controls import FAULT_KEYS, KeyControl
from .figures import PanelFigure, RunView
from .ism_controls import IsmControls
from .lessons import add_lessons_tab
from .scene import SceneRun, SkyScene

log = logging.getLogger(__name__)

NO_FAULT = "(no fault)"
NO_OUTPUT = "(none)"
PLAY_SPEEDS = ("1x", "5x", "20x", "60x")
#: Frames per second Play draws (announced in its hint).
PLAY_FPS = 8.0
#: A new fault's size in the editor (and what the inactive size control shows).
NEW_FAULT_BIAS_M = 50.0
NEW_FAULT_RATE_MPS = 1.0
#: Runs kept for all sessions together: going back to a setting, or opening a scenario
#: another tab ran, is instant. At most this many, and at most RESULT_CACHE_BYTES of
#: arrays.
RESULT_CACHE_SIZE = 16
RESULT_CACHE_BYTES = 600 * 2**20
#: Pause (s) after flushing a batch of GUI messages before queueing 3D-scene ones.
BATCH_GAP_S = 0.002
#: How long closing a session waits for its running job (s).
CLOSE_WAIT_S = 10.0
#: The scenario keys the dashboard shows, with their labels (unit from the key).
SCENARIO_CONTROLS = (("systems", "Systems"), ("sigma_m", "Noise sigma"),
                     ("error_model", "Error model"), ("noise_corr_s", "Noise correlation"),
                     ("p_fa", "P_fa"), ("mask_deg", "Elevation mask"), ("seed", "Random seed"))
#: The fault editor's keyed controls, with their labels.
FAULT_CONTROLS = (("kind", "Type"), ("bias_m", "Bias"), ("rate_mps", "Ramp rate"),
                  ("t0_s", "Fault start"), ("t1_s", "Fault end"))

class ResultCache:
    """Scenario runs shared by every session of the process, least recently used first
    out (a run is a pure function of its scenario: its seed fixes every random draw).

    Parameters
    ----------
    max_items : at most this many runs.
    max_bytes : at most this many bytes of numpy arrays (:func:`result_nbytes`); the
        newest run is always kept.
    """

    def __init__(self, max_items: int = RESULT_CACHE_SIZE,
                 max_bytes: int = RESULT_CACHE_BYTES) -> None:
        self.max_items, self.max_bytes = int(max_items), int(max_bytes)
        self._items: OrderedDict[str, tuple[ScenarioResult, int]] = OrderedDict()
        self._lock = threading.Lock()

    @staticmethod
    def key(scenario: Scenario) -> str:
        return repr(scenario.to_dict())

    def get(self, scenario: Scenario) -> ScenarioResult | None:
        key = self.key(scenario)
        with self._lock:
            item = self._items.get(key)
            if item is None:
                return None
            self._items.move_to_end(key)
            return item[0]

    def put(self, scenario: Scenario, result: ScenarioResult) -> None:
        key = self.key(scenario)
        size = result_nbytes(result)
        with self._lock:
            self._items[key] = (result, size)
            self._items.move_to_end(key)
            while len(self._items) > 1 and (len(self._items) > self.max_items
                                            or self.nbytes > self.max_bytes):
                self._items.popitem(last=False)

    @property
    def nbytes(self) -> int:
        return sum(n for _, n in self._items.values())

    def __len__(self) -> int:
        return len(self._items)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


def result_nbytes(obj, _depth: int = 0) -> int:
    """Bytes of the numpy arrays in a run (dataclasses, dicts, lists, tuples walked)."""
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if _depth > 4:
        return 0
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return sum(result_nbytes(getattr(obj, f.name), _depth + 1)
                   for f in dataclasses.fields(obj))
    if isinstance(obj, dict):
        return sum(result_nbytes(v, _depth + 1) for v in obj.values())
    if isinstance(obj, list | tuple):
        return sum(result_nbytes(v, _depth + 1) for v in obj)
    return 0


#: The process's run cache (every session uses it).
RESULTS = ResultCache()


def run_view(result: ScenarioResult) -> RunView:
    """The figures' view of a scenario result."""
    data, out, s = result.measurements, result.output, result.scenario
    spec = algorithms.get(s.algorithm)
    extras = dict(out.extras)
    if "particles_ecef_m" in extras:  # shown as offsets from the true position
        extras["particles_enu_m"] = ecef_to_enu(extras.pop("particles_ecef_m"),
                                                result.truth.pos_rx_ecef_m[:, None, :])
    return RunView(
        table=result.table.columns, per_sat={k: np.asarray(v) for k, v in out.per_sat.items()},
        sat_names=data.sat_names, used=np.asarray(data.used),
        excluded=np.asarray(out.excluded, dtype=bool),
        fault_bias_m=np.asarray(result.truth.fault_bias_m), faulted=result.truth.faulted,
        az_rad=data.az_rad, el_rad=data.el_rad,
        hal_m=s.hal_m, val_m=s.val_m, mask_deg=s.mask_deg, algorithm=spec.label,
        isolated_idx=np.asarray(out.isolated, dtype=int), extras=extras)


def scene_run(result: ScenarioResult, view: RunView) -> SceneRun:
    data = result.measurements
    return SceneRun(t_s=data.t_s, sat_names=data.sat_names, pos_sv_ecef_m=data.pos_sv_ecef_m,
                    pos_rx_ecef_m=result.truth.pos_rx_ecef_m, state=view.states(),
                    mask_deg=result.scenario.mask_deg, fault_bias_m=view.fault_bias_m,
                    faulted=view.faulted)


def _probe_window(page_script: page.PageScript, session_ref) -> None:
    """Ask the page for its window size; give it to the session if it is still open."""
    size = page_script.probe_viewport()
    session = session_ref()
    if size is not None and session is not None and not session._closed:
        session.scheduler.submit("layout", lambda: session.set_window(*size))


def _camera_aspect(camera) -> float | None:
    """The 3D view's width/height as the camera last reported it, or None."""
    try:
        w, h = int(camera.image_width), int(camera.image_height)
    except (AttributeError, TypeError, ValueError):
        return None
    return w / h if w > 0 and h > 0 else None


def fault_label(k: int, f: Fault) -> str:
    """``"#1 G10 ramp 2 m/s, 120 s..end"``, ``"#2 GAL (constellation) step 20 m, 300 s..end"``."""
    size = f"{f.bias_m:g} m" if f.kind == "step" else f"{f.rate_mps:g} m/s"
    end = "end" if not math.isfinite(f.t1_s) else f"{f.t1_s:g} s"
    return f"#{k + 1} {f.target} {f.kind} {size}, {f.t0_s:g} s..{end}"


@dataclass
class Timing:
    """Server-side timings (s) of the last recompute, for the benchmark and the status
    line."""

    run_s: float = 0.0
    figures_s: float = 0.0
    push_s: float = 0.0
    total_s: float = 0.0
    n_recomputes: int = 0
    history: list = field(default_factory=list)


class Session:
    """The dashboard of one connected client.

    Parameters
    ----------
    client : viser ``ClientHandle`` (or anything with ``.gui`` and ``.scene``).
    scenario : the scenario this session starts from.
    presets : names (or TOML paths) offered by the scenario preset control.
    """

    def __init__(self, client, scenario: Scenario, presets: dict[str, str] | None = None,
                 lesson_dirs=()):
        from .scheduler import CoalescingScheduler

        self.client = client
        self.lesson_dirs = tuple(lesson_dirs)
        self.gui = client.gui
        self.scenario = scenario
        self.presets = dict(presets or {})
        self.scheduler = CoalescingScheduler(("layout", "recompute", "panel", "time"),
                                             on_error=self._show_error)
        self.timing = Timing()
        self.result: ScenarioResult | None = None
        self.view: RunView | None = None
        self.figures: dict[str, PanelFigure] = {}
        self.plot_handles: dict[str, object] = {}
        self._sent: dict[str, tuple[str, float]] = {}  # key -> (rev, aspect) on the page
        self.i_epoch = 0
        # Set while this thread writes controls itself (their callbacks then ignore the
        # change). Thread-local: the worker refreshing controls must not swallow a user
        # event arriving at the same moment on viser's event thread.
        self._sync_state = threading.local()
        self._fault_index = 0 if scenario.faults else -1
        self._play_stop = threading.Event()
        self._play_thread: threading.Thread | None = None
        self.option_controls: dict[str, KeyControl] = {}
        self._edit_lock = threading.RLock()  # one edit of the scenario at a time
        self._results = RESULTS
        self._upload_dir: str | None = None
        self._closed = False
        # The page: time updates and the window's size (app.page).
        self.page = page.PageScript(client)
        self._time_seq = 0
        self.window_px = page.DEFAULT_WINDOW
        self.controls_px, self.plots_px = page.side_panel_widths(self.window_px[0])
        self._probe_thread: threading.Thread | None = None
        self._probe_aspect: float | None = None
        self._camera_hooked = False
        # The 3D scene is built after the first plots are sent (_recompute): the page then
        # draws the plots before the Earth's meshes (the first frame of a software-rendered
        # 3D view takes about a second).
        self.scene: SkyScene | None = None
        self._build_gui()
        self.request_recompute()
        self._probe_window()

    # -- GUI construction --------------------------------------------------------------
    def _build_gui(self) -> None:
        """The control panel (left), the plot panel (right, one tab per view), then the
        callbacks. A new tab is one more ``with self.plot_panel.add_tab(...)`` block in
        :meth:`_build_side_panel`."""
        self.status = self.gui.add_markdown("**Starting...**")
        self.verdict_md = self.gui.add_markdown("")
        self._build_controls()
        self._build_side_panel()
        self._apply_panel_widths()
        self._connect_controls()
        self._build_option_controls()
        self._sync_fault_controls()

    def _build_controls(self) -> None:
        gui = self.gui
        s = self.scenario
        keys = scenario_keys()
        self.controls: dict[str, KeyControl] = {}
        with gui.add_folder("Scenario"):
            names = list(self.presets) or [s.name]
            self.preset = gui.add_dropdown("Preset", names,
                                           initial_value=s.name if s.name in names
                                           else names[0])
            self._preset_name = self.preset.value
            self.algorithm = gui.add_dropdown("Algorithm", algorithms.names(),
                                              initial_value=s.algorithm,
                                              hint=keys["algorithm"].help)
            for name, title in SCENARIO_CONTROLS:
                self.controls[name] = KeyControl(gui, keys[name], getattr(s, name),
                                                 title=title)
        c = self.controls
        self.sigma, self.noise_corr, self.p_fa = (c["sigma_m"].handle, c["noise_corr_s"].handle,
                                                  c["p_fa"].handle)
        self.mask, self.seed = c["mask_deg"].handle, c["seed"].handle
        self.options_folder = gui.add_folder("Algorithm options", expand_by_default=False)
        self.ism_controls = IsmControls(self, gui)  # hidden where ARAIM is not used
        t_end = float(s.duration_s)
        self.fault_controls: dict[str, KeyControl] = {}
        with gui.add_folder("Faults"):
            self.fault_pick = gui.add_dropdown("Fault to edit", [NO_FAULT])
            self.fault_sat = gui.add_dropdown(
                "Satellite", ["-"], hint="a satellite in view, or a system (GPS, GAL, ...): "
                "a constellation fault on all its satellites, each by the bias x "
                "sin(elevation)")
            fc = self.fault_controls
            for name, title in FAULT_CONTROLS:
                key = FAULT_KEYS[name]
                extra = {}
                if name == "t1_s":  # "until the end" is shown at the slider's right end
                    extra = dict(encode=self._t1_shown, decode=self._t1_of)
                if name in ("t0_s", "t1_s"):  # sliders over the run (a key without range)
                    key = dataclasses.replace(key, ui_lo=0.0, ui_hi=t_end,
                                              ui_step=float(s.step_s))
                    extra["control"] = "slider"
                fc[name] = KeyControl(gui, key, key.default, title=title, **extra)
            self.fault_kind, self.fault_bias, self.fault_rate = (
                fc["kind"].handle, fc["bias_m"].handle, fc["rate_mps"].handle)
            self.fault_t0, self.fault_t1 = fc["t0_s"].handle, fc["t1_s"].handle
            self.fault_add = gui.add_button("Add fault")
            self.fault_remove = gui.add_button("Remove fault")
        with gui.add_folder("Time"):
            self.time = gui.add_slider("t (s)", 0.0, max(t_end, s.step_s), s.step_s, 0.0)
            self.play = gui.add_checkbox(
                "Play", False, hint=f"Play the run: up to {PLAY_FPS:g} frames per second, "
                                    "as fast as this page draws them (shown below); "
                                    "Speed = simulated seconds per second")
            self.speed = gui.add_dropdown("Speed", PLAY_SPEEDS, initial_value="5x")
            self.play_rate_md = gui.add_markdown("")
        with gui.add_folder("3D view legend", expand_by_default=False):
            self.legend_md = gui.add_markdown("")
        with gui.add_folder("Recording (RINEX or phone log)", expand_by_default=s.recorded):
            self.rec_obs = gui.add_text("Observation file", s.obs,
                                        hint="a RINEX observation file or an Android "
                                             "GnssLogger raw log (told by its content): "
                                             "path on the server, or upload below")
            self.rec_nav = gui.add_text("Navigation files", "; ".join(s.nav),
                                        hint="path(s) on the server; several (e.g. one "
                                             "per system): separate them with ; (an "
                                             "upload adds to the list)")
            self.rec_open = gui.add_button("Open recording")
            self.rec_upload_obs = gui.add_upload_button("Upload observation file or log")
            self.rec_upload_nav = gui.add_upload_button("Upload navigation file")
            self.rec_notes = gui.add_markdown("")
            self.rec_use_corr = gui.add_button(
                "Use the measured noise correlation", visible=False,
                hint="set Noise correlation (s) to the Gauss-Markov time fitted to this "
                     "recording's errors: PF-LLR then calibrates its threshold on it")
        with gui.add_folder("Export", expand_by_default=False):
            self.export_csv = gui.add_button("Download table (CSV)")
            self.export_html = gui.add_button("Download figures (HTML)")

    def _build_side_panel(self) -> None:
        """Plots and teaching text in their own panel, docked right."""
        gui = self.gui
        self.plot_panel = gui.add_panel()
        with self.plot_panel.add_tab("Plots"):
            self.per_sat_pick = gui.add_dropdown("Per-satellite panel", [NO_OUTPUT])
            self.plots_folder = gui.add_folder("Panels")
            self.page.attach(gui, self.time.label)  # hidden: time updates to the plots
        with self.plot_panel.add_tab("Learn"):
            self.teach_md = gui.add_markdown("")
            with gui.add_folder("Report on this scenario", expand_by_default=False):
                self.report_md = gui.add_markdown(scenario_report_markdown(self.scenario))
        with self.plot_panel.add_tab("Lessons"):
            self.lessons_tab = add_lessons_tab(self, gui, self.lesson_dirs)
        with self.plot_panel.add_tab("Availability"):  # a world map in the background
            self.availability_view = AvailabilityView(self, gui)
        self.plot_panel.dock_right()
        self.gui.main_panel.dock_left()

    def _connect_controls(self) -> None:
        for name, ctl in self.controls.items():
            ctl.handle.on_update(lambda _e, c=ctl, n=name: self._on_key(
                c, lambda v: self.scenario.replace(**{n: v})))
        self.preset.on_update(lambda _e: self._on_preset())
        self.algorithm.on_update(lambda _e: self._on_algorithm())
        for name, ctl in self.fault_controls.items():
            ctl.handle.on_update(lambda _e, c=ctl, n=name: self._on_key(
                c, lambda v: self._with_fault_field(n, v), after=self._sync_fault_controls))
        self.fault_sat.on_update(lambda _e: self._on_fault_sat())
        self.fault_pick.on_update(lambda _e: self._on_fault_pick())
        self.fault_add.on_click(lambda _e: self._on_fault_add())
        self.fault_remove.on_click(lambda _e: self._on_fault_remove())
        self.time.on_update(lambda _e: self._on_time())
        self.per_sat_pick.on_update(lambda _e: self._on_per_sat_pick())
        self.play.on_update(lambda _e: self._on_play())
        self.rec_open.on_click(lambda _e: self._on_open_recording())
        self.rec_use_corr.on_click(lambda _e: self.use_measured_correlation())
        self.rec_upload_obs.on_upload(lambda _e: self._on_upload(self.rec_upload_obs,
                                                                 self.rec_obs))
        self.rec_upload_nav.on_upload(lambda _e: self._on_upload(self.rec_upload_nav,
                                                                 self.rec_nav))
        self.export_csv.on_click(lambda _e: self.download_csv())
        self.export_html.on_click(lambda _e: self.download_html())

    def _make_scene(self) -> SkyScene:
        """The 3D scene of this client (built with the first run)."""
        scene = SkyScene(self.client.scene, camera=getattr(self.client, "camera", None))
        scene.attach_legend(self.legend_md)
        return scene

    # -- sizes ----------------------------------------------------------------------------
    def _apply_panel_widths(self) -> None:
        self.gui.main_panel.set_width(self.controls_px)
        self.plot_panel.set_width(self.plots_px)

    def plot_aspect(self, fig: PanelFigure) -> float:
        """viser's aspect that draws ``fig`` at its height in the plot panel."""
        return page.plot_aspect(fig.height_px, self.plots_px)

    def set_window(self, width_px: int, height_px: int) -> None:
        """The browser window is ``width_px`` x ``height_px``: side panels sized from it
        (the 3D view keeps at least half), plots kept at their heights."""
        self.window_px = (int(width_px), int(height_px))
        widths = page.side_panel_widths(width_px)
        if widths == (self.controls_px, self.plots_px):
            return
        self.controls_px, self.plots_px = widths
        self._apply_panel_widths()
        for key, handle in list(self.plot_handles.items()):
            fig = self.figures.get(key)
            if fig is not None:
                aspect = self.plot_aspect(fig)
                handle.aspect = aspect
                rev = self._sent.get(key, ("", 0.0))[0]
                self._sent[key] = (rev, aspect)

    def _probe_window(self) -> None:
        """Ask the page for its window size (on a short-lived thread: the answer takes a
        round trip); a camera report whose aspect changed (a resized window) asks again."""
        if not self.page.live or self._closed:
            return
        if self._probe_thread is not None and self._probe_thread.is_alive():
            return
        cam = getattr(self.client, "camera", None)
        if not self._camera_hooked and cam is not None:
            cam.on_update(self._on_camera)
            self._camera_hooked = True
        self._probe_aspect = _camera_aspect(cam)
        # The thread holds the page, not the session: a tab closed while it waits for the
        # answer lets its session go at once (the thread ends with the connection).
        self._probe_thread = threading.Thread(
            target=_probe_window, args=(self.page, weakref.ref(self)), daemon=True,
            name="raim-window-probe")
        self._probe_thread.start()

    def _on_camera(self, camera) -> None:
        aspect = _camera_aspect(camera)
        if aspect is None or self._closed:
            return
        if self._probe_aspect is None or abs(aspect / self._probe_aspect - 1.0) > 0.02:
            self._probe_window()

    def _build_option_controls(self) -> None:
        """One control per option of the scenario's algorithm (``AlgorithmSpec.options``),
        each made from the option's key."""
        for ctl in self.option_controls.values():
            ctl.remove()
        self.option_controls = {}
        spec = algorithms.get(self.scenario.algorithm)
        current = self.scenario.algorithm_options()
        with self.options_folder:
            for k in spec.options:
                ctl = KeyControl(self.gui, k, current[k.name])
                ctl.handle.on_update(lambda _e, c=ctl, n=k.name: self._on_key(
                    c, lambda v: self.scenario.replace(**{n: v})))
                self.option_controls[k.name] = ctl
        self.teach_md.content = teaching.teaching_markdown(spec.label, spec.summary,
                                                           spec.equations, spec.reference)

    @property
    def _option_handles(self) -> dict[str, object]:
        """The option controls' viser handles, by option name."""
        return {name: ctl.handle for name, ctl in self.option_controls.items()}

    @property
    def _syncing(self) -> bool:
        return getattr(self._sync_state, "on", False)

    @_syncing.setter
    def _syncing(self, on: bool) -> None:
        self._sync_state.on = on

    # -- control -> scenario ------------------------------------------------------------
    def current_scenario(self) -> Scenario:
        """The scenario the controls show (the one the next recompute runs)."""
        return self.scenario

    def _on_key(self, ctl: KeyControl, apply: Callable[[object], Scenario],
                after: Callable[[], None] | None = None) -> None:
        """A user's entry in ``ctl``: the scenario ``apply(value)`` gives, or a one-line
        refusal that leaves scenario and control at the last valid value."""
        if self._syncing:
            return
        with self._edit_lock:
            try:
                value = ctl.read()
                if value == ctl.value:  # the value it already stood for: nothing to do
                    ctl.accept(value)
                    return
                new = apply(value)
            except ValueError as exc:
                if not input_error(exc):
                    raise
                self._refuse(exc, ctl.revert)
                return
            ctl.accept(value)
            changed = self._set_scenario(new)
            if after is not None:
                after()
        if changed:
            self.request_recompute()

    def _set_scenario(self, new: Scenario) -> bool:
        """Make ``new`` the session's scenario; True when it differs from the old one."""
        old, self.scenario = self.scenario, new
        self.ism_controls.show(new)  # the ISM folder follows (systems, visibility)
        return new != old or new.to_dict() != old.to_dict()

    def _attempt(self, make: Callable[[], Scenario], revert: Callable[[], None]
                 ) -> Scenario | None:
        """``make()`` (a new scenario), or None after refusing a bad input with
        :meth:`_refuse`; anything else (a bug) is raised."""
        try:
            return make()
        except ValueError as exc:
            if not input_error(exc):
                raise
            self._refuse(exc, revert)
            return None

    def _refuse(self, exc: BaseException, revert: Callable[[], None]) -> None:
        """A refused entry: the control shows the last valid value again, the status line
        says why (one line naming the key), the log gets one line (no traceback)."""
        self._syncing = True
        try:
            revert()
        finally:
            self._syncing = False
        log.info("refused: %s", exc)
        self._show_error(exc)

    def _on_algorithm(self) -> None:
        if self._syncing:
            return
        with self._edit_lock:
            name = self.algorithm.value
            if name == self.scenario.algorithm:
                return
            new = self._attempt(lambda: self.scenario.replace(algorithm=name),
                                lambda: setattr(self.algorithm, "value",
                                                self.scenario.algorithm))
            if new is None:
                return
            self._set_scenario(new)
            self._build_option_controls()
        self.request_recompute()

    def _on_preset(self) -> None:
        if self._syncing:
            return
        if self.preset.value == self._preset_name:
            return  # the preset open now (edited or not): a touch is not a reload
        target = self.presets.get(self.preset.value, self.preset.value)
        scenario = self._attempt(
            lambda: target if isinstance(target, Scenario) else load_scenario(target),
            lambda: setattr(self.preset, "value", self.scenario.name))
        if scenario is None:
            return
        self._preset_name = self.preset.value
        self.open_scenario(scenario)

    def open_scenario(self, scenario: Scenario) -> None:
        """Switch this session to ``scenario``: controls, fault editor and time follow."""
        with self._edit_lock:
            self.scenario = s = scenario
            self._syncing = True
            try:
                self._show_preset(s)
                if s.recorded:
                    self.rec_obs.value, self.rec_nav.value = str(s.obs), "; ".join(s.nav)
                self.algorithm.value = s.algorithm
                for name, ctl in self.controls.items():
                    ctl.show(getattr(s, name))
                    ctl.reset_range()
                self.time.max = float(s.duration_s)
                self.time.step = float(s.step_s)
                self.time.value = 0.0
                self._fault_index = 0 if s.faults else -1
                self._build_option_controls()
                self.ism_controls.show(s)
                self.report_md.content = scenario_report_markdown(s)
            finally:
                self._syncing = False
            self._sync_fault_controls()
            for ctl in self.fault_controls.values():
                ctl.reset_range()
        self.request_recompute()

    def _show_preset(self, s: Scenario) -> None:
        """The Preset dropdown names the scenario now open: a scenario opened from
        elsewhere (a lesson, a recording) becomes a preset of this session."""
        self.presets.setdefault(s.name, s)
        if tuple(self.preset.options) != tuple(self.presets):
            self.preset.options = list(self.presets)
        self.preset.value = self._preset_name = s.name

    # -- recordings ---------------------------------------------------------------------
    @staticmethod
    def _nav_paths(text: str) -> list[str]:
        """The navigation files of the Recording folder's field: paths separated by
        ``;`` (shown joined by ``"; "``), blanks ignored."""
        return [p.strip() for p in text.split(";") if p.strip()]

    def open_recording(self, obs: str, nav: str | list[str]) -> None:
        """Open a recording (paths on the server) and offer it as a preset: ``obs`` a RINEX
        observation file or a phone's GnssLogger log, told by its content
        (:func:`raimcore.sky.recording.observation_source`); ``nav`` a list of navigation
        files, or one string of them separated by ``;``."""
        from raimcore.scenario import recording_scenario

        if isinstance(nav, str):
            nav = self._nav_paths(nav)
        scenario = recording_scenario(obs, nav, algorithm=self.scenario.algorithm)
        self.presets[scenario.name] = scenario  # re-opened: the file's new content
        self.open_scenario(scenario)

    def _on_open_recording(self) -> None:
        try:
            self.open_recording(self.rec_obs.value.strip(), self.rec_nav.value.strip())
        except ValueError as exc:
            if not input_error(exc):
                raise
            log.info("recording refused: %s", exc)
            self._show_error(exc)

    def use_measured_correlation(self) -> float | None:
        """Set the noise-correlation control to the Gauss-Markov time fitted to the open
        recording's errors (:func:`raimcore.sky.recording.error_statistics`); returns it, or
        None when there is no recording or no finite positive fit."""
        from raimcore.measure import error_statistics

        if self.result is None or not self.result.scenario.recorded:
            return None
        try:
            corr = error_statistics(self.result.measurements, self.result.truth).corr_s
        except ValueError as exc:
            self._show_error(exc)
            return None
        if not (0.0 < corr < math.inf):
            return None
        step = float(self.noise_corr.step)
        value = float(round(corr / step) * step)  # on the control's grid
        self.noise_corr.value = value  # a user's entry: checked, shown (widening), run
        return value

    def _on_upload(self, button, field) -> None:
        """Save an uploaded file in this session's temporary folder (a navigation file is
        added to the list of them); open the recording once both kinds are there."""
        up = button.value
        if self._upload_dir is None:
            self._upload_dir = tempfile.mkdtemp(prefix="raim-upload-")
        path = Path(self._upload_dir) / (Path(up.name).name or "upload.rnx")
        path.write_bytes(up.content)
        self._syncing = True
        try:
            if field is self.rec_nav:
                have = self._nav_paths(field.value)
                if str(path) not in have:
                    have.append(str(path))
                field.value = "; ".join(have)
            else:
                field.value = str(path)
        finally:
            self._syncing = False
        navs = self._nav_paths(self.rec_nav.value)
        obs = self.rec_obs.value.strip()
        if obs and navs and all(Path(p).is_file() for p in (obs, *navs)):
            self._on_open_recording()

    # -- faults -------------------------------------------------------------------------
    def _visible_sats(self) -> list[str]:
        if self.result is None:
            return list(self.scenario.sats) or ["-"]
        data = self.result.measurements
        used = np.asarray(data.used).any(axis=0)
        return [n for n, u in zip(data.sat_names, used, strict=True) if u]

    def _fault_targets(self) -> list[str]:
        """What the Satellite dropdown offers: the visible satellites, then the scenario's
        systems (a constellation fault)."""
        return [*self._visible_sats(), *self.scenario.systems]

    def _t1_shown(self, t1_s: float) -> float:
        """The fault-end slider's position for ``t1_s``: "until the end" at the run's end."""
        return float(self.scenario.duration_s) if t1_s == math.inf else float(t1_s)

    def _t1_of(self, x: float) -> float:
        """The fault end a user's slider position means (the run's end and beyond: none)."""
        return math.inf if x >= self.scenario.duration_s else float(x)

    def _sync_fault_controls(self) -> None:
        """Show the selected fault in the editor controls (without recomputing)."""
        s = self.scenario
        faults = s.faults
        fc = self.fault_controls
        self._syncing = True
        try:
            labels = [fault_label(k, f) for k, f in enumerate(faults)] or [NO_FAULT]
            self.fault_pick.options = labels
            visible = self._fault_targets()
            for name in ("t0_s", "t1_s"):
                fc[name].set_usual_range(0.0, float(s.duration_s), float(s.step_s))
            editing = 0 <= self._fault_index < len(faults)
            if editing:
                f = faults[self._fault_index]
                self.fault_pick.value = labels[self._fault_index]
                self.fault_sat.options = visible if f.sat in visible else [*visible, f.sat]
                self.fault_sat.value = f.sat
                fc["kind"].show(f.kind)
                # The inactive size shows what a change of type would give.
                fc["bias_m"].show(f.bias_m if f.kind == "step" or f.bias_m != 0.0
                                  else NEW_FAULT_BIAS_M)
                fc["rate_mps"].show(f.rate_mps if f.kind == "ramp" or f.rate_mps != 0.0
                                    else NEW_FAULT_RATE_MPS)
                fc["t0_s"].show(f.t0_s)
                fc["t1_s"].show(f.t1_s)
                for ctl in fc.values():
                    ctl.name = f"fault {f.sat} {ctl.key.name}"
            else:
                self.fault_pick.value = labels[0]
                self.fault_sat.options = visible
                fc["t1_s"].show(math.inf)
            for h in (self.fault_sat, *(c.handle for c in fc.values()), self.fault_remove):
                h.disabled = not editing
            if editing:
                self.fault_bias.disabled = f.kind != "step"
                self.fault_rate.disabled = f.kind != "ramp"
        finally:
            self._syncing = False

    def _refresh_fault_sats(self) -> None:
        """Offer the satellites visible in the current run and the scenario's systems
        (plus the edited fault's satellite)."""
        visible = self._fault_targets()
        current = self.fault_sat.value
        opts = visible if (current in visible or self._fault_index < 0) else [*visible, current]
        if list(self.fault_sat.options) != opts:
            self._syncing = True
            try:
                self.fault_sat.options = opts
                if self._fault_index >= 0:
                    self.fault_sat.value = current
            finally:
                self._syncing = False

    def _with_fault_field(self, name: str, value) -> Scenario:
        """The scenario with one field of the edited fault changed (the fault and the
        scenario check it). A change of type takes the size its control shows."""
        faults = list(self.scenario.faults)
        k = self._fault_index
        if not 0 <= k < len(faults):
            return self.scenario
        f = faults[k]
        changes = {name: value}
        if name == "kind" and value != f.kind:
            size = "bias_m" if value == "step" else "rate_mps"
            changes[size] = self.fault_controls[size].value
        faults[k] = dataclasses.replace(f, **changes)
        return self.scenario.with_faults(*faults)

    def _on_fault_sat(self) -> None:
        if self._syncing or not (0 <= self._fault_index < len(self.scenario.faults)):
            return
        with self._edit_lock:
            sat = self.fault_sat.value
            if sat == self.scenario.faults[self._fault_index].sat:
                return
            new = self._attempt(lambda: self._with_fault_field("sat", sat),
                                self._sync_fault_controls)
            if new is None:
                return
            self._set_scenario(new)
        self._sync_fault_controls()
        self.request_recompute()

    def _on_fault_pick(self) -> None:
        if self._syncing:
            return
        labels = [fault_label(k, f) for k, f in enumerate(self.scenario.faults)]
        if self.fault_pick.value in labels:
            self._fault_index = labels.index(self.fault_pick.value)
        self._sync_fault_controls()

    def add_fault(self, fault: Fault | None = None) -> None:
        """Add a fault (default: a step of the bias key's default size on a visible
        satellite not yet faulty, from a third of the run)."""
        with self._edit_lock:
            if fault is None:
                taken = {f.sat for f in self.scenario.faults}
                free = ([n for n in self._visible_sats() if n not in taken]
                        or self._visible_sats())
                t_mid = float(self.scenario.duration_s) / 3.0
                fault = Fault(sat=free[0], kind="step", t0_s=float(round(t_mid)),
                              bias_m=NEW_FAULT_BIAS_M)
            new = self._attempt(lambda: self.scenario.with_faults(*self.scenario.faults, fault),
                                lambda: None)
            if new is None:
                return
            self._set_scenario(new)
            self._fault_index = len(self.scenario.faults) - 1
        self._sync_fault_controls()
        self.request_recompute()

    def _on_fault_add(self) -> None:
        self.add_fault()

    def remove_fault(self, index: int | None = None) -> None:
        with self._edit_lock:
            k = self._fault_index if index is None else index
            faults = list(self.scenario.faults)
            if not (0 <= k < len(faults)):
                return
            del faults[k]
            self._set_scenario(self.scenario.with_faults(*faults))
            self._fault_index = min(k, len(faults) - 1)
        self._sync_fault_controls()
        self.request_recompute()

    def _on_fault_remove(self) -> None:
        self.remove_fault()

    # -- recompute ----------------------------------------------------------------------
    def request_recompute(self) -> None:
        self.scheduler.submit("recompute", self._recompute)

    def _recompute(self) -> None:
        t0 = time.perf_counter()
        scenario = self.current_scenario()
        try:
            result = self._run_cached(scenario)
        except ValueError as exc:
            if not input_error(exc):
                raise  # a bug: the scheduler logs its traceback
            log.info("run refused: %s", exc)  # bad input: one line, no traceback
            self._show_error(exc)
            return
        if self._closed:
            return
        t1 = time.perf_counter()
        view = run_view(result)
        figs = {key: build(view)
                for key, build in panels.panels_for(view, self.per_sat_pick.value)}
        verdict = teaching.verdict(view, result.summary, result.p_fa,
                                   faults=result.scenario.faults)
        t2 = time.perf_counter()
        if self._closed:  # the tab closed while the figures were built: nothing to send
            return
        self.result, self.view, self.figures = result, view, figs
        self.i_epoch = self._time_index(float(self.time.value))
        # Plots first, in batches of GUI messages of their own: the page draws those at
        # once, while a batch with 3D-scene messages waits for the 3D view's next frame.
        self.verdict_md.content = f"**Verdict.** {html.escape(verdict)}"
        self._push_figures()
        self._flush_batch()
        with self.client.atomic():
            if self.scene is None:
                self.scene = self._make_scene()
            self.scene.i_epoch = self.i_epoch
            self.scene.set_run(scene_run(result, view))
        t3 = time.perf_counter()
        tm = self.timing
        tm.run_s, tm.figures_s, tm.push_s, tm.total_s = t1 - t0, t2 - t1, t3 - t2, t3 - t0
        tm.n_recomputes += 1
        tm.history.append((tm.run_s, tm.figures_s, tm.push_s, tm.total_s))
        del tm.history[:-100]
        self.status.content = (f"**{scenario.name}** · {len(result.measurements.t_s)} "
                               f"epochs · {len(result.measurements.sat_names)} satellites · "
                               f"update "
                               f"{1e3 * tm.total_s:.0f} ms")
        self.rec_notes.content = "".join(f"- {html.escape(n)}\n"
                                         for n in result.summary.notes)
        self.rec_use_corr.visible = scenario.recorded
        self._refresh_fault_sats()
        self._refresh_per_sat_pick()
        self.client.flush()

    def _refresh_per_sat_pick(self) -> None:
        keys = panels.per_sat_keys(self.view) or [NO_OUTPUT]
        if list(self.per_sat_pick.options) != keys:
            self._syncing = True
            try:
                current = self.per_sat_pick.value
                self.per_sat_pick.options = keys
                self.per_sat_pick.value = current if current in keys else keys[0]
            finally:
                self._syncing = False

    def _on_per_sat_pick(self) -> None:
        if not self._syncing:
            self.scheduler.submit("panel", self._rebuild_per_sat)

    def _rebuild_per_sat(self) -> None:
        """Show another per-satellite output: one figure rebuilt, no engine run."""
        if self.view is None or self.per_sat_pick.value == NO_OUTPUT:
            return
        from .figures import per_sat_figure

        self.figures["per_sat"] = per_sat_figure(self.view, self.per_sat_pick.value)
        self._push_figures()

    def _run_cached(self, scenario: Scenario) -> ScenarioResult:
        """Run the scenario, or reuse the result of an identical recent one, from this
        session or another (:data:`RESULTS`)."""
        result = self._results.get(scenario)
        if result is None:
            result = _run_scenario(scenario)
            self._results.put(scenario, result)
        return result

    def _push_figures(self) -> None:
        """Send the figures the page does not have yet (a new static part or size), then
        one time update for all of them (:meth:`_send_time`)."""
        keep = set(self.figures)
        for key in list(self.plot_handles):
            if key not in keep:
                self.plot_handles.pop(key).remove()
                self._sent.pop(key, None)
        seq = self._time_seq + 1  # the time update sent right after these figures
        n_sent = 0
        for order, (key, fig) in enumerate(self.figures.items()):
            handle = self.plot_handles.get(key)
            aspect = self.plot_aspect(fig)
            if handle is None:
                with self.plots_folder:
                    handle = self.gui.add_plotly(fig.at(self.i_epoch, seq), aspect=aspect,
                                                 order=order)
                self.plot_handles[key] = handle
                n_sent += 1
            else:
                if self._sent.get(key) != (fig.rev, aspect):
                    handle.figure = fig.at(self.i_epoch, seq)
                    if handle.aspect != aspect:
                        handle.aspect = aspect
                    n_sent += 1
                if handle.order != order:
                    handle.order = order
            self._sent[key] = (fig.rev, aspect)
            if n_sent == 1 and order == 0:
                self._flush_batch()  # the top panel is drawn while the others are made
        if self.plot_handles:
            # plotly.js is in the page with the first plot.
            self.page.install_helper(self.time.label)
        self._send_time(self.i_epoch)

    # -- time ---------------------------------------------------------------------------
    def _time_index(self, t_s: float) -> int:
        if self.result is None:
            return 0
        t = self.result.measurements.t_s
        return int(np.clip(np.searchsorted(t, t_s - 1e-9), 0, len(t) - 1))

    def _on_time(self) -> None:
        self.scheduler.submit("time", self._apply_time)

    def _apply_time(self) -> None:
        i = self._time_index(float(self.time.value))
        if self.scene is None or (i == self.i_epoch and self.scene.i_epoch == i):
            return
        self.i_epoch = i
        self._send_time(i)  # the plots: a GUI batch of its own (see _recompute)
        self._flush_batch()
        with self.client.atomic():
            self.scene.set_time(i)
        self.client.flush()  # now, not at the end of viser's next 16 ms window

    def time_state(self, i_epoch: int) -> dict:
        """What the page needs to show epoch ``i_epoch`` on the plots it has: the
        cursor's time and each dynamic figure's traces (:mod:`app.page`)."""
        t = self.result.measurements.t_s if self.result is not None else np.zeros(1)
        i = int(np.clip(i_epoch, 0, len(t) - 1))
        dyn = {}
        for fig in self.figures.values():
            st = fig.time_state(i)
            if st is not None:
                dyn[fig.key] = st  # the page knows a figure by its key (layout.meta.raim)
        grid = None
        if len(t) >= 2:
            dt = float(t[1] - t[0])
            if dt > 0 and np.allclose(np.diff(t), dt, rtol=0.0, atol=1e-9 * max(1.0, t[-1])):
                grid = {"t0": float(t[0]), "dt": dt, "n": int(len(t))}
        return {"seq": self._time_seq, "t": float(t[i]), "grid": grid, "dyn": dyn}

    def _flush_batch(self) -> None:
        """Send what is queued as one batch now: flush, and let viser's event loop take
        it before more is queued (a short sleep releases the GIL to its thread)."""
        self.client.flush()
        time.sleep(BATCH_GAP_S)

    def _send_time(self, i_epoch: int) -> None:
        self._time_seq += 1
        self.page.send_time(self.time_state(i_epoch))

    def _on_play(self) -> None:
        if self.play.value and (self._play_thread is None or not self._play_thread.is_alive()):
            self._play_stop.clear()
            self._play_thread = threading.Thread(target=self._play_loop, daemon=True)
            self._play_thread.start()
        elif not self.play.value:
            self._play_stop.set()

    def _play_loop(self) -> None:
        """Play: simulated time advances by Speed x the real time elapsed, in frames sent
        at a rate that follows what the page paints (a page that draws slower than
        PLAY_FPS gets fewer frames, not a backlog it would drop). Once a second the page
        says how many updates it painted; the frames are sent at 1.2 x the last second's
        rate + 1, and the rate painted since Play started is shown under the controls."""
        rate = PLAY_FPS
        t_play = float(self.time.value)
        last = t_check = time.monotonic()
        painted0 = self.page.painted_count(timeout_s=1.0)
        first = (painted0, t_check)  # the rate shown: painted since Play started
        while not self._play_stop.is_set():
            now = time.monotonic()
            t_play += float(self.speed.value.rstrip("x")) * (now - last)
            last = now
            if t_play > float(self.time.max):
                t_play = 0.0
            self.time.value = t_play
            if now - t_check >= 1.0:
                painted = self.page.painted_count(timeout_s=1.0)
                if painted is not None and painted0 is not None:
                    drawn = (painted - painted0) / (time.monotonic() - t_check)
                    rate = min(PLAY_FPS, 1.2 * drawn + 1.0)  # probe one frame/s above
                    if first[0] is None:
                        first = (painted0, t_check)
                    shown = (painted - first[0]) / (time.monotonic() - first[1])
                    self.play_rate_md.content = (
                        f"Playing at {shown:.1f} frames/s (at most {PLAY_FPS:g}: as fast "
                        "as this page paints)")
                painted0, t_check = painted, time.monotonic()
            self._play_stop.wait(max(now + 1.0 / rate - time.monotonic(), 0.0))
        self.play_rate_md.content = ""

    # -- export -------------------------------------------------------------------------
    def table_csv(self) -> bytes:
        if self.result is None:
            return b""
        buf = io.StringIO()
        tbl = self.result.table
        buf.write(",".join(tbl.names) + "\n")
        for row in tbl.rows():
            buf.write(",".join("" if isinstance(v, float) and math.isnan(v) else str(v)
                               for v in row.values()) + "\n")
        return buf.getvalue().encode()

    def figures_html(self) -> bytes:
        """All panels as one standalone HTML page (plotly.js embedded, no CDN)."""
        import plotly.io as pio

        parts = []
        for k, fig in enumerate(self.figures.values()):
            # At the current time: the sky plot's and the particle cloud's "now" included.
            parts.append(pio.to_html(fig.to_plotly(self.i_epoch), full_html=False,
                                     include_plotlyjs=(k == 0)))
        verdict = (html.escape(teaching.verdict(self.view, self.result.summary,
                                                self.result.p_fa,
                                                faults=self.result.scenario.faults))
                   if self.view is not None else "")
        name = html.escape(self.scenario.name)
        page = ("<!doctype html><html><head><meta charset='utf-8'><title>RAIM Studio: "
                f"{name}</title></head><body><h2>RAIM Studio: {name}</h2><p>{verdict}</p>"
                + "\n".join(parts) + "</body></html>")
        return page.encode()

    def download_csv(self) -> None:
        self.client.send_file_download(f"{self.scenario.name}.csv", self.table_csv())

    def download_html(self) -> None:
        self.client.send_file_download(f"{self.scenario.name}-figures.html",
                                       self.figures_html())

    # -- lifecycle ----------------------------------------------------------------------
    def _show_error(self, exc: BaseException) -> None:
        """The status line says what went wrong, in one line."""
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        try:
            self.status.content = f"**Error:** {html.escape(text)}"
        except Exception:  # noqa: BLE001 - the client may be gone
            pass

    def close(self, wait_s: float = CLOSE_WAIT_S) -> None:
        """Let go of everything: stop Play and the worker (waiting up to ``wait_s`` for
        a running job), drop figures, runs and handles, remove uploads."""
        self._closed = True
        self._play_stop.set()
        self.availability_view.close(wait_s)  # cancels a running map, joins its thread
        self.scheduler.close()
        self.scheduler.wait_idle(wait_s)
        play = self._play_thread
        if play is not None and play is not threading.current_thread():
            play.join(timeout=wait_s)
        self._play_thread = self._probe_thread = None
        self.figures, self.plot_handles, self._sent = {}, {}, {}
        self.result = self.view = None
        self.page.last_state = None
        if self._upload_dir is not None:
            shutil.rmtree(self._upload_dir, ignore_errors=True)
            self._upload_dir = None


def scenario_report_markdown(scenario: Scenario) -> str:
    """The report beside a built-in scenario (``raim show NAME``), or a line saying there
    is none; a recording points to the real-data report (a phone log: the phone report)."""
    from raimcore.scenario import scenario_report

    name = {"rinex": "recordings", "android": "android"}.get(scenario.source, scenario.name)
    report = scenario_report(name)
    if report is None:
        return (f"No report for *{html.escape(scenario.name)}*: the built-in scenarios have "
                "one (`raim show NAME`).")
    return report


def preset_table() -> dict[str, str]:
    """Built-in scenario names offered by the preset control."""
    return {name: name for name in list_scenarios()}
