import json
import subprocess
import sys

import pytest

from raimcore.cli import build_parser, main


def test_run_writes_csv_and_json(tmp_path, capsys):
    out = tmp_path / "r.csv"
    assert main(["run", "seed000-step", "--set", "sigma_m=3", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "correct isolation rate over faulted epochs: 100.0%" in text
    header = out.read_text().splitlines()[0].split(",")
    for col in ("t_s", "n_sat", "statistic", "threshold", "alarm", "excluded", "hpe_before_m",
                "hpe_after_m", "vpe_before_m", "vpe_after_m", "faulty_truth", "pd_theory"):
        assert col in header
    js = tmp_path / "r.json"
    assert main(["run", "seed000-ramp", "--fault", "G04,step,300,10,20", "-q", "--out",
                 str(js)]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["faulted_epochs"] == 10
    data = json.loads(js.read_text())
    assert set(data["columns"]["faulty_truth"]) == {"", "G04"}
    assert "isolation" in data["per_sat"]


def test_errors_exit_2_with_a_message(capsys):
    assert main(["run", "default", "--set", "sigma_m"]) == 2
    assert "--set expects KEY=VALUE" in capsys.readouterr().err
    assert main(["run", "default", "--fault", "G10,step"]) == 2
    assert "--fault must be" in capsys.readouterr().err
    assert main(["run", "default", "--out", "x.txt"]) == 2
    assert "--out must end in .csv or .json" in capsys.readouterr().err


def test_bad_out_path_is_refused_before_the_run(tmp_path, capsys):
    missing = tmp_path / "no_such_folder" / "r.csv"
    assert main(["run", "default", "--out", str(missing)]) == 2
    err = capsys.readouterr().err
    assert "no_such_folder" in err and "does not exist" in err
    assert not missing.parent.exists()
    folder = tmp_path / "a.json"
    folder.mkdir()
    assert main(["compare", "default", "--algorithms", "parity", "--out", str(folder)]) == 2
    assert "is a folder" in capsys.readouterr().err


def test_time_correlated_noise_from_the_command_line(capsys):
    assert main(["run", "seed000-step", "--set", "noise_corr_s=30", "--set", "sigma_m=3"]) == 0
    out = capsys.readouterr().out
    assert "sigma 3 m (gaussian, correlated over 30 s)" in out
    assert "correct isolation rate over faulted epochs: 100.0%" in out
    assert main(["run", "seed000-step", "--set", "noise_corr_s=-1"]) == 2
    err = capsys.readouterr().err
    assert "noise_corr_s must be in [0, " in err and "got -1" in err


def test_list_and_help(capsys):
    assert main(["list"]) == 0
    text = capsys.readouterr().out
    assert "seed000-step" in text and "parity" in text
    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "--help"])
    help_text = capsys.readouterr().out
    for flag in ("--algorithm", "--set", "--fault", "--seed", "--out", "SAT,ramp,RATE_MPS"):
        assert flag in help_text


def test_console_entry_point_runs():
    out = subprocess.run([sys.executable, "-m", "raimcore.cli", "run", "default", "-q"],
                         capture_output=True, text=True, check=True)
    assert json.loads(out.stdout)["epochs"] == 600


def test_compare_shares_the_measurements_and_prints_one_row_each(tmp_path, capsys):
    from raimcore.pipeline import compare_algorithms, run_scenario

    out = tmp_path / "cmp.json"
    assert main(["compare", "seed000-step", "--algorithms", "parity,mss", "--set",
                 "sigma_m=3", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[1].split()[:3] == ["algorithm", "false", "al."]
    assert [ln.split()[0] for ln in lines[2:4]] == ["parity", "mss"]
    rows = json.loads(out.read_text())
    assert [r["algorithm"] for r in rows] == ["parity", "mss"]
    # The same numbers as a single run of each algorithm (same seed, same noise draw).
    for row in rows:
        single = run_scenario("seed000-step", sigma_m=3, algorithm=row["algorithm"]).summary
        assert row["correct_isolation_rate"] == pytest.approx(single["correct_isolation_rate"])
        assert row["rmse_after_m"] == pytest.approx(single["rmse_after_m"])
    res = compare_algorithms("seed000-step", ["parity", "mss"], sigma_m=3)
    assert res[0].measurements is res[1].measurements
    assert rows[0]["correct_isolation_rate"] == 1.0


def test_compare_averages_over_seeds_and_rejects_bad_input(capsys):
    assert main(["compare", "seed000-step", "--algorithms", "parity", "--seeds", "3"]) == 0
    text = capsys.readouterr().out
    assert "seed 0..2" in text
    assert main(["compare", "seed000-step", "--algorithms", "nope"]) == 2
    assert "algorithm must be one of" in capsys.readouterr().err
    assert main(["compare", "seed000-step", "--seeds", "0"]) == 2
    assert "--seeds must be >= 1" in capsys.readouterr().err


def test_compare_gives_each_option_to_the_algorithms_that_take_it(capsys):
    # max_exclusions is parity's; gf, rs and qv run without it (README example).
    assert main(["compare", "seed004-multi", "--algorithms", "gf,parity", "--set",
                 "max_exclusions=3", "--set", "duration_s=130"]) == 0
    out = capsys.readouterr().out
    assert "\ngf " in out and "\nparity " in out
    assert main(["compare", "seed004-multi", "--algorithms", "gf,rs", "--set",
                 "max_exclusions=3"]) == 2
    assert "max_exclusions' belongs to none of gf, rs" in capsys.readouterr().err


def test_nav_is_repeatable_on_run_and_dashboard(capsys):
    args = build_parser().parse_args(["run", "--obs", "o.rnx", "--nav", "A_GN.rnx",
                                      "--nav", "A_EN.rnx"])
    assert args.nav == ["A_GN.rnx", "A_EN.rnx"]
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    assert "repeatable: several files are merged" in " ".join(capsys.readouterr().out.split())
    pytest.importorskip("viser")
    args = build_parser().parse_args(["dashboard", "--obs", "o.rnx", "--nav", "A", "--nav",
                                      "B"])
    assert args.nav == ["A", "B"]


def test_compressed_recording_gives_the_same_run_as_the_plain_files(shared_data, tmp_path,
                                                                    capsys):
    """The first 20 epochs of ESBC, plain and as Hatanaka + gzip (``.crx.gz``, made by the
    ``hatanaka`` package) with a gzipped navigation file: the same summary."""
    import gzip

    import hatanaka

    lines = (shared_data / "ESBC00DNK_R_20201770000_02H_30S_MO.rnx").read_text().splitlines()
    epochs = [i for i, ln in enumerate(lines) if ln.startswith(">")]
    plain = tmp_path / "cut.rnx"
    plain.write_text("\n".join(lines[:epochs[20]]) + "\n")
    crx = tmp_path / "cut.crx.gz"
    crx.write_bytes(hatanaka.compress(plain.read_bytes(), compression="gz"))
    assert crx.read_bytes()[:2] == b"\x1f\x8b"  # gzip
    assert b"COMPACT RINEX" in gzip.decompress(crx.read_bytes())[:200]
    nav = shared_data / "ESBC00DNK_R_20201770000_01D_MN.rnx"
    nav_gz = tmp_path / "nav.rnx.gz"
    nav_gz.write_bytes(gzip.compress(nav.read_bytes()))
    out = []
    for obs, nv in ((plain, nav), (crx, nav_gz)):
        assert main(["run", "--obs", str(obs), "--nav", str(nv), "--fault",
                     "G05,step,50,300", "-q"]) == 0
        out.append(json.loads(capsys.readouterr().out))
    assert out[0]["epochs"] == 20 and out[0]["detection_rate"] == 1.0
    assert out[1] == out[0]


# -- phone logs and --error-model (issue 15 items 6 and 8) ----------------------------------

PHONE_LOG, PHONE_NAV = "pseudoranges_log_2016_06_30_21_26_07.txt", "hour1820.16n"
#: The log's surveyed point (data README: WGS-84 37.422578, -122.081678, -28 m), ECEF.
PHONE_TRUTH = "truth_ecef_m=[-2693671.7485, -4297132.6427, 3854726.4392]"


def test_android_runs_a_phone_log_on_run_and_compare(shared_data, capsys):
    log, nav = shared_data / PHONE_LOG, shared_data / PHONE_NAV
    if not log.is_file():
        pytest.skip(f"{PHONE_LOG} is not in ../shared/data")
    assert main(["run", "--android", str(log), "--nav", str(nav), "--set", PHONE_TRUTH,
                 "--fault", "G12,step,80,60", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["epochs"] == 223 and summary["unavailable_epochs"] == 0
    assert summary["detection_rate"] == 1.0  # lesson 12's answer: 80 m on G12
    assert summary["false_alarm_k"] == 0
    assert main(["compare", "--android", str(log), "--nav", str(nav), "--set", PHONE_TRUTH,
                 "--algorithms", "parity,mss", "--error-model", "elevation"]) == 0
    out = capsys.readouterr().out
    assert "223 epochs" in out and "\nparity " in out and "\nmss " in out
    assert "measured error model" not in out  # --error-model elevation replaced it


def test_error_model_option_is_the_set_shortcut_with_the_schemas_choices(capsys):
    from raimcore.scenario import SCENARIO_KEYS

    runs = []
    for argv in (["--error-model", "elevation"], ["--set", "error_model=elevation"]):
        assert main(["run", "seed000-step", "--set", "duration_s=30", "-q", *argv]) == 0
        runs.append(json.loads(capsys.readouterr().out))
    assert runs[0] == runs[1] and runs[0]["error_model"] == "elevation"
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    choices = ", ".join(SCENARIO_KEYS["error_model"].choices)
    assert f"--error-model NAME the pseudorange error model, one of {choices}" in help_text
    with pytest.raises(SystemExit) as exc:  # argparse's own refusal, exit 2
        main(["compare", "default", "--error-model", "nope"])
    assert exc.value.code == 2
    assert f"choose from {', '.join(map(repr, SCENARIO_KEYS['error_model'].choices))}" in \
        capsys.readouterr().err


def test_building_the_parser_imports_no_scenario_module():
    """--error-model's choices are looked up only when needed: `raim --version` stays fast."""
    code = ("import sys; from raimcore.cli import build_parser; build_parser(); "
            "print('raimcore.scenario' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"


def test_show_prints_the_reports_without_a_scenario_file(capsys):
    assert main(["list"]) == 0
    assert "Reports on real data (raim show NAME): android, recordings" in \
        capsys.readouterr().out
    for name, title in (("android", "# Phone logs"), ("recordings", "# Real recordings")):
        assert main(["show", name]) == 0
        assert capsys.readouterr().out.startswith(title)


def test_summary_header_names_the_error_model_where_sigma_m_is_not_used(capsys):
    assert main(["run", "default", "--set", "duration_s=60", "--error-model", "rtklib"]) == 0
    header = capsys.readouterr().out.splitlines()
    header = next(line for line in header if line.startswith("scenario "))
    assert "error model rtklib" in header and "sigma 3 m" not in header
    assert main(["run", "default", "--set", "duration_s=60"]) == 0
    header = next(line for line in capsys.readouterr().out.splitlines()
                  if line.startswith("scenario "))
    assert "sigma 3 m" in header
