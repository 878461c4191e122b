"""The dashboard's availability map: a small ARAIM LPV-200 grid run in the background.

One :class:`AvailabilityView` per session, in the plot panel's "Availability" tab. Its
controls are made from :data:`KEYS` (one declaration of each value's type, default, unit,
range and help, as the scenario's controls are: :mod:`app.controls`); a refused entry
shows the last valid value again and says why in one line. **Run** starts
:func:`raimcore.studies.availability.availability` on a thread of its own (at most one per
session: a second Run while one is running is refused with a message, the running map
goes on); the session's other controls and its worker are not blocked. A progress bar and
a line (``N of M user-epochs, x s``) follow the study's ``progress`` callback, which the
study calls between batches of at most :data:`BATCH_USER_EPOCHS`; **Cancel** makes that
callback raise a private exception, so the run stops within one batch, and closing the tab
(:meth:`AvailabilityView.close`, from ``Session.close``) cancels the run and joins the
thread. The result is drawn with the ``raim availability`` figure
(:func:`app.availability.map_figure`) fitted to the plot panel (:func:`panel_figure`),
under the study's own summary (coverage at the target, cos-lat weighted; median and 99th
percentile VPL).

The dashboard refuses maps of more than :data:`MAX_USER_EPOCHS` user-epochs (a few
minutes): larger studies belong to ``raim availability``, which can use processes or Dask.
"""

from __future__ import annotations

import html
import json
import logging
import threading
import time

import numpy as np

from raimcore.measure.error_models import USER_MODELS
from raimcore.scenario import scenario_keys
from raimcore.schema import Key, SchemaError, option
from raimcore.schema import is_input_error as input_error
from raimcore.studies.availability import (
    DEFAULT_ISM,
    ISM_PRESETS,
    AvailabilityResult,
    availability,
    user_grid,
)

from . import page
from .availability import LEVELS_PCT, map_figure
from .controls import KeyControl

log = logging.getLogger(__name__)

__all__ = ["AvailabilityView", "KEYS", "panel_figure", "study_kwargs", "n_user_epochs",
           "MAX_USER_EPOCHS", "BATCH_USER_EPOCHS", "MAP_HEIGHT_PX"]

#: Most user-epochs per call of the ARAIM kernel (and so between two progress reports):
#: a Cancel or a closed tab stops the run within one such batch (about 0.1-0.3 s).
BATCH_USER_EPOCHS = 1500
#: Largest map the dashboard computes (user-epochs; about 4 minutes on one core).
MAX_USER_EPOCHS = 2_000_000
#: Height of the map in the plot panel (px).
MAP_HEIGHT_PX = 330
#: Least time between two progress updates sent to the page (s).
PROGRESS_EVERY_S = 0.1
#: Name of the worker thread (one per session at most).
THREAD_NAME = "raim-availability"
#: How long closing waits for the worker to stop (s).
CLOSE_WAIT_S = 10.0

_SYSTEMS_KEY = scenario_keys()["systems"]


def _parse_systems(name: str, value) -> tuple[str, ...]:
    """Systems of the map: the scenario's systems key (``"GPS, GAL"`` or a list), each
    named once and at least one."""
    if isinstance(value, str):
        value = [w for w in value.replace(",", " ").split() if w]
    systems = _SYSTEMS_KEY.coerce(value, name=name)
    if not systems or len(set(systems)) != len(systems):
        raise SchemaError(f"{name} must name one or more of "
                          f"{', '.join(_SYSTEMS_KEY.choices)}, each once, got "
                          f"{', '.join(systems) or 'none'}")
    return systems


