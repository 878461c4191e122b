"""Advanced RAIM (multiple hypothesis solution separation, ARAIM ADD v4.2) as a registered
algorithm.

Thin orchestration over the kernel :func:`raimcore.araim.mhss`, all epochs at once:

1. the nominal error model of ``../shared/ARAIM.md`` section 2 from the scenario's ISM
   (key ``ism``) and airborne user model (key ``user_model``):
   :func:`raimcore.measure.error_models.araim_sigmas` gives ``sigma_int`` (URA) and
   ``sigma_acc`` (URE) of every pseudorange;
2. the all-in-view weighted least squares with ``C_int`` (:func:`raimcore.lsq.wls`, weights
   ``1 / sigma_int^2``, which is the kernel's ``S^(0)``) gives the position before
   exclusion, the rows ``G = [-u_E, -u_N, -u_U, one-hot clock]`` in the ENU frame of that
   position (NaN rows for satellites not used) and the residuals ``y`` there;
3. the kernel gives the protection levels, EMT, sigma_acc and the fault modes, and with
   ``y`` the separation test (alarm, the mode explaining it) and, with ``araim_fde``, the
   exclusion (a satellite or a whole constellation) and the position after it.

LPV-200 availability (ARAIM.md section 11): ``VPL <= val_m``, ``HPL <= hal_m`` (the
scenario's alert limits: set ``hal_m = 40``, ``val_m = 35`` for LPV-200, as the built-in
scenario ``araim`` does), ``EMT <= emt_max_m`` (15 m) and ``sigma_acc <= sigma_acc_max_m``
(1.87 m).

The model is linear about the all-in-view solution: a subset solution is
``x0 + (S^(k) y)[:3]`` in the ENU frame of ``x0``.

False alarms: the separation tests share ``P_FA_VERT + P_FA_HOR`` (divided by
``N_es,cont``) per epoch, a union bound over the modes, axes and signs (ARAIM.md section 6);
the scenario's ``p_fa`` has no effect. The output carries this budget (``p_fa``) and the
summary sets the fault-free alarm share against it.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

import numpy as np

from .. import araim as kernel
from ..araim import _params
from ..geometry import enu_to_ecef
from ..lsq import wls
from ..measure.error_models import MAAST_ISM, araim_sigmas
from ..schema import SchemaError, coerce_bool, coerce_float, coerce_int, did_you_mean, option
from .base import (
    STATUS_NO_ISOLATION,
    STATUS_OK,
    STATUS_UNAVAILABLE,
    AlgorithmOutput,
    AlgorithmSpec,
    Measurements,
    register,
)

#: Kernel keywords a scenario may override through ``araim_constants`` (the scalar
#: constants of ARAIM.md section 10; exposure goes through ``t_exp_s``, exclusion through
#: ``araim_fde``).
CONSTANT_NAMES = tuple(p.name for p in kernel.PARAMS
                       if p.kind not in ("array",)
                       and p.name not in ("t_exp_over_mfd", "fde", "return_modes"))
_PARAM = {p.name: p for p in kernel.PARAMS}

SUMMARY = (
    "Advanced RAIM protects against every fault the integrity support message (ISM) says "
    "is likely enough: one or two satellites, or a whole constellation. For each such "
    "fault mode it computes the position without the satellites the mode removes and "
    "compares it with the all-in-view position: the separation is tested against a "
    "threshold set by the false-alarm budget and the accuracy model (URE). The protection "
    "levels add, over all modes weighted by their prior probability, the threshold and the "
    "missed-detection margin of the integrity model (URA): the vertical and horizontal "
    "error stays below VPL and HPL except with probability PHMI. The effective monitor "
    "threshold (EMT) and the accuracy sigma complete the LPV-200 check. When a separation "
    "exceeds its threshold, the mode that explains it is excluded: a satellite, or a "
    "constellation."
)

EQUATIONS = r"""
- Nominal model: $C_{int} = \mathrm{diag}(\sigma_{URA}^2 + \sigma_{tropo}^2 +
  \sigma_{user}^2)$, $C_{acc}$ the same with $\sigma_{URE}$; $W = C_{int}^{-1}$
