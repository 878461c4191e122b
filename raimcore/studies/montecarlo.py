"""Monte Carlo studies of fault isolation: a grid of cells x runs, reproducible anywhere.

A study is a grid of *settings* (visible satellites N, number of faulty satellites, fault
bias in units of P_bias) times a list of *algorithms*; a cell is one setting and one
algorithm. Each run draws a random geometry of the study's systems (default GPS + BeiDou,
as seed 004; any of GPS, BDS, GAL, GLO, nominal constellations, one receiver clock each:
random time and user location with exactly N satellites tracked above the mask), random
faulty satellites and Gaussian noise on the linearised model ``y = H x + b + e``; every
algorithm of a setting sees the same runs (common random numbers), so their differences
are not sampling noise between algorithms.

Reproducibility: runs are cut into fixed chunks of :data:`CHUNK_RUNS`; setting ``s`` gets
``SeedSequence(seed, spawn_key=key(s))`` and chunk ``c`` its ``spawn``-ed child ``c``. The
results (integer counts summed per cell) are therefore identical in-process, on a process
pool with any number of workers, or on a Dask cluster, and whatever the order chunks finish.

Scoring (seed 004 section 3): a run is a correct isolation when the isolated set equals the
faulty set exactly. Every run is scored (each has a fault), without a detection gate, as
the paper's rate "correct isolations / isolations" suggests; with ``gate=True`` a run
counts only if the full-set chi-square test (all N satellites, dof N - 5) also alarms at
``p_fa``, as a receiver would isolate only after a detection. Every cell also reports how
often that test alarms (``detected_rate``, shared by the algorithms of a setting).

Algorithms are named kernels (:data:`KERNELS`): ``"gf"``, ``"rs"``, ``"qv"``, ``"parity"``,
with options after a colon, e.g. ``"gf:groups=100,weights=uniform"``. The options are those
the registered algorithm of the same name declares (:mod:`raimcore.algorithms`: type,
range, default), so a study and a scenario mean the same by ``gf_groups``. Another
algorithm joins every study by adding one function to ``KERNELS`` (see
:func:`register_kernel`).
"""

from __future__ import annotations

import csv
import functools
import json
import math
import os
import sys
import time
import zlib
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy import optimize, stats

from .._validate import check_choice, check_int, check_positive, check_probability, check_range
from ..algorithms import groupfusion as gfm
from ..algorithms._groupfusion_common import as_groups
from ..geometry import ecef_to_geodetic, enu_rotation, geodetic_to_ecef, los_enu
from ..sky.constellations import SYSTEM_PREFIX, builtin

__all__ = ["Study", "StudyResult", "run_study", "p_bias_m", "p_bias_group_m", "random_geometry",
           "simulate_runs", "KERNELS", "register_kernel", "parse_algorithm", "CHUNK_RUNS",
           "markdown_table", "write_csv", "run_chunk", "BIAS_UNITS", "full_set_alarm",
           "DEFAULT_SYSTEMS", "check_systems"]

#: Fault units: the spec's full-set P_bias, or the group-level hypothesis.
BIAS_UNITS = ("full", "group")

#: Runs per work unit. Fixed (not derived from the number of workers) so that the seeds of
#: every run, and hence the results, do not depend on how the work is spread.
CHUNK_RUNS = 250

#: Key of the full-set detection count in a chunk's counts (not an algorithm name).
DETECTED = "_detected"

#: Seconds in one sidereal-ish day used to draw random times (GPS repeats daily).
_DAY_S = 86_400.0
#: The systems of seed 004's geometries (the default of every study).
DEFAULT_SYSTEMS = ("GPS", "BDS")


@functools.lru_cache(maxsize=64)
def p_bias_group_m(sigma_m: float, p_fa: float, p_md: float, r: int = 6, n_states: int = 5):
    """An alternative fault unit: the P_bias of one group rather than of the full set.

    ``sigma0 sqrt(lambda_g r / dof_g)`` with ``lambda_g`` from ``ncx2(dof_g = r -
    n_states)`` at ``p_md`` and ``r / dof_g`` the inverse of a member's mean redundancy
    (trace of the group's residual projector / r). 658 m for the paper's setting, 2.0-2.1x
    :func:`p_bias_m` for N = 14 .. 22: our hypothesis for the paper's fault size (see the
    README). Not the spec's definition; offered as ``Study(bias_unit="group")``.
    """
    dof = r - n_states
    t = stats.chi2.isf(p_fa, dof)
    lam = optimize.brentq(lambda x: stats.ncx2.cdf(t, dof, x) - p_md, 1e-6, 1e5, xtol=1e-10)
    return math.sqrt(lam * r / dof) * sigma_m


