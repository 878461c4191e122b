"""Multiple solution separation with barometric aiding (seed 001) as a registered algorithm.

Thin orchestration over :mod:`raimcore.algorithms.mss`: a GNSS-only batched WLS gives the
linearisation point (:func:`raimcore.lsq.wls`), the pseudorange residuals there and the
local-frame geometry; the barometric row ``[0, 0, 1, 0, ...]`` with innovation
``h_baro - h(x_lin)`` is appended when the scenario has ``baro = true``. The kernels then
give, for every epoch at once, the MSS detection, identification, exclusion and PLs with
the scenario's baro setting, the MSS PLs without baro, and the classic slope-based PLs of
the chi-square (SSE) detector without baro (the paper's "classic RAIM").

The model is linear about the WLS solution: sub-solutions are ``X_i = X0 - dX_i`` in the
ENU frame of that point. The neglected second-order term is about ``offset^2 / range``,
below 1 m for offsets of a few km (a 1000 m fault on a weak geometry).
"""

from __future__ import annotations

import numpy as np

from ..geometry import ecef_to_geodetic, enu_to_ecef
from ..lsq import wls
from ..schema import option
from . import mss as kernel
from .base import AlgorithmOutput, AlgorithmSpec, Measurements, register

IDENT_RULES = ("unique", "rank")

SUMMARY = (
    "Solution separation compares the position from all measurements (the main solution) "
    "with the positions obtained by leaving out one satellite at a time (sub-solutions). "
    r"Without a fault they differ only by noise whose covariance is known "
    r"($dP_i = P_i - P_0$), so each separation is tested against a threshold set from the "
    "false-alarm probability. To name the faulty satellite each sub-solution is in turn "
    "checked against its own sub-sub-solutions: the sub-solution that left out the faulty "
    "satellite is consistent. A barometric altimeter adds one height measurement: it "
    "shrinks the vertical protection level and, with only 5 satellites, gives the second "
    "redundant measurement that identification needs. Protection levels bound the position "
    "error that a just missed fault could cause: HPL/VPL = separation threshold + "
    "missed-detection margin."
)

EQUATIONS = r"""
- Stacked model: $Z = [y;\ h_e - h_b]$, $H = [G;\ 0\ 0\ 1\ 0]$, $W = R^{-1}$,
  $R = \mathrm{diag}(\sigma^2, \dots, \sigma^2, \sigma_b^2)$ ($G$: the satellites' rows in
  east, north, up and clock; $h_e - h_b$: the altimeter's height)
- Main solution: $X_0 = S_0 Z$, $S_0 = (H^T W H)^{-1} H^T W$, $P_0 = (H^T W H)^{-1}$
- Sub-solution $i$ (satellite $i$ out, baro kept): $X_i = S_i Z$, $dX_i = X_0 - X_i$,
  $dP_i = P_i - P_0$
- Test: $d_i = \lVert dX_i^{EN} \rVert > T_i = \sqrt{\lambda_{\max}(dP_i^{EN})}\, k_{fa}$;
  vertically $|dX_i^U| > \sqrt{dP_i^{UU}}\, k_{fa}$, where
  $k_{fa} = Q^{-1}\big(P_{fa} / (2m)\big)$ ($Q$: the standard normal tail, $m$ satellites)
- Identification: $k$ is faulty if $X_k$ passes every test against $X_{k,j}$;
  ranking extension: $\mathrm{arg\,min}_k\, \max_j d_{kj} / T_{kj}$
- $\mathrm{HPL} = \max_i \big(T_i + \sqrt{\lambda_{\max}(P_i^{EN})}\, Q^{-1}(P_{md})\big)$
- $\mathrm{VPL} = \max_i \big(\sqrt{dP_i^{UU}}\, k_{fa} + \sqrt{P_i^{UU}}\, Q^{-1}(P_{md})\big)$
- Classic (SSE) slope PL: $\mathrm{HPL} = \max_i \mathrm{Hslope}_i \sqrt{\lambda_{det}}$,
  where $F_{\lambda_{det}}\big(F_0^{-1}(1 - P_{fa})\big) = P_{md}$ ($F_\lambda$: the CDF of
  $\chi^2_{m-n}(\lambda)$, non-central for $\lambda > 0$)
"""


