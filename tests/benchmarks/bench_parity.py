"""Benchmark: batched snapshot parity FDE against a per-epoch loop of the same code.

10 satellites, 1,000 and 10,000 epochs, a 60 m step fault in half of them, sigma 3 m.
Both paths run ``raimcore.algorithms.parity_fde.run``: once on all epochs, once epoch by
epoch. Prints epochs/s and the ratio (target in issue 2: >= 30x).

Run: ``python tests/benchmarks/bench_parity.py`` (from the repository root).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from raimcore.algorithms.parity_fde import SPEC, run  # noqa: E402
from raimcore.measure.faults import Fault  # noqa: E402
from raimcore.pipeline import simulate  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402

SATS = ["G02", "G05", "G06", "G09", "G10", "G15", "G20", "C02", "C21", "C28"]


def make_data(n_epochs: int):
    step = 0.1
    dur = (n_epochs - 1) * step
    s = load_scenario("default", systems=["GPS", "BDS"], duration_s=dur, step_s=step,
                      sigma_m=3.0, mask_deg=0.0).with_faults(
        Fault("G10", "step", t0_s=dur / 2, bias_m=60.0))
    s = s.replace(sats=SATS)
    data, _ = simulate(s)
    if not data.used.all():
        raise RuntimeError("benchmark geometry lost a satellite; pick others")
    return data


def epoch(data, e):
    return data.take_epochs([e])


def best_of(fn, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def bench(n_epochs: int, loop_epochs: int) -> None:
    data = make_data(n_epochs)
    opts = SPEC.resolve_options({"max_exclusions": 1})
    out = run(data, opts)  # warm up
    # Best of several repeats for both paths: the machine is shared, minima are stable.
    t_batch = best_of(lambda: run(data, opts), 5)
    # Loop over evenly spaced epochs so that half of them are faulted, as in the batch.
    picks = np.linspace(0, n_epochs - 1, loop_epochs).round().astype(int)
    slices = [epoch(data, e) for e in picks]
    loop_alarm = [run(d, opts).alarm[0] for d in slices]
    t_loop = best_of(lambda: [run(d, opts) for d in slices], 3)
    if not np.array_equal(np.array(loop_alarm), out.alarm[picks]):
        raise RuntimeError("batched and per-epoch results differ")
    rate_b = n_epochs / t_batch
    rate_l = loop_epochs / t_loop
    print(f"{n_epochs:>6} epochs x 10 sats: batched {rate_b:12,.0f} epochs/s "
          f"({t_batch * 1e3:7.1f} ms) | per-epoch loop {rate_l:8,.0f} epochs/s "
          f"(timed on {loop_epochs} epochs) | ratio {rate_b / rate_l:6.1f}x | "
          f"alarms {int(out.alarm.sum())}")


if __name__ == "__main__":
    bench(1_000, 1_000)
    bench(10_000, 1_000)
