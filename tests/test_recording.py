"""Real recordings (../shared/data, skipped when absent): SPP accuracy, false alarms of the
parity test on fault-free real data, faults injected into real pseudoranges."""

import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from raimcore import algorithms
from raimcore.cli import main
from raimcore.geometry import ecef_to_enu
from raimcore.measure.faults import Fault
from raimcore.pipeline import run_scenario
from raimcore.scenario import from_dict, load_scenario, recording_scenario
from raimcore.sky.rinex import read_nav, read_obs
from raimcore.sky.spp import spp

ESBC_OBS = "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
ESBC_NAV = "ESBC00DNK_R_20201770000_01D_MN.rnx"
SLAC_OBS, SLAC_NAV = "slac1180.21o", "brdc1180.21n"


@pytest.fixture
def esbc(shared_data):
    return str(shared_data / ESBC_OBS), str(shared_data / ESBC_NAV)


@pytest.fixture
def slac(shared_data):
    return str(shared_data / SLAC_OBS), str(shared_data / SLAC_NAV)


@pytest.mark.parametrize("files,systems", [
    ((ESBC_OBS, ESBC_NAV), ("GPS",)), ((ESBC_OBS, ESBC_NAV), ("BDS",)),
    ((ESBC_OBS, ESBC_NAV), ("GPS", "BDS")), ((SLAC_OBS, SLAC_NAV), ("GPS",))])
def test_spp_within_10_m_of_the_header_position(shared_data, files, systems):
    obs = read_obs(shared_data / files[0])
    res, corr = spp(obs, read_nav(shared_data / files[1]), systems)
    err = np.linalg.norm(ecef_to_enu(res.pos_ecef_m, obs.approx_pos_ecef_m), axis=-1)
    assert res.available.all() and not corr.notes
    print(f"{files[0][:4]} {'+'.join(systems)}: worst 3D error {err.max():.2f} m, "
          f"RMS {np.sqrt(np.mean(err**2)):.2f} m")
    assert err.max() < 10.0


def test_corrections_are_needed_for_the_accuracy(esbc):
    from raimcore.sky.spp import solve

    obs = read_obs(esbc[0])
    _, corr = spp(obs, read_nav(esbc[1]), ("GPS",))
    bare = corr.__class__(**{**corr.__dict__, "iono_m": 0 * corr.iono_m,
                             "tropo_m": 0 * corr.tropo_m})
    err = np.linalg.norm(ecef_to_enu(solve(bare).pos_ecef_m, obs.approx_pos_ecef_m), axis=-1)
    assert err.max() > 10.0


@pytest.mark.parametrize("which", ["esbc", "slac"])
def test_parity_false_alarm_rate_on_fault_free_real_data(request, which):
    obs, nav = request.getfixturevalue(which)
    r = run_scenario(recording_scenario(obs, nav))
    t = r.table
    nominal = t["status"] != "unavailable"
    k, n = int(t["alarm"][nominal].sum()), int(nominal.sum())
    print(f"{which}: parity false alarms {k}/{n} at p_fa {r.scenario.p_fa:g}, sigma 1 m")
    assert n == len(t)
    # No more alarms than the test's p_fa allows (one-sided binomial test at 1e-3).
    assert stats.binom.sf(k - 1, n, r.scenario.p_fa) > 1e-3
    err = np.hypot(t["hpe_before_m"], t["vpe_before_m"])
    assert np.nanmax(err) < 10.0


def test_a_50_m_step_on_a_real_satellite_is_detected_and_excluded(esbc):
    s = recording_scenario(*esbc, faults=[Fault("G05", "step", t0_s=600.0, t1_s=1800.0,
                                                bias_m=50.0)])
    t = run_scenario(s).table
    faulted = t["faulty_truth"] == "G05"
    assert faulted.sum() == 40
    assert t["alarm"][faulted].mean() >= 0.95
    assert np.mean(t["excluded"][faulted] == "G05") >= 0.95
    err = np.hypot(t["hpe_after_m"], t["vpe_after_m"])[faulted]
    assert np.nanmax(err) < 10.0


