"""Benchmark: every algorithm of the registry on a real four-system recording.

The 2-hour, 30-s RINEX 3.05 file of ESBC (../shared/data: GPS, Galileo, BeiDou and
GLONASS, about 40 satellites an epoch, 240 epochs) with its navigation file, as
``raim run --obs ... --nav ... --set systems=[...]`` runs it (the reading is cached after
the first run, as in the dashboard). Prints each algorithm's time, the sum, and the sum
scaled to a full day (2,880 epochs: the per-epoch cost times 12, the day's recording being
the same kind of data); the issue's target for the full day is 10 s.

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
    n_epochs = 0
    print(f"{'algorithm':10s} {'time':>8s} {'ms/epoch':>9s} {'full day (x12)':>15s}")
    for name in names:
        t0 = time.perf_counter()
        res = run_scenario(base.replace(algorithm=name))
        dt = time.perf_counter() - t0
        n_epochs = len(res.measurements.t_s)
        total += dt
        print(f"{name:10s} {dt:7.2f}s {1e3 * dt / n_epochs:9.2f} "
              f"{dt * DAY_EPOCHS / n_epochs:14.1f}s")
    print(f"{'all':10s} {total:7.2f}s {1e3 * total / max(n_epochs, 1):9.2f} "
          f"{total * DAY_EPOCHS / max(n_epochs, 1):14.1f}s  (target for the day: <= 10 s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
