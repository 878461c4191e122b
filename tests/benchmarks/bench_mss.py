"""Benchmark: MSS + protection levels, fast kernels vs the reference path (issue 17).

Run from the repository root::

    python tests/benchmarks/bench_mss.py [--epochs 10000] [--sats 10] [--repeat 7]

Everything runs in one process and prints ratios, never absolute pass/fail times:

1. Kernels, with baro, 10 satellites, 10k epochs (seed 001 noise, one 1000 m fault per
   epoch): :func:`raimcore.algorithms.mss.mss` against :func:`~raimcore.algorithms.mss.
   mss_reference`, and the set the ``mss`` algorithm computes (MSS with baro, MSS without
   baro and :func:`~raimcore.algorithms.mss.classic_raim`) against the reference set.
   Timings are interleaved (fast, reference, fast, ...) and the best of ``--repeat`` runs
   is kept, so load from other processes hurts both alike. It also checks that alarms,
   statuses and identification verdicts are identical and PLs agree to 1e-6.
2. Per-epoch time of the fast MSS at 1k, 10k and 100k epochs (one call each; the kernel
   works in blocks of ``BLOCK_ELEMENTS`` values, so the cost per epoch should be flat).
3. The registered ``mss`` algorithm on ``seed001-flight`` (WLS + the three kernels), with
   the fast kernels and with the reference kernels swapped in.
"""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout
from raimcore.algorithms import mss  # noqa: E402

SIGMA_M, SIGMA_BARO_M, P_FA, P_MD = 33.3, 50.0, 1e-5, 1e-3  # seed 001


def make_inputs(n_epochs: int, n_sat: int, seed: int = 0):
    """Random geometries above 7.5 deg with one 1000 m fault per epoch, plus a baro row."""
    rng = np.random.default_rng(seed)
    az = rng.uniform(0.0, 2.0 * np.pi, (n_epochs, n_sat))
    el = np.arcsin(rng.uniform(np.sin(np.radians(7.5)), 1.0, (n_epochs, n_sat)))
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], axis=-1)
    h = mss.geometry_rows(u, np.zeros(n_sat, int), 1, baro=True)
    sd = np.r_[np.full(n_sat, SIGMA_M), SIGMA_BARO_M]
    w = np.broadcast_to(sd**-2, (n_epochs, n_sat + 1))
    z = rng.normal(size=w.shape) * sd
    z[np.arange(n_epochs), rng.integers(0, n_sat, n_epochs)] += 1000.0
    return h, z, w, np.r_[np.ones(n_sat, bool), False]


def run_all(h, z, w, is_sat, *, reference=False):
    """MSS with and without baro plus the classic slope PLs (what the algorithm computes)."""
    f_mss = mss.mss_reference if reference else mss.mss
    f_classic = mss.classic_raim_reference if reference else mss.classic_raim
    w_off = w * is_sat
    return (f_mss(h, z, w, is_sat, P_FA, P_MD), f_mss(h, z, w_off, is_sat, P_FA, P_MD),
            f_classic(h, z, w_off, is_sat, P_FA, P_MD))


def best_of(fns, repeat):
    """Best wall time of each callable, interleaved over ``repeat`` rounds."""
    best = [np.inf] * len(fns)
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            t0 = time.perf_counter()
            fn()
            best[i] = min(best[i], time.perf_counter() - t0)
    return best


def same_results(fast, ref) -> bool:
    """Decisions identical, numbers to 1e-6 relative (what the agreement tests assert)."""
    for a, b in zip(fast, ref, strict=True):
        for name in a.__dataclass_fields__:
            x, y = np.asarray(getattr(a, name)), np.asarray(getattr(b, name))
            if x.dtype.kind == "f":
                if not np.allclose(x, y, rtol=1e-6, atol=1e-9, equal_nan=True):
                    return False
            elif not np.array_equal(x, y):
                return False
    return True


