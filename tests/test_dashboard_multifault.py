"""The dashboard's multi-fault panel (seed 004: GF / RS / QV), headless."""

import numpy as np
import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from app import panels  # noqa: E402
from app.session import run_view  # noqa: E402
from raimcore import algorithms  # noqa: E402
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario  # noqa: E402


def test_gf_rs_qv_are_offered_by_the_registry():
    assert {"gf", "rs", "qv"} <= set(algorithms.names())


@pytest.mark.parametrize(("name", "score"), [("gf", "mf"), ("qv", "qv_score"),
                                              ("rs", "rs_isolated")])
def test_multifault_panel_shows_score_threshold_and_isolated_set_vs_truth(name, score):
    r = run_scenario(load_scenario("seed004-multi", algorithm=name, duration_s=200))
    view = run_view(r)
    built = dict(panels.panels_for(view))
    assert f"multifault:{score}" in built
    assert score not in panels.per_sat_keys(view)  # claimed: not repeated generically
    fig = built[f"multifault:{score}"](view).to_plotly(150)
    traces = {t.name: t for t in fig.data}
    thr_col = {"mf": "mf_threshold", "qv_score": "qv_threshold",
               "rs_isolated": "rs_threshold"}[score]
    thr = traces[thr_col]
    np.testing.assert_allclose(np.asarray(thr.y, float), r.output.columns[thr_col],
                               equal_nan=True)
    # The truth rows are the three faulty satellites; excluded markers match the output.
    truth = traces["faulty (truth)"]
    assert set(truth.y) == {"G05", "C21", "C37"}
    assert len(traces["excluded"].x) == int(r.output.excluded.sum())
    title = fig.layout.title
    assert title.text == "Multi-fault isolation"  # short: fits the narrowest panel
    assert title.subtitle.text.startswith("isolated set = truth at")
