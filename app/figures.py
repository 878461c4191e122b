"""Plotly figure builders for the dashboard: pure functions of one run's result table.

Every builder takes a :class:`RunView` (the result table's columns plus the per-satellite
arrays, both plain numpy) and returns a :class:`PanelFigure`: the static traces of the run
plus an optional *dynamic* part that depends only on the current time index (the time
marker, the sky plot's "now" markers). The dashboard sends a figure once per recompute
(and not at all when it did not change); moving the time slider sends only
:meth:`PanelFigure.time_state` (the cursor's time and the dynamic traces, a few kB), which
the page applies to the plots already drawn (:mod:`app.page`).

Sizes: every figure declares its height in pixels (``layout["height"]``), the height it
has on screen whatever the panel's width (the session sets viser's ``aspect`` from it,
:func:`app.page.plot_aspect`); legends sit inside the figure, under the plot; titles are
short enough for the narrowest plot panel (:data:`TITLE_MAX_CHARS`), details go to a
second, smaller line.

Figures are kept as plain dicts (plotly's JSON schema) with numpy arrays inside, and are
serialised with numpy arrays as plotly.js typed arrays (base64 ``bdata``): building and
serialising a 600-epoch figure this way costs about a millisecond, against ~10 ms through
``plotly.graph_objects`` validation. :meth:`PanelFigure.to_plotly` gives a real
``go.Figure`` (used by the HTML export and the tests).
"""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# State colours, shared by the 3D scene and the sky plot (RGB 0-255).
STATE_COLORS = {
    "used": (46, 170, 90),
    "faulty": (245, 150, 20),
    "excluded": (220, 50, 50),
    "below mask": (150, 150, 150),
}
STATE_ORDER = ("used", "faulty", "excluded", "below mask")
# Protection-level columns shown with the position errors: hpl_m, vpl_nobaro_m, ...
PROTECTION_LEVEL = re.compile(r"^[hv]pl(_\w+)?_m$")


def rgb(state: str) -> str:
    r, g, b = STATE_COLORS[state]
    return f"rgb({r},{g},{b})"


@dataclass(frozen=True)
class RunView:
    """One run as the figures see it (all epochs; ``E`` epochs, ``S`` satellites).

    Attributes
    ----------
    table : column name -> (E,) array, the engine's result table (``t_s``,
        ``statistic``, ``threshold``, ``alarm``, ``hpe_before_m``, ... and every
        ``AlgorithmOutput.columns`` entry).
    per_sat : name -> (E, S) array, every ``AlgorithmOutput.per_sat`` entry.
    sat_names : (S,) satellite names.
    used : (E, S) bool, tracked and above the mask.
    excluded : (E, S) bool, excluded by the algorithm.
    fault_bias_m : (E, S) injected fault (truth).
    faulted : (E, S) bool, a fault acts on a used satellite (:attr:`raimcore.measure.Truth.
        faulted`, the one definition).
    az_rad, el_rad : (E, S) azimuth and elevation seen from the true receiver.
    hal_m, val_m : alert limits (m).
    mask_deg : elevation mask (deg).
    algorithm : label of the algorithm that produced the run.
    isolated_idx : (E,) int, index of the satellite the algorithm names, -1 for none.
    extras : name -> (E, ...) array, every ``AlgorithmOutput.extras`` entry (e.g. the
        particle cloud of ``pf-llr``).
    """

    table: Mapping[str, np.ndarray]
    per_sat: Mapping[str, np.ndarray]
    sat_names: tuple[str, ...]
    used: np.ndarray
    excluded: np.ndarray
    fault_bias_m: np.ndarray
    faulted: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    hal_m: float
    val_m: float
    mask_deg: float = 0.0
    algorithm: str = ""
    isolated_idx: np.ndarray | None = None
    extras: Mapping[str, np.ndarray] = field(default_factory=dict)

    @property
    def t_s(self) -> np.ndarray:
        return np.asarray(self.table["t_s"], dtype=float)

    def column(self, *names: str) -> np.ndarray | None:
        """The first of ``names`` present in the table, as a float array, else None."""
        for name in names:
            if name in self.table:
                return np.asarray(self.table[name], dtype=float)
        return None

    def states(self) -> np.ndarray:
        """(E, S) state index into :data:`STATE_ORDER` per epoch and satellite.

        Precedence: below mask (not used) > excluded > faulty (injected, not excluded) >
        used.
        """
        state = np.zeros(self.used.shape, dtype=np.int8)
        state[self.faulted] = 1
        state[self.excluded] = 2
        state[~self.used] = 3
        return state


# ---------------------------------------------------------------------------------------
# Serialisation


