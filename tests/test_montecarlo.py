"""Monte Carlo engine: reproducibility across chunking / workers / Dask, resume, and the
seeded statistical claims of seed 004 (spec 4)."""

import json
import math

import numpy as np
import pytest
from scipy import stats

from raimcore.cli import main
from raimcore.studies import montecarlo as mc
from raimcore.studies.seed004 import paper_table1, paper_table2, table2_study

P_FA = 1e-5 / 3600


def test_p_bias_matches_ncx2_and_the_spec():
    # spec 4: about 309 m for N = 14 and 330 m for N = 22.
    assert mc.p_bias_m(14, 33.0, P_FA, 0.014) == pytest.approx(309.0, abs=0.1)
    assert mc.p_bias_m(22, 33.0, P_FA, 0.014) == pytest.approx(330.2, abs=0.1)
    lam = (mc.p_bias_m(18, 33.0, P_FA, 0.014) / 33.0) ** 2
    assert stats.ncx2.cdf(stats.chi2.isf(P_FA, 13), 13, lam) == pytest.approx(0.014)


def test_group_fault_unit_is_about_twice_the_full_set_p_bias():
    g = mc.p_bias_group_m(33.0, P_FA, 0.014)
    lam = (g / 33.0) ** 2 / 6.0  # non-centrality of a member with mean redundancy 1/6
    assert stats.ncx2.cdf(stats.chi2.isf(P_FA, 1), 1, lam) == pytest.approx(0.014)
    for n in (14, 18, 22):
        assert 1.95 < g / mc.p_bias_m(n, 33.0, P_FA, 0.014) < 2.15
    with pytest.raises(ValueError, match="bias_unit must be one of full, group"):
        mc.Study(bias_unit="paper")


def test_random_geometry_has_exactly_n_visible_of_both_systems():
    h, sys_idx = mc.random_geometry(np.random.default_rng(0), 300, 16, mask_deg=5.0)
    assert h.shape == (300, 16, 5)
    np.testing.assert_allclose(np.linalg.norm(h[..., :3], axis=-1), 1.0)
    assert np.all(-h[..., 2] >= math.sin(math.radians(5.0)) - 1e-12)  # above the mask
    np.testing.assert_array_equal(h[..., 4], sys_idx)
    np.testing.assert_array_equal(h[..., 3] + h[..., 4], 1.0)
    assert np.all(sys_idx.sum(-1) >= 2) and np.all((1 - sys_idx).sum(-1) >= 2)
    assert 0.2 < sys_idx.mean() < 0.8


SMALL = mc.Study(n_visible=(14, 18), n_faults=(1, 2), bias=(1.0,),
                 algorithms=("gf", "rs", "qv"), runs=2 * mc.CHUNK_RUNS + 20, name="small")


@pytest.fixture(scope="module")
def small_in_process():
    return mc.run_study(SMALL, progress=False)


def _counts(res):
    return [(r["n_visible"], r["n_faults"], r["algorithm"], r["correct"]) for r in res.rows]


def test_identical_results_for_one_and_two_workers(small_in_process):
    two = mc.run_study(SMALL, workers=2, progress=False)
    assert _counts(two) == _counts(small_in_process)


def test_identical_results_on_a_dask_local_cluster(small_in_process):
    pytest.importorskip("dask.distributed")
    res = mc.run_study(SMALL, dask="local", workers=2, progress=False)
    assert _counts(res) == _counts(small_in_process)


def test_a_chunk_does_not_depend_on_the_total_number_of_runs():
    longer = mc.Study(**{**SMALL.__dict__, "runs": 3 * mc.CHUNK_RUNS})
    one = mc.run_chunk(SMALL, (18, 2, 1.0), 1)
    assert mc.run_chunk(longer, (18, 2, 1.0), 1) == one
    assert mc.run_chunk(SMALL, (18, 2, 1.0), 0) != one  # another chunk: other runs


def test_resume_skips_finished_settings(tmp_path, monkeypatch):
    study = mc.Study(n_visible=(14,), n_faults=(1, 2), bias=(1.5,), algorithms=("gf",),
                     runs=60, name="resume")
    first = mc.run_study(study, out_dir=tmp_path, progress=False)
    ledger = tmp_path / "ledger.jsonl"
    lines = ledger.read_text().splitlines()
    assert len(lines) == 2
    assert (tmp_path / "resume.csv").read_text().startswith("n_visible,n_faults,bias")
    assert "| bias | faults | algorithm | N=14 |" in (tmp_path / "resume.md").read_text()
    # Interrupted after the first setting (and a half-written line): only the second reruns.
    ledger.write_text(lines[0] + "\n" + lines[1][:10])
    calls = []
    real = mc.run_chunk
    monkeypatch.setattr(mc, "run_chunk", lambda st, s, c: calls.append(s) or real(st, s, c))
    again = mc.run_study(study, out_dir=tmp_path, progress=False)
    assert calls == [(14, 2, 1.5)]
    assert _counts(again) == _counts(first)
    calls.clear()
    mc.run_study(study, out_dir=tmp_path, progress=False)
    assert calls == []
    assert json.loads(ledger.read_text().splitlines()[-1])["counts"]["gf"] >= 0


