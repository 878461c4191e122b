"""The Stanford-ESA integrity diagram as a Plotly figure, a dashboard panel, HTML and PNG.

The counts come from :mod:`raimcore.scoring.stanford` (regions as gLAB draws them); this
module draws them: a heatmap of the 2-D histogram (position error PE on x, protection
level PL on y, log colour scale of the epochs per bin), the diagonal PE = PL, the alert
limit lines, the regions shaded as gLAB shades them (MI pink, HMI red, unavailable yellow,
unavailable with PE >= PL magenta) and one box per diagram with every region's count and
share. :func:`diagram_figure` puts the horizontal and vertical diagrams side by side
(``raim stanford``) or one above the other (the dashboard's narrow panel).

``raim stanford`` writes the figure as one self-contained HTML file (plotly.js inline, no
CDN) and, with ``--png``, a PNG that a headless Chromium renders from that file
(:func:`write_png`): no Python package beyond plotly.
"""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from raimcore.scoring.stanford import (
    DEFAULT_BIN_M,
    StanfordDiagram,
    StanfordResult,
    stanford_from_table,
)

from .figures import PanelFigure, RunView, _base_layout

#: Region colours (gLAB graph.py: HMI 'r', MI 'pink', MI above the AL 'm', alarm 'y').
REGION_FILL = {
    "mi": "rgba(255,105,180,0.18)",
    "hmi": "rgba(220,40,40,0.18)",
    "unavailable": "rgba(230,200,0,0.18)",
    "unavailable_mi": "rgba(180,0,180,0.18)",
}
#: Most bins per axis drawn: finer histograms are shown summed over blocks of bins.
HTML_MAX_BINS = 400
PANEL_MAX_BINS = 60
#: Size of the standalone figure (``raim stanford``), px.
HTML_WIDTH_PX = 1200
HTML_HEIGHT_PX = 620
PANEL_HEIGHT_PX = 480  # like every panel: it fits a 700 px window
#: Browsers ``write_png`` looks for on PATH, in this order.
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")
PNG_TIMEOUT_S = 120.0


def block_for(result: StanfordResult, max_bins: int) -> int:
    """The number of histogram bins summed per drawn cell so that at most ``max_bins``
    cells are drawn per axis."""
    return max(1, math.ceil(result.n_bins / max_bins))


def axis_range_m(result: StanfordResult) -> tuple[float, bool]:
    """The square axis range (m) of one diagram and whether the alert limit is on it:
    the histogram's range, stretched to show the alert limit when it is at most twice
    that (a 556 m HAL over errors of a few metres is left off and named instead)."""
    top = 1.03 * result.range_m  # the last bin off the frame
    if result.al_m <= top:
        return top, True
    if result.al_m <= 2.0 * top:
        return 1.1 * result.al_m, True
    return top, False


def region_lines(result: StanfordResult, al_name: str, al_on: bool, *,
                 width: int = 90) -> list[str]:
    """Every region's count and share, the alert limit, in lines of at most about
    ``width`` characters (the heading of a diagram)."""
    items = result.region_items("alarmed")
    extra = []
    if result.unavailable_mi:
        extra.append(f"unavailable with PE ≥ PL {result.unavailable_mi}")
    if result.no_solution:
        extra.append(f"no solution {result.no_solution}")
    extra.append(f"{al_name} {result.al_m:g} m" + ("" if al_on else " (off the chart)"))
    lines, cur = [], ""
    for item in items + extra:
        nxt = f"{cur}, {item}" if cur else item
        if cur and len(nxt) > width:
            lines.append(cur + ",")
            cur = item
        else:
            cur = nxt
    return lines + [cur]