- Subset $k$ (removes the satellites $R_k$): $S^{(k)} = (G_k^T W_k G_k)^{-1} G_k^T W_k$
- Separation test: $|((S^{(k)} - S^{(0)})\,y)_q| \le T_{k,q} = K_{fa,q}\,
  \sigma_{ss,q}^{(k)} + b_{ss,q}^{(k)}$, $K_{fa,3} = Q^{-1}\big(P_{FA,V} / (2 N_{fm})\big)$
- VPL: $2 Q\big(\tfrac{L - b_3^{(0)}}{\sigma_3^{(0)}}\big) + \sum_k p_k\,
  Q\big(\tfrac{L - T_{k,3} - b_3^{(k)}}{\sigma_3^{(k)}}\big) = PHMI_V \big(1 -
  \tfrac{P_{nm}}{PHMI_V + PHMI_H}\big)$, solved for $L$; HPL likewise per axis
- $\mathrm{EMT} = \max \{ T_{k,3} : p_k \ge P_{EMT} \}$; $\sigma_{acc} =
  \sqrt{(S^{(0)} C_{acc} S^{(0)T})_{33}}$
- LPV-200: $\mathrm{VPL} \le 35$ m, $\mathrm{HPL} \le 40$ m, $\mathrm{EMT} \le 15$ m,
  $\sigma_{acc} \le 1.87$ m
