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
