"""The "Fault modes now" panel: ARAIM's monitored fault modes at the time slider's epoch.

One bar pair per monitored fault mode (ARAIM.md sections 4-6): what the mode removes
(a satellite, a pair, or a constellation by its system key) and its prior ``p_inst`` on
the axis, and its solution separation against its threshold as the ratio
``|((S^(k) - S^(0)) y)_q| / T_k,q``, vertical (q = up) and horizontal (the larger of east
and north, each against its own threshold). A ratio above 1 (the dashed line) is an alarm
of that mode: its bars are red. The title counts the modes and gives ``P_not_monitored``;
an infinite protection level at this epoch gets its reason (the run's ``pl_note``) in a
note on the plot, never a silent infinity.

Everything here depends on the epoch, so the figure has no static traces: its dynamic
part (:attr:`app.figures.PanelFigure.dynamic`) is the whole drawing, rebuilt for one epoch
from the run's mode table (the ``araim`` algorithm's extras ``mode_*``) in well under a
millisecond and sent with the time update (a few kB), never as a whole figure.
"""

from __future__ import annotations

import textwrap

import numpy as np

from .figures import PanelFigure, RunView, _base_layout, _title

__all__ = ["fault_modes_figure", "mode_ratios", "NEEDS", "ALARM_COLOR"]

#: The run's extras this panel draws (``raimcore.algorithms.araim.MODE_EXTRAS``).
NEEDS = ("mode_label", "mode_p_inst", "mode_threshold_m", "mode_separation_m",
         "mode_monitored")
ALARM_COLOR = "#d62728"
V_COLOR = "#8c564b"
H_COLOR = "#9467bd"
#: Height (px) per mode row, and the figure's bounds.
ROW_PX = 17
HEIGHT_PX = (260, 760)
#: Characters per line of the infinite-PL note.
NOTE_WIDTH = 58


def mode_ratios(sep_m: np.ndarray, thr_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertical and horizontal separation / threshold of modes ``(K, 3)`` (E, N, U).

    A zero threshold (a mode whose separation has no spread) gives 0 for a zero
    separation and inf otherwise; NaN separations (no measurements) stay NaN.
    """
    sep = np.abs(np.asarray(sep_m, dtype=float))
    thr = np.asarray(thr_m, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.where(thr > 0, sep / thr, np.where(sep > 0, np.inf, 0.0))
    r = np.where(np.isnan(sep), np.nan, r)
    return r[..., 2], np.fmax(r[..., 0], r[..., 1])


def _fmt_p(p: float) -> str:
    return f"{p:.1e}".replace("e-0", "e-")


def fault_modes_figure(view: RunView) -> PanelFigure:
    """The monitored fault modes at the current epoch (module doc).

    Parameters
    ----------
    view : a run of algorithm ``araim`` (its extras :data:`NEEDS`, its columns
        ``p_not_monitored`` and ``pl_note``).

    Returns
    -------
    PanelFigure
        Key ``"araim_modes"``; no static traces, the bars and title per epoch
        (:meth:`~app.figures.PanelFigure.time_state`).
    """
    ex = view.extras
    labels = np.asarray(ex["mode_label"], dtype=object)
    p_inst = np.asarray(ex["mode_p_inst"], dtype=float)
    thr = np.asarray(ex["mode_threshold_m"], dtype=float)
    sep = np.asarray(ex["mode_separation_m"], dtype=float)
    mon = np.asarray(ex["mode_monitored"], dtype=bool)
    t = view.t_s
    n_ep = len(t)
    p_nm = view.column("p_not_monitored")
    notes = view.table.get("pl_note")
    n_rows = max(int(mon.sum(axis=1).max(initial=0)), 1)
    height = int(np.clip(120 + ROW_PX * n_rows, *HEIGHT_PX))

    def now(i: int) -> tuple[list[dict], dict]:
        i = int(np.clip(i, 0, n_ep - 1))
        ks = np.flatnonzero(mon[i])
        pnm = float(p_nm[i]) if p_nm is not None else float("nan")
        pnm_text = _fmt_p(pnm) if np.isfinite(pnm) else "n/a"
        rv, rh = mode_ratios(sep[i, ks], thr[i, ks])
        alarm_v, alarm_h = rv > 1.0, rh > 1.0
        n_alarm = int(np.sum(alarm_v | alarm_h))
        names = [f"{labels[i, k]} · {_fmt_p(p_inst[i, k])}" for k in ks]
        d, tk = np.abs(sep[i, ks]), thr[i, ks]  # |Δ| and T (m), east, north, up
        hover = [f"{labels[i, k]} prior {p_inst[i, k]:.1e}<br>|Δ|/T m: U "
                 f"{d[j, 2]:.1f}/{tk[j, 2]:.1f} E {d[j, 0]:.1f}/{tk[j, 0]:.1f} N "
                 f"{d[j, 1]:.1f}/{tk[j, 1]:.1f}"
                 for j, k in enumerate(ks)]
        finite = np.concatenate([rv[np.isfinite(rv)], rh[np.isfinite(rh)], [1.0]])
        x_max = float(max(1.5, 1.1 * finite.max()))
        traces = [
            {"type": "bar", "orientation": "h", "y": names, "x": np.minimum(rv, x_max),
             "name": "vertical |Δu|/T", "hovertext": hover, "hoverinfo": "text",
             "marker": {"color": [ALARM_COLOR if a else V_COLOR for a in alarm_v]}},
            {"type": "bar", "orientation": "h", "y": names, "x": np.minimum(rh, x_max),
             "name": "horizontal |Δ|/T (E, N)", "hoverinfo": "x",
             "marker": {"color": [ALARM_COLOR if a else H_COLOR for a in alarm_h],
                        "opacity": 0.75}},
        ]
        title = f"Fault modes now: {len(ks)} monitored"
        detail = f"t {t[i]:g} s · P_nm {pnm_text} · {n_alarm} alarm" + \
            ("s" if n_alarm != 1 else "")
        annotations = []
        note = str(notes[i]) if notes is not None else ""
        if not len(ks):
            note = note or ("no fault mode at this epoch: ARAIM unavailable (too few "
                            "satellites or a singular geometry)")
        if note:
            annotations.append({
                "xref": "paper", "yref": "paper", "x": 1.0, "y": 1.0, "xanchor": "right",
                "yanchor": "top", "align": "left", "showarrow": False,
                "text": "<br>".join(textwrap.wrap(note, NOTE_WIDTH)),
                "font": {"size": 9, "color": ALARM_COLOR}, "bgcolor": "rgba(255,255,255,0.85)",
                "bordercolor": ALARM_COLOR, "borderwidth": 1})
        layout = {"title": _title(title, detail), "annotations": annotations,
                  "xaxis": {"range": [0, x_max], "zeroline": True}}
        return traces, layout

    layout = _base_layout("Fault modes now", height=height, detail="ARAIM monitored modes",
                          barmode="group", bargap=0.25,
                          xaxis={"zeroline": True},
                          yaxis={"autorange": "reversed", "type": "category",
                                 "tickfont": {"size": 9}, "automargin": True},
                          shapes=[{"type": "line", "xref": "x", "yref": "paper", "x0": 1.0,
                                   "x1": 1.0, "y0": 0, "y1": 1, "name": "threshold",
                                   "line": {"color": ALARM_COLOR, "dash": "dash",
                                            "width": 1}}])
    layout.pop("uirevision")  # the axes follow each epoch's modes
    return PanelFigure("araim_modes", "Fault modes now", [], layout, dynamic=now, t_s=t,
                       marker=False)
