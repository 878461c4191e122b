"""The panel registry: which Plotly panels a run gets, keyed on the columns it has.

A panel declares the result columns it needs (``"statistic"``, ``"hpl_m"``) and the
per-satellite arrays it needs (``"per_sat:isolation"``). For a run, :func:`panels_for`
returns every registered panel whose needs are met, then one generic per-satellite panel
(showing one of the per-satellite arrays no panel claimed, picked in the GUI) and one
generic panel for the remaining numeric per-epoch columns. So an algorithm that returns
new outputs (``n_eff``, ``beta``, per-satellite ``llr`` or ``mf``) gets panels without any
dashboard change; a dedicated panel is one :func:`register_panel` call.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import figures
from .figures import PanelFigure, RunView

# Columns every run has, or that a built-in panel shows: never repeated in the generic panel.
ENGINE_COLUMNS = frozenset({
    "t_s", "n_sat", "status", "statistic", "threshold", "alarm", "isolated", "excluded",
    "hpe_before_m", "hpe_after_m", "vpe_before_m", "vpe_after_m", "faulty_truth",
    "pd_theory", "n_excluded", "epoch", "normalised", "dof", "memory_epochs",
})


@dataclass(frozen=True)
class PanelSpec:
    """A registered panel.

    Attributes
    ----------
    key : unique key (also the GUI element's identity across recomputes).
    needs : names that must all be present: table columns, ``"per_sat:NAME"`` or
        ``"extras:NAME"``.
    any_of : names of which at least one must be present (empty: no condition).
    build : ``build(view) -> PanelFigure``.
    order : position in the panel list (smaller first).
    claims : names this panel shows, kept out of the generic panels.
    claim_pattern : a regular expression for more such names (``hpl_nobaro_m``).
    """

    key: str
    build: Callable[[RunView], PanelFigure]
    needs: tuple[str, ...] = ()
    any_of: tuple[str, ...] = ()
    order: float = 100.0
    claims: tuple[str, ...] = ()
    claim_pattern: re.Pattern | None = None


_PANELS: dict[str, PanelSpec] = {}


def register_panel(spec: PanelSpec) -> PanelSpec:
    """Add (or replace) a panel in the registry."""
    _PANELS[spec.key] = spec
    return spec


def available(view: RunView) -> set[str]:
    """Names a run offers: its table columns, ``per_sat:NAME`` for each per-satellite
    array and ``extras:NAME`` for each display array."""
    return (set(view.table) | {f"per_sat:{k}" for k in view.per_sat}
            | {f"extras:{k}" for k in view.extras})


def _numeric_column(view: RunView, key: str) -> bool:
    arr = np.asarray(view.table[key])
    return arr.ndim == 1 and arr.dtype.kind in "fiu" and bool(np.isfinite(arr).any())


def _chosen(view: RunView) -> list[PanelSpec]:
    have = available(view)
    chosen = [p for p in _PANELS.values()
              if all(n in have for n in p.needs)
              and (not p.any_of or any(n in have for n in p.any_of))]
    return sorted(chosen, key=lambda p: p.order)


def _claimed(chosen: list[PanelSpec]) -> set[str]:
    return set().union(*(set(p.needs) | set(p.claims) for p in chosen)) if chosen else set()


def per_sat_keys(view: RunView) -> list[str]:
    """Per-satellite arrays no dedicated panel shows: the generic per-satellite panel
    offers these (one at a time, chosen in the GUI)."""
    claimed = _claimed(_chosen(view))
    return [k for k in view.per_sat if f"per_sat:{k}" not in claimed]


def panels_for(view: RunView, per_sat_key: str | None = None
               ) -> list[tuple[str, Callable[[RunView], PanelFigure]]]:
    """``(key, build)`` for every panel this run should show, in display order.

    Dedicated panels first, then one generic per-satellite panel (``"per_sat"``) showing
    ``per_sat_key`` (default: the first of :func:`per_sat_keys`), then one generic panel
    (``"columns"``) for the remaining numeric per-epoch columns.
    """
    chosen = _chosen(view)
    claimed = _claimed(chosen)
    out: list[tuple[str, Callable[[RunView], PanelFigure]]] = [(p.key, p.build)
                                                                 for p in chosen]
    keys = per_sat_keys(view)
    if keys:
        key = per_sat_key if per_sat_key in keys else keys[0]
        out.append(("per_sat", lambda v, k=key: figures.per_sat_figure(v, k)))
    patterns = [p.claim_pattern for p in chosen if p.claim_pattern is not None]
    extra = sorted(k for k in view.table
                   if k not in ENGINE_COLUMNS and k not in claimed
                   and not any(pat.match(k) for pat in patterns) and _numeric_column(view, k))
    if extra:
        out.append(("columns", lambda v, ks=tuple(extra): figures.columns_figure(v, list(ks))))
    return out


# Built-in panels.
register_panel(PanelSpec("sky", figures.sky_figure, order=40))
register_panel(PanelSpec("particles", figures.particle_figure,
                         needs=("extras:particles_enu_m",), order=45))
register_panel(PanelSpec("detection", figures.detection_figure,
                         needs=("statistic", "threshold"), order=10,
                         claims=("pd_theory", "alarm")))
register_panel(PanelSpec("isolation", figures.isolation_figure,
                         needs=("per_sat:isolation",), order=20))
register_panel(PanelSpec("errors", figures.error_figure,
                         any_of=("hpe_before_m", "hpe_after_m", "hpl_m"), order=30,
                         claims=("hpe_before_m", "hpe_after_m", "vpe_before_m",
                                 "vpe_after_m", "hpl_m", "vpl_m"),
                         claim_pattern=figures.PROTECTION_LEVEL))

from . import multifault  # noqa: E402,F401  (seed 004 multi-fault panel registers itself)
from . import stanford as _stanford  # noqa: E402,I001

# The Stanford-ESA diagram of every run with protection levels (after the sky plot: its
# x axis is an error, not the time).
register_panel(PanelSpec("stanford", _stanford.panel_figure,
                         needs=("hpl_m", "vpl_m", "hpe_before_m", "vpe_before_m"), order=50))

# ARAIM's protection levels against the four LPV-200 criteria (ARAIM.md section 11).
register_panel(PanelSpec("araim", figures.araim_figure, needs=("vpl_m", "emt_m"), order=15,
                         claims=("hpl_m", "sigma_acc_m", "available")))

from . import araim_modes as _araim_modes  # noqa: E402

# ARAIM's monitored fault modes at the time slider's epoch (follows the time updates).
register_panel(PanelSpec("araim_modes", _araim_modes.fault_modes_figure,
                         needs=tuple(f"extras:{k}" for k in _araim_modes.NEEDS), order=16))