def diagram_parts(result: StanfordResult, *, ax: str, max_bins: int,
                  font_px: int = 11) -> tuple[list[dict], list[dict], list[dict], float]:
    """Traces, shapes and annotations of one diagram on axes ``x{ax}``/``y{ax}`` (``ax``
    is ``""`` or ``"2"``), and the largest log10 count drawn.

    The heatmap's cells are ``block * bin_m`` wide (:func:`block_for`); empty cells are
    transparent (NaN), so the region shading shows through."""
    xr, yr = f"x{ax}", f"y{ax}"
    top, al_on = axis_range_m(result)
    block = block_for(result, max_bins)
    cell = block * result.bin_m
    counts = result.dense(block).T.astype(float)  # rows: PL, columns: PE
    with np.errstate(divide="ignore"):
        z = np.where(counts > 0, np.log10(np.maximum(counts, 1.0)), np.nan)
    zmax = float(np.nanmax(z)) if np.isfinite(z).any() else 0.0
    # float32 / int32: half the bytes of a standalone file's (base64) arrays.
    traces = [{
        "type": "heatmap", "z": z.astype(np.float32), "customdata": counts.astype(np.int32),
        "x0": cell / 2, "dx": cell, "y0": cell / 2, "dy": cell, "coloraxis": "coloraxis",
        "xaxis": xr, "yaxis": yr, "name": result.label, "hoverongaps": False,
        "hovertemplate": "PE %{x:.2f} m, PL %{y:.2f} m: %{customdata} epochs<extra></extra>",
    }]
    line = {"color": "black", "width": 1.2}
    shapes = [{"type": "line", "xref": xr, "yref": yr, "x0": 0, "y0": 0, "x1": top, "y1": top,
               "line": line}]
    al = result.al_m
    if al_on:
        shapes += [
            _poly(xr, yr, [(0, 0), (al, al), (al, 0)], REGION_FILL["mi"]),
            _poly(xr, yr, [(al, 0), (top, 0), (top, al), (al, al)], REGION_FILL["hmi"]),
            _poly(xr, yr, [(0, al), (0, top), (top, top), (al, al)],
                  REGION_FILL["unavailable"]),
            _poly(xr, yr, [(al, al), (top, top), (top, al)], REGION_FILL["unavailable_mi"]),
            {"type": "line", "xref": xr, "yref": yr, "x0": al, "x1": al, "y0": 0, "y1": al,
             "line": {"color": "#d62728", "dash": "dash", "width": 1.2}},
            {"type": "line", "xref": xr, "yref": yr, "x0": 0, "x1": top, "y0": al, "y1": al,
             "line": {"color": "#d62728", "dash": "dash", "width": 1.2}},
        ]
    else:  # only the MI side of the diagonal is on the chart
        shapes.append(_poly(xr, yr, [(0, 0), (top, top), (top, 0)], REGION_FILL["mi"]))
    annotations = []
    if al_on:  # region names where the regions are wide enough to hold them
        small = {"size": font_px - 1, "color": "#555"}
        spots = [("MI", 0.62 * al, 0.25 * al, al >= 0.15 * top),
                 ("HMI", (al + top) / 2, al / 2, top - al >= 0.15 * top and al >= 0.08 * top),
                 ("unavailable", 0.3 * (al + top) / 2, (al + top) / 2, top - al >= 0.1 * top)]
        annotations += [{"xref": xr, "yref": yr, "x": x, "y": y, "text": text,
                         "showarrow": False, "font": small}
                        for text, x, y, fits in spots if fits]
    return traces, shapes, annotations, zmax


def _poly(xr: str, yr: str, pts, fill: str) -> dict:
    path = "M " + " L ".join(f"{x:.6g},{y:.6g}" for x, y in pts) + " Z"
    return {"type": "path", "xref": xr, "yref": yr, "path": path, "fillcolor": fill,
            "line": {"width": 0}, "layer": "below"}


def _coloraxis(zmax: float, font_px: int, **colorbar) -> dict:
    top = max(1, math.ceil(zmax))
    ticks = list(range(top + 1))
    return {"colorscale": "Jet", "cmin": 0.0, "cmax": float(top),
            "colorbar": {"title": {"text": "epochs per bin", "side": "right",
                                   "font": {"size": font_px}},
                         "tickvals": ticks, "ticktext": [f"{10 ** t:g}" for t in ticks],
                         "tickfont": {"size": font_px}, **colorbar}}


def _axes(result: StanfordResult, which: str, *, font_px: int) -> tuple[dict, dict]:
    top, _ = axis_range_m(result)
    pe, pl = ("HPE", "HPL") if which == "horizontal" else ("|VPE|", "VPL")
    x = {"title": {"text": f"{pe} (m)", "font": {"size": font_px}}, "range": [0, top],
         "constrain": "domain", "zeroline": False}
    y = {"title": {"text": f"{pl} (m)", "font": {"size": font_px}}, "range": [0, top],
         "constrain": "domain", "zeroline": False}
    return x, y


