"""The Stanford-ESA integrity diagram: regions (gLAB's rules), histogram, result CSV, CLI,
HTML without a CDN, the dashboard panel and a real run whose counts add up."""

from __future__ import annotations

import math
import re
import struct

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from raimcore.cli import main
from raimcore.pipeline import run_scenario
from raimcore.scenario import load_scenario
from raimcore.scoring import (
    Rate,
    stanford_esa,
    stanford_from_csv,
    stanford_from_result,
    stanford_from_table,
)
from raimcore.scoring.stanford import REGIONS

AL_M = 40.0
NAN = math.nan
INF = math.inf

# One epoch per row: (PE, PL, region) with AL = 40 m. gLAB graph.py v5.2 (stanford.getPoints):
# fail when PE / PL >= 1; of the fails, PE < AL is MI, PL >= AL unavailable, else HMI;
# PL >= AL unavailable; the rest nominal. NaN (no solution) is unavailable here.
EDGES = [
    (1.0, 5.0, "nominal"),
    (4.999, 5.0, "nominal"),        # just below the diagonal's boundary
    (5.0, 5.0, "mi"),               # PE == PL: misleading (x / y >= 1)
    (6.0, 5.0, "mi"),
    (39.999, 39.0, "mi"),
    (40.0, 39.0, "hmi"),            # PE == AL with PL < AL: hazardous
    (100.0, 39.999, "hmi"),
    (1.0, 40.0, "unavailable"),     # PL == AL: unavailable (y >= AL)
    (1.0, 39.999, "nominal"),
    (50.0, 45.0, "unavailable"),    # PE >= PL above the AL: unavailable (and PE >= PL)
    (NAN, 5.0, "unavailable"),      # no position
    (1.0, NAN, "unavailable"),      # no protection level
    (1.0, INF, "unavailable"),      # an infinite (unavailable) PL
    (-6.0, 5.0, "mi"),              # a signed (vertical) error: its size counts
]


@pytest.mark.parametrize(("pe", "pl", "region"), EDGES)
def test_each_epoch_lands_in_its_gLAB_region(pe, pl, region):
    r = stanford_esa([pe], [pl], AL_M)
    assert r.counts == {k: int(k == region) for k in REGIONS}
    assert r.epochs == 1


def test_edge_table_counts_and_parts_of_unavailable():
    pe, pl, regions = zip(*EDGES, strict=True)
    r = stanford_esa(pe, pl, AL_M)
    assert r.counts == {k: regions.count(k) for k in REGIONS}
    assert r.unavailable_mi == 1          # (50, 45): PE >= PL above the AL
    assert r.no_solution == 2             # the two NaN rows
    assert sum(r.counts.values()) == r.epochs == len(EDGES)
    # Only epochs with a finite PE and PL enter the histogram (not the NaN or inf rows).
    assert int(r.hist_count.sum()) == len(EDGES) - 3
    assert r.shares["mi"] == pytest.approx(regions.count("mi") / len(EDGES))
    rate = r.rate("hmi")
    assert isinstance(rate, Rate) and (rate.k, rate.n) == (2, len(EDGES))
    lo, hi = rate.ci95
    assert lo < rate.value < hi


def test_a_nan_row_does_not_change_its_neighbours():
    pe = np.array([1.0, 6.0, 45.0, 2.0])
    pl = np.array([5.0, 5.0, 30.0, 50.0])
    base = stanford_esa(pe, pl, AL_M).counts
    with_nan = stanford_esa(np.r_[pe, NAN], np.r_[pl, 5.0], AL_M)
    assert with_nan.counts == {**base, "unavailable": base["unavailable"] + 1}
    all_nan = stanford_esa([NAN, NAN], [NAN, 3.0], AL_M)
    assert all_nan.counts == {"nominal": 0, "mi": 0, "hmi": 0, "unavailable": 2}
    assert all_nan.status == "empty" and all_nan.hist_count.size == 0


