"""Benchmark: the ARAIM MHSS kernel, batched vs a per-epoch loop, and a world LPV-200 grid.

Run from the repository root::

    python tests/benchmarks/bench_araim.py [--epochs 288] [--loop 300] [--repeat 2]
                                           [--world] [--fde] [--ism maast|b2012]
                                           [--reference] [--recording [--duration 7200]]

Inputs: nominal GPS + Galileo (``raimcore.sky.constellations.builtin(["GPS", "GAL"])``),
users on a 10 x 10 deg world grid at height 0 (MAAST's ``usrworld.dat`` grid: latitudes
-90..80, longitudes -180..170, 648 users), epochs every 300 s from t = 0, 5 deg mask,
MAAST's example ISM (``raimcore.araim.MAAST_EXAMPLE_ISM``), the ED-259A airborne model and
the LPV-200 ADD constants.

1. Kernel: :func:`raimcore.araim.mhss` on ``--epochs`` x 648 user-epochs at once, against
   the same function called once per user-epoch on ``--loop`` of them, and against the
   reference path (``raimcore.araim.mhss._mhss(..., reference=True)``: the kernel as first
   written, exclusion candidates one by one) on the same batch; prints user-epochs/s, the
   ratios, and whether the results agree (PLs to 1 um, decisions identical).
2. ``--world``: the full study, 288 epochs x 648 users = 186,624 user-epochs, in one
   process (geometry and kernel timed apart), with the LPV-200 availability (VPL <= 35,
   HPL <= 40, EMT <= 15, sigma_acc <= 1.87) and the coverage at 99.5 % weighted by
   cos(latitude) (ARAIM.md section 11). ``--fde`` adds exclusion (section 9);
   ``--reference`` also runs the reference path on it and prints the ratio (slow: about
   100 s with ``--fde``).
3. ``--recording``: the real GPS + GAL + BDS + GLO recording (``../shared/data/
   ESBC00DNK_R_20201770000_02H_30S_MO.rnx``, about 40 satellites, 30 s) for ``--duration``
   seconds through the ``araim`` algorithm (exclusion on, as by default): the whole run,
   then the kernel on the same inputs, fast and reference paths, with their ratio; then
   the fast path with the compiled kernels (numba, :mod:`raimcore.araim._numba`) against
   the same path in numpy (``RAIM_STUDIO_NUMBA=0``), and the kernels' compile time (cold:
   an empty numba cache; cached: loaded from it), each in a fresh interpreter.
Not a test: nothing here asserts a time.

Measured on the shared 2-core machine (December 2026, issue 17; other jobs running):
the 2-hour recording took about 22 s before (94 ms per epoch), the kernel now about
3.6x faster than the reference path on it; the world map with exclusion went from 95-130 s
to about 60 s in-process (kernel about 1.7x the reference path on the same batch).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout
import importlib  # noqa: E402

from raimcore import geometry  # noqa: E402
from raimcore.araim import (  # noqa: E402
    MAAST_EXAMPLE_ISM,
    mhss,
    sigma_tropo_m,
    sigma_user_ed259a_m,
)
from raimcore.sky.constellations import builtin  # noqa: E402

_KERNEL = importlib.import_module("raimcore.araim.mhss")
_KERNEL_MOD = importlib.import_module("raimcore.araim.kernel")
SYSTEMS = ("GPS", "GAL")
DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
MASK_RAD = np.radians(5.0)


def world_users(step_deg: float = 10.0):
    """MAAST's world grid: latitudes -90 .. 90 - step, longitudes -180 .. 180 - step."""
    lat = np.arange(-90.0, 90.0, step_deg)
    lon = np.arange(-180.0, 180.0, step_deg)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    return la.ravel(), lo.ravel()


