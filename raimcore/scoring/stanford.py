"""The Stanford-ESA integrity diagram: position error against protection level.

Every epoch of a run with protection levels is one point: position error PE on the x axis,
protection level PL on the y axis (gLAB's axes), horizontal (HPE vs HPL, alert limit HAL)
and vertical (|VPE| vs VPL, VAL) apart. The diagram is a 2-D histogram of the points
(square bins, 0.1 m by default, as gLAB's ``-filter:stfdesa`` file) and a count of the
epochs in each integrity region.

Regions, as gLAB draws them (``graph.py`` v5.2, class ``stanford``, ``getPoints`` and
``plotPatch``; gAGE/UPC & ESA 2018). With AL the alert limit, every epoch is in exactly one
of

=============  =========================================  ====================================
region         condition                                  gLAB's label
=============  =========================================  ====================================
nominal        PE < PL and PL < AL                        "Normal Operation"
mi             PE >= PL and PE < AL                       "MI" (below the alert limit)
hmi            PE >= PL, PE >= AL and PL < AL             "HMI"
unavailable    PL >= AL, or no PL or no position (NaN)    "System Unavailable / Alarm Epochs"
=============  =========================================  ====================================

so ``nominal + mi + hmi + unavailable == epochs``. An unavailable epoch whose error still
reaches its protection level (gLAB's "MI" triangle above the alert limit) is counted in
``unavailable_mi`` too, a part of ``unavailable``; one without a PL or a position (NaN: too
few satellites, a singular geometry) in ``no_solution``. gLAB writes ``x / y >= 1`` for
"error reaches the protection level" and ``y >= AL`` for "unavailable": an error equal to
its PL is misleading, a PL equal to the alert limit unavailable (note: the algorithms'
``available`` column counts ``PL <= AL`` as available; the two differ only on equality).
gLAB classifies its bin centres; here each epoch's exact values are classified, and the
histogram is the picture.

The regions do not look at the integrity monitor's alarms (gLAB's diagram does not: an SBAS
alarm shows as a PL above the alert limit). A RAIM detector may alarm at an epoch whose
full-set error exceeds its PL, warning the user; given the per-epoch alarms, the result
keeps how many MI and HMI epochs had one (``mi_alarmed``, ``hmi_alarmed``), so the reader
sees both gLAB's count and how much of it the detector flagged.

The histogram is kept sparse (the occupied bins and their counts, memory O(epochs)), so a
0.1 m bin over a kilometre of PL costs nothing; :meth:`StanfordResult.dense` gives the
counts as an array, summed over blocks of bins when asked. Its range starts at 0 and ends
past the largest finite PE or PL (``max_m=None``) or at ``max_m``; values beyond ``max_m``
go to the last bin (an error beyond the range whose PL is larger goes one bin lower, as
gLAB does, so that it does not land on the diagonal), and are counted in ``clipped``. An
epoch enters the histogram when its PE and PL are both finite.

References
----------
M. Tossaint, J. Samson, F. Toran, J. Ventura-Traveset, M. Hernandez-Pajares, J. M. Juan,
J. Sanz, P. Ramos-Bosch, "The Stanford-ESA Integrity Diagram: A New Tool for the User
Domain SBAS Integrity Assessment", NAVIGATION 54(2), 2007.
gLAB (gAGE/UPC & ESA), ``graph.py`` v5.2 (2018/03/09), classes ``stanford`` and
``stanfordESA``: the region rules above and the 0.1 m default pixel.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._validate import check_positive

__all__ = ["REGIONS", "StanfordResult", "StanfordDiagram", "stanford_esa",
           "stanford_from_table", "stanford_from_result", "stanford_from_csv",
           "pl_columns", "DEFAULT_BIN_M", "REGION_NAMES", "pct"]

#: The partition of the epochs, in the order the figures list it.
REGIONS = ("nominal", "mi", "hmi", "unavailable")
#: gLAB's Stanford-ESA pixel (graph.py v5.2, ``stanfordESA.resolution_x``).
DEFAULT_BIN_M = 0.1
#: The PE columns of a result table: the full-set solution the protection levels are
#: computed for ("before" exclusion) or the solution after exclusion.
ERRORS = ("before", "after")


@dataclass(frozen=True, eq=False)
class StanfordResult:
    """One Stanford-ESA diagram (horizontal or vertical): region counts and histogram.

    Attributes
    ----------
    label : ``"horizontal"``, ``"vertical"`` or what the caller named it.
    al_m : alert limit (m).
    epochs : all epochs (the denominator of every share).
    nominal, mi, hmi, unavailable : epochs in each region (module docstring); they add up
        to ``epochs``.
    unavailable_mi : unavailable epochs with PE >= PL (part of ``unavailable``).
    no_solution : epochs without a finite PE or PL (part of ``unavailable``).
    mi_alarmed, hmi_alarmed : MI and HMI epochs at which the monitor alarmed (part of
        ``mi`` and ``hmi``), or None when no alarms were given.
    bin_m : histogram bin (m), the same on both axes.
    n_bins : bins per axis; the edges are ``edges_m = arange(n_bins + 1) * bin_m``.
    hist_pe_bin, hist_pl_bin, hist_count : (K,) the occupied bins (PE index, PL index) and
        their counts, sorted by PE then PL index; ``hist_count.sum()`` is the number of
        epochs with a finite PE and PL.
    clipped : epochs whose PE or PL lies beyond the histogram's range (drawn in the last
        bin).
    status : ``"ok"``, or ``"empty"`` when no epoch has a finite PE and PL.
    """

    label: str
    al_m: float
    epochs: int
    nominal: int
    mi: int
    hmi: int
    unavailable: int
    unavailable_mi: int
    no_solution: int
    bin_m: float
    n_bins: int
    hist_pe_bin: np.ndarray
    hist_pl_bin: np.ndarray
    hist_count: np.ndarray
    clipped: int
    status: str
    mi_alarmed: int | None = None
    hmi_alarmed: int | None = None

    @property
    def edges_m(self) -> np.ndarray:
        """(n_bins + 1,) bin edges (m), both axes."""
        return np.arange(self.n_bins + 1) * self.bin_m

    @property
    def range_m(self) -> float:
        """The histogram's upper edge (m)."""
        return self.n_bins * self.bin_m

    @property
    def counts(self) -> dict[str, int]:
        """Epochs per region, in :data:`REGIONS` order."""
        return {r: getattr(self, r) for r in REGIONS}

    @property
    def shares(self) -> dict[str, float]:
        """Share of the epochs per region (NaN without epochs)."""
        n = self.epochs
        return {r: (k / n if n else math.nan) for r, k in self.counts.items()}

    def rate(self, region: str):
        """A region's epochs as a :class:`~raimcore.scoring.Rate` (counts and 95% interval)
        over all epochs; ``region`` is one of :data:`REGIONS` or ``"unavailable_mi"``."""
        from . import Rate

        if region not in (*REGIONS, "unavailable_mi", "no_solution"):
            raise ValueError(f"region must be one of {', '.join(REGIONS)}, unavailable_mi "
                             f"or no_solution, got {region!r}")
        return Rate(int(getattr(self, region)), int(self.epochs))

    def dense(self, block: int = 1) -> np.ndarray:
        """The histogram as an ``(n_pe, n_pl)`` int array, PE bins first.

        ``block`` > 1 sums blocks of ``block`` x ``block`` bins (a coarser picture, bins of
        ``block * bin_m``): ``n_pe = n_pl = ceil(n_bins / block)``.
        """
        if isinstance(block, bool) or not isinstance(block, int | np.integer) or block < 1:
            raise ValueError(f"block must be an integer >= 1, got {block!r}")
        n = -(-self.n_bins // int(block))
        out = np.zeros((n, n), dtype=np.int64)
        np.add.at(out, (self.hist_pe_bin // block, self.hist_pl_bin // block),
                  self.hist_count)
        return out

    def region_items(self, alarmed_word: str = "with an alarm") -> list[str]:
        """Every region's name, count and share (and how many of MI/HMI had an alarm,
        ``"N <alarmed_word>"``), one string each."""
        items = []
        alarmed = {"mi": self.mi_alarmed, "hmi": self.hmi_alarmed}
        for r, k in self.counts.items():
            share = self.shares[r]
            notes = [] if math.isnan(share) else [pct(share)]
            if alarmed.get(r):
                notes.append(f"{alarmed[r]} {alarmed_word}")
            items.append(f"{REGION_NAMES[r]} {k}" + (f" ({'; '.join(notes)})" if notes else ""))
        return items

    def summary_line(self) -> str:
        """One line: every region's count and share."""
        parts = self.region_items()
        extra = (f"; unavailable with PE >= PL {self.unavailable_mi}"
                 if self.unavailable_mi else "")
        return (f"{self.label} (AL {self.al_m:g} m, {self.epochs} epochs): "
                + ", ".join(parts) + extra)


#: The regions' names as the diagram and the summaries print them.
REGION_NAMES = {"nominal": "nominal", "mi": "MI", "hmi": "HMI", "unavailable": "unavailable"}


def pct(x: float) -> str:
    """A share as a percentage with 3 significant digits ("0%" for none)."""
    return f"{100 * x:.3g}%" if x > 0 else "0%"


@dataclass(frozen=True, eq=False)
class StanfordDiagram:
    """The horizontal and vertical Stanford-ESA diagrams of one run.

    Attributes
    ----------
    horizontal : HPE against HPL, alert limit HAL.
    vertical : |VPE| against VPL, alert limit VAL.
    error : which solution's errors: ``"before"`` (the full-set solution, the one the
        protection levels of ``parity`` and ``mss`` are computed for) or ``"after"``
        (after exclusion).
    pl_columns : the two protection-level columns read (``("hpl_m", "vpl_m")``).
    source : what the diagram was made from (a scenario name, a file).
    """

    horizontal: StanfordResult
    vertical: StanfordResult
    error: str
    pl_columns: tuple[str, str]
    source: str = ""

    def summary_lines(self) -> list[str]:
        return [self.horizontal.summary_line(), self.vertical.summary_line()]


def _classify(pe: np.ndarray, pl: np.ndarray, al: float,
              alarm: np.ndarray | None) -> dict[str, int | None]:
    """Region counts of flat arrays (gLAB graph.py v5.2, ``stanford.getPoints``)."""
    with np.errstate(invalid="ignore"):
        none = np.isnan(pe) | np.isnan(pl)
        unavailable = none | (pl >= al)          # i_alarm: y >= AL
        fail = ~none & (pe >= pl)                # i_fails: x / y >= 1
        mi = fail & ~unavailable & (pe < al)     # n_fail2: x < AL
        hmi = fail & ~unavailable & (pe >= al)   # n_fail1
    n = pe.size
    counts = {"mi": int(mi.sum()), "hmi": int(hmi.sum()),
              "unavailable": int(unavailable.sum())}
    counts["nominal"] = n - counts["mi"] - counts["hmi"] - counts["unavailable"]
    counts["unavailable_mi"] = int((fail & unavailable).sum())
    counts["no_solution"] = int(none.sum())
    counts["mi_alarmed"] = None if alarm is None else int((mi & alarm).sum())
    counts["hmi_alarmed"] = None if alarm is None else int((hmi & alarm).sum())
    return counts


def _bin_index(v: np.ndarray, bin_m: float) -> np.ndarray:
    """Index k of the bin ``[k * bin_m, (k + 1) * bin_m)`` holding each ``v >= 0``, the
    edges computed as :attr:`StanfordResult.edges_m` computes them (so a value lands in the
    bin its edges say even where ``v / bin_m`` rounds across an integer)."""
    k = np.floor(v / bin_m)
    k = np.where(k * bin_m > v, k - 1, k)
    k = np.where((k + 1) * bin_m <= v, k + 1, k)
    return k.astype(np.int64)


def _histogram(pe: np.ndarray, pl: np.ndarray, bin_m: float, max_m: float | None):
    """Sparse 2-D histogram of the finite (PE, PL) pairs (module docstring)."""
    ok = np.isfinite(pe) & np.isfinite(pl)
    x, y = pe[ok], pl[ok]
    if max_m is None:
        top = float(max(x.max(), y.max())) if x.size else 0.0
        n = int(np.floor(top / bin_m)) + 1  # the largest value inside the last bin
    else:
        n = math.ceil(max_m / bin_m - 1e-9)
    n = max(n, 2)
    i, j = _bin_index(x, bin_m), _bin_index(y, bin_m)
    over_x, over_y = i >= n, j >= n
    # An error beyond the range whose PL is larger goes one bin lower (gLAB dealData).
    i = np.where(over_x, np.where(y > x, n - 2, n - 1), i)
    j = np.minimum(j, n - 1)
    flat, count = np.unique(i * n + j, return_counts=True)
    return (n, (flat // n).astype(np.int64), (flat % n).astype(np.int64),
            count.astype(np.int64), int((over_x | over_y).sum()))


def stanford_esa(pe_m, pl_m, al_m: float, *, bin_m: float = DEFAULT_BIN_M,
                 max_m: float | None = None, alarm=None, label: str = "") -> StanfordResult:
    """The Stanford-ESA diagram of position errors against protection levels.

    Parameters
    ----------
    pe_m : (...,) position errors (m); the sign is dropped (a signed vertical error is
        fine). NaN: no position at that epoch.
    pl_m : (...,) protection levels (m), the same shape, >= 0; NaN: no PL at that epoch;
        +inf: an unavailable PL (more than the alert limit).
    al_m : alert limit (m), > 0.
    bin_m : histogram bin (m), > 0 (gLAB's 0.1 m by default).
    max_m : the histogram's upper edge (m), or None for just past the largest finite
        value; larger values go to the last bin (``clipped``).
    alarm : (...,) bool, the integrity monitor's alarm at each epoch, or None; it
        changes no region, the result counts the alarmed MI and HMI epochs.
    label : a name for the result (``"horizontal"``).

    Returns
    -------
    StanfordResult
        Region counts (module docstring) over all ``pe_m.size`` epochs, and the histogram.

    Raises
    ------
    ValueError
        Shapes differ, a protection level is negative, ``alarm`` is not boolean,
        ``al_m``, ``bin_m`` or ``max_m`` is not a finite number > 0, or ``max_m`` holds
        fewer than two bins.

    Examples
    --------
    >>> r = stanford_esa([1.0, 5.0, 45.0, 2.0, float("nan")],
    ...                  [4.0, 4.0, 30.0, 50.0, 3.0], al_m=40.0)
    >>> r.counts
    {'nominal': 1, 'mi': 1, 'hmi': 1, 'unavailable': 2}
    >>> r.no_solution, int(r.hist_count.sum())
    (1, 4)
    """
    pe = np.abs(np.asarray(pe_m, dtype=float))
    pl = np.asarray(pl_m, dtype=float)
    if pe.shape != pl.shape:
        raise ValueError(f"pe_m and pl_m must have the same shape, got {pe.shape} and "
                         f"{pl.shape}")
    if alarm is not None:
        alarm = np.asarray(alarm)
        if alarm.shape != pe.shape or alarm.dtype != bool:
            raise ValueError(f"alarm must be a boolean array of the shape of pe_m "
                             f"{pe.shape}, got {alarm.dtype} {alarm.shape}")
        alarm = alarm.ravel()
    pe, pl = pe.ravel(), pl.ravel()
    if np.any(pl < 0):  # NaN compares False: allowed
        raise ValueError(f"pl_m must be >= 0 (a protection level), got {pl[pl < 0][0]!r}")
    al = check_positive("al_m", al_m)
    bin_m = check_positive("bin_m", bin_m)
    if max_m is not None:
        max_m = check_positive("max_m", max_m)
        if max_m < 2 * bin_m:
            raise ValueError(f"max_m must hold at least two bins of bin_m {bin_m:g} m, "
                             f"got {max_m:g} m")
    counts = _classify(pe, pl, al, alarm)
    n, hi, hj, hc, clipped = _histogram(pe, pl, bin_m, max_m)
    return StanfordResult(
        label=label, al_m=al, epochs=int(pe.size), **counts, bin_m=bin_m, n_bins=n,
        hist_pe_bin=hi, hist_pl_bin=hj, hist_count=hc, clipped=clipped,
        status="ok" if hc.size else "empty")


def pl_columns(pl: str = "") -> tuple[str, str]:
    """The protection-level columns of a result table: ``("hpl_m", "vpl_m")`` for the
    algorithm's own PLs, ``("hpl_<pl>_m", "vpl_<pl>_m")`` for a variant (``mss`` also gives
    ``classic`` and ``nobaro``)."""
    if not isinstance(pl, str) or (pl != "" and not pl.replace("_", "").isalnum()):
        raise ValueError(f"pl must be a column suffix such as 'classic', got {pl!r}")
    return ("hpl_m", "vpl_m") if pl == "" else (f"hpl_{pl}_m", f"vpl_{pl}_m")


def _check_error(error: str) -> str:
    if error not in ERRORS:
        raise ValueError(f"error must be one of {', '.join(ERRORS)}, got {error!r}")
    return error


def _missing_pl(have, hpl: str, vpl: str, where: str) -> ValueError:
    others = sorted(c for c in have if c.startswith(("hpl_", "vpl_")))
    hint = (f" (it has {', '.join(others)}: choose one with pl, --pl on the command "
            "line)" if others else
            " (run an algorithm that gives protection levels, e.g. mss or parity)")
    return ValueError(f"{where} has no protection-level columns {hpl} and {vpl}{hint}")


def stanford_from_table(table, hal_m: float, val_m: float, *, error: str = "before",
                        pl: str = "", bin_m: float = DEFAULT_BIN_M,
                        max_m: float | None = None, source: str = "") -> StanfordDiagram:
    """The horizontal and vertical diagrams of a result table.

    Parameters
    ----------
    table : a :class:`~raimcore.scoring.table.ResultTable` or a mapping of its columns
        (``hpe_<error>_m``, ``vpe_<error>_m`` and the protection levels, each (E,); the
        ``alarm`` column, when there is one, gives the alarmed MI / HMI counts).
    hal_m, val_m : horizontal and vertical alert limits (m).
    error : ``"before"`` (default: the full-set solution, whose errors the ``parity`` and
        ``mss`` protection levels bound) or ``"after"`` (after exclusion).
    pl : protection-level variant (:func:`pl_columns`): ``""`` for ``hpl_m``/``vpl_m``,
        ``"classic"`` or ``"nobaro"`` for ``mss``'s others.
    bin_m, max_m : as :func:`stanford_esa`.
    source : a name for the run.

    Raises
    ------
    ValueError
        The table has no such protection-level or error columns, or a bad argument.
    """
    error = _check_error(error)
    hpl, vpl = pl_columns(pl)
    cols = table.columns if hasattr(table, "columns") else table
    if hpl not in cols or vpl not in cols:
        raise _missing_pl(cols, hpl, vpl, source or "the result table")
    pe_cols = (f"hpe_{error}_m", f"vpe_{error}_m")
    for c in pe_cols:
        if c not in cols:
            raise ValueError(f"{source or 'the result table'} has no error column {c}")
    alarm = _bools(cols["alarm"]) if "alarm" in cols else None
    kw = dict(bin_m=bin_m, max_m=max_m, alarm=alarm)
    return StanfordDiagram(
        horizontal=stanford_esa(_floats(cols[pe_cols[0]]), _floats(cols[hpl]), hal_m,
                                label="horizontal", **kw),
        vertical=stanford_esa(_floats(cols[pe_cols[1]]), _floats(cols[vpl]), val_m,
                              label="vertical", **kw),
        error=error, pl_columns=(hpl, vpl), source=source)


def _bools(col) -> np.ndarray:
    """A table column as booleans (a CSV's ``True``/``False`` text too)."""
    arr = np.asarray(col)
    if arr.dtype == bool:
        return arr
    text = np.array([str(v).strip().lower() for v in arr])
    bad = ~np.isin(text, ("true", "false", "1", "0"))
    if bad.any():
        raise ValueError(f"alarm column: {arr[bad][0]!r} is not true or false")
    return np.isin(text, ("true", "1"))


def _floats(col) -> np.ndarray:
    """A table column as floats (None -> NaN)."""
    arr = np.asarray(col)
    if arr.dtype == object:
        arr = np.array([np.nan if v is None else v for v in arr], dtype=float)
    return arr.astype(float)


def stanford_from_result(result, **kwargs) -> StanfordDiagram:
    """The diagrams of a :class:`~raimcore.pipeline.ScenarioResult`, with the scenario's
    alert limits (``hal_m``, ``val_m``); ``kwargs`` as :func:`stanford_from_table`."""
    s = result.scenario
    kwargs.setdefault("source", f"scenario {s.name}, algorithm {s.algorithm}")
    return stanford_from_table(result.table, s.hal_m, s.val_m, **kwargs)


def stanford_from_csv(path, hal_m: float, val_m: float, **kwargs) -> StanfordDiagram:
    """The diagrams of a result CSV (``raim run ... --out result.csv``); ``kwargs`` as
    :func:`stanford_from_table`. A CSV does not keep the run's alert limits: give them.

    Raises
    ------
    ValueError
        No such file, not a result CSV, no protection-level columns, or a value that is
        not a number.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{str(path)!r}: no such file")
    error = _check_error(kwargs.get("error", "before"))
    hpl, vpl = pl_columns(kwargs.get("pl", ""))
    kwargs.setdefault("source", path.name)
    try:
        with path.open(newline="", encoding="utf-8") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if not header:
                raise ValueError(f"{path.name}: empty file, not a result CSV")
            if hpl not in header or vpl not in header:
                raise _missing_pl(header, hpl, vpl, path.name)
            want = (f"hpe_{error}_m", f"vpe_{error}_m", hpl, vpl)
            missing = [c for c in want if c not in header]
            if missing:
                raise ValueError(f"{path.name} has no column {', '.join(missing)}: not a "
                                 "result CSV of 'raim run --out'")
            if "alarm" in header:
                want = (*want, "alarm")
            idx = [header.index(c) for c in want]
            rows = [[row[k] if k < len(row) else "" for k in idx] for row in reader]
    except UnicodeDecodeError:
        raise ValueError(f"{path.name}: not a text file, not a result CSV") from None
    cols: dict[str, np.ndarray] = {}
    for k, name in enumerate(want):
        if name == "alarm":
            cols[name] = _bools([row[k] for row in rows])
            continue
        vals = np.full(len(rows), np.nan)
        for r, row in enumerate(rows):
            text = row[k].strip()
            if text:
                try:
                    vals[r] = float(text)
                except ValueError:
                    raise ValueError(f"{path.name}, row {r + 2}, column {name}: "
                                     f"{text!r} is not a number") from None
        cols[name] = vals
    return stanford_from_table(_Columns(cols), hal_m, val_m, **kwargs)


class _Columns(Mapping):
    """The columns read from a CSV, as :func:`stanford_from_table` reads a table."""

    def __init__(self, cols: dict[str, np.ndarray]):
        self.columns = cols

    def __getitem__(self, key):
        return self.columns[key]

    def __iter__(self):
        return iter(self.columns)

    def __len__(self):
        return len(self.columns)
