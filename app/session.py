"""One browser tab = one :class:`Session`: its own controls, 3D scene, run and worker.

Every control change edits the session's :class:`~raimcore.scenario.Scenario` and submits
a recompute to the session's :class:`~app.scheduler.CoalescingScheduler` (never two at
once; a burst of slider moves ends on the last value). A recompute runs the scenario
through :func:`raimcore.scenario.run_scenario`, rebuilds the panels the run calls for (the
panel registry, :mod:`app.panels`), the teaching text and the verdict, and updates the 3D
scene. Moving the time slider only moves the scene and the panels' time markers.
"""

from __future__ import annotations

import html
import io
import math
import shutil
import tempfile
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from raimcore import algorithms
from raimcore.geometry import ecef_to_enu
from raimcore.measure.faults import Fault
from raimcore.pipeline import ScenarioResult
from raimcore.pipeline import run_scenario as _run_scenario
from raimcore.scenario import Scenario, list_scenarios, load_scenario

from . import panels, teaching
from .figures import PanelFigure, RunView
from .scene import SceneRun, SkyScene

NO_FAULT = "(no fault)"
NO_OUTPUT = "(none)"
PLAY_SPEEDS = ("1x", "5x", "20x", "60x")
PLAY_FPS = 8.0
PLOT_PANEL_WIDTH = 500
RESULT_CACHE_SIZE = 8  # recent runs kept per session: going back to a setting is instant


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
                    mask_deg=result.scenario.mask_deg)


