"""Teaching text for the dashboard: the chosen algorithm explained, and a one-line verdict
of the current run ("fault on G10 detected at t = 34 s, G10 excluded, HPE back to 12 m")
whose counts come from the run's :class:`~raimcore.scoring.Summary`.

Pure functions of plain data; no GUI import.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from raimcore.measure.faults import Fault
from raimcore.scoring import Summary, in_fault_memory
from raimcore.sky.constellations import SYSTEM_PREFIX

from .figures import RunView
from .mathrender import markdown_math

#: Longer Learn-tab text for some algorithms (by registry name), shown after the key
#: equations: what the algorithm's outputs mean and how to read its panel.
ALGORITHM_NOTES: dict[str, str] = {
    # ../shared/ARAIM.md sections 2-11 (the MAAST baseline, ARAIM ADD v4.2).
    "araim": r"""
**What MHSS computes.** Multiple hypothesis solution separation: one position from all
satellites in view, $\hat x^{(0)} = S^{(0)} y$, and one per monitored *fault mode* $k$,
$\hat x^{(k)} = S^{(k)} y$, computed without the satellites $R_k$ that the mode says may
be faulty. If mode $k$ is the truth, $\hat x^{(k)}$ is fault-free; the separation
$\hat x^{(k)} - \hat x^{(0)}$ is tested on each axis against $T_{k,q}$, and the protection
levels cover the error of every mode that passes its test.

**The integrity support message (ISM).** Per constellation: $\sigma_{URA}$, the clock and
orbit error bound used for integrity ($C_{int}$, the protection levels); $\sigma_{URE}$,
the one used for accuracy and continuity ($C_{acc}$, the thresholds and
$\sigma_{acc}$); the nominal bias $b_{nom}$; the prior probability $P_{sat}$ that one
satellite is faulty and $P_{const}$ that a whole constellation is. Scenario key `ism`
(e.g. `--set 'ism={GAL={p_const=1e-8}}'`); the default is MAAST's example message, H-ARAIM
grade (Galileo $\sigma_{URA} = 6$ m, $P_{const} = 2 \times 10^{-4}$).

**Fault modes.** Each satellite and each constellation is an independent event $e$ with
prior $p_e$; a set $E$ of events happens with probability
$p(E) = P_0 \prod_{e \in E} \frac{p_e}{1 - p_e}$, $P_0 = \prod_e (1 - p_e)$. The
modes are taken by size (single satellites, pairs, a constellation, ...) until the
probability left unmonitored is small: $P_{nm} \le P_{THRES}$. A likely constellation
fault ($P_{const}$ large) adds its mode, which removes all of that constellation's
satellites: a large separation and a weak subset geometry, so a larger VPL.

**Thresholds.** $T_{k,q} = K_{fa,q}\,\sigma_{ss,q}^{(k)} + b_{ss,q}^{(k)}$, the
false-alarm budget split over the $N_{fm}$ modes:
$K_{fa,3} = Q^{-1}\left(\frac{P_{FA,V}}{2 N_{fm}}\right)$.

**Protection level** (ARAIM.md section 7). Per axis $q$, $L$ solves
$2\,Q_m\left(\frac{L - b_q^{(0)}}{\sigma_q^{(0)}}\right) + \sum_{k \ge 1} p_k
\min\left(Q_m\left(\frac{L - T_{k,q} - b_q^{(k)}}{\sigma_q^{(k)}}\right),
a_k\right) = PHMI'$, with
$PHMI_V' = \frac{PHMI_{VERT}}{N_{es,int}}\left(1 - \frac{P_{nm}}{PHMI_{VERT} +
PHMI_{HOR}}\right)$ and $Q_m(x) = Q(x)$ for $x \ge 0$, $1$ below: the fault-free term
plus every mode's chance of an error beyond $L$ while its test stays quiet, weighted by
its prior, equals the integrity budget. $\mathrm{VPL} = L_3$,
$\mathrm{HPL} = \sqrt{L_1^2 + L_2^2}$.

