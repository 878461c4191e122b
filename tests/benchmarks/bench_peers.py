"""Benchmark: our snapshot parity FDE against peer libraries, in one process (issue 17).

Everything runs in this process, best of several interleaved repeats (the machine may be
shared: minima are stable), and is printed as one table of epochs/s and our ratio, with
each peer's decisions beside ours so that the speeds compare like with like. The peers
are not project dependencies: a peer that is not installed is reported ("not installed:
pip install X") and skipped, and the script still exits 0.

1. **gnss_lib_py** (Stanford NavLab; ``pip install gnss-lib-py``) on the epochs of
   ``bench_fde.py``'s scenario (10 satellites, 7 GPS + 3 BDS, 10,000 epochs at 10 Hz,
   sigma 3 m; fault-free, and with a 60 m step on G10 over the second half) as a
   ``NavData`` (``gps_millis``, ``x_sv_m``, ``y_sv_m``, ``z_sv_m``, ``b_sv_m``,
   ``corr_pr_m``, ``gnss_id``, ``sv_id``). gnss_lib_py estimates one receiver clock, so the
   BDS-GPS clock offset of the simulation (a constant, estimated from our fault-free
   solution to about 1 cm) is removed from the BDS pseudoranges, and ours runs on the same
   single-clock inputs (``sys_idx`` all 0) for the comparison. Measured:

   * ``solve_wls(sv_rx_time=True)`` (our positions are in the receive-time frame): its
     weighted least squares alone, against our whole FDE;
   * ``solve_fde(method="residual")`` (Blanch et al. 2015, greedy). Its chi-square is
     ``r^T r`` in m^2 (unit weights), so its threshold is ``sigma^2 chi2.isf(p_fa, n - 4)``
     with our ``p_fa = 1e-3``; ``max_faults=1`` (ours: ``max_exclusions=1``). Its internal
     ``solve_wls`` cannot be told that the positions are at receive time, so it gets them
     rotated back to the transmit-time frame by exactly the angle it applies;
   * ``solve_fde(method="edm")`` (Knowles & Gao 2023), ``max_faults=1``, on ranges without
     the receiver clock (its WLS clock removed: the EDM squares the ranges), with its
     default threshold and with the threshold that gives ``p_fa`` on the fault-free run
     (the 0.999 quantile of its statistic there, so its false alarms match by
     construction).

2. **RTKLIB** through **pyrtklib** (``pip install pyrtklib``: a binary wheel of RTKLIB
   2.4.3 b34 with pybind11 bindings; its library is built with ``trace()`` in, as
   ``traceopen`` works). ``pntpos`` takes observations and broadcast ephemerides, not
   satellite positions, so the data are synthetic and built here: 10 GPS satellites on
   circular Keplerian orbits (``eph_t``, e = 0, URA index 0, clock offsets of up to 0.2 ms)
   at 36-81 deg elevation over a receiver at 100 m height; C1C pseudoranges from the
   transmit-time position with RTKLIB's Sagnac term (``geodist``), its satellite clock,
   its Klobuchar ionosphere (default coefficients) and Saastamoinen troposphere, and noise
   of the sigma RTKLIB's variance model gives each of them (``err[1]`` set so that its
   non-atmospheric part is (3 m)^2; 3.8-4.7 m in all); 60 m on one satellite over the
   second half; 10,000 epochs at 10 Hz. Options: single mode, ``posopt[4] = 1`` (RAIM
   FDE), ``pntpos`` warm-started from the previous epoch as a receiver loop runs it. Ours
   gets the same epochs: satellite positions rotated into the receive-time frame,
   pseudoranges corrected with the same clock and atmosphere values, sigma per satellite
   from the same model (the script prints RTKLIB's position covariance over ours, and
   that both test the weighted residuals at chi2 0.999 with the same dof). Not the same
   work: ``pntpos`` also computes satellite positions and atmosphere delays in every
   iteration (its ``satposs`` alone is timed and printed) and runs through the binding
   (a call's overhead is printed); its exclusion re-solves every n - 1 subset, ours once.
   Two RTKLIB 2.4.3 b34 behaviours met on the way, avoided here: ``satposs`` writes the
   broadcast-clock variance (30 m)^2 into ``var[0]`` instead of ``var[i]`` when a
   satellite clock is exactly 0 (the first observation is then down-weighted); and with
   ionosphere/troposphere options that apply nothing (``IONOOPT_QZS`` without QZSS
   parameters, ``TROPOPT_ZTD``) a warm-started ``pntpos`` dropped the first observation.

Run: ``python tests/benchmarks/bench_peers.py [--repeats N] [--epochs N]`` (from the
repository root). ``--epochs`` sets the epochs of every decision run (default 10,000);
the peers are timed on 1,000 epochs spread over the run (their per-epoch loops are
linear in the epochs), ours on all of them.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import os
import platform
import sys
from functools import partial
from pathlib import Path

import numpy as np
from scipy import stats

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_fde import SATS, interleaved, scenario_arrays  # noqa: E402

import raimcore  # noqa: E402

SIGMA_M = 3.0
P_FA = 1e-3
N_TIMED = 1_000  # epochs of each peer timing run (per-epoch loops: the rate is linear)
FAULT_SAT = SATS.index("G10")  # the satellite faulted in bench_fde's scenario


# --- small helpers --------------------------------------------------------------------

def peer_version(dist: str) -> str | None:
    """Installed version of distribution ``dist``, None if it is not installed."""
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return None


def machine() -> str:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    n_aff = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else "?"
    return (f"machine: {cpu}; {os.cpu_count()} cores ({n_aff} usable); "
            f"Python {platform.python_version()}, numpy {np.__version__}")


def rate(k: int, n: int) -> str:
    """``k/n [lo, hi]`` with the exact 95 % interval (the counts stay visible)."""
    if n == 0:
        return "0/0"
    ci = stats.binomtest(k, n).proportion_ci(0.95)
    return f"{k}/{n} [{ci.low:.4f}, {ci.high:.4f}]"


def timed_picks(n_epochs: int) -> np.ndarray:
    return np.linspace(0, n_epochs - 1, N_TIMED).round().astype(int)


def decisions(alarm, excluded, faulted_half: bool, fault_sat: int) -> dict:
    """Counts of one run: alarms, and on the faulted half detections and exclusions."""
    t = len(alarm)
    sl = slice(t // 2, t) if faulted_half else slice(0, t)
    a, x = alarm[sl], excluded[sl]
    return {"n": len(a), "alarm": int(a.sum()), "excl_right": int(x[:, fault_sat].sum()),
            "excl_wrong": int((x.any(axis=1) & ~x[:, fault_sat]).sum())}


def print_decisions(label: str, d_free: dict, d_fault: dict) -> None:
    print(f"   {label:<34} false alarms {rate(d_free['alarm'], d_free['n']):<28}"
          f"faulted: detected {rate(d_fault['alarm'], d_fault['n']):<28}"
          f"excluded the faulty one {d_fault['excl_right']}/{d_fault['n']}, "
          f"another {d_fault['excl_wrong']}")


def agreement(label: str, ours_alarm, ours_excl, theirs_alarm, theirs_excl) -> None:
    n = len(ours_alarm)
    same_a = int((ours_alarm == theirs_alarm).sum())
    same_x = int((ours_excl == theirs_excl).all(axis=1).sum())
    print(f"   {label:<34} same alarm {same_a}/{n}, same excluded set {same_x}/{n}")


class Table:
    """The one result table: library, method, epochs/s, our ratio, what was compared."""

    def __init__(self):
        self.rows = []

    def add(self, lib, method, eps, ratio, what):
        self.rows.append((lib, method, eps, ratio, what))

    def print(self):
        x = lambda v: f"{v:,.0f}x" if v >= 100 else f"{v:.1f}x"  # noqa: E731
        print(f"\n{'library':<35}{'method':<40}{'epochs/s free | faulted':>25}"
              f"{'our ratio free | faulted':>26}  what was compared")
        for lib, method, eps, ratio, what in self.rows:
            e = ("" if eps is None else f"{eps[0]:>11,.0f} | {eps[1]:>9,.0f}")
            r = ("" if ratio is None else f"{x(ratio[0]):>12} | {x(ratio[1]):>9}")
            print(f"{lib:<35}{method:<40}{e:>25}{r:>26}  {what}")


# --- ours -----------------------------------------------------------------------------

def ours_rate(sv, pr, sys_idx, repeats: int) -> float:
    fn = partial(raimcore.fde, sv, pr, SIGMA_M, sys_idx=sys_idx, p_fa=P_FA,
                 max_exclusions=1)
    return len(pr) / interleaved({"ours": fn}, repeats)["ours"]


# --- gnss_lib_py ----------------------------------------------------------------------

def single_clock_inputs(n_epochs: int):
    """The scenario of bench_fde (fault-free, half faulted) with the BDS-GPS clock offset
    removed, so that one receiver clock fits (gnss_lib_py estimates one)."""
    free = scenario_arrays(n_epochs, False)
    sys_idx = free[3]
    clk = raimcore.fde(free[0], free[1], free[2], sys_idx=sys_idx).clock_m
    isb_m = float(np.median(clk[:, 1] - clk[:, 0]))  # a constant in the simulation
    out = {}
    for faulted, (sv, pr, _, _) in ((False, free), (True, scenario_arrays(n_epochs, True))):
        out[faulted] = (sv, pr - np.where(sys_idx == 1, isb_m, 0.0))
    return out, sys_idx, isb_m


def to_navdata(sv, pr, sys_idx, epochs, *, transmit_frame_b_m=None):
    """A gnss_lib_py NavData of ``epochs``; with ``transmit_frame_b_m`` (T,) the satellite
    positions are rotated back to the transmit-time frame by the angle gnss_lib_py's
    ``wls`` applies (``OMEGA_E_DOT (corr_pr - b) / C``), so that its rotation restores
    ours."""
    from gnss_lib_py import NavData
    from gnss_lib_py.utils import constants as consts

    sv, pr = sv[epochs], pr[epochs]
    if transmit_frame_b_m is not None:
        th = consts.OMEGA_E_DOT * (pr - transmit_frame_b_m[epochs][:, None]) / consts.C
        c, s = np.cos(th), np.sin(th)
        x, y = sv[..., 0], sv[..., 1]
        # inverse of gnss_lib_py wls: x' = c x + s y, y' = -s x + c y
        sv = np.stack([c * x - s * y, s * x + c * y, sv[..., 2]], axis=-1)
    t, n = pr.shape
    nd = NavData()
    nd["gps_millis"] = np.repeat(1.3e12 + 100.0 * np.asarray(epochs, dtype=float), n)
    nd["x_sv_m"] = sv[..., 0].ravel()
    nd["y_sv_m"] = sv[..., 1].ravel()
    nd["z_sv_m"] = sv[..., 2].ravel()
    nd["b_sv_m"] = np.zeros(t * n)
    nd["corr_pr_m"] = pr.ravel()
    nd["gnss_id"] = np.tile(np.where(sys_idx == 0, "gps", "beidou"), t)
    nd["sv_id"] = np.tile([int(s[1:]) for s in SATS], t)
    return nd


def section_gnss_lib_py(table: Table, n_epochs: int, repeats: int) -> None:
    ver = peer_version("gnss-lib-py")
    if ver is None:
        print("gnss_lib_py: not installed: pip install gnss-lib-py")
        table.add("gnss_lib_py", "(not installed: pip install gnss-lib-py)", None, None,
                  "not measured")
        return
    try:
        from gnss_lib_py.algorithms.fde import (
            _edm_detection_statistic,
            _edm_from_satellites_ranges,
            solve_fde,
        )
        from gnss_lib_py.algorithms.snapshot import solve_wls
    except ImportError as exc:  # installed but broken: say so, measure the rest
        print(f"gnss_lib_py {ver}: installed but not importable ({exc}): not measured")
        return

    inputs, sys_idx, isb_m = single_clock_inputs(n_epochs)
    one = np.zeros_like(sys_idx)
    n_sats = len(sys_idx)
    thr_m2 = SIGMA_M**2 * stats.chi2.isf(P_FA, n_sats - 4)
    print(f"gnss_lib_py {ver}: BDS-GPS clock offset removed ({isb_m:,.2f} m); residual "
          f"FDE threshold {thr_m2:.1f} m^2 = (3 m)^2 chi2.isf({P_FA:g}, {n_sats - 4})")
    picks = timed_picks(n_epochs)
    allp = np.arange(n_epochs)
    res = {}
    for faulted, (sv, pr) in inputs.items():
        ours = raimcore.fde(sv, pr, SIGMA_M, sys_idx=one, p_fa=P_FA, max_exclusions=1)
        b_m = solve_wls(to_navdata(sv, pr, sys_idx, allp), sv_rx_time=True)["b_rx_wls_m"]
        if not np.isfinite(b_m).all():  # a failed WLS must not pass silently
            raise RuntimeError("gnss_lib_py solve_wls failed on some epochs")
        wls_pos = solve_wls(to_navdata(sv, pr, sys_idx, picks), sv_rx_time=True)
        d_pos = np.nanmax(np.abs(wls_pos[["x_rx_wls_m", "y_rx_wls_m", "z_rx_wls_m"]].T
                                 - ours.pos_before_ecef_m[picks]))
        nd_wls = to_navdata(sv, pr, sys_idx, picks)
        nd_t = to_navdata(sv, pr, sys_idx, picks, transmit_frame_b_m=b_m)
        # EDM squares the ranges: it needs them without the receiver clock (its WLS's).
        ranges_m = pr - b_m[:, None]
        nd_e = to_navdata(sv, ranges_m, sys_idx, picks)
        if not faulted:  # the threshold that gives p_fa on this fault-free run
            edm_stat = np.array([_edm_detection_statistic(_edm_from_satellites_ranges(
                sv[t].T, ranges_m[t]))[0][0] for t in allp])
            edm_thr = float(np.quantile(edm_stat, 1.0 - P_FA))
        fns = {"wls": partial(solve_wls, nd_wls, sv_rx_time=True),
               "residual": partial(solve_fde, nd_t, method="residual", threshold=thr_m2,
                                   max_faults=1),
               "edm": partial(solve_fde, nd_e, method="edm", max_faults=1),
               "edm_cal": partial(solve_fde, nd_e, method="edm", max_faults=1,
                                  threshold=edm_thr)}
        t = interleaved(fns, repeats)
        eps = {k: N_TIMED / v for k, v in t.items()}
        eps["ours"] = ours_rate(sv, pr, one, repeats)
        # Decisions on every epoch, once (these runs are not timed).
        nd_all = to_navdata(sv, pr, sys_idx, allp, transmit_frame_b_m=b_m)
        nd_all_e = to_navdata(sv, ranges_m, sys_idx, allp)
        flags = {}
        for key, nd, method, thr in (("residual", nd_all, "residual", thr_m2),
                                     ("edm", nd_all_e, "edm", None),
                                     ("edm_cal", nd_all_e, "edm", edm_thr)):
            out = solve_fde(nd, method=method, max_faults=1, threshold=thr)
            flags[key] = np.asarray(out[f"fault_{method}"]).reshape(n_epochs, n_sats) == 1
        res[faulted] = {"eps": eps, "ours": ours, "flags": flags, "d_pos": d_pos}
    ff, hf = res[False], res[True]
    pair = lambda k: (ff["eps"][k], hf["eps"][k])  # noqa: E731
    ratio = lambda k: (ff["eps"]["ours"] / ff["eps"][k],  # noqa: E731
                       hf["eps"]["ours"] / hf["eps"][k])
    lib = f"gnss_lib_py {ver}"
    table.add("raimcore", "fde parity, 1 clock (ISB removed)", pair("ours"), None,
              "the input gnss_lib_py gets (rows below: ours / theirs)")
    table.add(lib, "solve_wls (sv_rx_time=True)", pair("wls"), ratio("wls"),
              "its WLS alone vs our whole FDE; positions agree to "
              f"{max(ff['d_pos'], hf['d_pos']):.1e} m")
    table.add(lib, "solve_fde residual, chi2 thr, 1 fault", pair("residual"),
              ratio("residual"), "same threshold and max exclusions (decisions below)")
    table.add(lib, "solve_fde edm, default thr 0.6, 1 fault", pair("edm"), ratio("edm"),
              "its default threshold (decisions below)")
    table.add(lib, f"solve_fde edm, thr {edm_thr:.4f}, 1 fault", pair("edm_cal"),
              ratio("edm_cal"), f"threshold = {1 - P_FA:g} quantile of its statistic, "
              "fault-free run")

    print(f"\n   decisions on all {n_epochs:,} epochs (faulted: the second half, 60 m on "
          f"G10; intervals exact 95 %)")
    runs = {"raimcore fde parity (1 clock)": lambda r: (r["ours"].alarm, r["ours"].excluded)}
    for key, label in (("residual", "residual"), ("edm", "edm thr 0.6"),
                       ("edm_cal", f"edm thr {edm_thr:.4f}")):
        runs[f"gnss_lib_py {label}"] = (
            lambda r, k=key: (r["flags"][k].any(axis=1), r["flags"][k]))
    for label, get in runs.items():
        print_decisions(label, decisions(*get(ff), False, FAULT_SAT),
                        decisions(*get(hf), True, FAULT_SAT))
    oa = np.concatenate([ff["ours"].alarm, hf["ours"].alarm])
    ox = np.concatenate([ff["ours"].excluded, hf["ours"].excluded])
    for key in ("residual", "edm_cal"):
        tx = np.concatenate([ff["flags"][key], hf["flags"][key]])
        agreement(f"ours vs {key} (both runs)", oa, ox, tx.any(axis=1), tx)
    # Why its isolation differs: fde.py _residual_exclude builds its geometry matrix from
    # the lines of sight normalised per axis (norm over axis=0), without a clock column.
    # The same normalised-residual statistic with unit lines of sight and a clock column:
    sv, pr = inputs[True]
    hit = named = 0
    half = n_epochs // 2
    alarmed = half + np.flatnonzero(hf["flags"]["residual"][half:].any(axis=1))
    for t in alarmed:
        d = hf["ours"].pos_before_ecef_m[t] - sv[t]
        g = np.hstack([d / np.linalg.norm(d, axis=1, keepdims=True), np.ones((n_sats, 1))])
        s_mat = np.eye(n_sats) - g @ np.linalg.solve(g.T @ g, g.T)
        r = pr[t] - np.linalg.norm(d, axis=1) - hf["ours"].clock_m[t, 0]
        hit += int(np.argmax((s_mat @ r) ** 2 / np.diag(s_mat)) == FAULT_SAT)
        named += int(hf["flags"]["residual"][t, FAULT_SAT])
    print(f"   gnss_lib_py residual isolation names G10 at {named}/{len(alarmed)} alarmed "
          f"epochs; its statistic with unit lines of sight and a clock column (instead of "
          f"fde.py _residual_exclude's per-axis normalisation, no clock) would: "
          f"{hit}/{len(alarmed)}")


# --- RTKLIB through pyrtklib ----------------------------------------------------------

_MU_GPS = 3.9860050e14  # RTKLIB 2.4.3 ephemeris.c MU_GPS (IS-GPS-200)
_A_M = 26_560e3  # semi-major axis of the synthetic orbits (GPS nominal, IS-GPS-200)


class RtklibSynthetic:
    """10 GPS satellites on circular broadcast orbits over one receiver; pseudoranges as
    RTKLIB's ``pntpos`` models them (transmit-time position, ``geodist`` Sagnac term)."""

    def __init__(self, p, rng: np.random.Generator, n_sats: int = 10):
        self.p, self.n = p, n_sats
        self.week, self.tow0 = 2300, 108_000.0
        self.t0 = p.gpst2time(self.week, self.tow0)
        llh = p.Arr1Ddouble(3)
        llh[0], llh[1], llh[2] = np.deg2rad(29.9), np.deg2rad(114.4), 100.0
        self.llh, self.h_m = (llh[0], llh[1]), llh[2]
        r = p.Arr1Ddouble(3)
        p.pos2ecef(llh, r)
        self.rx = np.array([r[0], r[1], r[2]])
        self.rr = r
        up = self.rx / np.linalg.norm(self.rx)
        east = np.cross([0.0, 0.0, 1.0], up)
        east /= np.linalg.norm(east)
        north = np.cross(up, east)
        el = np.deg2rad(rng.uniform(25.0, 85.0, n_sats))
        az = rng.uniform(0.0, 2 * np.pi, n_sats)
        a_m = _A_M
        self.dts_s = rng.uniform(-2e-4, 2e-4, n_sats)  # satellite clock offsets (s)
        self.el = np.empty(n_sats)
        self.elem = []  # (i0, OMG0, M0) of each satellite
        self.ephs = p.Arr1Deph_t(n_sats)
        for k in range(n_sats):
            u = (np.cos(el[k]) * (np.sin(az[k]) * east + np.cos(az[k]) * north)
                 + np.sin(el[k]) * up)
            b = self.rx @ u
            rho = -b + np.sqrt(b * b - self.rx @ self.rx + a_m * a_m)
            ps = (self.rx + rho * u) / a_m  # unit vector of the satellite at toe
            inc = max(np.deg2rad(55.0), np.arcsin(min(1.0, abs(ps[2]))) + 0.05)
            arg_lat = np.arcsin(ps[2] / np.sin(inc))
            node = (np.arctan2(ps[1], ps[0])
                    - np.arctan2(np.sin(arg_lat) * np.cos(inc), np.cos(arg_lat)))
            e = self.ephs[k]
            e.sat = p.satno(p.SYS_GPS, k + 1)
            e.iode, e.iodc, e.sva, e.svh, e.week = 1, 1, 0, 0, self.week
            e.toe = e.toc = e.ttr = self.t0
            e.toes = self.tow0
            e.A, e.e, e.i0, e.omg = a_m, 0.0, inc, 0.0
            e.OMG0 = node + p.OMGE * self.tow0
            e.M0 = arg_lat
            e.deln = e.OMGd = e.idot = 0.0
            e.crc = e.crs = e.cuc = e.cus = e.cic = e.cis = 0.0
            # A clock offset that is not 0: RTKLIB 2.4.3 b34 satposs() writes the broadcast
            # clock variance (30 m)^2 into var[0] instead of var[i] for a satellite whose
            # clock is exactly 0, which would down-weight the first observation.
            e.f0 = self.dts_s[k]
            e.f1 = e.f2 = 0.0
            e.fit = 4.0
            e.code = 1
            self.elem.append((inc, e.OMG0, arg_lat))
            self.el[k] = el[k]
        self.nav = p.nav_t()
        self.nav.eph = self.ephs
        self.nav.n = self.nav.nmax = n_sats

    def sat_ecef(self, tk_s):
        """(T, n, 3) ECEF position at ``toe + tk_s`` (T, n): RTKLIB ``eph2pos`` for e = 0
        and no harmonic terms (checked against it in :meth:`check`)."""
        inc, om0, m0 = np.array(self.elem).T
        u = m0 + np.sqrt(_MU_GPS / _A_M**3) * tk_s
        x, y = _A_M * np.cos(u), _A_M * np.sin(u)
        om = om0 - self.p.OMGE * (tk_s + self.tow0)
        return np.stack([x * np.cos(om) - y * np.cos(inc) * np.sin(om),
                         x * np.sin(om) + y * np.cos(inc) * np.cos(om),
                         y * np.sin(inc)], axis=-1)

    def ranges(self, t_s):
        """Geometric pseudoranges at receive times ``t_s`` (T,) from toe: RTKLIB's model
        (``geodist`` with its Sagnac term) and our receive-frame satellite positions."""
        c, omge = self.p.CLIGHT, self.p.OMGE
        tau = np.full((len(t_s), self.n), 0.075)
        for _ in range(4):
            rs = self.sat_ecef(t_s[:, None] - tau)
            d = rs - self.rx
            r = (np.linalg.norm(d, axis=-1)
                 + omge * (rs[..., 0] * self.rx[1] - rs[..., 1] * self.rx[0]) / c)
            tau = r / c
        th = omge * tau  # the Earth's rotation during the flight: into the receive frame
        sv = np.stack([np.cos(th) * rs[..., 0] + np.sin(th) * rs[..., 1],
                       -np.sin(th) * rs[..., 0] + np.cos(th) * rs[..., 1], rs[..., 2]],
                      axis=-1)
        return r, sv, rs

    def atmosphere(self, t_s, rs):
        """RTKLIB's own ionosphere (Klobuchar, its default coefficients: none in the
        navigation data) and troposphere (Saastamoinen) delays (m) and the variance its
        ``pntpos`` gives each pseudorange (m^2), at the true position, per epoch and
        satellite: ``varerr + URA^2 + ERR_CBIAS^2 + vion + vtrp`` (pntpos.c rescode)."""
        p = self.p
        lat, lon = self.llh
        rot = np.array([[-np.sin(lon), np.cos(lon), 0.0],
                        [-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)],
                        [np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)]])
        los = rs - self.rx
        enu = (los / np.linalg.norm(los, axis=-1, keepdims=True)) @ rot.T
        az = np.mod(np.arctan2(enu[..., 0], enu[..., 1]), 2 * np.pi)
        el = np.arcsin(enu[..., 2])
        pos, azel = p.Arr1Ddouble(3), p.Arr1Ddouble(2)
        pos[0], pos[1], pos[2] = lat, lon, self.h_m
        out, var = p.Arr1Ddouble(1), p.Arr1Ddouble(1)
        ion, trp, v = (np.empty(el.shape) for _ in range(3))
        for j in range(el.shape[0]):
            t = p.timeadd(self.t0, float(t_s[j]))
            for k in range(self.n):
                azel[0], azel[1] = float(az[j, k]), float(el[j, k])
                p.ionocorr(t, self.nav, k + 1, pos, azel, p.IONOOPT_BRDC, out, var)
                ion[j, k], v[j, k] = out[0], var[0]
                p.tropcorr(t, self.nav, pos, azel, p.TROPOPT_SAAS, out, var)
                trp[j, k] = out[0]
                v[j, k] += var[0]
        return ion, trp, v + VAR_RTKLIB_M2, el

    def check(self) -> float:
        """Largest difference (m) of :meth:`sat_ecef` from RTKLIB ``eph2pos``."""
        p = self.p
        rs, dts, var = p.Arr1Ddouble(6), p.Arr1Ddouble(2), p.Arr1Ddouble(1)
        worst = 0.0
        for tk in (0.0, 333.3, 999.9):
            mine = self.sat_ecef(np.full(self.n, tk))
            for k in range(self.n):
                p.eph2pos(p.timeadd(self.t0, tk), self.ephs[k], rs, dts, var)
                worst = max(worst, float(np.max(np.abs(mine[k] - [rs[0], rs[1], rs[2]]))))
        return worst

    def obs_epochs(self, pr_m):
        """One ``Arr1Dobsd_t`` per epoch (built before timing)."""
        p = self.p
        out = []
        for j, row in enumerate(pr_m):
            t = p.timeadd(self.t0, 0.1 * j)
            obs = p.Arr1Dobsd_t(self.n)
            for k in range(self.n):
                o = obs[k]
                o.time, o.sat, o.rcv = t, self.ephs[k].sat, 1
                o.P[0] = float(row[k])
                o.code[0] = p.CODE_L1C
            out.append(obs)
        return out


