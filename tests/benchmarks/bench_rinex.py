"""Benchmark: load + SPP + parity FDE of a real recording, batched against a per-epoch loop.

The 2-hour, 30-s RINEX 3.05 mixed file of ESBC (../shared/data, GPS + BDS, 240 epochs) and
its mixed navigation file. The batched path reads both files, corrects every epoch at once
(:func:`raimcore.sky.spp.correct`, through the recording loader), solves all epochs
(:func:`raimcore.sky.spp.solve`) and runs the parity FDE on the recording's Measurements.
The baseline reads the files once, then runs the same functions epoch by epoch
(one-epoch ObsFile slices, one-epoch Measurements). Prints epochs/s of both and the ratio.

Run: ``python tests/benchmarks/bench_rinex.py`` (from the repository root).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from raimcore.algorithms.parity_fde import SPEC, run  # noqa: E402
from raimcore.measure import measure  # noqa: E402
from raimcore.scenario import recording_scenario  # noqa: E402
from raimcore.sky import recording  # noqa: E402
from raimcore.sky.recording import load_recording, recording_sky  # noqa: E402
from raimcore.sky.rinex import read_nav, read_obs  # noqa: E402
from raimcore.sky.spp import correct, solve  # noqa: E402

DATA = ROOT.parent / "shared" / "data"
OBS = DATA / "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
NAV = DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx"
OPTS = SPEC.resolve_options({"max_exclusions": 1})


def batched():
    recording._read_obs.cache_clear()  # time the reading too, not the cache
    recording._corrected.cache_clear()
    s = recording_scenario(str(OBS), str(NAV))
    data, _ = measure(recording_sky(s), s)  # reads, corrects every epoch
    sol = solve(load_recording(s.obs, s.nav, s.systems, s.signals))  # SPP (cached reading)
    out = run(data, OPTS)
    return sol, out


def epoch_slice(obs, e):
    return dataclasses.replace(obs, t_gps_s=obs.t_gps_s[e:e + 1],
                               epoch_flag=obs.epoch_flag[e:e + 1],
                               codes={k: v[e:e + 1] for k, v in obs.codes.items()})


def data_slice(data, e):
    return data.take_epochs([e])


def per_epoch():
    obs, nav = read_obs(OBS), read_nav(NAV)
    s = recording_scenario(str(OBS), str(NAV))
    data, _ = measure(recording_sky(s), s)
    pos = []
    for e in range(len(obs.t_gps_s)):
        corr = correct(epoch_slice(obs, e), nav)
        pos.append(solve(corr).pos_ecef_m[0])
        run(data_slice(data, e), OPTS)
    return np.array(pos)


def best_of(fn, repeats: int) -> tuple[float, object]:
    best, res = float("inf"), None
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = fn()
        best = min(best, time.perf_counter() - t0)
    return best, res


def main() -> int:
    if not OBS.is_file():
        print(f"skipped: {OBS} not present")
        return 0
    t_load, _ = best_of(lambda: (read_obs(OBS), read_nav(NAV)), 3)
    t_b, (sol, _) = best_of(batched, 3)
    t_l, pos = best_of(per_epoch, 1)
    n = len(sol.pos_ecef_m)
    diff = np.nanmax(np.abs(pos - sol.pos_ecef_m))
    print(f"ESBC 2 h mixed, {n} epochs (GPS + BDS): reading obs + nav {t_load * 1e3:.0f} ms")
    print(f"  batched  load + SPP + parity FDE: {t_b * 1e3:8.1f} ms  {n / t_b:10.0f} epochs/s")
    print(f"  per-epoch loop (same code)      : {t_l * 1e3:8.1f} ms  {n / t_l:10.0f} epochs/s")
    print(f"  ratio {t_l / t_b:.1f}x; largest position difference between the two paths "
          f"{diff:.1e} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
