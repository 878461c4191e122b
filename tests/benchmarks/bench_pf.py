"""Benchmark: the bank of s + 1 particle filters, vectorised against a per-filter loop.

Seed 002 (6 satellites: 7 filters), N = 100, 1,000 and 10,000 particles. Both paths run
the same kernels (:class:`raimcore.algorithms.pf.ParticleBank` ``step``: predict, likelihood,
weights, N_eff, systematic resampling): once with the 7 filters as one batch axis, once
as 7 banks of one filter stepped in a Python loop. Prints epochs/s and the ratio.

Run: ``python tests/benchmarks/bench_pf.py`` (from the repository root).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from raimcore.algorithms import pf  # noqa: E402
from raimcore.pipeline import simulate  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402
from tests.benchmarks.bench_parity import best_of  # noqa: E402


def setup(n_particles: int):
    d, _ = simulate(load_scenario("seed002"))
    model = pf.ProcessModel()
    fix = pf.robust_fix(d.pos_sv_ecef_m[0], d.pr_m[:1], d.used[0], d.sys_idx, 1, d.noise)
    s_n = d.n_sats
    masks = np.vstack([np.ones(s_n, bool), ~np.eye(s_n, dtype=bool)])  # (Q, S)
    cloud = pf.initial_cloud(fix.pos_ecef_m, fix.clock_m, fix.cov_enu, n_particles, model,
                             np.random.default_rng(0), batch=(s_n + 1,), inflate=3.0)[0]
    return d, model, masks, cloud


def run_vectorised(d, model, masks, cloud, epochs):
    bank = pf.ParticleBank(cloud, model)
    rng = np.random.default_rng(1)
    for k in range(1, epochs + 1):
        bank.step(1.0, d.pos_sv_ecef_m[k][None], d.pr_m[k][None], masks & d.used[k],
                  d.sys_idx, d.noise, rng)


def run_loop(d, model, masks, cloud, epochs):
    banks = [pf.ParticleBank(c, model) for c in cloud]
    rng = np.random.default_rng(1)
    for k in range(1, epochs + 1):
        for bank, m in zip(banks, masks, strict=True):
            bank.step(1.0, d.pos_sv_ecef_m[k], d.pr_m[k], m & d.used[k], d.sys_idx,
                      d.noise, rng)


def main() -> None:
    print("bank of 7 particle filters (seed 002), epochs/s, best of 3")
    print(f"{'N':>7} {'vectorised':>12} {'loop':>12} {'ratio':>7} {'ms/epoch':>9}")
    for n, epochs in ((100, 200), (1000, 100), (10000, 20)):
        args = setup(n)
        t_vec = best_of(lambda a=args, e=epochs: run_vectorised(*a, e), 3)
        t_loop = best_of(lambda a=args, e=epochs: run_loop(*a, e), 3)
        print(f"{n:>7} {epochs / t_vec:>12.0f} {epochs / t_loop:>12.0f} "
              f"{t_loop / t_vec:>6.1f}x {1e3 * t_vec / epochs:>9.2f}")


if __name__ == "__main__":
    main()
