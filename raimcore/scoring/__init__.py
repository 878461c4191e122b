"""Stage 4 of the pipeline, scoring: the algorithm's output against the truth.

:func:`make_table` builds the per-epoch :class:`~raimcore.scoring.table.ResultTable`
(errors in the local frame, the theoretical detection probability, the truth);
:func:`summarize` reads it into a frozen :class:`Summary` whose every rate keeps its counts
and a 95% Clopper-Pearson interval (:class:`Rate`). The CLI, ``raim compare``, the
dashboard verdict and Monte Carlo read the summary.

Rules, stated once:

- *faulted* epochs: a fault acts on a used satellite (:attr:`raimcore.measure.Truth.faulted`);
  a constellation fault (:mod:`raimcore.measure.faults`) marks every used satellite of its
  system. *Detection*: an alarm at a faulted epoch, whatever the fault;
- *correct isolation*: the excluded satellites are exactly the faulted ones (the
  ``excluded`` and ``faulty_truth`` columns equal). For a constellation fault that is
  every used satellite of the constellation and no other: excluding only some of them
  leaves faulted measurements in the solution. An algorithm that excludes a constellation
  (ARAIM) reports its used satellites in ``excluded``;
- *fault memory*: epochs after a fault that a windowed algorithm still holds
  (:func:`in_fault_memory`); neither faulted nor fault-free;
- *unavailable* epochs (too few satellites, singular geometry) carry NaN positions and enter
  no statistic; they are counted. *Detect-only* epochs (one redundant measurement) enter the
  detection rates but not the isolation rate; they are counted too.
- *the error model against p_fa*: the fault-free alarm share is set against the run's
  ``p_fa`` (the scenario's, or the algorithm's own: ARAIM's budgets) with its 95%
  interval (``Summary.false_alarm_check``); when the whole interval lies above ``p_fa``,
  a note says that the error model under-bounds the errors and names it. The share
  counts every available fault-free epoch (a filter's not-yet-armed epochs too), and the
  interval assumes independent epochs: time-correlated real errors make the true
  uncertainty wider.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import stats

from ..algorithms.base import STATUS_NO_ISOLATION, STATUS_UNAVAILABLE, AlgorithmOutput
from ..algorithms.parity import _whitened_projector, detection_probability
from ..geometry import ecef_to_enu
from ..lsq import clock_columns, geometry_rows
from ..measure.data import Measurements, Truth
from .table import ResultTable

__all__ = ["make_table", "summarize", "Summary", "Rate", "in_fault_memory", "ResultTable",
           "false_alarm_check", "stanford_esa", "stanford_from_table",
           "stanford_from_result", "stanford_from_csv", "StanfordResult", "StanfordDiagram"]


@dataclass(frozen=True)
class Rate:
    """``k`` events in ``n`` trials, with the exact (Clopper-Pearson) 95% interval."""

    k: int
    n: int

    @property
    def value(self) -> float:
        """``k / n`` (NaN when ``n`` is 0)."""
        return self.k / self.n if self.n else math.nan

    @property
    def ci95(self) -> tuple[float, float]:
        """95% Clopper-Pearson interval, as ``scipy.stats.binomtest(k, n)
        .proportion_ci(0.95, "exact")`` gives it (NaN, NaN when ``n`` is 0)."""
        if self.n == 0:
            return (math.nan, math.nan)
        ci = stats.binomtest(self.k, self.n).proportion_ci(0.95, method="exact")
        return (float(ci.low), float(ci.high))

    def __str__(self) -> str:
        if self.n == 0:
            return "n/a (0 epochs)"
        lo, hi = self.ci95
        return f"{100 * self.value:.1f}% ({self.k}/{self.n}; 95% CI {100 * lo:.1f}-{100 * hi:.1f}%)"


@dataclass(frozen=True)
class Summary:
    """Headline numbers of one run; every rate is a :class:`Rate` (counts + interval).

    Epoch counts: ``epochs`` in all, ``unavailable_epochs``, ``detect_only_epochs``,
    ``faulted_epochs`` (a fault acts on a used satellite), ``fault_memory_epochs`` and the
    alarms raised in them (``fault_memory_alarms``: not false alarms).
    Rates: ``false_alarm`` over available fault-free epochs (outside fault memory),
    ``detection`` and ``correct_isolation`` over available faulted epochs (isolation: only
    where the algorithm can isolate, i.e. not detect-only), ``pl_availability`` over all
    epochs. Times, errors (m) and means are over available epochs; None where there is
    nothing to average. ``notes`` say what the user should know (faults that never act,
    ignored keys, a recording's measured errors, an error model that under-bounds).

    ``p_fa`` and ``error_model`` are those of the run; ``false_alarm_check`` is where the
    95% interval of ``false_alarm`` lies against ``p_fa``: ``"within"``, ``"above"`` (the
    error model under-bounds the errors) or ``"below"`` (it over-bounds them), None
    without fault-free epochs or ``p_fa``; ``false_alarm_statement`` says it in one line.

    ``summary["false_alarm_rate"]`` and :meth:`to_dict` give the flat form (rates as values,
    with ``*_k``, ``*_n`` and ``*_ci95`` beside them; None for missing values).
    """

    epochs: int
    unavailable_epochs: int
    detect_only_epochs: int
    faulted_epochs: int
    fault_memory_epochs: int
    false_alarm: Rate
    fault_memory_alarms: int = 0
    detection: Rate | None = None
    correct_isolation: Rate | None = None
    first_fault_t_s: float | None = None
    first_alarm_t_s: float | None = None
    pd_theory_mean: float | None = None
    hpe_before_faulted_mean_m: float | None = None
    hpe_after_faulted_mean_m: float | None = None
    hpe_nominal_mean_m: float | None = None
    rmse_before_m: float | None = None
    rmse_after_m: float | None = None
    n_eff_mean: float | None = None
    hpl_mean_m: float | None = None
    vpl_mean_m: float | None = None
    pl_availability: Rate | None = None
    baro_vpl_not_higher_share: float | None = None
    baro_vpl_lower_share: float | None = None
    baro_hpl_lower_share: float | None = None
    p_fa: float | None = None
    error_model: str | None = None
    false_alarm_check: str | None = None
    false_alarm_statement: str | None = None
    notes: tuple[str, ...] = field(default=())

    def to_dict(self) -> dict[str, Any]:
        """Flat JSON-safe form: rates as ``<name>_rate`` (value), ``<name>_k``, ``<name>_n``,
        ``<name>_ci95``; NaN written as None."""
        return dict(self._flat)

    @functools.cached_property
    def _flat(self) -> dict[str, Any]:
        """:meth:`to_dict`, computed once (each interval is a binomial inversion)."""
        out: dict[str, Any] = {}
        for name in self.__dataclass_fields__:
            v = getattr(self, name)
            if isinstance(v, Rate):
                key = name if name == "pl_availability" else f"{name}_rate"
                out[key] = _clean(v.value)
                out[f"{name}_k"], out[f"{name}_n"] = v.k, v.n
                out[f"{name}_ci95"] = [_clean(x) for x in v.ci95]
            elif name == "notes":
                out[name] = list(v)
            else:
                out[name] = _clean(v)
        return out

    def __getitem__(self, key: str):
        return self._flat[key]

    def get(self, key: str, default=None):
        v = self._flat.get(key, default)
        return default if v is None else v

    def __contains__(self, key: str) -> bool:
        return self._flat.get(key) is not None


def _clean(x):
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _mean(x) -> float | None:
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def make_table(data: Measurements, truth: Truth, out: AlgorithmOutput) -> ResultTable:
    """The per-epoch result table: algorithm output plus errors and truth.

    The table also keeps the run's ``p_fa`` (the algorithm's own, ``out.p_fa``, where it
    has one: ARAIM's budgets) and error model in its ``run_info`` dict, which
    :func:`summarize` reads to set the alarm share against ``p_fa``; the theoretical
    detection probability ``pd_theory`` is that of a chi-square test at this ``p_fa``."""
    names = np.array(data.sat_names + ("",), dtype=object)
    p_fa = float(data.p_fa if out.p_fa is None else out.p_fa)
    pos_true = truth.pos_rx_ecef_m
    err_b = ecef_to_enu(out.pos_before_ecef_m, pos_true)
    err_a = ecef_to_enu(out.pos_after_ecef_m, pos_true)
    faulty = truth.faulted
    # Theoretical detection probability of the snapshot chi-square test for the injected
    # faults, at the true geometry (spec section 1).
    pd = np.full(data.n_epochs, np.nan)
    rows = np.flatnonzero(faulty.any(axis=1))
    if rows.size:
        cols = np.flatnonzero(data.used[rows].any(axis=0))
        used = data.used[np.ix_(rows, cols)]
        cc = clock_columns(data.sys_idx[cols], len(data.systems))
        h, _ = geometry_rows(data.pos_sv_ecef_m[rows][:, cols], pos_true[rows], cc)
        w = np.where(used, 1.0 / data.sigma_m[np.ix_(rows, cols)] ** 2, 0.0)
        proj, _ = _whitened_projector(h, w)
        n_states = 3 + np.any(used[..., None] & (cc[None] > 0), axis=1).sum(-1)
        dof = used.sum(-1) - n_states
        pd[rows] = detection_probability(proj, truth.fault_bias_m[np.ix_(rows, cols)], w, dof,
                                         p_fa)
    thr = np.asarray(out.threshold, dtype=float)
    stat = np.asarray(out.statistic, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        normalised = stat / thr
    iso = np.asarray(out.isolated)
    cols = {
        "t_s": data.t_s,
        "n_sat": data.used.sum(-1),
        "status": np.asarray(out.status, dtype=object),
        "statistic": stat,
        "threshold": thr,
        "normalised": normalised,
        "alarm": np.asarray(out.alarm, dtype=bool),
        "isolated": names[np.where(iso >= 0, iso, -1)],
        "excluded": _names(out.excluded, data.sat_names),
        "faulty_truth": _names(faulty, data.sat_names),
        "hpe_before_m": np.hypot(err_b[:, 0], err_b[:, 1]),
        "hpe_after_m": np.hypot(err_a[:, 0], err_a[:, 1]),
        "vpe_before_m": np.abs(err_b[:, 2]),
        "vpe_after_m": np.abs(err_a[:, 2]),
        "pd_theory": pd,
    }
    for k, v in out.columns.items():
        if k in cols:
            raise ValueError(f"algorithm column {k!r} clashes with an engine column")
        cols[k] = np.asarray(v)
    per_sat = {"el_deg": np.degrees(data.el_rad), "az_deg": np.degrees(data.az_rad),
               "used": data.used, "fault_bias_m": truth.fault_bias_m,
               "excluded": np.asarray(out.excluded)}
    per_sat.update({k: np.asarray(v) for k, v in out.per_sat.items()})
    table = ResultTable(cols, per_sat, data.sat_names)
    table.run_info = {"p_fa": p_fa, "error_model": data.error_model}
    return table


def _names(mask, sat_names) -> np.ndarray:
    """Per row of a boolean ``(E, S)`` mask, the selected names joined by "+" (object array).

    Rows repeat (the same visible set for minutes), so each distinct row is joined once.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.size == 0:
        return np.full(mask.shape[0], "", dtype=object)
    uniq, inverse = np.unique(mask, axis=0, return_inverse=True)
    joined = np.array(["+".join(n for n, m in zip(sat_names, row, strict=True) if m)
                       for row in uniq], dtype=object)
    return joined[inverse.reshape(-1)]


def in_fault_memory(faulted, memory_epochs) -> np.ndarray:
    """(E,) bool: not faulted, but a faulted epoch lies within the last ``memory_epochs``
    epochs (``memory_epochs`` (E,) ints, or None for memoryless algorithms)."""
    faulted = np.asarray(faulted, dtype=bool)
    if memory_epochs is None or not faulted.any():
        return np.zeros_like(faulted)
    k = np.arange(faulted.size)
    last = np.maximum.accumulate(np.where(faulted, k, -1))
    mem = np.nan_to_num(np.asarray(memory_epochs, dtype=float), nan=1.0)
    return ~faulted & (last >= 0) & (k - last < mem)


def summarize(table: ResultTable, notes=(), *, p_fa: float | None = None,
              error_model: str | None = None) -> Summary:
    """The :class:`Summary` of a result table (``notes`` are passed through).

    ``p_fa`` and ``error_model`` default to those :func:`make_table` kept in the table's
    ``run_info``; with a ``p_fa`` the summary sets the fault-free alarm share against it
    (:func:`false_alarm_check`) and adds the under-bounding note when it is above."""
    t = table["t_s"]
    status = table["status"]
    faulted = table["faulty_truth"] != ""
    alarm = table["alarm"].astype(bool)
    excl = table["excluded"]
    available = status != STATUS_UNAVAILABLE
    detect_only = status == STATUS_NO_ISOLATION
    after = in_fault_memory(faulted, table["memory_epochs"] if "memory_epochs" in table
                             else None)
    nominal = ~faulted & ~after & available
    kw: dict[str, Any] = dict(
        epochs=len(table), unavailable_epochs=int((~available).sum()),
        detect_only_epochs=int(detect_only.sum()), faulted_epochs=int(faulted.sum()),
        fault_memory_epochs=int(after.sum()),
        false_alarm=Rate(int(alarm[nominal].sum()), int(nominal.sum())),
        fault_memory_alarms=int((alarm & after & available).sum()))
    if faulted.any():
        fa = faulted & available
        can_iso = fa & ~detect_only
        first = np.flatnonzero(faulted & alarm)
        kw.update(
            first_fault_t_s=float(t[faulted][0]),
            first_alarm_t_s=float(t[first[0]]) if first.size else None,
            detection=Rate(int(alarm[fa].sum()), int(fa.sum())),
            correct_isolation=Rate(int(np.sum(excl[can_iso] == table["faulty_truth"][can_iso])),
                                   int(can_iso.sum())),
            pd_theory_mean=_mean(table["pd_theory"][fa]),
            hpe_before_faulted_mean_m=_mean(table["hpe_before_m"][fa]),
            hpe_after_faulted_mean_m=_mean(table["hpe_after_m"][fa]))
    if nominal.any():
        kw["hpe_nominal_mean_m"] = _mean(table["hpe_before_m"][nominal])
    # 3-D position RMSE over every epoch with a position (seed 002 Table 1 compares these).
    for when in ("before", "after"):
        e2 = table[f"hpe_{when}_m"].astype(float) ** 2 + table[f"vpe_{when}_m"].astype(float) ** 2
        m = _mean(e2[available])
        kw[f"rmse_{when}_m"] = math.sqrt(m) if m is not None else None
    if "n_eff" in table:
        kw["n_eff_mean"] = _mean(table["n_eff"])
    kw.update(_summarize_pl(table))
    info = getattr(table, "run_info", {})
    p_fa = info.get("p_fa") if p_fa is None else p_fa
    error_model = info.get("error_model") if error_model is None else error_model
    notes = tuple(notes)
    if p_fa is not None:
        check, statement, note = false_alarm_check(kw["false_alarm"], p_fa, error_model)
        kw.update(p_fa=float(p_fa), false_alarm_check=check, false_alarm_statement=statement)
        if note:
            notes += (note,)
    return Summary(**kw, error_model=error_model, notes=notes)


def _pct(x: float) -> str:
    """A share in percent with 2 significant digits (0.1%, 0.0034%, 12%)."""
    return f"{100 * x:.2g}%" if x > 0 else "0%"


def false_alarm_check(rate: Rate, p_fa: float, error_model: str | None = None
                      ) -> tuple[str | None, str | None, str | None]:
    """The fault-free alarm share ``rate`` against ``p_fa``.

    Returns ``(check, statement, note)``: ``check`` is ``"within"``, ``"above"`` or
    ``"below"`` as the 95% Clopper-Pearson interval of ``rate`` contains ``p_fa`` or lies
    above or below it; ``statement`` says it in one line; ``note`` is the warning that
    the error model under-bounds the errors (``check == "above"``), else None. All None
    when ``rate`` has no trials.

    >>> check, statement, note = false_alarm_check(Rate(30, 1000), 1e-3, "elevation")
    >>> statement
    'fault-free alarm share 3% (30/1000; 95% CI 2%-4.3%): above p_fa 0.1%'
    >>> note.split(":")[0]
    'the error model under-bounds these errors (model elevation)'
    """
    if rate.n == 0:
        return None, None, None
    lo, hi = rate.ci95
    check = "above" if lo > p_fa else ("below" if hi < p_fa else "within")
    share = (f"fault-free alarm share {_pct(rate.value)} ({rate.k}/{rate.n}; 95% CI "
             f"{_pct(lo)}-{_pct(hi)})")
    where = {"within": f"p_fa {_pct(p_fa)} inside its interval",
             "above": f"above p_fa {_pct(p_fa)}",
             "below": f"below p_fa {_pct(p_fa)} (the error model over-bounds)"}[check]
    note = None
    if check == "above":
        note = (f"the error model under-bounds these errors (model "
                f"{error_model or 'not named'}): {share} {where}")
    return check, f"{share}: {where}", note


def _summarize_pl(table: ResultTable) -> dict[str, Any]:
    """Protection-level headlines for algorithms with ``hpl_m`` / ``vpl_m`` columns (and,
    for solution separation, the ``*_nobaro_m`` variants: how often the baro lowers them)."""
    out: dict[str, Any] = {}
    if "hpl_m" not in table or "vpl_m" not in table:
        return out
    hpl, vpl = table["hpl_m"].astype(float), table["vpl_m"].astype(float)
    out["hpl_mean_m"] = _mean(hpl)
    out["vpl_mean_m"] = _mean(vpl)
    if "available" in table:
        av = table["available"].astype(bool)
        out["pl_availability"] = Rate(int(av.sum()), int(av.size))
    if "vpl_nobaro_m" in table and "baro_used" in table and table["baro_used"].any():
        hpl0, vpl0 = table["hpl_nobaro_m"].astype(float), table["vpl_nobaro_m"].astype(float)
        both = np.isfinite(vpl) & np.isfinite(vpl0)
        if both.any():
            out["baro_vpl_not_higher_share"] = float(np.mean(vpl[both] <= vpl0[both]))
            out["baro_vpl_lower_share"] = float(np.mean(vpl[both] < vpl0[both]))
            out["baro_hpl_lower_share"] = float(np.mean(hpl[both] < hpl0[both]))
    return out


# The Stanford-ESA diagram (its results give their shares as Rate, defined above).
from .stanford import (  # noqa: E402
    StanfordDiagram,
    StanfordResult,
    stanford_esa,
    stanford_from_csv,
    stanford_from_result,
    stanford_from_table,
)