"""


@dataclass(frozen=True)
class AraimConstants:
    """The value of option ``araim_constants``: kernel constants that override those of
    the rule set (``items``: ``(name, value)`` pairs, sorted). ``str()`` is the TOML table
    that :func:`parse_constants` reads back."""

    items: tuple[tuple[str, object], ...] = ()

    def as_dict(self) -> dict:
        return dict(self.items)

    def __str__(self) -> str:
        def fmt(v):  # exact TOML literals, so that a text box's text parses back
            return ("true" if v else "false") if isinstance(v, bool) else repr(v)
        return "{" + ", ".join(f"{k} = {fmt(v)}" for k, v in self.items) + "}"


def _coerce_constant(name: str, value):
    p = _PARAM[name]
    where = f"araim_constants.{name}"
    if p.kind == "bool":
        return coerce_bool(where, value)
    if p.kind == "count":
        return coerce_int(where, value, 0)
    if p.kind == "prob":
        return coerce_float(where, value, 0.0, 1.0, lo_open=True, hi_open=True)
    if p.kind == "prob0":
        return coerce_float(where, value, 0.0, 1.0)
    if p.kind == "pos":
        return coerce_float(where, value, 0.0, lo_open=True, unit=p.unit)
    return coerce_float(where, value, 0.0, unit=p.unit)  # nonneg


def parse_constants(name: str, value) -> AraimConstants:
    """Option ``araim_constants``: a table ``{phmi_vert = 1e-9, n_es_int = 25}`` (or its
    TOML text, as a dashboard text box gives it) of kernel constants (ARAIM.md section 10;
    :data:`raimcore.araim.PARAMS` has their defaults per rule set)."""
    if isinstance(value, AraimConstants):
        return value
    if isinstance(value, str):
        text = value.strip() or "{}"
        try:
            value = tomllib.loads(f"v = {text}")["v"]
        except tomllib.TOMLDecodeError:
            raise SchemaError(f"{name} must be a table such as {{phmi_vert = 1e-9}}, got "
                              f"{text!r}"[:200]) from None
    if not isinstance(value, dict):
        raise SchemaError(f"{name} must be a table such as {{phmi_vert = 1e-9}}, got "
                          f"{value!r}"[:200])
    out = {}
    for k, v in value.items():
        if k not in CONSTANT_NAMES:
            raise SchemaError(f"{name}: unknown constant {k!r}"
                              f"{did_you_mean(str(k), CONSTANT_NAMES)}; constants: "
                              f"{', '.join(CONSTANT_NAMES)}")
        out[k] = _coerce_constant(k, v)
    return AraimConstants(tuple(sorted(out.items())))


#: Options (scenario keys) of ARAIM.
OPTIONS = (
    option("araim_rules", "choice", "add-v4.2", "ARAIM rule set: add-v4.2 (ADD baseline, "
           "LPV-200 constants, as MAAST) or blanch-2012 (the worked example's rules)",
           choices=tuple(kernel.RULES)),
    option("araim_fde", bool, True, "exclusion after an alarm (ARAIM.md section 9): the "
           "satellite or constellation whose removal passes every test is excluded; the "
           "PLs become the worst over the exclusion candidates, as MAAST's fde_flag (false: "
           "detection only, smaller PLs)"),
    option("emt_max_m", float, 15.0, "LPV-200 availability: largest effective monitor "
           "threshold", unit="m", lo=0.0, lo_open=True, hi=1.0e4, ui_lo=1.0, ui_hi=50.0,
           ui_step=0.5),
    option("sigma_acc_max_m", float, 1.87, "LPV-200 availability: largest vertical "
           "accuracy sigma", unit="m", lo=0.0, lo_open=True, hi=1.0e3, ui_lo=0.5,
           ui_hi=10.0, ui_step=0.01),
    option("t_exp_s", float, 0.0, "exposure time T_exp (add-v4.2): p_exp = p (1 + T_exp / "
           "MFD) with the ism's mean fault durations (0: the LPV-200 baseline; MAAST v5 "
           "150)", unit="s", lo=0.0, hi=1.0e6, ui_lo=0.0, ui_hi=600.0, ui_step=10.0),
    option("araim_constants", "custom", AraimConstants(), "kernel constants replacing "
           "those of the rule set (ARAIM.md section 10), e.g. {phmi_vert = 1e-9, n_es_int = "
           "25}: " + ", ".join(CONSTANT_NAMES), parse=parse_constants,
           allowed_text="table of constants"),
)


@dataclass(frozen=True)
class Solution:
    """ARAIM's decisions at every epoch (:func:`solve`); arrays (T,) unless said."""

    res: kernel.MhssResult  # the kernel's result
    avail: np.ndarray  # a position with redundancy and an ARAIM evaluation
    status: np.ndarray  # ok / detect-only / unavailable
    alarm: np.ndarray
    has_sat: np.ndarray  # alarm with a satellite excluded
    has_const: np.ndarray  # alarm with a constellation excluded
    excluded: np.ndarray  # (T, n) bool, False where not avail
    isolated: np.ndarray  # the satellite excluded or explaining the alarm, or -1
    pos_before: np.ndarray  # (T, 3) all-in-view ECEF position, NaN where not avail
    pos_after: np.ndarray  # (T, 3) after exclusion, NaN where not avail


