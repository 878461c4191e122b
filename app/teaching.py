"""Teaching text for the dashboard: the chosen algorithm explained, and a one-line verdict
of the current run ("fault on G10 detected at t = 34 s, G10 excluded, HPE back to 12 m")
whose counts come from the run's :class:`~raimcore.scoring.Summary`.

Pure functions of plain data; no GUI import.
"""

from __future__ import annotations

import re

import numpy as np

from raimcore.scoring import Summary

from .figures import RunView

# TeX macros -> Unicode, for viser's Markdown (which renders no math): equations are shown
# as code spans with readable symbols.
_TEX = {
    r"\sigma": "σ", r"\lambda": "λ", r"\beta": "β", r"\tau": "τ", r"\alpha": "α",
    r"\mu": "μ", r"\Delta": "Δ", r"\delta": "δ", r"\sum": "Σ", r"\chi": "χ", r"\theta": "θ",
    r"\epsilon": "ε", r"\varepsilon": "ε", r"\le": "≤", r"\ge": "≥", r"\leq": "≤",
    r"\geq": "≥", r"\neq": "≠", r"\approx": "≈", r"\sim": "~", r"\cdot": "·", r"\times": "×",
    r"\infty": "∞", r"\in": "∈", r"\|": "‖", r"\hat": "", r"\mathrm": "", r"\operatorname": "",
    r"\left": "", r"\right": "", r"\quad": " ", r"\,": " ", r"\;": " ", r"\max": "max",
    r"\min": "min", r"\arg": "arg", r"\log": "log", r"\sqrt": "√", r"\top": "T",
    r"\ldots": "…", r"\dots": "…", r"\to": "→", r"\rightarrow": "→", r"\propto": "∝",
    r"\Phi": "Φ", r"\phi": "φ", r"\pi": "π", r"\omega": "ω", r"\gamma": "γ", r"\eta": "η",
    r"\rho": "ρ", r"\nu": "ν", r"\mathcal": "", r"\mathbf": "", r"\boldsymbol": "",
}


def tex_to_text(tex: str) -> str:
    """Make TeX readable without a math renderer (``\\sigma^2`` -> ``σ^2``).

    >>> tex_to_text(r"\\lambda = \\|V b\\|^2 / \\sigma^2")
    'λ = ‖V b‖^2 / σ^2'
    """
    out = tex
    out = re.sub(r"\\lVert\s*", "‖", out)
    out = re.sub(r"\s*\\rVert", "‖", out)
    for macro in sorted(_TEX, key=len, reverse=True):
        tail = r"(?![A-Za-z])" if macro[-1].isalpha() else ""
        out = re.sub(re.escape(macro) + tail, lambda _m, r=_TEX[macro]: r, out)
    out = re.sub(r"\\frac\{([^{}]*)\}\{([^{}]*)\}", r"(\1)/(\2)", out)
    out = out.replace("{", "").replace("}", "")
    return re.sub(r"[ \t]+", " ", out).strip()


def markdown_math(md: str) -> str:
    """Replace ``$...$`` / ``$$...$$`` math in Markdown by code spans of readable text."""
    md = re.sub(r"\$\$(.+?)\$\$", lambda m: f"\n\n`{tex_to_text(m.group(1))}`\n\n", md,
                flags=re.S)
    return re.sub(r"\$([^$]+?)\$", lambda m: f"`{tex_to_text(m.group(1))}`", md)


def teaching_markdown(label: str, summary: str, equations: str, reference: str = "") -> str:
    """The teaching panel for one algorithm (from its ``AlgorithmSpec``)."""
    parts = [f"### {label}", summary.strip(), "**Key equations**", markdown_math(equations)]
    if reference:
        parts.append(f"*Reference:* {reference}")
    return "\n\n".join(p for p in parts if p)