def fault_label(k: int, f: Fault) -> str:
    size = f"{f.bias_m:g} m" if f.kind == "step" else f"{f.rate_mps:g} m/s"
    end = "end" if not math.isfinite(f.t1_s) else f"{f.t1_s:g} s"
    return f"#{k + 1} {f.sat} {f.kind} {size}, {f.t0_s:g} s..{end}"


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

    def __init__(self, client, scenario: Scenario, presets: dict[str, str] | None = None):
        from .scheduler import CoalescingScheduler

        self.client = client
        self.gui = client.gui
        self.scenario = scenario
        self.presets = dict(presets or {})
        self.scheduler = CoalescingScheduler(("recompute", "panel", "time"),
                                             on_error=self._show_error)
        self.timing = Timing()
        self.result: ScenarioResult | None = None
        self.view: RunView | None = None
        self.figures: dict[str, PanelFigure] = {}
        self.plot_handles: dict[str, object] = {}
        self.i_epoch = 0
        # Set while this thread writes controls itself (their callbacks then ignore the
        # change). Thread-local: the worker refreshing controls must not swallow a user
        # event arriving at the same moment on viser's event thread.
        self._sync_state = threading.local()
        self._fault_index = 0 if scenario.faults else -1
        self._play_stop = threading.Event()
        self._play_thread: threading.Thread | None = None
        self._option_handles: dict[str, object] = {}
        self._cache: OrderedDict[str, ScenarioResult] = OrderedDict()
        self._upload_dir: str | None = None
        self.scene = SkyScene(client.scene)
        self._build_gui()
        self.request_recompute()

    # -- GUI construction --------------------------------------------------------------
    def _build_gui(self) -> None:
        gui = self.gui
        s = self.scenario
        self.status = gui.add_markdown("**Starting...**")
        self.verdict_md = gui.add_markdown("")
        with gui.add_folder("Scenario"):
            names = list(self.presets) or [s.name]
            self.preset = gui.add_dropdown("Preset", names,
                                           initial_value=s.name if s.name in names
                                           else names[0])
            self.algorithm = gui.add_dropdown("Algorithm", algorithms.names(),
                                              initial_value=s.algorithm)
            self.sigma = gui.add_slider("Noise sigma (m)", 0.1, 50.0, 0.1, s.sigma_m)
            self.noise_corr = gui.add_slider(
                "Noise correlation (s)", 0.0, max(3600.0, s.noise_corr_s), 5.0, s.noise_corr_s,
                hint="correlation time of the noise (first-order Gauss-Markov); 0 = white. "
                     "On a recording: the assumed correlation of the real errors")
            self.p_fa = gui.add_number("P_fa", s.p_fa, min=1e-9, max=0.5, step=1e-6)
            self.mask = gui.add_slider("Elevation mask (deg)", 0.0, 40.0, 1.0, s.mask_deg)
            self.seed = gui.add_number("Random seed", int(s.seed), min=0, max=2**31 - 1,
                                       step=1)
        self.options_folder = gui.add_folder("Algorithm options", expand_by_default=False)
        with gui.add_folder("Faults"):
            self.fault_pick = gui.add_dropdown("Fault to edit", [NO_FAULT])
            self.fault_sat = gui.add_dropdown("Satellite", ["-"])
            self.fault_kind = gui.add_dropdown("Type", ["step", "ramp"])
            self.fault_bias = gui.add_slider("Bias (m)", 0.0, 500.0, 1.0, 100.0)
            self.fault_rate = gui.add_slider("Ramp rate (m/s)", 0.0, 20.0, 0.1, 2.0)
            t_end = float(s.duration_s)
            self.fault_t0 = gui.add_slider("Fault start (s)", 0.0, t_end, s.step_s, 0.0)
            self.fault_t1 = gui.add_slider("Fault end (s)", 0.0, t_end, s.step_s, t_end)
            self.fault_add = gui.add_button("Add fault")
            self.fault_remove = gui.add_button("Remove fault")
        with gui.add_folder("Time"):
            self.time = gui.add_slider("t (s)", 0.0, max(t_end, s.step_s), s.step_s, 0.0)
            self.play = gui.add_checkbox("Play", False)
            self.speed = gui.add_dropdown("Speed", PLAY_SPEEDS, initial_value="5x")
        with gui.add_folder("Recording (RINEX)", expand_by_default=s.source == "rinex"):
            self.rec_obs = gui.add_text("Observation file", s.obs,
                                        hint="path on the server, or upload below")
            self.rec_nav = gui.add_text("Navigation file", s.nav)
            self.rec_open = gui.add_button("Open recording")
            self.rec_upload_obs = gui.add_upload_button("Upload observation file")
            self.rec_upload_nav = gui.add_upload_button("Upload navigation file")
            self.rec_notes = gui.add_markdown("")
            self.rec_use_corr = gui.add_button(
                "Use the measured noise correlation", visible=False,
                hint="set Noise correlation (s) to the Gauss-Markov time fitted to this "
                     "recording's errors: PF-LLR then calibrates its threshold on it")
        with gui.add_folder("Export", expand_by_default=False):
            self.export_csv = gui.add_button("Download table (CSV)")
            self.export_html = gui.add_button("Download figures (HTML)")
        # Plots and teaching text in their own dockable panel.
        self.plot_panel = gui.add_panel()
        with self.plot_panel.add_tab("Plots"):
            self.per_sat_pick = gui.add_dropdown("Per-satellite panel", [NO_OUTPUT])
            self.plots_folder = gui.add_folder("Panels")
        with self.plot_panel.add_tab("Learn"):
            self.teach_md = gui.add_markdown("")
        self.plot_panel.dock_right()
        self.plot_panel.set_width(PLOT_PANEL_WIDTH)
        gui.main_panel.dock_left()
        gui.main_panel.set_width(340)

        for h in (self.sigma, self.noise_corr, self.p_fa, self.mask, self.seed):
            h.on_update(lambda _e: self._on_control())
        self.preset.on_update(lambda _e: self._on_preset())
        self.algorithm.on_update(lambda _e: self._on_algorithm())
        for h in (self.fault_sat, self.fault_kind, self.fault_bias, self.fault_rate,
                  self.fault_t0, self.fault_t1):
            h.on_update(lambda _e: self._on_fault_edit())
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
        self._build_option_controls()
        self._sync_fault_controls()

    def _build_option_controls(self) -> None:
        """One control per option of the chosen algorithm (``AlgorithmSpec.options``)."""
        for h in self._option_handles.values():
            h.remove()
        self._option_handles = {}
        spec = algorithms.get(self.algorithm.value)
        current = {**spec.defaults, **{k: v for k, v in self.scenario.options}}
        with self.options_folder:
            for k in spec.options:
                value = current.get(k.name, k.default)
                if k.kind == "bool":
                    h = self.gui.add_checkbox(k.name, bool(value), hint=k.help)
                elif k.kind == "choice":
                    h = self.gui.add_dropdown(k.name, k.choices, initial_value=value,
                                              hint=k.help)
                elif k.kind in ("int", "float"):
                    h = self.gui.add_number(k.name, value, hint=k.help)
                else:
                    h = self.gui.add_text(k.name, str(value), hint=k.help)
                h.on_update(lambda _e: self._on_control())
                self._option_handles[k.name] = h
        self.teach_md.content = teaching.teaching_markdown(spec.label, spec.summary,
                                                           spec.equations, spec.reference)

    @property
    def _syncing(self) -> bool:
        return getattr(self._sync_state, "on", False)

    @_syncing.setter
    def _syncing(self, on: bool) -> None:
        self._sync_state.on = on

    # -- control -> scenario ------------------------------------------------------------
    def current_scenario(self) -> Scenario:
        """The scenario the controls describe now."""
        changes = {
            "algorithm": self.algorithm.value, "sigma_m": float(self.sigma.value),
            "noise_corr_s": float(self.noise_corr.value),
            "p_fa": float(self.p_fa.value), "mask_deg": float(self.mask.value),
            "seed": int(self.seed.value),
        }
        keys = algorithms.get(self.algorithm.value).option_keys
        for name, h in list(self._option_handles.items()):
            if name not in keys:  # controls of the previous algorithm, going away
                continue
            val = h.value
            if keys[name].kind == "float_or_auto" and isinstance(val, str) \
                    and val.strip().lower() != "auto":
                from raimcore.scenario import parse_value

                val = parse_value(val.strip())
            changes[name] = val
        return self.scenario.replace(**changes)

    def _on_algorithm(self) -> None:
        if self._syncing:
            return
        self._build_option_controls()
        self.request_recompute()

    def _on_control(self) -> None:
        if not self._syncing:
            self.request_recompute()

    def _on_preset(self) -> None:
        if self._syncing:
            return
        target = self.presets.get(self.preset.value, self.preset.value)
        self.open_scenario(target if isinstance(target, Scenario) else load_scenario(target))

    def open_scenario(self, scenario: Scenario) -> None:
        """Switch this session to ``scenario``: controls, fault editor and time follow."""
        self.scenario = scenario
        self._syncing = True
        try:
            s = self.scenario
            self.algorithm.value = s.algorithm
            self.sigma.value = s.sigma_m
            self.noise_corr.max = max(float(self.noise_corr.max), s.noise_corr_s)
            self.noise_corr.value = s.noise_corr_s
            self.p_fa.value = s.p_fa
            self.mask.value = s.mask_deg
            self.seed.value = int(s.seed)
            for h in (self.fault_t0, self.fault_t1, self.time):
                h.max = float(s.duration_s)
                h.step = float(s.step_s)
            self.fault_t1.value = float(s.duration_s)
            self.time.value = 0.0
            self._fault_index = 0 if s.faults else -1
            self._build_option_controls()
        finally:
            self._syncing = False
        self._sync_fault_controls()
        self.request_recompute()

    # -- recordings ---------------------------------------------------------------------
    def open_recording(self, obs: str, nav: str) -> None:
        """Open a RINEX recording (paths on the server) and offer it as a preset."""
        from raimcore.scenario import recording_scenario

        scenario = recording_scenario(obs, nav, algorithm=self.algorithm.value)
        self.presets[scenario.name] = scenario
        self._syncing = True
        try:
            self.preset.options = list(self.presets)
            self.preset.value = scenario.name
            self.rec_obs.value, self.rec_nav.value = str(obs), str(nav)
        finally:
            self._syncing = False
        self.open_scenario(scenario)

    def _on_open_recording(self) -> None:
        try:
            self.open_recording(self.rec_obs.value.strip(), self.rec_nav.value.strip())
        except ValueError as exc:
            self._show_error(exc)

    def use_measured_correlation(self) -> float | None:
        """Set the noise-correlation control to the Gauss-Markov time fitted to the open
        recording's errors (:func:`raimcore.sky.recording.error_statistics`); returns it, or
        None when there is no recording or no finite positive fit."""
        from raimcore.measure import error_statistics

        if self.result is None or self.result.scenario.source != "rinex":
            return None
        try:
            corr = error_statistics(self.result.measurements, self.result.truth).corr_s
        except ValueError as exc:
            self._show_error(exc)
            return None
        if not (0.0 < corr < math.inf):
            return None
        value = float(round(corr / 5.0) * 5.0)  # the control's step
        self.noise_corr.max = max(float(self.noise_corr.max), value)
        self.noise_corr.value = value  # fires a recompute like a user's move
        return value

    def _on_upload(self, button, field) -> None:
        """Save an uploaded file in this session's temporary folder; open the recording
        once both files are there."""
        up = button.value
        if self._upload_dir is None:
            self._upload_dir = tempfile.mkdtemp(prefix="raim-upload-")
        path = Path(self._upload_dir) / (Path(up.name).name or "upload.rnx")
        path.write_bytes(up.content)
        self._syncing = True
        try:
            field.value = str(path)
        finally:
            self._syncing = False
        if all(Path(f.value).is_file() for f in (self.rec_obs, self.rec_nav)
               if f.value.strip()) and self.rec_obs.value.strip() and self.rec_nav.value.strip():
            self._on_open_recording()

    # -- faults -------------------------------------------------------------------------
    def _visible_sats(self) -> list[str]:
        if self.result is None:
            return list(self.scenario.sats) or ["-"]
        data = self.result.measurements
        used = np.asarray(data.used).any(axis=0)
        return [n for n, u in zip(data.sat_names, used, strict=True) if u]

    def _sync_fault_controls(self) -> None:
        """Show the selected fault in the editor controls (without recomputing)."""
        faults = self.scenario.faults
        self._syncing = True
        try:
            labels = [fault_label(k, f) for k, f in enumerate(faults)] or [NO_FAULT]
            self.fault_pick.options = labels
            visible = self._visible_sats()
            if 0 <= self._fault_index < len(faults):
                f = faults[self._fault_index]
                self.fault_pick.value = labels[self._fault_index]
                opts = visible if f.sat in visible else [*visible, f.sat]
                self.fault_sat.options = opts
                self.fault_sat.value = f.sat
                self.fault_kind.value = f.kind
                self.fault_bias.value = float(np.clip(f.bias_m, 0, self.fault_bias.max))
                self.fault_rate.value = float(np.clip(f.rate_mps, 0, self.fault_rate.max))
                self.fault_t0.value = float(f.t0_s)
                self.fault_t1.value = float(min(f.t1_s, self.scenario.duration_s))
                editing = True
            else:
                self.fault_pick.value = labels[0]
                self.fault_sat.options = visible
                editing = False
            for h in (self.fault_sat, self.fault_kind, self.fault_bias, self.fault_rate,
                      self.fault_t0, self.fault_t1, self.fault_remove):
                h.disabled = not editing
            if editing:
                kind = self.fault_kind.value
                self.fault_bias.disabled = kind != "step"
                self.fault_rate.disabled = kind != "ramp"
        finally:
            self._syncing = False

    def _refresh_fault_sats(self) -> None:
        """Offer the satellites visible in the current run (plus the edited fault's)."""
        visible = self._visible_sats()
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

    def _fault_from_controls(self) -> Fault:
        t0 = float(self.fault_t0.value)
        t1 = float(self.fault_t1.value)
        t1 = math.inf if t1 >= self.scenario.duration_s else t1
        if t1 <= t0:
            t1 = t0 + float(self.scenario.step_s)
        return Fault(sat=self.fault_sat.value, kind=self.fault_kind.value, t0_s=t0, t1_s=t1,
                     bias_m=float(self.fault_bias.value),
                     rate_mps=float(self.fault_rate.value))

    def _set_faults(self, faults) -> None:
        self.scenario = self.scenario.with_faults(*faults)

    def _on_fault_edit(self) -> None:
        if self._syncing or not (0 <= self._fault_index < len(self.scenario.faults)):
            return
        faults = list(self.scenario.faults)
        faults[self._fault_index] = self._fault_from_controls()
        self._set_faults(faults)
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
        """Add a fault (default: a 50 m step on a visible satellite not yet faulty)."""
        if fault is None:
            taken = {f.sat for f in self.scenario.faults}
            free = [n for n in self._visible_sats() if n not in taken] or self._visible_sats()
            t_mid = float(self.scenario.duration_s) / 3.0
            fault = Fault(sat=free[0], kind="step", t0_s=round(t_mid), bias_m=50.0)
        self._set_faults([*self.scenario.faults, fault])
        self._fault_index = len(self.scenario.faults) - 1
        self._sync_fault_controls()
        self.request_recompute()

    def _on_fault_add(self) -> None:
        self.add_fault()

    def remove_fault(self, index: int | None = None) -> None:
        k = self._fault_index if index is None else index
        faults = list(self.scenario.faults)
        if not (0 <= k < len(faults)):
            return
        del faults[k]
        self._set_faults(faults)
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
        result = self._run_cached(scenario)
        t1 = time.perf_counter()
        view = run_view(result)
        figs = {key: build(view)
                for key, build in panels.panels_for(view, self.per_sat_pick.value)}
        verdict = teaching.verdict(view, scenario.p_fa)
        t2 = time.perf_counter()
        self.result, self.view, self.figures = result, view, figs
        self.i_epoch = self._time_index(float(self.time.value))
        with self.client.atomic():
            self._push_figures()
            self.scene.i_epoch = self.i_epoch
            self.scene.set_run(scene_run(result, view))
            self.verdict_md.content = f"**Verdict.** {html.escape(verdict)}"
        t3 = time.perf_counter()
        tm = self.timing
        tm.run_s, tm.figures_s, tm.push_s, tm.total_s = t1 - t0, t2 - t1, t3 - t2, t3 - t0
        tm.n_recomputes += 1
        tm.history.append((tm.run_s, tm.figures_s, tm.push_s, tm.total_s))
        self.status.content = (f"**{scenario.name}** · {len(result.measurements.t_s)} "
                               f"epochs · {len(result.measurements.sat_names)} satellites · "
                               f"update "
                               f"{1e3 * tm.total_s:.0f} ms")
        self.rec_notes.content = "".join(f"- {html.escape(n)}\n"
                                         for n in result.summary.notes)
        self.rec_use_corr.visible = scenario.source == "rinex"
        self._refresh_fault_sats()
        self._refresh_per_sat_pick()

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

        fig = per_sat_figure(self.view, self.per_sat_pick.value)
        self.figures["per_sat"] = fig
        self.plot_handles["per_sat"].figure = fig.at(self.i_epoch)

    def _run_cached(self, scenario: Scenario) -> ScenarioResult:
        """Run the scenario, or reuse the result of an identical recent one (a run is a
        pure function of the scenario: its seed fixes every random draw)."""
        key = repr(scenario.to_dict())
        result = self._cache.get(key)
        if result is None:
            result = _run_scenario(scenario)
            self._cache[key] = result
            while len(self._cache) > RESULT_CACHE_SIZE:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return result

    def _push_figures(self) -> None:
        keep = set(self.figures)
        for key in list(self.plot_handles):
            if key not in keep:
                self.plot_handles.pop(key).remove()
        for order, (key, fig) in enumerate(self.figures.items()):
            handle = self.plot_handles.get(key)
            payload = fig.at(self.i_epoch)
            if handle is None:
                with self.plots_folder:
                    aspect = PLOT_PANEL_WIDTH / fig.layout["height"]
                    handle = self.gui.add_plotly(payload, aspect=aspect, order=order)
                self.plot_handles[key] = handle
            else:
                handle.figure = payload
                handle.order = order

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
        if i == self.i_epoch and self.scene.i_epoch == i:
            return
        self.i_epoch = i
        with self.client.atomic():
            self.scene.set_time(i)
            for key, fig in self.figures.items():
                if fig.marker or fig.dynamic is not None:
                    self.plot_handles[key].figure = fig.at(i)

    def _on_play(self) -> None:
        if self.play.value and (self._play_thread is None or not self._play_thread.is_alive()):
            self._play_stop.clear()
            self._play_thread = threading.Thread(target=self._play_loop, daemon=True)
            self._play_thread.start()
        elif not self.play.value:
            self._play_stop.set()

    def _play_loop(self) -> None:
        while not self._play_stop.wait(1.0 / PLAY_FPS):
            speed = float(self.speed.value.rstrip("x"))
            t_max = float(self.time.max)
            t_next = float(self.time.value) + speed / PLAY_FPS
            self.time.value = 0.0 if t_next > t_max else t_next

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
        verdict = html.escape(teaching.verdict(self.view)) if self.view else ""
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
        try:
            self.status.content = f"**Error:** {html.escape(str(exc))}"
        except Exception:  # noqa: BLE001 - the client may be gone
            pass

    def close(self) -> None:
        self._play_stop.set()
        self.scheduler.close()
        if self._upload_dir is not None:
            shutil.rmtree(self._upload_dir, ignore_errors=True)


def preset_table() -> dict[str, str]:
    """Built-in scenario names offered by the preset control."""
    return {name: name for name in list_scenarios()}
