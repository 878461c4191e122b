"""GF: group fault detection with evidence fusion for multiple faults (seed 004)."""

from __future__ import annotations

from .._validate import check_choice, check_range
from ._groupfusion_common import groups_option, run_multi_fault
from .base import AlgorithmSpec, EpochData, register
from .groupfusion import WEIGHTS, gf_isolate, select_groups

SUMMARY = (
    "Several satellites may be faulty at once. The visible satellites are split into many "
    "overlapping groups of 4 + q (six for GPS + BeiDou), and each group is tested on its "
    "own with the least-squares residual chi-square. A group's statistic becomes evidence "
    "m(F) that its members are faulty: 0.5 exactly at the threshold, towards 1 far above "
    "it, towards 0 far below. Each satellite fuses the evidence of all its groups (the "
    "weighted distribution of conflict, which here is a reliability-weighted mean), and "
    "every satellite whose fused m(F) stands more than M above the mean of all satellites "
    "is isolated - however many there are. Watch the per-satellite m(F) against the "
    "isolation threshold."
)

EQUATIONS = r"""
- Groups: $L = C_N^r$, $r = 4 + q$; keep $L_1 = \lfloor L/K \rfloor \approx N^2$ at spacing $K$
- Group test: $\theta = w^T w/\sigma_0^2$, $w = (I - G(G^TG)^{-1}G^T)y$,
  $\theta \sim \chi^2_{r-3-q_g}$, $T = \chi^{2\,-1}(1 - P_{FA})$
- Evidence: $m(F) = \tfrac12 F(\theta)/F(T)$ for $\theta \le T$,
  $m(F) = \tfrac12 + \tfrac12\,(1 - \bar F(\theta)/\bar F(T))$ above; $m(N) = 1 - m(F)$
- Fusion (weighted conflict, $\alpha = 1/p$): $m(F) = \sum_g \alpha_g m_g(F) / \sum_g \alpha_g$
- Isolation: $m_j(F) > \frac1N \sum_i m_i(F) + M$
"""


def run(data: EpochData, options: dict):
    n_groups = groups_option(options, "gf_groups")
    margin = check_range("gf_margin", options.get("gf_margin", 0.1), 0.0, 1.0)
    weights = check_choice("gf_weights", options.get("gf_weights", "pdop"), WEIGHTS)

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
    options={"gf_groups": 0, "gf_margin": 0.1, "gf_weights": "pdop"},
    reference="Seed 004: grouped fault detection with evidence fusion for multi-satellite "
              "fault isolation in GPS/BDS (spec ALGORITHMS.md section 4).",
))