# RTKLIB's pseudorange variance without its atmosphere terms (pntpos.c rescode):
# varerr = err0^2 err1^2 (err2 = 0 here: no elevation term) + URA^2 (index 0: 2.4 m,
# ephemeris.c ura_value) + ERR_CBIAS^2 (0.3 m); err1 is chosen to make it (3 m)^2.
VAR_RTKLIB_M2 = SIGMA_M**2


def rtklib_options(p):
    opt = p.prcopt_default  # RTKLIB's defaults: single mode, elmin 15 deg, Klobuchar +
    opt.ionoopt = p.IONOOPT_BRDC  # Saastamoinen (stated here, not left to defaults)
    opt.tropopt = p.TROPOPT_SAAS
    opt.err[1] = np.sqrt(VAR_RTKLIB_M2 - 2.4**2 - 0.3**2) / opt.err[0]
    opt.err[2] = 0.0
    opt.posopt[4] = 1  # RAIM FDE
    return opt


def section_rtklib(table: Table, n_epochs: int, repeats: int) -> None:
    ver = peer_version("pyrtklib")
    if ver is None:
        print("\nRTKLIB: not installed: pip install pyrtklib")
        table.add("RTKLIB (pyrtklib)", "(not installed: pip install pyrtklib)", None, None,
                  "not measured")
        return
    try:
        import pyrtklib as p
    except ImportError as exc:
        print(f"\nRTKLIB: pyrtklib {ver} installed but not importable ({exc}): not measured")
        return

    rng = np.random.default_rng(2026)
    syn = RtklibSynthetic(p, rng)
    err_eph = syn.check()
    if err_eph > 1e-3:
        raise RuntimeError(f"synthetic orbits differ from RTKLIB eph2pos by {err_eph} m")
    t_s = 0.1 * np.arange(n_epochs)
    geo_m, sv, rs = syn.ranges(t_s)
    d_frame = np.max(np.abs(np.linalg.norm(sv - syn.rx, axis=-1) - geo_m))
    ion_m, trp_m, var_m2, el = syn.atmosphere(t_s, rs)
    sigma_m = np.sqrt(var_m2)  # the sigma RTKLIB assumes; the noise has it, ours gets it
    noise = rng.normal(0.0, 1.0, geo_m.shape) * sigma_m
    fault = np.zeros_like(geo_m)
    fault[n_epochs // 2:, 4] = 60.0
    opt = rtklib_options(p)
    n = syn.n
    sol, azel = p.sol_t(), p.Arr1Ddouble(2 * n)
    ssat, msg = p.Arr1Dssat_t(p.MAXSAT), p.Arr1Dchar(256)
    sats = [syn.ephs[k].sat - 1 for k in range(n)]
    picks = timed_picks(n_epochs)
    empty = p.Arr1Dobsd_t(1)

    def run_rtklib(obs_list):
        for obs in obs_list:
            p.pntpos(obs.ptr, n, syn.nav, opt, sol, azel, ssat.ptr, msg)

    def decide(obs_list):
        """Alarm: RTKLIB excluded a satellite, or found no valid solution (its chi-square
        or GDOP test failed and RAIM could not repair it)."""
        excl = np.zeros((len(obs_list), n), dtype=bool)
        ok = np.zeros(len(obs_list), dtype=bool)
        pos = np.full((len(obs_list), 3), np.nan)
        used = np.zeros(len(obs_list), dtype=int)
        for j, obs in enumerate(obs_list):
            ok[j] = p.pntpos(obs.ptr, n, syn.nav, opt, sol, azel, ssat.ptr, msg) == 1
            vs = np.array([ssat[s].vs for s in sats], dtype=bool)
            excl[j] = ok[j] & ~vs
            used[j] = vs.sum()
            if ok[j]:
                pos[j] = [sol.rr[0], sol.rr[1], sol.rr[2]]
        return excl.any(axis=1) | ~ok, excl, ok, pos, used

    rs_a, dts_a = p.Arr1Ddouble(6 * n), p.Arr1Ddouble(2 * n)
    var_a, svh_a = p.Arr1Ddouble(n), p.Arr1Dint(n)

    def run_satposs(obs_list, times):
        for obs, t in zip(obs_list, times, strict=True):
            p.satposs(t, obs.ptr, n, syn.nav, p.EPHOPT_BRDC, rs_a, dts_a, var_a, svh_a)

    def overhead():
        for _ in range(N_TIMED):
            p.pntpos(empty.ptr, 0, syn.nav, opt, sol, azel, ssat.ptr, msg)

    res = {}
    for faulted in (False, True):
        clk_m = p.CLIGHT * syn.dts_s  # satellite clocks (RTKLIB: P - (r - c dts + I + T))
        pr = geo_m - clk_m + ion_m + trp_m + noise + (fault if faulted else 0.0)
        pr_corr = pr + clk_m - ion_m - trp_m  # ours: corrected pseudoranges, same models
        obs = syn.obs_epochs(pr)
        ours = raimcore.fde(sv, pr_corr, sigma_m, p_fa=P_FA, max_exclusions=1)
        sub = [obs[j] for j in picks]
        times = [p.timeadd(syn.t0, 0.1 * float(j)) for j in picks]
        t = interleaved({"rtk": partial(run_rtklib, sub), "call": overhead,
                         "satposs": partial(run_satposs, sub, times)}, repeats)
        alarm, excl, ok, pos, used = decide(obs)
        both = ok & (ours.excluded == excl).all(axis=1)
        fn = partial(raimcore.fde, sv, pr_corr, sigma_m, p_fa=P_FA, max_exclusions=1)
        res[faulted] = {"rtk": N_TIMED / t["rtk"], "call_us": t["call"] / N_TIMED * 1e6,
                        "satposs_us": t["satposs"] / N_TIMED * 1e6,
                        "ours": n_epochs / interleaved({"o": fn}, repeats)["o"],
                        "o": ours, "alarm": alarm, "excl": excl, "n_fail": int((~ok).sum()),
                        "d_pos": np.nanmax(np.abs(pos[both] - ours.pos_ecef_m[both])),
                        "used_min": int(used[ok & ~excl.any(axis=1)].min())}
    # RTKLIB's position covariance against ours at the first epoch (stochastic model).
    obs0 = syn.obs_epochs((geo_m - p.CLIGHT * syn.dts_s + ion_m + trp_m + noise)[:1])[0]
    p.pntpos(obs0.ptr, n, syn.nav, opt, p.sol_t(), azel, ssat.ptr, msg)
    sol0 = p.sol_t()
    p.pntpos(obs0.ptr, n, syn.nav, opt, sol0, azel, ssat.ptr, msg)
    u = sv[0] - syn.rx
    h = np.hstack([-u / np.linalg.norm(u, axis=-1, keepdims=True), np.ones((n, 1))])
    q_ours = np.linalg.inv(h.T @ (h / var_m2[0][:, None]))[:3, :3]
    var_ratio = np.array([sol0.qr[0], sol0.qr[1], sol0.qr[2]]) / np.diag(q_ours)

    ff, hf = res[False], res[True]
    lib = f"RTKLIB {p.VER_RTKLIB} {p.PATCH_LEVEL} (pyrtklib {ver})"
    table.add("raimcore", "fde parity on RTKLIB's synthetic data", (ff["ours"], hf["ours"]),
              None, "10 GPS satellites, 1 clock (row below: ours / theirs)")
    table.add(lib, "pntpos, posopt[4]=1 (raim_fde)", (ff["rtk"], hf["rtk"]),
              (ff["ours"] / ff["rtk"], hf["ours"] / hf["rtk"]),
              f"a pntpos call per epoch via the binding (call {ff['call_us']:.1f} us; "
              f"its satposs, ephemerides to positions, {ff['satposs_us']:.0f} us)")

    print(f"\nRTKLIB {p.VER_RTKLIB} {p.PATCH_LEVEL} via pyrtklib {ver}: synthetic GPS "
          f"orbits match eph2pos to {err_eph:.1e} m; receive-frame ranges vs geodist "
          f"{d_frame:.1e} m; "
          f"elevations {np.rad2deg(el.min()):.0f}-{np.rad2deg(el.max()):.0f} deg; "
          f"sigma {sigma_m.min():.2f}-{sigma_m.max():.2f} m (RTKLIB's model, Klobuchar "
          f"{ion_m.min():.1f}-{ion_m.max():.1f} m, Saastamoinen {trp_m.min():.1f}-"
          f"{trp_m.max():.1f} m)")
    print(f"   RTKLIB/our position variance (x, y, z) at epoch 0: "
          f"{', '.join(f'{v:.4f}' for v in var_ratio)}; both test the weighted residual "
          f"sum against chi2 0.999 at dof {n - 4} (RTKLIB's table: 22.5; ours "
          f"{stats.chi2.isf(P_FA, n - 4):.2f})")
    print(f"   decisions on all {n_epochs:,} epochs (faulted: second half, 60 m on "
          f"satellite 5)")
    print_decisions("raimcore fde parity", decisions(ff["o"].alarm, ff["o"].excluded,
                                                     False, 4),
                    decisions(hf["o"].alarm, hf["o"].excluded, True, 4))
    print_decisions("RTKLIB pntpos raim_fde", decisions(ff["alarm"], ff["excl"], False, 4),
                    decisions(hf["alarm"], hf["excl"], True, 4))
    oa = np.concatenate([ff["o"].alarm, hf["o"].alarm])
    ox = np.concatenate([ff["o"].excluded, hf["o"].excluded])
    agreement("ours vs RTKLIB (both runs)", oa, ox,
              np.concatenate([ff["alarm"], hf["alarm"]]),
              np.concatenate([ff["excl"], hf["excl"]]))
    print(f"   RTKLIB: no solution at {ff['n_fail']} fault-free and {hf['n_fail']} faulted "
          f"epochs; satellites used without exclusion >= "
          f"{min(ff['used_min'], hf['used_min'])}; positions where the exclusions agree "
          f"differ by <= {max(ff['d_pos'], hf['d_pos']):.1e} m")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--epochs", type=int, default=10_000)
    a = ap.parse_args(argv)
    print(machine())
    print(f"scenario: {len(SATS)} satellites, {a.epochs:,} epochs, sigma {SIGMA_M:g} m, "
          f"p_fa {P_FA:g}, 1 exclusion at most; peers timed on {N_TIMED:,} epochs, best "
          f"of {a.repeats}; ours on all epochs, best of {a.repeats}")
    table = Table()
    sv, pr, _, sys_idx = scenario_arrays(a.epochs, False)
    sv2, pr2, _, _ = scenario_arrays(a.epochs, True)
    table.add("raimcore", "fde parity, 2 clocks (bench_fde input)",
              (ours_rate(sv, pr, sys_idx, a.repeats), ours_rate(sv2, pr2, sys_idx, a.repeats)),
              None, "7 GPS + 3 BDS, as in bench_fde.py")
    section_gnss_lib_py(table, a.epochs, a.repeats)
    section_rtklib(table, a.epochs, a.repeats)
    table.print()


if __name__ == "__main__":
    main()
