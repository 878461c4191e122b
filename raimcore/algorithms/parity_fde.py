"""Parity-vector FDE (seed 000): detect with DF_D, isolate with DF_I, exclude and re-solve.

Snapshot algorithm, batched over all epochs at once: satellites are switched off by zero
weights, so the batch needs no grouping by visible set and an exclusion is one more weight
set to zero.
"""

from __future__ import annotations

import numpy as np

from ..lsq import wls
from ..schema import option
from .base import (
    STATUS_NO_ISOLATION,
    STATUS_OK,
    STATUS_UNAVAILABLE,
    AlgorithmOutput,
    AlgorithmSpec,
    Measurements,
    register,
)
from .mss import classic_raim
from .parity import parity_statistics

SUMMARY = (
    "The parity vector collects the part of the measurements that no position and clock "
    r"can explain. Without a fault its squared length $\mathrm{DF}_D$ follows a chi-square "
    r"law with $m - n$ degrees of freedom, so a threshold $T_D$ set from the false-alarm "
    r"probability decides 'fault'. A bias on satellite $j$ pushes the parity vector along "
    r"that satellite's column $v_j$: the satellite whose column best lines up with the "
    r"parity vector (largest $\mathrm{DF}_{I,j}$) is isolated, removed, and the position "
    "solved again. Two satellites whose columns are nearly parallel (isolability near 1) "
    "cannot be told apart."
)

EQUATIONS = r"""
- Parity matrix: $V H = 0$, $V V^T = I$, $V^T V = I - H(H^T H)^{-1}H^T$
  ($m$ satellites, $n$ states)
- Parity vector: $p = V z / \sigma$ ($z$: pseudorange residuals); detection statistic
  $\mathrm{DF}_D = p^T p \sim \chi^2_{m-n}$
- Threshold: $T_D = F^{-1}(1 - P_{fa})$ ($F$: the CDF of $\chi^2_{m-n}$); alarm when
  $\mathrm{DF}_D / T_D \ge 1$
- Fault: $\mathrm{DF}_D \sim \chi^2_{m-n}(\lambda)$, $\lambda = \lVert V b \rVert^2 / \sigma^2$
- Isolation: $\mathrm{DF}_{I,j} = (p^T v_j)^2 / (v_j^T v_j)$, faulty
  $k = \mathrm{arg\,max}_j\, \mathrm{DF}_{I,j}$
- Fault size: $\hat f_j = \sigma\, p^T v_j / (v_j^T v_j)$
"""


#: Options (scenario keys) of the parity algorithm.
OPTIONS = (
    option("max_exclusions", int, 1, "satellites that may be excluded one after another "
           "(greedy) at one epoch; 0 = detect only", lo=0, hi=10),
)


def run(data: Measurements, options: dict) -> AlgorithmOutput:
    """Run parity FDE on every epoch; ``options["max_exclusions"]`` (default 1) sets how
    many satellites may be excluded one after another (greedy) at one epoch."""
    max_excl = options["max_exclusions"]
    w = np.where(data.used, 1.0 / data.sigma_m**2, 0.0)
    n_sys = len(data.systems)
    before = wls(data.pos_sv_ecef_m, data.pr_m, w, data.sys_idx, n_sys)
    st = parity_statistics(before.h_enu, before.resid_m, w, data.p_fa, before.dof)
    available = before.available & (before.dof >= 1)
    # Classic slope-based protection levels of the chi-square detector (Brown 1992; see
    # raimcore.algorithms.mss.classic_raim), for comparison with solution separation (seed 001).
    pl = classic_raim(before.h_enu, before.resid_m, w, np.ones(w.shape[-1], dtype=bool),
                      data.p_fa, data.p_md)
    status = np.where(~available, STATUS_UNAVAILABLE,
                      np.where(before.dof >= 2, STATUS_OK, STATUS_NO_ISOLATION)).astype(object)
    excluded = np.zeros(w.shape, dtype=bool)
    after_pos = before.pos_ecef_m.copy()
    after_stat = st.statistic.copy()
    # State of the greedy exclusion loop: does the current set still alarm, and whom to drop.
    act = st.alarm & (st.best >= 0)
    drop = st.best
    for _ in range(max_excl):
        rows = np.flatnonzero(act)
        if rows.size == 0:
            break
        excluded[rows, drop[rows]] = True
        w_rows = np.where(excluded[rows], 0.0, w[rows])
        # Re-solve only the epochs that changed (seed 000 section 1.3, reconstruction).
        sub = wls(data.pos_sv_ecef_m[rows], data.pr_m[rows], w_rows, data.sys_idx, n_sys,
                  x0_ecef_m=after_pos[rows])
        sub_st = parity_statistics(sub.h_enu, sub.resid_m, w_rows, data.p_fa, sub.dof)
        after_pos[rows] = sub.pos_ecef_m
        after_stat[rows] = sub_st.statistic
        act = np.zeros_like(act)
        act[rows] = sub_st.alarm & (sub_st.best >= 0)
        drop = np.full_like(drop, -1)
        drop[rows] = sub_st.best
    alarm = st.alarm
    return AlgorithmOutput(
        status=status, statistic=st.statistic, threshold=st.threshold, alarm=alarm,
        pos_before_ecef_m=before.pos_ecef_m, pos_after_ecef_m=after_pos, excluded=excluded,
        isolated=np.where(alarm, st.best, -1),
        per_sat={"isolation": st.isolation, "fault_size_m": st.fault_size_m,
                 "isolability": st.isolability},
        columns={"dof": st.dof, "statistic_after": after_stat, "hpl_m": pl.hpl_m,
                 "vpl_m": pl.vpl_m},
    )


SPEC = register(AlgorithmSpec(
    name="parity",
    label="Parity vector (seed 000)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=OPTIONS,
    reference="Liao X., Huang S. (1996), parity vector method for GPS fault detection and "
              "isolation, J. UEST China (seed 000).",
))
