"""The panel registry: which Plotly panels a run gets, keyed on the columns it has.

A panel declares the result columns it needs (``"statistic"``, ``"hpl_m"``) and the
per-satellite arrays it needs (``"per_sat:isolation"``). For a run, :func:`panels_for`
returns every registered panel whose needs are met, then one generic per-satellite panel
for each per-satellite array no panel claimed, and one generic panel for the remaining
numeric per-epoch columns. So an algorithm that returns new outputs (``n_eff``, ``beta``,
per-satellite ``llr`` or ``mf``) gets panels without any dashboard change; a dedicated
panel is one :func:`register_panel` call.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import figures
from .figures import PanelFigure, RunView

# Columns every run has, or that a built-in panel shows: never repeated in the generic panel.
ENGINE_COLUMNS = frozenset({
    "t_s", "n_sat", "status", "statistic", "threshold", "alarm", "isolated", "excluded",
    "hpe_before_m", "hpe_after_m", "vpe_before_m", "vpe_after_m", "faulty_truth",
    "pd_theory", "n_excluded", "epoch",
})


@dataclass(frozen=True)
class PanelSpec:
    """A registered panel.

    Attributes
    ----------
    key : unique key (also the GUI element's identity across recomputes).
    needs : names that must all be present: table columns, or ``"per_sat:NAME"``.
    any_of : names of which at least one must be present (empty: no condition).
    build : ``build(view) -> PanelFigure``.
    order : position in the panel list (smaller first).
    claims : names this panel shows, kept out of the generic panels.
    """

    key: str
    build: Callable[[RunView], PanelFigure]
    needs: tuple[str, ...] = ()
    any_of: tuple[str, ...] = ()
    order: float = 100.0
    claims: tuple[str, ...] = ()


_PANELS: dict[str, PanelSpec] = {}


def register_panel(spec: PanelSpec) -> PanelSpec:
    """Add (or replace) a panel in the registry."""
    _PANELS[spec.key] = spec
    return spec


def available(view: RunView) -> set[str]:
    """Names a run offers: its table columns and ``per_sat:NAME`` for each array."""
    return set(view.table) | {f"per_sat:{k}" for k in view.per_sat}


def _numeric_column(view: RunView, key: str) -> bool:
    arr = np.asarray(view.table[key])
    return arr.ndim == 1 and arr.dtype.kind in "fiu" and bool(np.isfinite(arr).any())


def panels_for(view: RunView) -> list[tuple[str, Callable[[RunView], PanelFigure]]]:
    """``(key, build)`` for every panel this run should show, in display order."""
    have = available(view)
    chosen = [p for p in _PANELS.values()
              if all(n in have for n in p.needs)
              and (not p.any_of or any(n in have for n in p.any_of))]
    chosen.sort(key=lambda p: p.order)
    claimed = set().union(*(set(p.needs) | set(p.claims) for p in chosen)) if chosen else set()
    out: list[tuple[str, Callable[[RunView], PanelFigure]]] = [(p.key, p.build)
                                                                 for p in chosen]
    for key in view.per_sat:
        if f"per_sat:{key}" not in claimed:
            out.append((f"per_sat:{key}",
                        lambda v, k=key: figures.per_sat_figure(v, k)))
    extra = sorted(k for k in view.table
                   if k not in ENGINE_COLUMNS and k not in claimed and _numeric_column(view, k))
    if extra:
        out.append(("columns", lambda v, ks=tuple(extra): figures.columns_figure(v, list(ks))))
    return out


# Built-in panels.
register_panel(PanelSpec("sky", figures.sky_figure, order=40))
register_panel(PanelSpec("detection", figures.detection_figure,
                         needs=("statistic", "threshold"), order=10,
                         claims=("pd_theory", "alarm")))
register_panel(PanelSpec("isolation", figures.isolation_figure,
                         needs=("per_sat:isolation",), order=20))
register_panel(PanelSpec("errors", figures.error_figure,
                         any_of=("hpe_before_m", "hpe_after_m", "hpl_m"), order=30,
                         claims=("hpe_before_m", "hpe_after_m", "vpe_before_m",
                                 "vpe_after_m", "hpl_m", "vpl_m")))