def test_full_set_test_false_alarm_rate_and_detection_probability_match_theory():
    """The gate's full-set chi-square test: without a fault it alarms at p_fa; with one
    fault of b on satellite i its detection probability is ncx2.sf(T, N - 5, lam_i),
    lam_i = b^2 (1 - l_i) / sigma^2 (l_i the leverage), averaged over the runs' geometries:
    both checked on the count of alarms (normal approximation of the Poisson-binomial)."""
    rng = np.random.default_rng(21)
    p_fa, sigma, n = 0.05, 33.0, 16
    h, y, _ = mc.simulate_runs(rng, 4000, n, 0, 0.0, sigma)
    k = int(mc.full_set_alarm(h, y, sigma, p_fa).sum())
    assert stats.binomtest(k, 4000, p_fa).pvalue > 1e-3, k
    h, y, faulty = mc.simulate_runs(rng, 4000, n, 1, 150.0, sigma)
    alarm = mc.full_set_alarm(h, y, sigma, p_fa)
    lev = np.einsum("rni,rij,rnj->rn", h, np.linalg.inv(np.swapaxes(h, 1, 2) @ h), h)
    lam = 150.0**2 * (1.0 - lev[faulty]) / sigma**2
    pd = stats.ncx2.sf(stats.chi2.isf(p_fa, n - 5), n - 5, lam)
    z = (alarm.sum() - pd.sum()) / math.sqrt(np.sum(pd * (1 - pd)))
    assert abs(z) < 3.5, (int(alarm.sum()), float(pd.sum()))
    assert 0.2 < pd.mean() < 0.9  # a fault size where detection is genuinely uncertain


def test_gate_scores_only_detected_runs_and_reports_the_detection_rate(small_in_process):
    gated = mc.run_study(SMALL.__class__(**{**mc.study_dict(SMALL), "gate": True}),
                         progress=False)
    for a, b in zip(small_in_process.rows, gated.rows, strict=True):
        assert a["detected_rate"] == b["detected_rate"]  # same runs, same test
        assert b["correct"] <= a["correct"]
        assert b["rate"] <= a["detected_rate"]
    assert any(b["correct"] < a["correct"]
               for a, b in zip(small_in_process.rows, gated.rows, strict=True))
    s = SMALL.settings()[0]
    assert mc._ledger_key(SMALL, s) != mc._ledger_key(gated.study, s)  # never mixed on resume


def test_bad_study_parameters_raise():
    with pytest.raises(ValueError, match="algorithm must be one of gf, rs, qv, parity"):
        mc.Study(algorithms=("nope",))
    with pytest.raises(ValueError, match="runs"):
        mc.Study(runs=0)
    with pytest.raises(ValueError, match="workers"):
        mc.run_study(SMALL, workers=0)


@pytest.mark.slow
def test_gf_single_fault_isolation_at_1p5_pbias_with_18_satellites():
    # seed 004 Table 2: 98.74%. Claim: >= 95%, as a 95% binomial lower bound.
    st = mc.Study(n_visible=(18,), n_faults=(1,), bias=(1.5,), algorithms=("gf",),
                  runs=2000, seed=11)
    row = mc.run_study(st, progress=False).rows[0]
    assert stats.binomtest(row["correct"], row["runs"]).proportion_ci(0.95).low >= 0.95


@pytest.mark.slow
def test_gf_beats_rs_and_qv_for_dual_faults_at_1_pbias_with_18_satellites():
    st = mc.Study(n_visible=(18,), n_faults=(2,), bias=(1.0,), algorithms=("gf", "rs", "qv"),
                  runs=1500, seed=12)
    res = mc.run_study(st, progress=False)
    gf = res.rate(18, 2, 1.0, "gf")
    for base in ("rs", "qv"):
        row = next(r for r in res.rows if r["algorithm"] == base)
        # The baseline's upper 95% bound stays below GF's lower bound.
        gf_low = stats.binomtest(round(gf * st.runs), st.runs).proportion_ci(0.95).low
        assert row["ci_high"] < gf_low


def test_paper_tables_are_complete():
    t2 = paper_table2()
    assert len(t2) == 4 * 3 * 3 * 5
    assert t2[(18, 2, 1.0, "gf")] == 98.10
    assert t2[(14, 3, 0.8, "qv")] == 0.0
    t1 = paper_table1()
    assert len(t1) == 9 * 5 - 1 and (14, 6000) not in t1
    assert t1[(22, 6000)] == 99.90
    assert len(table2_study(runs=10).settings()) == 60


def test_cli_prints_our_table_beside_the_papers(capsys, tmp_path):
    rc = main(["montecarlo", "seed004-table2", "--runs", "20", "--bias-scale", "1",
               "--out", str(tmp_path), "--no-progress"])
    assert rc == 0
    out = capsys.readouterr().out
    assert "98.1 |" in out  # the paper's GF cell for N = 18, 2 faults, 1.0 P_bias
    assert "GF ahead of RS and QV in" in out
    assert (tmp_path / "seed004-table2-x1.csv").exists()
    assert (tmp_path / "seed004-table2-comparison.txt").exists()
    assert main(["montecarlo", "seed004-table2", "--runs", "0"]) == 2