def solve(sv, pr, used, sig_int, sig_acc, b_nom, b_cont, p_sat, p_const, sys_idx,
          n_sys: int, *, rules: str, fde: bool, params: dict) -> Solution:
    """The weighted all-in-view fix (weights 1 / sigma_int^2: the kernel's S^(0)), MHSS
    (:func:`raimcore.araim.mhss`) on its geometry and residuals, and the decisions: the
    one implementation behind the registered algorithm and ``raimcore.fde``.

    ``sv`` (T, n, 3), ``pr``, ``used``, ``sig_int``, ``sig_acc``, ``b_nom``, ``b_cont``,
    ``p_sat`` (T, n), ``p_const`` (q,), ``sys_idx`` (n,); ``params`` the kernel's keywords.
    An epoch without redundancy (dof 0) is unavailable: nothing to test.
    """
    t_n, s_n = pr.shape
    w = np.where(used, 1.0 / sig_int**2, 0.0)
    lin = wls(sv, pr, w, sys_idx, n_sys)
    ok = lin.available
    pos_lin = np.where(ok[:, None], lin.pos_ecef_m, 0.0)
    g = np.where(used[..., None] & ok[:, None, None], lin.h_enu, np.nan)
    y = np.where(used & ok[:, None], np.nan_to_num(lin.resid_m), 0.0)
    res = kernel.mhss(g, sig_int, sig_acc, b_nom, b_cont, p_sat, p_const, rules=rules, y=y,
                      fde=fde, **params)
    dof = lin.n_used - lin.n_states
    avail = ok & (res.status == "ok") & (dof >= 1)
    status = np.where(~avail, STATUS_UNAVAILABLE,
                      np.where(dof >= 2, STATUS_OK, STATUS_NO_ISOLATION)).astype(object)
    alarm = avail & res.alarm
    rows = np.arange(t_n)
    excluded = np.zeros((t_n, s_n), dtype=bool)
    has_s = has_c = np.zeros(t_n, dtype=bool)
    dx_after = np.zeros((t_n, 3))
    if fde:  # a satellite, or every used satellite of a constellation
        es, ec = res.excluded_sat, res.excluded_const
        has_s, has_c = alarm & (es >= 0), alarm & (ec >= 0)
        excluded[rows[has_s], es[has_s]] = True
        excluded |= has_c[:, None] & used & (np.asarray(sys_idx)[None, :] == ec[:, None])
        dx_after = np.where((has_s | has_c)[:, None], np.nan_to_num(res.dx_excluded_enu_m),
                            0.0)
    iso = np.where(excluded.sum(-1) == 1, np.argmax(excluded, axis=-1), -1)
    isolated = np.where(iso >= 0, iso,
                        np.where(alarm, _single_sat(res.modes, res.alarm_mode), -1))
    return Solution(
        res=res, avail=avail, status=status, alarm=alarm, has_sat=has_s, has_const=has_c,
        excluded=excluded & avail[:, None], isolated=np.where(avail, isolated, -1),
        pos_before=np.where(avail[:, None], lin.pos_ecef_m, np.nan),
        pos_after=np.where(avail[:, None], enu_to_ecef(dx_after, pos_lin), np.nan))


def false_alarm_budget(rules: str, params: dict) -> float:
    """The per-epoch false-alarm probability of the separation tests with the kernel
    keywords ``params``: ``(P_FA_VERT + P_FA_HOR) / N_es,cont`` (ARAIM.md section 6; the
    thresholds split it over the modes, the two horizontal axes and the signs)."""
    prm = _params.resolve(rules, params)
    return (prm["p_fa_vert"] + prm["p_fa_hor"]) / prm["n_es_cont"]


