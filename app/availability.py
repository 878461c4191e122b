"""The ARAIM availability map as a Plotly figure, HTML and PNG (``raim availability``).

The numbers come from :func:`raimcore.studies.availability.availability`; this module
draws them: a heatmap over longitude / latitude (one cell per user, colour = share of
available epochs in %, NaN outside the region), the coastlines as the 0.5 contour of the
dashboard's 1-degree land mask (``app/assets/land_mask_1deg.npz``, nothing fetched), the
contour of the target availability (99.5 % by default, MAAST's ``avail_contour4.m`` draws
it), and the coverage in the title. HTML is self-contained (plotly.js inline, no CDN); the
PNG is rendered by a headless Chromium as :func:`app.stanford.write_png` does.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from raimcore.studies.availability import AvailabilityResult

from . import stanford

#: Size of the standalone figure, px.
WIDTH_PX = 1200
HEIGHT_PX = 680
#: Availability classes (%, lower edges) and their colours, as MAAST's contour plots band
#: them: differences near 99-100 % matter, those below 90 % hardly.
LEVELS_PCT = (0.0, 50.0, 75.0, 90.0, 95.0, 99.0, 99.5, 99.9)
LEVEL_COLORS = ("#67000d", "#d7301f", "#fc8d59", "#fee08b", "#d9ef8b", "#91cf60",
                "#1a9850", "#006837")


def level_index(pct) -> np.ndarray:
    """Class of each availability (%) in :data:`LEVELS_PCT` (NaN stays NaN)."""
    pct = np.asarray(pct, dtype=float)
    idx = np.digitize(pct, LEVELS_PCT[1:]).astype(float)
    return np.where(np.isfinite(pct), idx, np.nan)


def _discrete_scale() -> list:
    n = len(LEVEL_COLORS)
    return [[k / n, c] for i, c in enumerate(LEVEL_COLORS) for k in (i, i + 1)]


def _level_labels() -> list[str]:
    lo = LEVELS_PCT
    return ([f"< {lo[1]:g} %"] + [f"{lo[i]:g}-{lo[i + 1]:g} %" for i in range(1, len(lo) - 1)]
            + [f">= {lo[-1]:g} %"])


def coastline_trace() -> dict:
    """The coastlines: the 0.5 contour of the 1-degree land mask (lines only)."""
    from .scene import land_mask

    land = land_mask()[::-1].astype(float)  # rows south -> north
    n_lat, n_lon = land.shape
    lat = -90.0 + 180.0 / n_lat * (np.arange(n_lat) + 0.5)
    lon = -180.0 + 360.0 / n_lon * (np.arange(n_lon) + 0.5)
    return {"type": "contour", "z": land.tolist(), "x": lon.tolist(), "y": lat.tolist(),
            "contours": {"start": 0.5, "end": 0.5, "size": 1.0, "coloring": "none"},
            "line": {"color": "rgba(20,20,20,0.8)", "width": 1.0}, "showscale": False,
            "hoverinfo": "skip", "name": "coastline", "showlegend": False}


def title_text(res: AvailabilityResult) -> str:
    s = res.settings
    return (f"ARAIM LPV-200 availability, {'+'.join(s['systems'])} ({s['constellation']}), "
            f"ISM {s['ism']}: coverage {res.coverage_pct:.1f} % of users at "
            f"{100 * res.target:g} % availability (cos-lat weighted)")


def map_figure(res: AvailabilityResult, *, width_px: int = WIDTH_PX,
               height_px: int = HEIGHT_PX) -> dict:
    """The availability map as a Plotly figure dict."""
    s = res.settings
    z = 100.0 * res.grid("availability")
    vpl = res.grid("vpl_median_m")
    custom = np.stack([z, vpl, res.grid("vpl_p99_m"), res.grid("hpl_median_m")], axis=-1)
    level = level_index(z)
    n = len(LEVEL_COLORS)
    heat = {"type": "heatmap", "x": res.lon_axis_deg.tolist(), "y": res.lat_axis_deg.tolist(),
            "z": np.where(np.isfinite(level), level, None).tolist(),
            "customdata": np.where(np.isfinite(custom), custom, None).tolist(),
            "zmin": -0.5, "zmax": n - 0.5, "colorscale": _discrete_scale(),
            "name": "availability",
            "colorbar": {"title": {"text": "available<br>epochs"},
                         "tickvals": list(range(n)), "ticktext": _level_labels()},
            "hovertemplate": "lat %{y:g} deg, lon %{x:g} deg<br>availability "
                             "%{customdata[0]:.2f} %<br>VPL median %{customdata[1]:.1f} m, "
                             "99th pct %{customdata[2]:.1f} m<br>HPL median "
                             "%{customdata[3]:.1f} m<extra></extra>"}
    data = [heat]
    if z.shape[0] >= 2 and z.shape[1] >= 2 and np.isfinite(z).any():
        t = 100.0 * res.target
        data.append({"type": "contour", "x": res.lon_axis_deg.tolist(),
                     "y": res.lat_axis_deg.tolist(),
                     "z": np.where(np.isfinite(z), z, None).tolist(),
                     "contours": {"start": t, "end": t, "size": 1.0, "coloring": "none",
                                  "showlabels": True},
                     "line": {"color": "#08306b", "width": 2.5, "dash": "dash"},
                     "showscale": False, "hoverinfo": "skip",
                     "name": f"{t:g} % availability", "showlegend": True})
    data.append(coastline_trace())
    lon_pad = s["lon_step_deg"] / 2.0
    lat_pad = s["lat_step_deg"] / 2.0
    layout = {
        "title": {"text": title_text(res), "x": 0.01, "font": {"size": 15}},
        "width": width_px, "height": height_px, "template": "plotly_white",
        "margin": {"l": 60, "r": 20, "t": 60, "b": 90},
        "xaxis": {"title": {"text": "longitude (deg)"}, "range":
                  [float(res.lon_axis_deg.min()) - lon_pad,
                   float(res.lon_axis_deg.max()) + lon_pad],
                  "ticksuffix": "°", "showgrid": False, "zeroline": False},
        "yaxis": {"title": {"text": "latitude (deg)"}, "range":
                  [float(res.lat_axis_deg.min()) - lat_pad,
                   float(res.lat_axis_deg.max()) + lat_pad],
                  "ticksuffix": "°", "scaleanchor": "x", "scaleratio": 1.0,
                  "showgrid": False, "zeroline": False},
        "legend": {"orientation": "h", "x": 0.0, "y": -0.12},
        "annotations": [{
            "text": (f"{s['t_step_s']:g} s epochs over {s['duration_s']:g} s, "
                     f"{s['lat_step_deg']:g} x {s['lon_step_deg']:g} deg, mask "
                     f"{s['mask_deg']:g} deg; available: VPL <= {s['val_m']:g} m, HPL <= "
                     f"{s['hal_m']:g} m, EMT <= {s['emt_max_m']:g} m, sigma_acc <= "
                     f"{s['sigma_acc_max_m']:g} m"),
            "xref": "paper", "yref": "paper", "x": 1.0, "y": -0.15, "xanchor": "right",
            "showarrow": False, "font": {"size": 11}}],
    }
    return {"data": data, "layout": layout}


def write_html(fig: dict, path) -> Path:
    """Self-contained HTML (plotly.js inline, no CDN)."""
    return stanford.write_html(fig, path)


def write_png(fig: dict, path) -> Path:
    """PNG rendered by a headless Chromium (:func:`app.stanford.write_png`)."""
    return stanford.write_png(fig, path)
