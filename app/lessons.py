"""Guided lessons: Markdown files that set the dashboard up, say what to try, and check the
student's answer from the run itself.

A lesson is one Markdown file whose TOML front matter (between ``+++`` lines at the top,
or a TOML file of the same name beside it) declares::

    title = "A ramp and the detection delay"
    order = 4                         # place in the list (optional)
    steps = ["Press Play ...", "Lower the noise ..."]   # 2 to 4 "try this" steps

    [scenario]                        # what "Set up" opens
    base = "seed000-ramp"             # a built-in scenario or a .toml path (optional),
    sigma_m = 33                      # ... then any scenario key or algorithm option
    # recording = { obs = "A.rnx", nav = "B.rnx" }    # instead of base: a RINEX recording

    [question]
    text = "Lower the noise until the ramp is flagged within 5 s of its start."
    keep = ["faults", "p_fa"]         # settings the answer must leave as the lesson set them
    check = { kind = "first_alarm_within", seconds = 5 }
    success = "..."                   # said when the check passes (optional)
    hint = "..."                      # said when it does not (optional)

    [test]                            # overrides the test suite applies to the lesson's
    pass = { sigma_m = 3 }            # scenario: the check must pass with these ...
    fail = [{}, { sigma_m = 10 }]     # ... and fail with each of these ({} = as set up)

Paths in a lesson (``base``, the recording's ``obs`` and ``nav``) are relative to the
lesson's folder. A lesson whose recording is not on this machine still loads: it says which
files it needs and cannot be set up.

The check language (:func:`parse_check`) is a small declarative tree evaluated on a
:class:`~raimcore.pipeline.ScenarioResult`:

- ``{ all = [c, ...] }``, ``{ any = [c, ...] }``, ``{ not = c }``;
- ``{ metric = NAME, op = OP, value = X }``: a number of the run, OP one of
  ``< <= == != >= >``. Metrics are every number of :class:`~raimcore.scoring.Summary` in its
  flat form (``detection_rate``, ``false_alarm_k``, ``first_alarm_t_s``, ...) and a few read
  from the table and the geometry (:data:`METRICS`, e.g. ``detection_delay_s``,
  ``hdop_max``, ``fault_slope_rank``);
- ``{ setting = NAME, op = OP, value = X }``: a setting of the run (a scenario key, an
  algorithm option, ``fault.FIELD`` for the first fault, ``fault.SAT.FIELD``,
  ``fault_count``);
- ``{ kind = KIND, ... }``: a named test (:data:`KINDS`): ``detected_every_faulted_epoch``,
  ``no_false_alarms``, ``false_alarm_rate_consistent``, ``first_alarm_within`` (``seconds``,
  optional ``sat`` and ``naming``), ``isolated`` (``sat``, optional ``share``), and
  ``smallest`` / ``largest`` (``setting``, ``by`` or ``factor``, ``check``): the inner check
  holds on this run and fails once the setting is moved by one step, so the answer is the
  smallest (largest) value that works, to within that step.

Every evaluation returns ``(passed, message)``; the message says what was measured.
"""

from __future__ import annotations

import dataclasses
import html
import logging
import math
import operator
import re
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from raimcore.measure.faults import FAULT_FIELDS
from raimcore.pipeline import ScenarioResult, run_scenario
from raimcore.scenario import (
    Scenario,
    all_keys,
    from_dict,
    load_scenario,
    recording_scenario,
)
from raimcore.schema import did_you_mean
from raimcore.scoring import Rate, Summary

__all__ = ["Lesson", "LessonError", "LessonUnavailable", "Check", "load_lesson",
           "load_lessons", "scan_lessons", "check_lesson_dirs", "parse_check",
           "evaluate_check", "add_lessons_tab", "LessonsTab", "METRICS", "KINDS",
           "BUILTIN_DIR"]

log = logging.getLogger(__name__)

#: The lessons shipped with the dashboard.
BUILTIN_DIR = Path(__file__).resolve().parent / "lessons"
#: Fewest and most "try this" steps of a lesson.
STEPS_MIN, STEPS_MAX = 2, 4
#: How long "Check my answer" waits for a pending recompute (s).
CHECK_WAIT_S = 60.0
#: The lines that open and close a lesson's front matter.
FRONT_MATTER_FENCE = "+++"
#: A lesson's scenario name: the tab checks that the run is the lesson's.
SCENARIO_PREFIX = "lesson-"


class LessonError(ValueError):
    """A lesson file that cannot be used; the message is one line naming the file and
    what is wrong with it."""


class LessonUnavailable(LessonError):
    """A valid lesson that cannot be set up on this machine (its recording is absent)."""


# -- numbers of a run --------------------------------------------------------------------

@dataclass(frozen=True)
class Metric:
    """A number read from a run: ``read(result)`` gives it, or None where the run has
    none (``needs`` says what it needs then)."""

    name: str
    label: str
    unit: str
    read: Callable[[ScenarioResult], Any]
    needs: str = ""


#: Labels of the Summary numbers whose field name does not read well in a sentence.
_LABELS = {
    "detect_only_epochs": "detect-only epochs", "false_alarm_k": "false alarms",
    "false_alarm_n": "fault-free epochs", "detection_k": "detected epochs",
    "detection_n": "faulted epochs", "correct_isolation_k": "correctly isolated epochs",
    "correct_isolation_n": "faulted epochs where isolation is possible",
    "first_alarm_t_s": "first alarm at t =", "first_fault_t_s": "first faulted epoch at t =",
    "pd_theory_mean": "mean theoretical detection probability",
}


def _summary_metrics() -> dict[str, Metric]:
    """Every number of :class:`Summary`, named as in its flat form (``Summary.to_dict``)."""
    out: dict[str, Metric] = {}
    hints = {"detection": "a fault that acts on a used satellite",
             "correct_isolation": "a fault on a satellite that the algorithm can isolate",
             "pl_availability": "an algorithm with protection levels and alert limits"}
    for f in dataclasses.fields(Summary):
        name = f.name
        if name == "notes" or "str" in str(f.type):  # words, not a number to check
            continue
        words = name.replace("_", " ")
        if "Rate" in str(f.type):
            rate = name if name == "pl_availability" else f"{name}_rate"
            need = hints.get(name, "")
            out[rate] = Metric(rate, words + (" rate" if rate != name else ""), "rate",
                               lambda r, n=name: getattr(r.summary, n), need)
            out[f"{name}_k"] = Metric(f"{name}_k", f"{words} count", "",
                                      lambda r, n=name: _rate_part(r, n, "k"), need)
            out[f"{name}_n"] = Metric(f"{name}_n", f"{words} epochs", "",
                                      lambda r, n=name: _rate_part(r, n, "n"), need)
        else:
            unit = "s" if name.endswith("_t_s") else "m" if name.endswith("_m") else ""
            label = re.sub(r" (t s|m)$", "", words)
            out[name] = Metric(name, label, unit, lambda r, n=name: getattr(r.summary, n))
    for name, label in _LABELS.items():
        out[name] = dataclasses.replace(out[name], label=label)
    return out


