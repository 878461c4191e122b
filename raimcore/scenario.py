"""Scenario descriptions and the engine that turns one into a per-epoch result table.

A :class:`Scenario` is flat: every key is a top-level field, so a TOML file, a CLI
``--set key=value`` and a dashboard control all address the same names. Named scenarios
are TOML files shipped in ``raimcore/scenarios/``. Algorithm options are scenario keys too:
each registered algorithm declares its own (``AlgorithmSpec.options``).

Pipeline: :func:`build_epoch_data` (constellation, trajectory, visibility, noise, faults,
baro) -> ``algorithm.run`` -> :func:`make_table` (errors in the local frame, theoretical
detection probability, truth) -> :class:`ScenarioResult`.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from . import algorithms
from ._validate import check_choice, check_int, check_positive, check_probability, check_range
from .algorithms.base import STATUS_UNAVAILABLE, AlgorithmOutput, EpochData
from .algorithms.parity import _whitened_projector, detection_probability
from .geometry import ecef_to_enu
from .lsq import clock_columns, geometry_rows
from .measure.faults import Fault, fault_biases
from .measure.noise import NOISE_KINDS, make_noise
from .scoring.table import ResultTable
from .sky.constellations import builtin, read_yuma
from .sky.trajectories import TRAJECTORY_KINDS, flight_profile, static, straight_line

__all__ = ["Scenario", "ScenarioResult", "Restrict", "load_scenario", "list_scenarios",
           "build_epoch_data", "run_scenario", "run_algorithm", "make_table", "parse_value",
           "summarize", "unavailable_output"]


@dataclass(frozen=True)
class Restrict:
    """Between ``t0_s`` and ``t1_s`` only the satellites ``sats`` are tracked."""

    sats: tuple[str, ...]
    t0_s: float = 0.0
    t1_s: float = math.inf


@dataclass(frozen=True)
class Scenario:
    """One scenario. All fields are scenario-file / ``--set`` keys (SI units, degrees).

    Constellation and time: ``systems`` (GPS, BDS), ``constellation`` ("nominal" or a
    YUMA almanac path), ``sats`` (subset to use; empty = all), ``rename`` (old -> new name),
    ``t_start_s`` (constellation time at t = 0), ``duration_s``, ``step_s``.
    Receiver: ``trajectory`` (static | line | flight), ``lat_deg``, ``lon_deg``,
    ``height_m``, ``speed_mps``, ``heading_deg``, ``climb_mps`` (line), ``cruise_speed_mps``,
    ``cruise_alt_m``, ``climb_s``, ``turn_start_s``, ``turn_rate_dps``, ``turn_deg``
    (flight); ``clock_drift_mps``.
    Measurements: ``mask_deg``, ``sigma_m``, ``noise`` (gaussian | mixture | student-t),
    ``mixture_eps``, ``mixture_scale``, ``student_nu``, ``noise_corr_s`` (correlation time
    of the noise in s, first-order Gauss-Markov; 0 = white; see :mod:`raimcore.measure.noise`),
    ``faults``, ``restrict``, ``baro``, ``sigma_baro_m``.
    Integrity: ``algorithm``, ``p_fa``, ``p_md``, ``hal_m``, ``val_m``, ``seed``;
    algorithm-specific keys land in ``options``.
    Real recordings (``source = "rinex"``, see :mod:`raimcore.sky.recording`): ``obs``,
    ``nav`` (RINEX paths), ``signals`` (code types, e.g. ``["C1C", "C2I"]``; empty = the
    defaults), ``truth_ecef_m`` (truth for the error columns; empty = the header position);
    ``t_start_s`` / ``duration_s`` / ``step_s`` then cut and thin the recording (t = 0 at
    its first epoch + ``t_start_s``).
    """

    name: str = "custom"
    description: str = ""
    systems: tuple[str, ...] = ("GPS",)
    constellation: str = "nominal"
    sats: tuple[str, ...] = ()
    rename: tuple[tuple[str, str], ...] = ()
    t_start_s: float = 0.0
    duration_s: float = 100.0
    step_s: float = 1.0
    trajectory: str = "static"
    lat_deg: float = 30.67
    lon_deg: float = 104.06
    height_m: float = 500.0
    speed_mps: float = 0.0
    heading_deg: float = 90.0
    climb_mps: float = 0.0
    cruise_speed_mps: float = 230.0
    cruise_alt_m: float = 10000.0
    climb_s: float = 900.0
    turn_start_s: float = 2400.0
    turn_rate_dps: float = 1.5
    turn_deg: float = 180.0
    clock_drift_mps: float = 0.0
    mask_deg: float = 5.0
    sigma_m: float = 33.0
    noise: str = "gaussian"
    mixture_eps: float = 0.1
    mixture_scale: float = 5.0
    student_nu: float = 3.0
    noise_corr_s: float = 0.0
    faults: tuple[Fault, ...] = ()
    restrict: tuple[Restrict, ...] = ()
    baro: bool = False
    sigma_baro_m: float = 50.0
    algorithm: str = "parity"
    p_fa: float = 1e-3
    p_md: float = 1e-3
    hal_m: float = 556.0
    val_m: float = 1000.0
    seed: int = 0
    options: tuple[tuple[str, Any], ...] = ()
    source: str = "sim"
    obs: str = ""
    nav: str = ""
    signals: tuple[str, ...] = ()
    truth_ecef_m: tuple[float, ...] = ()

    def __post_init__(self):
        _validate(self)

    # -- convenience -------------------------------------------------------------------
    def replace(self, **changes) -> Scenario:
        """A copy with ``changes`` applied; keys may be fields or algorithm options."""
        return from_dict({**self.to_dict(), **changes})

    def with_faults(self, *faults: Fault) -> Scenario:
        return dataclasses.replace(self, faults=tuple(faults))

    def option(self, key: str, default=None):
        return dict(self.options).get(key, default)

    def algorithm_options(self) -> dict[str, Any]:
        """The options of the chosen algorithm: its defaults, overridden by this scenario."""
        spec = algorithms.get(self.algorithm)
        return {**dict(spec.options), **{k: v for k, v in self.options if k in spec.options}}

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (TOML-like) form; ``from_dict(s.to_dict()) == s``."""
        d: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "faults":
                v = [x.to_dict() for x in v]
            elif f.name == "restrict":
                v = [{"sats": list(r.sats), "t0_s": r.t0_s,
                      **({"t1_s": r.t1_s} if math.isfinite(r.t1_s) else {})} for r in v]
            elif f.name == "rename":
                v = dict(v)
            elif f.name == "options":
                continue
            elif isinstance(v, tuple):
                v = list(v)
            d[f.name] = v
        d.update(dict(self.options))
        return d


