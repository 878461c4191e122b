"""Benchmark: the ARAIM LPV-200 world availability map (MAAST's study), in-process and on a
process pool, against a per-user-epoch loop of the same kernel.

Run from the repository root::

    python tests/benchmarks/bench_availability.py [--ism b2012|maast] [--workers 2]
                                                  [--loop 200] [--dask]
                                                  [--algorithm araim|mss|classic] [--fde]
                                                  [--t-step 300] [--profile]

The study: nominal GPS + Galileo, users on the 10 x 10 deg world grid (648), epochs every
300 s over 24 h (288): 186,624 user-epochs (target: under 60 s in-process on the 2-core
machine). The loop calls :func:`raimcore.araim.mhss` once per user-epoch on ``--loop``
random user-epochs (geometry included, as the study does) and the ratio compares the
rates. ``--dask`` also runs it on a 2-worker Dask LocalCluster. ``--algorithm`` maps the
MSS or classic protection levels instead, ``--fde`` ARAIM with exclusion; ``--t-step``
scales the study (1800: a sixth of it); ``--profile`` runs the in-process study under
cProfile and prints the 25 costliest functions. Not a test: nothing here asserts a time.

Measured on the shared 2-core machine (in-process, full study; December 2026): araim
about 15-20 s, mss about 30 s, classic about 4 s; araim with --fde about 130 s, of which
about 95 % inside ``raimcore.araim.kernel.evaluate`` (one call for the all-in-view and one
per exclusion candidate, about 20 per visibility pattern; see the report of issue 16).
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


def run(label: str, profile: bool = False, **kw) -> float:
    if profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        res = prof.runcall(availability, SYSTEMS, **kw)
        pstats.Stats(prof).sort_stats("tottime").print_stats(25)
    else:
        res = availability(SYSTEMS, **kw)
    rate = res.n_user_epochs / res.wall_s
    print(f"{label:12s}: {res.wall_s:6.1f} s, {res.n_user_epochs} user-epochs, "
          f"{rate:8.0f} user-epochs/s, coverage {res.coverage_pct:.1f} % "
          f"(ISM {res.settings['ism']}, {res.settings['algorithm']}"
          f"{', fde' if kw.get('fde') else ''})")
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ism", choices=sorted(ISM_PRESETS), default="b2012")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--loop", type=int, default=200)
    parser.add_argument("--dask", action="store_true")
    parser.add_argument("--algorithm", choices=("araim", "mss", "classic"), default="araim")
    parser.add_argument("--fde", action="store_true")
    parser.add_argument("--t-step", type=float, default=300.0)
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args()
    print(f"world 10 x 10 deg, 24 h at {args.t_step:g} s, GPS + Galileo nominal")
    kw = dict(ism=args.ism, algorithm=args.algorithm, t_step_s=args.t_step)
    if args.fde:
        kw["fde"] = True
    rate1 = run("in-process", profile=args.profile, **kw)
    if args.workers > 1:
        rate_w = run(f"{args.workers} processes", workers=args.workers, **kw)
        print(f"  pool / in-process: {rate_w / rate1:.2f}x")
    if args.dask:
        rate_d = run(f"dask {args.workers}w", workers=args.workers, dask="local", **kw)
        print(f"  dask / in-process: {rate_d / rate1:.2f}x")
    if args.algorithm != "araim" or args.fde or args.loop <= 0:
        return
    rate_l = loop_rate(args.loop, args.ism)
    print(f"per-user-epoch loop ({args.loop} calls): {rate_l:8.0f} user-epochs/s; "
          f"study / loop: {rate1 / rate_l:.1f}x")


if __name__ == "__main__":
    main()