def bench_kernels(n_epochs: int, n_sat: int, repeat: int) -> None:
    h, z, w, is_sat = make_inputs(n_epochs, n_sat)
    t_fast, t_ref = best_of([lambda: mss.mss(h, z, w, is_sat, P_FA, P_MD),
                             lambda: mss.mss_reference(h, z, w, is_sat, P_FA, P_MD)], repeat)
    print(f"MSS + PL with baro, {n_sat} satellites + baro, {n_epochs} epochs "
          f"(best of {repeat}, interleaved)")
    print(f"  fast      : {n_epochs / t_fast:10.0f} epochs/s")
    print(f"  reference : {n_epochs / t_ref:10.0f} epochs/s")
    print(f"  ratio fast/reference: {t_ref / t_fast:.1f}x")
    t_fast, t_ref = best_of([lambda: run_all(h, z, w, is_sat),
                             lambda: run_all(h, z, w, is_sat, reference=True)], repeat)
    same = same_results(run_all(h, z, w, is_sat), run_all(h, z, w, is_sat, reference=True))
    print("MSS with baro + MSS without baro + classic PLs (the mss algorithm's kernel set)")
    print(f"  fast      : {n_epochs / t_fast:10.0f} epochs/s")
    print(f"  reference : {n_epochs / t_ref:10.0f} epochs/s")
    print(f"  ratio fast/reference: {t_ref / t_fast:.1f}x   same results: {same}")


def bench_scaling(n_sat: int, repeat: int, sizes=(1_000, 10_000, 100_000)) -> None:
    h, z, w, is_sat = make_inputs(max(sizes), n_sat, seed=1)
    print(f"Fast MSS with baro, time per epoch vs batch size ({n_sat} satellites + baro, "
          f"blocks of {mss._block_epochs(n_sat)} epochs; interleaved, best of {repeat})")

    def timed(n):  # one sample: calls of n epochs covering at least 10k epochs
        calls = max(1, 10_000 // n)

        def run():
            for _ in range(calls):
                mss.mss(h[:n], z[:n], w[:n], is_sat, P_FA, P_MD)
        return run, calls * n

    runs = [timed(n) for n in sizes]
    times = best_of([r for r, _ in runs], repeat)
    per = {n: t / m for n, t, (_, m) in zip(sizes, times, runs, strict=True)}
    base = per[10_000] if 10_000 in per else per[sizes[0]]
    for n in sizes:
        print(f"  {n:7d} epochs: {per[n] * 1e6:6.2f} us/epoch  ({per[n] / base:.2f}x the 10k "
              "figure)")


@contextmanager
def reference_kernels():
    """Swap the reference kernels in for the fast ones (the algorithm calls them by name)."""
    saved = mss.mss, mss.classic_raim
    mss.mss, mss.classic_raim = mss.mss_reference, mss.classic_raim_reference
    try:
        yield
    finally:
        mss.mss, mss.classic_raim = saved


def bench_algorithm(repeat: int) -> None:
    from raimcore import algorithms
    from raimcore.pipeline import simulate
    from raimcore.scenario import load_scenario

    scen = load_scenario("seed001-flight")
    data, _ = simulate(scen)
    spec = algorithms.get("mss")
    opts = scen.algorithm_options()

    def run_ref():
        with reference_kernels():
            return spec.run(data, opts)

    t_fast, t_ref = best_of([lambda: spec.run(data, opts), run_ref], repeat)
    fast, ref = spec.run(data, opts), run_ref()
    same = (np.array_equal(fast.alarm, ref.alarm) and np.array_equal(fast.status, ref.status)
            and np.array_equal(fast.excluded, ref.excluded)
            and np.allclose(fast.columns["vpl_m"], ref.columns["vpl_m"], rtol=1e-6,
                            equal_nan=True))
    print(f"mss algorithm on seed001-flight ({data.n_epochs} epochs, {data.n_sats} satellites, "
          "baro on: WLS + MSS with/without baro + classic)")
    print(f"  fast kernels      : {data.n_epochs / t_fast:10.0f} epochs/s")
    print(f"  reference kernels : {data.n_epochs / t_ref:10.0f} epochs/s")
    print(f"  ratio: {t_ref / t_fast:.1f}x   same decisions and VPL: {same}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=10_000)
    parser.add_argument("--sats", type=int, default=10)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--no-scaling", action="store_true", help="skip the 1k..100k part")
    args = parser.parse_args()
    bench_kernels(args.epochs, args.sats, args.repeat)
    if not args.no_scaling:
        bench_scaling(args.sats, args.repeat)
    bench_algorithm(max(2, args.repeat // 2))


if __name__ == "__main__":
    main()