_FIELD_NAMES = {f.name for f in fields(Scenario)}
#: Where the pseudoranges come from: simulated, or a RINEX recording (raimcore.sky.recording).
SOURCES = ("sim", "rinex")


def _option_keys() -> dict[str, Any]:
    keys: dict[str, Any] = {}
    for name in algorithms.names():
        keys.update(algorithms.get(name).options)
    return keys


def from_dict(d: dict[str, Any]) -> Scenario:
    """Build a :class:`Scenario` from a TOML-like dict; unknown keys raise ``ValueError``."""
    d = dict(d)
    opts = dict(d.pop("options", {}) or {})
    known_opts = _option_keys()
    kw: dict[str, Any] = {}
    for key, val in d.items():
        if key in _FIELD_NAMES:
            kw[key] = val
        elif key in known_opts:
            opts[key] = val
        else:
            allowed = sorted(_FIELD_NAMES - {"options"}) + sorted(known_opts)
            raise ValueError(f"unknown scenario key {key!r}; allowed keys: {', '.join(allowed)}")
    bad = [k for k in opts if k not in known_opts]
    if bad:
        raise ValueError(f"unknown algorithm option(s) {', '.join(bad)}; allowed: "
                         f"{', '.join(sorted(known_opts))}")
    if "faults" in kw:
        kw["faults"] = tuple(f if isinstance(f, Fault) else _fault_from_dict(f)
                             for f in kw["faults"])
    if "restrict" in kw:
        kw["restrict"] = tuple(r if isinstance(r, Restrict) else Restrict(
            tuple(r["sats"]), float(r.get("t0_s", 0.0)), float(r.get("t1_s", math.inf)))
            for r in kw["restrict"])
    if "rename" in kw:
        ren = kw["rename"]
        kw["rename"] = tuple(sorted(ren.items() if isinstance(ren, dict) else ren))
    for f in fields(Scenario):  # TOML integers for float fields (duration_s = 100)
        if f.name in kw and isinstance(f.default, float) and isinstance(kw[f.name], int) \
                and not isinstance(kw[f.name], bool):
            kw[f.name] = float(kw[f.name])
    if "truth_ecef_m" in kw:
        kw["truth_ecef_m"] = tuple(float(x) for x in kw["truth_ecef_m"])
    for key in ("systems", "sats", "signals"):
        if key in kw:
            v = kw[key]
            kw[key] = (v,) if isinstance(v, str) else tuple(v)
    kw["options"] = tuple(sorted(opts.items()))
    return Scenario(**kw)


