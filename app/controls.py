"""Dashboard controls made from the schema: one :class:`KeyControl` per value a user sets.

Every control is built from its :class:`~raimcore.schema.Key` (the one declaration of the
value's type, default, unit, range, choices and help), never from numbers written here:

==================  =====================================================================
key                 control
==================  =====================================================================
``bool``            checkbox
``choice``          dropdown of ``Key.choices``
``int``, ``float``  slider over ``ui_lo..ui_hi`` (step ``ui_step``) when the key gives its
                    usual range; a slider over ``lo..hi`` when that range is short (an int
                    range of at most :data:`SLIDER_MAX_STEPS` values, a closed float
                    range of width at most 1); a text box for an open unit interval
                    (probabilities are typed, ``1e-5``: a number box shows at most 7
                    decimals, so 2.8e-9 would read 0); otherwise a number box
anything else       text box (``float_or_auto``: ``auto`` or a number)
==================  =====================================================================

Rules, the same for every control:

- a value outside a slider's range *widens the slider* to include it; it is never clipped
  (a new scenario brings back the usual range, widened to its values);
- reading a control the user did not move gives back exactly the value it was shown
  (:meth:`KeyControl.read`), so a control that cannot show a value (a lossy display such as
  the fault editor's "until the end") never rewrites it;
- a value the user types is checked by the key (:meth:`raimcore.schema.Key.coerce`) and
  refused with a one-line :class:`~raimcore.schema.SchemaError` naming the key.

The fault editor's keys are :data:`raimcore.measure.faults.FAULT_KEYS`, the ones
:class:`~raimcore.measure.faults.Fault` validates its values with.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from raimcore.measure.faults import FAULT_KEYS
from raimcore.schema import Key

__all__ = ["KeyControl", "control_kind", "FAULT_KEYS", "SLIDER_MAX_STEPS", "label_of"]

#: An int key whose whole range holds at most this many values is a slider.
SLIDER_MAX_STEPS = 100
#: Steps of a slider over a closed float range without a declared step.
FLOAT_SLIDER_STEPS = 100
#: Most decimals a slider or number box is asked to show (its `precision`).
MAX_DECIMALS = 12


def control_kind(key: Key) -> str:
    """Which control shows ``key``: ``checkbox``, ``dropdown``, ``slider``, ``number`` or
    ``text`` (the rules of the module docstring)."""
    if key.kind == "bool":
        return "checkbox"
    if key.kind == "choice":
        return "dropdown"
    if key.kind not in ("int", "float"):
        return "text"
    if key.ui_lo is not None and key.ui_hi is not None:
        return "slider"
    bounded = key.lo is not None and key.hi is not None
    if key.kind == "int":
        return "slider" if bounded and key.hi - key.lo <= SLIDER_MAX_STEPS else "number"
    if bounded and key.hi - key.lo <= 1.0:
        return "text" if (key.lo_open or key.hi_open) else "slider"
    return "number"


def label_of(key: Key, title: str | None = None) -> str:
    """A control's label: ``title`` (default: the key's name) and the unit."""
    text = title or key.name
    return f"{text} ({key.unit})" if key.unit and key.unit != "1" else text


def _hint(key: Key) -> str:
    """The tooltip: the key's help, then what it allows (``sigma_m: number in (0, 1e4] m``)."""
    allowed = key.allowed
    if allowed == "see help":
        return key.help
    bounded = key.kind in ("int", "float") and (key.lo is not None or key.hi is not None)
    unit = f" {key.unit}" if bounded and key.unit and key.unit != "1" else ""
    return f"{key.help}. {key.name}: {allowed}{unit}"


def _decimals(x: float) -> int:
    """Decimals needed to show ``x`` exactly (at most :data:`MAX_DECIMALS`)."""
    if not math.isfinite(x):
        return 0
    d = 0
    while d < MAX_DECIMALS and x != round(x, d):
        d += 1
    return d


def _text_of(value) -> str:
    """A value as text that parses back to itself (``repr`` of floats round-trips)."""
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, tuple | list):  # a list of names: "GPS, GAL"
        return ", ".join(str(v) for v in value)
    return str(value)


def _parse_text(key: Key, text: str):
    """A text box's value as the key's type (before the key checks it)."""
    t = text.strip()
    if key.kind == "float_or_auto" and t.lower() == "auto":
        return "auto"
    if key.kind in ("int", "float", "float_or_auto"):
        for conv in ((int, float) if key.kind == "int" else (float,)):
            try:
                return conv(t)
            except ValueError:
                continue
    if key.kind in ("choices", "strings"):  # "GPS, GAL" (commas or spaces)
        return [w for w in t.replace(",", " ").split() if w]
    return t