def test_alarms_change_no_region_but_are_counted():
    pe = [6.0, 6.0, 45.0, 1.0]
    pl = [5.0, 5.0, 30.0, 5.0]
    alarm = np.array([True, False, True, True])
    r = stanford_esa(pe, pl, AL_M, alarm=alarm)
    assert r.counts == stanford_esa(pe, pl, AL_M).counts
    assert (r.mi_alarmed, r.hmi_alarmed) == (1, 1)
    assert stanford_esa(pe, pl, AL_M).mi_alarmed is None
    assert "MI 2 (50%; 1 with an alarm)" in r.summary_line()


@given(st.lists(st.tuples(st.floats(0, 200), st.floats(0, 200) | st.just(NAN)),
                min_size=1, max_size=60),
       st.floats(1, 150))
def test_regions_partition_the_epochs_and_the_histogram_holds_the_finite_ones(pts, al_m):
    pe, pl = np.array(pts, dtype=float).T
    r = stanford_esa(pe, pl, al_m)
    assert sum(r.counts.values()) == r.epochs == len(pts)
    assert int(r.hist_count.sum()) == int(np.isfinite(pl).sum())
    assert 0 <= r.unavailable_mi <= r.unavailable and r.no_solution <= r.unavailable
    # The same epochs in another order: the same counts and histogram.
    k = np.random.default_rng(0).permutation(len(pts))
    s = stanford_esa(pe[k], pl[k], al_m)
    assert s.counts == r.counts
    np.testing.assert_array_equal(s.dense(), r.dense())


def test_batched_input_equals_the_flat_one():
    rng = np.random.default_rng(3)
    pe, pl = rng.uniform(0, 60, (2, 3, 50)), rng.uniform(0, 60, (2, 3, 50))
    pe[0, 1, :5] = NAN
    a, b = stanford_esa(pe, pl, AL_M), stanford_esa(pe.ravel(), pl.ravel(), AL_M)
    assert a.counts == b.counts and a.epochs == 300
    np.testing.assert_array_equal(a.dense(), b.dense())


def test_bins_follow_their_edges_and_agree_with_numpy():
    r = stanford_esa([0.05, 0.1, 0.25, 1.0], [0.0, 0.19, 0.35, 1.05], AL_M)
    assert r.bin_m == 0.1
    # Bin k is [k * 0.1, (k + 1) * 0.1): 0.1 opens bin 1; the range ends past 1.05.
    cells = set(zip(r.hist_pe_bin.tolist(), r.hist_pl_bin.tolist(), strict=True))
    assert cells == {(0, 0), (1, 1), (2, 3), (10, 10)}
    assert r.n_bins == 11 and r.range_m == pytest.approx(1.1)
    np.testing.assert_allclose(r.edges_m[:3], [0.0, 0.1, 0.2])
    rng = np.random.default_rng(1)
    pe, pl = rng.gamma(2.0, 2.0, 500), rng.gamma(6.0, 3.0, 500)
    for bin_m in (0.1, 0.5, 2.0):
        r = stanford_esa(pe, pl, AL_M, bin_m=bin_m)
        ref, _, _ = np.histogram2d(pe, pl, bins=[r.edges_m, r.edges_m])
        np.testing.assert_array_equal(r.dense(), ref)
        assert r.dense().sum() == 500


def test_block_sums_keep_the_total_and_coarsen_the_bins():
    rng = np.random.default_rng(2)
    r = stanford_esa(rng.uniform(0, 30, 400), rng.uniform(0, 30, 400), AL_M)
    fine = r.dense()
    for block in (1, 3, 7, 50):
        coarse = r.dense(block)
        assert coarse.shape == (math.ceil(r.n_bins / block),) * 2
        assert coarse.sum() == fine.sum() == 400
    np.testing.assert_array_equal(r.dense(3)[0, 0], fine[:3, :3].sum())
    with pytest.raises(ValueError, match="block"):
        r.dense(0)


def test_max_range_clips_into_the_last_bins_as_gLAB():
    # (100, 50): error beyond the range, an MI: the corner bin. (100, 200): error beyond,
    # PL larger: one PE bin lower, so it stays above the diagonal (gLAB dealData).
    r = stanford_esa([100.0, 100.0, 5.0], [50.0, 200.0, 5.5], AL_M, max_m=10.0)
    assert r.n_bins == 100 and r.clipped == 2
    cells = set(zip(r.hist_pe_bin.tolist(), r.hist_pl_bin.tolist(), strict=True))
    assert cells == {(99, 99), (98, 99), (50, 55)}
    # The regions still see the real values.
    assert (r.hmi, r.unavailable, r.nominal) == (0, 2, 1)


