"""Fault injection: step and ramp biases on any set of satellites."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .._validate import check_choice

__all__ = ["Fault", "fault_biases", "parse_fault"]

FAULT_KINDS = ("step", "ramp")


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
        check_choice("fault kind", self.kind, FAULT_KINDS)
        if not isinstance(self.sat, str) or not self.sat:
            raise ValueError(f"fault sat must be a satellite name such as 'G10', got {self.sat!r}")
        for name in ("t0_s", "t1_s", "bias_m", "rate_mps"):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or math.isnan(v):
                raise ValueError(f"fault {name} must be a number, got {v!r}")
        if self.t1_s <= self.t0_s:
            raise ValueError(f"fault t1_s must be after t0_s ({self.t0_s}), got {self.t1_s}")
        if math.isinf(self.bias_m) or math.isinf(self.rate_mps) or math.isinf(self.t0_s):
            raise ValueError("fault bias_m, rate_mps and t0_s must be finite")

    def bias_at(self, t_s) -> np.ndarray:
        """Bias (m) of this fault at times ``t_s`` (array)."""
        t = np.asarray(t_s, dtype=float)
        active = (t >= self.t0_s) & (t < self.t1_s)
        if self.kind == "step":
            return np.where(active, self.bias_m, 0.0)
        return np.where(active, self.rate_mps * (t - self.t0_s), 0.0)

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
