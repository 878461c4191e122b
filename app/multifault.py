"""Dedicated panel for multi-fault isolation (seed 004: GF, RS, QV).

Top: every satellite's isolation score (GF's fused m(F), QV's share of failing groups, RS's
isolated flag) against the adaptive threshold mean + M; faulty satellites (truth) thick.
Bottom: the isolated set against the truth, one row per satellite: orange = injected fault,
red cross = excluded; a cross on orange is a correct exclusion, a cross alone a false one,
orange alone a missed one.
"""

from __future__ import annotations

import numpy as np

from .figures import PanelFigure, RunView, _base_layout, _fault_windows, time_axis
from .panels import PanelSpec, register_panel

#: per-satellite score -> its threshold column and axis label.
SCORES = {
    "mf": ("mf_threshold", "fused m(F)"),
    "qv_score": ("qv_threshold", "share of failing groups"),
    "rs_isolated": ("rs_threshold", "isolated (RS)"),
}


def multifault_figure(view: RunView, key: str = "mf") -> PanelFigure:
    """Score ``view.per_sat[key]`` vs its threshold (top) and the isolated set vs the truth
    (bottom) over time."""
    thr_key, label = SCORES[key]
    t = view.t_s
    tx = time_axis(t)
    score = np.asarray(view.per_sat[key], dtype=float)
    faulty = view.faulted
    ever = faulty.any(axis=0)
    data = []
    for j, name in enumerate(view.sat_names):
        if not np.isfinite(score[:, j]).any():
            continue
        data.append({"type": "scatter", **tx, "y": score[:, j], "mode": "lines",
                     "name": name, "legendgroup": name, "showlegend": bool(ever[j]),
                     "line": {"width": 2.6 if ever[j] else 0.9},
                     "opacity": 1.0 if ever[j] else 0.55, "xaxis": "x", "yaxis": "y"})
    thr = view.column(thr_key)
    if thr is not None:
        data.append({"type": "scatter", **tx, "y": thr, "mode": "lines",
                     "name": thr_key,
                     "line": {"color": "#d62728", "dash": "dash", "width": 1.8},
                     "xaxis": "x", "yaxis": "y"})
    # Isolated set vs truth: one row per satellite that is ever faulty or excluded.
    rows = np.flatnonzero(ever | view.excluded.any(axis=0))
    names = [view.sat_names[j] for j in rows]
    ti, si = np.nonzero(faulty[:, rows])
    data.append({"type": "scatter", "x": t[ti], "y": [names[k] for k in si],
                 "mode": "markers", "name": "faulty (truth)",
                 "marker": {"color": "rgba(245,150,20,0.6)", "symbol": "square", "size": 11},
                 "xaxis": "x", "yaxis": "y2"})
    te, se = np.nonzero(view.excluded[:, rows])
    data.append({"type": "scatter", "x": t[te], "y": [names[k] for k in se],
                 "mode": "markers", "name": "excluded",
                 "marker": {"color": "#d62728", "symbol": "x-thin-open", "size": 7,
                            "line": {"width": 1.5}},
                 "xaxis": "x", "yaxis": "y2"})
    exact = np.all(view.excluded == faulty, axis=1)
    detail = f"isolated set = truth at {100 * exact.mean():.0f}% of epochs"
    layout = _base_layout(
        "Multi-fault isolation", height=440, detail=detail,
        shapes=_fault_windows(view),
        xaxis={"ticksuffix": " s", "automargin": True, "anchor": "y2"},
        yaxis={"title": {"text": label}, "domain": [0.42, 1.0]},
        yaxis2={"title": {"text": "satellite"}, "domain": [0.0, 0.34], "type": "category",
                "categoryorder": "array", "categoryarray": names},
    )
    return PanelFigure(f"multifault:{key}", "Multi-fault isolation", data, layout, t_s=t)


def _builder(key: str):
    return lambda view: multifault_figure(view, key)


# One panel per score; it needs the score and its threshold column (a bare per-satellite
# "mf" from another algorithm still goes to the generic per-satellite panel).
for _key, (_thr, _) in SCORES.items():
    register_panel(PanelSpec(f"multifault:{_key}", _builder(_key),
                             needs=(f"per_sat:{_key}", _thr), order=20,
                             claims=(f"per_sat:{_key}", _thr)))