def test_docstring_examples_run():
    import doctest

    import raimcore.scoring.stanford as mod

    result = doctest.testmod(mod)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize(("args", "kw", "match"), [
    (([1.0, 2.0], [1.0]), {}, "same shape"),
    (([1.0], [-1.0]), {}, "pl_m must be >= 0"),
    (([1.0], [1.0]), {"al_m": 0.0}, "al_m must be"),
    (([1.0], [1.0]), {"bin_m": 0.0}, "bin_m must be"),
    (([1.0], [1.0]), {"bin_m": NAN}, "bin_m must be"),
    (([1.0], [1.0]), {"max_m": 0.1}, "at least two bins"),
    (([1.0], [1.0]), {"alarm": [1]}, "alarm must be a boolean"),
])
def test_bad_arguments_are_refused(args, kw, match):
    kw = {"al_m": AL_M, **kw}
    with pytest.raises(ValueError, match=match):
        stanford_esa(*args, **kw)


# -- runs, tables and CSV ------------------------------------------------------------------

@pytest.fixture(scope="module")
def mss_result():
    return run_scenario(load_scenario("default", algorithm="mss", hal_m=40.0, val_m=50.0))


def test_mss_run_gives_a_diagram_whose_counts_add_up_to_the_epochs(mss_result):
    d = stanford_from_result(mss_result)
    n = len(mss_result.table)
    for r, al in ((d.horizontal, 40.0), (d.vertical, 50.0)):
        assert r.epochs == n and sum(r.counts.values()) == n and r.al_m == al
        assert int(r.hist_count.sum()) == n  # every epoch has a position and a PL
    assert d.pl_columns == ("hpl_m", "vpl_m") and d.error == "before"
    # The G10 ramp drives the full-set error far past its PL: MI, then HMI, each alarmed
    # by the detector; after exclusion every epoch is nominal.
    assert d.horizontal.hmi > 0 and d.horizontal.hmi_alarmed == d.horizontal.hmi
    after = stanford_from_result(mss_result, error="after")
    assert after.horizontal.counts["nominal"] == n
    # The table's own PL columns, checked by hand: MI is PE >= PL below the AL.
    t = mss_result.table
    pe, pl = t["hpe_before_m"], t["hpl_m"]
    assert d.horizontal.mi == int(((pe >= pl) & (pe < 40.0) & (pl < 40.0)).sum())
    classic = stanford_from_result(mss_result, pl="classic")
    assert classic.pl_columns == ("hpl_classic_m", "vpl_classic_m")


def test_the_csv_gives_the_same_diagram_as_the_run(mss_result, tmp_path):
    path = mss_result.table.to_csv(tmp_path / "r.csv")
    a = stanford_from_result(mss_result)
    b = stanford_from_csv(path, 40.0, 50.0)
    for x, y in ((a.horizontal, b.horizontal), (a.vertical, b.vertical)):
        assert x.counts == y.counts and x.mi_alarmed == y.mi_alarmed
        np.testing.assert_array_equal(x.dense(), y.dense())
    assert b.source == "r.csv"


def test_csv_empty_fields_are_unavailable_epochs(tmp_path):
    path = tmp_path / "hand.csv"
    path.write_text("t_s,hpe_before_m,vpe_before_m,hpl_m,vpl_m,alarm\n"
                    "0,1.0,2.0,10.0,20.0,False\n"
                    "1,,,,,False\n"
                    "2,12.0,-30.0,10.0,20.0,True\n")
    d = stanford_from_csv(path, 40.0, 50.0)
    assert d.horizontal.counts == {"nominal": 1, "mi": 1, "hmi": 0, "unavailable": 1}
    assert d.vertical.counts == {"nominal": 1, "mi": 1, "hmi": 0, "unavailable": 1}
    assert d.horizontal.no_solution == 1 and d.horizontal.mi_alarmed == 1


