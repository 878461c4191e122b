"""ARAIM availability maps: a tiny grid equals a per-user loop of ``mhss``, MAAST's grid and
region rules, the cos(latitude) coverage, CSV round trip, bad inputs, the CLI and its HTML."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from raimcore.araim import mhss
from raimcore.cli import main
from raimcore.geometry import geodetic_to_ecef, los_enu
from raimcore.measure.error_models import araim_sigmas
from raimcore.sky.constellations import builtin
from raimcore.studies.availability import (
    ISM_PRESETS,
    availability,
    coverage_pct,
    in_polygon,
    read_csv,
    user_grid,
)

ONE_MM = 1e-3
SYSTEMS = ("GPS", "GAL")
#: A small region: two by two users at 20 deg steps around Europe.
EUROPE = [(40.0, 0.0), (60.0, 0.0), (60.0, 20.0), (40.0, 20.0)]


@pytest.fixture(scope="module")
def small():
    return availability(SYSTEMS, lat_step_deg=20, lon_step_deg=20, region=EUROPE,
                        t_step_s=600, duration_s=3000, ism="maast")


def _loop_user(lat_deg, lon_deg, t_s, ism, mask_deg=5.0, user_model="ed259a"):
    """One user, one epoch at a time, through the unbatched kernel (independent geometry:
    ``los_enu`` on ECEF positions)."""
    const = builtin(SYSTEMS)
    sys_idx = np.array([SYSTEMS.index(s) for s in const.systems])
    rx = geodetic_to_ecef(math.radians(lat_deg), math.radians(lon_deg), 0.0)
    p = ism.per_sat(SYSTEMS, sys_idx)
    p_const = ism.per_system(SYSTEMS)["p_const"]
    out = []
    for t in t_s:
        sv = const.positions_ecef_m(np.array([t]))[0]
        u, _ = los_enu(sv, rx)
        el = np.arcsin(np.clip(u[:, 2], -1, 1))
        vis = el >= math.radians(mask_deg)
        g = np.concatenate([-u, (sys_idx[:, None] == np.arange(2)).astype(float)], axis=1)
        s_int, s_acc = araim_sigmas(el, SYSTEMS, sys_idx, ism, user_model)
        r = mhss(g[vis], s_int[vis], s_acc[vis], p["b_nom_m"][vis], p["b_cont_m"][vis],
                 p["p_sat"][vis], p_const)
        ok = (r.vpl_m <= 35) & (r.hpl_m <= 40) & (r.emt_m <= 15) & (r.sigma_acc_v_m <= 1.87)
        out.append((float(r.hpl_m), float(r.vpl_m), bool(ok)))
    return np.array(out)


def test_tiny_grid_equals_a_per_user_loop_of_mhss(small):
    t_s = np.arange(0.0, 3000.0, 600.0)
    assert small.inside.all() and small.lat_deg.size == 4
    for k in range(small.lat_deg.size):
        loop = _loop_user(small.lat_deg[k], small.lon_deg[k], t_s, ISM_PRESETS["maast"])
        assert small.n_epochs[k] == t_s.size
        assert small.n_available[k] == loop[:, 2].sum()
        assert small.availability[k] == pytest.approx(loop[:, 2].mean())
        for name, col, q in (("vpl_median_m", 1, 0.5), ("vpl_p99_m", 1, 0.99),
                             ("hpl_median_m", 0, 0.5), ("hpl_p99_m", 0, 0.99)):
            assert getattr(small, name)[k] == pytest.approx(np.quantile(loop[:, col], q),
                                                            abs=ONE_MM), name


def test_batch_size_and_workers_do_not_change_the_answer(small, monkeypatch):
    import raimcore.studies.availability as mod

    monkeypatch.setattr(mod, "CHUNK_USERS", 1)  # 4 chunks: the pool really runs
    kw = dict(lat_step_deg=20, lon_step_deg=20, region=EUROPE, t_step_s=600,
              duration_s=3000, ism="maast")
    for other in (availability(SYSTEMS, batch_user_epochs=3, **kw),
                  availability(SYSTEMS, workers=2, **kw)):
        for name in ("availability", "vpl_median_m", "vpl_p99_m", "hpl_median_m"):
            np.testing.assert_allclose(getattr(other, name), getattr(small, name),
                                       rtol=1e-12, atol=1e-9)


def test_maast_ism_fails_sigma_acc_and_b2012_passes():
    kw = dict(lat_step_deg=30, lon_step_deg=60, t_step_s=1800, duration_s=7200)
    assert availability(SYSTEMS, ism="maast", **kw).coverage_pct == 0.0
    assert availability(SYSTEMS, **kw).coverage_pct > 50.0  # default: b2012


def test_coverage_is_cos_latitude_weighted_by_hand():
    lat = np.array([0.0, 60.0, -60.0, -90.0])
    share = np.array([1.0, 0.99, 0.995, 0.0])
    # cos: 1, 0.5, 0.5, 0 -> covered 1 + 0.5 of 2.
    assert coverage_pct(share, lat, 0.995) == pytest.approx(75.0)
    assert coverage_pct(share, lat, 0.995, inside=[False, True, True, True]) == \
        pytest.approx(50.0)
    assert coverage_pct([np.nan, 1.0], [0.0, 0.0], 0.5) == pytest.approx(50.0)
    assert math.isnan(coverage_pct([1.0], [-90.0], 0.5))  # no weight at all


def test_world_grid_is_maasts():
    lat_axis, lon_axis, lat, lon, inside = user_grid(10, 10)
    assert lat_axis[0] == -90 and lat_axis[-1] == 80 and lat_axis.size == 18
    assert lon_axis[0] == -180 and lon_axis[-1] == 170 and lon_axis.size == 36
    assert inside.all() and lat.size == 648
    assert (lat[1], lon[1]) == (-90, -170)  # latitude-major order


def test_region_polygon_grid_and_edges():
    tri = [(12.0, -7.0), (48.0, -7.0), (12.0, 33.0)]
    lat_axis, lon_axis, lat, lon, inside = user_grid(10, 10, tri)
    # MAAST: floor(min/step) step .. ceil(max/step) step.
    assert lat_axis.tolist() == [10, 20, 30, 40, 50]
    assert lon_axis.tolist() == [-10, 0, 10, 20, 30, 40]
    got = {(a, b) for a, b, i in zip(lat, lon, inside, strict=True) if i}
    assert (20.0, 0.0) in got and (40.0, 0.0) in got and (50.0, 30.0) not in got
    assert (10.0, 0.0) not in got  # below the polygon
    # Points on an edge or a vertex count as inside (MAAST's inpolygon > 0).
    sq = [(0, 0), (0, 10), (10, 10), (10, 0)]
    assert in_polygon([0, 5, 10, 5, 11], [5, 0, 10, 5, 5], sq).tolist() == \
        [True, True, True, True, False]
    res = availability(SYSTEMS, lat_step_deg=10, lon_step_deg=10, region=tri, t_step_s=1800,
                       duration_s=3600)
    assert np.isnan(res.availability[~res.inside]).all()
    assert np.isfinite(res.availability[res.inside]).all()
    assert res.n_user_epochs == 2 * res.inside.sum()


def test_csv_round_trip(small, tmp_path):
    back = read_csv(small.to_csv(tmp_path / "grid.csv"))
    for name in ("lat_axis_deg", "lon_axis_deg", "lat_deg", "lon_deg", "inside",
                 "availability", "n_epochs", "n_available", "n_unavailable_geometry",
                 "vpl_median_m", "vpl_p99_m", "hpl_median_m", "hpl_p99_m"):
        np.testing.assert_array_equal(getattr(back, name), getattr(small, name))
    assert back.coverage_pct == small.coverage_pct and back.target == small.target
    assert back.settings["systems"] == list(SYSTEMS) and back.settings["ism"] == "maast"


@pytest.mark.parametrize(("kw", "name"), [
    ({"systems": ("GPS", "XXX")}, "systems"),
    ({"systems": ()}, "systems"),
    ({"lat_step_deg": 0}, "lat_step_deg"),
    ({"lon_step_deg": 200}, "lon_step_deg"),
    ({"t_step_s": -1}, "t_step_s"),
    ({"duration_s": math.nan}, "duration_s"),
    ({"region": [(0, 0), (1, 1)]}, "region"),
    ({"region": [(0, 0), (1, 1), (95, 1)]}, "region"),
    ({"algorithm": "gf"}, "algorithm"),
    ({"ism": "nope"}, "ism"),
    ({"ism": {"GPS": {"sigma_ura_m": -1}}}, "ism"),
    ({"user_model": "x"}, "user_model"),
    ({"val_m": 0}, "val_m"),
    ({"target": 1.5}, "target"),
    ({"workers": 0}, "workers"),
    ({"progress": 3}, "progress"),
    ({"constellation": "/nonexistent.alm"}, "constellation"),
    ({"p_thres": 2.0}, "p_thres"),
    ({"bogus": 1}, "bogus"),
])
def test_bad_inputs_are_refused_in_one_line_naming_the_parameter(kw, name):
    kw = dict(kw)
    systems = kw.pop("systems", SYSTEMS)
    with pytest.raises(ValueError) as info:
        availability(systems, duration_s=kw.pop("duration_s", 600), **kw)
    msg = str(info.value)
    assert name in msg and "\n" not in msg, msg


def test_progress_is_called_up_to_the_total():
    calls = []
    res = availability(SYSTEMS, lat_step_deg=45, lon_step_deg=90, duration_s=1200,
                       progress=lambda d, t: calls.append((d, t)))
    assert calls and calls[-1][0] == calls[-1][1] == res.n_user_epochs
    assert all(a[0] <= b[0] for a, b in zip(calls, calls[1:], strict=False))


# -- command line ---------------------------------------------------------------------------

def _one_line_error(capsys, needle: str) -> None:
    err = capsys.readouterr().err.strip()
    assert err.startswith("raim: error: ") and "\n" not in err and needle in err, err


@pytest.mark.parametrize(("argv", "needle"), [
    (["--systems", "GPS,XYZ"], "--systems"),
    (["--step", "0"], "--step"),
    (["--t-step", "-5"], "--t-step"),
    (["--region", "10,10;20"], "--region"),
    (["--region", "10,10;20,20"], "at least 3 vertices"),
    (["--almanac", "/nonexistent.alm"], "not found"),
    (["--workers", "0"], "--workers"),
    (["--target", "150"], "--target"),
    (["--out", "map.png"], "--out must end in .html"),
    (["--csv", "x/y/z.csv"], "does not exist"),
])
def test_cli_refuses_bad_inputs_with_exit_2(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["availability", "--duration", "600", *argv]) == 2
    _one_line_error(capsys, needle)


def test_cli_png_without_browser_is_refused_before_work(capsys, tmp_path, monkeypatch):
    pytest.importorskip("plotly")
    from app import stanford

    monkeypatch.setattr(stanford, "find_browser", lambda: None)
    out = tmp_path / "m.html"
    assert main(["availability", "--out", str(out), "--png", str(tmp_path / "m.png")]) == 2
    _one_line_error(capsys, "Chromium or Chrome")
    assert not out.exists()


def test_cli_writes_csv_and_self_contained_html(capsys, tmp_path):
    pytest.importorskip("plotly")
    from plotly.offline import get_plotlyjs

    out, grid = tmp_path / "m.html", tmp_path / "g.csv"
    assert main(["availability", "--step", "30", "--duration", "1200",
                 "--region=-30,-60;60,-60;60,90", "--out", str(out), "--csv", str(grid)]) == 0
    cap = capsys.readouterr()
    res = read_csv(grid)
    assert f"{res.coverage_pct:.1f} %" in cap.out and "user-epochs/s" in cap.out
    assert "availability [" in cap.err  # the progress bar
    html = out.read_text()
    assert get_plotlyjs() in html  # plotly.js inline
    assert not re.search(r"<script[^>]*\bsrc=", html)
    assert "cdn" not in html.replace(get_plotlyjs(), "").lower()
    assert "ARAIM LPV-200 availability" in html and "coastline" in html


def test_map_figure_has_cells_coastline_and_target_contour(small):
    pytest.importorskip("plotly")
    from app import availability as figure

    fig = figure.map_figure(small)
    kinds = [t.get("name") for t in fig["data"]]
    assert kinds == ["availability", "99.5 % availability", "coastline"]
    heat = fig["data"][0]
    assert np.array(heat["z"], dtype=float).shape == (2, 2)
    # The hover carries the real share (%), the colour its class.
    assert np.array(heat["customdata"], dtype=float)[..., 0].ravel() == \
        pytest.approx(100 * small.availability)
    assert f"{small.coverage_pct:.1f} %" in fig["layout"]["title"]["text"]
    figure.stanford.to_plotly(fig)  # a valid plotly figure
