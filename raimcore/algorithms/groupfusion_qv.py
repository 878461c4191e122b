"""QV: quality value / confidence index isolation (Patino-Studencka 2010), seed 004's baseline."""

from __future__ import annotations

from ..schema import option
from ._groupfusion_common import as_groups, groups_option, run_multi_fault
from .base import AlgorithmSpec, Measurements, register
from .groupfusion import qv_isolate, select_groups

SUMMARY = (
    "The quality value method tests the same groups as GF but listens only to the groups "
    "that fail: each failing group gives a confidence index to its members. A satellite's "
    "score is the share of its groups that fail, and satellites scoring more than $M$ above "
    "the mean are isolated. One baseline of seed 004."
)

EQUATIONS = r"""
- Same groups and test as GF: group $g$ fails when $\theta_g > T_g$
- Score of satellite $j$, the share of its groups that fail ($\#$: how many):
  $\mathrm{QV}_j = \#\{g \ni j : \theta_g > T_g\} \,/\, \#\{g \ni j\}$
- Isolation: $\mathrm{QV}_j > \frac{1}{N} \sum_i \mathrm{QV}_i + M$
"""


def run(data: Measurements, options: dict):
    n_groups = as_groups(options["qv_groups"])
    margin = options["qv_margin"]
    norm = options["qv_norm"]

    def isolate(h, y, w, p_fa, rng):
        g = select_groups(y.shape[-1], h.shape[-1] + 1, n_groups)
        return qv_isolate(h, y, g, p_fa, weights_lsq=w, margin=margin, norm=norm)

    return run_multi_fault(data, isolate, "qv_score", "qv_threshold")


SPEC = register(AlgorithmSpec(
    name="qv",
    label="Quality value, multi-fault (seed 004 baseline)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=(
        groups_option("qv_groups"),
        option("qv_margin", float, 0.1, "isolation margin M: isolated when the "
               "confidence index exceeds the mean index + M", lo=0.0,
               hi=1.0),
        option("qv_norm", "choice", "share", "normalisation of the confidence index",
               choices=("share", "max")),
    ),
    reference="Patino-Studencka et al. (2010), confidence index RAIM, as cited by seed 004 "
              "(its ref. [6]); reading in ALGORITHMS.md section 4.",
))