def test_several_faulty_satellites_and_every_algorithm_runs_on_real_data(slac):
    s = recording_scenario(*slac, duration_s=900.0, faults=[
        Fault("G13", "ramp", t0_s=300.0, rate_mps=1.0), Fault("G15", "step", t0_s=600.0,
                                                              bias_m=80.0)])
    for name in algorithms.names():
        r = run_scenario(s.replace(algorithm=name))
        t = r.table
        assert len(t) == 31
        assert set(t["faulty_truth"][t["t_s"] >= 600.0]) == {"G13+G15"}
        ok = (t["faulty_truth"] == "") & (t["status"] != "unavailable")
        assert np.nanmax(np.hypot(t["hpe_before_m"], t["vpe_before_m"])[ok]) < 10.0, name


def test_window_step_truth_and_round_trip(esbc):
    s = recording_scenario(*esbc, t_start_s=600.0, duration_s=1200.0, step_s=60.0,
                           systems=["BDS"], truth_ecef_m=[3582105.0, 532589.0, 5232754.0])
    assert from_dict(s.to_dict()) == s
    r = run_scenario(s)
    m = r.measurements
    assert m.t_s[0] == 0.0 and m.t_s[-1] == 1200.0 and len(m.t_s) == 21
    assert all(n.startswith("C") for n in m.sat_names)
    np.testing.assert_allclose(r.truth.pos_rx_ecef_m[0], s.truth_ecef_m)
    with pytest.raises(ValueError, match="select no epoch"):
        run_scenario(s.replace(t_start_s=1e5))


def test_satellite_without_ephemeris_left_out_with_a_note(esbc, tmp_path):
    lines = open(esbc[1]).read().splitlines()
    out, skip = [], 0
    for line in lines:
        if line.startswith("G05 "):
            skip = 8
        if skip:
            skip -= 1
            continue
        out.append(line)
    nav = tmp_path / "nav_without_g05.rnx"
    nav.write_text("\n".join(out) + "\n")
    r = run_scenario(recording_scenario(esbc[0], str(nav)))
    assert "G05" not in r.measurements.sat_names
    assert any("G05" in n and "left out" in n for n in r.measurements.notes)
    with pytest.raises(ValueError, match="G05"):
        run_scenario(recording_scenario(esbc[0], str(nav), faults=[Fault("G05", "step",
                                                                         bias_m=50.0)]))


def test_rinex_source_needs_files_and_bad_files_are_value_errors(tmp_path):
    with pytest.raises(ValueError, match="needs obs and nav"):
        load_scenario("default", source="rinex")
    with pytest.raises(ValueError, match="source must be one of"):
        load_scenario("default", source="csv")
    with pytest.raises(ValueError, match="does not exist"):
        run_scenario(load_scenario("default", source="rinex", obs=str(tmp_path / "a"),
                                   nav=str(tmp_path / "b")))


@pytest.mark.parametrize("algorithm", ["parity", "mss"])
def test_no_satellite_ever_used_gives_all_unavailable(algorithm):
    r = run_scenario("default", mask_deg=89.0, duration_s=10.0, algorithm=algorithm)
    assert set(r.table["status"]) == {"unavailable"}
    assert not r.table["alarm"].any()


def test_cli_done_when_ramp_detected_and_excluded(esbc, capsys):
    obs, nav = esbc
    assert main(["run", "--obs", obs, "--nav", nav, "--fault", "G05,ramp,2,600"]) == 0
    out = capsys.readouterr().out
    assert "first alarm: t = 630 s" in out
    assert "correct isolation rate over faulted epochs: 100.0%" in out
    assert "mean HPE on fault-free epochs: " in out
    assert main(["run", "--obs", obs]) == 2
    assert "--obs and --nav go together" in capsys.readouterr().err


def test_batched_spp_equals_a_per_epoch_loop(esbc):
    import dataclasses

    from raimcore.sky.spp import correct, solve

    obs, nav = read_obs(esbc[0]), read_nav(esbc[1])
    batched = solve(correct(obs, nav)).pos_ecef_m
    for e in (0, 77, 239):
        one = dataclasses.replace(obs, t_gps_s=obs.t_gps_s[e:e + 1],
                                  epoch_flag=obs.epoch_flag[e:e + 1],
                                  codes={k: v[e:e + 1] for k, v in obs.codes.items()})
        np.testing.assert_allclose(solve(correct(one, nav)).pos_ecef_m[0], batched[e],
                                   atol=1e-6)


