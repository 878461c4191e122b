"""One typed schema for every user-settable value: scenario keys and algorithm options.

A :class:`Key` declares a value once: its name, type, default, unit, allowed range or
choices and a one-line help. Everything else is derived from it: validation and coercion
(:meth:`Key.coerce`, used by :class:`~raimcore.scenario.Scenario` before any simulation),
TOML files and ``--set`` (same coercion), the dashboard controls (range, step, dropdown
choices), Monte Carlo defaults, ``raim list`` / ``raim keys`` and the README's key table.

Scenario keys are declared on the :class:`~raimcore.scenario.Scenario` dataclass itself
(``sigma_m: float = key(...)``); algorithm options in each algorithm's module
(``options=(option("max_exclusions", int, 1, ...),)``).

Rules, the same everywhere: booleans are not numbers, numbers are finite, integers are
whole (``3.0`` is accepted as 3, ``3.5`` is not), numpy scalars are accepted as Python
numbers, strings are not split into characters, containers hold the right types.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Key", "SchemaError", "key", "option", "did_you_mean", "is_input_error", "coerce_float",
           "coerce_int", "coerce_bool", "coerce_str"]

#: Value kinds a :class:`Key` may have.
KINDS = ("float", "int", "bool", "str", "choice", "choices", "strings", "float_or_auto",
         "custom")


class SchemaError(ValueError):
    """A value that the schema refuses; the message names the key, the value and what is
    allowed. A :class:`ValueError`, so callers that catch those keep working."""


def _show(value) -> str:
    """A short printable form of a user value for error messages."""
    if isinstance(value, np.generic):
        value = value.item()
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def is_input_error(exc: BaseException) -> bool:
    """True when ``exc`` is a refused input: a :class:`SchemaError`, or a ``ValueError``
    raised by RAIM Studio's own code (``raimcore`` or ``app``: a checked value); False when
    it comes from inside numpy, scipy or the standard library (a bug, whose traceback is
    wanted). The command line and the dashboard draw the line here."""
    if isinstance(exc, SchemaError):
        return True
    if not isinstance(exc, ValueError):
        return False
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    if tb is None:
        return True
    from pathlib import Path

    core = Path(__file__).resolve().parent
    where = Path(tb.tb_frame.f_code.co_filename).resolve()
    return core in where.parents or (core.parent / "app") in where.parents


def did_you_mean(name: str, candidates: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest candidate, or ``""``."""
    close = difflib.get_close_matches(name, list(candidates), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _is_number(value) -> bool:
    return (isinstance(value, int | float | np.integer | np.floating)
            and not isinstance(value, bool | np.bool_))


def coerce_float(name: str, value, lo: float | None = None, hi: float | None = None, *,
                 lo_open: bool = False, hi_open: bool = False, unit: str = "") -> float:
    """``value`` as a finite float within the bounds, or :class:`SchemaError`."""
    allowed = _interval(lo, hi, lo_open, hi_open, unit)
    if not _is_number(value):
        raise SchemaError(f"{name} must be a number{allowed}, got {_show(value)}")
    x = float(value)
    if not math.isfinite(x):
        raise SchemaError(f"{name} must be a finite number{allowed}, got {_show(value)}")
    if (lo is not None and (x < lo or (lo_open and x == lo))) or \
            (hi is not None and (x > hi or (hi_open and x == hi))):
        raise SchemaError(f"{name} must be{allowed or ' in range'}, got {_show(value)}")
    return x


def coerce_int(name: str, value, lo: int | None = None, hi: int | None = None) -> int:
    """``value`` as an int within the bounds (a whole float such as 3.0 is accepted)."""
    allowed = _interval(lo, hi, False, False, "")
    if not _is_number(value):
        raise SchemaError(f"{name} must be an integer{allowed}, got {_show(value)}")
    if isinstance(value, float | np.floating):
        if not (math.isfinite(value) and float(value).is_integer()):
            raise SchemaError(f"{name} must be an integer{allowed}, got {_show(value)}")
    v = int(value)
    if (lo is not None and v < lo) or (hi is not None and v > hi):
        raise SchemaError(f"{name} must be an integer{allowed}, got {_show(value)}")
    return v


def coerce_bool(name: str, value) -> bool:
    """``value`` if it is a boolean (``true``/``false``; not 0/1, not a string)."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    raise SchemaError(f"{name} must be true or false, got {_show(value)}")


def coerce_str(name: str, value, choices: Sequence[str] | None = None) -> str:
    """``value`` if it is a string (and one of ``choices`` when given)."""
    if not isinstance(value, str):
        want = f"one of {', '.join(choices)}" if choices else "a string"
        raise SchemaError(f"{name} must be {want}, got {_show(value)}")
    if choices is not None and value not in choices:
        raise SchemaError(f"{name} must be one of {', '.join(choices)}; got {_show(value)}"
                          + did_you_mean(value, choices))
    return value


def _num(x) -> str:
    """A bound as typed: integers in full (4294967295, not 4.29497e+09)."""
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e15 else f"{x:g}"


def _interval(lo, hi, lo_open, hi_open, unit) -> str:
    u = f" {unit}" if unit and unit not in ("1",) else ""
    if lo is None and hi is None:
        return ""
    if hi is None:
        return f" {'>' if lo_open else '>='} {_num(lo)}{u}"
    if lo is None:
        return f" {'<' if hi_open else '<='} {_num(hi)}{u}"
    return f" in {'(' if lo_open else '['}{_num(lo)}, {_num(hi)}{')' if hi_open else ']'}{u}"


@dataclass(frozen=True)
class Key:
    """One user-settable value.

    Attributes
    ----------
    name : the key (``sigma_m``); scenario files, ``--set`` and the dashboard use it.
    kind : one of :data:`KINDS`: ``float``, ``int``, ``bool``, ``str``, ``choice`` (one of
        ``choices``), ``choices`` (a list of ``choices``), ``strings`` (a list of strings),
        ``float_or_auto`` (a number or the string ``"auto"``), ``custom`` (``parse`` does
        the work).
    default : the default value (already of the key's type).
    help : one line for ``--help``, ``raim keys``, tooltips and the README.
    unit : SI unit or ``deg`` (``""`` when unitless).
    lo, hi, lo_open, hi_open : allowed interval of numbers (None: unbounded).
    choices : allowed strings (``choice`` and ``choices``).
    group : where the key belongs (``receiver``, ``measurements``, an algorithm name, ...).
    ui_lo, ui_hi, ui_step : the dashboard control's usual range and step; a value outside
        widens the control, never clipped.
    parse : for ``custom`` keys, ``parse(name, value) -> value`` (raises SchemaError).
    allowed_text : what a ``custom`` key allows, in words (for ``raim keys`` and the docs).
    """

    name: str
    kind: str
    default: Any
    help: str
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple[str, ...] = ()
    group: str = ""
    ui_lo: float | None = None
    ui_hi: float | None = None
    ui_step: float | None = None
    parse: Callable[[str, Any], Any] | None = None
    allowed_text: str = ""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"key {self.name!r}: kind must be one of {', '.join(KINDS)}")
        if self.kind == "custom" and self.parse is None:
            raise ValueError(f"key {self.name!r}: a custom key needs parse")

    def coerce(self, value, name: str | None = None):
        """``value`` checked and converted to this key's type, or :class:`SchemaError`
        naming the key (``name`` overrides the key's name in the message)."""
        n = name or self.name
        k = self.kind
        if k == "float":
            return coerce_float(n, value, self.lo, self.hi, lo_open=self.lo_open,
                                hi_open=self.hi_open, unit=self.unit)
        if k == "int":
            return coerce_int(n, value, self.lo, self.hi)
        if k == "bool":
            return coerce_bool(n, value)
        if k == "str":
            return coerce_str(n, value)
        if k == "choice":
            return coerce_str(n, value, self.choices)
        if k in ("choices", "strings"):
            items = _as_list(n, value, "a list of strings")
            out = []
            for i, item in enumerate(items):
                if not isinstance(item, str):
                    raise SchemaError(f"{n}[{i}] must be a string, got {_show(item)}")
                if k == "choices":
                    coerce_str(f"{n}[{i}]", item, self.choices)
                out.append(item)
            return tuple(out)
        if k == "float_or_auto":
            if isinstance(value, str) and value.strip().lower() == "auto":
                return "auto"
            if not _is_number(value):
                raise SchemaError(f"{n} must be \"auto\" or a finite number, got {_show(value)}")
            return coerce_float(n, value, self.lo, self.hi, unit=self.unit)
        return self.parse(n, value)

    @property
    def allowed(self) -> str:
        """What this key allows, in words (for messages, ``raim keys`` and the README)."""
        k = self.kind
        if self.allowed_text:
            return self.allowed_text
        if k == "float":
            return "number" + _interval(self.lo, self.hi, self.lo_open, self.hi_open, "")
        if k == "int":
            return "integer" + _interval(self.lo, self.hi, False, False, "")
        if k == "bool":
            return "true / false"
        if k == "choice":
            return " | ".join(self.choices)
        if k == "choices":
            return "list of " + " | ".join(self.choices)
        if k == "strings":
            return "list of strings"
        if k == "float_or_auto":
            return '"auto" or number'
        if k == "str":
            return "string"
        return "see help"


def _as_list(name: str, value, what: str) -> list:
    if isinstance(value, str) or not isinstance(value, Sequence | np.ndarray):
        raise SchemaError(f"{name} must be {what}, got {_show(value)}")
    return list(value)


_KIND_OF_TYPE = {float: "float", int: "int", bool: "bool", str: "str"}


def option(name: str, kind, default, help: str, **kw) -> Key:  # noqa: A002 - numpydoc name
    """An algorithm option: a :class:`Key` (``kind`` may be a Python type: ``float``,
    ``int``, ``bool``, ``str``). The default is checked against the key itself."""
    kind = _KIND_OF_TYPE.get(kind, kind)
    k = Key(name=name, kind=kind, default=default, help=help, **kw)
    if k.coerce(default) != default:  # a default the key would change is a declaration bug
        raise ValueError(f"option {name!r}: default {default!r} is not of its own type")
    return k


def key(default, help: str, kind=None, **kw) -> dataclasses.Field:  # noqa: A002
    """A dataclass field that carries its :class:`Key` (the name is the field's own,
    filled in by :func:`keys_of`)."""
    kind = kind or _KIND_OF_TYPE[type(default)]
    meta = {"key": dict(kind=kind, default=default, help=help, **kw)}
    if isinstance(default, list | dict):
        raise TypeError("use a tuple default for container keys")
    return dataclasses.field(default=default, metadata=meta)


def keys_of(cls) -> dict[str, Key]:
    """The :class:`Key` of every field of dataclass ``cls`` declared with :func:`key`."""
    out = {}
    for f in dataclasses.fields(cls):
        spec = f.metadata.get("key")
        if spec is not None:
            out[f.name] = Key(name=f.name, **spec)
    return out
