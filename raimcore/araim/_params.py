"""The keywords of :func:`raimcore.araim.mhss`, declared once.

Each :class:`Param` carries its default under every rule set it belongs to, its kind
(which fixes validation), its unit, a one-line help and its source. Validation, the
error messages, :func:`defaults` and the documentation are all made from :data:`PARAMS`;
a GUI or CLI can build its controls from it too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

from .._validate import check_int, check_positive, check_probability, check_range

__all__ = ["Param", "PARAMS", "RULES", "defaults", "resolve"]

ADD = "add-v4.2"
B2012 = "blanch-2012"
#: The rule sets of :func:`raimcore.araim.mhss`.
RULES = (ADD, B2012)


@dataclass(frozen=True)
class Param:
    """One keyword of :func:`raimcore.araim.mhss`.

    ``default`` maps each rule set the keyword belongs to onto its default; ``kind`` is
    one of ``"prob"`` (in (0, 1)), ``"prob0"`` (in [0, 1]), ``"pos"`` (> 0), ``"nonneg"``
    (>= 0), ``"count"`` (integer >= 0), ``"bool"`` or ``"array"`` (checked with the inputs).
    """

    name: str
    default: dict
    kind: str
    unit: str
    help: str
    source: str


_BOTH = (ADD, B2012)


def _p(name, add, b2012, kind, unit, help_, source, rules=_BOTH):
    default = {}
    if ADD in rules:
        default[ADD] = add
    if B2012 in rules:
        default[B2012] = b2012
    return Param(name, default, kind, unit, help_, source)


#: Every keyword, with its defaults (ARAIM.md section 10: LPV-200 baseline; B2012).
PARAMS: tuple[Param, ...] = (
    _p("phmi_vert", 9.8e-8, 9.8e-8, "prob", "", "vertical integrity budget PHMI_VERT",
       "ARAIM.md s10; ADD v4.2 Table 2"),
    _p("phmi_hor", 2e-9, 2e-9, "prob", "", "horizontal integrity budget PHMI_HOR",
       "ARAIM.md s10"),
    _p("p_fa_vert", 3.9e-6, 3.9e-6, "prob", "", "vertical false-alarm budget P_FA_VERT",
       "ARAIM.md s10"),
    _p("p_fa_hor", 9e-8, 9e-8, "prob", "", "horizontal false-alarm budget P_FA_HOR",
       "ARAIM.md s10 (MAAST v5 V-ARAIM script: 9e-7)"),
    _p("p_thres", 8e-8, None, "prob", "",
       "integrity risk left to unmonitored modes P_THRES", "ARAIM.md s10", rules=(ADD,)),
    _p("p_thres_sat", None, 4e-8, "prob", "",
       "B2012: threshold for unmonitored satellite faults", "B2012 App. J", rules=(B2012,)),
    _p("p_thres_const", None, 4e-8, "prob", "",
       "B2012: threshold for unmonitored constellation faults", "B2012 App. J",
       rules=(B2012,)),
    _p("fc_thres", 0.01, None, "prob0", "", "fault consolidation ratio FC_THRES",
       "ARAIM.md s4 step 3", rules=(ADD,)),
    _p("p_emt", 1e-5, 1e-5, "prob", "", "probability above which a mode enters the EMT",
       "ARAIM.md s8"),
    _p("tol_pl_m", 5e-2, 5e-2, "pos", "m", "protection-level bisection tolerance TOL_PL",
       "ARAIM.md s7"),
    _p("n_es_int", 1.0, 1.0, "pos", "", "effective independent samples, integrity",
       "ARAIM.md s10 (MAAST v5: 25)"),
    _p("n_es_cont", 1.0, 1.0, "pos", "", "effective independent samples, continuity",
       "ARAIM.md s10 (MAAST v5: 25)"),
    _p("max_pmd", False, False, "bool", "",
       "cap each mode's missed-detection allocation at p_exp/(p_inst N_es,int)",
       "ARAIM.md s7 (MAAST v5: on)"),
    _p("k_acc", 1.96, 1.96, "pos", "", "95 % accuracy multiplier K_acc", "ARAIM.md s10"),
    _p("k_ff", 5.33, 5.33, "pos", "", "fault-free 1e-7 multiplier K_ff", "ARAIM.md s10"),
    _p("p_exc_thres", 1.0, 1.0, "prob0", "",
       "with fde: modes above it are exclusion options (1: none; MAAST H-ARAIM 9e-7)",
       "ARAIM.md s4 step 6"),
    _p("t_exp_over_mfd", 0.0, None, "nonneg", "",
       "exposure tau = T_exp / MFD for every event (p_exp = p (1 + tau))",
       "ARAIM.md s3 (MAAST v5: 150 s / 1 h)", rules=(ADD,)),
    _p("tau_sat", None, None, "array", "", "per-satellite tau (..., n_sat)", "ARAIM.md s3",
       rules=(ADD,)),
    _p("tau_const", None, None, "array", "", "per-constellation tau (..., n_const)",
       "ARAIM.md s3", rules=(ADD,)),
    _p("y", None, None, "array", "m",
       "measured minus predicted pseudoranges (..., n_sat): solution-separation test",
       "ARAIM.md s6"),
    _p("used", None, None, "array", "", "bool (..., n_sat): satellites to use",
       "this module"),
    _p("fde", False, False, "bool", "", "exclusion (section 9): PLs over the candidates",
       "ARAIM.md s9"),
    _p("fde_const", True, True, "bool", "",
       "with fde: constellations with P_const > 1e-7 are candidates (MAAST fde_wf_flag)",
       "ARAIM.md s9"),
    _p("pl_max_iter", 0, 0, "count", "",
       "cap on bisection steps (0: until tol_pl_m; MAAST: 10)", "ARAIM.md s7"),
    _p("return_modes", True, True, "bool", "", "return the per-epoch fault-mode table",
       "this module"),
)

_BY_NAME = {p.name: p for p in PARAMS}


def defaults(rules: str = ADD) -> dict:
    """The default value of every keyword of rule set ``rules``."""
    _check_rules(rules)
    return {p.name: p.default[rules] for p in PARAMS if rules in p.default}


def _check_rules(rules) -> str:
    if rules not in RULES:
        raise ValueError(f"rules must be one of {', '.join(RULES)}; got {rules!r}")
    return rules


def _check_value(p: Param, value):
    if p.kind == "array":
        return value
    if value is None:
        raise ValueError(f"{p.name} must not be None")
    if p.kind == "bool":
        if not isinstance(value, bool) and not (hasattr(value, "dtype")
                                                and value.dtype.kind == "b"
                                                and getattr(value, "ndim", 1) == 0):
            raise ValueError(f"{p.name} must be True or False, got {value!r}")
        return bool(value)
    if p.kind == "prob":
        return check_probability(p.name, value)
    if p.kind == "prob0":
        return check_probability(p.name, value, open_interval=False)
    if p.kind == "pos":
        return check_positive(p.name, value)
    if p.kind == "nonneg":
        return check_positive(p.name, value, allow_zero=True)
    if p.kind == "count":
        return check_int(p.name, value, 0)
    raise AssertionError(p.kind)  # pragma: no cover - table defect


def resolve(rules: str, params: dict) -> dict:
    """Validated keywords of ``rules``: defaults overridden by ``params``.

    Raises
    ------
    ValueError
        For an unknown keyword (the message lists the allowed ones) or a bad value.
    """
    _check_rules(rules)
    allowed = [p.name for p in PARAMS if rules in p.default]
    for name in params:
        if name not in allowed:
            raise ValueError(f"unknown keyword {name!r} for rules={rules!r}; allowed: "
                             f"{', '.join(allowed)}")
    out = defaults(rules)
    for name, value in params.items():
        out[name] = _check_value(_BY_NAME[name], value)
    if "t_exp_over_mfd" in params and ("tau_sat" in params or "tau_const" in params):
        raise ValueError("give either t_exp_over_mfd or tau_sat/tau_const, not both")
    budget = out["phmi_vert"] + out["phmi_hor"]
    check_range("phmi_vert + phmi_hor", budget, 0.0, 1.0)
    if not math.isfinite(budget):  # pragma: no cover - caught above
        raise ValueError("phmi_vert + phmi_hor must be finite")
    return out


def frozen(d: dict) -> MappingProxyType:
    """A read-only view of the scalar constants (arrays and options left out)."""
    return MappingProxyType({k: v for k, v in d.items()
                             if _BY_NAME[k].kind not in ("array",)})