def _fault_from_dict(f: dict) -> Fault:
    allowed = {"sat", "kind", "t0_s", "t1_s", "bias_m", "rate_mps"}
    unknown = set(f) - allowed
    if unknown:
        raise ValueError(f"unknown fault key(s) {', '.join(sorted(unknown))}; allowed: "
                         f"{', '.join(sorted(allowed))}")
    return Fault(**{k: (float(v) if k not in ("sat", "kind") else v) for k, v in f.items()})


def _validate(s: Scenario) -> None:
    for sys_name in s.systems:
        check_choice("systems", sys_name, ("GPS", "BDS"))
    if not s.systems:
        raise ValueError("systems must name at least one of GPS, BDS")
    check_positive("duration_s", s.duration_s, allow_zero=True)
    check_positive("step_s", s.step_s)
    if s.duration_s / s.step_s > 2_000_000:
        raise ValueError("duration_s / step_s must be at most 2,000,000 epochs")
    check_choice("trajectory", s.trajectory, TRAJECTORY_KINDS)
    check_range("lat_deg", s.lat_deg, -90.0, 90.0)
    check_range("lon_deg", s.lon_deg, -180.0, 360.0)
    check_range("mask_deg", s.mask_deg, -10.0, 89.0)
    check_positive("sigma_m", s.sigma_m)
    check_choice("noise", s.noise, NOISE_KINDS)
    check_positive("noise_corr_s", s.noise_corr_s, allow_zero=True)
    check_probability("p_fa", s.p_fa)
    check_probability("p_md", s.p_md)
    check_positive("sigma_baro_m", s.sigma_baro_m)
    check_positive("hal_m", s.hal_m)
    check_positive("val_m", s.val_m)
    check_int("seed", s.seed, 0)
    if not isinstance(s.baro, bool):
        raise ValueError(f"baro must be true or false, got {s.baro!r}")
    check_choice("source", s.source, SOURCES)
    if s.source == "rinex" and not (s.obs and s.nav):
        raise ValueError("source 'rinex' needs obs and nav (RINEX observation and navigation "
                         "file paths)")
    if len(s.truth_ecef_m) not in (0, 3):
        raise ValueError(f"truth_ecef_m must be [] or [x, y, z] in metres, got "
                         f"{list(s.truth_ecef_m)}")
    if s.algorithm not in algorithms.names():
        raise ValueError(f"algorithm must be one of {', '.join(algorithms.names())}; "
                         f"got {s.algorithm!r}")