def run(data: Measurements, options: dict) -> AlgorithmOutput:
    """Run ARAIM MHSS on every epoch (module doc).

    Raises
    ------
    SchemaError
        A constant of ``araim_constants`` or ``t_exp_s > 0`` that the chosen rule set does
        not take.
    """
    rules = options["araim_rules"]
    fde = options["araim_fde"]
    consts = options["araim_constants"].as_dict()
    for k in consts:
        if rules not in _PARAM[k].default:
            raise SchemaError(f"araim_constants: {k} is a constant of "
                              f"{', '.join(_PARAM[k].default)}, not of araim_rules {rules!r}")
    if options["t_exp_s"] > 0 and rules != "add-v4.2":
        raise SchemaError(f"t_exp_s applies to araim_rules \"add-v4.2\" only (blanch-2012 has "
                          f"no exposure), got t_exp_s = {options['t_exp_s']:g}")
    n_ep = data.pr_m.shape[0]
    n_sys = len(data.systems)
    ism = MAAST_ISM if data.ism is None else data.ism
    sig_int, sig_acc = araim_sigmas(data.el_rad, data.systems, data.sys_idx, ism,
                                    data.user_model)
    used = data.used & np.isfinite(data.pr_m)
    per_sat = ism.per_sat(data.systems, data.sys_idx)
    per_sys = ism.per_system(data.systems)
    params = dict(consts)
    if rules == "add-v4.2":
        params["tau_sat"] = options["t_exp_s"] / per_sat["mfd_sat_s"]
        params["tau_const"] = options["t_exp_s"] / per_sys["mfd_const_s"]
    sol = solve(data.pos_sv_ecef_m, data.pr_m, used, sig_int, sig_acc, per_sat["b_nom_m"],
                per_sat["b_cont_m"], per_sat["p_sat"], per_sys["p_const"], data.sys_idx,
                n_sys, rules=rules, fde=fde, params=params)
    res, avail, alarm = sol.res, sol.avail, sol.alarm

    # The mode explaining the alarm (largest normalised separation), named.
    mode_names = _mode_names(res.modes, res.alarm_mode, data)
    alarm_mode = np.where(alarm, mode_names, "").astype(object)
    exc_name = np.full(n_ep, "", dtype=object)
    if fde:  # what was excluded: a satellite or a constellation, named
        names = np.array(data.sat_names + ("",), dtype=object)
        sys_names = np.array(tuple(data.systems) + ("",), dtype=object)
        es, ec = res.excluded_sat, res.excluded_const
        exc_name = np.where(sol.has_sat, names[np.where(es >= 0, es, -1)], exc_name)
        exc_name = np.where(sol.has_const, sys_names[np.where(ec >= 0, ec, -1)],
                            exc_name).astype(object)

    hpl, vpl = res.hpl_m, res.vpl_m
    emt, sacc = res.emt_m, res.sigma_acc_v_m
    lpv = (avail & (vpl <= data.val_m) & (hpl <= data.hal_m)
           & (emt <= options["emt_max_m"]) & (sacc <= options["sigma_acc_max_m"]))
    cols = {
        "hpl_m": hpl,
        "vpl_m": vpl,
        "emt_m": emt,
        "sigma_acc_m": sacc,
        "available": lpv,
        "n_modes": res.n_modes,
        "p_not_monitored": res.p_not_monitored,
        "k_fa_v": res.k_fa[..., 2],
        "alarm_mode": alarm_mode,
        "excluded_mode": exc_name,
    }
    if fde:
        cols["pl_set_by"] = _set_by(res, avail, data)
    cols["pl_note"] = _pl_note(res, avail, cols.get("pl_set_by"), data)
    return AlgorithmOutput(
        status=sol.status,
        statistic=np.where(avail, res.test_ratio, np.nan),
        threshold=np.where(avail, 1.0, np.nan),
        alarm=alarm,
        pos_before_ecef_m=sol.pos_before,
        pos_after_ecef_m=sol.pos_after,
        excluded=sol.excluded,
        isolated=sol.isolated,
        per_sat={"sigma_int_m": np.where(used, sig_int, np.nan),
                 "sigma_acc_m": np.where(used, sig_acc, np.nan)},
        columns=cols,
        extras=_mode_extras(res.modes, avail, data),
        p_fa=false_alarm_budget(rules, params),
    )


def _set_by(res, avail, data: Measurements) -> np.ndarray:
    """Per epoch, the exclusion candidate whose evaluation gave the VPL (where the VPL is
    the all-in-view's: the HPL), by name (a satellite, or a system key for a whole
    constellation); ``""`` where both are the all-in-view's (kernel ``vpl_set_by``,
    ``hpl_set_by``)."""
    by = np.where(res.vpl_set_by >= 0, res.vpl_set_by, res.hpl_set_by)
    labels = np.array(tuple(data.sat_names) + tuple(data.systems) + ("",), dtype=object)
    return np.where(avail & (by >= 0), labels[np.where(by >= 0, by, -1)], "").astype(object)