@functools.lru_cache(maxsize=256)
def p_bias_m(n_visible: int, sigma_m: float, p_fa: float, p_md: float, n_states: int = 5):
    """Critical bias P_bias = sqrt(lambda) sigma0 (seed 004 eq. 13).

    lambda solves ``ncx2.cdf(T, dof, lambda) = p_md`` with ``dof = N - n_states`` and
    ``T = chi2.isf(p_fa, dof)`` (the full-set test). About 309 m for N = 14 and 330 m for
    N = 22 with the paper's sigma0 = 33 m, P_FA = 1e-5/3600, P_MD = 0.014.
    """
    dof = int(n_visible) - n_states
    if dof < 1:
        raise ValueError(f"n_visible must exceed {n_states} states, got {n_visible}")
    t = stats.chi2.isf(p_fa, dof)
    lam = optimize.brentq(lambda x: stats.ncx2.cdf(t, dof, x) - p_md, 1e-6, 1e5, xtol=1e-10)
    return math.sqrt(lam) * sigma_m


# --------------------------------------------------------------------------------------
# Random geometry and runs


def check_systems(systems) -> tuple[str, ...]:
    """``systems`` as a tuple of distinct names of GPS, BDS, GAL, GLO, or a ValueError."""
    if isinstance(systems, str) or not isinstance(systems, Sequence) or not systems \
            or len(set(systems)) != len(systems) \
            or any(x not in SYSTEM_PREFIX for x in systems):
        raise ValueError(f"systems must be a non-empty list of distinct names of "
                         f"{', '.join(SYSTEM_PREFIX)}, got {systems!r}")
    return tuple(systems)


@functools.lru_cache(maxsize=8)
def _constellation(systems: tuple[str, ...]):
    return builtin(systems)


@functools.lru_cache(maxsize=8)
def _circular_terms(systems: tuple[str, ...]):
    """Time-independent terms of :meth:`Constellation.positions_ecef_m` for ``systems``,
    or None when an orbit is not circular (then the general propagation is used)."""
    c = _constellation(systems)
    if np.any(c.ecc != 0.0):
        return None
    a = c.sqrt_a**2
    return {"r": a, "n0": np.sqrt(c.gm_m3ps2 / a**3), "toa": c.toa_s, "m0": c.m0_rad,
            "argp": c.argp_rad, "om0": c.omega0_rad, "om_rate": c.omega_dot_radps
            - c.omega_e_radps, "om_toa": c.omega_e_radps * c.toa_s,
            "ci": np.cos(c.inc_rad), "si": np.sin(c.inc_rad)}


def _positions_ecef_m(systems: tuple[str, ...], t_s) -> np.ndarray:
    """ECEF positions ``(E, S, 3)`` of the nominal ``systems`` at times ``t_s`` ``(E,)``.

    Bit for bit :meth:`Constellation.positions_ecef_m` (IS-GPS-200 table 20-IV): for the
    circular orbits of the nominal constellations (e = 0) its Newton iterations on Kepler's
    equation return ``E = M`` exactly, ``sqrt(1 - e^2) sin E = sin E``, ``cos E - e = cos E``
    and ``r = a``, so those 20 sines and cosines per satellite and epoch are skipped and the
    time-independent terms computed once.
    """
    k = _circular_terms(systems)
    if k is None:
        return _constellation(systems).positions_ecef_m(t_s)
    tk = np.asarray(t_s, dtype=float)[..., None] - k["toa"]
    mk = k["m0"] + k["n0"] * tk
    u = np.arctan2(np.sin(mk), np.cos(mk)) + k["argp"]
    om = k["om0"] + k["om_rate"] * tk - k["om_toa"]
    xp, yp = k["r"] * np.cos(u), k["r"] * np.sin(u)
    co, so = np.cos(om), np.sin(om)
    return np.stack([xp * co - yp * k["ci"] * so, xp * so + yp * k["ci"] * co, yp * k["si"]],
                    axis=-1)


