"""Fault injection: step and ramp biases on satellites, or on a whole constellation.

A *satellite fault* (``sat = "G10"``) adds its bias to that satellite's pseudorange.

A *constellation fault* (``sat`` a system key: ``"GPS"``, ``"BDS"``, ``"GAL"``, ``"GLO"``)
acts on every satellite of that system at once (a ground-segment fault, ARAIM's
``P_const`` event): each of its satellites gets the fault's bias times ``sin(el)``, its
elevation, which is the range error of the constellation's orbits displaced by the bias
along the receiver's vertical (first order: ``u . up = sin(el)`` for a line of sight
``u``). Why not the same bias on every satellite: each system has its own receiver clock
(:func:`raimcore.lsq.clock_columns`), so a bias common to a constellation is absorbed by
that clock (an inter-system bias): it moves no position and no test can see it. The
``sin(el)`` profile has a common part (absorbed) and a part that differs between
satellites: a constellation alone still fits it exactly (it reads as a vertical error of
the bias), another constellation disagrees, which is what an ARAIM constellation mode or
a multi-constellation RAIM detects.

Scenario files write a constellation fault as a satellite fault whose ``sat`` is the
system key, ``{sat = "GAL", kind = "step", bias_m = 20, t0_s = 300}`` (the canonical
form, written back by :meth:`Fault.to_dict`), or as ``{kind = "constellation", system =
"GAL", shape = "step", bias_m = 20, t0_s = 300}``; the command line as
``--fault GAL,step,20,300``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..schema import Key, SchemaError, coerce_float, did_you_mean
from ..sky.constellations import SYSTEM_PREFIX

__all__ = ["Fault", "fault_biases", "fault_bias", "fault_columns", "parse_fault",
           "SYSTEM_KEYS"]

FAULT_KINDS = ("step", "ramp")
#: The system keys a constellation fault may name (the scenario's ``systems`` keys).
SYSTEM_KEYS = tuple(SYSTEM_PREFIX)
#: Largest step bias (m) and ramp rate (m/s) a fault may have: far beyond any real
#: satellite fault (a 1e308 m bias would overflow the statistics to inf / NaN).
MAX_BIAS_M = 1.0e7
MAX_RATE_MPS = 1.0e5
#: The keys of a fault in a scenario file.
FAULT_FIELDS = ("sat", "kind", "t0_s", "t1_s", "bias_m", "rate_mps")
#: The keys of the other spelling of a constellation fault (``kind = "constellation"``).
CONSTELLATION_FIELDS = ("kind", "system", "shape", "t0_s", "t1_s", "bias_m", "rate_mps")


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
    """One satellite or constellation fault.

    A step adds ``bias_m`` for ``t0_s <= t < t1_s``; a ramp adds ``rate_mps * (t - t0_s)``
    for ``t >= t0_s`` (until ``t1_s`` when given; spec, notation). ``t1_s = inf`` means
    "until the end".

    ``sat`` is a satellite name (``"G10"``) or a system key (``"GAL"``): a constellation
    fault, on every satellite of the system, each by that bias times the sine of its
    elevation (see the module docstring for why).
    """

    sat: str
    kind: str = "step"
    t0_s: float = 0.0
    t1_s: float = math.inf
    bias_m: float = 0.0
    rate_mps: float = 0.0

    def __post_init__(self):
        if not isinstance(self.sat, str) or not self.sat.strip():
            raise SchemaError(f"fault sat must be a satellite name such as 'G10' or a "
                              f"system key ({', '.join(SYSTEM_KEYS)}), got {self.sat!r}")
        if self.sat.isalpha() and self.sat not in SYSTEM_KEYS:
            raise SchemaError(
                f"fault {self.sat}: {self.sat!r} is neither a satellite name such as 'G10' "
                f"nor a system key ({', '.join(SYSTEM_KEYS)}) for a constellation fault"
                f"{did_you_mean(self.sat.upper(), SYSTEM_KEYS)}")
        if self.kind == "constellation":
            raise SchemaError(
                f"fault {self.sat}: kind 'constellation' is a scenario file's spelling "
                f"({{kind = \"constellation\", system = ..., shape = \"step\"}}); here "
                f"give the system as sat and step or ramp as kind")
        for name, k in FAULT_KEYS.items():
            where = "fault kind" if name == "kind" else f"fault {self.sat} {name}"
            object.__setattr__(self, name, k.coerce(getattr(self, name), where))
        if self.t1_s <= self.t0_s:
            raise SchemaError(f"fault {self.sat} t1_s must be after t0_s ({self.t0_s:g} s), "
                              f"got {self.t1_s:g}")

    @property
    def system(self) -> str | None:
        """The system key of a constellation fault (``"GAL"``), None for a satellite's."""
        return self.sat if self.sat in SYSTEM_KEYS else None

    @property
    def target(self) -> str:
        """What the fault acts on, for messages: ``"G10"`` or ``"GAL (constellation)"``."""
        return f"{self.sat} (constellation)" if self.system else self.sat

    def bias_at(self, t_s) -> np.ndarray:
        """Bias (m) of this fault at times ``t_s`` (array): a satellite's, or a
        constellation's at the zenith (its satellites get it times ``sin(el)``)."""
        t = np.asarray(t_s, dtype=float)
        active = (t >= self.t0_s) & (t < self.t1_s)
        if self.kind == "step":
            return np.where(active, self.bias_m, 0.0)
        return np.where(active, self.rate_mps * (t - self.t0_s), 0.0)

    @classmethod
    def from_dict(cls, d, where: str = "faults") -> Fault:
        """A fault from a scenario file's table, every key checked: ``sat``, ``kind``
        (step or ramp), ``t0_s``, ``t1_s``, ``bias_m`` or ``rate_mps``; or a constellation
        fault as ``kind = "constellation"``, ``system``, ``shape`` (step or ramp) and the
        same times and size."""
        if isinstance(d, Fault):
            return d
        if not isinstance(d, dict):
            raise SchemaError(f"{where} must be a table such as {{sat = \"G10\", kind = "
                              f"\"step\", bias_m = 50, t0_s = 100}}, got {d!r}")
        if d.get("kind") == "constellation":
            return cls._from_constellation_table(d, where)
        unknown = [k for k in d if k not in FAULT_FIELDS]
        if unknown:
            raise SchemaError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}; "
                              f"allowed: {', '.join(FAULT_FIELDS)} (a constellation fault: "
                              f"sat = a system key, or kind = \"constellation\" with "
                              f"system and shape)")
        if "sat" not in d:
            raise SchemaError(f"{where}: missing sat (the satellite name, e.g. \"G10\", or "
                              f"a system key such as \"GAL\" for a constellation fault)")
        kind = d.get("kind", "step")
        _check_size_key(d, kind, where)
        return cls(**d)

    @classmethod
    def _from_constellation_table(cls, d: dict, where: str) -> Fault:
        """``{kind = "constellation", system = "GAL", shape = "step", ...}`` as the fault
        ``Fault("GAL", "step", ...)``."""
        unknown = [k for k in d if k not in CONSTELLATION_FIELDS]
        if unknown:
            raise SchemaError(f"{where}: unknown key(s) {', '.join(map(str, unknown))} in a "
                              f"constellation fault; allowed: "
                              f"{', '.join(CONSTELLATION_FIELDS)}")
        system = d.get("system")
        if system is None:
            raise SchemaError(f"{where}: a constellation fault needs system (one of "
                              f"{', '.join(SYSTEM_KEYS)})")
        if system not in SYSTEM_KEYS:
            raise SchemaError(f"{where}: constellation fault system must be one of "
                              f"{', '.join(SYSTEM_KEYS)}, got {system!r}"
                              f"{did_you_mean(str(system).upper(), SYSTEM_KEYS)}")
        shape = d.get("shape", "step")
        if shape not in FAULT_KINDS:
            raise SchemaError(f"{where}: constellation fault {system} shape must be "
                              f"{' or '.join(FAULT_KINDS)}, got {shape!r}")
        _check_size_key(d, shape, where)
        rest = {k: v for k, v in d.items() if k not in ("kind", "system", "shape")}
        return cls(sat=system, kind=shape, **rest)

    def to_dict(self) -> dict:
        d = {"sat": self.sat, "kind": self.kind, "t0_s": self.t0_s}
        if math.isfinite(self.t1_s):
            d["t1_s"] = self.t1_s
        d["bias_m" if self.kind == "step" else "rate_mps"] = (
            self.bias_m if self.kind == "step" else self.rate_mps)
        return d


