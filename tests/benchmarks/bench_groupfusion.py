"""Benchmark: group evidence fusion (seed 004), fast kernels vs reference, and Table 2.

Run from the repository root::

    python tests/benchmarks/bench_groupfusion.py [--runs 2000] [--sats 18] [--faults 2]
    python tests/benchmarks/bench_groupfusion.py --issue17 [--sample 6] [--repeat 3]
    python tests/benchmarks/bench_groupfusion.py --table2 [--workers 2] [--table-runs 5000]

1. One Monte Carlo cell (default 18 satellites, 2 faults at 1.0 P_bias, N^2 groups), the
   same simulated runs for every variant, in the same process:
   - vectorised: :func:`raimcore.algorithms.groupfusion.gf_isolate`, all groups of a chunk of
     runs in one membership-matrix product (as the Monte Carlo engine calls it);
   - per-group loop: :func:`raimcore.algorithms.groupfusion.gf_isolate_loop` (batched over
     runs, one Python iteration per group);
   - scalar loop: one ``numpy.linalg.lstsq`` per run and per group with scipy.stats
     (timed on a subset of runs).
   Prints runs/s of each (best of ``--repeat``), the ratios, and whether the isolated sets
   agree; plus runs/s of a whole cell with fresh geometry (``run_chunk``: simulation + GF).
2. ``--issue17``: the fast kernels of issue 17 against the reference path they replaced
   (``reference=True``: the pre-issue kernels; geometry propagated by
   ``Constellation.positions_ecef_m``; fusion and m(F), changed only a little, are shared),
   same inputs, interleaved, best of ``--repeat``:
   per call (group chi-square, GF, QV after GF, RS, random geometry) and per Monte Carlo
   chunk of Table 2 (every ``--sample``-th setting, both fault scales, all three
   algorithms; the counts must be equal). Prints the ratios and the full Table 2 (2 fault
   scales x 60 settings x 20 chunks of 250 runs) projected on ``--workers`` processes from
   the per-chunk times, against the target of 60 s on two workers.
3. ``--table2``: wall time of the full Table 2 (both fault scales, RS, QV, GF, ``--table-runs``
   runs a cell) on ``--workers`` processes, measured, against the same target, and the
   workers' CPU time (the wall time on cores that nothing else uses). A reduced
   ``--table-runs`` is scaled up to 5,000 with its fixed costs (two process pools started,
   one per fault scale), so it overstates the full run.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout
from raimcore.algorithms import groupfusion as gfm  # noqa: E402
from raimcore.algorithms._groupfusion_common import as_groups  # noqa: E402
from raimcore.studies import montecarlo as mc  # noqa: E402
from raimcore.studies.seed004 import run_table, table2_study  # noqa: E402

SIGMA_M, P_FA, P_MD = 33.0, 1e-5 / 3600, 0.014  # seed 004
#: Issue 17's target for the full Table 2 (both fault scales, 5,000 runs a cell), 2 workers.
TARGET_S = 60.0
#: Chunks in the full Table 2: 2 fault scales x 60 settings x 5,000 / 250 runs.
FULL_CHUNKS = 2 * 60 * (5000 // mc.CHUNK_RUNS)


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


def _forget():
    """Drop the group statistics GF keeps for QV, so each timed call does its own work."""
    gfm._memo = None


def _best(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        _forget()
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


@contextlib.contextmanager
def _reference_geometry():
    """random_geometry with the constellation's own propagation (the pre-issue path)."""
    fast = mc._positions_ecef_m
    mc._positions_ecef_m = lambda systems, t: mc._constellation(systems).positions_ecef_m(t)
    try:
        yield
    finally:
        mc._positions_ecef_m = fast


def _reference_kernel(name, h, y, *, sigma_m, p_fa, rng, **o):
    """The Monte Carlo kernels of :mod:`raimcore.studies.montecarlo` on the reference path."""
    w = sigma_m**-2
    if name == "gf":
        g = gfm.select_groups(y.shape[-1], h.shape[-1] + 1, as_groups(o["gf_groups"]))
        return gfm.gf_isolate(h, y, g, p_fa, weights_lsq=w, margin=o["gf_margin"],
                              weights=o["gf_weights"], reference=True).isolated
    if name == "qv":
        g = gfm.select_groups(y.shape[-1], h.shape[-1] + 1, as_groups(o["qv_groups"]))
        return gfm.qv_isolate(h, y, g, p_fa, weights_lsq=w, margin=o["qv_margin"],
                              norm=o["qv_norm"], reference=True)[0]
    return gfm.rs_isolate(h, y, p_fa, rng, weights_lsq=w, n_draws=o["rs_draws"],
                          reference=True)


