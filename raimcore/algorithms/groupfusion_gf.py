"""GF: group fault detection with evidence fusion for multiple faults (seed 004)."""

from __future__ import annotations

from ..schema import option
from ._groupfusion_common import as_groups, groups_option, run_multi_fault
from .base import AlgorithmSpec, Measurements, register
from .groupfusion import WEIGHTS, gf_isolate, select_groups

SUMMARY = (
    "Several satellites may be faulty at once. The visible satellites are split into many "
    "overlapping groups of $r = 4 + q$ ($q$ constellations: six for GPS + BeiDou), and each "
    "group is tested on its own with the least-squares residual chi-square. A group's "
    "statistic becomes evidence $m(F)$ that its members are faulty: 0.5 exactly at the "
    "threshold, towards 1 far above it, towards 0 far below. Each satellite fuses the "
    "evidence of all its groups (the weighted distribution of conflict, which here is a "
    "reliability-weighted mean), and every satellite whose fused $m(F)$ stands more than "
    "$M$ above the mean of all satellites is isolated - however many there are. Watch the "
    "per-satellite $m(F)$ against the isolation threshold."
)

EQUATIONS = r"""
- Groups: all $L = \binom{N}{r}$ subsets of $r = 4 + q$ of the $N$ satellites ($q$
  constellations); keep $L_1 = \lfloor L/K \rfloor \approx N^2$ of them, every $K$-th
- Group test: $\theta = w^T w / \sigma_0^2$, $w = (I - G(G^T G)^{-1} G^T)\, y$,
  $\theta \sim \chi^2_{r-3-q_g}$ ($q_g$ constellations in the group),
  $T = C^{-1}(1 - P_{FA})$ ($C$: that chi-square law's CDF)
- Evidence that the group is faulty ($F$) or not ($N$):
  $m(F) = \tfrac12\, C(\theta) / C(T)$ for $\theta \le T$,
  $m(F) = \tfrac12 + \tfrac12 \big(1 - \bar C(\theta) / \bar C(T)\big)$ above
  ($\bar C = 1 - C$); $m(N) = 1 - m(F)$
- Fusion (weighted conflict, reliability $\alpha_g = 1/p_g$):
  $m_j(F) = \sum_{g \ni j} \alpha_g\, m_g(F) / \sum_{g \ni j} \alpha_g$
- Isolation: $m_j(F) > \frac{1}{N} \sum_i m_i(F) + M$
"""


def run(data: Measurements, options: dict):
    n_groups = as_groups(options["gf_groups"])
    margin = options["gf_margin"]
    weights = options["gf_weights"]

    def isolate(h, y, w, p_fa, rng):
        g = select_groups(y.shape[-1], h.shape[-1] + 1, n_groups)
        r = gf_isolate(h, y, g, p_fa, weights_lsq=w, margin=margin, weights=weights)
        return r.isolated, r.m_f, r.threshold

    return run_multi_fault(data, isolate, "mf", "mf_threshold")


SPEC = register(AlgorithmSpec(
    name="gf",
    label="Group evidence fusion, multi-fault (seed 004)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=(
        groups_option("gf_groups"),
        option("gf_margin", float, 0.1, "isolation margin M of seed 004 eq. 3: isolated "
               "when the fused score exceeds the mean score + M", lo=0.0, hi=1.0),
        option("gf_weights", "choice", "pdop", "group weights of the evidence fusion",
               choices=WEIGHTS),
    ),
    reference="Seed 004: grouped fault detection with evidence fusion for multi-satellite "
              "fault isolation in GPS/BDS (spec ALGORITHMS.md section 4).",
))
