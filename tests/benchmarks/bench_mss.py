"""Benchmark: MSS + protection levels, batched over epochs vs a per-epoch loop.

Run from the repository root::

    python tests/benchmarks/bench_mss.py [--epochs 3600] [--sats 9] [--repeat 3]

1. Kernels: the same kernels (:func:`raimcore.algorithms.mss.mss` and
   :func:`raimcore.algorithms.mss.classic_raim`, with and without baro) on the same random
   geometries, batched vs called once per epoch.
2. Algorithm: the registered ``mss`` algorithm (WLS linearisation + kernels) on the
   ``seed001-flight`` data, all epochs at once vs one single-epoch ``Measurements`` at a time.
Both in the same process; prints epochs/s of each, the ratio, and whether the PLs agree.
"""

from __future__ import annotations

import argparse
import sys
import time
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


def run_all(h, z, w, is_sat):
    """MSS with and without baro plus the classic slope PLs (what the algorithm computes)."""
    w_off = w * is_sat
    with_baro = mss.mss(h, z, w, is_sat, P_FA, P_MD)
    without = mss.mss(h, z, w_off, is_sat, P_FA, P_MD)
    classic = mss.classic_raim(h, z, w_off, is_sat, P_FA, P_MD)
    return np.stack([with_baro.hpl_m, with_baro.vpl_m, without.hpl_m, without.vpl_m,
                     classic.hpl_m, classic.vpl_m], axis=-1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=3600)
    parser.add_argument("--sats", type=int, default=9)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    h, z, w, is_sat = make_inputs(args.epochs, args.sats)

    best_batch = np.inf
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        pl_batch = run_all(h, z, w, is_sat)
        best_batch = min(best_batch, time.perf_counter() - t0)

    n_loop = min(args.epochs, 600)  # the loop is slow: time a slice, report per epoch
    best_loop = np.inf
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        pl_loop = np.stack([run_all(h[e], z[e], w[e], is_sat) for e in range(n_loop)])
        best_loop = min(best_loop, time.perf_counter() - t0)

    same = np.allclose(pl_loop, pl_batch[:n_loop], rtol=1e-9, equal_nan=True)
    rate_batch = args.epochs / best_batch
    rate_loop = n_loop / best_loop
    print(f"MSS + PL (with/without baro + classic), {args.sats} satellites + baro")
    print(f"  batched : {rate_batch:10.0f} epochs/s  ({args.epochs} epochs)")
    print(f"  loop    : {rate_loop:10.0f} epochs/s  ({n_loop} epochs, one call per epoch)")
    print(f"  ratio batched/loop: {rate_batch / rate_loop:.1f}x   same PLs: {same}")
    bench_algorithm(args.repeat)


def epoch_slice(data, e):
    """A single-epoch ``Measurements`` (every per-epoch array cut to ``[e:e+1]``)."""
    return data.take_epochs([e])


def bench_algorithm(repeat: int, n_loop: int = 300) -> None:
    from raimcore import algorithms
    from raimcore.pipeline import simulate
    from raimcore.scenario import load_scenario

    scen = load_scenario("seed001-flight")
    data, _ = simulate(scen)
    spec = algorithms.get("mss")
    opts = scen.algorithm_options()
    best_batch = best_loop = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = spec.run(data, opts)
        best_batch = min(best_batch, time.perf_counter() - t0)
        t0 = time.perf_counter()
        loop = [spec.run(epoch_slice(data, e), opts) for e in range(n_loop)]
        best_loop = min(best_loop, time.perf_counter() - t0)
    same = all(np.allclose(o.columns["vpl_m"], out.columns["vpl_m"][e], rtol=1e-9)
               for e, o in enumerate(loop))
    rate_batch, rate_loop = data.n_epochs / best_batch, n_loop / best_loop
    print(f"mss algorithm on seed001-flight ({data.n_epochs} epochs, {data.n_sats} satellites, "
          "baro on: WLS + MSS with/without baro + classic)")
    print(f"  batched : {rate_batch:10.0f} epochs/s")
    print(f"  loop    : {rate_loop:10.0f} epochs/s  ({n_loop} epochs, one run per epoch)")
    print(f"  ratio batched/loop: {rate_batch / rate_loop:.1f}x   same VPL: {same}")


if __name__ == "__main__":
    main()