#: ISMs: MAAST's example (``main_maast_araim.m``: sigma_URA 2.4 / 6 m, a horizontal-ARAIM
#: example, far from LPV-200 accuracy) and the B2012 worked-example ISM (sigma_URA 0.75 m,
#: sigma_URE 0.5 m, b_nom 0.5 m) with MAAST's priors.
ISMS = {
    "maast": MAAST_EXAMPLE_ISM,
    "b2012": {s: dict(MAAST_EXAMPLE_ISM[s], sigma_ura_m=0.75, sigma_ure_m=0.5, b_nom_m=0.5)
              for s in SYSTEMS},
}


def world_inputs(n_epochs: int, step_deg: float = 10.0, t_step_s: float = 300.0,
                 ism: str = "maast"):
    """Arguments of :func:`mhss` for ``(n_epochs, n_users)`` user-epochs."""
    const = builtin(SYSTEMS)
    sys_of = np.array(const.systems)
    t = np.arange(n_epochs) * t_step_s
    sv = const.positions_ecef_m(t)  # (T, S, 3)
    lat, lon = world_users(step_deg)
    rx = geometry.geodetic_to_ecef(np.radians(lat), np.radians(lon), 0.0)  # (U, 3)
    u, _ = geometry.los_enu(sv[:, None], rx[None])  # (T, U, S, 3)
    el = np.arcsin(np.clip(u[..., 2], -1.0, 1.0))
    clock = (sys_of[:, None] == np.array(SYSTEMS)[None, :]).astype(float)  # (S, 2)
    g = np.concatenate([-u, np.broadcast_to(clock, u.shape[:-1] + (2,))], axis=-1)
    g[el < MASK_RAD] = np.nan
    table = ISMS[ism]
    ism = {k: np.array([table[s][k] for s in sys_of]) for k in
           ("sigma_ura_m", "sigma_ure_m", "b_nom_m", "p_sat")}
    with np.errstate(invalid="ignore"):
        common = sigma_tropo_m(el) ** 2 + sigma_user_ed259a_m(el) ** 2
    s_int = np.sqrt(ism["sigma_ura_m"] ** 2 + common)
    s_acc = np.sqrt(ism["sigma_ure_m"] ** 2 + common)
    p_const = np.array([table[s]["p_const"] for s in SYSTEMS])
    b = np.broadcast_to(ism["b_nom_m"], s_int.shape)
    return (g, s_int, s_acc, b, np.zeros_like(s_int), ism["p_sat"], p_const), lat


def pls(res):
    return np.stack([res.hpl_m, res.vpl_m, res.emt_m, res.sigma_acc_v_m], axis=-1)


def reference(*args, **kw):
    """The reference path of :func:`mhss` (the kernel as first written)."""
    return _KERNEL._mhss(*args, reference=True, **kw)


def agree(fast, ref) -> str:
    """Largest PL difference and whether every decision is the same."""
    d = np.nan_to_num(np.abs(pls(fast) - pls(ref)), nan=0.0, posinf=np.inf)
    same_inf = np.array_equal(np.isinf(pls(fast)), np.isinf(pls(ref)))
    flags = all(np.array_equal(getattr(fast, f), getattr(ref, f))
                for f in ("status", "alarm", "excluded_sat", "excluded_const", "vpl_set_by",
                          "hpl_set_by", "n_modes") if getattr(fast, f) is not None)
    return (f"max |PL, EMT, sigma_acc diff| {np.max(d[np.isfinite(d)], initial=0.0):.1e} m, "
            f"same infinities {same_inf}, same decisions {flags}")