def reference_chunk(study, setting, chunk: int) -> dict[str, int]:
    """:func:`raimcore.studies.montecarlo.run_chunk` on the reference path (same seeds)."""
    n, k, b = setting
    n_runs = min(mc.CHUNK_RUNS, study.runs - chunk * mc.CHUNK_RUNS)
    css = mc._setting_ss(study.seed, setting).spawn(chunk + 1)[chunk]
    rng = np.random.default_rng(css)
    with _reference_geometry():
        h, y, faulty = mc.simulate_runs(rng, n_runs, n, k, b * study.bias_scale
                                        * study.unit_m(n), study.sigma_m, study.mask_deg,
                                        study.systems)
    detected = mc.full_set_alarm(h, y, study.sigma_m, study.p_fa)
    out = {mc.DETECTED: int(detected.sum())}
    for algo in study.algorithms:
        name, opts = mc.parse_algorithm(algo)
        arng = np.random.default_rng(mc._algo_ss(css, algo))
        iso = _reference_kernel(name, h, y, sigma_m=study.sigma_m, p_fa=study.p_fa,
                                rng=arng, **opts)
        out[algo] = int(np.sum(np.all(iso == faulty, axis=-1)))
    return out


def _call_pairs(n_sat: int) -> tuple[int, dict]:
    """(reference, fast) callables on one chunk of runs of ``n_sat`` satellites."""
    rng = np.random.default_rng(n_sat)
    bias = 2.0 * mc.p_bias_m(n_sat, SIGMA_M, P_FA, P_MD)
    h, y, _ = mc.simulate_runs(rng, mc.CHUNK_RUNS, n_sat, 2, bias, SIGMA_M)
    g = gfm.select_groups(n_sat, 6)
    w = SIGMA_M**-2

    def chi2(ref):
        return gfm.group_chi2(h, y, g, P_FA, w, reference=ref)

    def gf(ref):
        return gfm.gf_isolate(h, y, g, P_FA, weights_lsq=w, reference=ref).isolated

    def gf_qv(ref):
        return gf(ref), gfm.qv_isolate(h, y, g, P_FA, weights_lsq=w, reference=ref)[0]

    def rs(ref):
        return gfm.rs_isolate(h, y, P_FA, np.random.default_rng(1), weights_lsq=w,
                              reference=ref)

    def geometry(ref):
        with _reference_geometry() if ref else contextlib.nullcontext():
            return mc.random_geometry(np.random.default_rng(2), mc.CHUNK_RUNS, n_sat)

    return len(g), {"group_chi2": chi2, "gf_isolate": gf, "gf + qv": gf_qv,
                    "rs_isolate": rs, "random_geometry": geometry}


def bench_calls(repeat: int) -> None:
    """Per call: fast vs reference on one chunk of runs (250), same inputs."""
    print(f"per call, one chunk of {mc.CHUNK_RUNS} runs, 2 faults at 2 P_bias, best of "
          f"{repeat}, reference / fast:")
    for n_sat in (14, 18, 22):
        n_groups, pairs = _call_pairs(n_sat)
        cells = []
        for name, fn in pairs.items():
            fn(True), fn(False)  # warm
            t_ref = _best(lambda f=fn: f(True), repeat)
            t_fast = _best(lambda f=fn: f(False), repeat)
            cells.append(f"{name} {1e3 * t_ref:.1f}/{1e3 * t_fast:.1f} ms "
                         f"= {t_ref / t_fast:.1f}x")
        _forget()
        same = all(np.array_equal(a, b) for name in ("gf + qv", "random_geometry")
                   for a, b in zip(pairs[name](True), pairs[name](False), strict=True))
        same &= np.array_equal(pairs["rs_isolate"](True), pairs["rs_isolate"](False))
        print(f"  N = {n_sat} ({n_groups} groups): " + "; ".join(cells)
              + f"; same decisions and geometry: {same}")