class KeyControl:
    """One GUI control for one :class:`~raimcore.schema.Key`.

    Parameters
    ----------
    gui : viser GUI API (``client.gui``); the control is created in its current container.
    key : the value's declaration.
    value : the value shown first (already valid).
    title : the label without unit (default: the key's name).
    name : how messages name the value (default: the key's name; a fault's field says
        which fault, ``"fault G10 bias_m"``).
    encode, decode : for lossy displays, value -> handle value and back (the fault end:
        ``inf`` shown at the slider's right end).
    control : the control's kind when the key alone does not say (a ``custom`` key shown
        as a ``"slider"`` over ``ui_lo..ui_hi``).

    Attributes
    ----------
    handle : the viser handle.
    value : the value the control stands for (the scenario's, not necessarily the one it
        can show).
    """

    def __init__(self, gui, key: Key, value, *, title: str | None = None,
                 name: str | None = None, hint: str | None = None,
                 encode: Callable[[Any], Any] | None = None,
                 decode: Callable[[Any], Any] | None = None,
                 control: str | None = None) -> None:
        self.key = key
        self.name = name or key.name
        self.kind = control or control_kind(key)
        self.value = value
        self._encode = encode
        self._decode = decode
        label = label_of(key, title)
        hint = hint or _hint(key)
        shown = self._shown_of(value)
        if self.kind == "checkbox":
            self.handle = gui.add_checkbox(label, bool(shown), hint=hint)
        elif self.kind == "dropdown":
            self.handle = gui.add_dropdown(label, key.choices, initial_value=shown, hint=hint)
        elif self.kind == "slider":
            self._ui = self._usual_range()
            lo, hi = self._range_with(shown)
            self.handle = gui.add_slider(label, lo, hi, self._ui[2], shown, hint=hint)
            self._set_precision(shown)
        elif self.kind == "number":
            num = int if key.kind == "int" else float
            closed_lo = key.lo if key.lo is not None and not key.lo_open else None
            closed_hi = key.hi if key.hi is not None and not key.hi_open else None
            self.handle = gui.add_number(
                label, shown, min=None if closed_lo is None else num(closed_lo),
                max=None if closed_hi is None else num(closed_hi),
                step=num(key.ui_step) if key.ui_step else (1 if key.kind == "int" else None),
                hint=hint)
            self._set_precision(shown)
        else:
            self.handle = gui.add_text(label, shown, hint=hint)
        self._shown = self.handle.value

    # -- ranges -------------------------------------------------------------------------
    def _usual_range(self) -> tuple[float, float, float]:
        """The slider's usual (lo, hi, step) from the key."""
        k = self.key
        lo = k.ui_lo if k.ui_lo is not None else k.lo
        hi = k.ui_hi if k.ui_hi is not None else k.hi
        if k.kind == "int":
            return int(lo), int(hi), int(k.ui_step or 1)
        step = k.ui_step or (hi - lo) / FLOAT_SLIDER_STEPS or 1.0
        return float(lo), float(hi), float(step)

    def set_usual_range(self, lo: float, hi: float, step: float | None = None) -> None:
        """Change a slider's usual range (the fault times follow the run's length); the
        value shown stays shown (the range widens to it)."""
        num = int if self.key.kind == "int" else float
        ui = (num(lo), num(hi), num(step if step is not None else self._ui[2]))
        if ui != self._ui:
            self._ui = ui
            self.handle.step = ui[2]
            self.reset_range()

    def reset_range(self) -> None:
        """Back to the usual range, widened to the value shown (a new scenario)."""
        if self.kind == "slider":
            self._set_range(*self._range_with(self.handle.value))

    def _range_with(self, x) -> tuple[float, float]:
        lo, hi, _ = self._ui
        return min(lo, x), max(hi, x)

    def _widen(self, x) -> None:
        """Widen the range to include ``x``: never clipped; never narrowed here (a range
        must not jump under the user's hand)."""
        h = self.handle
        self._set_range(min(h.min, x), max(h.max, x))

    def _set_range(self, lo, hi) -> None:
        h = self.handle
        if h.min != lo:
            h.min = lo
        if h.max != hi:
            h.max = hi

    def _set_precision(self, x) -> None:
        if isinstance(x, float):
            step = float(self.handle.step)
            need = max(_decimals(x), _decimals(step))
            if need != self.handle.precision:
                self.handle.precision = need

    # -- value ---------------------------------------------------------------------------
    def _shown_of(self, value):
        """The handle value that shows ``value``."""
        v = self._encode(value) if self._encode is not None else value
        if self.kind == "text":
            return _text_of(v)
        if self.kind in ("slider", "number"):
            return int(v) if self.key.kind == "int" else float(v)
        return v

    def show(self, value) -> None:
        """Show ``value`` (valid) in the control: a slider widens to include it, a number
        shows every decimal it has. Fires the handle's callbacks: call it while the
        session ignores them (``Session._syncing``)."""
        self.value = value
        shown = self._shown_of(value)
        if self.kind == "slider":
            self._widen(shown)
        if self.kind in ("slider", "number"):
            self._set_precision(shown)
        self.handle.value = shown
        self._shown = self.handle.value

    def read(self):
        """The value the control holds: :attr:`value` while it still shows it, otherwise
        the user's entry, checked by the key (:class:`SchemaError` naming the value)."""
        raw = self.handle.value
        if raw == self._shown:
            return self.value
        if self.kind == "text":
            raw = _parse_text(self.key, raw)
        if self._decode is not None:
            raw = self._decode(raw)
        return self.key.coerce(raw, name=self.name)

    def accept(self, value) -> None:
        """The user's entry became ``value``: remember it as shown."""
        self.value = value
        self._shown = self.handle.value
        if self.kind == "slider":
            self._widen(self._shown)
        if self.kind in ("slider", "number"):
            self._set_precision(self._shown)

    def revert(self) -> None:
        """Show :attr:`value` again after a refused entry."""
        self.show(self.value)

    @property
    def shows_exactly(self) -> bool:
        """True when the handle shows :attr:`value` itself (not an encoding of it)."""
        if self._encode is not None:
            return False
        h = self.handle.value
        if self.kind == "text":
            return _parse_text(self.key, h) == self.value or h == _text_of(self.value)
        return h == self.value

    def remove(self) -> None:
        self.handle.remove()
