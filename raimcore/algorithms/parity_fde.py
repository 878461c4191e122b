"""Parity-vector FDE (seed 000): detect with DF_D, isolate with DF_I, exclude and re-solve.

Snapshot algorithm, batched over all epochs at once: satellites are switched off by zero
weights, so the batch needs no grouping by visible set and an exclusion is one more weight
set to zero. The kernel lives in :mod:`raimcore.snapshot` (shared with :func:`raimcore.fde`).
"""

from __future__ import annotations

import numpy as np

from ..schema import option
from ..snapshot import FDE_OUTPUTS, _parity_fde
from .base import (
    STATUS_NO_ISOLATION,
    STATUS_OK,
    STATUS_UNAVAILABLE,
    AlgorithmOutput,
    AlgorithmSpec,
    Measurements,
    register,
)

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
    many satellites may be excluded one after another (greedy) at one epoch.

    The kernel is :func:`raimcore.snapshot._parity_fde`, the one behind
    :func:`raimcore.fde` (one implementation); here it also returns the per-satellite
    isolation, fault size and isolability and the classic slope-based protection levels
    (Brown 1992; see :func:`raimcore.algorithms.mss.classic_raim`), for comparison with
    solution separation (seed 001).
    """
    w = np.where(data.used, 1.0 / data.sigma_m**2, 0.0)
    out = _parity_fde(data.pos_sv_ecef_m, data.pr_m, w, np.asarray(data.sys_idx),
                      len(data.systems), data.p_fa, options["max_exclusions"],
                      outputs=tuple(FDE_OUTPUTS), p_md=data.p_md)
    status = np.where(~out["valid"], STATUS_UNAVAILABLE,
                      np.where(out["dof"] >= 2, STATUS_OK, STATUS_NO_ISOLATION)).astype(object)
    alarm = out["alarm"]
    return AlgorithmOutput(
        status=status, statistic=out["statistic"], threshold=out["threshold"], alarm=alarm,
        pos_before_ecef_m=out["pos_before"], pos_after_ecef_m=out["pos_after"],
        excluded=out["excluded"], isolated=np.where(alarm, out["best"], -1),
        per_sat={"isolation": out["isolation"], "fault_size_m": out["fault_size_m"],
                 "isolability": out["isolability"]},
        columns={"dof": out["dof"], "statistic_after": out["statistic_after"],
                 "hpl_m": out["hpl_m"], "vpl_m": out["vpl_m"]},
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