def random_geometry(rng: np.random.Generator, n_runs: int, n_visible: int,
                    mask_deg: float = 5.0, min_per_system: int = 2,
                    systems: Sequence[str] = DEFAULT_SYSTEMS):
    """Random geometries of the nominal ``systems`` with exactly ``n_visible`` satellites
    tracked.

    Times are uniform over a day, user locations uniform on the sphere (height 0). Where
    more than ``n_visible`` satellites are above the mask, a random ``n_visible`` of them
    are tracked; draws with fewer, or with fewer than ``min_per_system`` of a system
    among the tracked ones, are rejected and redrawn (so every run has every clock).
    Satellites are propagated by :func:`_positions_ecef_m` (bit for bit the constellation's
    own propagation, without its Kepler iterations on these circular orbits).

    Speed, with the same random numbers drawn in the same order and the same geometries
    returned, bit for bit:

    * Screening: on circular orbits, a rough propagation (angles and their sines and
      cosines in single precision) puts each line of sight's up component within about
      1e-5 of the exact one; a draw with fewer than ``n_visible`` satellites above the
      mask lowered by 1e-3 cannot be accepted and is rejected without the exact
      propagation (most draws for 20 or more satellites).
    * The other draws are examined in blocks, stopping once enough are accepted (with few
      satellites nearly every draw is, and the rest of a round is never propagated).
    * Visibility needs only the up component of each line of sight (the arithmetic of
      :func:`raimcore.geometry.los_enu`); the full lines of sight are formed by
      ``los_enu`` for the tracked satellites of accepted draws only.

    Returns
    -------
    h : (n_runs, n_visible, 3 + q) rows ``[-u_enu, 1_sys0, ..., 1_sys(q-1)]`` for the
        q = ``len(systems)`` systems in the order given (default GPS + BDS: 5 columns),
        satellites in constellation order (the first system's first).
    sys_idx : (n_runs, n_visible) index of each satellite's system in ``systems``.
    """
    def screen(orbit, t, lat, lon, rx):
        """(b,) bool: the draws that may have ``n_visible`` satellites above the mask.

        Single precision from the angles on. The margin, 1e-3 in the sine of the
        elevation, is 100 times the worst error: float32 angles up to 20 rad and their
        sines and cosines, about 3e-6 rad, 130 m at a GEO orbit's radius, plus float32
        positions (tens of metres), 1e-5 in the up component seen from 19,000 km or more
        (the up direction, from the drawn latitude and longitude rather than from ``rx``
        as ``los_enu`` finds it, is within 1e-9).
        """
        f32 = np.float32
        r, ci, si = (orbit[k].astype(f32) for k in ("r", "ci", "si"))
        tk = t[:, None] - orbit["toa"]
        arg = (orbit["m0"] + orbit["n0"] * tk + orbit["argp"]).astype(f32)
        om = (orbit["om0"] + orbit["om_rate"] * tk - orbit["om_toa"]).astype(f32)
        xp, yp = r * np.cos(arg), r * np.sin(arg)
        co, so = np.cos(om), np.sin(om)
        rx = rx.astype(f32)
        dx = xp * co - yp * ci * so - rx[:, :1]
        dy = xp * so + yp * ci * co - rx[:, 1:2]
        dz = yp * si - rx[:, 2:]
        cos_lat = np.cos(lat)
        up = [(v[:, None]).astype(f32) for v in (cos_lat * np.cos(lon), cos_lat * np.sin(lon),
                                                 np.sin(lat))]
        rise = dx * up[0] + dy * up[1] + dz * up[2]
        above = rise >= (sin_mask - 1e-3) * np.sqrt(dx * dx + dy * dy + dz * dz)
        return above.sum(axis=-1) >= n_visible

    systems = check_systems(systems)
    const = _constellation(systems)
    sys_of = np.array([systems.index(s) for s in const.systems], dtype=int)
    q = len(systems)
    sin_mask = math.sin(math.radians(mask_deg))
    orbit = _circular_terms(systems)
    out_h, out_sys, have = [], [], 0
    seen = accepted = 0  # draws examined and accepted so far
    for _ in range(200):
        need = n_runs - have
        if need <= 0:
            break
        m = max(64, 2 * need)
        t = rng.uniform(0.0, _DAY_S, m)
        lat = np.arcsin(rng.uniform(-1.0, 1.0, m))
        lon = rng.uniform(-np.pi, np.pi, m)
        keys = rng.random((m, len(const)))
        rx = geodetic_to_ecef(lat, lon, 0.0)
        lo, found = 0, 0
        while lo < m and found < need:
            # As many draws as the runs still needed at the acceptance seen so far (at
            # first, as many as the runs), at least 32.
            size = max(32, math.ceil(1.25 * (need - found) * seen / accepted) if accepted
                       else need - found)
            sel = np.arange(lo, min(m, lo + size))
            lo, seen = sel[-1] + 1, seen + sel.size
            if orbit is not None:  # screening (see above)
                sel = sel[screen(orbit, t[sel], lat[sel], lon[sel], rx[sel])]
            up = enu_rotation(*ecef_to_geodetic(rx[sel])[:2])[:, 2]  # as los_enu rotates
            sv = _positions_ecef_m(systems, t[sel])  # (b, S, 3)
            d = sv - rx[sel, None, :]
            vis = (np.einsum("...j,...sj->...s", up, d) / np.linalg.norm(d, axis=-1)
                   >= sin_mask)
            # Track a random n_visible of the visible ones: the smallest random keys.
            k = np.where(vis, keys[sel], np.inf)
            pick = np.sort(np.argsort(k, axis=-1)[:, :n_visible], axis=-1)  # const. order
            ok = vis.sum(axis=-1) >= n_visible
            sys_pick = sys_of[pick]
            for j in range(q):
                ok &= (sys_pick == j).sum(axis=-1) >= min_per_system
            rows = np.flatnonzero(ok)[:need - found]
            found += rows.size
            accepted += rows.size
            uu, _ = los_enu(np.take_along_axis(sv[rows], pick[rows][..., None], axis=1),
                            rx[sel[rows]])
            clocks = (sys_pick[rows][..., None] == np.arange(q)).astype(float)
            out_h.append(np.concatenate([-uu, clocks], axis=-1))
            out_sys.append(sys_pick[rows])
        have += found
    else:  # pragma: no cover - only for absurd n_visible
        raise ValueError(f"n_visible={n_visible}: too few geometries with that many "
                         f"satellites above {mask_deg} deg")
    return np.concatenate(out_h)[:n_runs], np.concatenate(out_sys)[:n_runs]