def _rate_part(result: ScenarioResult, name: str, part: str):
    rate = getattr(result.summary, name)
    return None if rate is None else getattr(rate, part)


def _faults(result: ScenarioResult):
    return result.scenario.faults


def _onset_s(result: ScenarioResult, sat: str | None = None) -> float | None:
    """When the fault on ``sat`` (default: the earliest fault) starts, as its control
    states it (``t0_s``), no earlier than the run's first epoch."""
    faults = [f for f in _faults(result) if sat is None or f.sat == sat]
    if not faults:
        return None
    t = result.table["t_s"]
    return max(min(f.t0_s for f in faults), float(t[0]) if len(t) else 0.0)


def _first_alarm_after(result: ScenarioResult, t0_s: float, sat: str | None = None
                       ) -> float | None:
    """Time of the first alarm at or after ``t0_s`` (naming ``sat`` when given)."""
    tbl = result.table
    ok = (tbl["t_s"] >= t0_s - 1e-9) & tbl["alarm"].astype(bool)
    if sat is not None:
        ok &= _names_sat(tbl, sat)
    idx = np.flatnonzero(ok)
    return float(tbl["t_s"][idx[0]]) if idx.size else None


def _names_sat(tbl, sat: str) -> np.ndarray:
    """(E,) bool: the epoch's isolated satellite is ``sat`` or ``sat`` is excluded; ``sat``
    may name a constellation (``GAL``) that ``araim`` excluded as one fault mode (its
    column ``excluded_mode``)."""
    excl = np.array([sat in str(x).split("+") for x in tbl["excluded"]], dtype=bool)
    if "excluded_mode" in tbl:
        excl |= np.asarray(tbl["excluded_mode"]) == sat
    return (tbl["isolated"] == sat) | excl


def _detection_delay(result: ScenarioResult):
    onset = _onset_s(result)
    if onset is None:
        return None
    t = _first_alarm_after(result, onset)
    return None if t is None else t - onset


def _column_max(name: str):
    def read(result: ScenarioResult):
        if name not in result.table:
            return None
        x = result.table[name].astype(float)
        return float(np.nanmax(x)) if np.isfinite(x).any() else None
    return read


def _dops(result: ScenarioResult) -> dict[str, np.ndarray]:
    """DOPs of the satellites used at each epoch, at the true receiver position."""
    from raimcore.geometry import dops
    from raimcore.lsq import clock_columns, geometry_rows

    m = result.measurements
    cc = clock_columns(m.sys_idx, len(m.systems))
    h, _ = geometry_rows(m.pos_sv_ecef_m, result.truth.pos_rx_ecef_m, cc)
    h = np.where(m.used[..., None], h, 0.0)
    # A system without a satellite in view leaves an all-zero clock column: drop it.
    h = np.where(np.any(h != 0.0, axis=-2, keepdims=True), h, 0.0)
    out = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        full = np.any(h != 0.0, axis=-2)  # (E, n) states with data
        for k in ("hdop", "pdop"):
            out[k] = np.full(h.shape[0], np.nan)
        for cols in {tuple(c) for c in full}:
            rows = np.flatnonzero((full == np.array(cols)).all(axis=1))
            sub = h[rows][..., np.array(cols, dtype=bool)]
            if sub.shape[-1] < 4:
                continue
            d = dops(sub)
            for k in out:
                out[k][rows] = d[k]
    for k in out:  # singular or under-determined geometry: no DOP
        out[k] = np.where(m.used.sum(-1) >= 4, out[k], np.nan)
    return out


def _dop(kind: str, how: str):
    def read(result: ScenarioResult):
        x = _dops(result)[kind]
        x = x[np.isfinite(x)]
        if not x.size:
            return None
        return float(x.max() if how == "max" else x.mean())
    return read


def _hpe_faulted_max(missed: bool):
    def read(result: ScenarioResult):
        tbl = result.table
        sel = (tbl["faulty_truth"] != "") & (tbl["status"] != "unavailable")
        if missed:
            sel &= ~tbl["alarm"].astype(bool)
        x = tbl["hpe_before_m"].astype(float)[sel]
        x = x[np.isfinite(x)]
        return float(x.max()) if x.size else None
    return read


def _baro_vpl_ratio(result: ScenarioResult):
    tbl = result.table
    if "vpl_nobaro_m" not in tbl or "baro_used" not in tbl or not tbl["baro_used"].any():
        return None
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = tbl["vpl_m"].astype(float) / tbl["vpl_nobaro_m"].astype(float)
    ratio = ratio[np.isfinite(ratio)]
    return float(ratio.mean()) if ratio.size else None


def _first_fault_sat_series(result: ScenarioResult):
    """The first fault's satellite index and the epochs where it is faulted."""
    faults = _faults(result)
    names = result.measurements.sat_names
    if not faults or faults[0].sat not in names:
        return None, None
    j = names.index(faults[0].sat)
    rows = np.flatnonzero(result.truth.faulted[:, j])
    return (j, rows) if rows.size else (None, None)


def _fault_slope_rank(result: ScenarioResult):
    """Rank (1 = steepest) of the first faulty satellite's horizontal slope among the
    satellites in use, median over its faulted epochs (noise-free: the true geometry)."""
    from raimcore.algorithms.mss import classic_raim
    from raimcore.lsq import clock_columns, geometry_rows

    j, rows = _first_fault_sat_series(result)
    if j is None:
        return None
    m = result.measurements
    cc = clock_columns(m.sys_idx, len(m.systems))
    h, _ = geometry_rows(m.pos_sv_ecef_m[rows], result.truth.pos_rx_ecef_m[rows], cc)
    w = np.where(m.used[rows], 1.0 / m.sigma_m[rows] ** 2, 0.0)
    cr = classic_raim(h, np.zeros_like(w), w, np.ones(w.shape[-1], dtype=bool), m.p_fa,
                      m.p_md)
    slope = np.where(np.isfinite(cr.hslope_m), cr.hslope_m, -np.inf)
    mine = slope[:, j]
    ok = np.isfinite(mine)
    if not ok.any():
        return None
    rank = 1 + (slope[ok] > mine[ok, None]).sum(axis=1)
    return float(np.median(rank))