# -- named scenarios -------------------------------------------------------------------

def _scenario_dir():
    return resources.files("raimcore") / "scenarios"


def list_scenarios() -> dict[str, str]:
    """Names and one-line descriptions of the built-in scenarios."""
    out = {}
    for entry in sorted(_scenario_dir().iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".toml"):
            d = tomllib.loads(entry.read_text())
            out[entry.name[:-5]] = d.get("description", "").strip().splitlines()[0:1]
    return {k: (v[0] if v else "") for k, v in out.items()}


def load_scenario(name_or_path, **overrides) -> Scenario:
    """Load a built-in scenario by name or a TOML file by path, then apply ``overrides``.

    Raises
    ------
    ValueError for an unknown name (listing the built-in ones), a missing file, a TOML
    syntax error (with its position) or an unknown key.
    """
    text, where = _scenario_text(name_or_path)
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{where}: invalid TOML: {exc}") from None
    d.setdefault("name", Path(str(name_or_path)).stem)
    d.update(overrides)
    try:
        return from_dict(d)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


def _scenario_text(name_or_path) -> tuple[str, str]:
    s = str(name_or_path)
    if s.endswith(".toml") or "/" in s or Path(s).exists():
        p = Path(s)
        if not p.is_file():
            raise ValueError(f"scenario file {s!r} does not exist")
        return p.read_text(), str(p)
    entry = _scenario_dir() / f"{s}.toml"
    if not entry.is_file():
        raise ValueError(f"unknown scenario {s!r}; built-in scenarios: "
                         f"{', '.join(list_scenarios())} (or give a path to a .toml file)")
    return entry.read_text(), f"scenario {s}"