def _pl_note(res, avail, set_by, data: Measurements) -> np.ndarray:
    """Per epoch, why a protection level is infinite where the geometry is available
    (``""`` where both are finite): never a silent infinity (ARAIM.md sections 7, 9).

    An infinite PL means the budget left for it is used up: by ``P_not_monitored``
    (``PHMI' <= 0``), by an exclusion candidate that leaves 3 satellites or fewer (MAAST's
    rule), or, in a candidate's evaluation, by the priors of the fault modes it leaves
    unmonitorable (each spends ``p_inst``, more than ``rho PHMI'``). No commas: the
    note is a column of the result CSV."""
    n_ep = len(avail)
    note = np.full(n_ep, "", dtype=object)
    inf = avail & ~(np.isfinite(res.vpl_m) & np.isfinite(res.hpl_m))
    if not inf.any():
        return note
    used = data.used & np.isfinite(data.pr_m)
    n_used = used.sum(axis=1)
    systems = tuple(data.systems)
    for i in np.flatnonzero(inf):
        which = ("VPL and HPL" if not (np.isfinite(res.vpl_m[i]) or np.isfinite(res.hpl_m[i]))
                 else "VPL" if not np.isfinite(res.vpl_m[i]) else "HPL")
        budget = f"PHMI_V' = {res.phmi_vert_alloc[i]:.2g}"
        cand = "" if set_by is None else set_by[i]
        if not cand:
            note[i] = (f"{which} infinite: P_not_monitored = {res.p_not_monitored[i]:.2g} "
                       f"uses up the integrity budget ({budget})")
            continue
        gone = (int(np.sum(used[i] & (data.sys_idx == systems.index(cand))))
                if cand in systems else 1)
        if n_used[i] - gone <= 3:
            why = f"excluding {cand} leaves {n_used[i] - gone} satellites (3 or fewer)"
        else:
            why = (f"after excluding {cand} the fault modes left unmonitorable (too few "
                   f"satellites to separate them) have priors above its budget ({budget})")
        note[i] = (f"{which} infinite (set by the exclusion candidate {cand}): {why}; "
                   "araim_fde = false gives the detection-only PLs")
    return note


#: Extras of the fault-mode panel: per epoch and monitored mode (padded to K).
MODE_EXTRAS = ("mode_label", "mode_p_inst", "mode_threshold_m", "mode_separation_m",
               "mode_monitored")


def _mode_extras(modes, avail, data: Measurements) -> dict[str, np.ndarray]:
    """The fault modes of every epoch for displays (:data:`MODE_EXTRAS`), all ``(E, K)``
    or ``(E, K, 3)`` (E, N, U), the fault-free mode left out: ``mode_label`` names what the
    mode removes (:func:`_mode_names`), ``mode_p_inst`` its prior, ``mode_threshold_m``
    ``T_k,q``, ``mode_separation_m`` ``((S^(k) - S^(0)) y)_q``, ``mode_monitored`` a real,
    monitorable mode at an available epoch. Empty without the kernel's mode table."""
    if modes is None or modes.sats.shape[1] <= 1:
        return {}
    labels = _all_mode_names(modes, data)
    mon = modes.monitored[:, 1:] & avail[:, None]
    sep = modes.separation_m[:, 1:] if modes.separation_m is not None else None
    return {
        "mode_label": np.where(mon, labels, "").astype(object),
        "mode_p_inst": np.where(mon, modes.p_inst[:, 1:], 0.0),
        "mode_threshold_m": np.where(mon[..., None], modes.threshold_m[:, 1:], np.nan),
        "mode_separation_m": (np.where(mon[..., None], sep, np.nan) if sep is not None
                              else np.full(mon.shape + (3,), np.nan)),
        "mode_monitored": mon,
    }