def _fault_isolability(result: ScenarioResult):
    """Mean isolability (largest |cos| between the first faulty satellite's parity column
    and another's) over its faulted epochs; parity algorithm only."""
    j, rows = _first_fault_sat_series(result)
    iso = result.table.per_sat.get("isolability")
    if j is None or iso is None:
        return None
    x = np.asarray(iso, dtype=float)[rows, j]
    x = x[np.isfinite(x)]
    return float(x.mean()) if x.size else None


def _lpv200_availability(result: ScenarioResult) -> Rate | None:
    """Epochs meeting all four LPV-200 criteria (``araim``'s ``available`` column: VPL,
    HPL, EMT and sigma_acc within their limits, ARAIM.md section 11)."""
    if "available" not in result.table:
        return None
    avail = np.asarray(result.table["available"], dtype=bool)
    return Rate(int(avail.sum()), int(avail.size))


def _derived_metrics() -> dict[str, Metric]:
    fault = "an injected fault"
    return {m.name: m for m in (
        Metric("detection_delay_s", "time from the fault's start to the first alarm", "s",
               _detection_delay, f"{fault} and an alarm after it starts"),
        Metric("hpl_max_m", "largest HPL", "m", _column_max("hpl_m"),
               "an algorithm with protection levels (parity, mss)"),
        Metric("vpl_max_m", "largest VPL", "m", _column_max("vpl_m"),
               "an algorithm with protection levels (parity, mss)"),
        Metric("lpv200_availability", "LPV-200 availability", "rate",
               _lpv200_availability, "the araim algorithm (its available column)"),
        Metric("hdop_max", "worst HDOP", "", _dop("hdop", "max"), "at least 4 satellites"),
        Metric("hdop_mean", "mean HDOP", "", _dop("hdop", "mean"), "at least 4 satellites"),
        Metric("pdop_max", "worst PDOP", "", _dop("pdop", "max"), "at least 4 satellites"),
        Metric("sats_min", "fewest satellites in use", "",
               lambda r: int(r.table["n_sat"].min()) if len(r.table) else None),
        Metric("sats_max", "most satellites in use", "",
               lambda r: int(r.table["n_sat"].max()) if len(r.table) else None),
        Metric("hpe_faulted_max_m", "largest horizontal error under the fault", "m",
               _hpe_faulted_max(False), fault),
        Metric("hpe_missed_max_m", "largest horizontal error while the fault went "
               "undetected", "m", _hpe_faulted_max(True), f"{fault} missed at some epoch"),
        Metric("baro_vpl_ratio_mean", "mean VPL with baro / VPL without", "",
               _baro_vpl_ratio, "solution separation (mss) with baro = true"),
        Metric("fault_slope_rank", "slope rank of the faulty satellite (1 = steepest)", "",
               _fault_slope_rank, f"{fault} on a satellite in use"),
        Metric("fault_isolability", "isolability of the faulty satellite", "",
               _fault_isolability, f"{fault} and the parity algorithm"),
    )}


#: Every metric a check may name.
METRICS: dict[str, Metric] = {**_summary_metrics(), **_derived_metrics()}

_OPS: dict[str, Callable[[Any, Any], bool]] = {
    "<": operator.lt, "<=": operator.le, ">": operator.gt, ">=": operator.ge,
    "==": lambda a, b: _same(a, b), "!=": lambda a, b: not _same(a, b)}
_OP_TEXT = {"<": "<", "<=": "≤", ">": ">", ">=": "≥", "==": "=", "!=": "≠"}


def _same(a, b) -> bool:
    if _is_number(a) and _is_number(b):
        return math.isclose(float(a), float(b), rel_tol=1e-9, abs_tol=1e-12)
    return a == b


def _is_number(x) -> bool:
    return isinstance(x, int | float | np.integer | np.floating) and not isinstance(x, bool)


def _fmt(x, unit: str = "") -> str:
    """A value for a message: rates as percent with counts, numbers with units."""
    if isinstance(x, Rate):
        return "n/a (0 epochs)" if x.n == 0 else f"{100 * x.value:.1f}% ({x.k} of {x.n})"
    if x is None:
        return "none"
    if isinstance(x, str):
        return f"{x!r}" if x else "''"
    if isinstance(x, bool) or not _is_number(x):
        return str(x)
    x = float(x)
    if math.isinf(x):
        return "∞"
    if unit == "rate":
        return f"{100 * x:g}%"
    if x != 0 and (abs(x) < 1e-3 or abs(x) >= 1e6):
        text = f"{x:.3g}"
    elif x == round(x):
        text = f"{x:.0f}"
    else:
        text = f"{x:.3g}" if abs(x) < 10 else f"{x:.1f}"
    return f"{text} {unit}" if unit and unit != "rate" else text


# -- settings of a run -------------------------------------------------------------------

_FAULT_PATH = re.compile(r"^fault\.(?:(?P<sat>[A-Z]\d{2,3})\.)?(?P<field>[a-z0-9_]+)$")


def _check_setting_name(name: str, where: str) -> None:
    """Refuse a setting path that names nothing (LessonError-free: ValueError)."""
    if name in ("faults", "fault_count") or name in all_keys():
        return
    m = _FAULT_PATH.match(name)
    if m and m["field"] in FAULT_FIELDS:
        return
    raise ValueError(f"{where}: unknown setting {name!r}"
                     f"{did_you_mean(name, [*all_keys(), 'faults', 'fault_count'])}; a "
                     "setting is a scenario key, an algorithm option, fault.FIELD, "
                     "fault.SAT.FIELD or fault_count")


def _setting(scenario: Scenario, name: str):
    """The value of setting ``name`` in ``scenario`` (None when it has none)."""
    if name == "fault_count":
        return len(scenario.faults)
    if name == "faults":
        return tuple(f.to_dict() for f in scenario.faults)
    m = _FAULT_PATH.match(name)
    if m:
        faults = [f for f in scenario.faults if m["sat"] in (None, f.sat)]
        return getattr(faults[0], m["field"]) if faults else None
    d = scenario.to_dict()
    if name in d:
        value = d[name]
        return tuple(value) if isinstance(value, list) else value
    return scenario.algorithm_options().get(name)