def _encode(obj: Any) -> Any:
    """Numpy arrays -> plotly.js typed-array dicts; recurse through dicts and lists."""
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f":
            arr = np.ascontiguousarray(obj, dtype="<f8")
            return {"dtype": "f8", "bdata": base64.b64encode(arr.tobytes()).decode("ascii")}
        if obj.dtype.kind in "iub":
            arr = np.ascontiguousarray(obj, dtype="<i4")
            return {"dtype": "i4", "bdata": base64.b64encode(arr.tobytes()).decode("ascii")}
        return obj.tolist()
    if isinstance(obj, dict):
        return {k: _encode(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        if obj and isinstance(obj[0], str | int | float) and not isinstance(obj[0], bool):
            return obj  # plain labels or numbers: nothing to convert
        return [_encode(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _dumps(obj: Any) -> str:
    return json.dumps(_encode(obj), separators=(",", ":"), allow_nan=False, default=str)


def _plain(obj: Any, decimals: int = 4) -> Any:
    """Numpy arrays -> lists of numbers rounded to ``decimals`` (NaN -> None): the small
    time updates go to the page as plain JSON."""
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind == "f":
            arr = np.round(obj.astype(float), decimals)
            return [None if not np.isfinite(v) else float(v) for v in arr.ravel()] \
                if obj.ndim == 1 else [_plain(row, decimals) for row in arr]
        return obj.tolist()
    if isinstance(obj, dict):
        return {k: _plain(v, decimals) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_plain(v, decimals) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, float) and not np.isfinite(obj):
        return None
    return obj


def time_axis(t_s: np.ndarray) -> dict:
    """A trace's x for the epoch times: ``x0`` and ``dx`` when the epochs are evenly
    spaced (half the bytes of a time panel: every trace would repeat the same x array),
    else ``x``."""
    t = np.asarray(t_s, dtype=float)
    if t.size >= 2:
        dt = float(t[1] - t[0])
        if dt > 0 and np.allclose(np.diff(t), dt, rtol=0.0,
                                  atol=1e-9 * max(1.0, float(np.abs(t).max()))):
            return {"x0": float(t[0]), "dx": dt}
    return {"x": t}


def _clean(arr: np.ndarray) -> np.ndarray:
    return np.asarray(arr, dtype=float)


DynamicPart = Callable[[int], tuple[list[dict], dict]]


@dataclass
class PanelFigure:
    """A figure whose static traces are serialised once and whose time-dependent part
    (extra traces and layout entries for one epoch index) is cheap to redo.

    Attributes
    ----------
    key, title : panel registry key and human title.
    data : static traces (plotly dicts, numpy arrays inside).
    layout : static layout; ``layout["height"]`` is the figure's height on screen (px).
    dynamic : ``f(i_epoch) -> (traces, layout_updates)`` or None.
    t_s : (E,) epoch times, for the default time marker.
    marker : draw the time marker (a vertical line named ``"now"``).
    """

    key: str
    title: str
    data: list[dict]
    layout: dict
    dynamic: DynamicPart | None = None
    t_s: np.ndarray | None = None
    marker: bool = True
    _static_json: str | None = field(default=None, repr=False)
    _rev: str | None = field(default=None, repr=False)

    @property
    def height_px(self) -> int:
        """The figure's height on screen (px)."""
        return int(self.layout.get("height", 300))

    def t_now(self, i_epoch: int) -> float | None:
        """The time marker's position at epoch index ``i_epoch`` (None: no marker)."""
        if not self.marker or self.t_s is None or not len(self.t_s):
            return None
        return float(self.t_s[int(np.clip(i_epoch, 0, len(self.t_s) - 1))])

    def parts(self, i_epoch: int | None) -> tuple[list[dict], dict]:
        """All traces and the full layout at epoch index ``i_epoch`` (None: no marker)."""
        traces: list[dict] = []
        layout = dict(self.layout)
        if i_epoch is not None:
            t_now = self.t_now(i_epoch)
            if t_now is not None:
                shapes = list(layout.get("shapes", []))
                shapes.append(time_marker_shape(t_now))
                layout["shapes"] = shapes
            if self.dynamic is not None:
                extra, upd = self.dynamic(int(i_epoch))
                traces = extra
                layout.update(upd)
        return traces, layout

    def to_dict(self, i_epoch: int | None = None) -> dict:
        traces, layout = self.parts(i_epoch)
        return {"data": list(self.data) + traces, "layout": layout}

    def _data_json(self) -> str:
        if self._static_json is None:
            self._static_json = _dumps(self.data)
        return self._static_json

    @property
    def rev(self) -> str:
        """A digest of the static figure (traces and layout): two figures with the same
        ``rev`` draw the same thing apart from the time-dependent part, so the page
        keeps the one it has and a time update made for one applies to the other."""
        if self._rev is None:
            h = hashlib.blake2b(digest_size=8)
            h.update(self._data_json().encode())
            h.update(_dumps(self.layout).encode())
            self._rev = h.hexdigest()
        return self._rev

    def to_json(self, i_epoch: int | None = None, seq: int | None = None) -> str:
        """Plotly JSON; the static traces are serialised once and cached.

        ``layout.meta`` names the panel for the page's time updates (:mod:`app.page`):
        ``raim`` (the key), ``rev`` (:attr:`rev`), ``n`` (the number of static traces;
        the dynamic ones follow) and ``seq`` (the time update the figure was made at).
        """
        traces, layout = self.parts(i_epoch)
        layout["meta"] = {"raim": self.key, "rev": self.rev, "n": len(self.data),
                          "seq": -1 if seq is None else int(seq)}
        data_json = self._data_json()
        if traces:
            extra = _dumps(traces)
            data_json = (data_json[:-1] + "," + extra[1:]) if self.data else extra
        return '{"data":' + data_json + ',"layout":' + _dumps(layout) + "}"

    def at(self, i_epoch: int | None, seq: int | None = None) -> _FigureAt:
        """An object with ``to_json()`` for viser's ``GuiPlotlyHandle.figure``."""
        return _FigureAt(self, i_epoch, seq)

    def time_state(self, i_epoch: int) -> dict | None:
        """What changes with time beyond the time marker, as plain JSON for the page:
        ``{"rev", "traces", "layout"}`` (the dynamic traces and layout entries at epoch
        index ``i_epoch``), or None for a figure without a dynamic part."""
        if self.dynamic is None:
            return None
        traces, upd = self.dynamic(int(i_epoch))
        return {"rev": self.rev, "traces": _plain(traces), "layout": _plain(upd)}

    def to_plotly(self, i_epoch: int | None = None):
        """A validated ``plotly.graph_objects.Figure`` (slow path: export and tests)."""
        import plotly.graph_objects as go

        return go.Figure(self.to_dict(i_epoch))


@dataclass(frozen=True)
class _FigureAt:
    panel: PanelFigure
    i_epoch: int | None
    seq: int | None = None

    def to_json(self) -> str:
        return self.panel.to_json(self.i_epoch, self.seq)


def time_marker_shape(t_s: float) -> dict:
    """A vertical dashed line at ``t_s`` across the whole plot (the current-time marker)."""
    return {
        "type": "line", "xref": "x", "yref": "paper", "x0": t_s, "x1": t_s, "y0": 0, "y1": 1,
        "line": {"color": "rgba(30,30,30,0.7)", "width": 1.5, "dash": "dot"},
        "name": "now",
    }


#: Longest title line (characters at TITLE_FONT_PX) and detail line (at DETAIL_FONT_PX)
#: that fit the narrowest plot panel (about 230 px of plot width).
TITLE_MAX_CHARS = 34
DETAIL_MAX_CHARS = 44
TITLE_FONT_PX = 12
DETAIL_FONT_PX = 10
LEGEND_FONT_PX = 10
#: Gap (px) between the plot's bottom and its legend: room for the tick labels.
LEGEND_GAP_PX = 24
# Top margin (px) for a title of one line, and of two (title and detail).
_TOP_PX = (30, 54)


def clip_text(text: str, n: int) -> str:
    """``text`` cut to ``n`` characters with an ellipsis."""
    return text if len(text) <= n else text[: n - 1].rstrip(" ,;:") + "…"


def _title(text: str, detail: str | None = None) -> dict:
    """A title at the figure's top left: a short first line and an optional smaller
    detail line (the algorithm, what the marks mean)."""
    title = {"text": clip_text(text, TITLE_MAX_CHARS), "font": {"size": TITLE_FONT_PX},
             "x": 0.0, "xref": "container", "xanchor": "left", "pad": {"l": 8},
             "y": 1.0, "yref": "container", "yanchor": "top"}
    title["pad"]["t"] = 8
    if detail:
        title["subtitle"] = {"text": html.escape(clip_text(detail, DETAIL_MAX_CHARS)),
                             "font": {"size": DETAIL_FONT_PX, "color": "#666"}}
    return title


def _legend(height: int, top_px: int, bottom_px: int) -> dict:
    """A horizontal legend under the plot, inside the figure: plotly widens the bottom
    margin to hold its rows; ``y`` puts it below the tick labels (a fraction of the plot
    area, estimated from the figure's height and margins)."""
    plot_px = max(height - top_px - bottom_px - 40, 60)
    return {"orientation": "h", "x": 0.0, "xanchor": "left",
            "y": -LEGEND_GAP_PX / plot_px, "yanchor": "top",
            "font": {"size": LEGEND_FONT_PX}, "itemwidth": 30, "tracegroupgap": 0,
            "bgcolor": "rgba(255,255,255,0)"}


def _base_layout(title: str, height: int = 260, detail: str | None = None, **kw) -> dict:
    top = _TOP_PX[1 if detail else 0]
    bottom = 8
    layout = {
        "title": _title(title, detail),
        "height": height,
        "margin": {"l": 48, "r": 12, "t": top, "b": bottom},
        "legend": _legend(height, top, bottom),
        "xaxis": {"ticksuffix": " s", "automargin": True},
        "template": "plotly_white",
        "uirevision": "keep",
    }
    layout.update(kw)
    return layout


def _fault_windows(view: RunView) -> list[dict]:
    """Shaded rectangles over the epochs where any fault is injected (truth)."""
    active = np.any(view.faulted, axis=1)
    if not active.any():
        return []
    t = view.t_s
    edges = np.flatnonzero(np.diff(np.concatenate([[0], active.astype(np.int8), [0]])))
    shapes = []
    for i0, i1 in zip(edges[::2], edges[1::2], strict=True):
        shapes.append({
            "type": "rect", "xref": "x", "yref": "paper", "x0": float(t[i0]),
            "x1": float(t[i1 - 1]), "y0": 0, "y1": 1, "line": {"width": 0},
            "fillcolor": "rgba(245,150,20,0.12)", "layer": "below",
        })
    return shapes


# ---------------------------------------------------------------------------------------
# Builders


def detection_figure(view: RunView) -> PanelFigure:
    """Detection statistic vs threshold (top), normalised statistic and the theoretical
    detection probability of the injected fault (bottom) over time."""
    t = view.t_s
    tx = time_axis(t)
    stat = view.column("statistic")
    thr = view.column("threshold")
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = stat / thr
    alarm = np.asarray(view.table.get("alarm", np.zeros(t.shape, bool)), dtype=bool)
    data = [
        {"type": "scatter", **tx, "y": stat, "mode": "lines", "name": "statistic",
         "line": {"color": "#1f5eea", "width": 1.5}, "xaxis": "x", "yaxis": "y"},
        {"type": "scatter", **tx, "y": thr, "mode": "lines", "name": "threshold",
         "line": {"color": "#d62728", "dash": "dash", "width": 1.5}, "xaxis": "x",
         "yaxis": "y"},
        {"type": "scatter", "x": t[alarm], "y": stat[alarm], "mode": "markers",
         "name": "alarm", "marker": {"color": "#d62728", "size": 5, "symbol": "x"},
         "xaxis": "x", "yaxis": "y"},
        {"type": "scatter", **tx, "y": norm, "mode": "lines", "name": "statistic / threshold",
         "line": {"color": "#1f5eea", "width": 1.2}, "xaxis": "x", "yaxis": "y2",
         "showlegend": True},
    ]
    pd = view.column("pd_theory")
    if pd is not None:
        data.append({"type": "scatter", **tx, "y": pd, "mode": "lines",
                     # The engine's ncx2 probability of the snapshot chi-square test on the
                     # same epoch: a reference for every algorithm, exact only for that test.
                     "name": "P_d theory (snapshot χ² test)",
                     "line": {"color": "#f59614", "width": 1.5},
                     "xaxis": "x", "yaxis": "y3"})
    shapes = _fault_windows(view)
    shapes.append({"type": "line", "xref": "paper", "yref": "y2", "x0": 0, "x1": 1, "y0": 1,
                   "y1": 1, "line": {"color": "#d62728", "dash": "dash", "width": 1}})
    layout = _base_layout(
        "Detection: statistic vs threshold", height=400, detail=view.algorithm,
        xaxis={"ticksuffix": " s", "automargin": True, "anchor": "y2"},
        yaxis={"title": {"text": "statistic"}, "domain": [0.55, 1.0], "type": "log",
               "exponentformat": "power"},
        yaxis2={"title": {"text": "normalised"}, "domain": [0.0, 0.45], "type": "log",
                "exponentformat": "power"},
        yaxis3={"title": {"text": "P_d theory", "standoff": 2}, "overlaying": "y2",
                "side": "right", "range": [0, 1.05], "tickvals": [0, 0.5, 1],
                "showgrid": False},
        shapes=shapes,
    )
    layout["margin"] = dict(layout["margin"], r=40)
    return PanelFigure("detection", "Detection", data, layout, t_s=t)


def per_sat_figure(view: RunView, key: str, title: str | None = None,
                   y_title: str | None = None, log_y: bool = False) -> PanelFigure:
    """One line per satellite of ``view.per_sat[key]`` (E, S) over time; the satellites
    with an injected fault are drawn thick and named in the legend, the others thin under
    one legend entry; the algorithm's isolated satellite at each alarm epoch is marked."""
    t = view.t_s
    tx = time_axis(t)
    values = np.asarray(view.per_sat[key], dtype=float)
    faulty = np.any(view.faulted, axis=0)
    data = []
    for j, name in enumerate(view.sat_names):
        col = values[:, j]
        if not np.isfinite(col).any():
            continue
        trace = {"type": "scatter", **tx, "y": col, "mode": "lines", "name": name,
                 "line": {"width": 2.6 if faulty[j] else 1.0},
                 "opacity": 1.0 if faulty[j] else 0.7}
        if not faulty[j]:  # under one legend entry (the hover still names each)
            trace.update(legendgroup="others", showlegend=False)
        data.append(trace)
    if any(tr.get("legendgroup") == "others" for tr in data):
        data.insert(0, {"type": "scatter", "x": [None], "y": [None], "mode": "lines",
                        "name": "fault-free satellites", "legendgroup": "others",
                        "line": {"color": "#999", "width": 1.0}, "hoverinfo": "skip"})
    isolated = view.isolated_idx
    alarm = view.table.get("alarm")
    if isolated is not None and alarm is not None:
        iso = np.asarray(isolated, dtype=int)
        sel = np.asarray(alarm, dtype=bool) & (iso >= 0)
        if sel.any():
            data.append({"type": "scatter", "x": t[sel], "y": values[sel, iso[sel]],
                         "mode": "markers", "name": "isolated",
                         "marker": {"color": "#d62728", "size": 6, "symbol": "circle-open"},
                         "text": [view.sat_names[k] for k in iso[sel]],
                         "hovertemplate": "%{text}: %{y:.3g}<extra>isolated</extra>"})
    layout = _base_layout(title or f"Per satellite: {key}", height=300,
                          detail="thick: faulty (truth); o: isolated",
                          yaxis={"title": {"text": y_title or key},
                                 "type": "log" if log_y else "linear",
                                 "exponentformat": "power"},
                          shapes=_fault_windows(view))
    return PanelFigure(f"per_sat:{key}", title or key, data, layout, t_s=t)


def isolation_figure(view: RunView) -> PanelFigure:
    """Per-satellite isolation statistics (``per_sat["isolation"]``)."""
    return per_sat_figure(view, "isolation", "Isolation statistic per satellite",
                          "isolation statistic", log_y=True)


def error_figure(view: RunView) -> PanelFigure:
    """Horizontal (and vertical) position error before vs after isolation, with the alert
    limits and any protection levels the algorithm returns (``hpl_m``, ``vpl_m``).

    The error axis is logarithmic: a metre-level error after exclusion and a alert limit
    of hundreds of metres are both readable (a linear axis scaled by the HAL flattens the
    first)."""
    t = view.t_s
    tx = time_axis(t)
    data = []
    styles = [
        (("hpe_before_m",), "HPE before", "#7f7f7f", "solid", 1.2),
        (("hpe_after_m",), "HPE after exclusion", "#1f5eea", "solid", 1.8),
        (("vpe_before_m",), "VPE before", "#bcbd22", "dot", 1.0),
        (("vpe_after_m",), "VPE after exclusion", "#17becf", "dot", 1.2),
        (("hpl_m",), "HPL", "#9467bd", "dash", 1.5),
        (("vpl_m",), "VPL", "#8c564b", "dash", 1.2),
    ]
    for names, label, color, dash, width in styles:
        col = view.column(*names)
        if col is None:
            continue
        data.append({"type": "scatter", **tx,
                     "y": np.abs(col) if "pe_" in names[0] else col,
                     "mode": "lines", "name": label,
                     "line": {"color": color, "dash": dash, "width": width},
                     "visible": True if names[0].startswith("h") else "legendonly"})
    # Other protection levels an algorithm returns (hpl_nobaro_m, vpl_classic_m, ...).
    for key in view.table:
        if PROTECTION_LEVEL.match(key) and key not in ("hpl_m", "vpl_m"):
            data.append({"type": "scatter", **tx, "y": view.column(key), "mode": "lines",
                         "name": key, "line": {"dash": "dash", "width": 1.0},
                         "visible": "legendonly"})
    shapes = _fault_windows(view)
    shapes.append({"type": "line", "xref": "paper", "yref": "y", "x0": 0, "x1": 1,
                   "y0": view.hal_m, "y1": view.hal_m,
                   "line": {"color": "#d62728", "dash": "dash", "width": 1}})
    layout = _base_layout("Position error", height=300,
                          detail=f"before vs after exclusion; HAL {view.hal_m:g} m dashed",
                          yaxis={"title": {"text": "error (m)"}, "type": "log",
                                 "exponentformat": "power"},
                          shapes=shapes)
    layout["annotations"] = [{"xref": "paper", "yref": "y", "x": 1.0,
                              "y": float(np.log10(view.hal_m)) if view.hal_m > 0 else 0.0,
                              "text": "HAL", "showarrow": False, "xanchor": "right",
                              "yanchor": "bottom", "font": {"size": 10, "color": "#d62728"}}]
    return PanelFigure("errors", "Position error", data, layout, t_s=t)


def columns_figure(view: RunView, keys: list[str]) -> PanelFigure:
    """Generic panel: one line per extra per-epoch column (for algorithm outputs the
    dashboard has no dedicated panel for yet, e.g. ``n_eff``, ``beta``)."""
    t = view.t_s
    tx = time_axis(t)
    data = [{"type": "scatter", **tx, "y": view.column(k), "mode": "lines", "name": k}
            for k in keys]
    layout = _base_layout("Algorithm outputs", height=280, detail=", ".join(keys),
                          shapes=_fault_windows(view))
    return PanelFigure("columns", "Algorithm outputs", data, layout, t_s=t)


def particle_figure(view: RunView) -> PanelFigure:
    """The main particle filter's cloud now (East/North offsets from the true position,
    marker area by weight, colour by the Up offset), its weighted mean and the truth.

    The axes are fixed over the run (the 98th percentile of the cloud's extent) so that
    moving the time slider shows the cloud move and shrink, not the axes rescale.
    """
    enu = np.asarray(view.extras["particles_enu_m"], dtype=float)       # (E, K, 3)
    w = np.asarray(view.extras.get("particle_weight",
                                   np.full(enu.shape[:2], 1.0 / max(enu.shape[1], 1))))
    n_e, k_n = enu.shape[:2]
    ok = np.isfinite(enu).all(-1).all(-1)
    if ok.any():
        # Epochs ``ok`` have every particle finite: np.percentile (vectorised; nanpercentile
        # along an axis loops over the rows in Python, 40 ms for seed002's 419 epochs).
        radius = np.percentile(np.abs(enu[ok][..., :2]), 90, axis=1).max(-1)
        half = float(max(np.percentile(radius, 98) * 1.6, 2.0))
        u_lim = float(max(np.percentile(np.abs(enu[ok][..., 2]), 98), 1.0))
    else:
        half, u_lim = 10.0, 10.0

    def now(i: int) -> tuple[list[dict], dict]:
        i = int(np.clip(i, 0, n_e - 1))
        if not ok[i]:
            return [], {"annotations": [{"xref": "paper", "yref": "paper", "x": 0.5,
                                         "y": 0.5, "text": "no filter yet at this epoch",
                                         "showarrow": False}]}
        e, n, u = enu[i, :, 0], enu[i, :, 1], enu[i, :, 2]
        wi = np.nan_to_num(w[i])
        size = 4.0 + 14.0 * np.sqrt(wi * k_n / max(float((wi * k_n).max()), 1e-12))
        mean = (wi[:, None] * enu[i]).sum(0) / max(wi.sum(), 1e-300)
        traces = [
            {"type": "scatter", "x": e, "y": n, "mode": "markers", "name": "particles",
             "marker": {"size": size, "color": u, "colorscale": "RdBu", "cmin": -u_lim,
                        "cmax": u_lim, "opacity": 0.6, "line": {"width": 0},
                        "colorbar": {"title": {"text": "Up (m)"}, "thickness": 10,
                                     "len": 0.8}},
             "hovertemplate": "E %{x:.2f} m<br>N %{y:.2f} m<extra></extra>"},
            {"type": "scatter", "x": [mean[0]], "y": [mean[1]], "mode": "markers",
             "name": "estimate (weighted mean)",
             "marker": {"symbol": "x", "size": 12, "color": "#1f5eea"}},
            {"type": "scatter", "x": [0.0], "y": [0.0], "mode": "markers", "name": "truth",
             "marker": {"symbol": "star", "size": 14, "color": "#2ca02c",
                        "line": {"color": "white", "width": 1}}},
        ]
        return traces, {"annotations": []}

    layout = _base_layout("Particle cloud (now)", height=360,
                          detail="main filter; offsets from the true position",
                          xaxis={"title": {"text": "East (m)"}, "range": [-half, half],
                                 "zeroline": True},
                          yaxis={"title": {"text": "North (m)"}, "range": [-half, half],
                                 "zeroline": True, "scaleanchor": "x"})
    layout["legend"] = dict(layout["legend"], y=-0.2)
    return PanelFigure("particles", "Particle cloud", [], layout, dynamic=now,
                       t_s=view.t_s, marker=False)


#: Most epochs drawn per satellite track in the sky plot.
SKY_TRACK_POINTS = 120


#: Sky-plot marker of each system (a satellite name's first letter), and its legend mark.
SYSTEM_SYMBOLS = {"G": "circle", "E": "diamond", "C": "square", "R": "triangle-up"}
SYSTEM_MARKS = {"G": "●", "E": "◆", "C": "■", "R": "▲"}
SYSTEM_NAMES = {"G": "GPS", "E": "GAL", "C": "BDS", "R": "GLO"}


def sky_figure(view: RunView) -> PanelFigure:
    """2D sky plot (polar: azimuth clockwise from north, radius = 90 - elevation): every
    satellite's track over the run (static) and its position and state now (dynamic)."""
    az_deg = np.degrees(view.az_rad)
    zen_deg = 90.0 - np.degrees(view.el_rad)
    above = zen_deg <= 90.0
    tracks_r = np.where(above, zen_deg, np.nan)
    data = []
    # All tracks in one trace, NaN-separated, at most SKY_TRACK_POINTS epochs each (a
    # track is a smooth arc; every epoch would make each redraw of the sky plot, one per
    # time step, draw thousands of points).
    n_e, n_s = az_deg.shape
    keep = np.unique(np.r_[np.arange(0, n_e, max(1, -(-n_e // SKY_TRACK_POINTS))), n_e - 1])
    sep = np.full((1, n_s), np.nan)
    r_all = np.concatenate([tracks_r[keep], sep], axis=0).T.ravel()
    th_all = np.concatenate([az_deg[keep], sep], axis=0).T.ravel()
    data.append({"type": "scatterpolar", "r": r_all, "theta": th_all, "mode": "lines",
                 "name": "tracks", "line": {"color": "rgba(120,120,120,0.45)", "width": 1},
                 "hoverinfo": "skip", "showlegend": False})
    states = view.states()
    names = np.asarray(view.sat_names)
    # The colour is the state; the symbol is the system (a satellite name's letter).
    symbols = np.array([SYSTEM_SYMBOLS.get(n[:1], "circle") for n in names])
    letters = sorted({n[:1] for n in names}, key=lambda x: list(SYSTEM_SYMBOLS).index(x)
                     if x in SYSTEM_SYMBOLS else 99)

    def now(i: int) -> tuple[list[dict], dict]:
        i = int(np.clip(i, 0, n_e - 1))
        traces = []
        for k, state in enumerate(STATE_ORDER):
            sel = (states[i] == k) & above[i]
            traces.append({
                "type": "scatterpolar", "r": zen_deg[i, sel], "theta": az_deg[i, sel],
                "mode": "markers+text", "name": state, "text": names[sel].tolist(),
                "textposition": "top center", "textfont": {"size": 9},
                "marker": {"color": rgb(state), "size": 10, "symbol": symbols[sel].tolist(),
                           "line": {"color": "white", "width": 1}},
            })
        return traces, {}

    detail = (", ".join(f"{SYSTEM_MARKS[x]} {SYSTEM_NAMES[x]}" for x in letters
                        if x in SYSTEM_MARKS) if len(letters) > 1 else None)
    layout = _base_layout("Sky plot (now)", height=380, detail=detail)
    layout.pop("xaxis")
    layout["polar"] = {
        "radialaxis": {"range": [0, 90], "tickvals": [0, 30, 60, 90],
                       "ticktext": ["90", "60", "30", "0"], "angle": 90,
                       "tickfont": {"size": 9}},
        "angularaxis": {"rotation": 90, "direction": "clockwise",
                        "tickvals": [0, 90, 180, 270], "ticktext": ["N", "E", "S", "W"]},
    }
    layout["margin"] = {"l": 30, "r": 30, "t": _TOP_PX[1 if detail else 0] + 12, "b": 8}
    layout["legend"] = dict(layout["legend"], y=-0.06)
    ring = np.linspace(0.0, 360.0, 73)
    data.append({"type": "scatterpolar", "r": np.full(ring.shape, 90.0 - view.mask_deg),
                 "theta": ring, "mode": "lines", "name": "mask", "hoverinfo": "skip",
                 "line": {"color": "rgba(140,80,230,0.8)", "dash": "dash", "width": 1}})
    return PanelFigure("sky", "Sky plot", data, layout, dynamic=now, t_s=view.t_s,
                       marker=False)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``(i0, i1)`` index ranges (``i1`` exclusive) of the runs of True in ``mask``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True))


def _araim_limit(name: str, default: float) -> float:
    """An LPV-200 limit as the ``araim`` option declares its default (``emt_max_m``,
    ``sigma_acc_max_m``); ``default`` when the algorithm is not registered."""
    try:
        from raimcore import algorithms

        for opt in algorithms.get("araim").options:
            if opt.name == name:
                return float(opt.default)
    except (KeyError, AttributeError, ValueError):
        pass
    return default


def araim_figure(view: RunView) -> PanelFigure:
    """ARAIM protection levels over time (ARAIM.md sections 7, 8 and 11): VPL and HPL
    against VAL and HAL (top), the effective monitor threshold (EMT) and the vertical
    accuracy sigma against their LPV-200 limits (bottom); the epochs that fail any of the
    four LPV-200 criteria (column ``available``) shaded grey.

    The EMT and sigma_acc limits drawn are the ``araim`` option defaults (15 m and 1.87 m);
    the shading reads the run's own ``available`` column, so it follows the options the
    run used. Each trace's ``meta.column`` names the table column it draws."""
    t = view.t_s
    tx = time_axis(t)

    def col(name: str) -> np.ndarray:
        arr = view.column(name)
        return np.where(np.isfinite(arr), arr, np.nan)

    emt_max = _araim_limit("emt_max_m", 15.0)
    acc_max = _araim_limit("sigma_acc_max_m", 1.87)
    data = [
        {"type": "scatter", **tx, "y": col("vpl_m"), "mode": "lines", "name": "VPL",
         "meta": {"column": "vpl_m"},
         "line": {"color": "#8c564b", "width": 1.6}, "xaxis": "x", "yaxis": "y"},
        {"type": "scatter", **tx, "y": col("hpl_m"), "mode": "lines", "name": "HPL",
         "meta": {"column": "hpl_m"},
         "line": {"color": "#9467bd", "width": 1.4}, "xaxis": "x", "yaxis": "y"},
        {"type": "scatter", **tx, "y": col("emt_m"), "mode": "lines", "name": "EMT",
         "meta": {"column": "emt_m"},
         "line": {"color": "#1f5eea", "width": 1.4}, "xaxis": "x", "yaxis": "y2"},
    ]
    if "sigma_acc_m" in view.table:
        data.append({"type": "scatter", **tx, "y": col("sigma_acc_m"), "mode": "lines",
                     "name": "σ_acc", "meta": {"column": "sigma_acc_m"},
                     "line": {"color": "#2ca02c", "width": 1.4},
                     "xaxis": "x", "yaxis": "y2"})

    def hline(y: float, yref: str, color: str) -> dict:
        return {"type": "line", "xref": "paper", "yref": yref, "x0": 0, "x1": 1, "y0": y,
                "y1": y, "line": {"color": color, "dash": "dash", "width": 1}}

    def label(y: float, yref: str, text: str, color: str) -> dict:
        return {"xref": "paper", "yref": yref, "x": 1.0, "y": y, "text": text,
                "showarrow": False, "xanchor": "right", "yanchor": "bottom",
                "font": {"size": 9, "color": color}}

    shapes = _fault_windows(view)
    if "available" in view.table:
        avail = np.asarray(view.table["available"], dtype=bool)
        for i0, i1 in _runs(~avail):
            shapes.append({"type": "rect", "xref": "x", "yref": "paper",
                           "x0": float(t[i0]), "x1": float(t[i1 - 1]), "y0": 0, "y1": 1,
                           "line": {"width": 0}, "fillcolor": "rgba(120,120,120,0.13)",
                           "layer": "below", "name": "unavailable"})
    shapes += [hline(view.val_m, "y", "#8c564b"), hline(view.hal_m, "y", "#9467bd"),
               hline(emt_max, "y2", "#1f5eea"), hline(acc_max, "y2", "#2ca02c")]
    annotations = [label(view.val_m, "y", f"VAL {view.val_m:g}", "#8c564b"),
                   label(view.hal_m, "y", f"HAL {view.hal_m:g}", "#9467bd"),
                   label(emt_max, "y2", f"EMT max {emt_max:g}", "#1f5eea"),
                   label(acc_max, "y2", f"σ_acc max {acc_max:g}", "#2ca02c")]
    avail_col = view.table.get("available")
    share = (f"{100 * float(np.mean(np.asarray(avail_col, dtype=bool))):.0f}%"
             if avail_col is not None and len(t) else "n/a")
    layout = _base_layout(
        "ARAIM protection levels", height=400,
        detail=f"LPV-200 available {share}; grey: not",
        xaxis={"ticksuffix": " s", "automargin": True, "anchor": "y2"},
        yaxis={"title": {"text": "PL (m)"}, "domain": [0.5, 1.0], "rangemode": "tozero"},
        yaxis2={"title": {"text": "EMT, σ_acc (m)"}, "domain": [0.0, 0.4],
                "rangemode": "tozero"},
        shapes=shapes)
    layout["annotations"] = annotations
    return PanelFigure("araim", "ARAIM protection levels", data, layout, t_s=t)