def best_time(fn, repeat: int):
    best, out = np.inf, None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def bench_kernel(n_epochs: int, n_loop: int, repeat: int, kw: dict, ism: str) -> None:
    args, _ = world_inputs(n_epochs, ism=ism)
    g = args[0]
    n = g.shape[0] * g.shape[1]
    best_batch = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        res = mhss(*args, **kw)
        best_batch = min(best_batch, time.perf_counter() - t0)
    flat = [np.broadcast_to(a, g.shape[:2] + np.shape(a)[-1:] if np.ndim(a) else a)
            for a in args[1:]]
    rng = np.random.default_rng(0)
    pick = rng.choice(n, size=min(n_loop, n), replace=False)
    ti, ui = np.unravel_index(pick, g.shape[:2])
    best_loop = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        loop = np.stack([pls(mhss(g[a, b], *(f[a, b] if f.ndim == 3 else f for f in flat),
                                  **kw)) for a, b in zip(ti, ui, strict=True)])
        best_loop = min(best_loop, time.perf_counter() - t0)
    same = np.allclose(loop, pls(res)[ti, ui], rtol=1e-9, atol=1e-9)
    t_ref, ref = best_time(lambda: reference(*args, **kw), repeat)
    rate_b, rate_l = n / best_batch, len(pick) / best_loop
    print(f"mhss {kw or ''} GPS+GAL nominal, {g.shape[0]} epochs x {g.shape[1]} users")
    print(f"  batched : {rate_b:10.0f} user-epochs/s  ({n} user-epochs, {best_batch:.2f} s)")
    print(f"  loop    : {rate_l:10.0f} user-epochs/s  ({len(pick)} calls, one per user-epoch)")
    print(f"  reference path (same batch): {n / t_ref:10.0f} user-epochs/s ({t_ref:.2f} s)")
    print(f"  ratio batched/loop: {rate_b / rate_l:.1f}x   same PLs: {same}")
    print(f"  ratio batched/reference: {t_ref / best_batch:.2f}x   {agree(res, ref)}")


def bench_world(kw: dict, ism: str, with_reference: bool) -> None:
    t0 = time.perf_counter()
    args, lat = world_inputs(288, ism=ism)
    t1 = time.perf_counter()
    res = mhss(*args, return_modes=False, **kw)
    t2 = time.perf_counter()
    avail = ((res.vpl_m <= 35.0) & (res.hpl_m <= 40.0) & (res.emt_m <= 15.0)
             & (res.sigma_acc_v_m <= 1.87))
    share = avail.mean(axis=0)  # per user
    w = np.cos(np.radians(lat))
    cover = 100.0 * w[share >= 0.995].sum() / w.sum()
    n = avail.size
    print(f"world 10x10 deg, 288 epochs, {n} user-epochs, ISM {ism} {kw or ''}")
    print(f"  geometry {t1 - t0:6.1f} s, kernel {t2 - t1:6.1f} s "
          f"({n / (t2 - t1):.0f} user-epochs/s), total {t2 - t0:6.1f} s")
    print(f"  LPV-200 coverage (99.5 %, cos-lat weighted): {cover:.1f} %; "
          f"median VPL {np.median(res.vpl_m):.1f} m, 99th pct VPL "
          f"{np.percentile(res.vpl_m, 99):.1f} m; unavailable epochs "
          f"{np.sum(res.status != 'ok')}")
    for name, ok in (("VPL <= 35", res.vpl_m <= 35.0), ("HPL <= 40", res.hpl_m <= 40.0),
                     ("EMT <= 15", res.emt_m <= 15.0),
                     ("sigma_acc <= 1.87", res.sigma_acc_v_m <= 1.87)):
        print(f"  {name:18s} met in {100.0 * ok.mean():5.1f} % of user-epochs")
    if with_reference:
        t_ref, ref = best_time(lambda: reference(*args, return_modes=False, **kw), 1)
        print(f"  reference path kernel {t_ref:6.1f} s; ratio {t_ref / (t2 - t1):.2f}x; "
              f"{agree(res, ref)}")