**EMT and accuracy.** The effective monitor threshold is the largest vertical threshold
of a mode likely enough to matter,
$\mathrm{EMT} = \max \{ T_{k,3} : k \ge 1,\ p_k \ge P_{EMT} \}$ with
$P_{EMT} = 10^{-5}$: the biggest vertical error the monitor lets pass without an alarm.
$\sigma_{acc} = \sqrt{(S^{(0)} C_{acc} S^{(0)T})_{33}}$ is the all-in-view vertical
accuracy.

**LPV-200 availability.** An epoch is available when all four hold:
$\mathrm{VPL} \le \mathrm{VAL} = 35$ m, $\mathrm{HPL} \le \mathrm{HAL} = 40$ m,
$\mathrm{EMT} \le 15$ m and $\sigma_{acc} \le 1.87$ m (column `available`; the
*ARAIM protection levels* panel shades the epochs that fail). With exclusion
(`araim_fde`), the mode that explains an alarm is removed (a satellite or a whole
constellation, column `excluded_mode`) and the protection levels are the worst over the
exclusion candidates.
""",
}


def algorithm_notes(name: str) -> str:
    """The longer Learn-tab text of algorithm ``name`` (empty when it has none)."""
    return ALGORITHM_NOTES.get(name, "")


def _name_of(label: str) -> str:
    """The registry name of the algorithm labelled ``label`` (empty when none is)."""
    from raimcore import algorithms

    return next((n for n in algorithms.names() if algorithms.get(n).label == label), "")


def teaching_markdown(label: str, summary: str, equations: str, reference: str = "",
                      name: str | None = None) -> str:
    """The teaching panel for one algorithm (from its ``AlgorithmSpec``): its summary and
    key equations, then its longer notes (:data:`ALGORITHM_NOTES`, found by ``name``, or
    by ``label`` when ``name`` is None), every ``$...$`` typeset as MathML
    (:mod:`app.mathrender`).

    Raises
    ------
    app.mathrender.MathError : a formula does not typeset (the test suite renders every
        registered algorithm's text).
    """
    parts = [f"### {label}", markdown_math(summary.strip()), "**Key equations**",
             markdown_math(equations.strip())]
    notes = algorithm_notes(_name_of(label) if name is None else name)
    if notes:
        parts.append(markdown_math(notes.strip()))
    if reference:
        parts.append(f"*Reference:* {markdown_math(reference)}")
    return "\n\n".join(p for p in parts if p)


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def format_probability(p: float, digits: int = 2) -> str:
    """A probability in scientific notation, the way the teaching text writes it.

    A fixed number of decimals hides small probabilities (``P_fa = 2.8e-9`` shown with 7
    decimals reads ``0.0000000``), so every probability is written as a mantissa times a
    power of ten, with ``digits`` significant digits.

    >>> format_probability(2.8e-9)
    '2.8 × 10⁻⁹'
    >>> format_probability(1e-3)
    '1 × 10⁻³'
    >>> format_probability(0.0)
    '0'
    """
    if p == 0 or not np.isfinite(p):
        return f"{p:g}"
    mant, exp = f"{p:.{digits - 1}e}".split("e")
    mant = mant.rstrip("0").rstrip(".") if "." in mant else mant
    exp = int(exp)
    if exp == 0:
        return mant
    return f"{mant} × 10{str(exp).translate(_SUPERSCRIPT)}"


def _fmt_count(x: float) -> str:
    """An expected number of events: ``0.6``, ``12``, or scientific when below 0.01."""
    return f"{x:.2g}" if x >= 0.01 or x == 0 else format_probability(x)


def _fmt_t(t_s: float) -> str:
    return f"{t_s:.0f} s" if abs(t_s - round(t_s)) < 1e-6 else f"{t_s:.1f} s"


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


@dataclass(frozen=True)
class _Onset:
    """A fault as the verdict needs it (duck-typed like :class:`raimcore.measure.Fault`)."""

    sat: str
    t0_s: float
    t1_s: float = math.inf


def _onsets_from_truth(view: RunView) -> list[_Onset]:
    """Faults read back from ``view.faulted`` when the scenario's list is not given: one per
    run of faulted epochs of a satellite (a ramp's onset then reads one epoch late, its
    bias being zero at ``t0_s``: pass the faults to :func:`verdict`)."""
    t = view.t_s
    out = []
    for j in np.flatnonzero(np.any(view.faulted, axis=0)):
        on = np.concatenate([[False], view.faulted[:, j], [False]]).astype(np.int8)
        starts, ends = np.flatnonzero(np.diff(on) == 1), np.flatnonzero(np.diff(on) == -1)
        for i0, i1 in zip(starts, ends, strict=True):
            out.append(_Onset(view.sat_names[j], float(t[i0]),
                              float(t[i1]) if i1 < t.size else math.inf))
    return sorted(out, key=lambda f: f.t0_s)


def verdict(view: RunView, summary: Summary, p_fa: float | None = None,
            faults: Sequence[Fault] | None = None) -> str:
    """What happened in the run, one sentence per injected fault, then the false alarms.

    Each fault gets its own detection: the first alarm, while the fault acts (or while a
    windowed algorithm still holds it), whose isolated or excluded satellite is that fault's.
    When an alarm raised by another fault is already on at its onset and the fault is never
    named, the verdict says so ("alarm already active (raised by G10's fault)") instead of
    crediting that alarm. Onsets are the faults' own ``t0_s``, as the controls state them
    (a ramp's bias is still zero there). The counts (false alarms k of n fault-free
    epochs, unavailable and detect-only epochs, faults that never act) are the run's
    :class:`~raimcore.scoring.Summary`, the same the command line prints; probabilities
    are written in scientific notation (:func:`format_probability`).

    A constellation fault (``sat`` a system key) is told over all its satellites: its
    detection is the first alarm naming any of them, and it reads "GAL excluded" only where
    every faulted satellite of it is excluded ("only E05 of GAL excluded" otherwise).

    Parameters
    ----------
    view : the run as the figures see it.
    summary : the run's summary.
    p_fa : the false-alarm probability per epoch, for the expected number of false alarms.
    faults : the scenario's injected faults (``scenario.faults``); without them the faults
        are read back from ``view.faulted`` (a ramp then seems to start one epoch late,
        a constellation fault reads as one fault per satellite).

    Examples: ``"Fault on G10 detected at t = 129 s (9 s after its onset at t = 120 s),
    G10 excluded, HPE back to 3.1 m."``, ``"Fault on G05 from t = 300 s: alarm already
    active (raised by G10's fault), G05 never isolated, HPE up to 15 m."``, ``"No fault
    injected: 1 alarm in 600 epochs (false alarms, P_fa = 1 × 10⁻³ per epoch: about 0.6
    expected)."``
    """
    t = view.t_s
    n_e = t.shape[0]
    if n_e == 0:
        return "Empty run."
    fa = summary.false_alarm
    warnings = [_sentence(n.removeprefix("warning:").strip()) for n in summary.notes
                if n.startswith("warning:")]
    tail = [*warnings, *_epoch_notes(summary)]
    expected = (f", P_fa = {format_probability(p_fa)} per epoch: about "
                f"{_fmt_count(p_fa * fa.n)} expected" if p_fa is not None else "")
    if summary.faulted_epochs == 0 or not np.any(view.faulted):
        what = "No fault acts" if warnings else "No fault injected"
        return " ".join([f"{what}: {_plural(fa.k, 'alarm')} in {fa.n} epochs (false "
                         f"alarms{expected}).", *tail])
    story = _FaultStory(view)
    onsets = list(faults) if faults is not None else _onsets_from_truth(view)
    lines = [line for f in onsets if (line := story.tell(f, onsets)) is not None]
    if fa.k:
        lines.append(f"{_plural(fa.k, 'alarm')} while no fault was on ({fa.k} of {fa.n} "
                     f"fault-free epochs){expected}.")
    # Windowed or filtering algorithms still hold a fault for `memory_epochs` after it ends:
    # their alarms there are not false alarms (the summary counts them apart).
    if summary.fault_memory_alarms:
        lines.append(f"{_plural(summary.fault_memory_alarms, 'alarm')} just after the fault "
                     f"ended, while it was still in the algorithm's window.")
    return " ".join([*lines, *tail])


class _FaultStory:
    """The per-fault sentences of :func:`verdict`, over one run."""

    def __init__(self, view: RunView):
        self.view = view
        self.t = view.t_s
        n_e = self.t.shape[0]
        self.alarm = np.asarray(view.table.get("alarm", np.zeros(n_e, bool)), dtype=bool)
        self.memory = view.table.get("memory_epochs")
        iso = (np.full(n_e, -1) if view.isolated_idx is None
               else np.asarray(view.isolated_idx, dtype=int))
        # named[i, j]: the algorithm isolates or excludes satellite j at epoch i.
        self.named = np.asarray(view.excluded, dtype=bool).copy()
        rows = np.flatnonzero(iso >= 0)
        self.named[rows, iso[rows]] = True
        self.hpe_after = view.column("hpe_after_m", "hpe_before_m")

    def window(self, f) -> np.ndarray:
        """(E,) bool: epochs with ``t0_s <= t < t1_s``."""
        return (self.t >= f.t0_s) & (self.t < f.t1_s)

    def held(self, f) -> np.ndarray:
        """(E,) bool: the fault's window and the epochs a windowed algorithm still holds it."""
        w = self.window(f)
        if self.memory is None:
            return w
        return w | in_fault_memory(w, self.memory)

    def columns(self, f) -> np.ndarray:
        """Indices of the satellites fault ``f`` acts on: its satellite, or every
        satellite of its system for a constellation fault (``f.sat`` a system key; the
        satellites are told by their names' RINEX letter)."""
        names = self.view.sat_names
        if f.sat in SYSTEM_PREFIX:
            letter = SYSTEM_PREFIX[f.sat]
            return np.array([k for k, n in enumerate(names) if n[:1] == letter], dtype=int)
        return np.array([names.index(f.sat)] if f.sat in names else [], dtype=int)

    def tell(self, f, faults) -> str | None:
        """The sentence for fault ``f`` (None when it never acts: the summary warns)."""
        v, alarm = self.view, self.alarm
        cols = self.columns(f)
        window = self.window(f)
        if cols.size == 0 or not (window[:, None] & v.faulted[:, cols]).any():
            return None
        who = _who(f)
        i_on = int(np.argmax(window))
        held = self.held(f)
        onset = f"t = {_fmt_t(f.t0_s)}"
        # Alarms raised by the other faults: they name another faulty satellite that its
        # fault holds at that epoch. Excluding those satellites is right, not "instead".
        by_other = np.zeros_like(alarm)
        culprit: dict[int, str] = {}
        rightly = set()
        for g in faults:
            if g.sat == f.sat:
                continue
            ks = np.setdiff1d(self.columns(g), cols)
            if ks.size == 0:
                continue
            rightly.update(int(k) for k in ks)
            mine = alarm & self.named[:, ks].any(axis=1) & self.held(g)
            for i in np.flatnonzero(mine & ~by_other):
                culprit[int(i)] = g.sat
            by_other |= mine
        own = alarm & held & self.named[:, cols].any(axis=1)
        if own.any():
            return self._detected(f, cols, int(np.argmax(own)), window, rightly) + "."
        hpe = self._hpe_up_to(window)
        # An alarm raised by another fault was on just before the onset and still is: it
        # is not this fault's detection.
        if i_on > 0 and by_other[i_on - 1] and alarm[i_on]:
            wrong = self._excluded_instead(cols, window, rightly)
            return (f"{who} from {onset}: alarm already active (raised by "
                    f"{culprit[i_on - 1]}'s fault), {f.sat} never isolated"
                    f"{f', {wrong}' if wrong else ''}{hpe}.")
        other = alarm & held & ~by_other
        if other.any():
            return self._detected(f, cols, int(np.argmax(other)), window, rightly) + "."
        if (alarm & held).any():
            names = sorted({culprit[int(i)] for i in np.flatnonzero(alarm & held)})
            return (f"{who} from {onset} never isolated: every alarm while it "
                    f"acted named {' or '.join(names)}'s fault{hpe}.")
        return f"{who} (from {onset}) never detected{hpe}."

    def _detected(self, f, cols: np.ndarray, i_det: int, window: np.ndarray,
                  rightly: set) -> str:
        v, t = self.view, self.t
        delay = t[i_det] - f.t0_s
        msg = f"{_who(f)} detected at t = {_fmt_t(t[i_det])}"
        msg += (f" ({_fmt_t(delay)} after its onset at t = {_fmt_t(f.t0_s)})" if delay > 0
                else " (at its onset)")
        excluded = v.excluded[:, cols]
        excl = excluded.any(axis=1) & window
        if excl.any():
            if f.sat in SYSTEM_PREFIX:
                # The whole constellation out: every faulted satellite of it excluded.
                faulted = v.faulted[:, cols]
                whole = window & faulted.any(axis=1) & ~np.any(faulted & ~excluded, axis=1)
                if whole.any():
                    msg += f", {f.sat} excluded (every one of its satellites in view)"
                    excl = whole
                else:
                    some = [v.sat_names[k] for k in cols[np.any(excluded[window], axis=0)]]
                    more = f" and {len(some) - 3} more" if len(some) > 3 else ""
                    return (msg + f", only {', '.join(some[:3])}{more} of {f.sat} excluded "
                            f"(its other satellites stay faulty){self._hpe_up_to(window)}")
            else:
                msg += f", {f.sat} excluded"
            hpe = self.hpe_after
            if hpe is not None and np.isfinite(hpe[excl]).any():
                med = float(np.nanmedian(np.abs(hpe[excl])))
                # Metres for snapshot errors; decimetres where they are small (filters,
                # real data), so "back to 0 m" never shows.
                msg += f", HPE back to {med:.0f} m" if med >= 10 else \
                    f", HPE back to {med:.1f} m"
            return msg
        wrong = self._excluded_instead(cols, window, rightly)
        return msg + (f", but {wrong}" if wrong else ", nothing excluded")

    def _excluded_instead(self, cols: np.ndarray, window: np.ndarray, rightly: set) -> str:
        """``"G02, G09 excluded instead (wrong satellite)"``: satellites excluded while the
        fault acts that are neither its own nor another fault's (empty if none)."""
        v = self.view
        own = {int(k) for k in cols}
        wrong = [v.sat_names[k] for k in np.flatnonzero(np.any(v.excluded[window], axis=0))
                 if k not in own and k not in rightly]
        if not wrong:
            return ""
        more = f" and {len(wrong) - 3} more" if len(wrong) > 3 else ""
        return (f"{', '.join(wrong[:3])}{more} excluded instead (wrong "
                f"satellite{'s' if len(wrong) > 1 else ''})")

    def _hpe_up_to(self, window: np.ndarray) -> str:
        """``", HPE up to 15 m"``: the largest horizontal error of the output position
        while the fault acts (empty without an error column)."""
        hpe = self.hpe_after
        if hpe is None or not np.isfinite(hpe[window]).any():
            return ""
        return f", HPE up to {np.nanmax(np.abs(hpe[window])):.0f} m"


def _who(f) -> str:
    """``"Fault on G10"``, or ``"Constellation fault on GAL (all its satellites)"``."""
    if f.sat in SYSTEM_PREFIX:
        return f"Constellation fault on {f.sat} (all its satellites)"
    return f"Fault on {f.sat}"


def _sentence(text: str) -> str:
    """``text`` as a sentence: capital first letter, full stop."""
    text = text.strip()
    if not text:
        return text
    return text[0].upper() + text[1:] + ("" if text.endswith((".", "!", "?")) else ".")


def _epoch_notes(summary: Summary) -> list[str]:
    """The epochs no statistic covers fully, named with their reason."""
    out = []
    if summary.unavailable_epochs:
        out.append(f"{_plural(summary.unavailable_epochs, 'epoch')} of {summary.epochs} "
                   f"unavailable (too few satellites or singular geometry: no position, in "
                   f"no statistic).")
    if summary.detect_only_epochs:
        out.append(f"{_plural(summary.detect_only_epochs, 'epoch')} detect-only (one "
                   f"redundant measurement: a fault can be detected, not isolated).")
    return out
