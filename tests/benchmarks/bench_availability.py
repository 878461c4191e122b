"""Benchmark: the ARAIM LPV-200 world availability map (MAAST's study), in-process and on a
process pool, against a per-user-epoch loop of the same kernel.

Run from the repository root::

    python tests/benchmarks/bench_availability.py [--ism b2012|maast] [--workers 2]
                                                  [--loop 200] [--dask]

The study: nominal GPS + Galileo, users on the 10 x 10 deg world grid (648), epochs every
300 s over 24 h (288): 186,624 user-epochs (target: under 60 s in-process on the 2-core
machine). The loop calls :func:`raimcore.araim.mhss` once per user-epoch on ``--loop``
random user-epochs (geometry included, as the study does) and the ratio compares the
rates. ``--dask`` also runs it on a 2-worker Dask LocalCluster. Not a test: nothing here
asserts a time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout
from raimcore.araim import mhss  # noqa: E402
from raimcore.sky.constellations import builtin  # noqa: E402
from raimcore.studies.availability import (  # noqa: E402
    ISM_PRESETS,
    _Task,
    availability,
    geometry_inputs,
    user_grid,
)

SYSTEMS = ("GPS", "GAL")


def loop_rate(n: int, ism: str) -> float:
    """User-epochs per second of one ``mhss`` call per user-epoch (geometry included)."""
    _, _, lat, lon, _ = user_grid(10, 10)
    t_all = np.arange(0.0, 86400.0, 300.0)
    rng = np.random.default_rng(0)
    pick_u = rng.integers(0, lat.size, n)
    pick_t = rng.integers(0, t_all.size, n)
    task = _Task(builtin(SYSTEMS), SYSTEMS, t_all, lat, lon, 0.0, 5.0, ISM_PRESETS[ism],
                 "ed259a", (35.0, 40.0, 15.0, 1.87))
    t0 = time.perf_counter()
    for u, t in zip(pick_u, pick_t, strict=True):
        args = geometry_inputs(task, t_all[t:t + 1], lat[u:u + 1], lon[u:u + 1])
        g = args[0][0, 0]
        vis = np.isfinite(g).all(axis=-1)
        one = [a[0, 0][vis] for a in args[1:5]]
        mhss(g[vis], *one, args[5][vis], args[6], return_modes=False)
    return n / (time.perf_counter() - t0)


def run(label: str, **kw) -> float:
    res = availability(SYSTEMS, **kw)
    rate = res.n_user_epochs / res.wall_s
    print(f"{label:12s}: {res.wall_s:6.1f} s, {res.n_user_epochs} user-epochs, "
          f"{rate:8.0f} user-epochs/s, coverage {res.coverage_pct:.1f} % "
          f"(ISM {res.settings['ism']})")
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ism", choices=sorted(ISM_PRESETS), default="b2012")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--loop", type=int, default=200)
    parser.add_argument("--dask", action="store_true")
    args = parser.parse_args()
    print("world 10 x 10 deg, 24 h at 300 s, GPS + Galileo nominal")
    rate1 = run("in-process", ism=args.ism)
    if args.workers > 1:
        rate_w = run(f"{args.workers} processes", ism=args.ism, workers=args.workers)
        print(f"  pool / in-process: {rate_w / rate1:.2f}x")
    if args.dask:
        rate_d = run(f"dask {args.workers}w", ism=args.ism, workers=args.workers,
                     dask="local")
        print(f"  dask / in-process: {rate_d / rate1:.2f}x")
    rate_l = loop_rate(args.loop, args.ism)
    print(f"per-user-epoch loop ({args.loop} calls): {rate_l:8.0f} user-epochs/s; "
          f"study / loop: {rate1 / rate_l:.1f}x")


if __name__ == "__main__":
    main()