@pytest.mark.slow
def test_real_errors_are_time_correlated_and_pf_llr_needs_that_in_its_threshold(esbc):
    """ESBC's real pseudorange errors (against the station position) are strongly
    correlated over 30 s. PF-LLR calibrated on white noise false-alarms at most armed
    epochs; calibrated with the measured correlation time it holds, and a slow ramp is
    still caught and isolated."""
    from raimcore.measure import error_statistics, measure
    from raimcore.sky.recording import recording_sky

    s = recording_scenario(*esbc, algorithm="pf-llr")
    data, truth = measure(recording_sky(s), s)
    fit = error_statistics(data, truth)
    print(f"ESBC errors: sigma {fit.sigma_m:.2f} m, rho {fit.rho:.2f} over {fit.dt_s:g} s, "
          f"corr {fit.corr_s:.0f} s")
    assert 0.2 < fit.sigma_m < 2.0 and fit.rho > 0.5 and fit.dt_s == 30.0
    assert any(n.startswith("measured pseudorange errors") for n in data.notes)
    white = run_scenario(s)
    corr = run_scenario(s.replace(noise_corr_s=round(fit.corr_s)))
    assert corr.table["threshold"][-1] > white.table["threshold"][-1]
    assert white.summary["false_alarm_rate"] > 0.2
    assert corr.summary["false_alarm_rate"] <= 0.05
    ramp = run_scenario(s.replace(noise_corr_s=round(fit.corr_s)).with_faults(
        Fault("G05", "ramp", t0_s=3600.0, rate_mps=0.5)))
    assert ramp.summary["first_alarm_t_s"] <= 3600.0 + 120.0
    assert ramp.summary["correct_isolation_rate"] >= 0.9


def test_measured_error_note_is_computed_before_any_fault(esbc):
    """The recording's measured-error note describes its real errors: an injected fault
    (here 500 m on G05 for the whole recording) does not change it."""
    s = recording_scenario(*esbc, duration_s=1800.0)
    clean = run_scenario(s).summary.notes
    faulted = run_scenario(s.with_faults(Fault("G05", "step", t0_s=0.0, bias_m=500.0)))
    note = [n for n in clean if n.startswith("measured pseudorange errors")]
    assert note and note[0] in faulted.summary.notes


# -- four systems, several navigation files, notes (issue 15 items 1, 3) -----------------

def _split_nav_by_system(path, out_dir) -> list[str]:
    """An IGS-style per-system copy (``_GN``, ``_CN``, ``_EN``, ``_RN``) of the RINEX 3 mixed
    navigation file ``path``: the header, then the records of one system each."""
    lines = open(path).read().splitlines()
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    per: dict[str, list[str]] = {}
    letter = ""
    for ln in lines[end:]:
        if ln[:1].strip():
            letter = ln[0]
        per.setdefault(letter, []).append(ln)
    out = []
    for letter, code in (("G", "GN"), ("C", "CN"), ("E", "EN"), ("R", "RN")):
        p = out_dir / f"ESBC_{code}.rnx"
        p.write_text("\n".join(lines[:end] + per[letter]) + "\n")
        out.append(str(p))
    return out