def simulate_runs(rng: np.random.Generator, n_runs: int, n_visible: int, n_faults: int,
                  bias_m: float, sigma_m: float, mask_deg: float = 5.0,
                  systems: Sequence[str] = DEFAULT_SYSTEMS):
    """Draw ``n_runs`` runs: geometry (:func:`random_geometry` of ``systems``), faulty
    satellites and noisy measurements.

    Returns ``h (R, N, 3 + q)`` (5 for GPS + BDS), ``y (R, N)`` (m, measurement minus
    truth prediction: noise + bias) and ``faulty (R, N)`` bool.
    """
    h, _ = random_geometry(rng, n_runs, n_visible, mask_deg, systems=systems)
    order = np.argsort(rng.random((n_runs, n_visible)), axis=-1)
    faulty = np.zeros((n_runs, n_visible), dtype=bool)
    faulty[np.arange(n_runs)[:, None], order[:, :n_faults]] = True
    y = sigma_m * rng.standard_normal((n_runs, n_visible)) + bias_m * faulty
    return h, y, faulty


# --------------------------------------------------------------------------------------
# Algorithm kernels: isolated set of a batch of runs on the linear model

Kernel = Callable[..., np.ndarray]
KERNELS: dict[str, Kernel] = {}


def register_kernel(name: str, fn: Kernel) -> None:
    """Make ``fn(h, y, *, sigma_m, p_fa, rng, **options) -> isolated (R, N) bool`` available
    to every study as algorithm ``name``."""
    KERNELS[name] = fn


def _r(h):
    return h.shape[-1] + 1  # r = 4 + q, q systems (seed 004: 6 for GPS + BDS)


# Each kernel takes its algorithm's options as the registered algorithm declares them
# (raimcore.algorithms: gf_groups, gf_margin, ...), validated and with their defaults.

def _gf(h, y, *, sigma_m, p_fa, rng, gf_groups, gf_margin, gf_weights):
    g = gfm.select_groups(y.shape[-1], _r(h), as_groups(gf_groups))
    return gfm.gf_isolate(h, y, g, p_fa, weights_lsq=sigma_m**-2, margin=gf_margin,
                          weights=gf_weights).isolated


def _qv(h, y, *, sigma_m, p_fa, rng, qv_groups, qv_margin, qv_norm):
    g = gfm.select_groups(y.shape[-1], _r(h), as_groups(qv_groups))
    return gfm.qv_isolate(h, y, g, p_fa, weights_lsq=sigma_m**-2, margin=qv_margin,
                          norm=qv_norm)[0]


def _rs(h, y, *, sigma_m, p_fa, rng, rs_draws):
    return gfm.rs_isolate(h, y, p_fa, rng, weights_lsq=sigma_m**-2, n_draws=rs_draws)


def _parity(h, y, *, sigma_m, p_fa, rng, max_exclusions):
    return gfm.parity_isolate(h, y, p_fa, weights_lsq=sigma_m**-2,
                              max_exclusions=max_exclusions)


register_kernel("gf", _gf)
register_kernel("rs", _rs)
register_kernel("qv", _qv)
register_kernel("parity", _parity)


def _option_name(algorithm: str, short: str, keys) -> str:
    """``groups`` of ``gf`` is the option ``gf_groups``; full names are taken as they are."""
    prefixed = f"{algorithm}_{short}"
    return prefixed if short not in keys and prefixed in keys else short


