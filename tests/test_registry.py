"""Every registered algorithm keeps the common contract on shared scenarios."""

import numpy as np
import pytest

from raimcore import algorithms
from raimcore.algorithms.base import (
    STATUS_NO_ISOLATION,
    STATUS_NOT_ARMED,
    STATUS_OK,
    STATUS_UNAVAILABLE,
)
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario

STATUSES = {STATUS_OK, STATUS_NO_ISOLATION, STATUS_UNAVAILABLE, STATUS_NOT_ARMED}


@pytest.mark.parametrize("name", algorithms.names())
def test_algorithm_contract_on_a_short_scenario(name):
    spec = algorithms.get(name)
    assert spec.label and spec.summary and spec.equations
    s = load_scenario("default", algorithm=name, duration_s=60, sigma_m=3.0)
    r = run_scenario(s)
    t = r.table
    assert len(t) == 61
    assert set(t["status"]) <= STATUSES
    ok = t["status"] != STATUS_UNAVAILABLE
    assert np.all(np.isfinite(t["hpe_before_m"][ok]))
    # Unused satellites are never excluded.
    assert not np.any(r.output.excluded & ~r.measurements.used)


@pytest.mark.parametrize("name", algorithms.names())
def test_algorithm_reports_unavailable_with_too_few_satellites(name):
    s = load_scenario("seed000-step", algorithm=name, duration_s=30, restrict=[
        {"sats": ["G03", "G04", "G07"], "t0_s": 10, "t1_s": 20}])
    t = run_scenario(s).table
    window = (t["t_s"] >= 10) & (t["t_s"] < 20)
    assert np.all(t["status"][window] == STATUS_UNAVAILABLE)
    assert not t["alarm"][window].any()
    # Unavailable epochs carry no position (the pipeline blanks them).
    assert np.all(np.isnan(t["hpe_before_m"][window]))
    assert np.all(np.isnan(t["hpe_after_m"][window]))


def test_unknown_algorithm_lists_the_registered_ones():
    with pytest.raises(ValueError, match="algorithm must be one of .*parity"):
        algorithms.get("nope")
