"""The staged pipeline: one scenario in, one per-epoch result table and summary out.

1. sky source (:func:`raimcore.sky.build_sky`): where the satellites and the receiver are;
2. measure (:func:`raimcore.measure.measure`): :class:`~raimcore.measure.Measurements`
   (what a receiver has) and :class:`~raimcore.measure.Truth`;
3. algorithm (:mod:`raimcore.algorithms`): sees the measurements only;
4. scoring (:mod:`raimcore.scoring`): the :class:`~raimcore.scoring.table.ResultTable` and
   a frozen :class:`~raimcore.scoring.Summary`.

The scenario is validated when it is built (:class:`~raimcore.scenario.Scenario`), and the
algorithm's options before the sky is computed, so a bad value never costs a simulation.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from . import algorithms
from .algorithms.base import STATUS_UNAVAILABLE, AlgorithmOutput
from .measure import measure
from .measure.data import Measurements, Truth
from .scenario import SCENARIO_KEYS, Scenario, load_scenario
from .schema import SchemaError, did_you_mean
from .scoring import Summary, make_table, summarize
from .scoring.table import ResultTable
from .sky import build_sky

__all__ = ["ScenarioResult", "run_scenario", "compare_algorithms", "run_algorithm",
           "simulate", "unavailable_output", "check_output"]


@dataclass(frozen=True)
class ScenarioResult:
    """A scenario, its measurements and truth, the algorithm's output, the result table
    and the summary."""

    scenario: Scenario
    measurements: Measurements
    truth: Truth
    output: AlgorithmOutput
    table: ResultTable
    summary: Summary

    @property
    def p_fa(self) -> float:
        """The false-alarm probability per epoch the run was tested at: the summary's (an
        algorithm's own where it has one, as ARAIM's budgets), else the scenario's."""
        return self.scenario.p_fa if self.summary.p_fa is None else self.summary.p_fa


def simulate(s: Scenario) -> tuple[Measurements, Truth]:
    """Stages 1 and 2: the measurements and the truth of scenario ``s``."""
    return measure(build_sky(s), s)


def run_algorithm(spec, data: Measurements, options: dict[str, Any]) -> AlgorithmOutput:
    """Run ``spec`` on the satellites used at least once, then map back to all of them.

    Satellites never above the mask cannot matter to any algorithm; dropping them first
    makes every per-satellite array (and the S x S projectors) several times smaller. The
    output is checked (shapes) and unavailable epochs are made NaN: an algorithm cannot
    report a position, a statistic or an alarm where it says it has none.
    """
    options = spec.resolve_options(options)
    cols = np.flatnonzero(data.used.any(axis=0))
    if cols.size == 0:  # no satellite ever used: nothing to run, every epoch unavailable
        return unavailable_output(data)
    small = data.take_sats(cols)
    out = spec.run(small, options)
    check_output(spec.name, small, out)
    return _blank_unavailable(out.expand_sats(cols, data.n_sats))


def _blank_unavailable(out: AlgorithmOutput) -> AlgorithmOutput:
    bad = np.asarray(out.status, dtype=object) == STATUS_UNAVAILABLE
    if not bad.any():
        return out
    nan_rows = bad[:, None]
    return dataclasses.replace(
        out, statistic=np.where(bad, np.nan, np.asarray(out.statistic, dtype=float)),
        threshold=np.where(bad, np.nan, np.asarray(out.threshold, dtype=float)),
        alarm=np.asarray(out.alarm, dtype=bool) & ~bad,
        pos_before_ecef_m=np.where(nan_rows, np.nan, out.pos_before_ecef_m),
        pos_after_ecef_m=np.where(nan_rows, np.nan, out.pos_after_ecef_m),
        excluded=np.asarray(out.excluded, dtype=bool) & ~nan_rows,
        isolated=np.where(bad, -1, np.asarray(out.isolated)))


def unavailable_output(data: Measurements) -> AlgorithmOutput:
    """An output with every epoch "unavailable" (NaN statistics and positions)."""
    e, s = data.n_epochs, data.n_sats
    nan = np.full(e, np.nan)
    return AlgorithmOutput(
        status=np.full(e, STATUS_UNAVAILABLE, dtype=object), statistic=nan, threshold=nan,
        alarm=np.zeros(e, dtype=bool), pos_before_ecef_m=np.full((e, 3), np.nan),
        pos_after_ecef_m=np.full((e, 3), np.nan), excluded=np.zeros((e, s), dtype=bool),
        isolated=np.full(e, -1, dtype=int))