def _check_size_key(d: dict, kind, where: str) -> None:
    """A step takes ``bias_m``, a ramp ``rate_mps``: the other one is refused."""
    wrong = "rate_mps" if kind == "step" else "bias_m"
    if wrong in d:
        raise SchemaError(f"{where}: a {kind} fault takes "
                          f"{'bias_m' if kind == 'step' else 'rate_mps'}, not {wrong}")


def fault_columns(fault: Fault, sat_names, sat_systems=None) -> np.ndarray:
    """Indices of the satellites ``fault`` acts on: its satellite, or every satellite of
    its system (``sat_systems`` (S,): the system key of each satellite; needed for a
    constellation fault). A satellite fault on an absent satellite raises ValueError; a
    constellation without satellite here gives no index (the fault never acts)."""
    if fault.system is None:
        names = list(sat_names)
        if fault.sat not in names:
            raise ValueError(f"fault satellite {fault.sat!r} is not in this scenario; "
                             f"choose one of {', '.join(names)}")
        return np.array([names.index(fault.sat)])
    if sat_systems is None:
        raise ValueError(f"constellation fault {fault.sat}: the system of each satellite "
                         "(sat_systems) is needed")
    return np.flatnonzero(np.asarray(sat_systems) == fault.system)


def fault_bias(fault: Fault, t_s, sat_names, sat_systems=None, el_rad=None) -> np.ndarray:
    """The ``(E, S)`` bias (m) of one fault at times ``t_s`` (E,).

    A satellite fault's column is :meth:`Fault.bias_at`; a constellation fault gives each
    satellite of its system ``bias_at(t) * sin(el)`` (``el_rad`` (E, S), needed then;
    0 where the elevation is not finite)."""
    t = np.asarray(t_s, dtype=float)
    cols = fault_columns(fault, sat_names, sat_systems)
    out = np.zeros((t.shape[0], len(sat_names)))
    b = fault.bias_at(t)
    if fault.system is None:
        out[:, cols[0]] = b
        return out
    if el_rad is None:
        raise ValueError(f"constellation fault {fault.sat}: the satellites' elevations "
                         "(el_rad) are needed")
    el = np.asarray(el_rad, dtype=float)[:, cols]
    # The orbits displaced by b along the receiver's vertical: u . up = sin(el).
    out[:, cols] = b[:, None] * np.where(np.isfinite(el), np.sin(el), 0.0)
    return out


def fault_biases(faults, t_s, sat_names, sat_systems=None, el_rad=None) -> np.ndarray:
    """Sum of all faults as an ``(E, S)`` bias array (m) (:func:`fault_bias`); faults on
    absent satellites raise, a constellation absent from ``sat_systems`` adds nothing."""
    t = np.asarray(t_s, dtype=float)
    out = np.zeros((t.shape[0], len(sat_names)))
    for f in faults:
        out += fault_bias(f, t, sat_names, sat_systems, el_rad)
    return out


def parse_fault(text: str) -> Fault:
    """Parse the CLI form ``SAT,step,BIAS_M,T0_S[,T1_S]`` or ``SAT,ramp,RATE_MPS,T0_S[,T1_S]``;
    ``SAT`` may be a system key (``GAL,step,20,300``): a constellation fault."""
    parts = [p.strip() for p in text.split(",")]
    usage = ("--fault must be SAT,step,BIAS_M,T0_S[,T1_S] or SAT,ramp,RATE_MPS,T0_S[,T1_S] "
             f"(SAT a satellite or a system key: {', '.join(SYSTEM_KEYS)}), got {text!r}")
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