def bench_chunks(sample: int, repeat: int, workers: int) -> None:
    """Whole Monte Carlo chunks of Table 2: run_chunk vs reference_chunk, same seeds.

    Timed both by the wall clock and by this process's CPU time (which counts BLAS threads
    spinning, and does not count other programs sharing the cores); best of ``repeat``.
    """
    studies = [table2_study(runs=5000, bias_scale=s) for s in (1.0, 2.0)]
    todo = [(st, s) for st in studies for s in st.settings()[::sample]]
    mc.run_chunk(studies[0], todo[0][1], 0)  # warm: imports, group lists
    reference_chunk(studies[0], todo[0][1], 0)
    clocks = {"wall": time.perf_counter, "cpu": time.process_time}
    total = {(p, c): 0.0 for p in ("fast", "reference") for c in clocks}
    same = True
    for st, s in todo:
        best = dict.fromkeys(total, np.inf)
        for _ in range(repeat):  # interleaved: load changes hit both alike
            for path, fn in (("fast", mc.run_chunk), ("reference", reference_chunk)):
                _forget()
                t0 = {c: f() for c, f in clocks.items()}
                out = fn(st, s, 0)
                for c, f in clocks.items():
                    best[path, c] = min(best[path, c], f() - t0[c])
                if path == "fast":
                    fast = out
            same &= fast == out
        for key in total:
            total[key] += best[key] / len(todo)
    print(f"Table 2 chunks ({len(todo)} of {FULL_CHUNKS // 20} settings x fault scales, "
          f"{mc.CHUNK_RUNS} runs each, best of {repeat}); same counts: {same}")
    for c in clocks:
        f, r = total["fast", c], total["reference", c]
        proj_f, proj_r = f * FULL_CHUNKS / workers, r * FULL_CHUNKS / workers
        print(f"  {c:>4}: reference {1e3 * r:6.1f} ms, fast {1e3 * f:5.1f} ms per chunk = "
              f"{r / f:.2f}x; full Table 2 projected on {workers} worker(s) (x{FULL_CHUNKS} "
              f"chunks, ideal scaling): reference {proj_r:.0f} s, fast {proj_f:.0f} s, "
              f"target {TARGET_S:.0f} s {'met' if proj_f <= TARGET_S else 'NOT met'}")


def _children_cpu_s() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def bench_table2(runs: int, workers: int) -> None:
    """The full Table 2 as ``raim montecarlo seed004-table2 --workers N`` runs it: wall
    time, and the CPU time of the worker processes (what the cores would need if nothing
    else ran on them)."""
    n = 2 * 60 * 3
    t0, c0 = time.perf_counter(), _children_cpu_s()
    results, _ = run_table("seed004-table2", runs=runs, workers=workers, scales=(1.0, 2.0),
                           progress=False)
    dt, cpu = time.perf_counter() - t0, _children_cpu_s() - c0
    scale = 5000 / runs
    full = dt * scale
    print(f"full Table 2 measured: {n} cells x {runs} runs, both fault scales, {workers} "
          f"worker(s): {dt:.1f} s wall" + (f" (x{scale:g} for 5,000 runs: {full:.0f} s)"
                                           if runs != 5000 else "")
          + f", target {TARGET_S:.0f} s {'met' if full <= TARGET_S else 'NOT met'}; "
          f"worker CPU {cpu:.1f} s ({cpu * scale / workers:.0f} s per worker for 5,000 runs)"
          f"; GF (18, 2, 1.0) = {100 * results[0].rate(18, 2, 1.0, 'gf'):.1f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=2000)
    parser.add_argument("--sats", type=int, default=18)
    parser.add_argument("--faults", type=int, default=2)
    parser.add_argument("--scalar-runs", type=int, default=40)
    parser.add_argument("--repeat", type=int, default=3, help="best of this many")
    parser.add_argument("--issue17", action="store_true",
                        help="fast kernels vs the reference path, per call and per chunk")
    parser.add_argument("--sample", type=int, default=6,
                        help="--issue17: time every this-many-th setting of Table 2")
    parser.add_argument("--table2", action="store_true", help="time the full Table 2")
    parser.add_argument("--table-runs", type=int, default=5000)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    if args.table2:
        bench_table2(args.table_runs, args.workers)
    elif args.issue17:
        bench_calls(args.repeat)
        bench_chunks(args.sample, args.repeat, args.workers)
    else:
        bench_cell(args.runs, args.sats, args.faults, args.scalar_runs, args.repeat)


if __name__ == "__main__":
    main()
