"""RS: random search multi-fault isolation (Chen & Zhang 2011), seed 004's baseline."""

from __future__ import annotations

import numpy as np

from ..schema import option
from ._groupfusion_common import run_multi_fault
from .base import AlgorithmSpec, Measurements, register
from .groupfusion import rs_isolate

SUMMARY = (
    "Random search looks for a consistent subset first: it draws random groups of 4 + q "
    "satellites until one passes the chi-square test, and presumes it fault-free. The "
    "other satellites are then added one at a time; a satellite whose addition makes the "
    "test fail is isolated, the others join the consistent set. One baseline of seed 004."
)

EQUATIONS = r"""
- Draw random subsets $S$ of $r = 4 + q$ satellites until $\theta_S \le T_S$
- For each other satellite $j$ (random order): isolate $j$ if
  $\theta_{S \cup \{j\}} > T_{S \cup \{j\}}$, else $S \leftarrow S \cup \{j\}$
"""


def run(data: Measurements, options: dict):
    draws = options["rs_draws"]

    def isolate(h, y, w, p_fa, rng):
        iso = rs_isolate(h, y, p_fa, rng, weights_lsq=w, n_draws=draws)
        return iso, iso.astype(float), np.full(y.shape[0], 0.5)

    return run_multi_fault(data, isolate, "rs_isolated", "rs_threshold")


SPEC = register(AlgorithmSpec(
    name="rs",
    label="Random search, multi-fault (seed 004 baseline)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=(option("rs_draws", int, 50, "random subsets drawn per epoch", lo=1, hi=10_000),),
    reference="Chen & Zhang (2011), random search multi-fault RAIM, as cited by seed 004 "
              "(its ref. [5]); reading in ALGORITHMS.md section 4.",
))
