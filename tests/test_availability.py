"""ARAIM availability maps: a tiny grid equals a per-user loop of ``mhss`` (and of the MSS and
classic PL kernels), MAAST's grid and region rules, the cos(latitude) coverage, CSV round trip,
the resumable ledger, the real YUMA almanac, bad inputs, the CLI and its HTML."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import raimcore.studies.availability as mod
from raimcore.algorithms import mss as ss
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
SMALL = dict(lat_step_deg=20, lon_step_deg=20, region=EUROPE, t_step_s=600, duration_s=3000,
             ism="maast")
#: The GPS YUMA almanac of week 819 (31 satellites, all healthy), shared by the projects.
ALMANAC = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "yuma_week819.alm"
needs_almanac = pytest.mark.skipif(not ALMANAC.is_file(), reason=f"{ALMANAC} absent")


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


# -- mss and classic protection levels ----------------------------------------------------

def _loop_user_ss(lat_deg, lon_deg, t_s, ism, algorithm):
    """One user, one epoch at a time: the unbatched MSS / classic kernel on the satellites in
    view, weights 1 / sigma_int^2 (independent geometry through ``los_enu``)."""
    const = builtin(SYSTEMS)
    sys_idx = np.array([SYSTEMS.index(s) for s in const.systems])
    rx = geodetic_to_ecef(math.radians(lat_deg), math.radians(lon_deg), 0.0)
    fn = ss.mss if algorithm == "mss" else ss.classic_raim
    out = []
    for t in t_s:
        u, _ = los_enu(const.positions_ecef_m(np.array([t]))[0], rx)
        el = np.arcsin(np.clip(u[:, 2], -1, 1))
        vis = el >= math.radians(5.0)
        h = np.concatenate([-u, (sys_idx[:, None] == np.arange(2)).astype(float)], axis=1)
        s_int, _ = araim_sigmas(el, SYSTEMS, sys_idx, ism, "ed259a")
        r = fn(h[vis], np.zeros(vis.sum()), 1.0 / s_int[vis] ** 2, np.ones(vis.sum(), bool),
               mod.PL_P_FA, mod.PL_P_MD)
        out.append((float(r.hpl_m), float(r.vpl_m), bool(r.vpl_m <= 35 and r.hpl_m <= 40)))
    return np.array(out)


@pytest.mark.parametrize("algorithm", ["mss", "classic"])
def test_tiny_grid_equals_a_per_user_loop_of_the_pl_kernel(algorithm):
    res = availability(SYSTEMS, algorithm=algorithm, **SMALL)
    t_s = np.arange(0.0, 3000.0, 600.0)
    for k in range(res.lat_deg.size):
        loop = _loop_user_ss(res.lat_deg[k], res.lon_deg[k], t_s, ISM_PRESETS["maast"],
                             algorithm)
        assert res.n_available[k] == loop[:, 2].sum()
        for name, col, q in (("vpl_median_m", 1, 0.5), ("vpl_p99_m", 1, 0.99),
                             ("hpl_median_m", 0, 0.5), ("hpl_p99_m", 0, 0.99)):
            assert getattr(res, name)[k] == pytest.approx(np.quantile(loop[:, col], q),
                                                          abs=ONE_MM), name
    # EMT and sigma_acc do not apply: said in the settings and the notes.
    assert res.settings["emt_max_m"] is None and res.settings["sigma_acc_max_m"] is None
    assert res.settings["criteria"] == "VPL <= 35 m, HPL <= 40 m"
    assert any("do not apply" in n for n in res.notes)
    # With MAAST's ISM the ARAIM map is 0 % (sigma_acc); these PLs do not look at it.
    assert res.availability.min() > 0.0


def test_mss_pl_is_at_least_the_classic_one_and_follows_p_md():
    kw = dict(SMALL, ism="b2012")
    m = availability(SYSTEMS, algorithm="mss", **kw)
    c = availability(SYSTEMS, algorithm="classic", **kw)
    loose = availability(SYSTEMS, algorithm="mss", p_md=0.1, **kw)
    # Both share slopes; MSS adds a noise term, so its PL is larger (mss.py docstring).
    assert np.all(m.vpl_median_m > c.vpl_median_m)
    assert np.all(loose.vpl_median_m < m.vpl_median_m)  # a laxer P_md, smaller PLs
    assert loose.settings["p_md"] == 0.1 and m.settings["p_fa"] == mod.PL_P_FA


def test_mss_with_too_few_satellites_is_unavailable_not_nan():
    res = availability(("GPS",), algorithm="mss", mask_deg=60, **dict(SMALL, ism="b2012"))
    assert (res.n_unavailable_geometry > 0).all()
    assert np.isinf(res.vpl_p99_m).all() and (res.availability < 1).all()


# -- resumable ledger ---------------------------------------------------------------------

_FIELDS = ("availability", "n_epochs", "n_available", "n_unavailable_geometry",
           "vpl_median_m", "vpl_p99_m", "hpl_median_m", "hpl_p99_m")


def _same(a, b) -> None:
    for name in _FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    assert a.coverage_pct == b.coverage_pct


@pytest.fixture()
def count_chunks(monkeypatch):
    """Chunks of one user each (4 in SMALL), and a count of the chunks computed."""
    monkeypatch.setattr(mod, "CHUNK_USERS", 1)
    calls = []
    real = mod._run_users
    monkeypatch.setattr(mod, "_run_users", lambda t, p=None: calls.append(1) or real(t, p))
    return calls


def test_ledger_rerun_reuses_every_chunk_and_gives_identical_results(small, tmp_path,
                                                                     count_chunks):
    first = availability(SYSTEMS, ledger_dir=tmp_path / "led", **SMALL)
    assert len(count_chunks) == 4 and len(list((tmp_path / "led").glob("chunk_*.npz"))) == 4
    _same(first, small)
    again = availability(SYSTEMS, ledger_dir=tmp_path / "led", target=0.5, **SMALL)
    assert len(count_chunks) == 4  # nothing computed again (target is not in the key)
    for name in _FIELDS:
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name))
    assert "4 of 4 chunks reused, 0 computed" in again.notes[-1]


def test_ledger_written_by_a_pool_is_resumed_in_process(small, tmp_path, monkeypatch):
    monkeypatch.setattr(mod, "CHUNK_USERS", 2)
    availability(SYSTEMS, ledger_dir=tmp_path, workers=2, **SMALL)
    assert len(list(tmp_path.glob("chunk_*.npz"))) == 2
    monkeypatch.setattr(mod, "_run_users", lambda *a: pytest.fail("computed again"))
    _same(availability(SYSTEMS, ledger_dir=tmp_path, **SMALL), small)


def test_interrupted_run_resumes_where_it_stopped(small, tmp_path, count_chunks):
    def stop_at_third(done, total):
        if done > 2 * total // 4:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        availability(SYSTEMS, ledger_dir=tmp_path, progress=stop_at_third, **SMALL)
    assert len(count_chunks) == 3  # the third was computed, interrupted before its save
    assert len(list(tmp_path.glob("chunk_*.npz"))) == 2
    assert not list(tmp_path.glob("*.part"))
    seen = []
    res = availability(SYSTEMS, ledger_dir=tmp_path, progress=lambda d, t: seen.append(d),
                       **SMALL)
    assert len(count_chunks) == 5  # only the two missing chunks
    assert seen[0] == 2 * 5 and seen[-1] == 4 * 5  # the reused chunks count as done
    _same(res, small)
    assert "2 of 4 chunks reused, 2 computed" in res.notes[-1]


@pytest.mark.parametrize(("change", "differs"), [
    ({"mask_deg": 10.0}, "mask_deg"),
    ({"ism": "b2012"}, "ism"),
    ({"duration_s": 3600}, "epochs"),
    ({"algorithm": "classic"}, "algorithm"),
    ({"p_thres": 9e-8}, "araim_params"),
])
def test_ledger_of_other_parameters_is_refused_or_started_afresh(change, differs, small,
                                                                 tmp_path, count_chunks):
    availability(SYSTEMS, ledger_dir=tmp_path, **SMALL)
    kw = dict(SMALL, **change)
    with pytest.raises(ValueError) as info:
        availability(SYSTEMS, ledger_dir=tmp_path, **kw)
    msg = str(info.value)
    assert "ledger_dir" in msg and differs in msg and "\n" not in msg, msg
    assert len(count_chunks) == 4  # refused before any work
    fresh = availability(SYSTEMS, ledger_dir=tmp_path, resume=False, **kw)
    assert len(count_chunks) == 8 and any("started afresh" in n for n in fresh.notes)
    _same(fresh, availability(SYSTEMS, **kw))
    # The ledger now holds the new parameters: resumed as they are, refused for the old.
    assert "4 of 4 chunks reused" in availability(SYSTEMS, ledger_dir=tmp_path,
                                                  **kw).notes[-1]
    with pytest.raises(ValueError, match="other parameters"):
        availability(SYSTEMS, ledger_dir=tmp_path, **SMALL)


def test_damaged_chunk_is_computed_again(small, tmp_path, count_chunks):
    availability(SYSTEMS, ledger_dir=tmp_path, **SMALL)
    (tmp_path / "chunk_00001.npz").write_bytes(b"not a zip")
    res = availability(SYSTEMS, ledger_dir=tmp_path, **SMALL)
    assert len(count_chunks) == 5
    _same(res, small)


def test_ledger_dir_that_is_a_file_is_refused(tmp_path):
    f = tmp_path / "x"
    f.write_text("")
    with pytest.raises(ValueError, match="ledger_dir.*is a file"):
        availability(SYSTEMS, ledger_dir=f, **SMALL)


# -- the real YUMA almanac -----------------------------------------------------------------

@needs_almanac
def test_yuma_almanac_uses_its_healthy_satellites_and_beats_the_nominal_24(tmp_path):
    kw = dict(lat_step_deg=45, lon_step_deg=90, t_step_s=3600, duration_s=6 * 3600,
              ism="b2012")
    alm = availability(("GPS",), constellation=str(ALMANAC), **kw)
    nom = availability(("GPS",), **kw)
    assert alm.settings["n_satellites"] == {"GPS": 31} and alm.settings["unhealthy"] == []
    assert nom.settings["n_satellites"] == {"GPS": 24}
    assert alm.settings["constellation"] == str(ALMANAC)
    # 31 satellites instead of 24: more in view, a better geometry, smaller PLs.
    fin = np.isfinite(alm.vpl_median_m) & np.isfinite(nom.vpl_median_m)
    assert fin.sum() >= 8
    assert np.median(alm.vpl_median_m[fin]) < np.median(nom.vpl_median_m[fin])
    assert alm.n_available.sum() >= nom.n_available.sum()
    # Set PRN 5 unhealthy: it is left out, and named.
    text = ALMANAC.read_text().split("\n")
    i = next(k for k, line in enumerate(text) if line.startswith("ID:") and
             line.split()[-1] == "05")
    assert text[i + 1].startswith("Health:")
    text[i + 1] = "Health:                     063"
    sick = tmp_path / "sick.alm"
    sick.write_text("\n".join(text))
    one_less = availability(("GPS",), constellation=str(sick), **kw)
    assert one_less.settings["n_satellites"] == {"GPS": 30}
    assert one_less.settings["unhealthy"] == ["G05"]
    assert not np.array_equal(one_less.vpl_median_m, alm.vpl_median_m)


@needs_almanac
def test_gal_alone_from_a_gps_almanac_is_refused_in_one_line():
    with pytest.raises(ValueError) as info:
        availability(("GPS", "GAL"), constellation=str(ALMANAC), duration_s=600)
    assert "no healthy GAL" in str(info.value) and "\n" not in str(info.value)


@needs_almanac
def test_cli_with_the_yuma_almanac(capsys, tmp_path):
    grid = tmp_path / "g.csv"
    assert main(["availability", "--systems", "GPS", "--almanac", str(ALMANAC), "--step",
                 "60", "--duration", "3600", "--t-step", "1800", "-q", "--csv",
                 str(grid)]) == 0
    res = read_csv(grid)
    assert res.settings["n_satellites"] == {"GPS": 31}
    assert "GPS" in capsys.readouterr().out


# -- command line ---------------------------------------------------------------------------
# ``raim availability`` is ``app.availability.add_subcommand``, registered by ``app.cli``.

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
def test_cli_refuses_bad_inputs_with_exit_2(argv, needle, capsys, tmp_path,
                                            monkeypatch):
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


def test_cli_writes_csv_and_self_contained_html(capsys, tmp_path, monkeypatch):
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
    from app import stanford

    stanford.to_plotly(fig)  # a valid plotly figure


# -- the subcommand of app/availability.py (algorithm, ledger, resume) ----------------------

@pytest.fixture()
def new_cli(monkeypatch):
    """``raim`` with the ``availability`` subcommand of :mod:`app.availability`."""
    from app import availability as sub

    return sub


TINY = ["--step", "20", "--region=40,0;60,0;60,20;40,20", "--t-step", "600", "--duration",
        "3000", "-q"]


def test_new_cli_help_documents_algorithms_and_resume(new_cli, capsys):
    with pytest.raises(SystemExit):
        main(["availability", "--help"])
    out = capsys.readouterr().out
    for needle in ("--algorithm", "{araim,mss,classic}", "--ledger DIR", "--resume",
                   "--no-resume", "do not apply", "resumes", f"{mod.PL_P_FA:g}"):
        assert needle in out, needle


def test_new_cli_mss_map_says_emt_does_not_apply(new_cli, capsys, tmp_path):
    out, grid = tmp_path / "m.html", tmp_path / "g.csv"
    assert main(["availability", *TINY, "--algorithm", "mss", "--p-md", "1e-2", "--out",
                 str(out), "--csv", str(grid)]) == 0
    text = capsys.readouterr().out
    assert "mss:" in text and "note: EMT and sigma_acc are ARAIM outputs" in text
    res = read_csv(grid)
    assert res.settings["algorithm"] == "mss" and res.settings["p_md"] == 0.01
    assert res.notes and "do not apply" in res.notes[0]
    html = out.read_text()
    assert "MSS (solution separation) LPV-200 availability" in html
    assert "EMT, sigma_acc do not apply to mss" in html


def test_new_cli_ledger_resumes_after_ctrl_c_and_refuses_other_parameters(
        new_cli, capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(mod, "CHUNK_USERS", 1)
    led, grid = tmp_path / "led", tmp_path / "g.csv"
    calls = []

    class Interrupting:
        def __init__(self, enabled):
            pass

        def __call__(self, done, total):
            calls.append(done)
            if len(calls) == 3:
                raise KeyboardInterrupt

    monkeypatch.setattr(new_cli, "ProgressBar", Interrupting)
    argv = ["availability", *TINY, "--ledger", str(led), "--csv", str(grid)]
    assert main(argv) == 130  # raim: interrupted
    assert len(list(led.glob("chunk_*.npz"))) == 2 and not grid.exists()
    monkeypatch.setattr(new_cli, "ProgressBar", lambda enabled: None)
    capsys.readouterr()
    assert main(argv) == 0
    assert "2 of 4 chunks reused, 2 computed" in capsys.readouterr().out
    resumed = read_csv(grid)
    assert main(["availability", *TINY, "--csv", str(tmp_path / "plain.csv")]) == 0
    plain = read_csv(tmp_path / "plain.csv")
    for name in _FIELDS:
        np.testing.assert_array_equal(getattr(resumed, name), getattr(plain, name))
    # Other parameters: refused in one line naming the option and what differs.
    assert main([*argv, "--mask", "10"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("raim: error: --ledger ") and "\n" not in err, err
    assert "mask_deg" in err and "--no-resume" in err and "resume=False" not in err, err
    assert main([*argv, "--mask", "10", "--no-resume"]) == 0
    assert "started afresh" in capsys.readouterr().out


@pytest.mark.parametrize(("argv", "needle"), [
    (["--algorithm", "mss", "--p-fa", "2"], "--p-fa"),
    (["--algorithm", "classic", "--p-md", "0"], "--p-md"),
    (["--p-fa", "1e-3"], "--p-fa applies to --algorithm mss or classic"),
    (["--algorithm", "mss", "--fde"], "--fde applies to --algorithm araim"),
    (["--no-resume"], "--no-resume needs --ledger"),
    (["--ledger", "afile"], "--ledger"),
])
def test_new_cli_refuses_bad_inputs_with_exit_2(argv, needle, new_cli, capsys, tmp_path,
                                                monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("")
    assert main(["availability", "--duration", "600", "--csv", "x.csv", *argv]) == 2
    _one_line_error(capsys, needle)


def test_new_cli_unknown_algorithm_is_an_argparse_error(new_cli, capsys):
    with pytest.raises(SystemExit) as info:
        main(["availability", "--algorithm", "gf"])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--algorithm" in err and "'mss'" in err, err


def test_new_cli_fde_reaches_the_araim_kernel(new_cli, capsys, tmp_path):
    grid = tmp_path / "g.csv"
    assert main(["availability", *TINY, "--fde", "--csv", str(grid)]) == 0
    res = read_csv(grid)
    assert res.settings["araim_params"] == {"fde": True}
    plain = availability(SYSTEMS, **dict(SMALL, ism="b2012"))
    # The worst case over the exclusion candidates (ARAIM.md section 9) is never smaller.
    assert np.all(res.vpl_median_m >= plain.vpl_median_m - ONE_MM)
    assert np.any(res.vpl_median_m > plain.vpl_median_m + 1.0)
