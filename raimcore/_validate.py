"""Input validation at the public edge: one small helper per kind of check.

Every helper raises :class:`ValueError` naming the argument and what is allowed. Kernels
underneath trust their inputs.

Numbers: Python ``int`` and ``float``, numpy integer and floating scalars (``np.int64(5)``,
``np.float32(0.1)``) and 0-d real numpy arrays are accepted wherever a number is expected.
``bool`` (and ``np.bool_``), strings, complex numbers and ``None`` are not numbers.

Arrays: shape helpers check O(ndim) metadata only; value checks (finite, >= 0) are one
vectorised pass, never a Python loop over elements.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Mapping

import numpy as np


def _real(name: str, value, what: str) -> float:
    """``value`` as a Python float if it is a real number (not a bool), else raise."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
        return float(value)
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise ValueError(f"{name} must be {what}, got {value!r}")
    return float(value)


def check_finite_number(name: str, value) -> float:
    """Return ``value`` as a finite float, or raise naming ``name``."""
    x = _real(name, value, "a finite number")
    if not math.isfinite(x):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return x


def check_probability(name: str, value, *, open_interval: bool = True) -> float:
    """Return ``value`` as a float in (0, 1) (``[0, 1]`` if not ``open_interval``), or raise."""
    rng = "(0, 1)" if open_interval else "[0, 1]"
    p = _real(name, value, f"a probability in {rng}")
    ok = 0.0 < p < 1.0 if open_interval else 0.0 <= p <= 1.0
    if not ok:  # also catches NaN
        raise ValueError(f"{name} must be a probability in {rng}, got {value!r}")
    return p


def check_positive(name: str, value, *, allow_zero: bool = False) -> float:
    """Return ``value`` as a finite float > 0 (>= 0 with ``allow_zero``), or raise."""
    rel = ">= 0" if allow_zero else "> 0"
    x = _real(name, value, f"a finite number {rel}")
    bad = (x < 0.0) if allow_zero else (x <= 0.0)
    if bad or not math.isfinite(x):
        raise ValueError(f"{name} must be a finite number {rel}, got {value!r}")
    return x


def check_range(name: str, value, lo: float, hi: float) -> float:
    """Return ``value`` as a float in [lo, hi], or raise naming the interval."""
    x = _real(name, value, f"a number in [{lo}, {hi}]")
    if not (lo <= x <= hi):
        raise ValueError(f"{name} must be in [{lo}, {hi}], got {value!r}")
    return x


def check_int(name: str, value, lo: int | None = None, hi: int | None = None) -> int:
    """Return ``value`` as an int within the optional bounds, or raise.

    Integral floats (``5.0``) are accepted; ``bool`` is not an integer here.
    """
    if isinstance(value, (numbers.Integral, np.integer)) and not isinstance(
            value, (bool, np.bool_)):
        v = int(value)
    else:
        f = _real(name, value, "an integer")
        if not f.is_integer():
            raise ValueError(f"{name} must be an integer, got {value!r}")
        v = int(f)
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


def shape_str(dims) -> str:
    """``(..., 6, 4)`` for ``dims = (6, 4)``; names (``"m"``) are written as they are."""
    return "(..., " + ", ".join(map(str, dims)) + ")" if len(dims) else "(...)"


def check_array(name: str, value, *, ndim_min: int = 1, last: tuple | None = None,
                finite: bool = True, match: str | None = None) -> np.ndarray:
    """Return ``value`` as a float array, checking dimensions, trailing shape and finiteness.

    Parameters
    ----------
    last : required trailing shape; an ``int`` entry must match, a ``str`` entry (a name
        such as ``"m"``) or ``None`` accepts any length.
    match : what the trailing shape comes from, for the message, e.g. ``"h (..., 6, 4)"``.
    """
    if isinstance(value, (str, bytes)):
        raise ValueError(f"{name} must be a numeric array, got {value!r}")
    try:
        a = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array") from None
    want = None
    if last is not None:
        ndim_min = max(ndim_min, len(last))
        want = shape_str(["*" if d is None else d for d in last])
    bad = a.ndim < ndim_min
    if not bad and last is not None:
        tail = a.shape[a.ndim - len(last):]
        bad = any(isinstance(d, (int, np.integer)) and t != d
                  for t, d in zip(tail, last, strict=True))
    if bad:
        if want is None:
            raise ValueError(f"{name} must have at least {ndim_min} dimension(s), "
                             f"got shape {a.shape}")
        raise ValueError(f"{name} must have shape {want}"
                         + (f" to match {match}" if match else "") + f", got {a.shape}")
    if finite and not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must contain only finite values (no NaN or inf)")
    return a