def _with_setting(scenario: Scenario, name: str, value) -> Scenario:
    """``scenario`` with setting ``name`` set to ``value`` (ValueError if refused)."""
    m = _FAULT_PATH.match(name)
    if m:
        faults = list(scenario.faults)
        for k, f in enumerate(faults):
            if m["sat"] in (None, f.sat):
                faults[k] = dataclasses.replace(f, **{m["field"]: value})
                return scenario.with_faults(*faults)
        raise ValueError(f"setting {name}: the run has no such fault")
    return scenario.replace(**{name: value})


# -- checks ------------------------------------------------------------------------------

@dataclass(frozen=True)
class Check:
    """One node of a lesson's check tree (see the module docstring)."""

    form: str  # "all", "any", "not", "metric", "setting", or a kind of KINDS
    params: dict[str, Any] = field(default_factory=dict)
    children: tuple[Check, ...] = ()


@dataclass(frozen=True)
class Kind:
    """A named test: its parameters (name -> (type, required)) and its evaluation."""

    params: dict[str, tuple[type | tuple[type, ...], bool]]
    evaluate: Callable[[Check, ScenarioResult], tuple[bool, str]]
    help: str


def _kind_detected_every(c: Check, r: ScenarioResult) -> tuple[bool, str]:
    det = r.summary.detection
    if det is None or det.n == 0:
        return False, "no fault acts on a satellite in use, so there is nothing to detect"
    return det.k == det.n, f"detected at {det.k} of {det.n} faulted epochs"


def _kind_no_false_alarms(c: Check, r: ScenarioResult) -> tuple[bool, str]:
    fa = r.summary.false_alarm
    if fa.n == 0:
        return False, "no fault-free epoch to count false alarms on"
    return fa.k == 0, f"{fa.k} false alarm{'' if fa.k == 1 else 's'} in {fa.n} fault-free epochs"


def _kind_fa_consistent(c: Check, r: ScenarioResult) -> tuple[bool, str]:
    fa, p_fa = r.summary.false_alarm, r.p_fa  # ARAIM: its own budget
    if fa.n == 0:
        return False, "no fault-free epoch to count false alarms on"
    lo, hi = fa.ci95
    ok = lo <= p_fa <= hi
    return ok, (f"false alarms {fa.k} of {fa.n} ({100 * fa.value:.1f}%, 95% interval "
                f"{100 * lo:.1f}-{100 * hi:.1f}%) against P_fa = {p_fa:.3g}: "
                + ("consistent" if ok else "P_fa is outside the interval"))


def _kind_first_alarm_within(c: Check, r: ScenarioResult) -> tuple[bool, str]:
    sat, seconds = c.params.get("sat"), float(c.params["seconds"])
    onset = _onset_s(r, sat)
    what = f"the fault on {sat}" if sat else "the fault"
    if onset is None:
        return False, f"the run has no fault{' on ' + sat if sat else ''}"
    naming = sat if c.params.get("naming") else None
    if c.params.get("naming") and sat is None:
        naming = min(_faults(r), key=lambda f: f.t0_s).sat
    t = _first_alarm_after(r, onset, naming)
    named = f" naming {naming}" if naming else ""
    if t is None:
        return False, f"no alarm{named} after {what} starts at t = {_fmt(onset, 's')}"
    delay = t - onset
    return delay <= seconds + 1e-9, (
        f"first alarm{named} at t = {_fmt(t, 's')}, {_fmt(delay, 's')} after {what} starts "
        f"at t = {_fmt(onset, 's')} (asked: within {_fmt(seconds, 's')})")


def _kind_isolated(c: Check, r: ScenarioResult) -> tuple[bool, str]:
    sat, share = c.params["sat"], float(c.params.get("share", 0.9))
    tbl = r.table
    sel = (tbl["faulty_truth"] != "") & tbl["alarm"].astype(bool)
    n = int(sel.sum())
    if n == 0:
        return False, "no alarm while a fault acts, so nothing was isolated"
    k = int((_names_sat(tbl, sat) & sel).sum())
    return k >= share * n - 1e-9, (f"{sat} isolated at {k} of {n} alarmed faulted epochs "
                                   f"({100 * k / n:.0f}%; asked: at least "
                                   f"{100 * share:.0f}%)")


def _kind_extreme(c: Check, r: ScenarioResult) -> tuple[bool, str]:
    """``smallest`` / ``largest``: the inner check passes here and fails one step away."""
    smallest = c.form == "smallest"
    name = c.params["setting"]
    inner = c.children[0]
    ok, msg = evaluate_check(inner, r)
    value = _setting(r.scenario, name)
    if not ok:
        return False, msg
    if not _is_number(value):
        return False, f"{name} is not set to a number in this run"
    if "by" in c.params:
        step = float(c.params["by"])
        other = value - step if smallest else value + step
        step_text = _fmt(step)
    else:
        f = float(c.params["factor"])
        other = value * f
        step_text = f"a factor {f:g}"
    other = float(f"{other:.12g}")  # no round-off tails in what the message shows
    try:
        there = run_scenario(_with_setting(r.scenario, name, other))
    except ValueError as exc:  # the setting cannot go further: this is the extreme
        return True, f"{msg}; and {name} cannot go to {_fmt(other)} ({exc})"
    ok2, msg2 = evaluate_check(inner, there)
    word = "smaller" if smallest else "larger"
    if ok2:
        return False, (f"{msg}; but {name} = {_fmt(other)} works too ({msg2}): try a {word} "
                       f"value")
    return True, (f"{msg}; with {name} = {_fmt(other)} it does not ({msg2}): "
                  f"{_fmt(value)} is the {word[:-1]}st to within {step_text}")


#: The named tests a check may use.
KINDS: dict[str, Kind] = {
    "detected_every_faulted_epoch": Kind({}, _kind_detected_every,
                                         "the fault is detected at every faulted epoch"),
    "no_false_alarms": Kind({}, _kind_no_false_alarms, "no alarm at a fault-free epoch"),
    "false_alarm_rate_consistent": Kind(
        {}, _kind_fa_consistent, "P_fa lies in the 95% interval of the false-alarm rate"),
    "first_alarm_within": Kind(
        {"seconds": ((int, float), True), "sat": (str, False), "naming": (bool, False)},
        _kind_first_alarm_within,
        "the first alarm comes within `seconds` of the fault's start (of the fault on "
        "`sat`; `naming = true`: an alarm that isolates that satellite)"),
    "isolated": Kind({"sat": (str, True), "share": ((int, float), False)}, _kind_isolated,
                     "the isolated satellite is `sat` at a `share` (default 0.9) of the "
                     "alarmed faulted epochs"),
    "smallest": Kind({"setting": (str, True), "by": ((int, float), False),
                      "factor": ((int, float), False), "check": (dict, True)}, _kind_extreme,
                     "`check` holds, and fails with `setting` lowered by `by` (or times "
                     "`factor`)"),
    "largest": Kind({"setting": (str, True), "by": ((int, float), False),
                     "factor": ((int, float), False), "check": (dict, True)}, _kind_extreme,
                    "`check` holds, and fails with `setting` raised by `by` (or times "
                    "`factor`)"),
}