def bench_recording(duration_s: float, repeat: int) -> None:
    """The ``araim`` algorithm on the four-system recording; the kernel fast vs reference."""
    obs = DATA / "ESBC00DNK_R_20201770000_02H_30S_MO.rnx"
    if not obs.exists():
        print(f"recording: {obs} not found, skipped")
        return
    from raimcore import araim as kernel_pkg
    from raimcore.algorithms import araim as algo
    from raimcore.pipeline import run_scenario
    from raimcore.scenario import load_scenario

    s = load_scenario("default").replace(
        source="rinex", obs=str(obs), nav=[str(DATA / "ESBC00DNK_R_20201770000_01D_MN.rnx")],
        systems=["GPS", "GAL", "BDS", "GLO"], faults=[], duration_s=duration_s, step_s=30.0,
        algorithm="araim")
    captured = []
    real = kernel_pkg.mhss

    def spy(*a, **k):
        captured.append((a, k))
        return real(*a, **k)

    algo.kernel.mhss = spy
    try:
        t0 = time.perf_counter()
        run_scenario(s)
        t_run = time.perf_counter() - t0
    finally:
        algo.kernel.mhss = real
    (a, k), = captured
    n_ep, n_sat = a[0].shape[:2]
    t_fast, fast = best_time(lambda: real(*a, **k), repeat)
    t_ref, ref = best_time(lambda: reference(*a, **k), 1)
    print(f"recording GPS+GAL+BDS+GLO, {n_ep} epochs x {n_sat} satellites, araim with "
          f"exclusion")
    print(f"  run_scenario (whole araim run): {t_run:6.2f} s ({1e3 * t_run / n_ep:.1f} ms/epoch)")
    print(f"  kernel fast     : {t_fast:6.2f} s ({1e3 * t_fast / n_ep:.1f} ms/epoch)")
    print(f"  kernel reference: {t_ref:6.2f} s ({1e3 * t_ref / n_ep:.1f} ms/epoch)")
    print(f"  ratio fast/reference: {t_ref / t_fast:.2f}x   {agree(fast, ref)}")
    if _KERNEL_MOD.numba_kernels() is None:
        print("  numba: not installed or RAIM_STUDIO_NUMBA=0, compiled kernels not timed")
        return
    os.environ[_KERNEL_MOD.NUMBA_ENV] = "0"
    try:
        t_np, plain = best_time(lambda: real(*a, **k), repeat)
    finally:
        del os.environ[_KERNEL_MOD.NUMBA_ENV]
    t_nb, comp = best_time(lambda: real(*a, **k), repeat)
    print(f"  kernel numba    : {t_nb:6.2f} s ({1e3 * t_nb / n_ep:.1f} ms/epoch)")
    print(f"  kernel numpy    : {t_np:6.2f} s ({1e3 * t_np / n_ep:.1f} ms/epoch), "
          f"RAIM_STUDIO_NUMBA=0")
    print(f"  ratio numba/numpy: {t_np / t_nb:.2f}x   {agree(comp, plain)}")


def bench_compile() -> None:
    """Compile time of :mod:`raimcore.araim._numba`: cold (an empty numba cache directory)
    and cached (the same directory again), each in a fresh interpreter, with the import."""
    if _KERNEL_MOD.numba_kernels() is None:
        print("compile: numba not installed or RAIM_STUDIO_NUMBA=0, skipped")
        return
    code = ("import time; t = time.perf_counter(); from raimcore.araim import _numba; "
            "_numba.warm_up(); print(time.perf_counter() - t)")
    root = str(Path(__file__).resolve().parents[2])
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, PYTHONPATH=root)
        times = [float(subprocess.run([sys.executable, "-c", code], env=env, check=True,
                                      capture_output=True, text=True).stdout)
                 for _ in range(2)]
    print(f"compile araim numba kernels (import numba + compile or load): cold {times[0]:.2f} s,"
          f" cached {times[1]:.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=24)
    parser.add_argument("--loop", type=int, default=300)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--world", action="store_true")
    parser.add_argument("--fde", action="store_true")
    parser.add_argument("--ism", choices=sorted(ISMS), default="maast")
    parser.add_argument("--reference", action="store_true")
    parser.add_argument("--recording", action="store_true")
    parser.add_argument("--duration", type=float, default=7200.0)
    args = parser.parse_args()
    kw = {"fde": True} if args.fde else {}
    bench_kernel(args.epochs, args.loop, args.repeat, kw, args.ism)
    if args.world:
        bench_world(kw, args.ism, args.reference)
    if args.recording:
        bench_compile()
        bench_recording(args.duration, args.repeat)


if __name__ == "__main__":
    main()