#: The view's values, declared once: the controls, their checks and their hints come from
#: these keys. The defaults make a coarse world map that takes about a second.
KEYS: dict[str, Key] = {k.name: k for k in (
    Key(name="systems", kind="custom", default=("GPS", "GAL"),
        help="constellations of the map (ARAIM needs two for LPV-200)",
        parse=_parse_systems, group="availability",
        allowed_text=f"distinct names of {', '.join(_SYSTEMS_KEY.choices)}"),
    option("grid_step_deg", float, 30.0, "grid step in latitude and longitude",
           unit="deg", lo=1.0, hi=90.0, ui_lo=5.0, ui_hi=90.0, ui_step=5.0,
           group="availability"),
    option("duration_h", float, 24.0, "time span from t = 0", unit="h", lo=0.0,
           lo_open=True, hi=240.0, ui_lo=1.0, ui_hi=24.0, ui_step=1.0,
           group="availability"),
    option("t_step_s", float, 600.0, "time between epochs", unit="s", lo=1.0, hi=86400.0,
           ui_lo=60.0, ui_hi=3600.0, ui_step=60.0, group="availability"),
    option("ism", "choice", DEFAULT_ISM, "integrity support message: b2012 (B2012's "
           "sigma_URA 0.75 m) or maast (MAAST's example ISD: 0 % LPV-200 everywhere)",
           choices=tuple(ISM_PRESETS), group="availability"),
    option("user_model", "choice", "ed259a", "airborne multipath + noise: ed259a "
           "(MAAST v5) or add (ADD / B2012)", choices=tuple(USER_MODELS),
           group="availability"),
)}
#: Labels of the controls (the unit is added from the key).
TITLES = {"systems": "Systems", "grid_step_deg": "Grid step", "duration_h": "Duration",
          "t_step_s": "Time step", "ism": "ISM preset", "user_model": "User model"}


class _Cancelled(Exception):
    """Raised by the progress callback to stop a cancelled run between two batches."""


def study_kwargs(values: dict) -> dict:
    """The keywords of :func:`~raimcore.studies.availability.availability` for the view's
    values (:data:`KEYS`; the hours become seconds, one step serves both axes)."""
    return dict(systems=tuple(values["systems"]), lat_step_deg=float(values["grid_step_deg"]),
                lon_step_deg=float(values["grid_step_deg"]),
                duration_s=3600.0 * float(values["duration_h"]),
                t_step_s=float(values["t_step_s"]), ism=values["ism"],
                user_model=values["user_model"])


def n_user_epochs(kwargs: dict) -> int:
    """User-epochs a study of ``kwargs`` (:func:`study_kwargs`) computes."""
    *_, inside = user_grid(kwargs["lat_step_deg"], kwargs["lon_step_deg"])
    n_t = np.arange(0.0, kwargs["duration_s"], kwargs["t_step_s"]).size  # as the study
    return int(inside.sum()) * n_t


def panel_figure(res: AvailabilityResult, height_px: int = MAP_HEIGHT_PX) -> dict:
    """The ``raim availability`` map (:func:`app.availability.map_figure`) fitted to the
    plot panel: its width follows the panel, a short title (the summary is written under
    it), the colour bar below the map labelled by the classes' lower edges (%).

    Parameters
    ----------
    res : the study's result.
    height_px : the figure's height (px).

    Returns
    -------
    dict
        A Plotly figure (``data``, ``layout``), JSON-ready.
    """
    fig = map_figure(res, height_px=height_px)
    lay = fig["layout"]
    lay.pop("width", None)
    systems = "+".join(res.settings["systems"])
    lay.update(
        title={"text": f"LPV-200 availability, {systems}", "x": 0.01,
               "font": {"size": 13}},
        margin={"l": 44, "r": 8, "t": 30, "b": 8}, annotations=[],
        legend={"orientation": "h", "x": 0.0, "y": -0.34, "font": {"size": 10}},
        uirevision="keep")
    for ax in ("xaxis", "yaxis"):
        lay[ax] = dict(lay[ax], title=None, tickfont={"size": 9})
    heat = fig["data"][0]
    heat["colorbar"] = dict(
        heat["colorbar"], orientation="h", x=0.5, xanchor="center", y=-0.12,
        yanchor="top", thickness=10, len=1.0, tickfont={"size": 9},
        title={"text": "available epochs (%, at least)", "side": "top",
               "font": {"size": 10}},
        ticktext=[f"{lo:g}" for lo in LEVELS_PCT])
    return fig


class _Figure:
    """A figure dict for viser's ``GuiPlotlyHandle.figure`` (its ``to_json``)."""

    def __init__(self, fig: dict) -> None:
        self.fig = fig

    def to_json(self) -> str:
        return json.dumps(self.fig, allow_nan=False, separators=(",", ":"))