def _fmt_t(t_s: float) -> str:
    return f"{t_s:.0f} s" if abs(t_s - round(t_s)) < 1e-6 else f"{t_s:.1f} s"


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def verdict(view: RunView, summary: Summary, p_fa: float | None = None) -> str:
    """One line saying what happened in the run, for every injected fault.

    The counts (false alarms k of n fault-free epochs, unavailable and detect-only epochs,
    faults that never act) are the run's :class:`~raimcore.scoring.Summary`, the same the
    command line prints; the per-fault story (detection time, exclusion, error) is read
    from ``view``.

    Examples: ``"Fault on G10 detected at t = 34 s (14 s after onset), G10 excluded, HPE
    back to 12 m."``, ``"Fault on G10 (from t = 20 s) never detected."``, ``"No fault
    injected: 1 alarm in 600 epochs (false alarms, expected about 0.6)."``
    """
    t = view.t_s
    n_e = t.shape[0]
    if n_e == 0:
        return "Empty run."
    fa = summary.false_alarm
    warnings = [_sentence(n.removeprefix("warning:").strip()) for n in summary.notes
                if n.startswith("warning:")]
    tail = [*warnings, *_epoch_notes(summary)]
    alarm = np.asarray(view.table.get("alarm", np.zeros(n_e, bool)), dtype=bool)
    faulty = np.flatnonzero(np.any(view.faulted, axis=0))
    if summary.faulted_epochs == 0 or faulty.size == 0:
        what = "No fault acts" if warnings else "No fault injected"
        rate = f", expected about {p_fa * fa.n:.2g}" if p_fa is not None else ""
        return " ".join([f"{what}: {_plural(fa.k, 'alarm')} in {fa.n} epochs (false "
                         f"alarms{rate}).", *tail])
    hpe_after = view.column("hpe_after_m")
    hpe_before = view.column("hpe_before_m")
    lines = []
    for j in faulty:
        name = view.sat_names[j]
        active = view.faulted[:, j]
        i_on = int(np.argmax(active))
        det = alarm & (np.arange(n_e) >= i_on) & active
        if not det.any():
            msg = (f"Fault on {name} (from t = {_fmt_t(t[i_on])}) never detected")
            if hpe_before is not None and np.isfinite(hpe_before[active]).any():
                msg += f", HPE up to {np.nanmax(np.abs(hpe_before[active])):.0f} m"
            lines.append(msg + ".")
            continue
        i_det = int(np.argmax(det))
        delay = t[i_det] - t[i_on]
        msg = f"Fault on {name} detected at t = {_fmt_t(t[i_det])}"
        msg += f" ({_fmt_t(delay)} after onset)" if delay > 0 else " (at onset)"
        excl = view.excluded[:, j] & active
        if excl.any():
            msg += f", {name} excluded"
            if hpe_after is not None and np.isfinite(hpe_after[excl]).any():
                hpe = float(np.nanmedian(np.abs(hpe_after[excl])))
                # Metres for snapshot errors; decimetres where they are small (filters,
                # real data), so "back to 0 m" never shows.
                msg += f", HPE back to {hpe:.0f} m" if hpe >= 10 else \
                    f", HPE back to {hpe:.1f} m"
        else:
            others = np.flatnonzero(np.any(view.excluded[active], axis=0))
            others = [view.sat_names[k] for k in others if k != j]
            if others:
                msg += f", but {', '.join(others[:3])} excluded instead (wrong satellite)"
            else:
                msg += ", nothing excluded"
        lines.append(msg + ".")
    if fa.k:
        lines.append(f"{_plural(fa.k, 'alarm')} while no fault was on ({fa.k} of {fa.n} "
                     f"fault-free epochs).")
    # Windowed or filtering algorithms still hold a fault for `memory_epochs` after it ends:
    # their alarms there are not false alarms (the summary counts them apart).
    if summary.fault_memory_alarms:
        lines.append(f"{_plural(summary.fault_memory_alarms, 'alarm')} just after the fault "
                     f"ended, while it was still in the algorithm's window.")
    return " ".join([*lines, *tail])


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
