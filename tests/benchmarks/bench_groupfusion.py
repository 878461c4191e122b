"""Benchmark: group evidence fusion (seed 004), vectorised vs loops, and the full Table 2.

Run from the repository root::

    python tests/benchmarks/bench_groupfusion.py [--runs 2000] [--sats 18] [--faults 2]
    python tests/benchmarks/bench_groupfusion.py --table2 [--workers 2] [--table-runs 5000]

1. One Monte Carlo cell (default 18 satellites, 2 faults at 1.0 P_bias, N^2 groups), the
   same simulated runs for every variant, in the same process:
   - vectorised: :func:`raimcore.algorithms.groupfusion.gf_isolate`, all groups of a chunk of
     runs in one membership-matrix product (as the Monte Carlo engine calls it);
   - per-group loop: :func:`raimcore.algorithms.groupfusion.gf_isolate_loop` (batched over runs, one
     Python iteration per group);
   - scalar loop: one ``numpy.linalg.lstsq`` per run and per group with scipy.stats
     (timed on a subset of runs).
   Prints runs/s of each (best of ``--repeat``), the ratios, and whether the isolated sets
   agree; plus runs/s of a whole cell with fresh geometry (``run_chunk``: simulation + GF).
2. ``--table2``: wall time of the full Table 2 (60 settings x RS, QV, GF x runs) at fault
   bias scale 1, against the issue's target of 15 minutes for 5,000 runs on 2 cores.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout
from raimcore.algorithms import groupfusion as gfm  # noqa: E402
from raimcore.studies import montecarlo as mc  # noqa: E402
from raimcore.studies.seed004 import table2_study  # noqa: E402

SIGMA_M, P_FA, P_MD = 33.0, 1e-5 / 3600, 0.014  # seed 004


def scalar_gf(h, y, groups, margin=0.1):
    """The textbook implementation: one least squares per run and per group."""
    n_runs, n_sat = y.shape
    iso = np.zeros(y.shape, dtype=bool)
    for k in range(n_runs):
        num = np.zeros(n_sat)
        den = np.zeros(n_sat)
        for g in groups:
            hg = h[k, g]
            hg = hg[:, np.abs(hg).sum(axis=0) > 0]  # drop the clock of an absent system
            dof = len(g) - hg.shape[1]
            x, *_ = np.linalg.lstsq(hg, y[k, g], rcond=None)
            theta = np.sum((y[k, g] - hg @ x) ** 2) / SIGMA_M**2
            t = stats.chi2.isf(P_FA, dof)
            if theta <= t:
                m_f = 0.5 * stats.chi2.cdf(theta, dof) / stats.chi2.cdf(t, dof)
            else:
                m_f = 0.5 + 0.5 * (1 - stats.chi2.sf(theta, dof) / P_FA)
            alpha = 1.0 / np.sqrt(np.trace(np.linalg.inv(hg.T @ hg)[:3, :3]))
            num[g] += alpha * m_f
            den[g] += alpha
        m = num / den
        iso[k] = m > m.mean() + margin
    return iso


def bench_cell(runs: int, n_sat: int, n_faults: int, scalar_runs: int, repeat: int) -> None:
    rng = np.random.default_rng(0)
    bias = mc.p_bias_m(n_sat, SIGMA_M, P_FA, P_MD)
    h, y, faulty = mc.simulate_runs(rng, runs, n_sat, n_faults, bias, SIGMA_M)
    groups = gfm.select_groups(n_sat, 6)
    w = SIGMA_M**-2
    chunk = mc.CHUNK_RUNS

    def vectorised():
        return np.concatenate([gfm.gf_isolate(h[i:i + chunk], y[i:i + chunk], groups, P_FA,
                                              weights_lsq=w).isolated
                               for i in range(0, runs, chunk)])

    def per_group():
        return np.concatenate([gfm.gf_isolate_loop(h[i:i + chunk], y[i:i + chunk], groups,
                                                   P_FA, weights_lsq=w).isolated
                               for i in range(0, runs, chunk)])

    vectorised()  # warm caches (group list)
    res = {}
    for name, fn, n in (("vectorised", vectorised, runs), ("per-group loop", per_group, runs),
                        ("scalar loop", lambda: scalar_gf(h[:scalar_runs], y[:scalar_runs],
                                                          groups), scalar_runs)):
        best = np.inf
        for _ in range(repeat if name != "scalar loop" else 1):
            t0 = time.perf_counter()
            iso = fn()
            best = min(best, time.perf_counter() - t0)
        res[name] = (n / best, iso)
    base = res["vectorised"][0]
    print(f"one cell: N = {n_sat}, {n_faults} faults at 1.0 P_bias ({bias:.1f} m), "
          f"{len(groups)} groups, {runs} runs (scalar loop: {scalar_runs})")
    for name, (rate, iso) in res.items():
        agree = np.array_equal(iso, res["vectorised"][1][:len(iso)])
        print(f"  {name:<15} {rate:10.0f} runs/s   vectorised is {base / rate:6.1f}x   "
              f"same isolated sets: {agree}")
    correct = np.mean(np.all(res["vectorised"][1] == faulty, axis=-1))
    print(f"  correct isolation rate {100 * correct:.1f}%")
    study = mc.Study(n_visible=(n_sat,), n_faults=(n_faults,), bias=(1.0,),
                     algorithms=("gf",), runs=runs)
    dt = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for c in range(-(-runs // chunk)):
            mc.run_chunk(study, (n_sat, n_faults, 1.0), c)
        dt = min(dt, time.perf_counter() - t0)
    print(f"  whole cell with fresh geometry (simulation + GF): {runs / dt:.0f} runs/s")


def bench_table2(runs: int, workers: int) -> None:
    study = table2_study(runs=runs, bias_scale=1.0)
    n = len(study.settings()) * len(study.algorithms)
    t0 = time.perf_counter()
    res = mc.run_study(study, workers=workers, progress=True)
    dt = time.perf_counter() - t0
    print(f"full Table 2: {n} cells x {runs} runs, {workers} worker(s): {dt:.1f} s "
          f"(target 900 s: {dt / 900:.2f} of it); GF (18, 2, 1.0) = "
          f"{100 * res.rate(18, 2, 1.0, 'gf'):.1f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2000)
    parser.add_argument("--sats", type=int, default=18)
    parser.add_argument("--faults", type=int, default=2)
    parser.add_argument("--scalar-runs", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=3, help="best of this many")
    parser.add_argument("--table2", action="store_true", help="time the full Table 2")
    parser.add_argument("--table-runs", type=int, default=5000)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    if args.table2:
        bench_table2(args.table_runs, args.workers)
    else:
        bench_cell(args.runs, args.sats, args.faults, args.scalar_runs, args.repeat)


if __name__ == "__main__":
    main()