def parse_value(text: str):
    """Parse a ``--set`` value as a TOML value (numbers, booleans, arrays), else a string."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


# -- the engine ------------------------------------------------------------------------

def build_epoch_data(s: Scenario) -> EpochData:
    """Simulate every epoch of a scenario: geometry, visibility, pseudoranges, faults.

    Random streams (noise, receiver clock, baro) are spawned from ``s.seed`` with
    ``SeedSequence``, so each is reproducible on its own. ``source = "rinex"`` reads a
    recording instead (:func:`raimcore.sky.recording.recording_epoch_data`).
    """
    if s.source == "rinex":
        from .sky.recording import recording_epoch_data

        return recording_epoch_data(s)
    const = (builtin(s.systems) if s.constellation == "nominal"
             else read_yuma(s.constellation))
    const = const if set(const.systems) <= set(s.systems) else const.subset(
        [n for n, sy in zip(const.names, const.systems, strict=True) if sy in s.systems])
    if s.sats:
        const = const.subset(list(s.sats))
    if s.rename:
        const = const.renamed(dict(s.rename))
    n_ep = int(math.floor(s.duration_s / s.step_s + 1e-9)) + 1
    t = np.arange(n_ep, dtype=float) * s.step_s
    if s.trajectory == "static":
        traj = static(t, s.lat_deg, s.lon_deg, s.height_m)
    elif s.trajectory == "line":
        traj = straight_line(t, s.lat_deg, s.lon_deg, s.height_m, s.speed_mps, s.heading_deg,
                             s.climb_mps)
    else:
        traj = flight_profile(t, s.lat_deg, s.lon_deg, s.height_m, s.heading_deg,
                              s.cruise_speed_mps, s.cruise_alt_m, s.climb_s, s.turn_start_s,
                              s.turn_rate_dps, s.turn_deg)
    sv = const.positions_ecef_m(s.t_start_s + t)
    systems = const.sys_names
    sys_idx = np.array([systems.index(x) for x in const.systems], dtype=int)
    cc = clock_columns(sys_idx, len(systems))
    h_enu, rng_m = geometry_rows(sv, traj.pos_ecef_m, cc, frame="enu")
    el = np.arcsin(np.clip(-h_enu[..., 2], -1.0, 1.0))
    az = np.mod(np.arctan2(-h_enu[..., 0], -h_enu[..., 1]), 2 * np.pi)
    used = (el >= math.radians(s.mask_deg)) & np.asarray(const.healthy)[None, :]
    apply_restrict(used, t, const.names, s.restrict)
    bias = fault_biases(s.faults, t, const.names)
    noise = make_noise(s.noise, s.sigma_m, mixture_eps=s.mixture_eps,
                       mixture_scale=s.mixture_scale, student_nu=s.student_nu,
                       corr_s=s.noise_corr_s)
    ss = np.random.SeedSequence(int(s.seed))
    noise_ss, clock_ss, baro_ss = ss.spawn(3)
    eps = noise.sample(np.random.default_rng(noise_ss), rng_m.shape, t_s=t)
    clk0 = np.random.default_rng(clock_ss).uniform(-3e5, 3e5, len(systems))
    clock = clk0[None, :] + s.clock_drift_mps * t[:, None]
    pr = rng_m + clock @ cc.T + eps + bias
    pr = np.where(used, pr, np.nan)
    baro_alt = None
    if s.baro:
        baro_alt = traj.h_m + s.sigma_baro_m * np.random.default_rng(baro_ss).standard_normal(
            n_ep)
    return EpochData(
        t_s=t, sat_names=tuple(const.names), sys_idx=sys_idx, systems=systems,
        pos_sv_ecef_m=sv, pr_m=pr, used=used, az_rad=az, el_rad=el,
        sigma_m=np.full(pr.shape, s.sigma_m), noise=noise,
        pos_rx_true_ecef_m=traj.pos_ecef_m, vel_rx_true_ecef_mps=traj.vel_ecef_mps,
        fault_bias_m=bias, p_fa=s.p_fa, p_md=s.p_md, seed=int(s.seed),
        baro_alt_m=baro_alt, sigma_baro_m=s.sigma_baro_m if s.baro else None,
        hal_m=s.hal_m, val_m=s.val_m)


def apply_restrict(used, t, sat_names, restrict) -> None:
    """Clear ``used`` (E, S) in place outside each restriction's satellites and window."""
    for r in restrict:
        unknown = [x for x in r.sats if x not in sat_names]
        if unknown:
            raise ValueError(f"restrict: unknown satellite(s) {', '.join(unknown)}")
        window = (t >= r.t0_s) & (t < r.t1_s)
        keep = np.isin(np.array(sat_names), list(r.sats))
        used[window] &= keep[None, :]


@dataclass(frozen=True)
class ScenarioResult:
    """A scenario, its simulated data, the algorithm's raw output and the result table."""

    scenario: Scenario
    data: EpochData
    output: AlgorithmOutput
    table: ResultTable
    summary: dict[str, Any] = field(default_factory=dict)