def parse_check(spec, where: str = "check") -> Check:
    """A :class:`Check` from its TOML table; ValueError naming ``where`` and the fault."""
    if not isinstance(spec, dict):
        raise ValueError(f"{where} must be a table such as {{ kind = "
                         f"\"detected_every_faulted_epoch\" }}, got {spec!r}")
    forms = (["kind"] if "kind" in spec else
             [k for k in ("all", "any", "not", "metric", "setting") if k in spec])
    if len(forms) != 1:
        raise ValueError(f"{where} must have exactly one of all, any, not, metric, setting "
                         f"or kind; got {', '.join(spec) or 'an empty table'}")
    form = forms[0]
    if form in ("all", "any"):
        _only(spec, {form}, where)
        items = spec[form]
        if not isinstance(items, list) or not items:
            raise ValueError(f"{where}.{form} must be a non-empty list of checks")
        return Check(form, children=tuple(parse_check(c, f"{where}.{form}[{i}]")
                                          for i, c in enumerate(items)))
    if form == "not":
        _only(spec, {"not"}, where)
        return Check("not", children=(parse_check(spec["not"], f"{where}.not"),))
    if form in ("metric", "setting"):
        _only(spec, {form, "op", "value"}, where)
        for k in ("op", "value"):
            if k not in spec:
                raise ValueError(f"{where}: a {form} check needs {k} (e.g. {{ {form} = "
                                 f"..., op = \">=\", value = 1.0 }})")
        op, value = spec["op"], spec["value"]
        if op not in _OPS:
            raise ValueError(f"{where}: unknown op {op!r}; allowed: {' '.join(_OPS)}")
        name = spec[form]
        if not isinstance(name, str):
            raise ValueError(f"{where}: {form} must be a name, got {name!r}")
        if form == "metric":
            if name not in METRICS:
                raise ValueError(f"{where}: unknown metric {name!r}"
                                 f"{did_you_mean(name, METRICS)}; see app.lessons.METRICS")
            if not _is_number(value):
                raise ValueError(f"{where}: value of metric {name} must be a number, got "
                                 f"{value!r}")
        else:
            _check_setting_name(name, where)
            if not (_is_number(value) or isinstance(value, str | bool)):
                raise ValueError(f"{where}: value of setting {name} must be a number, a "
                                 f"string or a boolean, got {value!r}")
            if isinstance(value, str | bool) and op not in ("==", "!="):
                raise ValueError(f"{where}: op {op!r} compares numbers; use == or != for "
                                 f"{value!r}")
        return Check(form, {"name": name, "op": op, "value": value})
    kind = spec["kind"]
    if kind not in KINDS:
        raise ValueError(f"{where}: unknown kind {kind!r}{did_you_mean(str(kind), KINDS)}; "
                         f"allowed: {', '.join(KINDS)}")
    decl = KINDS[kind]
    _only(spec, {"kind", *decl.params}, where)
    params = {}
    for name, (typ, required) in decl.params.items():
        if name not in spec:
            if required:
                raise ValueError(f"{where}: kind {kind} needs {name}")
            continue
        value = spec[name]
        if not isinstance(value, typ) or (typ is not bool and isinstance(value, bool)):
            raise ValueError(f"{where}: {name} of kind {kind} has the wrong type: {value!r}")
        params[name] = value
    children: tuple[Check, ...] = ()
    if kind in ("smallest", "largest"):
        _check_setting_name(params["setting"], where)
        if ("by" in params) == ("factor" in params):
            raise ValueError(f"{where}: kind {kind} needs exactly one of by (a step) or "
                             "factor (a ratio)")
        if "by" in params and not params["by"] > 0:
            raise ValueError(f"{where}: by must be > 0, got {params['by']!r}")
        if "factor" in params:
            f = params["factor"]
            good = 0 < f < 1 if kind == "smallest" else f > 1
            if not good:
                raise ValueError(f"{where}: factor of {kind} must be "
                                 + ("in (0, 1)" if kind == "smallest" else "> 1")
                                 + f", got {f!r}")
        children = (parse_check(params.pop("check"), f"{where}.check"),)
    if kind == "first_alarm_within" and params["seconds"] < 0:
        raise ValueError(f"{where}: seconds must be >= 0, got {params['seconds']!r}")
    if kind == "isolated" and not 0 < params.get("share", 0.9) <= 1:
        raise ValueError(f"{where}: share must be in (0, 1], got {params['share']!r}")
    return Check(kind, params, children)


def _only(spec: dict, allowed: set[str], where: str) -> None:
    extra = [k for k in spec if k not in allowed]
    if extra:
        raise ValueError(f"{where}: unexpected key(s) {', '.join(extra)}; allowed here: "
                         f"{', '.join(sorted(allowed))}")


def evaluate_check(check: Check, result: ScenarioResult) -> tuple[bool, str]:
    """Evaluate ``check`` on a run: ``(passed, message)``, the message saying what was
    measured (several parts joined by "; ")."""
    form = check.form
    if form in ("all", "any"):
        parts = [evaluate_check(c, result) for c in check.children]
        ok = all(p for p, _ in parts) if form == "all" else any(p for p, _ in parts)
        if form == "all" and len(parts) > 1:
            text = "; ".join(f"{'✔' if p else '✘'} {m}" for p, m in parts)
        else:
            text = "; ".join(m for _, m in parts)
        return ok, text
    if form == "not":
        ok, msg = evaluate_check(check.children[0], result)
        return not ok, f"not ({msg})"
    if form == "metric":
        metric = METRICS[check.params["name"]]
        raw = metric.read(result)
        op, want = check.params["op"], check.params["value"]
        if isinstance(raw, Rate):
            value, shown = (raw.value if raw.n else None), _fmt(raw)
        else:
            value, shown = raw, _fmt(raw, metric.unit)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            needs = f" (it needs {metric.needs})" if metric.needs else ""
            return False, f"{metric.label}: not available in this run{needs}"
        ok = bool(_OPS[op](value, want))
        return ok, (f"{metric.label} {shown} (asked: {_OP_TEXT[op]} "
                    f"{_fmt(want, metric.unit)})")
    if form == "setting":
        name, op, want = check.params["name"], check.params["op"], check.params["value"]
        value = _setting(result.scenario, name)
        if value is None:
            return False, f"{name}: not set in this run"
        try:
            ok = bool(_OPS[op](value, want))
        except TypeError:
            ok = False
        return ok, f"{name} = {_fmt(value)} (asked: {_OP_TEXT[op]} {_fmt(want)})"
    return KINDS[form].evaluate(check, result)


