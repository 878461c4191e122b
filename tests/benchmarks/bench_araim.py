"""Benchmark: the ARAIM MHSS kernel, batched vs a per-epoch loop, and a world LPV-200 grid.

Run from the repository root::

    python tests/benchmarks/bench_araim.py [--epochs 288] [--loop 300] [--repeat 2]
                                           [--world] [--fde] [--ism maast|b2012]

Inputs: nominal GPS + Galileo (``raimcore.sky.constellations.builtin(["GPS", "GAL"])``),
users on a 10 x 10 deg world grid at height 0 (MAAST's ``usrworld.dat`` grid: latitudes
-90..80, longitudes -180..170, 648 users), epochs every 300 s from t = 0, 5 deg mask,
MAAST's example ISM (``raimcore.araim.MAAST_EXAMPLE_ISM``), the ED-259A airborne model and
the LPV-200 ADD constants.

1. Kernel: :func:`raimcore.araim.mhss` on ``--epochs`` x 648 user-epochs at once, against
   the same function called once per user-epoch on ``--loop`` of them; prints user-epochs/s,
   the ratio, and whether the protection levels agree.
2. ``--world``: the full study, 288 epochs x 648 users = 186,624 user-epochs, in one
   process (geometry and kernel timed apart), with the LPV-200 availability (VPL <= 35,
   HPL <= 40, EMT <= 15, sigma_acc <= 1.87) and the coverage at 99.5 % weighted by
   cos(latitude) (ARAIM.md section 11). ``--fde`` adds exclusion (section 9).
Not a test: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # run from a checkout
from raimcore import geometry  # noqa: E402
from raimcore.araim import (  # noqa: E402
    MAAST_EXAMPLE_ISM,
    mhss,
    sigma_tropo_m,
    sigma_user_ed259a_m,
)
from raimcore.sky.constellations import builtin  # noqa: E402

SYSTEMS = ("GPS", "GAL")
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
    rate_b, rate_l = n / best_batch, len(pick) / best_loop
    print(f"mhss {kw or ''} GPS+GAL nominal, {g.shape[0]} epochs x {g.shape[1]} users")
    print(f"  batched : {rate_b:10.0f} user-epochs/s  ({n} user-epochs, {best_batch:.2f} s)")
    print(f"  loop    : {rate_l:10.0f} user-epochs/s  ({len(pick)} calls, one per user-epoch)")
    print(f"  ratio batched/loop: {rate_b / rate_l:.1f}x   same PLs: {same}")


def bench_world(kw: dict, ism: str) -> None:
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--epochs", type=int, default=24)
    parser.add_argument("--loop", type=int, default=300)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--world", action="store_true")
    parser.add_argument("--fde", action="store_true")
    parser.add_argument("--ism", choices=sorted(ISMS), default="maast")
    args = parser.parse_args()
    kw = {"fde": True} if args.fde else {}
    bench_kernel(args.epochs, args.loop, args.repeat, kw, args.ism)
    if args.world:
        bench_world(kw, args.ism)


if __name__ == "__main__":
    main()
