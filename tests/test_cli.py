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