# -- lessons -----------------------------------------------------------------------------

_TOP_KEYS = {"title", "order", "steps", "scenario", "question", "test", "summary"}
_QUESTION_KEYS = {"text", "check", "keep", "success", "hint"}
_TEST_KEYS = {"pass", "fail"}


@dataclass(frozen=True)
class Lesson:
    """One lesson (see the module docstring). Build with :func:`load_lesson`."""

    path: Path
    id: str
    title: str
    order: float
    body: str
    steps: tuple[str, ...]
    question: str
    check: Check
    keep: tuple[str, ...] = ()
    success: str = ""
    hint: str = ""
    summary: str = ""
    scenario_spec: dict = field(default_factory=dict, compare=False)
    test_pass: tuple[dict, ...] = ()
    test_fail: tuple[dict, ...] = ()

    # -- the scenario ----------------------------------------------------------------
    @property
    def scenario_name(self) -> str:
        return f"{SCENARIO_PREFIX}{self.id}"

    def required_files(self) -> tuple[Path, ...]:
        """Files the lesson's scenario needs (a recording's), resolved."""
        rec = self.scenario_spec.get("recording")
        if not rec:
            return ()
        return tuple(_resolve(self.path, rec[k]) for k in ("obs", "nav"))

    def missing_files(self) -> tuple[Path, ...]:
        return tuple(p for p in self.required_files() if not p.is_file())

    @property
    def available(self) -> bool:
        return not self.missing_files()

    def unavailable_reason(self) -> str:
        """One line saying which files are absent ("" when the lesson can be set up)."""
        missing = self.missing_files()
        if not missing:
            return ""
        return (f"This lesson needs the recording {', '.join(p.name for p in missing)}, "
                f"which is not on this machine (looked for "
                f"{', '.join(str(p) for p in missing)}).")

    def scenario(self, **overrides) -> Scenario:
        """The lesson's scenario (with ``overrides``, scenario keys).

        Raises
        ------
        LessonUnavailable when a recording it needs is absent; LessonError (naming the
        file) when the scenario is refused.
        """
        if not self.available:
            raise LessonUnavailable(f"{self.path}: {self.unavailable_reason()}")
        spec = dict(self.scenario_spec)
        rec, base = spec.pop("recording", None), spec.pop("base", None)
        spec.setdefault("name", self.scenario_name)
        spec.update(overrides)
        try:
            if rec:
                obs, nav = self.required_files()
                return recording_scenario(obs, nav, **spec)
            if base is not None:
                return load_scenario(_resolve_base(self.path, base), **spec)
            return from_dict(spec)
        except ValueError as exc:
            raise LessonError(f"{self.path}: scenario: {_one_line(exc)}") from None

    # -- the answer ------------------------------------------------------------------
    def evaluate(self, result: ScenarioResult) -> tuple[bool, str]:
        """Is the question answered by this run? ``(passed, message)``."""
        s = result.scenario
        if s.name != self.scenario_name:
            return False, (f"The dashboard shows the scenario {s.name!r}, not this "
                           f"lesson's: press Set up first.")
        setup = self.scenario()
        changed = [k for k in self.keep if not _same_setting(_setting(setup, k),
                                                             _setting(s, k))]
        if changed:
            what = "; ".join(f"{k}: the lesson sets {_fmt_setting(_setting(setup, k))}, "
                             f"your run has {_fmt_setting(_setting(s, k))}" for k in changed)
            return False, (f"Not yet: keep {', '.join(changed)} as the lesson set "
                           f"{'it' if len(changed) == 1 else 'them'} ({what}).")
        ok, msg = evaluate_check(self.check, result)
        if ok:
            return True, " ".join(x for x in ("Yes!", self.success.strip(),
                                              f"Measured: {msg}.") if x)
        return False, " ".join(x for x in ("Not yet.", f"Measured: {msg}.",
                                           self.hint.strip()) if x)

    def markdown(self) -> str:
        """The lesson as the Lessons tab shows it: title, text, steps and question."""
        steps = "\n".join(f"{k}. {s}" for k, s in enumerate(self.steps, 1))
        parts = [f"### {self.title}", self.body.strip(), f"**Try this**\n\n{steps}",
                 f"**Question.** {self.question.strip()}"]
        if not self.available:
            parts.insert(1, f"**Not available here.** {self.unavailable_reason()}")
        return "\n\n".join(p for p in parts if p)


def _same_setting(a, b) -> bool:
    if _is_number(a) and _is_number(b):
        return _same(a, b)
    return a == b


def _fmt_setting(v) -> str:
    if isinstance(v, tuple) and v and isinstance(v[0], dict):
        return "; ".join(", ".join(f"{k} {_fmt(x)}" for k, x in d.items()) for d in v)
    return _fmt(v)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _resolve(lesson_path: Path, p) -> Path:
    q = Path(str(p)).expanduser()
    return q if q.is_absolute() else (lesson_path.parent / q).resolve()


def _resolve_base(lesson_path: Path, base: str) -> str:
    """A built-in scenario name stays a name; a path is taken relative to the lesson."""
    if base.endswith(".toml") or "/" in base:
        return str(_resolve(lesson_path, base))
    return base


def _split_front_matter(path: Path, text: str) -> tuple[str, str]:
    """``(toml, body)`` of a lesson file (its front matter, or the TOML beside it)."""
    beside = path.with_suffix(".toml")
    lines = text.splitlines(keepends=True)
    has_fm = bool(lines) and lines[0].strip() == FRONT_MATTER_FENCE
    if has_fm:
        if beside.is_file():
            raise ValueError(f"has both front matter and {beside.name} beside it; keep one")
        for k in range(1, len(lines)):
            if lines[k].strip() == FRONT_MATTER_FENCE:
                return "".join(lines[1:k]), "".join(lines[k + 1:])
        raise ValueError(f"front matter opened with {FRONT_MATTER_FENCE} on line 1 is never "
                         f"closed (a line {FRONT_MATTER_FENCE} must end it)")
    if beside.is_file():
        try:
            return beside.read_text(encoding="utf-8"), text
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{beside.name} cannot be read: {exc}") from None
    raise ValueError(f"no front matter (TOML between {FRONT_MATTER_FENCE} lines at the top) "
                     f"and no {beside.name} beside it")


