"""Fault injection: step and ramp biases on any set of satellites."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..schema import SchemaError, coerce_float, coerce_str

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
        coerce_str("fault kind", self.kind, FAULT_KINDS)
        set_ = object.__setattr__
        set_(self, "t0_s", coerce_float(f"fault {self.sat} t0_s", self.t0_s, unit="s"))
        t1 = self.t1_s
        if not (_is_inf(t1)):
            t1 = coerce_float(f"fault {self.sat} t1_s", t1, unit="s")
        set_(self, "t1_s", math.inf if _is_inf(t1) else t1)
        set_(self, "bias_m", coerce_float(f"fault {self.sat} bias_m", self.bias_m,
                                          -MAX_BIAS_M, MAX_BIAS_M, unit="m"))
        set_(self, "rate_mps", coerce_float(f"fault {self.sat} rate_mps", self.rate_mps,
                                            -MAX_RATE_MPS, MAX_RATE_MPS, unit="m/s"))
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
