"""Every bad input refused with one line that names the key (issue 13, items 3, 5 and 7b).

One table of bad command lines, one of bad scenario files, one of bad public-API calls:
each row is the input and the words its message must contain (the key or argument, and
the value where the message can show it). The CLI must exit 2 with one line on stderr and
no traceback; the API must raise ValueError. Then the cases that are not errors: numpy
scalars accepted, a fault that never acts is a warning note in the summary, strict JSON and
CSV output, the dashboard's port and host checks, Ctrl-C, and a real bug that still gets
a traceback and a "please report" line.

Real data (../shared/data) is used where it adds a case and skipped when absent; the RINEX
and YUMA files of the other cases are written here, in tmp_path.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from rinex_snippets import GPS6, _hdr, _v3_record, nav_v2, nav_v3, obs_v2, obs_v3

import raimcore.cli as cli
from raimcore.cli import main
from raimcore.measure.faults import Fault
from raimcore.pipeline import compare_algorithms, run_scenario, simulate
from raimcore.scenario import Scenario, from_dict, load_scenario, recording_scenario
from raimcore.sky.constellations import read_yuma
from raimcore.sky.recording import load_recording
from raimcore.sky.rinex import read_nav, read_obs
from raimcore.studies.montecarlo import Study, parse_algorithm

RAIM = Path(sys.executable).with_name("raim")  # the console script of this environment
ESBC_OBS = "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
SLAC_NAV = "brdc1180.21n"


def run_cli(argv) -> tuple[int, str, str]:
    """``raim argv`` in this process: (exit status, stdout, stderr). argparse errors end in
    SystemExit; their status is taken the same way."""
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


def assert_one_line_error(rc, err: str, *words: str) -> None:
    """Exit 2, exactly one line on stderr, no traceback, every word in it."""
    assert "Traceback" not in err, err
    lines = err.strip().splitlines()
    assert rc == 2, f"exit {rc}: {err}"
    assert len(lines) == 1, f"expected one line, got {len(lines)}:\n{err}"
    assert "error" in lines[0]
    for w in words:
        assert w in lines[0], f"{w!r} not in {lines[0]!r}"


def assert_one_line_value_error(exc: pytest.ExceptionInfo, *words: str) -> None:
    msg = str(exc.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, f"{w!r} not in {msg!r}"


# -- tiny YUMA almanacs ----------------------------------------------------------------

# Two records in the YUMA layout (values of a real week-819 almanac, rounded).
_YUMA_FIELDS = (
    ("ID", "{prn:02d}"), ("Health", "000"), ("Eccentricity", "{ecc}"),
    ("Time of Applicability(s)", "319488.0000"), ("Orbital Inclination(rad)", "0.9617"),
    ("Rate of Right Ascen(r/s)", "-0.7954E-008"), ("SQRT(A)  (m 1/2)", "{sqrt_a}"),
    ("Right Ascen at Week(rad)", "-0.1551E+001"), ("Argument of Perigee(rad)", "0.3745"),
    ("Mean Anom(rad)", "{m0}"), ("Af0(s)", "-0.5722E-005"), ("Af1(s/s)", "0.0"),
    ("week", "819"),
)


def write_yuma(path: Path, *records: dict) -> Path:
    """A YUMA file of ``records`` (each: prn, and optionally ecc, sqrt_a, m0, drop)."""
    lines = []
    for r in records:
        vals = {"ecc": "0.4164E-002", "sqrt_a": "5153.605957", "m0": "-0.3011E+001", **r}
        lines.append(f"******** Week 819 almanac for PRN-{r['prn']:02d} ********")
        for label, fmt in _YUMA_FIELDS:
            if label != r.get("drop"):
                lines.append(f"{label + ':':<28}{fmt.format(**vals)}")
        lines.append("")
    path.write_text("\n".join(lines) + "\n")
    return path


#: (id, records, words of the message)
YUMA_CASES = [
    ("nan-eccentricity", [{"prn": 1, "ecc": "nan"}], ["'eccentricity'", "nan", "[0, 1)"]),
    ("eccentricity-1.5", [{"prn": 1, "ecc": "1.5"}], ["'eccentricity'", "1.5", "[0, 1)"]),
    ("negative-eccentricity", [{"prn": 1, "ecc": "-0.01"}], ["'eccentricity'", "-0.01"]),
    ("negative-sqrt-a", [{"prn": 1, "sqrt_a": "-5153.6"}],
     ["'sqrt(a)  (m 1/2)'", "-5153.6", "> 0"]),
    ("inf-sqrt-a", [{"prn": 1, "sqrt_a": "inf"}], ["'sqrt(a)  (m 1/2)'", "inf"]),
    ("sqrt-a-inside-the-earth", [{"prn": 1, "sqrt_a": "2000"}], ["PRN 1", "inside the Earth"]),
    ("nan-mean-anomaly", [{"prn": 1, "m0": "nan"}], ["'mean anom(rad)'", "nan", "finite"]),
    ("not-a-number", [{"prn": 1, "m0": "abc"}], ["'mean anom(rad)'", "abc"]),
    ("prn-0", [{"prn": 0}], ["'id'", "[1, 63]"]),
    ("duplicate-prn", [{"prn": 1}, {"prn": 1}], ["PRN 1", "twice"]),
    ("truncated-record", [{"prn": 1, "drop": "week"}], ["missing", "week"]),
]


@pytest.mark.parametrize("records, words", [c[1:] for c in YUMA_CASES],
                         ids=[c[0] for c in YUMA_CASES])
def test_bad_yuma_almanac_is_refused_naming_the_field(tmp_path, records, words):
    path = write_yuma(tmp_path / "bad.alm", *records)
    with pytest.raises(ValueError) as exc:
        read_yuma(path)
    assert_one_line_value_error(exc, str(path), *words)
    # The scenario refuses it when it is built (before any simulation), naming its key.
    with pytest.raises(ValueError) as exc:
        Scenario(constellation=str(path), faults=())
    assert_one_line_value_error(exc, "constellation", *words)
    rc, _, err = run_cli(["run", "default", "--set", f'constellation="{path}"'])
    assert_one_line_error(rc, err, "constellation", *words)


def test_good_tiny_yuma_almanac_reads(tmp_path):
    c = read_yuma(write_yuma(tmp_path / "ok.alm", {"prn": 1}, {"prn": 2, "m0": "1.0"}))
    assert c.names == ("G01", "G02") and np.all(c.healthy)
    assert np.all(np.isfinite(c.positions_ecef_m(np.array([0.0, 60.0]))))


def test_fault_on_a_satellite_missing_from_the_almanac_is_refused_at_build(tmp_path):
    path = write_yuma(tmp_path / "two.alm", {"prn": 1}, {"prn": 2})
    with pytest.raises(ValueError) as exc:
        Scenario(constellation=str(path), faults=[{"sat": "G10", "bias_m": 50.0}])
    assert_one_line_value_error(exc, "faults", "G10", str(path))


# -- RINEX files of different days (written here) ---------------------------------------

def _nav_of_another_day(path: Path) -> Path:
    """A navigation file whose only GPS record is G05 of 2021-04-28 (the values of GPS 6):
    the snippet observation file :func:`obs_v3` is of 2020-06-25."""
    lines = [_hdr("     3.05           NAVIGATION DATA     MIXED", "RINEX VERSION / TYPE"),
             _hdr("", "END OF HEADER"), *_v3_record("G05", "2021 04 28 17 59 44", GPS6)]
    path.write_text("\n".join(lines) + "\n")
    return path


NO_EPHEMERIS = "no ephemeris of the navigation file is valid within 4 h of the observation epochs"


def test_obs_and_nav_of_different_days_is_refused_with_a_message(tmp_path):
    obs = obs_v3(tmp_path / "obs.rnx", events=False)
    nav = _nav_of_another_day(tmp_path / "nav.rnx")
    rc, _, err = run_cli(["run", "--obs", obs, "--nav", nav])
    assert_one_line_error(rc, err, NO_EPHEMERIS, "2020-06-25", "2021-04-28")
    from raimcore.scenario import recording_scenario

    with pytest.raises(ValueError) as exc:
        run_scenario(recording_scenario(obs, nav))
    assert_one_line_value_error(exc, NO_EPHEMERIS)


#: A GnssLogger 1.4 log in the test tree (tests/test_android.py).
PHONE_SNIPPET = Path(__file__).parent / "data" / "android" / "gnsslogger_v1.4.txt"


@pytest.mark.parametrize("command", ["run", "compare", "dashboard"])
@pytest.mark.parametrize("option, kind, words", [
    ("--obs", "log", ["is an Android GnssLogger log, not a RINEX observation file",
                      "give it with --android"]),
    ("--android", "obs", ["is a RINEX observation file, not an Android GnssLogger log",
                          "give it with --obs"]),
    ("--android", "nav", ["is a RINEX navigation", "give it with --nav"]),
], ids=["log-to-obs", "rinex-obs-to-android", "rinex-nav-to-android"])
def test_a_file_given_to_the_wrong_option_names_the_right_one(tmp_path, command, option,
                                                                kind, words):
    """Told by the content, whatever the name (the log is gzipped and named .rnx)."""
    import gzip

    if command == "dashboard":
        pytest.importorskip("viser")
    nav = nav_v2(tmp_path / "n.rnx")
    log = tmp_path / "phone.rnx"
    log.write_bytes(gzip.compress(PHONE_SNIPPET.read_bytes()))
    path = {"log": log, "obs": obs_v2(tmp_path / "o.21o"), "nav": nav}[kind]
    extra = ["--port", "0"] if command == "dashboard" else []
    rc, out, err = run_cli([command, option, path, "--nav", nav, *extra])
    assert_one_line_error(rc, err, str(path), *words)
    assert out == ""


def test_real_obs_and_nav_of_different_days(shared_data):
    rc, _, err = run_cli(["run", "--obs", shared_data / ESBC_OBS, "--nav",
                          shared_data / SLAC_NAV])
    assert_one_line_error(rc, err, NO_EPHEMERIS)


@pytest.mark.parametrize("what", ["nan", "inf"])
def test_non_finite_numbers_in_rinex_files_are_refused(tmp_path, what):
    obs = obs_v3(tmp_path / "o.rnx")
    text = obs.read_text().replace("20000000.125", f"{what:>12}", 1)
    obs.write_text(text)
    with pytest.raises(ValueError) as exc:
        read_obs(obs)
    assert_one_line_value_error(exc, str(obs), "line 10", what)
    nav = nav_v2(tmp_path / "n.rnx")
    nav.write_text(nav.read_text().replace("0.310000000000D+02", f"{what:>18}", 1))
    with pytest.raises(ValueError) as exc:
        read_nav(nav)
    assert_one_line_value_error(exc, str(nav), what)


# -- the command line ------------------------------------------------------------------

#: (id, argv after "raim", words of the message). Every one exits 2 with one line.
CLI_CASES = [
    # The crashes and silent acceptances of issue 13.
    ("set-systems-5", ["run", "default", "--set", "systems=5"], ["systems", "5"]),
    ("set-sats-5", ["run", "default", "--set", "sats=5"], ["sats", "5"]),
    ("set-rename-5", ["run", "default", "--set", "rename=5"], ["rename", "5"]),
    ("set-restrict-5", ["run", "default", "--set", "restrict=5"], ["restrict", "5"]),
    ("set-faults-3", ["run", "default", "--set", "faults=3"], ["faults", "3"]),
    ("set-options-5", ["run", "default", "--set", "options=5"], ["options", "5"]),
    ("restrict-without-sats", ["run", "default", "--set", "restrict=[{t0_s=0}]"],
     ["restrict[0]", "sats"]),
    ("fault-without-sat", ["run", "default", "--set", 'faults=[{kind="step", bias_m=5}]'],
     ["faults[0]", "sat"]),
    ("sats-with-a-number", ["run", "default", "--set", 'sats=["G01", 7]'], ["sats[1]", "7"]),
    ("t-start-nan", ["run", "default", "--set", "t_start_s=nan"], ["t_start_s", "nan", "finite"]),
    ("t-start-inf", ["run", "default", "--set", "t_start_s=inf"], ["t_start_s", "inf", "finite"]),
    ("clock-drift-inf", ["run", "default", "--set", "clock_drift_mps=inf"],
     ["clock_drift_mps", "inf"]),
    ("bias-1e308", ["run", "default", "--fault", "G10,step,1e308,10"], ["bias_m", "1e+308"]),
    ("ramp-rate-inf", ["run", "default", "--fault", "G10,ramp,inf,10"], ["rate_mps", "inf"]),
    ("sigma-true", ["run", "default", "--set", "sigma_m=true"], ["sigma_m", "True"]),
    ("duration-true", ["run", "default", "--set", "duration_s=true"], ["duration_s", "True"]),
    ("duration-string", ["run", "default", "--set", 'duration_s="100"'], ["duration_s", "'100'"]),
    ("option-of-another-algorithm", ["run", "default", "--algorithm", "parity", "--set",
                                     "gf_groups=10"], ["gf_groups", "parity", "gf"]),
    ("unknown-key", ["run", "default", "--set", "sigmam=3"], ["sigmam", "sigma_m"]),
    ("seed-negative", ["run", "default", "--seed", "-1"], ["seed", "-1"]),
    ("seed-bool", ["run", "default", "--set", "seed=true"], ["seed", "True"]),
    ("rename-collision", ["run", "default", "--set", 'rename={G01="G02"}'],
     ["rename", "G02", "two satellites"]),
    ("sats-twice", ["run", "default", "--set", 'sats=["G01", "G01"]'], ["sats", "G01", "twice"]),
    ("fault-on-unknown-satellite", ["run", "default", "--fault", "G99,step,50,0"],
     ["faults", "G99"]),
    ("fault-on-other-system", ["run", "default", "--fault", "C21,step,50,0"],
     ["faults", "C21", "GPS"]),
    ("fault-window-reversed", ["run", "default", "--fault", "G10,step,50,20,10"],
     ["t1_s", "10"]),
    ("fault-syntax", ["run", "default", "--fault", "G10,step"], ["--fault", "G10,step"]),
    ("constellation-fault-unknown-system", ["run", "default", "--fault", "QZS,step,20,300"],
     ["fault QZS", "GPS, BDS, GAL, GLO"]),
    ("constellation-fault-system-not-in-scenario", ["run", "default", "--fault",
                                                    "GAL,step,20,300"],
     ["faults", "constellation fault GAL", "systems (GPS)"]),
    ("constellation-fault-bad-shape", ["run", "default", "--set", 'systems=["GPS","GAL"]',
                                       "--fault", "GAL,jump,20,300"],
     ["--fault", "GAL,jump,20,300"]),
    ("constellation-missing-file", ["run", "default", "--set",
                                    'constellation="/no/such/almanac.alm"'],
     ["constellation", "/no/such/almanac.alm"]),
    ("truth-on-a-simulation", ["run", "default", "--set", "truth_ecef_m=[0,0,0]"],
     ["truth_ecef_m"]),
    ("set-without-value", ["run", "default", "--set", "sigma_m"], ["--set", "sigma_m"]),
    ("unknown-scenario", ["run", "nope"], ["scenario", "nope"]),
    ("missing-toml", ["run", "/no/such/file.toml"], ["/no/such/file.toml", "does not exist"]),
    ("obs-without-nav", ["run", "--obs", "x.rnx"], ["--obs", "--nav"]),
    ("android-without-nav", ["run", "--android", "log.txt"], ["--android", "--nav"]),
    ("nav-without-obs", ["run", "--nav", "n.rnx"], ["--nav", "--obs", "--android"]),
    ("obs-and-android", ["run", "--obs", "o.rnx", "--android", "log.txt", "--nav", "n.rnx"],
     ["--obs", "--android", "exclude each other"]),
    ("missing-phone-log", ["run", "--android", "/no/log.txt", "--nav", "/no/nav.rnx"],
     ["obs", "/no/log.txt", "does not exist"]),
    ("error-model-measured-on-a-simulation", ["run", "default", "--error-model", "measured"],
     ["error_model", "measured", "recording"]),
    ("missing-rinex", ["run", "--obs", "/no/obs.rnx", "--nav", "/no/nav.rnx"],
     ["obs", "/no/obs.rnx", "does not exist"]),
    ("set-nav-entry-number", ["run", "default", "--set", 'nav=["a.rnx", 5]'], ["nav[1]", "5"]),
    ("out-suffix", ["run", "default", "--out", "x.txt"], ["--out", "x.txt"]),
    ("bad-algorithm", ["run", "default", "--algorithm", "nope"], ["algorithm", "nope"]),
    ("seed-not-an-integer", ["run", "default", "--seed", "abc"], ["--seed", "abc"]),
    ("compare-seeds-0", ["compare", "default", "--seeds", "0"], ["--seeds", "0"]),
    ("compare-seeds-past-the-last", ["compare", "default", "--seed", "4294967295",
                                     "--seeds", "2"], ["--seeds", "4294967295"]),
    ("compare-no-names", ["compare", "default", "--algorithms", ","], ["algorithm"]),
    ("compare-unknown-algorithm", ["compare", "default", "--algorithms", "parity,nope"],
     ["algorithm", "nope"]),
    ("compare-option-of-none", ["compare", "default", "--algorithms", "parity", "--set",
                                "gf_groups=3"], ["gf_groups"]),
    ("montecarlo-runs-0", ["montecarlo", "seed004-table2", "--runs", "0"], ["--runs", "0"]),
    ("montecarlo-seed-negative", ["montecarlo", "seed004-table2", "--runs", "1", "--seed",
                                  "-1"], ["--seed", "-1"]),
    ("montecarlo-bias-scale-nan", ["montecarlo", "seed004-table2", "--runs", "1",
                                   "--bias-scale", "nan"], ["--bias-scale", "nan"]),
    ("montecarlo-workers-0", ["montecarlo", "seed004-table2", "--workers", "0"],
     ["--workers", "0"]),
    ("montecarlo-unknown-study", ["montecarlo", "seed004-table3"], ["seed004-table3"]),
    ("keys-unknown-algorithm", ["keys", "nope"], ["algorithm", "nope"]),
    ("show-unknown-scenario", ["show", "nope"], ["nope"]),
    ("unknown-command", ["frobnicate"], ["frobnicate"]),
]


@pytest.mark.parametrize("argv, words", [c[1:] for c in CLI_CASES],
                         ids=[c[0] for c in CLI_CASES])
def test_cli_refuses_bad_input_in_one_line(argv, words):
    rc, out, err = run_cli(argv)
    assert_one_line_error(rc, err, *words)
    assert out == ""  # nothing was run


#: Scenario files with one bad key each: (id, TOML text, words of the message).
TOML_CASES = [
    ("duration-string", 'duration_s = "100"', ["duration_s", "'100'"]),
    ("fault-without-sat", '[[faults]]\nkind = "step"\nbias_m = 5', ["faults[0]", "sat"]),
    ("sats-with-a-number", 'sats = ["G01", 7]', ["sats[1]", "7"]),
    ("t-start-nan", "t_start_s = nan", ["t_start_s", "nan"]),
    ("t-start-inf", "t_start_s = inf", ["t_start_s", "inf"]),
    ("clock-drift-inf", "clock_drift_mps = inf", ["clock_drift_mps", "inf"]),
    ("bias-1e308", '[[faults]]\nsat = "G10"\nbias_m = 1e308', ["bias_m", "1e+308"]),
    ("sigma-true", "sigma_m = true", ["sigma_m", "True"]),
    ("duration-true", "duration_s = true", ["duration_s", "True"]),
    ("faults-as-one-table", '[faults]\nsat = "G10"', ["faults", "[[faults]]"]),
    ("options-of-another-algorithm", "[options]\ngf_groups = 10", ["gf_groups", "parity"]),
    ("syntax-error", "sigma_m = ", ["invalid TOML", "line 1"]),
    ("a-date", "duration_s = 1979-05-27", ["duration_s", "1979"]),
    ("ramp-with-a-bias", '[[faults]]\nsat = "G10"\nkind = "ramp"\nbias_m = 3',
     ["faults[0]", "rate_mps"]),
    ("unknown-fault-key", '[[faults]]\nsat = "G10"\nbias = 3', ["faults[0]", "bias"]),
    ("constellation-fault-unknown-system",
     '[[faults]]\nkind = "constellation"\nsystem = "QZS"\nbias_m = 20',
     ["faults[0]", "system", "'QZS'", "GAL"]),
    ("constellation-fault-system-not-in-scenario",
     '[[faults]]\nkind = "constellation"\nsystem = "GAL"\nbias_m = 20',
     ["faults", "constellation fault GAL", "systems (GPS)"]),
    ("constellation-fault-bad-shape",
     'systems = ["GPS", "GAL"]\n[[faults]]\nkind = "constellation"\nsystem = "GAL"\n'
     'shape = "jump"\nbias_m = 20', ["faults[0]", "GAL", "shape", "'jump'"]),
    ("constellation-fault-without-system", '[[faults]]\nkind = "constellation"\nbias_m = 20',
     ["faults[0]", "system"]),
    ("constellation-fault-with-sat",
     '[[faults]]\nkind = "constellation"\nsat = "GAL"\nbias_m = 20', ["faults[0]", "sat"]),
    ("nav-a-number", "nav = 5", ["nav", "5"]),
    ("nav-entry-a-number", 'nav = ["a.rnx", 5]', ["nav[1]", "5"]),
]


@pytest.mark.parametrize("text, words", [c[1:] for c in TOML_CASES],
                         ids=[c[0] for c in TOML_CASES])
def test_bad_scenario_files_are_refused_naming_the_file_and_key(tmp_path, text, words):
    path = tmp_path / "bad.toml"
    path.write_text(text + "\n")
    rc, _, err = run_cli(["run", path])
    assert_one_line_error(rc, err, str(path), *words)
    with pytest.raises(ValueError) as exc:
        load_scenario(path)
    assert_one_line_value_error(exc, *words)


def test_truth_at_the_earth_centre_on_a_recording_is_refused(tmp_path):
    obs, nav = obs_v2(tmp_path / "o.rnx"), nav_v2(tmp_path / "n.rnx")
    rc, _, err = run_cli(["run", "--obs", obs, "--nav", nav, "--set", "truth_ecef_m=[0,0,0]"])
    assert_one_line_error(rc, err, "truth_ecef_m", "0.0 km")


def test_missing_navigation_file_in_the_list_is_named(tmp_path):
    obs, nav = obs_v3(tmp_path / "o.rnx"), nav_v2(tmp_path / "n.rnx")
    missing = tmp_path / "no_such_EN.rnx"
    rc, out, err = run_cli(["run", "--obs", obs, "--nav", nav, "--nav", missing])
    assert_one_line_error(rc, err, "nav[1]", str(missing), "does not exist")
    assert out == ""
    pytest.importorskip("viser")
    pytest.importorskip("plotly")
    rc, out, err = run_cli(["dashboard", "--port", "0", "--obs", obs, "--nav", nav, "--nav",
                            missing])  # refused before serving
    assert_one_line_error(rc, err, "nav[1]", str(missing), "does not exist")


def test_console_script_refuses_bad_input_in_one_line():
    if not RAIM.exists():
        pytest.skip("the raim console script is not installed in this environment")
    for argv, words in ((["run", "default", "--set", "systems=5"], ["systems"]),
                        (["run", "default", "--set", "t_start_s=nan"], ["t_start_s"]),
                        (["run", "default", "--seed", "x"], ["--seed"])):
        r = subprocess.run([str(RAIM), *argv], capture_output=True, text=True, timeout=60)
        assert_one_line_error(r.returncode, r.stderr, *words)


# -- the public API --------------------------------------------------------------------

#: (id, call, words of the message); every call raises ValueError.
API_CASES = [
    ("Scenario-seed-True", lambda: Scenario(seed=True), ["seed", "True"]),
    ("Scenario-seed-float", lambda: Scenario(seed=1.5), ["seed", "1.5"]),
    ("Scenario-sigma-True", lambda: Scenario(sigma_m=True), ["sigma_m", "True"]),
    ("Scenario-sigma-0", lambda: Scenario(sigma_m=0.0), ["sigma_m", "0"]),
    ("Scenario-sigma-1e-300", lambda: Scenario(sigma_m=1e-300), ["sigma_m", "1e-300", "0.001"]),
    ("Scenario-duration-True", lambda: Scenario(duration_s=True), ["duration_s"]),
    ("Scenario-t-start-nan", lambda: Scenario(t_start_s=math.nan), ["t_start_s", "nan"]),
    ("Scenario-clock-drift-inf", lambda: Scenario(clock_drift_mps=math.inf),
     ["clock_drift_mps", "inf"]),
    ("Scenario-systems-5", lambda: Scenario(systems=5), ["systems"]),
    ("Scenario-systems-unknown", lambda: Scenario(systems=["QZS"]), ["systems[0]", "QZS"]),
    ("Scenario-sats-string", lambda: Scenario(sats="G01"), ["sats", "'G01'"]),
    ("Scenario-sats-number", lambda: Scenario(sats=["G01", 7]), ["sats[1]", "7"]),
    ("Scenario-rename-5", lambda: Scenario(rename=5), ["rename"]),
    ("Scenario-restrict-5", lambda: Scenario(restrict=5), ["restrict"]),
    ("Scenario-restrict-no-sats", lambda: Scenario(restrict=[{"t0_s": 0}]),
     ["restrict[0]", "sats"]),
    ("Scenario-faults-3", lambda: Scenario(faults=3), ["faults"]),
    ("Scenario-fault-no-sat", lambda: Scenario(faults=[{"kind": "step"}]), ["faults[0]", "sat"]),
    ("Scenario-options-5", lambda: Scenario(options=5), ["options"]),
    ("Scenario-option-of-another-algorithm",
     lambda: Scenario(options={"gf_groups": 10}), ["gf_groups", "parity"]),
    ("Scenario-option-value", lambda: Scenario(options={"max_exclusions": 2.5}),
     ["max_exclusions", "2.5"]),
    ("Scenario-algorithm", lambda: Scenario(algorithm="nope"), ["algorithm", "nope"]),
    ("Scenario-truth-at-the-centre",
     lambda: Scenario(source="rinex", obs="o.rnx", nav="n.rnx", truth_ecef_m=[0, 0, 0]),
     ["truth_ecef_m", "0.0 km"]),
    ("Scenario-truth-two-values",
     lambda: Scenario(source="rinex", obs="o.rnx", nav="n.rnx", truth_ecef_m=[1e6, 2e6]),
     ["truth_ecef_m", "2 values"]),
    ("Scenario-rinex-without-files", lambda: Scenario(source="rinex"), ["obs", "nav"]),
    ("Scenario-android-without-files", lambda: Scenario(source="android"),
     ["android", "obs", "GnssLogger", "nav"]),
    ("Scenario-source-unknown", lambda: Scenario(source="phone"), ["source", "phone",
                                                                   "android"]),
    ("recording_scenario-source-sim", lambda: recording_scenario(__file__, [__file__],
                                                                 source="sim"),
     ["source", "sim", "rinex", "android"]),
    ("load_recording-source-unknown",
     lambda: load_recording(__file__, [__file__], source="sp3"), ["source", "sp3"]),
    ("Scenario-nav-empty-list", lambda: Scenario(source="rinex", obs="o.rnx", nav=[]),
     ["nav", "no file"]),
    ("Scenario-nav-entry-number", lambda: Scenario(source="rinex", obs="o.rnx",
                                                   nav=["n.rnx", 5]), ["nav[1]", "5"]),
    ("Scenario-nav-twice", lambda: Scenario(source="rinex", obs="o.rnx",
                                            nav=["n.rnx", "n.rnx"]), ["nav[1]", "n.rnx"]),
    ("load_recording-missing-nav-1",
     lambda: load_recording(__file__, [__file__, "/no/such/nav.rnx"]),
     ["nav[1]", "/no/such/nav.rnx", "does not exist"]),
    ("load_recording-no-nav", lambda: load_recording(__file__, []), ["nav", "none"]),
    ("replace-algorithm-list", lambda: Scenario().replace(algorithm=["gf"]), ["algorithm"]),
    ("from_dict-not-a-table", lambda: from_dict([1]), ["table"]),
    ("from_dict-duration-string", lambda: from_dict({"duration_s": "100"}),
     ["duration_s", "'100'"]),
    ("from_dict-unknown-key", lambda: from_dict({"sigmam": 3}), ["sigmam", "sigma_m"]),
    ("from_dict-option-for-parity", lambda: from_dict({"algorithm": "parity",
                                                       "gf_groups": 10}),
     ["gf_groups", "parity"]),
    ("load_scenario-unknown", lambda: load_scenario("nope"), ["unknown scenario", "nope"]),
    ("load_scenario-override", lambda: load_scenario("default", sigma_m=True), ["sigma_m"]),
    ("Fault-bias-1e308", lambda: Fault("G10", bias_m=1e308), ["bias_m", "1e+308"]),
    ("Fault-bias-True", lambda: Fault("G10", bias_m=True), ["bias_m", "True"]),
    ("Fault-bias-nan", lambda: Fault("G10", bias_m=math.nan), ["bias_m", "nan"]),
    ("Fault-sat-number", lambda: Fault(7), ["sat", "7"]),
    ("Fault-kind", lambda: Fault("G10", kind="spike"), ["kind", "spike"]),
    ("Fault-window", lambda: Fault("G10", t0_s=50.0, t1_s=10.0), ["t1_s", "10"]),
    ("Fault-t0-inf", lambda: Fault("G10", t0_s=math.inf), ["t0_s", "inf"]),
    ("Fault-unknown-system", lambda: Fault("Gal", bias_m=20.0), ["fault Gal", "'GAL'"]),
    ("Fault-kind-constellation", lambda: Fault("GAL", kind="constellation"),
     ["fault GAL", "constellation", "step or ramp"]),
    ("Scenario-constellation-fault-not-in-systems",
     lambda: Scenario(faults=[Fault("GLO", bias_m=20.0)]),
     ["faults", "constellation fault GLO", "systems (GPS)"]),
    ("Scenario-constellation-fault-bad-shape",
     lambda: Scenario(systems=["GPS", "GAL"], faults=[
         {"kind": "constellation", "system": "GAL", "shape": "spike"}]),
     ["faults[0]", "shape", "'spike'"]),
    ("run_scenario-not-a-scenario", lambda: run_scenario(5), ["Scenario", "int"]),
    ("run_scenario-bad-override", lambda: run_scenario("default", sigma_m=True),
     ["sigma_m"]),
    ("compare-unknown-algorithm", lambda: compare_algorithms("default", ["nope"]),
     ["algorithm", "nope"]),
    ("compare-option-of-none", lambda: compare_algorithms("default", ["parity"],
                                                          gf_groups=3), ["gf_groups"]),
    ("compare-algorithm-key-list", lambda: compare_algorithms("default", ["parity"],
                                                              algorithm=[1]), ["algorithm"]),
    ("read_obs-missing", lambda: read_obs("/no/such/obs.rnx"), ["/no/such/obs.rnx"]),
    ("read_nav-missing", lambda: read_nav("/no/such/nav.rnx"), ["/no/such/nav.rnx"]),
    ("read_yuma-missing", lambda: read_yuma("/no/such/almanac.alm"), ["/no/such/almanac.alm"]),
    ("Study-seed-negative", lambda: Study(seed=-1), ["seed", "-1"]),
    ("Study-n-visible-not-a-list", lambda: Study(n_visible=14), ["n_visible", "14"]),
    ("Study-option-out-of-range", lambda: Study(algorithms=("gf:groups=-1",)),
     ["gf_groups", "-1"]),
    ("Study-option-of-another-algorithm", lambda: Study(algorithms=("rs:groups=10",)),
     ["groups", "rs"]),
    ("parse_algorithm-bool", lambda: parse_algorithm("rs:draws=true"), ["rs_draws", "True"]),
]


@pytest.mark.parametrize("call, words", [c[1:] for c in API_CASES],
                         ids=[c[0] for c in API_CASES])
def test_api_refuses_bad_input_naming_it(call, words):
    with pytest.raises(ValueError) as exc:
        call()
    assert_one_line_value_error(exc, *words)


@pytest.mark.parametrize("call, words", [
    (lambda p: read_nav(obs_v3(p / "o.rnx")), ["navigation file", "line 1"]),
    (lambda p: read_obs(nav_v3(p / "n.rnx")), ["observation file", "line 1"]),
    (lambda p: read_obs(obs_v3(p / "o.rnx", truncate=True)), ["file ends"]),
    (lambda p: read_obs(obs_v3(p / "o.rnx", bad_number=True)), ["2100x060.250"]),
    (lambda p: read_nav(nav_v2(p / "n.rnx", truncate=True)), ["file ends"]),
], ids=["nav-is-obs", "obs-is-nav", "obs-truncated", "obs-bad-number", "nav-truncated"])
def test_rinex_readers_refuse_bad_files_naming_file_and_line(tmp_path, call, words):
    with pytest.raises(ValueError) as exc:
        call(tmp_path)
    assert_one_line_value_error(exc, str(tmp_path), *words)


def test_numpy_scalars_are_numbers():
    f = Fault("G10", bias_m=np.int64(5), t0_s=np.float32(2.0))
    assert f.bias_m == 5.0 and type(f.bias_m) is float and type(f.t0_s) is float
    s = Scenario(seed=np.int64(3), sigma_m=np.float32(2.5), faults=[f])
    assert s.seed == 3 and type(s.seed) is int and s.sigma_m == 2.5


def test_gf_groups_reaches_the_monte_carlo_kernel_from_the_schema():
    name, opts = parse_algorithm("gf:groups=100")
    from raimcore import algorithms

    assert name == "gf" and opts == algorithms.get("gf").resolve_options({"gf_groups": 100})
    assert parse_algorithm("gf")[1] == algorithms.get("gf").defaults


# -- faults that never act: a warning note, listed in the summary -------------------------

def _never_used_satellite(s: Scenario) -> str:
    data, _ = simulate(s)
    never = ~data.used.any(axis=0)
    assert never.any(), "every satellite is in view: choose another scenario"
    return data.sat_names[int(np.flatnonzero(never)[0])]


@pytest.mark.parametrize("case", ["never-in-view", "before-the-start", "after-the-end"])
def test_a_fault_that_never_acts_is_a_warning_in_the_summary(case, capsys):
    base = load_scenario("default", duration_s=20, faults=[])
    if case == "never-in-view":
        sat = _never_used_satellite(base)
        fault, why = {"sat": sat, "bias_m": 100.0}, f"{sat} is never used"
    elif case == "before-the-start":
        sat, why = "G10", "outside the run"
        fault = {"sat": sat, "bias_m": 100.0, "t0_s": -50.0, "t1_s": -10.0}
    else:
        sat, why = "G10", "outside the run"
        fault = {"sat": sat, "bias_m": 100.0, "t0_s": 500.0}
    result = run_scenario(base.replace(faults=[fault]))
    notes = [n for n in result.summary.notes if n.startswith("warning: fault")]
    assert len(notes) == 1 and sat in notes[0] and "never acts" in notes[0] and why in notes[0]
    assert result.summary.faulted_epochs == 0
    f = Fault.from_dict(fault)
    spec = f"{f.sat},step,{f.bias_m:g},{f.t0_s:g}" + (
        f",{f.t1_s:g}" if math.isfinite(f.t1_s) else "")
    rc, out, err = run_cli(["run", "default", "--set", "duration_s=20", "--fault", spec])
    assert rc == 0 and "Traceback" not in err
    assert any(line.startswith(f"note: warning: fault {sat}") and "never acts" in line
               for line in out.splitlines()), out


def test_a_fault_that_acts_gets_no_warning():
    r = run_scenario("default", duration_s=20, faults=[{"sat": "G10", "bias_m": 100.0}])
    assert not [n for n in r.summary.notes if n.startswith("warning: fault")]


# -- strict outputs --------------------------------------------------------------------

def _no_nan(text: str):
    def refuse(const):
        raise AssertionError(f"{const} in the JSON output")

    return json.loads(text, parse_constant=refuse)


def test_quiet_json_has_null_not_nan_and_csv_has_empty_cells(tmp_path):
    # Mask 89 deg: no satellite is ever used, every epoch unavailable, nearly every
    # statistic missing.
    csv_path, json_path = tmp_path / "t.csv", tmp_path / "t.json"
    rc, out, err = run_cli(["run", "default", "--set", "mask_deg=89", "--set",
                            "duration_s=10", "-q", "--out", csv_path])
    assert rc == 0, err
    summary = _no_nan(out)
    assert summary["unavailable_epochs"] == 11 and summary["rmse_before_m"] is None
    text = csv_path.read_text()
    assert "nan" not in text.lower() and "inf" not in text.lower()
    header, *rows = text.splitlines()
    col = header.split(",").index("hpe_before_m")
    assert len(rows) == 11 and all(r.split(",")[col] == "" for r in rows)
    rc, _, err = run_cli(["run", "default", "--set", "mask_deg=89", "--set",
                          "duration_s=10", "-q", "--out", json_path])
    assert rc == 0, err
    table = _no_nan(json_path.read_text())
    assert set(table["columns"]["hpe_before_m"]) == {None}


def test_compare_outputs_are_strict(tmp_path):
    for name in ("c.json", "c.csv"):
        rc, _, err = run_cli(["compare", "default", "--algorithms", "parity,rs", "--set",
                              "mask_deg=89", "--set", "duration_s=5", "--out", tmp_path / name])
        assert rc == 0, err
    rows = _no_nan((tmp_path / "c.json").read_text())
    assert rows[0]["rmse_before_m"] is None
    text = (tmp_path / "c.csv").read_text()
    assert "nan" not in text.lower() and ",," in text


# -- the dashboard: port and host ------------------------------------------------------

def _dashboard(*args) -> tuple[subprocess.CompletedProcess, float]:
    pytest.importorskip("viser")
    if not RAIM.exists():
        pytest.skip("the raim console script is not installed in this environment")
    t0 = time.perf_counter()
    r = subprocess.run([str(RAIM), "dashboard", *args], capture_output=True, text=True,
                       timeout=10)
    return r, time.perf_counter() - t0


@pytest.mark.parametrize("args, words", [
    (["--port", "99999"], ["--port", "99999"]),
    (["--port", "-1"], ["--port", "-1"]),
    (["--port", "http"], ["--port", "http"]),
    (["--host", "999.1.1.1"], ["--host", "999.1.1.1"]),
    (["--scenario", "nope"], ["nope"]),
], ids=["port-99999", "port-negative", "port-not-a-number", "host-999", "unknown-scenario"])
def test_dashboard_bad_port_or_host_exits_at_once(args, words):
    r, _ = _dashboard(*args)  # timeout=10: a dashboard that serves instead fails the test
    assert_one_line_error(r.returncode, r.stderr, *words)
    assert r.stdout == ""


def test_dashboard_on_a_busy_explicit_port_exits_with_a_message():
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r, _ = _dashboard("--port", str(port))
    assert_one_line_error(r.returncode, r.stderr, "--port", str(port), "busy")


# -- Ctrl-C and real bugs --------------------------------------------------------------

@pytest.mark.parametrize("workers", [1, 2])
def test_ctrl_c_during_monte_carlo_ends_with_one_line(workers, tmp_path):
    if not RAIM.exists():
        pytest.skip("the raim console script is not installed in this environment")
    out_dir = tmp_path / "mc"
    # Ctrl-C as in a terminal: the command starts with SIGINT's default action even when
    # the test runs as a background job (which inherits SIGINT ignored; Python then keeps
    # it ignored and never raises KeyboardInterrupt).
    p = subprocess.Popen([str(RAIM), "montecarlo", "seed004-table2", "--runs", "5000",
                          "--workers", str(workers), "--no-progress", "--out", out_dir],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True,  # its own group: we can see its workers
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 30.0
        while not out_dir.exists() and time.monotonic() < deadline:  # the study started
            time.sleep(0.05)
        time.sleep(2.0)  # well inside the study (it takes minutes)
        p.send_signal(signal.SIGINT)  # to the main process only, as `kill -INT` would
        out, err = p.communicate(timeout=30)
        assert p.returncode == 130, err
        assert "Traceback" not in err
        assert err.strip().splitlines() == ["raim: interrupted"]
        deadline = time.monotonic() + 5.0
        while time.monotonic() < deadline:  # the pool's workers end with it
            try:
                os.killpg(p.pid, 0)
            except ProcessLookupError:
                break
            time.sleep(0.1)
        else:
            pytest.fail("worker processes outlived the interrupted command")
    finally:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        p.wait(timeout=10)


def test_an_unexpected_exception_is_a_bug_with_a_traceback(monkeypatch):
    def broken(args):
        return 1 / 0

    monkeypatch.setattr(cli, "_cmd_list", broken)
    rc, _, err = run_cli(["list"])
    assert rc == 1
    assert "Traceback" in err and "ZeroDivisionError" in err
    assert "please report" in err.strip().splitlines()[-1]


def test_a_value_error_from_inside_numpy_is_a_bug_not_a_user_error(monkeypatch):
    def broken(args):
        np.random.SeedSequence(-1)  # numpy refuses: our bug, not the user's input

    monkeypatch.setattr(cli, "_cmd_list", broken)
    rc, _, err = run_cli(["list"])
    assert rc == 1 and "Traceback" in err and "please report" in err