def load_lesson(path) -> Lesson:
    """Read and check one lesson file.

    Raises
    ------
    LessonError
        One line naming the file and what is wrong: unreadable, no front matter, TOML
        syntax, a missing or unknown key, 2-4 steps, a scenario the schema refuses, an
        unknown metric, kind, op or setting in the check, test overrides that do not apply.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
        meta_text, body = _split_front_matter(path, text)
        try:
            meta = tomllib.loads(meta_text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"front matter is not valid TOML: {exc}") from None
        return _lesson_from(path, meta, body)
    except LessonError:
        raise
    except (OSError, UnicodeDecodeError) as exc:
        raise LessonError(f"{path}: cannot be read: {_one_line(exc)}") from None
    except ValueError as exc:
        raise LessonError(f"{path}: {_one_line(exc)}") from None


def _need(d: dict, key: str, typ, where: str):
    if key not in d:
        raise ValueError(f"missing {where}{key}")
    value = d[key]
    if not isinstance(value, typ) or isinstance(value, bool) and typ is not bool:
        raise ValueError(f"{where}{key} has the wrong type: {value!r}"[:200])
    return value


def _lesson_from(path: Path, meta: dict, body: str) -> Lesson:
    extra = [k for k in meta if k not in _TOP_KEYS]
    if extra:
        raise ValueError(f"unknown key {extra[0]!r}{did_you_mean(extra[0], _TOP_KEYS)}; "
                         f"allowed: {', '.join(sorted(_TOP_KEYS))}")
    title = _need(meta, "title", str, "").strip()
    if not title:
        raise ValueError("title is empty")
    order = meta.get("order", math.inf)
    if not _is_number(order):
        raise ValueError(f"order must be a number, got {order!r}")
    steps = _need(meta, "steps", list, "")
    if not STEPS_MIN <= len(steps) <= STEPS_MAX or not all(
            isinstance(s, str) and s.strip() for s in steps):
        raise ValueError(f"steps must be {STEPS_MIN} to {STEPS_MAX} non-empty strings, got "
                         f"{len(steps)}")
    q = _need(meta, "question", dict, "")
    extra = [k for k in q if k not in _QUESTION_KEYS]
    if extra:
        raise ValueError(f"unknown key question.{extra[0]}"
                         f"{did_you_mean(extra[0], _QUESTION_KEYS)}; allowed: "
                         f"{', '.join(sorted(_QUESTION_KEYS))}")
    text = _need(q, "text", str, "question.")
    check = parse_check(_need(q, "check", dict, "question."), "question.check")
    keep = q.get("keep", [])
    if not isinstance(keep, list) or not all(isinstance(k, str) for k in keep):
        raise ValueError(f"question.keep must be a list of setting names, got {keep!r}")
    for k in keep:
        _check_setting_name(k, "question.keep")
    for k in ("success", "hint"):
        if not isinstance(q.get(k, ""), str):
            raise ValueError(f"question.{k} must be a string")
    spec = _need(meta, "scenario", dict, "")
    if "recording" in spec:
        rec = spec["recording"]
        if "base" in spec:
            raise ValueError("scenario has both base and recording; give one")
        if not (isinstance(rec, dict) and set(rec) == {"obs", "nav"}
                and all(isinstance(v, str) and v for v in rec.values())):
            raise ValueError("scenario.recording must be { obs = \"FILE\", nav = \"FILE\" }")
    if "base" in spec and not isinstance(spec["base"], str):
        raise ValueError(f"scenario.base must be a scenario name or a .toml path, got "
                         f"{spec['base']!r}")
    tests = meta.get("test", {})
    if not isinstance(tests, dict):
        raise ValueError("test must be a table with pass and fail override sets")
    extra = [k for k in tests if k not in _TEST_KEYS]
    if extra:
        raise ValueError(f"unknown key test.{extra[0]}; allowed: pass, fail")
    test_pass = _override_sets(tests.get("pass", []), "test.pass")
    test_fail = _override_sets(tests.get("fail", []), "test.fail")
    summary = meta.get("summary", "")
    if not isinstance(summary, str):
        raise ValueError("summary must be a string")
    lesson = Lesson(path=path, id=path.stem, title=title, order=float(order), body=body,
                    steps=tuple(s.strip() for s in steps), question=text, check=check,
                    keep=tuple(keep), success=q.get("success", ""), hint=q.get("hint", ""),
                    summary=summary, scenario_spec=dict(spec), test_pass=test_pass,
                    test_fail=test_fail)
    if lesson.available:  # build it now, so that a bad key is reported on loading
        setup = lesson.scenario()
        for where, sets in (("test.pass", test_pass), ("test.fail", test_fail)):
            for k, o in enumerate(sets):
                try:
                    setup.replace(**o)
                except ValueError as exc:
                    raise ValueError(f"{where}[{k}]: {_one_line(exc)}") from None
    else:
        _check_keys(spec, "scenario")
    return lesson


def _override_sets(value, where: str) -> tuple[dict, ...]:
    sets = [value] if isinstance(value, dict) else value
    if not isinstance(sets, list) or not all(isinstance(s, dict) for s in sets):
        raise ValueError(f"{where} must be a table of scenario keys or a list of them")
    for s in sets:
        _check_keys(s, where)
    return tuple(dict(s) for s in sets)


def _check_keys(d: dict, where: str) -> None:
    """Keys of a scenario table (without building it): scenario keys or options."""
    known = all_keys()
    for k in d:
        if k not in known and not (where == "scenario" and k in ("base", "recording")):
            raise ValueError(f"{where}: unknown scenario key {k!r}{did_you_mean(k, known)}")


def _lesson_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("*.md") if p.is_file()
                  and not p.name.lower().startswith("readme"))


def scan_lessons(dirs: Iterable = (), *, builtin: bool = True
                 ) -> tuple[list[Lesson], list[str]]:
    """Every lesson that loads, and one line per file that does not.

    Built-in lessons come first, then each folder of ``dirs`` in order; within a folder,
    by ``order`` then file name. A folder that does not exist is an error line too.
    """
    folders = ([BUILTIN_DIR] if builtin else []) + [Path(d) for d in dirs]
    lessons: list[Lesson] = []
    errors: list[str] = []
    seen: dict[str, Path] = {}
    for folder in folders:
        if not folder.is_dir():
            errors.append(f"{folder}: lessons folder does not exist")
            continue
        found = []
        for p in _lesson_files(folder):
            try:
                found.append(load_lesson(p))
            except LessonError as exc:
                errors.append(str(exc))
        for lesson in sorted(found, key=lambda x: (x.order, x.path.name)):
            key = lesson.title.casefold()
            if key in seen:
                errors.append(f"{lesson.path}: title {lesson.title!r} is already used by "
                              f"{seen[key]}")
                continue
            seen[key] = lesson.path
            lessons.append(lesson)
    return lessons, errors


def load_lessons(dirs: Iterable = (), *, builtin: bool = True) -> list[Lesson]:
    """The built-in lessons and those in the folders ``dirs`` (a teacher's).

    Raises
    ------
    LessonError for the first file that cannot be used (one line naming it), or a folder
    that does not exist.
    """
    lessons, errors = scan_lessons(dirs, builtin=builtin)
    if errors:
        more = f" (and {len(errors) - 1} more)" if len(errors) > 1 else ""
        raise LessonError(errors[0] + more)
    return lessons


def check_lesson_dirs(dirs: Sequence) -> None:
    """For ``raim dashboard --lessons DIR``: refuse, in one line, a folder that does not
    exist, has no lesson, or holds a lesson that cannot be used."""
    for d in dirs:
        if not Path(d).is_dir():
            raise LessonError(f"--lessons {d}: not a folder")
        if not _lesson_files(Path(d)):
            raise LessonError(f"--lessons {d}: no lesson (*.md) in this folder")
    load_lessons(dirs)


# -- the Lessons tab ---------------------------------------------------------------------

def _label(k: int, lesson: Lesson) -> str:
    return f"{k}. {lesson.title}"


class LessonsTab:
    """The Lessons tab of one session: a lesson picker, its text, "Set up" and "Check my
    answer". Build with :func:`add_lessons_tab`.

    ``session`` needs ``open_scenario(scenario)``, ``result`` (the last
    :class:`ScenarioResult` or None) and ``scenario`` (the scenario the controls show);
    a ``scheduler`` with ``wait_idle(timeout)`` is waited for before checking.
    """

    def __init__(self, session, gui, lessons: list[Lesson], errors: list[str]):
        self.session = session
        self.lessons = list(lessons)
        self.labels = [_label(k, x) for k, x in enumerate(self.lessons, 1)]
        self._by_label = dict(zip(self.labels, self.lessons, strict=True))
        if not self.lessons:
            self.labels = ["(no lessons)"]
        self.pick = gui.add_dropdown("Lesson", self.labels, initial_value=self.labels[0],
                                     hint="choose a lesson; Set up opens its scenario")
        self.text_md = gui.add_markdown("")
        self.setup_button = gui.add_button("Set up", hint="open this lesson's scenario in "
                                           "the dashboard (replaces the current one)")
        self.check_button = gui.add_button("Check my answer", hint="read the current run "
                                           "and say whether it answers the question")
        self.answer_md = gui.add_markdown("")
        self.errors_md = gui.add_markdown(_errors_markdown(errors), visible=bool(errors))
        self.pick.on_update(lambda _e: self.show())
        self.setup_button.on_click(lambda _e: self.set_up())
        self.check_button.on_click(lambda _e: self.check())
        self.show()

    @property
    def lesson(self) -> Lesson | None:
        return self._by_label.get(self.pick.value)

    def show(self) -> None:
        """Show the picked lesson (and forget the last answer)."""
        lesson = self.lesson
        self.text_md.content = (lesson.markdown() if lesson is not None else
                                "No lesson could be loaded.")
        ready = lesson is not None and lesson.available
        self.setup_button.disabled = not ready
        self.check_button.disabled = not ready
        self.answer_md.content = ""

    def set_up(self) -> bool:
        """Open the picked lesson's scenario in the session; False (and a line saying why)
        when it cannot be set up."""
        lesson = self.lesson
        if lesson is None:
            return False
        try:
            scenario = lesson.scenario()
        except LessonError as exc:
            self.answer_md.content = f"**Cannot set up.** {html.escape(_one_line(exc))}"
            return False
        self.session.open_scenario(scenario)
        self.answer_md.content = ("*Set up.* Follow the steps, then press **Check my "
                                  "answer**.")
        return True

    def check(self) -> tuple[bool, str]:
        """Evaluate the picked lesson's question on the session's current run; the answer
        is shown under the buttons and returned."""
        lesson = self.lesson
        if lesson is None:
            return False, "No lesson."
        ok, msg = self._evaluate(lesson)
        mark = "✔" if ok else "✘"  # in every font (emoji fonts are often absent)
        self.answer_md.content = f"{mark} {html.escape(msg)}"
        return ok, msg

    def _evaluate(self, lesson: Lesson) -> tuple[bool, str]:
        sched = getattr(self.session, "scheduler", None)
        if sched is not None and not sched.wait_idle(CHECK_WAIT_S):
            return False, "The dashboard is still computing: press Check again in a moment."
        result = getattr(self.session, "result", None)
        if result is None:
            return False, "There is no run yet: press Set up, then try the steps."
        current = getattr(self.session, "scenario", None)
        if current is not None and current != result.scenario:
            return False, ("The run on screen is not the current settings' (the last "
                           "change is still running or was refused, see the status line): "
                           "press Check again in a moment.")
        try:
            return lesson.evaluate(result)
        except LessonError as exc:
            return False, _one_line(exc)


def _errors_markdown(errors: list[str]) -> str:
    if not errors:
        return ""
    lines = "\n".join(f"- {html.escape(e)}" for e in errors)
    return f"**Lessons that could not be loaded**\n\n{lines}"


def add_lessons_tab(session, gui, dirs: Iterable = (), *,
                    lessons: list[Lesson] | None = None) -> LessonsTab:
    """Build the Lessons tab's controls in ``gui``'s current container.

    Parameters
    ----------
    session : the dashboard session (:class:`app.session.Session` or any object with
        ``open_scenario``, ``result`` and ``scenario``).
    gui : viser GUI API (``client.gui``).
    dirs : teachers' lesson folders (``raim dashboard --lessons DIR``), read now: a file
        dropped in one shows up in the next browser tab. Files that do not load are listed
        at the bottom of the tab, one line each.
    lessons : the lessons to offer instead of reading the folders (tests).
    """
    if lessons is None:
        lessons, errors = scan_lessons(dirs)
        for e in errors:
            log.warning("lesson not loaded: %s", e)
    else:
        errors = []
    return LessonsTab(session, gui, lessons, errors)