def _mode_names(modes, index, data: Measurements) -> np.ndarray:
    """Name of mode ``index[e]`` at each epoch: its constellation events by system key,
    then the satellites it removes outside them, joined by "+" ("" for none)."""
    n_ep = index.shape[0]
    if modes is None or modes.sats.shape[1] == 0:
        return np.full(n_ep, "", dtype=object)
    k = np.clip(index, 0, modes.sats.shape[1] - 1)
    rows = np.arange(n_ep)
    sats = modes.sats[rows, k] & (index >= 0)[:, None]
    consts = modes.consts[rows, k] & (index >= 0)[:, None]
    in_const = consts[:, data.sys_idx]  # satellites of a constellation event
    mask = np.concatenate([consts, sats & ~in_const], axis=1)
    labels = tuple(data.systems) + tuple(data.sat_names)
    uniq, inverse = np.unique(mask, axis=0, return_inverse=True)
    joined = np.array(["+".join(n for n, m in zip(labels, row, strict=True) if m)
                       for row in uniq], dtype=object)
    return joined[inverse.reshape(-1)]


#: Modes named per block in :func:`_all_mode_names` (bounds its (E, block, n) masks).
_NAME_BLOCK = 64


def _all_mode_names(modes, data: Measurements) -> np.ndarray:
    """:func:`_mode_names` of every mode ``1..K-1`` of every epoch, ``(E, K - 1)``: the
    masks of a block of modes are packed to bytes and each distinct one is named once
    (a recording with 800 modes and thousands of epochs has a few thousand names)."""
    n_ep, k_all = modes.p_inst.shape
    out = np.empty((n_ep, max(k_all - 1, 0)), dtype=object)
    labels = tuple(data.systems) + tuple(data.sat_names)
    named: dict[bytes, str] = {}
    for k0 in range(1, k_all, _NAME_BLOCK):
        ks = slice(k0, min(k_all, k0 + _NAME_BLOCK))
        consts = modes.consts[:, ks]
        sats = modes.sats[:, ks] & ~consts[..., data.sys_idx]
        mask = np.concatenate([consts, sats], axis=-1)
        flat = mask.reshape(-1, mask.shape[-1])
        packed = np.ascontiguousarray(np.packbits(flat, axis=1))
        keys = packed.view(np.dtype((np.void, packed.shape[1]))).reshape(-1)
        uniq, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
        names = []
        for u, i in zip(uniq, first, strict=True):
            b = u.tobytes()
            if b not in named:
                named[b] = "+".join(n for n, m in zip(labels, flat[i], strict=True) if m)
            names.append(named[b])
        out[:, ks.start - 1:ks.stop - 1] = np.array(names, dtype=object)[
            inverse.reshape(-1)].reshape(n_ep, ks.stop - ks.start)
    return out


def _single_sat(modes, index) -> np.ndarray:
    """The satellite of mode ``index[e]`` if it removes exactly one, else -1."""
    n_ep = index.shape[0]
    if modes is None or modes.sats.shape[1] == 0:
        return np.full(n_ep, -1)
    k = np.clip(index, 0, modes.sats.shape[1] - 1)
    sats = modes.sats[np.arange(n_ep), k] & (index >= 0)[:, None]
    return np.where(sats.sum(-1) == 1, np.argmax(sats, axis=-1), -1)


SPEC = register(AlgorithmSpec(
    name="araim",
    label="Advanced RAIM (MHSS, ADD v4.2)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=OPTIONS,
    reference="EU-US WG-C ARAIM TSG, ARAIM Airborne Algorithm Description Document v4.2 "
              "(2022); Blanch J. et al., ION GNSS 2012 and IEEE TAES 51(1) 2015; Stanford "
              "MAAST (maast_for_araim_2).",
))

__all__ = ["SPEC", "OPTIONS", "AraimConstants", "parse_constants", "run", "CONSTANT_NAMES"]
