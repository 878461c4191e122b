"""Benchmark: every algorithm of the registry on a real four-system recording.

The 2-hour, 30-s RINEX 3.05 file of ESBC (../shared/data: GPS, Galileo, BeiDou and
GLONASS, about 40 satellites an epoch, 240 epochs) with its navigation file, as
``raim run --obs ... --nav ... --set systems=[...]`` runs it (the reading is cached after
the first run, as in the dashboard). Each algorithm runs twice: first (its one-time work
included: PF-LLR's threshold calibration, unless cached on disk) and again with another
seed (what every further run costs). The full day (2,880 epochs, the same kind of data)
is the one-time work plus 12 times the second run; the issue's target for all algorithms
together is 10 s.

Run: ``python tests/benchmarks/bench_recording.py [--algorithms parity,mss,...]``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from raimcore import algorithms  # noqa: E402
from raimcore.pipeline import run_scenario  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
OBS = DATA / "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
NAV = DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx"
DAY_EPOCHS = 2880


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--algorithms", default=",".join(algorithms.names()),
                    help="comma-separated names (default: all)")
    args = ap.parse_args(argv)
    names = [a.strip() for a in args.algorithms.split(",") if a.strip()]
    unknown = sorted(set(names) - set(algorithms.names()))
    if unknown:
        ap.error(f"unknown algorithm(s) {', '.join(unknown)}; "
                 f"allowed: {', '.join(algorithms.names())}")
    if not OBS.exists() or not NAV.exists():
        print(f"skipped: {OBS.name} or {NAV.name} not in {DATA}")
        return 0
    base = load_scenario("default").replace(
        source="rinex", obs=str(OBS), nav=[str(NAV)], systems=["GPS", "GAL", "BDS", "GLO"],
        faults=[], duration_s=7200.0, step_s=30.0)
    t0 = time.perf_counter()
    run_scenario(base)
    print(f"reading + correcting the recording (once): {time.perf_counter() - t0:.2f} s")
    total = 0.0
    print(f"{'algorithm':10s} {'first run':>10s} {'again':>8s} {'ms/epoch':>9s} "
          f"{'full day':>9s}")
    for name in names:
        t0 = time.perf_counter()
        res = run_scenario(base.replace(algorithm=name))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        run_scenario(base.replace(algorithm=name, seed=base.seed + 1))  # caches kept
        again = time.perf_counter() - t0
        n_epochs = len(res.measurements.t_s)
        day = max(first - again, 0.0) + again * DAY_EPOCHS / n_epochs
        total += day
        print(f"{name:10s} {first:9.2f}s {again:7.2f}s {1e3 * again / n_epochs:9.2f} "
              f"{day:8.1f}s")
    print(f"{'all':10s} {'':>10s} {'':>8s} {'':>9s} {total:8.1f}s  "
          f"(target for the day: <= 10 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