@pytest.mark.parametrize(("text", "match"), [
    ("t_s,hpe_before_m,vpe_before_m\n0,1,2\n", "no protection-level columns hpl_m"),
    ("t_s,hpe_before_m,vpe_before_m,hpl_m,vpl_m\n0,x,2,3,4\n", "row 2, column "
                                                                "hpe_before_m"),
    ("t_s,hpl_m,vpl_m\n0,3,4\n", "no column hpe_before_m"),
    ("", "empty file"),
])
def test_bad_csv_is_refused_in_one_line(tmp_path, text, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        stanford_from_csv(path, 40.0, 50.0)


def test_table_without_pl_and_bad_options_are_refused(mss_result):
    cols = {k: v for k, v in mss_result.table.columns.items() if not k.startswith("hpl")}
    with pytest.raises(ValueError, match="no protection-level columns hpl_m"):
        stanford_from_table(cols, 40.0, 50.0)
    with pytest.raises(ValueError, match="error must be one of before, after"):
        stanford_from_result(mss_result, error="during")
    with pytest.raises(ValueError, match="it has hpl_classic_m"):
        stanford_from_result(mss_result, pl="nope")
    with pytest.raises(ValueError, match="no such file"):
        stanford_from_csv("/nonexistent/r.csv", 40.0, 50.0)


# -- command line ---------------------------------------------------------------------------

@pytest.fixture
def need_plotly():
    pytest.importorskip("plotly")


def _one_line_error(capsys, needle: str) -> None:
    err = capsys.readouterr().err.strip()
    assert err.startswith("raim: error: ") and "\n" not in err and needle in err, err


def test_cli_refuses_bad_inputs_with_exit_2(need_plotly, tmp_path, capsys, monkeypatch):
    assert main(["stanford", str(tmp_path / "nope.csv")]) == 2
    _one_line_error(capsys, "no such file")
    gf = tmp_path / "gf.csv"
    assert main(["run", "default", "-a", "gf", "-q", "--out", str(gf)]) == 0
    capsys.readouterr()
    assert main(["stanford", str(gf)]) == 2
    _one_line_error(capsys, "no protection-level columns")
    assert main(["stanford", "default", "-a", "gf"]) == 2
    _one_line_error(capsys, "algorithm gf has no protection-level columns")
    assert main(["stanford", "default", "--out", str(tmp_path / "x.png")]) == 2
    _one_line_error(capsys, "--out must end in .html")
    assert main(["stanford", str(gf), "--fault", "G10,step,50,10"]) == 2
    _one_line_error(capsys, "a result CSV is not run again")
    assert main(["stanford", str(gf), "--set", "sigma_m=3"]) == 2
    _one_line_error(capsys, "takes only --set hal_m=... and --set val_m=...")
    assert main(["stanford", "default", "--bin", "0"]) == 2
    _one_line_error(capsys, "--bin must be a finite number > 0")
    from app import stanford

    monkeypatch.setattr(stanford, "find_browser", lambda: None)
    out = tmp_path / "d.html"
    assert main(["stanford", "default", "--out", str(out), "--png",
                 str(tmp_path / "d.png")]) == 2
    _one_line_error(capsys, "needs a Chromium or Chrome browser on PATH")
    assert not out.exists()  # refused before any work


def _outside_plotlyjs(html: str) -> str:
    from plotly.offline import get_plotlyjs

    bundle = get_plotlyjs()
    assert bundle in html  # plotly.js is inline
    return html.replace(bundle, "")


def test_cli_writes_self_contained_html_from_a_csv(need_plotly, mss_result, tmp_path, capsys):
    csv_path = mss_result.table.to_csv(tmp_path / "r.csv")
    out = tmp_path / "r.html"
    assert main(["stanford", str(csv_path), "--set", "hal_m=40", "--set", "val_m=50",
                 "--out", str(out)]) == 0
    text = capsys.readouterr().out
    d = stanford_from_result(mss_result)
    assert d.horizontal.summary_line() in text and f"diagram written to {out}" in text
    html = out.read_text()
    # No script or style from elsewhere: nothing but the inline bundle mentions a CDN
    # (plotly.js itself holds map-tile URLs it would only fetch for map traces).
    assert not re.search(r"<script[^>]*\bsrc=", html)
    assert "cdn" not in _outside_plotlyjs(html).lower()
    assert "Stanford-ESA integrity diagram" in html


def test_cli_default_output_name_and_csv_alert_limit_note(need_plotly, mss_result, tmp_path, capsys,
                                                          monkeypatch):
    csv_path = mss_result.table.to_csv(tmp_path / "run1.csv")
    monkeypatch.chdir(tmp_path)
    assert main(["stanford", str(csv_path)]) == 0
    text = capsys.readouterr().out
    assert "a result CSV keeps no alert limits: hal_m 556 m, val_m 1000 m" in text
    assert (tmp_path / "run1-stanford.html").is_file()


# -- figure and dashboard panel --------------------------------------------------------------

def test_figure_has_both_diagrams_diagonal_and_alert_limits(need_plotly, mss_result):
    from app import stanford

    d = stanford_from_result(mss_result, error="after")
    fig = stanford.diagram_figure(d)
    heat = [tr for tr in fig["data"] if tr["type"] == "heatmap"]
    assert [tr["xaxis"] for tr in heat] == ["x", "x2"]
    for tr, r in zip(heat, (d.horizontal, d.vertical), strict=True):
        assert int(np.asarray(tr["customdata"]).sum()) == r.epochs  # every epoch drawn
        z = np.asarray(tr["z"], dtype=float)
        np.testing.assert_allclose(z[np.isfinite(z)],
                                   np.log10(np.asarray(tr["customdata"])[np.isfinite(z)]))
    lines = [s for s in fig["layout"]["shapes"] if s["type"] == "line"]
    diag = [s for s in lines if s["x0"] == 0 and s["y0"] == 0 and s["x1"] == s["y1"]]
    assert len(diag) == 2
    assert {40.0, 50.0} <= {s["x0"] for s in lines}  # HAL, VAL verticals
    heads = " ".join(a["text"] for a in fig["layout"]["annotations"])
    assert "nominal 600 (100%)" in heads and "HAL 40 m" in heads and "VAL 50 m" in heads
    stanford.to_plotly(fig)  # a valid plotly figure


def test_panel_is_offered_for_runs_with_protection_levels_only(need_plotly, mss_result):
    from app import panels
    from app.session import run_view

    view = run_view(mss_result)
    built = dict(panels.panels_for(view))
    assert "stanford" in built
    fig = built["stanford"](view)
    assert fig.height_px == fig.layout["height"] > 0
    assert not fig.marker  # its x axis is an error, not the time
    fig.to_plotly(0)  # valid plotly (the dashboard's HTML export goes this way)
    data = fig.to_dict(0)["data"]
    heat = [tr for tr in data if tr["type"] == "heatmap"]
    assert sum(int(np.asarray(tr["customdata"]).sum()) for tr in heat) == 2 * len(view.t_s)
    # The current epoch is marked on both diagrams and follows the time slider.
    now = [tr for tr in data if tr.get("name") == "now"]
    assert len(now) == 2
    assert now[0]["x"] == [pytest.approx(mss_result.table["hpe_before_m"][0])]
    later = fig.time_state(300)["traces"]
    assert later[0]["y"] == [pytest.approx(mss_result.table["hpl_m"][300], abs=1e-4)]
    gf_view = run_view(run_scenario(load_scenario("default", algorithm="gf")))
    assert "stanford" not in dict(panels.panels_for(gf_view))


@pytest.mark.browser
def test_png_is_rendered_by_headless_chromium(need_plotly, mss_result, tmp_path):
    from app import stanford

    if stanford.find_browser() is None:
        pytest.skip(stanford.png_requirement())
    fig = stanford.diagram_figure(stanford_from_result(mss_result))
    png = stanford.write_png(fig, tmp_path / "d.png")
    head = png.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", head[16:24])
    assert width >= fig["layout"]["width"] and height >= fig["layout"]["height"]
