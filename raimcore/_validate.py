"""Input validation at the public edge: one small helper per kind of check.

Every helper raises :class:`ValueError` naming the argument and what is allowed. Kernels
underneath trust their inputs.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np


def check_probability(name: str, value, *, open_interval: bool = True) -> float:
    """Return ``value`` as a float in (0, 1), or raise naming ``name``."""
    try:
        p = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in (0, 1), got {value!r}") from None
    ok = 0.0 < p < 1.0 if open_interval else 0.0 <= p <= 1.0
    if not ok or math.isnan(p):
        rng = "(0, 1)" if open_interval else "[0, 1]"
        raise ValueError(f"{name} must be a probability in {rng}, got {value!r}")
    return p


def check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a finite float > 0 (>= 0 with ``allow_zero``), or raise."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    bad = (x < 0.0) if allow_zero else (x <= 0.0)
    if bad or not math.isfinite(x):
        rel = ">= 0" if allow_zero else "> 0"
        raise ValueError(f"{name} must be a finite number {rel}, got {value!r}")
    return x


def check_range(name: str, value, lo: float, hi: float) -> float:
    """Return ``value`` as a float in [lo, hi], or raise naming the interval."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number in [{lo}, {hi}], got {value!r}") from None
    if not (lo <= x <= hi):
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value!r}")
    return x


def check_int(name: str, value, lo: int | None = None, hi: int | None = None) -> int:
    """Return ``value`` as an int within the optional bounds, or raise."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        try:
            f = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be an integer, got {value!r}") from None
        if not f.is_integer():
            raise ValueError(f"{name} must be an integer, got {value!r}")
        value = int(f)
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        bounds = f"[{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
        raise ValueError(f"{name} must be an integer in {bounds}, got {value!r}")
    return v


def check_choice(name: str, value, choices: Iterable[str]) -> str:
    """Return ``value`` if it is one of ``choices``, or raise listing them."""
    choices = list(choices)
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(map(str, choices))}; got {value!r}")
    return value


def check_array(name: str, value, *, ndim_min: int = 1, last: tuple[int, ...] | None = None,
                finite: bool = True) -> np.ndarray:
    """Return ``value`` as a float array, checking dimensions, trailing shape and finiteness."""
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array") from None
    if a.ndim < ndim_min:
        raise ValueError(f"{name} must have at least {ndim_min} dimension(s), got shape {a.shape}")
    if last is not None and a.shape[a.ndim - len(last):] != tuple(last):
        want = "(..., " + ", ".join(map(str, last)) + ")"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if finite and not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must contain only finite values (no NaN or inf)")
    return a