def diagram_figure(diagram: StanfordDiagram, *, side_by_side: bool = True,
                   max_bins: int = HTML_MAX_BINS) -> dict:
    """The horizontal and vertical diagrams as one plotly figure dict (``data``,
    ``layout``; numpy arrays inside), side by side (``raim stanford``) or stacked."""
    h, v = diagram.horizontal, diagram.vertical
    font = 12 if side_by_side else 9
    th, sh, ah, zh = diagram_parts(h, ax="", max_bins=max_bins, font_px=font)
    tv, sv, av, zv = diagram_parts(v, ax="2", max_bins=max_bins, font_px=font)
    xh, yh = _axes(h, "horizontal", font_px=font)
    xv, yv = _axes(v, "vertical", font_px=font)
    if side_by_side:
        xh["domain"], xv["domain"] = [0.0, 0.43], [0.53, 0.96]
        yh["domain"] = yv["domain"] = [0.0, 1.0]
    else:
        xh["domain"] = xv["domain"] = [0.0, 1.0]
        yh["domain"], yv["domain"] = [0.56, 1.0], [0.0, 0.44]
    xh["anchor"], yh["anchor"] = "y", "x"
    xv["anchor"], yv["anchor"] = "y2", "x2"
    yh["scaleanchor"], yv["scaleanchor"] = "x", "x2"
    blocks = {block_for(r, max_bins) * r.bin_m for r in (h, v)}
    shown = ", ".join(f"{b:g}" for b in sorted(blocks))
    title = f"Stanford-ESA integrity diagram: {diagram.source}" if diagram.source else \
        "Stanford-ESA integrity diagram"
    detail = (f"errors of the {diagram.error}-exclusion solution; protection levels "
              f"{diagram.pl_columns[0]}, {diagram.pl_columns[1]}; {shown} m bins"
              + (f" (histogram {h.bin_m:g} m)" if blocks != {h.bin_m} else ""))
    width = 80 if side_by_side else 44
    heads = []
    for x, y, name, al_name, r in (("x", "y", "Horizontal", "HAL", h),
                                   ("x2", "y2", "Vertical", "VAL", v)):
        lines = [f"<b>{name}</b> ({r.epochs} epochs)"]
        lines += region_lines(r, al_name, axis_range_m(r)[1], width=width)
        heads.append({"xref": f"{x} domain", "yref": f"{y} domain", "x": 0.0, "y": 1.0,
                      "xanchor": "left", "yanchor": "bottom", "align": "left",
                      "showarrow": False, "text": "<br>".join(lines),
                      "font": {"size": font}})
    layout = {
        "title": {"text": title, "subtitle": {"text": detail}, "x": 0.02, "xanchor": "left",
                  "y": 0.985, "yref": "container", "yanchor": "top"},
        "width": HTML_WIDTH_PX, "height": HTML_HEIGHT_PX,
        "margin": {"l": 60, "r": 40, "t": 125, "b": 60},
        "xaxis": xh, "yaxis": yh, "xaxis2": xv, "yaxis2": yv,
        "coloraxis": _coloraxis(max(zh, zv), font, x=1.0, thickness=14),
        "shapes": sh + sv, "annotations": ah + av + heads, "showlegend": False,
        "template": "plotly_white", "plot_bgcolor": "white",
    }
    return {"data": th + tv, "layout": layout}


# ---------------------------------------------------------------------------------------
# Dashboard panel