def _names(mask, sat_names) -> np.ndarray:
    """Per row of a boolean ``(E, S)`` mask, the selected names joined by "+" (object array).

    Rows repeat (the same visible set for minutes), so each distinct row is joined once.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.size == 0:
        return np.full(mask.shape[0], "", dtype=object)
    uniq, inverse = np.unique(mask, axis=0, return_inverse=True)
    joined = np.array(["+".join(n for n, m in zip(sat_names, row, strict=True) if m)
                       for row in uniq], dtype=object)
    return joined[inverse.reshape(-1)]


def run_algorithm(spec, data: EpochData, options: dict[str, Any]) -> AlgorithmOutput:
    """Run ``spec`` on the satellites used at least once, then map back to all of them.

    Satellites never above the mask cannot matter to any algorithm; dropping them first
    makes every per-satellite array (and the S x S projectors) several times smaller.
    """
    cols = np.flatnonzero(data.used.any(axis=0))
    if cols.size == 0:  # no satellite ever used: nothing to run, every epoch unavailable
        return unavailable_output(data)
    small = data.take_sats(cols)
    out = spec.run(small, options)
    check_output(spec.name, small, out)
    return out.expand_sats(cols, data.n_sats)


def unavailable_output(data: EpochData) -> AlgorithmOutput:
    """An output with every epoch "unavailable" (NaN statistics and positions)."""
    e, s = data.n_epochs, data.n_sats
    nan = np.full(e, np.nan)
    return AlgorithmOutput(
        status=np.full(e, STATUS_UNAVAILABLE, dtype=object), statistic=nan, threshold=nan,
        alarm=np.zeros(e, dtype=bool), pos_before_ecef_m=np.full((e, 3), np.nan),
        pos_after_ecef_m=np.full((e, 3), np.nan), excluded=np.zeros((e, s), dtype=bool),
        isolated=np.full(e, -1, dtype=int))


def check_output(name: str, data: EpochData, out: AlgorithmOutput) -> None:
    """Check that algorithm ``name`` kept the output contract (shapes), or raise."""
    e, s = data.n_epochs, data.n_sats
    want = {"status": (e,), "statistic": (e,), "threshold": (e,), "alarm": (e,),
            "pos_before_ecef_m": (e, 3), "pos_after_ecef_m": (e, 3), "excluded": (e, s),
            "isolated": (e,)}
    for key, shape in want.items():
        got = np.shape(getattr(out, key))
        if got != shape:
            raise RuntimeError(f"algorithm {name!r} returned {key} with shape {got}, "
                               f"expected {shape}")
    for group, shape in (("columns", (e,)), ("per_sat", (e, s))):
        for key, val in getattr(out, group).items():
            if np.shape(val) != shape:
                raise RuntimeError(f"algorithm {name!r} returned {group}[{key!r}] with shape "
                                   f"{np.shape(val)}, expected {shape}")


def make_table(data: EpochData, out: AlgorithmOutput) -> ResultTable:
    """The per-epoch result table: algorithm output plus errors and truth."""
    names = np.array(data.sat_names + ("",), dtype=object)
    truth = data.pos_rx_true_ecef_m
    err_b = ecef_to_enu(out.pos_before_ecef_m, truth)
    err_a = ecef_to_enu(out.pos_after_ecef_m, truth)
    faulty = (data.fault_bias_m != 0) & data.used
    # Theoretical detection probability of the snapshot chi-square test for the injected
    # faults, at the true geometry (spec section 1).
    pd = np.full(data.n_epochs, np.nan)
    rows = np.flatnonzero(faulty.any(axis=1))
    if rows.size:
        cols = np.flatnonzero(data.used[rows].any(axis=0))
        used = data.used[np.ix_(rows, cols)]
        cc = clock_columns(data.sys_idx[cols], len(data.systems))
        h, _ = geometry_rows(data.pos_sv_ecef_m[rows][:, cols], truth[rows], cc)
        w = np.where(used, 1.0 / data.sigma_m[np.ix_(rows, cols)] ** 2, 0.0)
        proj, _ = _whitened_projector(h, w)
        n_states = 3 + np.any(used[..., None] & (cc[None] > 0), axis=1).sum(-1)
        dof = used.sum(-1) - n_states
        pd[rows] = detection_probability(proj, data.fault_bias_m[np.ix_(rows, cols)], w, dof,
                                         data.p_fa)
    thr = np.asarray(out.threshold, dtype=float)
    stat = np.asarray(out.statistic, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        normalised = stat / thr
    iso = np.asarray(out.isolated)
    cols = {
        "t_s": data.t_s,
        "n_sat": data.used.sum(-1),
        "status": np.asarray(out.status, dtype=object),
        "statistic": stat,
        "threshold": thr,
        "normalised": normalised,
        "alarm": np.asarray(out.alarm, dtype=bool),
        "isolated": names[np.where(iso >= 0, iso, -1)],
        "excluded": _names(out.excluded, data.sat_names),
        "faulty_truth": _names(faulty, data.sat_names),
        "hpe_before_m": np.hypot(err_b[:, 0], err_b[:, 1]),
        "hpe_after_m": np.hypot(err_a[:, 0], err_a[:, 1]),
        "vpe_before_m": np.abs(err_b[:, 2]),
        "vpe_after_m": np.abs(err_a[:, 2]),
        "pd_theory": pd,
    }
    for k, v in out.columns.items():
        if k in cols:
            raise ValueError(f"algorithm column {k!r} clashes with an engine column")
        cols[k] = np.asarray(v)
    per_sat = {"el_deg": np.degrees(data.el_rad), "az_deg": np.degrees(data.az_rad),
               "used": data.used, "fault_bias_m": data.fault_bias_m,
               "excluded": np.asarray(out.excluded)}
    per_sat.update({k: np.asarray(v) for k, v in out.per_sat.items()})
    return ResultTable(cols, per_sat, data.sat_names)


def summarize(table: ResultTable) -> dict[str, Any]:
    """Headline numbers: first alarm, detection and correct-isolation rates, errors.

    Algorithms with memory (a sliding window, a filter) report it in an optional
    ``memory_epochs`` column: the epochs right after a fault whose memory still holds a
    faulted epoch are neither faulted nor fault-free; they are left out of the
    false-alarm rate and counted as ``fault_memory_epochs``.
    """
    t = table["t_s"]
    faulted = table["faulty_truth"] != ""
    alarm = table["alarm"]
    excl = table["excluded"]
    after = in_fault_memory(faulted, table["memory_epochs"] if "memory_epochs" in table
                             else None)
    nominal = ~faulted & ~after & (table["status"] != "unavailable")
    out: dict[str, Any] = {
        "epochs": len(table),
        "faulted_epochs": int(faulted.sum()),
        "unavailable_epochs": int(np.sum(table["status"] == "unavailable")),
        "false_alarm_rate": float(alarm[nominal].mean()) if nominal.any() else math.nan,
    }
    if after.any():
        out["fault_memory_epochs"] = int(after.sum())
    if faulted.any():
        first = np.flatnonzero(faulted & alarm)
        out["first_fault_t_s"] = float(t[faulted][0])
        out["first_alarm_t_s"] = float(t[first[0]]) if first.size else None
        out["detection_rate"] = float(alarm[faulted].mean())
        out["pd_theory_mean"] = float(np.nanmean(table["pd_theory"][faulted]))
        out["correct_isolation_rate"] = float(np.mean(excl[faulted] == table["faulty_truth"][
            faulted]))
        out["hpe_before_faulted_mean_m"] = float(np.nanmean(table["hpe_before_m"][faulted]))
        out["hpe_after_faulted_mean_m"] = float(np.nanmean(table["hpe_after_m"][faulted]))
    if nominal.any():
        out["hpe_nominal_mean_m"] = float(np.nanmean(table["hpe_before_m"][nominal]))
    # 3-D position RMSE over every epoch with a position (seed 002 Table 1 compares these).
    for when in ("before", "after"):
        e2 = table[f"hpe_{when}_m"].astype(float) ** 2 + table[f"vpe_{when}_m"].astype(float) ** 2
        if np.isfinite(e2).any():
            out[f"rmse_{when}_m"] = float(np.sqrt(np.nanmean(e2)))
    if "n_eff" in table and np.isfinite(table["n_eff"].astype(float)).any():
        out["n_eff_mean"] = float(np.nanmean(table["n_eff"].astype(float)))
    out.update(_summarize_pl(table))
    return out


def in_fault_memory(faulted, memory_epochs) -> np.ndarray:
    """(E,) bool: not faulted, but a faulted epoch lies within the last ``memory_epochs``
    epochs (``memory_epochs`` (E,) ints, or None for memoryless algorithms)."""
    faulted = np.asarray(faulted, dtype=bool)
    if memory_epochs is None or not faulted.any():
        return np.zeros_like(faulted)
    k = np.arange(faulted.size)
    last = np.maximum.accumulate(np.where(faulted, k, -1))
    mem = np.nan_to_num(np.asarray(memory_epochs, dtype=float), nan=1.0)
    return ~faulted & (last >= 0) & (k - last < mem)


def _summarize_pl(table: ResultTable) -> dict[str, Any]:
    """Protection-level headlines for algorithms with ``hpl_m`` / ``vpl_m`` columns (and,
    for solution separation, the ``*_nobaro_m`` variants: how often the baro lowers them)."""
    out: dict[str, Any] = {}
    if "hpl_m" not in table or "vpl_m" not in table:
        return out
    hpl, vpl = table["hpl_m"].astype(float), table["vpl_m"].astype(float)
    if np.isfinite(hpl).any():
        out["hpl_mean_m"] = float(np.nanmean(hpl))
        out["vpl_mean_m"] = float(np.nanmean(vpl))
    if "available" in table:
        out["pl_availability"] = float(np.mean(table["available"].astype(bool)))
    if "vpl_nobaro_m" in table and "baro_used" in table and table["baro_used"].any():
        hpl0, vpl0 = table["hpl_nobaro_m"].astype(float), table["vpl_nobaro_m"].astype(float)
        both = np.isfinite(vpl) & np.isfinite(vpl0)
        if both.any():
            out["baro_vpl_not_higher_share"] = float(np.mean(vpl[both] <= vpl0[both]))
            out["baro_vpl_lower_share"] = float(np.mean(vpl[both] < vpl0[both]))
            out["baro_hpl_lower_share"] = float(np.mean(hpl[both] < hpl0[both]))
    return out


def run_scenario(s: Scenario | str, **overrides) -> ScenarioResult:
    """Run one scenario (an object, a built-in name or a TOML path) end to end."""
    if isinstance(s, str | Path):
        s = load_scenario(s, **overrides)
    elif overrides:
        s = s.replace(**overrides)
    data = build_epoch_data(s)
    out = run_algorithm(algorithms.get(s.algorithm), data, s.algorithm_options())
    table = make_table(data, out)
    return ScenarioResult(s, data, out, table, summarize(table))


def compare_algorithms(s: Scenario | str, names: list[str] | None = None,
                       **overrides) -> list[ScenarioResult]:
    """Run several algorithms on the same measurements (one noise draw, the same faults).

    Parameters
    ----------
    s : a scenario object, a built-in name or a TOML path.
    names : algorithm names (default: every registered algorithm).
    overrides : scenario keys or algorithm options, as for :func:`run_scenario`.

    Returns
    -------
    One :class:`ScenarioResult` per algorithm, in the order of ``names``. An algorithm
    that cannot run on these measurements reports "unavailable" epochs, as in a single run.

    Raises
    ------
    ValueError
        An unknown algorithm name (the message lists the registered ones).
    """
    if isinstance(s, str | Path):
        s = load_scenario(s, **overrides)
    elif overrides:
        s = s.replace(**overrides)
    names = list(algorithms.names() if names is None else names)
    if not names:
        raise ValueError("names must list at least one algorithm")
    specs = [algorithms.get(n) for n in names]  # unknown names fail before any work
    data = build_epoch_data(s)  # the measurements are drawn once, shared by all
    results = []
    for spec in specs:
        sa = dataclasses.replace(s, algorithm=spec.name)
        out = run_algorithm(spec, data, sa.algorithm_options())
        table = make_table(data, out)
        results.append(ScenarioResult(sa, data, out, table, summarize(table)))
    return results