def check_weights(name: str, value, *, last: tuple, match: str | None = None) -> np.ndarray:
    """Weights ``1 / sigma^2``: a float array, >= 0, not +inf; NaN is kept (means unused).

    Returns the array with NaN replaced by 0 (an unused measurement).
    """
    w = check_array(name, value, last=last, finite=False, match=match)
    if np.any(w < 0.0) or np.any(np.isinf(w)):
        raise ValueError(f"{name} must be finite and >= 0 (0 or NaN marks an unused "
                         "measurement)")
    return np.where(np.isnan(w), 0.0, w)


def check_batch(shapes: Mapping[str, tuple]) -> tuple:
    """Broadcast the batch (leading) shapes of several arguments, naming the first misfit.

    ``shapes`` maps each argument name to its batch shape, in order.
    """
    out: tuple = ()
    seen: list[str] = []
    for name, s in shapes.items():
        try:
            out = np.broadcast_shapes(out, tuple(s))
        except ValueError:
            raise ValueError(f"{name} has batch shape {tuple(s)}, which does not broadcast "
                             f"with the batch shape {out} of {', '.join(seen)}") from None
        seen.append(name)
    return tuple(out)


def check_indices(name: str, value, *, length: int | None, hi: int | None = None,
                  match: str | None = None) -> np.ndarray:
    """A 1-d integer array of ``length`` (any if None) entries in ``[0, hi)``.

    Integral floats are accepted; booleans are not indices.
    """
    a = np.asarray(value)
    if a.ndim != 1 or (length is not None and a.shape != (length,)):
        length = "S" if length is None else length
        raise ValueError(f"{name} must have shape ({length},)"
                         + (f" to match {match}" if match else "") + f", got {a.shape}")
    if a.dtype.kind == "b" or a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be an integer array, got dtype {a.dtype}")
    if a.dtype.kind == "f" and not np.all(np.isfinite(a) & (a == np.round(a))):
        raise ValueError(f"{name} must hold integers")
    a = a.astype(int)
    if a.size and (a.min() < 0 or (hi is not None and a.max() >= hi)):
        rng = f"[0, {hi})" if hi is not None else ">= 0"
        raise ValueError(f"{name} entries must be in {rng}, got {a.min()}..{a.max()}")
    return a


def check_mask(name: str, value, *, length: int, match: str | None = None) -> np.ndarray:
    """A 1-d boolean array of ``length`` entries (0/1 integers accepted)."""
    a = np.asarray(value)
    if a.shape != (length,):
        raise ValueError(f"{name} must have shape ({length},)"
                         + (f" to match {match}" if match else "") + f", got {a.shape}")
    if a.dtype.kind != "b":
        if a.dtype.kind not in "iuf" or not np.all((a == 0) | (a == 1)):
            raise ValueError(f"{name} must be a boolean array (or 0/1), got {a!r}")
    return a.astype(bool)


def check_int_array(name: str, value) -> np.ndarray:
    """An integer array of any shape (integral floats accepted, booleans not)."""
    a = np.asarray(value)
    if a.dtype.kind not in "iuf":
        raise ValueError(f"{name} must be an integer array, got dtype {a.dtype}")
    if a.dtype.kind == "f":
        if not np.all(np.isfinite(a) & (a == np.round(a))):
            raise ValueError(f"{name} must hold integers")
        a = a.astype(int)
    return a
