"""LPV-200 availability maps of ARAIM: users on a latitude/longitude grid over a day.

MAAST's availability study (``svmrun_araim.m``, ``init_usrdata.m``, ``evaluate_coverage.m``;
``shared/ARAIM.md`` section 11) in one function, :func:`availability`:

* users on a ``lat_step_deg`` x ``lon_step_deg`` grid at height ``height_m``, cut from a
  region polygon by MAAST's rules: latitudes ``max(floor(min/step) step, -90) ..
  min(ceil(max/step) step, 90 - step)``, longitudes ``max(floor(min/step) step, -180) ..
  min(ceil(max/step) step, 180 - step)``; users inside the polygon (or on its edge, as
  MAAST's ``inpolygon(...) > 0``) are computed, the others are not (NaN, weight 0). The
  default region is MAAST's ``usrworld.dat`` (the whole world: 18 x 36 users at 10 deg);
* epochs ``t = 0, t_step_s, ... < duration_s`` of the nominal constellations of
  ``systems`` (:func:`raimcore.sky.constellations.builtin`) or of YUMA/SEM almanacs;
* at each user-epoch the ARAIM MHSS protection levels (:func:`raimcore.araim.mhss`, every
  ADD constant a keyword), with the nominal error model of section 2 from an ISM
  (``ism``) and an airborne user model (``user_model``); an epoch is available when
  ``VPL <= val_m``, ``HPL <= hal_m``, ``EMT <= emt_max_m`` and
  ``sigma_acc <= sigma_acc_max_m``;
* per user the share of available epochs, the median and 99th percentile of VPL and HPL,
  and the coverage ``100 sum_{share >= target} cos(lat) / sum cos(lat)`` over the users
  inside the region (``evaluate_coverage.m``).

Vectorised: whole blocks of epochs x users go through ``mhss`` at once (at most
``batch_user_epochs`` per call, so memory stays bounded whatever the grid); users are cut
into chunks of :data:`CHUNK_USERS`, run in this process (``workers=1``), on a process pool
(``workers > 1``) or on a Dask cluster (``dask="local"`` or an address). The study has no
randomness: the answer is the same however it is spread.

ISM presets (:data:`ISM_PRESETS`): ``"b2012"`` (default) is MAAST's example ISM with the
integrity/accuracy values of the B2012 worked example (sigma_URA 0.75 m, sigma_URE 0.5 m,
b_nom 0.5 m, every system); ``"maast"`` is MAAST's example ISD (sigma_URA GPS 2.4 / GAL 6 m),
an H-ARAIM-grade message with which no geometry meets ``sigma_acc <= 1.87 m`` (vertical
accuracy sigma about 3.3 m for GPS + Galileo), so its LPV-200 map is 0 % everywhere. The
default is therefore ``"b2012"``: an LPV-200 map that says something (95.2 % coverage at
99.5 % for the nominal GPS + Galileo world); ``"maast"`` or a table
(:func:`raimcore.measure.error_models.parse_ism`) is one keyword away.

``algorithm``: ``"araim"`` (the MHSS above), ``"mss"`` (single-fault solution separation) or
``"classic"`` (the chi-square RAIM slope protection levels), the last two the MSS and classic
PLs of the baro paper (:func:`raimcore.algorithms.mss.mss`, :func:`~raimcore.algorithms.mss.
classic_raim`, called batched over user-epochs, no baro row). Their error model is one sigma
per pseudorange: the ARAIM integrity sigma of section 2 (``sigma_URA`` of the ISM, troposphere,
airborne user model; ``b_nom``, ``P_sat`` and ``P_const`` do not enter), with ``p_fa`` and
``p_md`` (:data:`PL_P_FA`, :data:`PL_P_MD`). An epoch is then available when ``HPL <= hal_m``
and ``VPL <= val_m``: EMT and sigma_acc are ARAIM outputs and do not apply (the result's
``notes`` and the settings say so; ``emt_max_m``/``sigma_acc_max_m`` are stored as None).

Resumable runs (``ledger_dir``): every finished chunk of users is written to
``ledger_dir/chunk_NNNNN.npz`` (atomically) under ``ledger_dir/manifest.json``, which holds
a SHA-256 key of every parameter that changes a chunk's numbers (users, epochs, height, mask,
the constellation's elements, algorithm, ISM, user model, limits, ``p_fa``/``p_md``, the
``mhss`` keywords, :data:`CHUNK_USERS`, :data:`LEDGER_VERSION`). A rerun with the same key
reuses the finished chunks (an interrupted run resumes where it stopped) and gives the same
numbers; ``target``, ``workers``, ``dask``, ``batch_user_epochs`` and ``progress`` do not
enter the key (they do not change a chunk). A ledger of other parameters is never reused:
with ``resume=True`` the run is refused naming the parameters that differ, with
``resume=False`` the folder's ledger files are deleted and the run starts fresh.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._validate import check_choice, check_int, check_positive, check_probability, check_range
from ..geometry import enu_rotation, geodetic_to_ecef
from ..measure.error_models import USER_MODELS, Ism, araim_sigmas, parse_ism
from ..sky.constellations import SYSTEM_PREFIX, Constellation, builtin, combine
from ._availability_defaults import ALGORITHMS, PL_P_FA, PL_P_MD
from .montecarlo import run_on_dask, run_on_pool

__all__ = ["availability", "AvailabilityResult", "ISM_PRESETS", "DEFAULT_ISM", "ALGORITHMS",
           "user_grid", "in_polygon", "coverage_pct", "WORLD", "CHUNK_USERS",
           "read_csv", "PL_P_FA", "PL_P_MD", "LEDGER_VERSION"]

#: MAAST's ``usrworld.dat``: the whole world (lat, lon vertices in degrees).
WORLD = ((-90.0, -180.0), (-90.0, 180.0), (90.0, 180.0), (90.0, -180.0))
#: ``mss`` keeps (user-epoch, satellite, satellite) arrays: per call it takes
#: ``batch_user_epochs // SS_BATCH_DIVISOR`` user-epochs (about 80 kB each).
SS_BATCH_DIVISOR = 10
#: Version of the ledger format and of the numbers in it; a change invalidates old ledgers.
LEDGER_VERSION = 1
#: Users per work unit (pool / Dask task). Fixed, so a study spreads the same way anywhere.
CHUNK_USERS = 72
#: Most user-epochs per ``mhss`` call (memory: about 40 kB each with the kernel's temporaries).
BATCH_USER_EPOCHS = 20_000

_B2012_VALUES = {"sigma_ura_m": 0.75, "sigma_ure_m": 0.5, "b_nom_m": 0.5}
#: ISM presets: MAAST's example ISD, and the same with B2012's worked-example sigmas/bias.
ISM_PRESETS: dict[str, Ism] = {
    "maast": parse_ism("ism", "maast"),
    "b2012": parse_ism("ism", {s: dict(_B2012_VALUES) for s in SYSTEM_PREFIX}),
}
#: Default ISM of the study (see the module docstring for why not MAAST's).
DEFAULT_ISM = "b2012"

_STAT_FIELDS = ("n_epochs", "n_available", "n_unavailable_geometry", "vpl_median_m",
                "vpl_p99_m", "hpl_median_m", "hpl_p99_m")


# --------------------------------------------------------------------------------------
# Grid and region


def in_polygon(lat_deg, lon_deg, poly) -> np.ndarray:
    """Points inside the polygon ``poly`` (``(n, 2)`` lat, lon vertices, deg) or on its
    edge, as MAAST's ``inpolygon(...) > 0`` (even-odd rule, lon as x, lat as y)."""
    y = np.asarray(lat_deg, dtype=float)[..., None]
    x = np.asarray(lon_deg, dtype=float)[..., None]
    p = np.asarray(poly, dtype=float)
    y1, x1 = p[:, 0], p[:, 1]
    y2, x2 = np.roll(y1, -1), np.roll(x1, -1)
    eps = 1e-9
    # On an edge: collinear and within the segment's box.
    cross = (x2 - x1) * (y - y1) - (y2 - y1) * (x - x1)
    on = (np.abs(cross) <= eps * np.maximum(1.0, np.hypot(x2 - x1, y2 - y1))) \
        & (np.minimum(x1, x2) - eps <= x) & (x <= np.maximum(x1, x2) + eps) \
        & (np.minimum(y1, y2) - eps <= y) & (y <= np.maximum(y1, y2) + eps)
    straddle = (y1 > y) != (y2 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        x_cross = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
    inside = np.sum(straddle & (x < x_cross), axis=-1) % 2 == 1
    return inside | on.any(axis=-1)


def _check_region(region) -> np.ndarray:
    if region is None:
        return np.array(WORLD)
    try:
        p = np.asarray(region, dtype=float)
    except (TypeError, ValueError):
        p = None
    if p is None or p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3 \
            or not np.all(np.isfinite(p)):
        raise ValueError(f"region must be a polygon of at least 3 (lat, lon) vertices in "
                         f"degrees, got {region!r}"[:200])
    if np.any(np.abs(p[:, 0]) > 90.0) or np.any(np.abs(p[:, 1]) > 180.0):
        raise ValueError("region: latitudes must be in [-90, 90] and longitudes in "
                         f"[-180, 180] deg, got {p.tolist()!r}"[:200])
    return p


def user_grid(lat_step_deg: float = 10.0, lon_step_deg: float = 10.0, region=None):
    """MAAST's user grid (``init_usrdata.m``) of a region polygon.

    Returns
    -------
    lat_axis_deg (n_lat,), lon_axis_deg (n_lon,), lat_deg (U,), lon_deg (U,) with
    ``U = n_lat n_lon`` in latitude-major order (user ``i * n_lon + j`` at
    ``lat_axis[i], lon_axis[j]``), inside (U,) bool (in the polygon or on its edge).
    """
    poly = _check_region(region)
    la0 = max(math.floor(poly[:, 0].min() / lat_step_deg) * lat_step_deg, -90.0)
    la1 = min(math.ceil(poly[:, 0].max() / lat_step_deg) * lat_step_deg, 90.0 - lat_step_deg)
    lo0 = max(math.floor(poly[:, 1].min() / lon_step_deg) * lon_step_deg, -180.0)
    lo1 = min(math.ceil(poly[:, 1].max() / lon_step_deg) * lon_step_deg,
              180.0 - lon_step_deg)
    lat_axis = la0 + lat_step_deg * np.arange(int(round((la1 - la0) / lat_step_deg)) + 1)
    lon_axis = lo0 + lon_step_deg * np.arange(int(round((lo1 - lo0) / lon_step_deg)) + 1)
    la, lo = np.meshgrid(lat_axis, lon_axis, indexing="ij")
    lat, lon = la.ravel(), lo.ravel()
    return lat_axis, lon_axis, lat, lon, in_polygon(lat, lon, poly)


def coverage_pct(share, lat_deg, target: float, inside=None) -> float:
    """``100 sum_{share >= target} cos(lat) / sum cos(lat)`` over the users ``inside``
    (``evaluate_coverage.m``; ARAIM.md section 11). NaN shares count as not covered."""
    share = np.asarray(share, dtype=float)
    w = np.cos(np.radians(np.asarray(lat_deg, dtype=float)))
    w = np.where(np.abs(np.asarray(lat_deg)) >= 90.0, 0.0, np.maximum(w, 0.0))
    if inside is not None:
        w = np.where(inside, w, 0.0)
    total = w.sum()
    if total <= 0.0:
        return float("nan")
    with np.errstate(invalid="ignore"):
        hit = share >= target - 1e-12
    return float(100.0 * w[hit].sum() / total)


# --------------------------------------------------------------------------------------
# Inputs


def _check_systems(systems) -> tuple[str, ...]:
    if isinstance(systems, str):
        systems = tuple(s.strip() for s in systems.split(",") if s.strip())
    if not isinstance(systems, Sequence) or not systems or len(set(systems)) != len(systems) \
            or any(s not in SYSTEM_PREFIX for s in systems):
        raise ValueError(f"systems must be a non-empty list of distinct names of "
                         f"{', '.join(SYSTEM_PREFIX)}, got {systems!r}")
    return tuple(systems)


def _almanac_items(constellation) -> list[tuple[str, str]]:
    """``path`` (GPS), ``"GAL=path"``, a list of those, or ``{system: path}``."""
    if isinstance(constellation, Mapping):
        return [(str(k), str(v)) for k, v in constellation.items()]
    items = [constellation] if isinstance(constellation, (str, Path)) else list(constellation)
    out = []
    for it in items:
        text = str(it)
        head, sep, tail = text.partition("=")
        if sep and head.strip().upper() in SYSTEM_PREFIX:
            out.append((head.strip().upper(), tail.strip()))
        else:
            out.append(("GPS", text))
    return out


def _load_constellation(constellation, systems) -> tuple[Constellation, list[str]]:
    """The healthy satellites of ``systems`` and the names of those left out as
    unhealthy."""
    if isinstance(constellation, Constellation):
        const = constellation
    elif isinstance(constellation, str) and constellation == "nominal":
        return builtin(systems), []
    else:
        from ..sky.constellations import read_almanac_cached

        try:
            items = _almanac_items(constellation)
        except TypeError:
            items = []
        if not items:
            raise ValueError(f"constellation must be \"nominal\", an almanac path, "
                             f"\"SYS=path\" or a list of them, got {constellation!r}")
        parts = []
        for system, path in items:
            if not Path(path).is_file():
                raise ValueError(f"constellation: almanac file {path!r} not found")
            parts.append(read_almanac_cached(path, system))
        const = combine(*parts)
    keep = [n for n, s, h in zip(const.names, const.systems, np.asarray(const.healthy),
                                 strict=True) if s in systems and bool(h)]
    missing = [s for s in systems if s not in {const.systems[const.names.index(n)]
                                               for n in keep}]
    if missing:
        raise ValueError(f"constellation: no healthy {', '.join(missing)} satellite in the "
                         f"almanac(s); give one per system as SYS=FILE (e.g. GAL=gal.alm)")
    unhealthy = [n for n, s, h in zip(const.names, const.systems, np.asarray(const.healthy),
                                      strict=True) if s in systems and not bool(h)]
    return const.subset(keep), unhealthy


def _check_ism(ism) -> Ism:
    if isinstance(ism, str) and ism.strip().lower() in ISM_PRESETS:
        return ISM_PRESETS[ism.strip().lower()]
    if isinstance(ism, str):
        raise ValueError(f"ism must be one of {', '.join(ISM_PRESETS)} or a table of "
                         f"systems, got {ism!r}")
    try:
        return parse_ism("ism", ism)
    except ValueError:
        raise
    except Exception as exc:  # SchemaError is a ValueError; anything else: one line too
        raise ValueError(f"ism: {exc}") from None


def _check_araim_params(params: dict) -> dict:
    from ..araim._params import resolve

    rules = params.get("rules", "add-v4.2")
    rest = {k: v for k, v in params.items() if k != "rules"}
    for bad in ("y", "used", "return_modes"):
        if bad in rest:
            raise ValueError(f"{bad} is not an availability option (no measurements here)")
    resolve(rules, rest)  # raises naming the keyword and the allowed ones
    return dict(params)


# --------------------------------------------------------------------------------------
# Work unit: a block of users over every epoch


@dataclass(frozen=True)
class _Task:
    const: Constellation
    systems: tuple[str, ...]
    t_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    height_m: float
    mask_deg: float
    ism: Ism
    user_model: str
    limits: tuple[float, float, float, float]  # val, hal, emt, sigma_acc
    araim_params: dict = field(default_factory=dict)
    batch_user_epochs: int = BATCH_USER_EPOCHS
    algorithm: str = "araim"
    pl_probs: tuple[float, float] = (PL_P_FA, PL_P_MD)  # p_fa, p_md of mss / classic


def _quantiles(x: np.ndarray, q) -> np.ndarray:
    """Quantiles over axis 0 that stay inf (not NaN) where infinite values meet."""
    with np.errstate(invalid="ignore"):
        out = np.quantile(x, q, axis=0)
    return np.where(np.isnan(out) & np.isinf(x).any(axis=0), np.inf, out)


def geometry_inputs(task: _Task, t_s: np.ndarray, lat_deg: np.ndarray, lon_deg: np.ndarray):
    """Arguments of :func:`raimcore.araim.mhss` for ``(T, U)`` user-epochs."""
    const, systems = task.const, task.systems
    sys_idx = np.array([systems.index(s) for s in const.systems], dtype=int)
    sv = const.positions_ecef_m(t_s)  # (T, S, 3)
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    rx = geodetic_to_ecef(lat, lon, task.height_m)  # (U, 3)
    rot = enu_rotation(lat, lon)  # (U, 3, 3)
    d = sv[:, None, :, :] - rx[None, :, None, :]  # (T, U, S, 3)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    u = np.einsum("uij,tusj->tusi", rot, d)
    el = np.arcsin(np.clip(u[..., 2], -1.0, 1.0))
    clock = (sys_idx[:, None] == np.arange(len(systems))[None, :]).astype(float)
    g = np.concatenate([-u, np.broadcast_to(clock, u.shape[:-1] + (len(systems),))], axis=-1)
    g[el < math.radians(task.mask_deg)] = np.nan
    s_int, s_acc = araim_sigmas(el, systems, sys_idx, task.ism, task.user_model)
    per_sat = task.ism.per_sat(systems, sys_idx)
    per_sys = task.ism.per_system(systems)
    b_int = np.broadcast_to(per_sat["b_nom_m"], s_int.shape)
    b_acc = np.broadcast_to(per_sat["b_cont_m"], s_int.shape)
    return g, s_int, s_acc, b_int, b_acc, per_sat["p_sat"], per_sys["p_const"]


def _run_users(task: _Task, progress: Callable[[int], None] | None = None):
    """Per-epoch HPL, VPL and availability ``(T, U)`` of the task's users (HPL, VPL inf
    where an epoch has no protection level)."""
    n_t, n_u = task.t_s.size, task.lat_deg.size
    hpl = np.empty((n_t, n_u))
    vpl = np.empty((n_t, n_u))
    ok = np.empty((n_t, n_u), dtype=bool)
    geo_bad = np.empty((n_t, n_u), dtype=bool)
    batch = task.batch_user_epochs
    if task.algorithm == "mss":
        batch = max(1, batch // SS_BATCH_DIVISOR)
    per = max(1, batch // max(n_u, 1))  # epochs per kernel call
    levels = _araim_levels if task.algorithm == "araim" else _ss_levels
    for a in range(0, n_t, per):
        b = min(n_t, a + per)
        args = geometry_inputs(task, task.t_s[a:b], task.lat_deg, task.lon_deg)
        hpl[a:b], vpl[a:b], ok[a:b], geo_bad[a:b] = levels(task, args)
        if progress is not None:
            progress((b - a) * n_u)
    return hpl, vpl, ok, geo_bad


def _araim_levels(task: _Task, args):
    """ARAIM MHSS: HPL, VPL, available (VPL, HPL, EMT, sigma_acc within their limits) and
    no-solution flags of a block of user-epochs."""
    from ..araim import mhss

    val, hal, emt_max, sacc_max = task.limits
    res = mhss(*args, return_modes=False, **task.araim_params)
    ok = ((res.vpl_m <= val) & (res.hpl_m <= hal) & (res.emt_m <= emt_max)
          & (res.sigma_acc_v_m <= sacc_max))
    return res.hpl_m, res.vpl_m, ok, res.status != "ok"


def _ss_levels(task: _Task, args):
    """Solution separation (``mss``) or classic slope PLs of a block of user-epochs, one
    batched kernel call: rows of the satellites in view compacted to the front (the
    kernels' cost grows with the square of the row count), weights ``1 / sigma_int^2``, zero
    innovations (the PLs do not depend on them). Available: ``HPL <= HAL`` and
    ``VPL <= VAL``; no PL (under 4 satellites, no redundancy, singular geometry) is inf."""
    from ..algorithms import mss as kernel

    g, s_int = args[0], args[1]
    vis = np.isfinite(g).all(axis=-1) & np.isfinite(s_int) & (s_int > 0.0)
    m_max = max(int(vis.sum(axis=-1).max(initial=0)), 1)
    slot = np.argsort(~vis, axis=-1, kind="stable")[..., :m_max]  # in-view rows first
    h = np.take_along_axis(g, slot[..., None], axis=-2)
    with np.errstate(divide="ignore"):
        w = np.where(vis, 1.0 / s_int**2, 0.0)
    w = np.take_along_axis(w, slot, axis=-1)
    z = np.zeros(w.shape)
    is_sat = np.ones(m_max, dtype=bool)
    p_fa, p_md = task.pl_probs
    fn = kernel.mss if task.algorithm == "mss" else kernel.classic_raim
    res = fn(h, z, w, is_sat, p_fa, p_md)
    bad = res.status == kernel.STATUS_UNAVAILABLE
    hpl = np.where(np.isnan(res.hpl_m), np.inf, res.hpl_m)
    vpl = np.where(np.isnan(res.vpl_m), np.inf, res.vpl_m)
    val, hal = task.limits[:2]
    return hpl, vpl, (vpl <= val) & (hpl <= hal), bad | ~np.isfinite(hpl + vpl)


def _summarise(hpl, vpl, ok, geo_bad) -> dict[str, np.ndarray]:
    v_med, v_99 = _quantiles(vpl, [0.5, 0.99])
    h_med, h_99 = _quantiles(hpl, [0.5, 0.99])
    return {"n_epochs": np.full(ok.shape[1], ok.shape[0]), "n_available": ok.sum(axis=0),
            "n_unavailable_geometry": geo_bad.sum(axis=0), "vpl_median_m": v_med,
            "vpl_p99_m": v_99, "hpl_median_m": h_med, "hpl_p99_m": h_99}


def run_chunk(task: _Task) -> dict[str, np.ndarray]:
    """One work unit: the per-user statistics of the task's users."""
    return _summarise(*_run_users(task))


# --------------------------------------------------------------------------------------
# Result


@dataclass(frozen=True, eq=False)
class AvailabilityResult:
    """An availability map. Users in latitude-major order (``lat_deg``, ``lon_deg``).

    Attributes
    ----------
    lat_axis_deg (n_lat,), lon_axis_deg (n_lon,) : the grid axes.
    lat_deg, lon_deg, inside : (U,) users and whether each is in the region (computed).
    availability : (U,) share of available epochs (NaN outside the region).
    n_epochs, n_available, n_unavailable_geometry : (U,) counts (the evidence behind
        ``availability``; the last: epochs with under 4 satellites or singular geometry,
        for ``mss``/``classic`` also no redundancy: no protection level).
    vpl_median_m, vpl_p99_m, hpl_median_m, hpl_p99_m : (U,) per-user statistics (m;
        inf where over half, or 1 %, of the epochs have no solution).
    coverage_pct : cos(latitude)-weighted share of the region's users with
        ``availability >= target`` (%).
    settings : the study's parameters (systems, steps, limits, ISM, ...), JSON-ready;
        ``criteria`` says what "available" meant, ``n_satellites`` the satellites used per
        system and ``unhealthy`` those of ``systems`` left out as unhealthy.
    wall_s : wall time (s). status : ``"ok"``, or ``"empty"`` when no user is inside.
    notes : one-line remarks: criteria that do not apply to the algorithm, what the
        ledger reused or started afresh.
    """

    lat_axis_deg: np.ndarray
    lon_axis_deg: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    inside: np.ndarray
    availability: np.ndarray
    n_epochs: np.ndarray
    n_available: np.ndarray
    n_unavailable_geometry: np.ndarray
    vpl_median_m: np.ndarray
    vpl_p99_m: np.ndarray
    hpl_median_m: np.ndarray
    hpl_p99_m: np.ndarray
    coverage_pct: float
    target: float
    settings: dict
    wall_s: float = 0.0
    status: str = "ok"
    notes: tuple[str, ...] = ()

    @property
    def n_user_epochs(self) -> int:
        """User-epochs computed."""
        return int(self.n_epochs[self.inside].sum())

    def grid(self, name: str = "availability") -> np.ndarray:
        """A per-user attribute as a ``(n_lat, n_lon)`` grid."""
        return np.asarray(getattr(self, name)).reshape(self.lat_axis_deg.size,
                                                       self.lon_axis_deg.size)

    def to_csv(self, path) -> Path:
        """One row per user; the first line is ``# `` + the settings and coverage as JSON
        (:func:`read_csv` reads it back)."""
        path = Path(path)
        head = dict(self.settings, coverage_pct=self.coverage_pct, target=self.target,
                    lat_axis_deg=self.lat_axis_deg.tolist(),
                    lon_axis_deg=self.lon_axis_deg.tolist(), wall_s=self.wall_s,
                    status=self.status, notes=list(self.notes))
        cols = ("lat_deg", "lon_deg", "inside", "availability", *_STAT_FIELDS)
        with path.open("w", newline="") as f:
            f.write("# " + json.dumps(head) + "\n")
            w = csv.writer(f)
            w.writerow(cols)
            for i in range(self.lat_deg.size):
                w.writerow([repr(float(self.lat_deg[i])), repr(float(self.lon_deg[i])),
                            int(self.inside[i]), repr(float(self.availability[i]))]
                           + [int(getattr(self, c)[i]) if c.startswith("n_")
                              else repr(float(getattr(self, c)[i])) for c in _STAT_FIELDS])
        return path

    def summary_lines(self) -> list[str]:
        s = self.settings
        n_in = int(self.inside.sum())
        n_cov = int(np.sum(self.inside & (self.availability >= self.target - 1e-12)))
        fin = self.inside & np.isfinite(self.vpl_median_m)
        return [
            f"{s.get('algorithm', 'araim')}: {'+'.join(s['systems'])} {s['constellation']}, "
            f"ISM {s['ism']}, "
            f"{s['lat_step_deg']:g} x {s['lon_step_deg']:g} deg grid, {n_in} users, "
            f"{int(self.n_epochs.max(initial=0))} epochs every {s['t_step_s']:g} s, "
            f"{self.n_user_epochs} user-epochs",
            f"coverage at {100 * self.target:g} % availability (cos-lat weighted): "
            f"{self.coverage_pct:.1f} % ({n_cov}/{n_in} users)",
            f"median VPL (median over users) "
            f"{np.median(self.vpl_median_m[fin]) if fin.any() else np.nan:.1f} m, "
            f"worst user 99th pct VPL "
            f"{np.max(self.vpl_p99_m[self.inside]) if n_in else np.nan:.1f} m",
            f"available: {s.get('criteria', '')}",
            *(f"note: {n}" for n in self.notes),
        ]


def read_csv(path) -> AvailabilityResult:
    """An :class:`AvailabilityResult` back from :meth:`AvailabilityResult.to_csv`."""
    path = Path(path)
    with path.open(newline="") as f:
        first = f.readline()
        if not first.startswith("# "):
            raise ValueError(f"{str(path)!r} is not an availability CSV (no '# {{...}}' "
                             "header line)")
        head = json.loads(first[2:])
        rows = list(csv.DictReader(f))
    col = {k: np.array([r[k] for r in rows]) for k in rows[0]} if rows else {}
    num = {k: v.astype(float) for k, v in col.items()}
    return AvailabilityResult(
        lat_axis_deg=np.array(head.pop("lat_axis_deg")),
        lon_axis_deg=np.array(head.pop("lon_axis_deg")),
        lat_deg=num["lat_deg"], lon_deg=num["lon_deg"], inside=num["inside"] > 0,
        availability=num["availability"],
        **{k: (num[k].astype(int) if k.startswith("n_") else num[k]) for k in _STAT_FIELDS},
        coverage_pct=float(head.pop("coverage_pct")), target=float(head.pop("target")),
        wall_s=float(head.pop("wall_s")), status=head.pop("status"),
        notes=tuple(head.pop("notes", ())), settings=head)


# --------------------------------------------------------------------------------------
# Ledger of finished chunks (resumable runs)

_MANIFEST = "manifest.json"


def _fingerprint(value):
    """JSON-ready stand-in of a parameter: arrays by shape and SHA-256 of their bytes."""
    if isinstance(value, np.ndarray) or (isinstance(value, (list, tuple)) and value
                                         and isinstance(value[0], np.ndarray)):
        a = np.ascontiguousarray(np.asarray(value, dtype=float))
        return {"shape": list(a.shape), "sha256": hashlib.sha256(a.tobytes()).hexdigest()}
    if isinstance(value, Mapping):
        return {str(k): _fingerprint(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_fingerprint(v) for v in value]
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    return value


def _constellation_fingerprint(const: Constellation) -> str:
    h = hashlib.sha256(json.dumps([list(const.names), list(const.systems)]).encode())
    for name in ("sqrt_a", "ecc", "inc_rad", "omega0_rad", "omega_dot_radps", "argp_rad",
                 "m0_rad", "toa_s", "gm_m3ps2", "omega_e_radps"):
        h.update(np.ascontiguousarray(getattr(const, name), dtype=float).tobytes())
    return h.hexdigest()


class _Ledger:
    """``folder/manifest.json`` (key and parameters) and one ``chunk_NNNNN.npz`` per
    finished chunk. Opening it checks the manifest (module docstring: reuse, refuse or
    start afresh); :meth:`load` gives a finished chunk's statistics or None."""

    def __init__(self, folder, params: dict, n_chunks: int, resume: bool):
        self.folder = Path(folder)
        if self.folder.exists() and not self.folder.is_dir():
            raise ValueError(f"ledger_dir: {str(self.folder)!r} is a file, not a folder")
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"ledger_dir: cannot create {str(self.folder)!r} "
                             f"({exc.strerror})") from None
        self.params = json.loads(json.dumps(params))
        self.key = hashlib.sha256(json.dumps(self.params, sort_keys=True).encode()).hexdigest()
        self.fresh_reason = ""
        old = self._read_manifest()
        if old is not None and old.get("key") != self.key:
            if resume:
                diff = sorted(k for k in set(old.get("params", {})) | set(self.params)
                              if old.get("params", {}).get(k) != self.params.get(k))
                raise ValueError(
                    f"ledger_dir {str(self.folder)!r} holds a ledger of other parameters "
                    f"(differing: {', '.join(diff) or 'format'}); use another folder, or "
                    "resume=False (--no-resume) to delete it and start afresh")
            self.fresh_reason = "its ledger had other parameters"
        elif old is not None and not resume:
            self.fresh_reason = "resume is off"
        if old is None or self.fresh_reason:
            for f in self.folder.glob("chunk_*.npz"):
                f.unlink()
            self._write(self.folder / _MANIFEST, lambda f: f.write(json.dumps(
                {"key": self.key, "version": LEDGER_VERSION, "n_chunks": n_chunks,
                 "params": self.params}, indent=1, sort_keys=True).encode()))

    def _read_manifest(self):
        path = self.folder / _MANIFEST
        if not path.exists():
            return None
        try:
            return json.loads(path.read_text())
        except (OSError, ValueError):
            return {}  # unreadable: not ours to trust, treated as other parameters

    def _path(self, i: int) -> Path:
        return self.folder / f"chunk_{i:05d}.npz"

    @staticmethod
    def _write(path: Path, write) -> None:
        tmp = path.with_name(path.name + ".part")
        with tmp.open("wb") as f:
            write(f)
        os.replace(tmp, path)  # atomic: an interrupted write leaves no half chunk

    def load(self, i: int, users: np.ndarray) -> dict | None:
        path = self._path(i)
        if not path.exists():
            return None
        try:
            with np.load(path, allow_pickle=False) as z:
                if str(z["key"]) != self.key or not np.array_equal(z["users"], users):
                    return None
                return {k: z[k] for k in _STAT_FIELDS}
        except (OSError, ValueError, KeyError):
            return None  # damaged: computed again

    def save(self, i: int, users: np.ndarray, part: dict) -> None:
        self._write(self._path(i), lambda f: np.savez(f, key=np.array(self.key), users=users,
                                                      **part))


# --------------------------------------------------------------------------------------
# The study


def availability(systems=("GPS", "GAL"), *, lat_step_deg: float = 10.0,
                 lon_step_deg: float = 10.0, region=None, t_step_s: float = 300.0,
                 duration_s: float = 86400.0, height_m: float = 0.0,
                 constellation="nominal", algorithm: str = "araim", mask_deg: float = 5.0,
                 ism=DEFAULT_ISM, user_model: str = "ed259a", val_m: float = 35.0,
                 hal_m: float = 40.0, emt_max_m: float = 15.0,
                 sigma_acc_max_m: float = 1.87, target: float = 0.995, workers: int = 1,
                 dask: str | None = None,
                 progress: Callable[[int, int], None] | None = None,
                 batch_user_epochs: int = BATCH_USER_EPOCHS,
                 p_fa: float | None = None, p_md: float | None = None,
                 ledger_dir: str | Path | None = None, resume: bool = True,
                 **araim_params) -> AvailabilityResult:
    """LPV-200 availability of ARAIM (or MSS, classic RAIM) on a user grid over a day
    (module docstring).

    Parameters
    ----------
    systems : constellations (GPS, GAL, BDS, GLO), one clock each, in this order.
    lat_step_deg, lon_step_deg : grid steps (deg, in (0, 90] and (0, 180]).
    region : polygon of (lat, lon) vertices (deg); None = the world (MAAST's rules).
    t_step_s, duration_s : epochs ``0, t_step_s, ... < duration_s`` (s).
    height_m : user height above the ellipsoid (m).
    constellation : ``"nominal"`` (built-in), an almanac path (GPS), ``"GAL=path"``, a
        list of those, ``{system: path}`` or a :class:`Constellation`; only healthy
        satellites of ``systems`` are used.
    algorithm : ``"araim"`` (MHSS), ``"mss"`` (solution separation) or ``"classic"``
        (chi-square slope PLs); see the module docstring.
    mask_deg : elevation mask (deg). ism : ``"b2012"`` (default), ``"maast"`` or a table
        for :func:`~raimcore.measure.error_models.parse_ism`. user_model : ``"ed259a"``
        (MAAST v5, default) or ``"add"``.
    val_m, hal_m, emt_max_m, sigma_acc_max_m : LPV-200 criteria (m); the last two apply to
        ``"araim"`` only.
    target : availability a user needs to count as covered (0.995).
    workers : processes (1: in this process). dask : ``"local"`` (a LocalCluster of
        ``workers`` processes) or a scheduler address; needs ``dask.distributed``.
    progress : ``progress(done_user_epochs, total_user_epochs)``, called as work finishes
        (chunks reused from the ledger count as done at once). An exception it raises
        stops the study; the chunks finished so far stay in the ledger.
    batch_user_epochs : most user-epochs per kernel call (bounds the memory).
    p_fa, p_md : false-alarm and missed-detection probabilities of ``"mss"`` and
        ``"classic"`` (default :data:`PL_P_FA`, :data:`PL_P_MD`); not for ``"araim"``.
    ledger_dir : folder of the ledger of finished chunks (None: no ledger); created if
        missing. resume : reuse the ledger's finished chunks when its parameters match
        (a ledger of other parameters is refused); False: delete it and start afresh.
    **araim_params : keywords of :func:`raimcore.araim.mhss` (``rules``, ``fde``, the
        section 10 constants); ``"araim"`` only.

    Returns
    -------
    AvailabilityResult

    Raises
    ------
    ValueError
        A bad parameter, in one line naming it (also a ledger of other parameters with
        ``resume=True``).

    Examples
    --------
    >>> res = availability(("GPS", "GAL"), lat_step_deg=45, lon_step_deg=90,
    ...                    t_step_s=3600, duration_s=7200, algorithm="classic")
    >>> res.lat_deg.size, int(res.n_epochs.max()), res.settings["emt_max_m"]
    (16, 2, None)
    """
    t0 = time.perf_counter()
    systems = _check_systems(systems)
    lat_step_deg = check_range("lat_step_deg", lat_step_deg, 1e-3, 90.0)
    lon_step_deg = check_range("lon_step_deg", lon_step_deg, 1e-3, 180.0)
    t_step_s = check_positive("t_step_s", t_step_s)
    duration_s = check_positive("duration_s", duration_s)
    height_m = check_range("height_m", height_m, -1e3, 1e5)
    check_choice("algorithm", algorithm, ALGORITHMS)
    mask_deg = check_range("mask_deg", mask_deg, 0.0, 60.0)
    check_choice("user_model", user_model, USER_MODELS)
    limits = tuple(check_positive(n, v) for n, v in (
        ("val_m", val_m), ("hal_m", hal_m), ("emt_max_m", emt_max_m),
        ("sigma_acc_max_m", sigma_acc_max_m)))
    target = check_range("target", target, 0.0, 1.0)
    workers = check_int("workers", workers, 1, 256)
    batch_user_epochs = check_int("batch_user_epochs", batch_user_epochs, 1)
    if progress is not None and not callable(progress):
        raise ValueError(f"progress must be a callable or None, got {progress!r}")
    if dask is not None and not isinstance(dask, str):
        raise ValueError(f"dask must be \"local\" or a scheduler address, got {dask!r}")
    if not isinstance(resume, (bool, np.bool_)):
        raise ValueError(f"resume must be True or False, got {resume!r}")
    if ledger_dir is not None and not isinstance(ledger_dir, (str, os.PathLike)):
        raise ValueError(f"ledger_dir must be a folder path or None, got {ledger_dir!r}")
    ism_obj = _check_ism(ism)
    if algorithm == "araim":
        for name, v in (("p_fa", p_fa), ("p_md", p_md)):
            if v is not None:
                raise ValueError(f"{name} applies to algorithm mss or classic; araim takes "
                                 "its budgets as p_fa_vert, p_fa_hor, phmi_vert, ...")
        araim_params = _check_araim_params(araim_params)
        probs = (PL_P_FA, PL_P_MD)
    else:
        if araim_params:
            name = sorted(araim_params)[0]
            raise ValueError(f"{name} is not an option of algorithm {algorithm} (araim "
                             "keywords apply to algorithm araim only; mss and classic take "
                             "p_fa and p_md)")
        probs = (check_probability("p_fa", PL_P_FA if p_fa is None else p_fa),
                 check_probability("p_md", PL_P_MD if p_md is None else p_md))
    lat_axis, lon_axis, lat, lon, inside = user_grid(lat_step_deg, lon_step_deg, region)
    const, unhealthy = _load_constellation(constellation, systems)
    t_s = np.arange(0.0, duration_s, t_step_s)
    if t_s.size * lat.size > 5e8:
        raise ValueError(f"the study has {t_s.size * lat.size} user-epochs, more than 5e8: "
                         "use larger steps or a smaller region")

    idx = np.flatnonzero(inside)
    chunks = [idx[a:a + CHUNK_USERS] for a in range(0, idx.size, CHUNK_USERS)]
    tasks = [_Task(const, systems, t_s, lat[c], lon[c], height_m, mask_deg, ism_obj,
                   user_model, limits, araim_params, batch_user_epochs, algorithm, probs)
             for c in chunks]
    araim = algorithm == "araim"
    settings = {
        "systems": list(systems), "lat_step_deg": lat_step_deg, "lon_step_deg": lon_step_deg,
        "region": None if region is None else np.asarray(region, dtype=float).tolist(),
        "t_step_s": t_step_s, "duration_s": duration_s, "height_m": height_m,
        "constellation": constellation if isinstance(constellation, str) else "almanac",
        "algorithm": algorithm, "mask_deg": mask_deg,
        "ism": ism.strip().lower() if isinstance(ism, str) else str(ism_obj),
        "user_model": user_model, "val_m": limits[0], "hal_m": limits[1],
        "emt_max_m": limits[2] if araim else None,
        "sigma_acc_max_m": limits[3] if araim else None,
        "araim_params": {k: v for k, v in araim_params.items()
                         if isinstance(v, (bool, int, float, str))},
        "criteria": (f"VPL <= {limits[0]:g} m, HPL <= {limits[1]:g} m, EMT <= "
                     f"{limits[2]:g} m, sigma_acc <= {limits[3]:g} m" if araim else
                     f"VPL <= {limits[0]:g} m, HPL <= {limits[1]:g} m"),
        "n_satellites": {sy: int(sum(x == sy for x in const.systems)) for sy in systems},
        "unhealthy": unhealthy,
    }
    if not araim:
        settings.update(p_fa=probs[0], p_md=probs[1])
    notes = [] if araim else [
        f"EMT and sigma_acc are ARAIM outputs and do not apply to {algorithm}: available "
        f"means HPL <= HAL and VPL <= VAL ({algorithm} PLs with p_fa {probs[0]:g}, p_md "
        f"{probs[1]:g}, sigma = ARAIM sigma_int)"]
    ledger = None
    if ledger_dir is not None:
        params = {k: settings[k] for k in ("systems", "height_m", "algorithm", "mask_deg",
                                           "user_model", "val_m", "hal_m", "emt_max_m",
                                           "sigma_acc_max_m")}
        params.update(
            version=LEDGER_VERSION, chunk_users=CHUNK_USERS,
            users=_fingerprint(np.stack([lat[idx], lon[idx]])),
            epochs=_fingerprint(t_s), constellation=_constellation_fingerprint(const),
            ism=ism_obj.to_dict(), araim_params=_fingerprint(dict(araim_params)),
            probs=list(probs) if not araim else None)
        ledger = _Ledger(ledger_dir, params, len(chunks), bool(resume))

    stats = {k: np.full(lat.size, np.nan) for k in _STAT_FIELDS}
    total = int(idx.size * t_s.size)
    done = [0]

    def tick(n: int) -> None:
        done[0] += n
        if progress is not None:
            progress(done[0], total)

    def finish(c, part):
        for k, v in part.items():
            stats[k][c] = v

    todo = list(range(len(chunks)))
    if ledger is not None:
        reused = []
        for i in todo:
            part = ledger.load(i, chunks[i])
            if part is not None:
                finish(chunks[i], part)
                reused.append(i)
        todo = [i for i in todo if i not in set(reused)]
        if ledger.fresh_reason:
            notes.append(f"ledger {str(ledger.folder)!r}: started afresh "
                         f"({ledger.fresh_reason})")
        notes.append(f"ledger {str(ledger.folder)!r}: {len(reused)} of {len(chunks)} chunks "
                     f"reused, {len(todo)} computed")
        if reused:
            tick(sum(chunks[i].size for i in reused) * t_s.size)

        def finish_and_save(c, part, i):
            ledger.save(i, c, part)
            finish(c, part)
    else:
        def finish_and_save(c, part, i):
            finish(c, part)

    items = [(i, chunks[i], tasks[i]) for i in todo]
    if dask is not None and items:
        _run_dask(items, finish_and_save, tick, dask, workers)
    elif workers == 1 or len(items) <= 1:
        for i, c, task in items:
            finish_and_save(c, _summarise(*_run_users(task, tick)), i)
    else:
        _run_pool(items, finish_and_save, tick, workers)

    n_epochs = np.where(inside, stats["n_epochs"], 0).astype(int)
    n_avail = np.where(inside, stats["n_available"], 0).astype(int)
    share = np.where(inside, n_avail / np.maximum(n_epochs, 1), np.nan)
    cover = coverage_pct(share, lat, target, inside)
    return AvailabilityResult(
        lat_axis_deg=lat_axis, lon_axis_deg=lon_axis, lat_deg=lat, lon_deg=lon,
        inside=inside, availability=share, n_epochs=n_epochs, n_available=n_avail,
        n_unavailable_geometry=np.where(inside, stats["n_unavailable_geometry"], 0)
        .astype(int),
        vpl_median_m=stats["vpl_median_m"], vpl_p99_m=stats["vpl_p99_m"],
        hpl_median_m=stats["hpl_median_m"], hpl_p99_m=stats["hpl_p99_m"],
        coverage_pct=cover, target=target, settings=settings,
        wall_s=time.perf_counter() - t0, status="ok" if idx.size else "empty",
        notes=tuple(notes))


def _run_pool(items, finish, tick, workers: int) -> None:
    """Chunks on a process pool (:func:`raimcore.studies.montecarlo.run_on_pool`)."""
    run_on_pool(run_chunk, [(item, (item[2],)) for item in items],
                lambda item, res: _done(item, res, finish, tick), workers)


def _run_dask(items, finish, tick, address: str, workers: int) -> None:
    """Chunks on Dask (:func:`raimcore.studies.montecarlo.run_on_dask`)."""
    run_on_dask(run_chunk, [(item, (item[2],)) for item in items],
                lambda item, res: _done(item, res, finish, tick), address, workers,
                option="dask")


def _done(item, result, finish, tick) -> None:
    i, c, t = item
    finish(c, result, i)
    tick(c.size * t.t_s.size)