class AvailabilityView:
    """The "Availability map" controls, run, progress and map of one session.

    Parameters
    ----------
    session : the dashboard session (:class:`app.session.Session`, or anything with
        ``plots_px``); held until :meth:`close`.
    gui : viser GUI API; the view is built in its current container.

    Attributes
    ----------
    controls : the :class:`~app.controls.KeyControl` of each key of :data:`KEYS`.
    result : the last completed map (:class:`AvailabilityResult`), or None.
    figure : its Plotly figure (:func:`panel_figure`), or None.
    progress : ``(done, total)`` user-epochs of the current or last run.
    """

    def __init__(self, session, gui) -> None:
        self._session = session
        self.gui = gui
        self.result: AvailabilityResult | None = None
        self.figure: dict | None = None
        self.progress = (0, 0)
        self.plot_handle = None
        self._thread: threading.Thread | None = None
        self._cancel = threading.Event()
        self._lock = threading.Lock()  # one start at a time
        self._closed = False
        # Set while this view writes a control itself (its callback then ignores the
        # change); thread-local, as the session's (a user event may arrive meanwhile).
        self._sync_state = threading.local()
        self._t0 = 0.0
        self._last_sent = 0.0
        self.intro_md = gui.add_markdown(
            "ARAIM LPV-200 availability of users on a world grid (MAAST's study, "
            "`raim availability`): the share of epochs with VPL <= 35 m, HPL <= 40 m, "
            "EMT <= 15 m and sigma_acc <= 1.87 m. Runs in the background; the other "
            "controls stay live.")
        self.controls: dict[str, KeyControl] = {
            name: KeyControl(gui, key, key.default, title=TITLES[name])
            for name, key in KEYS.items()}
        self.run_button = gui.add_button("Run availability map")
        self.cancel_button = gui.add_button("Cancel", disabled=True)
        self.progress_bar = gui.add_progress_bar(0.0)
        self.progress_md = gui.add_markdown("")
        self.message_md = gui.add_markdown("")
        self.summary_md = gui.add_markdown("")
        self.map_folder = gui.add_folder("Map")
        for ctl in self.controls.values():
            ctl.handle.on_update(lambda _e, c=ctl: self._on_entry(c))
        self.run_button.on_click(lambda _e: self.run())
        self.cancel_button.on_click(lambda _e: self.cancel())

    # -- controls -----------------------------------------------------------------------
    @property
    def values(self) -> dict:
        """The values the controls stand for (the last valid entries)."""
        return {name: ctl.value for name, ctl in self.controls.items()}

    def _on_entry(self, ctl: KeyControl) -> bool:
        """A user's entry: kept when the key accepts it, otherwise the control shows its
        last valid value again and the message line says why. Returns True if kept."""
        if self._closed or getattr(self._sync_state, "on", False):
            return False
        try:
            value = ctl.read()
        except ValueError as exc:
            if not input_error(exc):
                raise
            self._sync_state.on = True
            try:
                ctl.revert()
            finally:
                self._sync_state.on = False
            self._say(exc)
            return False
        ctl.accept(value)
        return True

    def _say(self, msg) -> None:
        """One line in the view's message line (and the log), no traceback."""
        text = str(msg).strip().splitlines()[0] if str(msg).strip() else type(msg).__name__
        if isinstance(msg, BaseException):
            log.info("availability map refused: %s", text)
            text = f"**Refused:** {html.escape(text)}"
        else:
            text = html.escape(text)
        if not self._closed:
            self.message_md.content = text

    # -- run ----------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        """True while a map is being computed."""
        t = self._thread
        return t is not None and t.is_alive()

    def run(self) -> bool:
        """Start a map of the controls' values in the background. Refused (False, with a
        one-line message) while another map of this session runs, after :meth:`close`,
        or when the map would exceed :data:`MAX_USER_EPOCHS`."""
        with self._lock:
            if self._closed:
                return False
            if self.running:
                done, total = self.progress
                self._say(ValueError(f"a map is already running ({done} of {total} "
                                     "user-epochs): wait for it or Cancel it first"))
                return False
            kwargs = study_kwargs(self.values)
            n = n_user_epochs(kwargs)
            if n > MAX_USER_EPOCHS:
                self._say(ValueError(
                    f"the map would take {n} user-epochs, more than {MAX_USER_EPOCHS:.0e} "
                    "in the dashboard: use a larger grid step or time step, a shorter "
                    "duration, or `raim availability`"))
                return False
            self._cancel.clear()
            self.progress = (0, n)
            self._t0 = self._last_sent = time.perf_counter()
            self.run_button.disabled = True
            self.cancel_button.disabled = False
            self.progress_bar.value = 0.0
            self.progress_bar.animated = True
            self.progress_md.content = f"0 of {n} user-epochs, 0.0 s"
            self.message_md.content = "Computing the map..."
            self._thread = threading.Thread(target=self._work, args=(kwargs,), daemon=True,
                                            name=THREAD_NAME)
            self._thread.start()
            return True

    def cancel(self) -> bool:
        """Stop the running map (within one batch); True if one was running."""
        if not self.running:
            return False
        self._cancel.set()
        return True

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the running map to end; True when none runs any more."""
        t = self._thread
        if t is not None and t is not threading.current_thread():
            t.join(timeout_s)
        return not self.running

    def _on_progress(self, done: int, total: int) -> None:
        """The study's progress callback (between batches): stop a cancelled run, show the
        progress at most every :data:`PROGRESS_EVERY_S`."""
        if self._cancel.is_set() or self._closed:
            raise _Cancelled
        self.progress = (int(done), int(total))
        now = time.perf_counter()
        if now - self._last_sent >= PROGRESS_EVERY_S or done >= total:
            self._last_sent = now
            self._show_progress(now)

    def _show_progress(self, now: float) -> None:
        done, total = self.progress
        self.progress_bar.value = 100.0 * done / max(total, 1)
        self.progress_md.content = f"{done} of {total} user-epochs, {now - self._t0:.1f} s"

    def _work(self, kwargs: dict) -> None:
        """The worker thread: the study, then the map and the summary (or a message)."""
        try:
            res = availability(**kwargs, progress=self._on_progress,
                               batch_user_epochs=BATCH_USER_EPOCHS)
            if self._cancel.is_set() or self._closed:
                raise _Cancelled
            fig = panel_figure(res)
            if self._closed:
                return
            self._show(res, fig)
        except _Cancelled:
            if not self._closed:
                done, total = self.progress
                self._say(f"Cancelled after {done} of {total} user-epochs, "
                          f"{time.perf_counter() - self._t0:.1f} s.")
        except ValueError as exc:
            if not input_error(exc):
                log.exception("availability map failed")
            self._say(exc)
        except Exception as exc:  # noqa: BLE001 - a bug: its traceback goes to the log
            log.exception("availability map failed")
            self._say(RuntimeError(f"the map failed ({type(exc).__name__}: {exc})"))
        finally:
            if not self._closed:
                self.progress_bar.animated = False
                self.run_button.disabled = False
                self.cancel_button.disabled = True

    def _show(self, res: AvailabilityResult, fig: dict) -> None:
        """Show a finished map and its summary."""
        self.result, self.figure = res, fig
        now = time.perf_counter()
        self._show_progress(now)
        self.summary_md.content = "\n".join(
            f"- {html.escape(line)}" for line in
            [*res.summary_lines(), f"{res.n_user_epochs} user-epochs in {res.wall_s:.1f} s"])
        session = self._session
        panel_px = getattr(session, "plots_px", page.side_panel_widths(
            page.DEFAULT_WINDOW[0])[1])
        aspect = page.plot_aspect(fig["layout"]["height"], panel_px)
        if self.plot_handle is None:
            with self.map_folder:
                self.plot_handle = self.gui.add_plotly(_Figure(fig), aspect=aspect)
        else:
            self.plot_handle.figure = _Figure(fig)
            self.plot_handle.aspect = aspect
        self.message_md.content = f"Done: coverage {res.coverage_pct:.1f} %."

    # -- lifecycle ----------------------------------------------------------------------
    def close(self, wait_s: float = CLOSE_WAIT_S) -> None:
        """Cancel a running map, wait up to ``wait_s`` for its thread, let go of the
        result, the figure and the session."""
        self._closed = True
        self._cancel.set()
        self.wait(wait_s)
        self._thread = None
        self.result = self.figure = self.plot_handle = None
        self._session = None