def _set_nav_field(text: str, sat: str, index: int, value: str | None) -> str:
    """A RINEX 3 navigation file ``text`` with record value ``index`` (0 = af0, then 3 + 4
    per broadcast-orbit line) of the first record of ``sat`` set to ``value`` (19
    characters, None: blank)."""
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(sat + " "))
    row, pos = (0, index) if index < 3 else (1 + (index - 3) // 4, (index - 3) % 4)
    col = (23 if row == 0 else 4) + 19 * pos
    ln = lines[start + row].ljust(col + 19)
    lines[start + row] = ln[:col] + (value if value is not None else " " * 19) + ln[col + 19:]
    return "\n".join(lines) + "\n"


def test_recording_offers_every_system_of_the_file(esbc):
    s = recording_scenario(*esbc)
    assert s.systems == ("GPS", "BDS", "GAL", "GLO") and s.nav == (esbc[1],)
    r = run_scenario(s)
    m = r.measurements
    assert set(m.systems) == {"GPS", "BDS", "GAL", "GLO"}
    assert all(n[0] == "GCER"[("GPS", "BDS", "GAL", "GLO").index(m.systems[k])]
               for n, k in zip(m.sat_names, m.sys_idx, strict=True))
    t = r.table
    assert not t["alarm"].any()
    assert np.nanmax(np.hypot(t["hpe_before_m"], t["vpe_before_m"])) < 10.0


def test_per_system_navigation_files_equal_the_mixed_one(esbc, tmp_path):
    from raimcore.sky.recording import recording_sky

    navs = _split_nav_by_system(esbc[1], tmp_path)
    mixed = recording_sky(recording_scenario(*esbc))
    split = recording_sky(recording_scenario(esbc[0], navs))
    assert split.sat_names == mixed.sat_names
    np.testing.assert_array_equal(split.pr_m, mixed.pr_m)
    np.testing.assert_array_equal(split.pos_sv_ecef_m, mixed.pos_sv_ecef_m)
    # A TOML file lists them as nav = [...]; the scenario round-trips.
    toml = tmp_path / "station.toml"
    toml.write_text(f'source = "rinex"\nobs = "{esbc[0]}"\nnav = {json.dumps(navs)}\n'
                    'systems = ["GPS", "GAL"]\n')
    s = load_scenario(toml)
    assert s.nav == tuple(navs) and from_dict(s.to_dict()) == s
    assert set(run_scenario(s).measurements.systems) == {"GPS", "GAL"}


def test_recording_is_cached_on_every_navigation_file(esbc, tmp_path):
    from raimcore.sky.recording import load_recording

    navs = _split_nav_by_system(esbc[1], tmp_path)
    a = load_recording(esbc[0], navs, ("GPS", "GAL"))
    assert load_recording(esbc[0], navs, ("GPS", "GAL")) is a
    with open(navs[2], "a") as f:  # the Galileo file changes (size and time)
        f.write("\n")
    assert load_recording(esbc[0], navs, ("GPS", "GAL")) is not a


def test_run_notes_name_real_rejections_of_observed_satellites_only(esbc, tmp_path):
    obs = read_obs(esbc[0])
    nav_text = open(esbc[1]).read()
    in_nav = {ln[:3] for ln in nav_text.splitlines() if ln[:1] == "G"}
    observed = sorted(n for n in in_nav if n in obs.sat_names)[0]
    unobserved = sorted(n for n in in_nav if n not in obs.sat_names)[0]
    text = nav_text
    for sat in (observed, unobserved):  # first record unhealthy (health field = 1)
        text = _set_nav_field(text, sat, 24, f"{1.0:19.12e}")
    bds = sorted({ln[:3] for ln in nav_text.splitlines() if ln[:1] == "C"})
    for sat in bds:  # a blank spare field (BROADCAST ORBIT - 5, 2nd): not a reason
        text = _set_nav_field(text, sat, 20, None)
    nav = tmp_path / "edited.rnx"
    nav.write_text(text)
    notes = run_scenario(recording_scenario(esbc[0], str(nav))).summary.notes
    # The navigation reader's notes (systems skipped) and the records not used.
    assert "15 records of QZSS skipped (systems read: GPS, BeiDou, Galileo, GLONASS)" in notes
    assert f"{observed}: 1 record unhealthy (health 1)" in notes
    assert not any(n.startswith(unobserved) for n in notes)
    assert not any(n[:1] == "C" for n in notes)  # BDS records all accepted
    # Every other note is one of the recording's known ones.
    known = ("records of SBAS skipped", "GAL: 781 F/NAV records", "measured pseudorange")
    rest = [n for n in notes if "QZSS" not in n and not n.startswith(observed)]
    assert all(any(k in n for k in known) for n in rest), rest


# -- the epoch grid (issue 15 item 5) ------------------------------------------------------

def _obs_g06(path, tags_s):
    """A RINEX 3.05 observation file of GPS 6 (C1C) at the time tags ``tags_s`` (s from
    2021-04-28 18:00:00 GPST, in file order), for the navigation record of ``nav_v2``."""
    from rinex_snippets import _hdr, _obs3_sat

    lines = [_hdr("     3.05           OBSERVATION DATA    M (MIXED)", "RINEX VERSION / TYPE"),
             _hdr("  3582105.2910   532589.7313  5232754.8054", "APPROX POSITION XYZ"),
             _hdr("G    1 C1C", "SYS / # / OBS TYPES"),
             _hdr("  2021     4    28    18     0    0.0000000     GPS", "TIME OF FIRST OBS"),
             _hdr("", "END OF HEADER")]
    for k, t in enumerate(tags_s):
        hh, rest = divmod(t, 3600.0)
        mm, ss = divmod(rest, 60.0)
        lines += [f"> 2021 04 28 {18 + int(hh):02d} {int(mm):02d}{ss:11.7f}  0  1",
                  _obs3_sat("G06", [21_000_000.0 + 100.0 * k])]
    path.write_text("\n".join(lines) + "\n")
    return path


#: 120 epochs at 30 s, as a receiver that steers its clock writes them: every 7th tag 1 ms
#: early, every 11th 0.4 ms late (tags 29.999 s and 30.001 s apart, among 30 s).
GRID = np.arange(120) * 30.0
JITTERED = GRID - 1e-3 * (np.arange(120) % 7 == 3) + 4e-4 * (np.arange(120) % 11 == 5)


def test_jittered_time_tags_keep_every_epoch(tmp_path):
    from rinex_snippets import nav_v2

    from raimcore.sky.recording import recording_sky

    obs = _obs_g06(tmp_path / "jitter.rnx", JITTERED)
    nav = nav_v2(tmp_path / "brdc.21n")
    s = recording_scenario(obs, nav)
    assert s.step_s == 30.0 and s.duration_s == pytest.approx(3570.0)
    sky = recording_sky(s)
    assert len(sky.t_s) == 120
    np.testing.assert_allclose(sky.t_s, JITTERED)  # the real tags
    assert not any("grid" in n or "duplicated" in n for n in sky.notes)
    # Thinned to 60 s: the epochs on the 60 s grid, from t_start_s.
    thin = recording_sky(s.replace(step_s=60.0, t_start_s=600.0, duration_s=1200.0))
    np.testing.assert_allclose(thin.t_s, np.arange(21) * 60.0, atol=2e-3)
    # A step that is no multiple of the interval: the next multiple, said so.
    odd = recording_sky(s.replace(step_s=45.0))
    np.testing.assert_allclose(np.diff(odd.t_s), 60.0, atol=2e-3)
    assert any("step_s 45 s is not a multiple" in n for n in odd.notes)


def test_duplicated_and_off_grid_epochs_are_dropped_and_counted(tmp_path):
    from rinex_snippets import nav_v2

    tags = list(JITTERED)
    tags.insert(11, tags[10])  # the epoch at 300 s written twice
    tags.insert(22, 600.002)  # a second tag for the 600 s epoch
    tags.insert(43, 1212.0)  # a tag off the grid (12 s after 1200 s)
    obs = _obs_g06(tmp_path / "dup.rnx", tags)
    r = run_scenario(recording_scenario(obs, nav_v2(tmp_path / "brdc.21n")))
    assert len(r.measurements.t_s) == 120
    notes = r.summary.notes
    assert ("2 duplicated epochs dropped (a second time tag for one grid time; the first is "
            "kept): t = 299.999, 600.002 s") in notes
    assert "1 epoch off the 30 s grid dropped (more than 7.5 s from it): t = 1212 s" in notes


def test_dashboard_recording_folder_takes_several_navigation_files(esbc, tmp_path, request):
    """The Navigation files field: paths separated by ";" (shown joined by "; "); an
    upload adds to the list."""
    pytest.importorskip("viser")
    pytest.importorskip("plotly")
    from viser._gui_handles import UploadedFile

    dash = request.getfixturevalue("dash")  # conftest: an in-process dashboard
    from app.session import Session

    navs = _split_nav_by_system(esbc[1], tmp_path)
    s = Session(dash.server, dash.start_scenario, dash.presets)
    try:
        assert s.scheduler.wait_idle(60.0)
        s.rec_obs.value = esbc[0]
        s.rec_nav.value = f"{navs[0]} ;{navs[2]};"
        s._on_open_recording()
        assert s.scheduler.wait_idle(60.0)
        assert s.result.scenario.nav == (navs[0], navs[2])
        assert s.rec_nav.value == f"{navs[0]}; {navs[2]}"
        assert set(s.result.measurements.systems) == {"GPS", "GAL"}  # no BDS, GLO records
        s.rec_upload_nav._impl.value = UploadedFile("ESBC_CN.rnx", open(navs[1], "rb").read())
        s._on_upload(s.rec_upload_nav, s.rec_nav)
        assert s.scheduler.wait_idle(60.0)
        nav = s.result.scenario.nav
        assert nav[:2] == (navs[0], navs[2]) and nav[2].endswith("ESBC_CN.rnx")
        assert nav[2].startswith(s._upload_dir) and s.rec_nav.value == "; ".join(nav)
        assert set(s.result.measurements.systems) == {"GPS", "GAL", "BDS"}
    finally:
        s.close()


# -- phone logs: source "android" (issue 15 item 8) ----------------------------------------

PHONE_LOG, PHONE_NAV = "pseudoranges_log_2016_06_30_21_26_07.txt", "hour1820.16n"
PHONE_SNIPPET = Path(__file__).parent / "data" / "android" / "gnsslogger_v1.4.txt"
#: The log's surveyed point (data README: WGS-84 37.422578, -122.081678, -28 m), ECEF (m).
PHONE_TRUTH = [-2693671.7485, -4297132.6427, 3854726.4392]
#: A phone's epoch spacing as in the shared log: about 1 s, 0.93-1.42 s apart (duty cycling).
PHONE_GAPS = np.tile([0.995, 0.931, 1.419, 0.99, 1.012, 0.96], 20)
PHONE_TAGS = np.concatenate([[0.0], np.cumsum(PHONE_GAPS)])


@pytest.fixture
def phone(shared_data):
    log = shared_data / PHONE_LOG
    if not log.is_file():
        pytest.skip(f"{PHONE_LOG} is not in ../shared/data")
    return str(log), str(shared_data / PHONE_NAV)


def test_phone_epochs_are_on_no_grid_and_every_one_is_kept():
    from raimcore.sky.recording import _window, nominal_interval_s

    t = PHONE_TAGS
    dt = nominal_interval_s(t)
    rows, notes = _window(t, 0.0, t[-1], dt, grid=False)
    np.testing.assert_array_equal(rows, np.arange(t.size))
    assert notes == []
    # On a grid the 1.419 s gaps put later tags between grid times: dropped (with a note).
    grid_rows, grid_notes = _window(t, 0.0, t[-1], dt)
    assert grid_rows.size < t.size and "off the" in grid_notes[0]
    # Thinned to 2 s: each kept epoch at least 2 - dt / 4 s after the one before.
    thin, thin_notes = _window(t, 0.0, t[-1], 2.0, grid=False)
    assert np.diff(t[thin]).min() >= 2.0 - dt / 4 and thin.size >= t.size // 2 - 1
    assert thin_notes == []  # thinning on purpose: no note
    # A second measurement 0.3 s after an epoch is dropped and counted.
    close = np.sort(np.append(t, t[10] + 0.3))
    dc = nominal_interval_s(close)
    for step in (dc, 3.0):  # counted whatever the step (from t[10]: kept first)
        rows, notes = _window(close, t[10], close[-1] - t[10], step, grid=False)
        assert t[10] in close[rows] and t[10] + 0.3 not in close[rows]
        assert notes == [f"1 epoch less than {0.75 * dc:g} s after the one before dropped "
                         f"(the log's interval is {dc:g} s): t = 0.3 s"]
    rows, _ = _window(close, 0.0, close[-1], dc, grid=False)
    np.testing.assert_array_equal(close[rows], t)
    # The window: tags within dt / 4 of [t0, t0 + duration].
    rows, _ = _window(t, 10.0, 5.0, dt, grid=False)
    assert t[rows].min() >= 10.0 - dt / 4 and t[rows].max() <= 15.0 + dt / 4


def test_the_kind_of_observation_file_is_told_by_its_content(tmp_path):
    import bz2
    import gzip
    import zipfile

    from rinex_snippets import nav_v2, obs_v2, obs_v3

    from raimcore.sky.recording import observation_source

    log = PHONE_SNIPPET.read_bytes()
    (tmp_path / "log.gz").write_bytes(gzip.compress(log))
    (tmp_path / "log.bz2").write_bytes(bz2.compress(log))
    with zipfile.ZipFile(tmp_path / "log.zip", "w") as z:
        z.writestr("gnss_log.txt", log)
    (tmp_path / "bom.txt").write_bytes(b"\xef\xbb\xbf" + log)
    for name in ("log.gz", "log.bz2", "log.zip", "bom.txt"):
        assert observation_source(tmp_path / name) == "android", name
    assert observation_source(PHONE_SNIPPET) == "android"
    assert observation_source(obs_v2(tmp_path / "o.21o")) == "rinex"
    assert observation_source(obs_v3(tmp_path / "o.rnx")) == "rinex"
    assert observation_source(nav_v2(tmp_path / "n.21n")) == "rinex-nav"
    (tmp_path / "notes.txt").write_text("Raw, but not a header\n# a comment\n")
    assert observation_source(tmp_path / "notes.txt") == ""
    (tmp_path / "broken.gz").write_bytes(b"\x1f\x8b" + b"\0" * 20)
    assert observation_source(tmp_path / "broken.gz") == ""


def test_phone_log_runs_end_to_end_with_phone_defaults(phone):
    from raimcore.sky.recording import PHONE_DEFAULTS

    s = recording_scenario(*phone)  # the source told by the content
    assert (s.source, s.obs, s.systems) == ("android", phone[0], ("GPS",))
    assert s.error_model == PHONE_DEFAULTS["error_model"] == "measured"
    assert s.sigma_m == PHONE_DEFAULTS["sigma_m"] and s.recorded
    assert s.step_s == pytest.approx(0.995, abs=0.01)
    r = run_scenario(s)
    notes = r.summary.notes
    assert len(r.measurements.t_s) == 223  # every epoch of the log, none dropped
    assert not any("dropped" in n for n in notes), notes
    assert "no header position and no truth_ecef_m: truth is the median single-point " \
           "solution" in notes
    assert any(n.startswith("the phone's hardware clock restarted between 214 of 222 pairs")
               for n in notes), notes
    assert "3 Raw measurements: ReceivedSvTimeUncertaintyNanos above 500 ns" in notes
    # At the surveyed point: parity holds near p_fa, the position is a phone's.
    r = run_scenario(s.replace(truth_ecef_m=PHONE_TRUTH))
    sm = r.summary
    assert sm.unavailable_epochs == 0 and sm.false_alarm.n == 223
    assert sm.false_alarm.k <= 3  # measured 2
    assert 4.0 < sm.hpe_nominal_mean_m < 15.0  # measured 8.8 m
    # A 100 m step on G12 (42 degrees) is detected at every faulted epoch, mostly isolated.
    flt = run_scenario(s.replace(truth_ecef_m=PHONE_TRUTH,
                                 faults=[Fault("G12", bias_m=100.0, t0_s=60.0)])).summary
    assert flt.detection.n == 163 and flt.detection.k == 163
    assert flt.correct_isolation.value > 0.6  # measured 130/163


def test_phone_log_given_as_rinex_is_refused_and_same_chain_as_rinex(phone):
    from raimcore.sky.recording import load_recording

    with pytest.raises(ValueError, match="give it with --android"):
        recording_scenario(*phone, source="rinex")
    corr = load_recording(phone[0], phone[1], ("GPS",), (), "android")
    assert corr.notes[0].startswith("3 Raw measurements")  # the log's notes, then correct()'s


def test_ekf_holds_on_the_phone_once_its_clock_may_jump(phone):
    """The phone's clock restarts between almost every pair of epochs (jumps of tens of
    metres, below the filters' 1000 m re-initialisation): with a clock process noise that
    lets the clock move (q_clk_mps = 100) the EKF's fault-free alarms are at p_fa's level,
    which shows the restarts are what the filter cannot follow (raim show android)."""
    s = recording_scenario(*phone, truth_ecef_m=PHONE_TRUTH, algorithm="ekf",
                           q_clk_mps=100.0)
    fa = run_scenario(s).summary.false_alarm
    assert fa.n == 223 and fa.k <= 3  # measured 1
    assert stats.binomtest(fa.k, fa.n, 1e-3).pvalue > 1e-3


def test_dashboard_opens_a_phone_log_like_a_recording(phone, request):
    """The Recording folder's "Open recording" and the uploads take a GnssLogger log (told
    by its content); the Learn tab shows the phone report."""
    pytest.importorskip("viser")
    pytest.importorskip("plotly")
    from viser._gui_handles import UploadedFile

    dash = request.getfixturevalue("dash")
    from app.session import Session

    s = Session(dash.server, dash.start_scenario, dash.presets)
    try:
        assert s.scheduler.wait_idle(60.0)
        s.rec_obs.value, s.rec_nav.value = phone
        s._on_open_recording()
        assert s.scheduler.wait_idle(120.0)
        assert s.result.scenario.source == "android"
        assert len(s.result.measurements.t_s) == 223
        assert s.preset.value == "pseudoranges_log_2016_06_30_21_26_07"
        assert "hardware clock restarted" in s.rec_notes.content
        assert s.report_md.content.startswith("# Phone logs")
        s.close()
        s = Session(dash.server, dash.start_scenario, dash.presets)
        assert s.scheduler.wait_idle(60.0)
        for button, field, path in ((s.rec_upload_nav, s.rec_nav, phone[1]),
                                    (s.rec_upload_obs, s.rec_obs, phone[0])):
            button._impl.value = UploadedFile(Path(path).name, Path(path).read_bytes())
            s._on_upload(button, field)
        assert s.scheduler.wait_idle(120.0)
        assert s.result.scenario.source == "android"
        assert s.result.scenario.obs.startswith(s._upload_dir)
    finally:
        s.close()


def test_recording_doctests():
    import doctest

    from raimcore.sky import recording

    res = doctest.testmod(recording)
    assert res.attempted >= 1 and res.failed == 0


def test_group_delay_of_each_signal_follows_the_icds():
    from raimcore.constants import F_E5B_HZ, F_L1_HZ, F_L2_HZ
    from raimcore.sky.spp import group_delay_s

    tgd, tgd2 = np.array([-1.2e-8, 4e-9]), np.array([3e-9, np.nan])
    for letter, code, want in (("G", "C1C", tgd), ("G", "C2W", (F_L1_HZ / F_L2_HZ) ** 2 * tgd),
                               ("C", "C2I", tgd), ("C", "C1I", tgd), ("C", "C7I", [3e-9, 0.0]),
                               ("C", "C6I", [0.0, 0.0]), ("E", "C1C", tgd),
                               ("E", "C7Q", (F_L1_HZ / F_E5B_HZ) ** 2 * np.array([3e-9, 0.0])),
                               ("R", "C1C", tgd)):
        got, note = group_delay_s(letter, code, tgd, tgd2)
        np.testing.assert_allclose(got, want, rtol=1e-15, atol=0, err_msg=code)
        assert (note is None) == (code not in ("C7I", "C7Q")), code  # the missing TGD2
    for letter, code in (("G", "C5Q"), ("C", "C1P"), ("C", "C5X"), ("E", "C5Q"), ("E", "C6C"),
                         ("R", "C2P")):
        got, note = group_delay_s(letter, code, tgd, tgd2)
        np.testing.assert_array_equal(got, tgd)
        assert "no broadcast group delay" in note


@pytest.mark.parametrize("system, code", [("GPS", "C2W"), ("BDS", "C7I"), ("BDS", "C6I"),
                                          ("GAL", "C7Q")])
def test_a_signals_own_group_delay_aligns_the_satellites_of_a_real_recording(esbc, system,
                                                                             code):
    """ESBC at its surveyed position: each satellite's mean residual (after the epoch's
    common clock) spreads less with the signal's own broadcast group delay than with the
    default signal's (what was applied before): GPS L2 1.47 -> 1.22 m, BDS B2I 1.13 ->
    0.84 m, B3I 2.81 -> 1.48 m, Galileo E5b 3.62 -> 1.04 m."""
    from raimcore.sky import spp as spp_module

    obs, nav = read_obs(esbc[0]), read_nav(esbc[1], systems="GCER")
    rx = obs.approx_pos_ecef_m
    c = spp_module.correct(obs, nav, (system,), (code,), rx_ecef_m=rx)
    eph, _ = spp_module.from_nav(nav).select(c.sat_names, c.t_gps_s)
    own, _ = spp_module.group_delay_s(spp_module.ALL_SYSTEM_LETTER[system], code,
                                      eph.tgd_s, eph.tgd2_s)
    rng = np.linalg.norm(c.pos_sv_ecef_m - rx, axis=-1)

    def spread(clock_m):
        res = c.pr_raw_m + clock_m - rng - c.iono_m - c.tropo_m
        res = res - np.nanmedian(res, axis=1, keepdims=True)
        per = np.nanmean(res, axis=0)
        return np.std(per[np.isfinite(per)])

    default = spread(c.clock_m + spp_module.C_MPS * (own - eph.tgd_s))
    assert spread(c.clock_m) < 0.9 * default
    assert not any("group delay" in n for n in c.notes)