@functools.lru_cache(maxsize=256)
def _parse_cached(text: str) -> tuple[str, tuple]:
    from .. import algorithms
    from ..scenario import parse_value

    name, _, rest = text.partition(":")
    if name not in KERNELS:
        raise ValueError(f"algorithm must be one of {', '.join(KERNELS)} (with options "
                         f"after ':'), got {text!r}")
    keys = algorithms.get(name).option_keys if name in algorithms.names() else {}
    given = {}
    for item in filter(None, (x.strip() for x in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq or not key.strip():
            raise ValueError(f"algorithm option must be KEY=VALUE, got {item!r} in {text!r}")
        given[_option_name(name, key.strip(), keys)] = parse_value(val.strip())
    if name not in algorithms.names():  # a kernel registered here only: no options
        if given:
            raise ValueError(f"algorithm {name!r} takes no options here, got {text!r}")
        return name, ()
    try:
        opts = algorithms.get(name).resolve_options(given)
    except ValueError as exc:
        raise ValueError(f"algorithm {text!r}: {exc}") from None
    return name, tuple(opts.items())


def parse_algorithm(text: str) -> tuple[str, dict]:
    """``"gf:groups=100,weights=uniform"`` -> ``("gf", {"gf_groups": 100, "gf_margin": 0.1,
    "gf_weights": "uniform"})``: every option of the registered algorithm of that name,
    the given ones checked by its option keys (values are TOML literals, as with ``--set``;
    the algorithm's prefix may be left out), the others at their declared defaults.

    Raises
    ------
    ValueError
        An unknown algorithm, an option it does not take, or a value its key refuses.
    """
    if not isinstance(text, str):
        raise ValueError(f"algorithm must be a string such as \"gf:groups=100\", got "
                         f"{text!r}")
    name, opts = _parse_cached(text)
    return name, dict(opts)


# --------------------------------------------------------------------------------------
# Studies


@dataclass(frozen=True)
class Study:
    """A grid of settings x algorithms, ``runs`` Monte Carlo runs per cell.

    Attributes
    ----------
    n_visible : visible satellite counts N. n_faults : faulty satellite counts.
    bias : fault biases in units of P_bias(N) (seed 004 eq. 13).
    algorithms : kernel names with options (``"gf:groups=100"``).
    runs : runs per cell. seed : root seed.
    sigma_m, p_fa, p_md : noise 1-sigma (m) and the probabilities (paper: 33 m,
        1e-5 / 3600, 0.014). mask_deg : elevation mask (deg).
    bias_scale : extra factor on every fault (1 = as written; see the README on the
        paper's fault size, which behaves like 2x ours).
    bias_unit : ``"full"`` (spec: P_bias of the full set, eq. 13) or ``"group"``
        (:func:`p_bias_group_m`, a hypothesis for the paper's unit).
    systems : the constellations of the geometries (:func:`random_geometry`), default
        GPS + BDS as seed 004; one clock state each, so P_bias uses ``3 + q`` states.
    gate : score a run only when the full-set chi-square test also alarms (module doc).
    name : used in file names.
    """

    n_visible: tuple[int, ...] = (14, 16, 18, 20, 22)
    n_faults: tuple[int, ...] = (1, 2, 3)
    bias: tuple[float, ...] = (0.8, 1.0, 1.5, 2.0)
    algorithms: tuple[str, ...] = ("rs", "qv", "gf")
    runs: int = 5000
    seed: int = 4
    sigma_m: float = 33.0
    p_fa: float = 1e-5 / 3600
    p_md: float = 0.014
    mask_deg: float = 5.0
    bias_scale: float = 1.0
    bias_unit: str = "full"
    gate: bool = False
    name: str = "study"
    systems: tuple[str, ...] = DEFAULT_SYSTEMS

    def __post_init__(self):
        for name in ("n_visible", "n_faults", "bias", "algorithms"):
            v = getattr(self, name)
            if isinstance(v, str) or not isinstance(v, Sequence) or not v:
                raise ValueError(f"{name} must be a non-empty list, got {v!r}")
        for n in self.n_visible:
            check_int("n_visible", n, 8, 40)
        for k in self.n_faults:
            check_int("n_faults", k, 0, 6)
        for b in self.bias:
            check_positive("bias", b, allow_zero=True)
        for a in self.algorithms:
            parse_algorithm(a)
        if len(set(self.algorithms)) != len(self.algorithms):
            raise ValueError(f"algorithms lists one twice: {list(self.algorithms)}")
        check_int("runs", self.runs, 1)
        check_int("seed", self.seed, 0, 2**63 - 1)
        if not isinstance(self.name, str) or not self.name.strip():
            raise ValueError(f"name must be a non-empty string, got {self.name!r}")
        check_positive("sigma_m", self.sigma_m)
        check_probability("p_fa", self.p_fa)
        check_probability("p_md", self.p_md)
        check_range("mask_deg", self.mask_deg, 0.0, 60.0)
        check_positive("bias_scale", self.bias_scale)
        check_choice("bias_unit", self.bias_unit, BIAS_UNITS)
        if not isinstance(self.gate, bool):
            raise ValueError(f"gate must be true or false, got {self.gate!r}")
        # n_visible >= 8 exceeds the 3 + q <= 7 states of any choice of systems.
        object.__setattr__(self, "systems", check_systems(self.systems))

    @property
    def n_states(self) -> int:
        """Position and one clock per system."""
        return 3 + len(self.systems)

    def unit_m(self, n_visible: int) -> float:
        """The fault unit (m) for ``n_visible`` satellites."""
        if self.bias_unit == "group":
            return p_bias_group_m(self.sigma_m, self.p_fa, self.p_md, r=self.n_states + 1,
                                  n_states=self.n_states)
        return p_bias_m(n_visible, self.sigma_m, self.p_fa, self.p_md, self.n_states)

    def settings(self) -> list[tuple[int, int, float]]:
        """(N, faults, bias) in a fixed order: bias, faults, N (the paper's row order)."""
        return [(n, k, b) for b in self.bias for k in self.n_faults for n in self.n_visible]


def _setting_ss(seed: int, setting) -> np.random.SeedSequence:
    n, k, b = setting
    # The setting's own stream, independent of the grid it sits in (resume-safe).
    return np.random.SeedSequence(seed, spawn_key=(int(n), int(k), int(round(b * 1000))))


def _algo_ss(chunk_ss: np.random.SeedSequence, algo: str) -> np.random.SeedSequence:
    return np.random.SeedSequence(chunk_ss.entropy, spawn_key=chunk_ss.spawn_key + (
        1_000_000 + zlib.crc32(algo.encode()),))


def run_chunk(study: Study, setting, chunk: int) -> dict[str, int]:
    """Run chunk ``chunk`` of one setting for every algorithm; correct-isolation counts.

    Pure function of its arguments (a worker can run it anywhere).
    """
    n, k, b = setting
    n_total = study.runs
    lo = chunk * CHUNK_RUNS
    n_runs = min(CHUNK_RUNS, n_total - lo)
    css = _setting_ss(study.seed, setting).spawn(chunk + 1)[chunk]
    rng = np.random.default_rng(css)
    bias_m = b * study.bias_scale * study.unit_m(n)
    h, y, faulty = simulate_runs(rng, n_runs, n, k, bias_m, study.sigma_m, study.mask_deg,
                                 study.systems)
    detected = full_set_alarm(h, y, study.sigma_m, study.p_fa)
    out = {DETECTED: int(detected.sum())}
    for algo in study.algorithms:
        name, opts = parse_algorithm(algo)
        arng = np.random.default_rng(_algo_ss(css, algo))
        iso = KERNELS[name](h, y, sigma_m=study.sigma_m, p_fa=study.p_fa, rng=arng, **opts)
        right = np.all(iso == faulty, axis=-1)
        out[algo] = int(np.sum(right & detected if study.gate else right))
    return out


def full_set_alarm(h, y, sigma_m: float, p_fa: float) -> np.ndarray:
    """The full-set least-squares residual chi-square test of each run.

    ``h (R, N, n)``, ``y (R, N)``: ``SSE = ||y - H x_hat||^2 / sigma^2`` against
    ``chi2.isf(p_fa, N - n)``. Returns ``(R,)`` bool.
    """
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    x = np.linalg.solve(np.swapaxes(h, -1, -2) @ h,
                        np.einsum("rni,rn->ri", h, y)[..., None])[..., 0]
    r = y - np.einsum("rni,ri->rn", h, x)
    sse = np.einsum("rn,rn->r", r, r) / sigma_m**2
    return sse > stats.chi2.isf(p_fa, h.shape[-2] - h.shape[-1])


@dataclass(frozen=True)
class StudyResult:
    """Rows of the study: one dict per cell (see :func:`run_study`), and the wall time."""

    study: Study
    rows: list[dict] = field(default_factory=list)
    wall_s: float = 0.0

    def rate(self, n, k, b, algo) -> float:
        for r in self.rows:
            if (r["n_visible"], r["n_faults"], r["bias"], r["algorithm"]) == (n, k, b, algo):
                return r["rate"]
        raise KeyError((n, k, b, algo))


class _Progress:
    """A one-line progress bar on stderr (only when stderr is a terminal or forced)."""

    def __init__(self, total: int, enabled: bool | None = None, label: str = ""):
        self.total, self.done, self.t0, self.label = total, 0, time.perf_counter(), label
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._last = 0.0

    def step(self, n: int = 1):
        self.done += n
        now = time.perf_counter()
        if self.enabled and (now - self._last > 0.2 or self.done >= self.total):
            self._last = now
            frac = self.done / max(self.total, 1)
            el = now - self.t0
            eta = el / frac - el if frac > 0 else float("nan")
            bar = "#" * int(30 * frac)
            sys.stderr.write(f"\r{self.label} [{bar:<30}] {100 * frac:5.1f}% "
                             f"{self.done}/{self.total} chunks, {el:6.1f} s, eta {eta:6.1f} s")
            if self.done >= self.total:
                sys.stderr.write("\n")
            sys.stderr.flush()

    def close(self):
        """End a bar left unfinished (an interruption) with a newline."""
        if self.enabled and self._last and self.done < self.total:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _ledger_key(study: Study, setting) -> str:
    n, k, b = setting
    return json.dumps([n, k, b, study.runs, study.seed, study.sigma_m, study.p_fa,
                       study.p_md, study.mask_deg, study.bias_scale]
                      + ([study.bias_unit] if study.bias_unit != "full" else [])
                      + (["gate"] if study.gate else [])
                      + ([list(study.systems)] if study.systems != DEFAULT_SYSTEMS else []))


def _read_ledger(path: Path) -> dict[str, dict]:
    done = {}
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                rec = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line cut by an interruption
            done[rec["key"]] = rec["counts"]
    return done


def run_study(study: Study, *, workers: int = 1, dask: str | None = None,
              out_dir: str | os.PathLike | None = None, progress: bool | None = None,
              resume: bool = True) -> StudyResult:
    """Run every cell of ``study``.

    Parameters
    ----------
    workers : 1 runs in this process; > 1 uses a process pool of that size.
    dask : a scheduler address, or ``"local"`` for a ``LocalCluster`` of ``workers``
        processes (needs the optional extra ``raim-studio[dask]``).
    out_dir : directory for ``ledger.jsonl`` (one line per finished setting, used to
        resume an interrupted study), ``<name>.csv`` and ``<name>.md``.
    progress : show a progress bar on stderr (default: when stderr is a terminal).
    resume : skip settings already in the ledger.

    Returns
    -------
    StudyResult with one row per cell: n_visible, n_faults, bias, algorithm, runs,
    correct, rate, ci_low, ci_high (95% Clopper-Pearson), p_bias_m, fault_m, detected_rate
    (share of the runs where the full-set chi-square test alarms).
    """
    workers = check_int("workers", workers, 1, 256)
    t0 = time.perf_counter()
    out = Path(out_dir) if out_dir is not None else None
    ledger = out / "ledger.jsonl" if out is not None else None
    done = _read_ledger(ledger) if (ledger is not None and resume) else {}
    settings = study.settings()
    n_chunks = -(-study.runs // CHUNK_RUNS)
    counts: dict[tuple, dict[str, int]] = {}
    todo = []
    for s in settings:
        prev = done.get(_ledger_key(study, s))
        keys = (*study.algorithms, DETECTED)
        if prev is not None and all(a in prev for a in keys):
            counts[s] = {a: prev[a] for a in keys}
        else:
            counts[s] = dict.fromkeys(keys, 0)
            todo += [(s, c) for c in range(n_chunks)]
    remaining = {s: n_chunks for s, c in todo if c == 0}
    bar = _Progress(len(todo), progress, study.name)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if ledger.exists() and not ledger.read_text().endswith("\n"):
            with ledger.open("a") as f:  # a line cut by an interruption: start afresh
                f.write("\n")

    def finish(s, part):
        for a, v in part.items():
            counts[s][a] += v
        remaining[s] -= 1
        bar.step()
        if remaining[s] == 0 and ledger is not None:
            with ledger.open("a") as f:
                f.write(json.dumps({"key": _ledger_key(study, s), "counts": counts[s]}) + "\n")

    try:
        if dask is not None:
            _run_dask(study, todo, finish, dask, workers)
        elif workers == 1:
            for s, c in todo:
                finish(s, run_chunk(study, s, c))
        else:
            _run_pool(study, todo, finish, workers)
    finally:
        bar.close()
    rows = []
    for s in settings:
        n, k, b = s
        pb = study.unit_m(n)
        for a in study.algorithms:
            c = counts[s][a]
            ci = stats.binomtest(c, study.runs).proportion_ci(0.95)
            rows.append({"n_visible": n, "n_faults": k, "bias": b, "algorithm": a,
                         "runs": study.runs, "correct": c, "rate": c / study.runs,
                         "ci_low": ci.low, "ci_high": ci.high, "p_bias_m": round(pb, 2),
                         "fault_m": round(b * study.bias_scale * pb, 2),
                         "detected_rate": counts[s][DETECTED] / study.runs})
    res = StudyResult(study, rows, time.perf_counter() - t0)
    if out is not None:
        write_csv(res, out / f"{study.name}.csv")
        (out / f"{study.name}.md").write_text(markdown_table(res))
    return res


def _ignore_sigint() -> None:
    """Pool workers leave Ctrl-C to the parent (which stops them): no traceback each."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_on_pool(fn, calls, on_result, workers: int) -> None:
    """Run ``fn(*args)`` for each ``(tag, args)`` of ``calls`` on a process pool and hand
    each result to ``on_result(tag, result)`` as it comes; on Ctrl-C (or any error) stop
    the workers at once instead of waiting for the queued calls."""
    pool = ProcessPoolExecutor(max_workers=workers, initializer=_ignore_sigint)
    try:
        futs = {pool.submit(fn, *args): tag for tag, args in calls}
        for f in as_completed(futs):
            on_result(futs[f], f.result())
    except BaseException:
        # The executor has no public way to stop running work: terminate its processes.
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for p in procs:
            p.terminate()
        for p in procs:
            p.join(timeout=5)
        raise
    pool.shutdown()


def run_on_dask(fn, calls, on_result, address: str, workers: int, *, option: str,
                keys=None) -> None:
    """:func:`run_on_pool` on Dask: ``address`` ``"local"`` (a LocalCluster of
    ``workers`` processes, closed after) or a scheduler's address; ``keys`` names the
    tasks (one per call); ``option`` names the setting in the message when dask is not
    installed."""
    try:
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as d_as_completed
    except ImportError as exc:
        raise ValueError(f"{option} needs the optional dependency: pip install "
                         f"'raim-studio[dask]' ({exc})") from None
    cluster = None
    if address == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(address)
    try:
        futs = [client.submit(fn, *args, pure=False,
                              **({} if keys is None else {"key": keys[k]}))
                for k, (_tag, args) in enumerate(calls)]
        tags = {f.key: tag for f, (tag, _) in zip(futs, calls, strict=True)}
        for f in d_as_completed(futs):
            on_result(tags[f.key], f.result())
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _run_pool(study, todo, finish, workers: int) -> None:
    run_on_pool(run_chunk, [(s, (study, s, c)) for s, c in todo], finish, workers)


def _run_dask(study, todo, finish, address: str, workers: int):
    keys = [f"raim-{study.name}-{s}-{c}-{study.seed}-{study.runs}-{study.bias_scale}-"
            f"{study.bias_unit}-{'+'.join(study.systems)}" for s, c in todo]
    run_on_dask(run_chunk, [(s, (study, s, c)) for s, c in todo], finish, address,
                workers, option="--dask", keys=keys)


def write_csv(res: StudyResult, path) -> None:
    """Write the study rows (one per cell) as CSV."""
    rows = res.rows
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["n_visible"])
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6f}" if isinstance(v, float) else v) for k, v in r.items()})


def markdown_table(res: StudyResult, reference: dict | None = None,
                   ref_label: str = "paper") -> str:
    """Rates (%) as a Markdown table: rows bias / faults / algorithm, columns N.

    ``reference`` maps ``(N, faults, bias, algorithm_name) -> rate %`` to print
    "ours (paper)" in each cell.
    """
    st = res.study
    head = "| bias | faults | algorithm | " + " | ".join(f"N={n}" for n in st.n_visible) + " |"
    lines = [head, "|" + "---|" * (3 + len(st.n_visible))]
    for b in st.bias:
        for k in st.n_faults:
            for a in st.algorithms:
                cells = []
                for n in st.n_visible:
                    v = 100 * res.rate(n, k, b, a)
                    ref = None if reference is None else reference.get(
                        (n, k, b, a.split(":")[0]))
                    cells.append(f"{v:.1f}" + (f" ({ref})" if ref is not None else ""))
                lines.append(f"| {b:g} | {k} | {a} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def study_dict(study: Study) -> dict:
    """The study's parameters as a plain dict (for logs)."""
    return asdict(study)


def chunks_of(study: Study) -> Sequence[tuple]:
    """Every (setting, chunk) work unit of ``study``."""
    n_chunks = -(-study.runs // CHUNK_RUNS)
    return [(s, c) for s in study.settings() for c in range(n_chunks)]
