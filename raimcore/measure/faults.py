"""Fault injection: step and ramp biases on any set of satellites."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..schema import Key, SchemaError, coerce_float

__all__ = ["Fault", "fault_biases", "parse_fault"]

FAULT_KINDS = ("step", "ramp")
#: Largest step bias (m) and ramp rate (m/s) a fault may have: far beyond any real
#: satellite fault (a 1e308 m bias would overflow the statistics to inf / NaN).
MAX_BIAS_M = 1.0e7
MAX_RATE_MPS = 1.0e5
#: The keys of a fault in a scenario file.
FAULT_FIELDS = ("sat", "kind", "t0_s", "t1_s", "bias_m", "rate_mps")


def _is_inf(x) -> bool:
    return isinstance(x, float | int) and not isinstance(x, bool) and x == math.inf


def _t1(name: str, value) -> float:
    """A fault end: a finite time in seconds, or ``inf`` (until the end of the run)."""
    if _is_inf(value):
        return math.inf
    return coerce_float(name, value, unit="s")


#: The keys of one fault (a ``[[faults]]`` table), declared once: :class:`Fault` checks
#: its values with them and the dashboard's fault editor is built from them.
FAULT_KEYS: dict[str, Key] = {
    "kind": Key("kind", "choice", "step", "step: a constant bias; ramp: a growing one",
                choices=FAULT_KINDS, group="faults"),
    "bias_m": Key("bias_m", "float", 0.0, "step fault bias (negative: shorter range)",
                  unit="m", lo=-MAX_BIAS_M, hi=MAX_BIAS_M, ui_lo=-500.0, ui_hi=500.0,
                  ui_step=1.0, group="faults"),
    "rate_mps": Key("rate_mps", "float", 0.0, "ramp fault rate (negative: shrinking range)",
                    unit="m/s", lo=-MAX_RATE_MPS, hi=MAX_RATE_MPS, ui_lo=-20.0, ui_hi=20.0,
                    ui_step=0.1, group="faults"),
    "t0_s": Key("t0_s", "float", 0.0, "fault start (run time)", unit="s", group="faults"),
    "t1_s": Key("t1_s", "custom", math.inf, "fault end (run time); inf or absent: until the "
                "end of the run", unit="s", parse=_t1, allowed_text="number or inf",
                group="faults"),
}


@dataclass(frozen=True)
class Fault:
    """One satellite fault.

    A step adds ``bias_m`` for ``t0_s <= t < t1_s``; a ramp adds ``rate_mps * (t - t0_s)``
    for ``t >= t0_s`` (until ``t1_s`` when given; spec, notation). ``t1_s = inf`` means
    "until the end".
    """

    sat: str
    kind: str = "step"
    t0_s: float = 0.0
    t1_s: float = math.inf
    bias_m: float = 0.0
    rate_mps: float = 0.0

    def __post_init__(self):
        if not isinstance(self.sat, str) or not self.sat.strip():
            raise SchemaError(f"fault sat must be a satellite name such as 'G10', got "
                              f"{self.sat!r}")
        for name, k in FAULT_KEYS.items():
            where = "fault kind" if name == "kind" else f"fault {self.sat} {name}"
            object.__setattr__(self, name, k.coerce(getattr(self, name), where))
        if self.t1_s <= self.t0_s:
            raise SchemaError(f"fault {self.sat} t1_s must be after t0_s ({self.t0_s:g} s), "
                              f"got {self.t1_s:g}")

    def bias_at(self, t_s) -> np.ndarray:
        """Bias (m) of this fault at times ``t_s`` (array)."""
        t = np.asarray(t_s, dtype=float)
        active = (t >= self.t0_s) & (t < self.t1_s)
        if self.kind == "step":
            return np.where(active, self.bias_m, 0.0)
        return np.where(active, self.rate_mps * (t - self.t0_s), 0.0)

    @classmethod
    def from_dict(cls, d, where: str = "faults") -> Fault:
        """A fault from a scenario file's table (``sat``, ``kind``, ``t0_s``, ``t1_s``,
        ``bias_m`` or ``rate_mps``), every key checked."""
        if isinstance(d, Fault):
            return d
        if not isinstance(d, dict):
            raise SchemaError(f"{where} must be a table such as {{sat = \"G10\", kind = "
                              f"\"step\", bias_m = 50, t0_s = 100}}, got {d!r}")
        unknown = [k for k in d if k not in FAULT_FIELDS]
        if unknown:
            raise SchemaError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}; "
                              f"allowed: {', '.join(FAULT_FIELDS)}")
        if "sat" not in d:
            raise SchemaError(f"{where}: missing sat (the satellite name, e.g. \"G10\")")
        kind = d.get("kind", "step")
        wrong = "rate_mps" if kind == "step" else "bias_m"
        if wrong in d:
            raise SchemaError(f"{where}: a {kind} fault takes "
                              f"{'bias_m' if kind == 'step' else 'rate_mps'}, not {wrong}")
        return cls(**d)

    def to_dict(self) -> dict:
        d = {"sat": self.sat, "kind": self.kind, "t0_s": self.t0_s}
        if math.isfinite(self.t1_s):
            d["t1_s"] = self.t1_s
        d["bias_m" if self.kind == "step" else "rate_mps"] = (
            self.bias_m if self.kind == "step" else self.rate_mps)
        return d


def fault_biases(faults, t_s, sat_names) -> np.ndarray:
    """Sum of all faults as an ``(E, S)`` bias array (m); faults on absent satellites raise."""
    t = np.asarray(t_s, dtype=float)
    index = {name: k for k, name in enumerate(sat_names)}
    out = np.zeros((t.shape[0], len(sat_names)))
    for f in faults:
        if f.sat not in index:
            raise ValueError(
                f"fault satellite {f.sat!r} is not in this scenario; choose one of "
                f"{', '.join(sat_names)}")
        out[:, index[f.sat]] += f.bias_at(t)
    return out


def parse_fault(text: str) -> Fault:
    """Parse the CLI form ``SAT,step,BIAS_M,T0_S[,T1_S]`` or ``SAT,ramp,RATE_MPS,T0_S[,T1_S]``."""
    parts = [p.strip() for p in text.split(",")]
    usage = ("--fault must be SAT,step,BIAS_M,T0_S[,T1_S] or SAT,ramp,RATE_MPS,T0_S[,T1_S], "
             f"got {text!r}")
    if len(parts) not in (4, 5) or parts[1] not in FAULT_KINDS:
        raise ValueError(usage)
    try:
        nums = [float(p) for p in parts[2:]]
    except ValueError:
        raise ValueError(usage) from None
    t1 = nums[2] if len(nums) == 3 else math.inf
    if parts[1] == "step":
        return Fault(parts[0], "step", t0_s=nums[1], t1_s=t1, bias_m=nums[0])
    return Fault(parts[0], "ramp", t0_s=nums[1], t1_s=t1, rate_mps=nums[0])