def panel_figure(view: RunView) -> PanelFigure:
    """The Stanford-ESA panel of the current run (needs ``hpl_m`` and ``vpl_m``): the
    horizontal diagram above the vertical one, and the current epoch marked on both."""
    diagram = stanford_from_table(view.table, view.hal_m, view.val_m,
                                  bin_m=DEFAULT_BIN_M, source="")
    fig = diagram_figure(diagram, side_by_side=False, max_bins=PANEL_MAX_BINS)
    cells = sorted({block_for(r, PANEL_MAX_BINS) * r.bin_m
                    for r in (diagram.horizontal, diagram.vertical)})
    layout = _base_layout("Stanford-ESA", height=PANEL_HEIGHT_PX,
                          detail=f"PE vs PL; {', '.join(f'{c:g}' for c in cells)} m "
                                 "bins; log colour")
    for key in ("xaxis", "yaxis", "xaxis2", "yaxis2", "coloraxis", "shapes",
                "annotations"):
        layout[key] = fig["layout"][key]
    layout["showlegend"] = False
    layout["margin"] = dict(layout["margin"], l=44, r=8, b=40)
    layout["coloraxis"]["colorbar"].update(thickness=8, len=0.9, x=1.02)
    layout["coloraxis"]["colorbar"]["title"]["text"] = "epochs"
    # From the bottom: vertical diagram, its heading, the horizontal one's x axis, the
    # horizontal diagram, its heading.
    layout["yaxis"]["domain"], layout["yaxis2"]["domain"] = [0.55, 0.855], [0.0, 0.355]
    pe = {k: np.abs(view.column(f"{k}pe_before_m")) for k in "hv"}
    pl = {"h": view.column("hpl_m"), "v": view.column("vpl_m")}
    n_e = len(view.t_s)

    def now(i: int) -> tuple[list[dict], dict]:
        i = int(np.clip(i, 0, max(n_e - 1, 0)))
        traces = []
        for k, ax in (("h", ""), ("v", "2")):
            x, y = pe[k][i], pl[k][i]
            if np.isfinite(x) and np.isfinite(y):
                traces.append({"type": "scatter", "x": [float(x)], "y": [float(y)],
                               "mode": "markers", "name": "now", "xaxis": f"x{ax}",
                               "yaxis": f"y{ax}", "hoverinfo": "skip",
                               "marker": {"symbol": "circle-open", "size": 11,
                                          "color": "black", "line": {"width": 2}}})
        return traces, {}

    return PanelFigure("stanford", "Stanford-ESA", fig["data"], layout, dynamic=now,
                       t_s=view.t_s, marker=False)


# ---------------------------------------------------------------------------------------
# Files


def to_plotly(fig: dict):
    """A validated ``plotly.graph_objects.Figure`` of a figure dict."""
    import plotly.graph_objects as go

    return go.Figure(fig)


def write_html(fig: dict, path) -> Path:
    """The figure as one self-contained HTML file: plotly.js inline (no CDN, works
    offline)."""
    path = Path(path)
    to_plotly(fig).write_html(path, include_plotlyjs=True, full_html=True,
                              config={"displaylogo": False, "responsive": False})
    return path


def find_browser() -> str | None:
    """A Chromium or Chrome executable on PATH (:data:`BROWSERS`), or None."""
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    return None


def png_requirement() -> str:
    return ("--png needs a Chromium or Chrome browser on PATH (one of "
            f"{', '.join(BROWSERS)}; Debian: apt-get install chromium), which renders "
            "the HTML headless")


def write_png(fig: dict, png_path, *, browser: str | None = None,
              timeout_s: float = PNG_TIMEOUT_S) -> Path:
    """The figure as a PNG, rendered by a headless Chromium from a static HTML page (no
    mode bar) at the figure's size.

    Raises
    ------
    ValueError
        No browser (:func:`png_requirement`), or the browser failed or wrote no image.
    """
    browser = browser or find_browser()
    if browser is None:
        raise ValueError(f"cannot write a PNG: {png_requirement()}")
    png_path = Path(png_path).resolve()
    width = int(fig["layout"].get("width", HTML_WIDTH_PX))
    height = int(fig["layout"].get("height", HTML_HEIGHT_PX))
    with tempfile.TemporaryDirectory(prefix="raim-png-") as tmp:
        page = Path(tmp) / "figure.html"
        to_plotly(fig).write_html(page, include_plotlyjs=True, full_html=True,
                                  config={"staticPlot": True, "displayModeBar": False})
        # The page's body has a margin: the window is a little larger than the figure.
        cmd = [browser, "--headless", "--no-sandbox", "--disable-gpu",
               "--hide-scrollbars", "--no-first-run", "--disable-extensions",
               f"--user-data-dir={tmp}/profile", f"--window-size={width + 16},{height + 16}",
               "--virtual-time-budget=15000", f"--screenshot={png_path}", page.as_uri()]
        env = dict(os.environ, HOME=tmp)  # the browser writes its caches here
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s,
                                  env=env, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            raise ValueError(f"cannot write a PNG: {browser} did not finish within "
                             f"{timeout_s:g} s") from None
    if not png_path.is_file() or png_path.stat().st_size == 0:
        tail = (done.stderr or done.stdout or "").strip().splitlines()
        why = tail[-1] if tail else f"exit status {done.returncode}"
        raise ValueError(f"cannot write a PNG: {browser} wrote no image ({why})")
    return png_path