#: Options (scenario keys) of solution separation.
OPTIONS = (
    option("mss_ident_rule", "choice", "unique", "identification rule: 'unique' (the "
           "paper's: exactly one sub-solution passes) or 'rank' (the smallest normalised "
           "sub-sub statistic)", choices=IDENT_RULES),
)


def run(data: Measurements, options: dict) -> AlgorithmOutput:
    """Run MSS (with the scenario's baro setting), MSS without baro and classic RAIM.

    Options
    -------
    mss_ident_rule : ``"unique"`` (paper: exclude only when exactly one candidate passes)
        or ``"rank"`` (spec extension: also pick the best-ranked candidate when several
        pass). After a multiple-fault verdict the same rule applies to satellite pairs
        (second level, redundancy >= 3) and both satellites of the pair are excluded.
    """
    rule = options["mss_ident_rule"]
    n_ep, n_sat = data.pr_m.shape
    w_sat = np.where(data.used, 1.0 / data.sigma_m**2, 0.0)
    lin = wls(data.pos_sv_ecef_m, data.pr_m, w_sat, data.sys_idx, len(data.systems))
    ok = lin.available
    pos_lin = np.where(ok[:, None], lin.pos_ecef_m, 0.0)
    has_baro = data.baro_alt_m is not None and data.sigma_baro_m is not None

    # Compact the used satellites to the front of each epoch (the kernels' cost grows with
    # the square of the row count, and most of a constellation is below the horizon).
    order = np.argsort(~(w_sat > 0), axis=1, kind="stable")
    m_max = max(int((w_sat > 0).sum(axis=1).max()), 1)
    slot = order[:, :m_max]  # (E, m_max) satellite index of each compacted row
    h = np.take_along_axis(lin.h_enu, slot[..., None], axis=1)
    h = np.concatenate([h, np.zeros((n_ep, 1, h.shape[-1]))], axis=1)
    h[:, -1, 2] = 1.0  # baro row [0, 0, 1, 0, ...] (spec section 2)
    w_gnss = np.zeros((n_ep, m_max + 1))
    w_gnss[:, :m_max] = np.take_along_axis(w_sat, slot, axis=1)
    w_gnss[~ok] = 0.0  # no linearisation point: the epoch is unavailable
    z = np.zeros((n_ep, m_max + 1))
    z[:, :m_max] = np.nan_to_num(np.take_along_axis(lin.resid_m, slot, axis=1))
    w_baro = w_gnss.copy()
    if has_baro:
        _, _, h_lin_m = ecef_to_geodetic(pos_lin)
        z[:, -1] = np.asarray(data.baro_alt_m, dtype=float) - h_lin_m  # h_e - h_b innovation
        w_baro[:, -1] = np.where(ok, 1.0 / data.sigma_baro_m**2, 0.0)
    is_sat = np.r_[np.ones(m_max, dtype=bool), False]

    main = kernel.mss(h, z, w_baro, is_sat, data.p_fa, data.p_md)
    nobaro = main if not has_baro else kernel.mss(h, z, w_gnss, is_sat, data.p_fa, data.p_md)
    classic = kernel.classic_raim(h, z, w_gnss, is_sat, data.p_fa, data.p_md)

    rows = np.arange(n_ep)

    def to_sat(row):
        """Compacted row index (E,) -> satellite index, -1 stays -1."""
        return np.where(row >= 0, slot[rows, np.maximum(row, 0)], -1)

    def scatter(a, fill=np.nan):
        """Compacted per-row array (E, m_max + 1) -> per-satellite (E, S)."""
        out = np.full((n_ep, n_sat), fill, dtype=np.asarray(a).dtype)
        np.put_along_axis(out, slot, a[:, :m_max], axis=1)
        return out

    pick_row = main.ident_unique if rule == "unique" else main.ident_rank
    pick = to_sat(pick_row)
    valid = main.status != kernel.STATUS_UNAVAILABLE
    dx0 = np.where(valid[:, None], main.dx0_m[:, :3], np.nan)
    pos_before = enu_to_ecef(dx0, pos_lin)
    sep_pick = main.dx_sep_m[rows, np.maximum(pick_row, 0), :3]
    dx_after = np.where((pick_row >= 0)[:, None], dx0 - sep_pick, dx0)
    excluded = np.zeros((n_ep, n_sat), dtype=bool)
    excluded[rows[pick >= 0], pick[pick >= 0]] = True
    # Second level after a multiple-fault verdict: exclude the identified pair.
    pair = main.ident_pair_unique if rule == "unique" else main.ident_pair_rank
    has_pair = pair >= 0
    pair_sats = [to_sat(np.where(has_pair, main.pairs[np.maximum(pair, 0), c], -1))
                 for c in (0, 1)]
    for sat in pair_sats:
        excluded[rows[has_pair], sat[has_pair]] = True
    dx_pair = main.pair_dx_m[rows, np.maximum(pair, 0), :3]
    dx_after = np.where(has_pair[:, None], dx_pair, dx_after)
    pos_after = enu_to_ecef(dx_after, pos_lin)

    ratio = scatter(main.ratio)
    statistic = np.where(valid, np.nanmax(np.where(np.isnan(ratio), -np.inf, ratio), axis=1),
                         np.nan)
    statistic = np.where(np.isinf(statistic), np.nan, statistic)
    # The best-ranked candidate is reported (isolated) whenever identification ran, so a
    # "unique" user still sees which satellite the ranking would name.
    rank = to_sat(main.ident_rank)
    isolated = np.where(pick >= 0, pick, rank)
    names = np.array(data.sat_names + ("",), dtype=object)
    cols = {
        "hpl_m": main.hpl_m,
        "vpl_m": main.vpl_m,
        "available": kernel.availability(main.hpl_m, main.vpl_m, data.hal_m, data.val_m),
        "hpl_nobaro_m": nobaro.hpl_m,
        "vpl_nobaro_m": nobaro.vpl_m,
        "available_nobaro": kernel.availability(nobaro.hpl_m, nobaro.vpl_m, data.hal_m,
                                                data.val_m),
        "hpl_classic_m": classic.hpl_m,
        "vpl_classic_m": classic.vpl_m,
        "classic_statistic": classic.sse / classic.threshold,
        "classic_alarm": classic.alarm,
        "classic_status": classic.status.astype(object),
        "nobaro_alarm": nobaro.alarm,
        "nobaro_status": nobaro.status.astype(object),
        "baro_used": np.full(n_ep, has_baro),
        "ident_status": main.ident_status.astype(object),
        "ident_unique": names[to_sat(main.ident_unique)],
        "ident_rank": names[rank],
        "ident_pair_unique": _pair_names(main, main.ident_pair_unique, to_sat, names),
        "ident_pair_rank": _pair_names(main, main.ident_pair_rank, to_sat, names),
    }
    alarm_col = main.alarm[:, None]
    per_sat = {
        "sep_ratio": ratio,
        "sep_ratio_h": scatter(_ratio(main.d_h_m, main.t_h_m)),
        "sep_ratio_v": scatter(_ratio(main.d_v_m, main.t_v_m)),
        "sep_h_m": scatter(main.d_h_m),
        "sep_threshold_h_m": scatter(main.t_h_m),
        "sep_v_m": scatter(main.d_v_m),
        "sep_threshold_v_m": scatter(main.t_v_m),
        "ident_score": np.where(alarm_col, scatter(main.ident_score), np.nan),
        "ident_pass": scatter(main.ident_pass, fill=False) & alarm_col,
    }
    return AlgorithmOutput(
        status=main.status.astype(object),
        statistic=statistic,
        threshold=np.where(valid, 1.0, np.nan),
        alarm=main.alarm,
        pos_before_ecef_m=pos_before,
        pos_after_ecef_m=pos_after,
        excluded=excluded,
        isolated=isolated,
        per_sat=per_sat,
        columns=cols,
    )


def _pair_names(main, pair, to_sat, names):
    """Pair index (E,) into ``main.pairs`` -> ``"G01+G02"`` ("" for none)."""
    a, b = (names[to_sat(np.where(pair >= 0, main.pairs[np.maximum(pair, 0), c], -1))]
            for c in (0, 1))
    return np.where(pair >= 0, a + "+" + b, "").astype(object)


def _ratio(d, t):
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where((t == 0.0) & (d == 0.0), 0.0, d / t)


SPEC = register(AlgorithmSpec(
    name="mss",
    label="Solution separation + baro (seed 001)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=OPTIONS,
    reference="Chen W., Yang Z., Gu S., Wang Y., barometric-altimeter-aided autonomous "
              "integrity monitoring by multiple solution separation (seed 001); classic PLs: "
              "Brown (1992) Navigation 39(3); Walter & Enge (1995) ION GPS.",
))