def check_output(name: str, data: Measurements, out: AlgorithmOutput) -> None:
    """Check that algorithm ``name`` kept the output contract (shapes), or raise."""
    e, s = data.n_epochs, data.n_sats
    want = {"status": (e,), "statistic": (e,), "threshold": (e,), "alarm": (e,),
            "pos_before_ecef_m": (e, 3), "pos_after_ecef_m": (e, 3), "excluded": (e, s),
            "isolated": (e,)}
    for key, shape in want.items():
        got = np.shape(getattr(out, key))
        if got != shape:
            raise RuntimeError(f"algorithm {name!r} returned {key} with shape {got}, "
                               f"expected {shape}")
    for group, shape in (("columns", (e,)), ("per_sat", (e, s))):
        for key, val in getattr(out, group).items():
            if np.shape(val) != shape:
                raise RuntimeError(f"algorithm {name!r} returned {group}[{key!r}] with shape "
                                   f"{np.shape(val)}, expected {shape}")


def _score(s: Scenario, data: Measurements, truth: Truth, out: AlgorithmOutput
           ) -> ScenarioResult:
    table = make_table(data, truth, out)
    notes = s.notes + data.notes
    if out.p_fa is not None and out.p_fa != s.p_fa:
        notes += (f"p_fa {s.p_fa:g} has no effect on {s.algorithm}: its tests are built "
                  f"for a false-alarm probability of {out.p_fa:.3g} per epoch, which the "
                  "summary uses",)
    return ScenarioResult(s, data, truth, out, table, summarize(table, notes=notes))


def _as_scenario(s, overrides) -> Scenario:
    if isinstance(s, str | Path):
        return load_scenario(s, **overrides)
    if not isinstance(s, Scenario):
        raise SchemaError(f"expected a Scenario, a built-in scenario name or a .toml path, "
                          f"got {type(s).__name__}")
    return s.replace(**overrides) if overrides else s


def run_scenario(s: Scenario | str, **overrides) -> ScenarioResult:
    """Run one scenario (an object, a built-in name or a TOML path) end to end."""
    s = _as_scenario(s, overrides)
    spec = algorithms.get(s.algorithm)
    options = s.algorithm_options()
    data, truth = simulate(s)
    return _score(s, data, truth, run_algorithm(spec, data, options))


def compare_algorithms(s: Scenario | str, names: list[str] | None = None,
                       **overrides) -> list[ScenarioResult]:
    """Run several algorithms on the same measurements (one noise draw, the same faults).

    Parameters
    ----------
    s : a scenario object, a built-in name or a TOML path.
    names : algorithm names (default: every registered algorithm).
    overrides : scenario keys, or options of at least one of the algorithms (each algorithm
        gets the options it takes).

    Returns
    -------
    One :class:`ScenarioResult` per algorithm, in the order of ``names``. An algorithm
    that cannot run on these measurements reports "unavailable" epochs, as in a single run.

    Raises
    ------
    ValueError
        An unknown algorithm name (the message lists the registered ones), or an option
        that none of the algorithms takes.
    """
    if isinstance(names, str):
        raise SchemaError(f"names must be a list of algorithm names, got the string {names!r}"
                          f" (write [{names!r}])")
    names = list(algorithms.names() if names is None else names)
    if not names:
        raise SchemaError("names must list at least one algorithm")
    specs = [algorithms.get(n) for n in names]  # unknown names fail before any work
    base = s if isinstance(s, Scenario) else None
    if base is None:
        base = load_scenario(s)
    keys = {k: v for k, v in overrides.items() if k in SCENARIO_KEYS}
    opts = {**dict(base.options), **{k: v for k, v in overrides.items()
                                       if k not in SCENARIO_KEYS}}
    takers = {k: [sp.name for sp in specs if k in sp.option_keys] for k in opts}
    for k, who in takers.items():
        if not who:
            raise SchemaError(f"option {k!r} belongs to none of {', '.join(names)}"
                              f"{did_you_mean(k, [o for sp in specs for o in sp.option_keys])}")
    base = dataclasses.replace(base, options=()).replace(**keys)
    per_alg = []
    for spec in specs:  # every scenario and option checked before any simulation
        mine = {k: v for k, v in opts.items() if k in spec.option_keys}
        sa = dataclasses.replace(base, algorithm=spec.name, options=tuple(mine.items()))
        per_alg.append((spec, sa, sa.algorithm_options()))
    data, truth = simulate(base)  # the measurements are drawn once, shared by all
    return [_score(sa, data, truth, run_algorithm(spec, data, options))
            for spec, sa, options in per_alg]
