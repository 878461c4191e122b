"""Scenario descriptions: one typed, validated, frozen description of a run.

A :class:`Scenario` is flat: every key is a top-level field, so a TOML file, a CLI
``--set key=value`` and a dashboard control all address the same names. Each field declares
its :class:`~raimcore.schema.Key` (type, default, unit, range, help) once, right here; the
constructor checks every value against it before anything is simulated. Algorithm options
are scenario keys too: each algorithm declares its own (``AlgorithmSpec.options``), and a
scenario takes only the options of its algorithm.

Named scenarios are TOML files shipped in ``raimcore/scenarios/`` (with a Markdown report
beside some of them, :func:`scenario_report`). The run itself is
:func:`raimcore.pipeline.run_scenario`.
"""

from __future__ import annotations

import dataclasses
import math
import os
import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from . import algorithms
from .measure.error_models import (
    ERROR_MODELS,
    MAAST_ISM,
    USER_MODELS,
    Ism,
    ism_help,
    parse_ism,
)
from .measure.faults import Fault
from .measure.noise import NOISE_KINDS
from .schema import (
    Key,
    SchemaError,
    coerce_float,
    coerce_str,
    did_you_mean,
    key,
    keys_of,
)
from .sky.constellations import SYSTEM_PREFIX
from .sky.trajectories import TRAJECTORY_KINDS

__all__ = ["Scenario", "Restrict", "load_scenario", "list_scenarios", "from_dict",
           "parse_value", "scenario_keys", "all_keys", "scenario_report", "report_names",
           "recording_scenario", "SYSTEMS", "SOURCES"]

#: Satellite systems and the first letter of their satellites' names (RINEX 3): GPS,
#: BeiDou, Galileo, GLONASS. Each system has its own receiver clock.
SYSTEMS = SYSTEM_PREFIX
#: Where the pseudoranges come from: simulated, a RINEX recording or an Android GnssLogger
#: log (both raimcore.sky.recording: one chain, two readers of ``obs``).
SOURCES = ("sim", "rinex", "android")
#: Longest run, in epochs (duration_s / step_s).
MAX_EPOCHS = 2_000_000
#: Smallest noise sigma (m) of a scenario: no pseudorange or altimeter is known better than
#: a millimetre, and far smaller values overflow the weights 1 / sigma^2 (1e-300 m) or make
#: a filter's covariance singular (1e-20 m).
SIGMA_MIN_M = 1e-3
#: A receiver position must lie this far from the Earth's centre (m): the surface to
#: beyond the GEO ring, so [0, 0, 0] or a position typed in km is refused.
TRUTH_RADIUS_M = (6.0e6, 5.0e7)


@dataclass(frozen=True)
class Restrict:
    """Between ``t0_s`` and ``t1_s`` only the satellites ``sats`` are tracked."""

    sats: tuple[str, ...]
    t0_s: float = 0.0
    t1_s: float = math.inf

    def __post_init__(self):
        sats = Key("restrict sats", "strings", (), "").coerce(self.sats)
        if not sats:
            raise SchemaError("restrict sats must name at least one satellite")
        object.__setattr__(self, "sats", sats)
        object.__setattr__(self, "t0_s", coerce_float("restrict t0_s", self.t0_s, unit="s"))
        if not (isinstance(self.t1_s, float) and self.t1_s == math.inf):
            object.__setattr__(self, "t1_s", coerce_float("restrict t1_s", self.t1_s,
                                                          unit="s"))
        if self.t1_s <= self.t0_s:
            raise SchemaError(f"restrict t1_s must be after t0_s ({self.t0_s:g}), got "
                              f"{self.t1_s:g}")

    @classmethod
    def from_dict(cls, d, where: str = "restrict") -> Restrict:
        if isinstance(d, Restrict):
            return d
        if not isinstance(d, dict):
            raise SchemaError(f"{where} must be a table such as {{sats = [\"G04\", \"G08\"], "
                              f"t0_s = 0, t1_s = 100}}, got {d!r}")
        unknown = [k for k in d if k not in ("sats", "t0_s", "t1_s")]
        if unknown:
            raise SchemaError(f"{where}: unknown key(s) {', '.join(map(str, unknown))}; "
                              "allowed: sats, t0_s, t1_s")
        if "sats" not in d:
            raise SchemaError(f"{where}: missing sats (the satellites tracked in the window)")
        return cls(**d)

    def to_dict(self) -> dict:
        return {"sats": list(self.sats), "t0_s": self.t0_s,
                **({"t1_s": self.t1_s} if math.isfinite(self.t1_s) else {})}


def _table_list(cls, what: str):
    """A key parser for a list of tables (``[[faults]]``, ``[[restrict]]``), each read by
    ``cls.from_dict``."""
    def parse(name, value):
        if not isinstance(value, list | tuple):
            raise SchemaError(f"{name} must be a list of {what} ([[{name}]] in TOML), got "
                              f"{value!r}"[:200])
        return tuple(cls.from_dict(x, f"{name}[{i}]") for i, x in enumerate(value))
    return parse


_parse_faults = _table_list(Fault, "fault tables")
_parse_restrict = _table_list(Restrict, "tables")


def _parse_rename(name, value):
    pairs = value.items() if isinstance(value, dict) else value
    if isinstance(value, str) or not isinstance(pairs, list | tuple | type({}.items())):
        raise SchemaError(f"{name} must be a table of old = new satellite names, e.g. "
                          f"{{G05 = \"G04\"}}, got {value!r}")
    out = []
    for pair in pairs:
        if not (isinstance(pair, list | tuple) and len(pair) == 2
                and all(isinstance(x, str) and x for x in pair)):
            raise SchemaError(f"{name} must map satellite names to satellite names, got "
                              f"{pair!r}")
        out.append(tuple(pair))
    if len({a for a, _ in out}) != len(out):
        raise SchemaError(f"{name} renames a satellite twice")
    return tuple(sorted(out))


def _parse_truth(name, value):
    if isinstance(value, str) or not isinstance(value, list | tuple | np.ndarray):
        raise SchemaError(f"{name} must be [] or [x, y, z] in metres (ECEF), got {value!r}")
    if len(value) == 0:
        return ()
    if len(value) != 3:
        raise SchemaError(f"{name} must be [] or [x, y, z] in metres (ECEF), got {len(value)} "
                          "values")
    xyz = tuple(coerce_float(f"{name}[{i}]", v, unit="m") for i, v in enumerate(value))
    r = math.sqrt(sum(x * x for x in xyz))
    lo, hi = TRUTH_RADIUS_M
    if not lo <= r <= hi:
        raise SchemaError(f"{name} must be an ECEF position in metres between {lo / 1e3:,.0f} "
                          f"and {hi / 1e3:,.0f} km from the Earth's centre, got "
                          f"{r / 1e3:,.1f} km")
    return xyz


def _parse_times(name, value):
    if isinstance(value, str) or not isinstance(value, list | tuple | np.ndarray):
        raise SchemaError(f"{name} must be a list of times in seconds, e.g. [120, 480], got "
                          f"{value!r}"[:200])
    return tuple(sorted(coerce_float(f"{name}[{i}]", v, 0.0, 1e9, unit="s")
                        for i, v in enumerate(value)))


def _parse_paths(name, value):
    """A file path or a list of file paths -> a tuple of paths; ``""`` and ``[]`` (none
    given) -> ``()``. Whether the files exist is checked when they are read."""
    if isinstance(value, str | os.PathLike):
        value = [value] if os.fspath(value) else []
    if not isinstance(value, list | tuple):
        raise SchemaError(f"{name} must be a file path or a list of file paths, e.g. "
                          f"[\"A_GN.rnx\", \"A_EN.rnx\"], got {value!r}"[:200])
    out = []
    for i, v in enumerate(value):
        v = os.fspath(v) if isinstance(v, os.PathLike) else v
        if not isinstance(v, str) or not v.strip():
            raise SchemaError(f"{name}[{i}] must be a file path, got {v!r}"[:200])
        if v in out:
            raise SchemaError(f"{name}[{i}] lists {v!r} a second time (it is {name}"
                              f"[{out.index(v)}])")
        out.append(v)
    return tuple(out)


def _parse_algorithm(name, value):
    names = algorithms.names()
    if not isinstance(value, str) or value not in names:
        algorithms.get(value if isinstance(value, str) else repr(value))  # names the choices
    return value


def _parse_path_or_nominal(name, value):
    v = coerce_str(name, value)
    if not v.strip():
        raise SchemaError(f"{name} must be \"nominal\" or the path of a YUMA or SEM almanac")
    if v != "nominal" and not Path(v).is_file():
        raise SchemaError(f"{name} must be \"nominal\" or the path of a YUMA or SEM almanac "
                          f"file; {v!r} is not a file")
    return v


def _constellation_names(s) -> tuple[tuple[str, ...], str]:
    """The satellite names of ``s``'s constellation in its systems (before ``sats`` and
    ``rename``) and how to call that constellation in a message. A YUMA or SEM almanac is
    read (and checked, its system told by its orbits) here, so that its errors name the key
    ``constellation``."""
    from .sky.constellations import builtin
    from .sky.simulated import almanac_constellation

    if s.constellation == "nominal":
        return builtin(s.systems).names, f"nominal {'+'.join(s.systems)} constellation"
    try:
        const = almanac_constellation(s.constellation, s.systems)
    except ValueError as exc:
        raise SchemaError(f"constellation: {exc}") from None
    return const.names, f"almanac {s.constellation}"


@dataclass(frozen=True)
class Scenario:
    """One scenario. Every field is a scenario-file / ``--set`` key with its declaration
    (``raim keys`` lists them, with units, ranges and help). SI units, angles in degrees.

    Algorithm options live in ``options`` (``(name, value)`` pairs of the chosen algorithm's
    options; on the command line and in files they are plain keys). ``notes`` (not a key)
    records what loading did that the user should know.

    Raises
    ------
    SchemaError (a ValueError)
        A value its key refuses, an option the algorithm does not take, or keys that do not
        fit together (a satellite not in the chosen systems, ``source = "rinex"`` without
        files); the message names the key, the value and what is allowed.
    """

    name: str = key("custom", "scenario name (shown in outputs)", group="scenario")
    description: str = key("", "one-line description", group="scenario")
    systems: tuple[str, ...] = key(("GPS",), "satellite systems to use", kind="choices",
                                   choices=tuple(SYSTEMS), group="constellation")
    constellation: str = key("nominal", '"nominal" or the path of a YUMA or SEM almanac '
                             '(GPS, Galileo or BeiDou: told by its orbits)',
                             kind="custom", parse=_parse_path_or_nominal,
                             allowed_text='"nominal" or a file path', group="constellation")
    sats: tuple[str, ...] = key((), "satellites to use (empty: all of the systems)",
                                kind="strings", group="constellation")
    rename: tuple[tuple[str, str], ...] = key(
        (), "rename satellites, old = new (to match a paper's PRNs)", kind="custom",
        parse=_parse_rename, allowed_text="table of satellite names", group="constellation")
    t_start_s: float = key(0.0, "constellation time at t = 0 (a recording: the start of "
                           "the cut)", unit="s", lo=0.0, hi=1e9, group="time")
    duration_s: float = key(100.0, "length of the run", unit="s", lo=0.0, hi=1e9,
                            group="time")
    step_s: float = key(1.0, "epoch interval (a recording: thinned to at least this)",
                        unit="s", lo=0.0, lo_open=True, hi=86400.0, group="time")
    trajectory: str = key("static", "receiver motion", kind="choice",
                          choices=TRAJECTORY_KINDS, group="receiver")
    lat_deg: float = key(30.67, "receiver start latitude", unit="deg", lo=-90.0, hi=90.0,
                         group="receiver")
    lon_deg: float = key(104.06, "receiver start longitude", unit="deg", lo=-180.0,
                         hi=360.0, group="receiver")
    height_m: float = key(500.0, "receiver start height (ellipsoidal)", unit="m",
                          lo=-1000.0, hi=1.0e6, group="receiver")
    speed_mps: float = key(0.0, "ground speed (line)", unit="m/s", lo=0.0, hi=1.0e4,
                           group="receiver")
    heading_deg: float = key(90.0, "heading, clockwise from north (line, flight)",
                             unit="deg", lo=-360.0, hi=360.0, group="receiver")
    climb_mps: float = key(0.0, "vertical speed (line)", unit="m/s", lo=-1.0e3, hi=1.0e3,
                           group="receiver")
    cruise_speed_mps: float = key(230.0, "cruise speed (flight)", unit="m/s", lo=0.0,
                                  lo_open=True, hi=1.0e4, group="receiver")
    cruise_alt_m: float = key(10000.0, "cruise altitude (flight)", unit="m", lo=-1000.0,
                              hi=1.0e6, group="receiver")
    climb_s: float = key(900.0, "duration of the climb (flight)", unit="s", lo=0.0,
                         lo_open=True, hi=1e7, group="receiver")
    turn_start_s: float = key(2400.0, "start of the banked turn (flight)", unit="s", lo=0.0,
                              hi=1e9, group="receiver")
    turn_rate_dps: float = key(1.5, "turn rate (flight)", unit="deg/s", lo=0.0,
                               lo_open=True, hi=90.0, group="receiver")
    turn_deg: float = key(180.0, "total turn (flight)", unit="deg", lo=0.0, hi=3600.0,
                          group="receiver")
    clock_drift_mps: float = key(0.0, "receiver clock drift", unit="m/s", lo=-1.0e5,
                                 hi=1.0e5, group="receiver")
    clock_jumps_s: tuple[float, ...] = key(
        (), "times of 1 ms receiver clock jumps (299,792 m on every pseudorange; against "
        "the drift, as a clock-steering receiver)", unit="s", kind="custom",
        parse=_parse_times, allowed_text="list of times in [0, 1e9]", group="receiver")
    mask_deg: float = key(5.0, "elevation mask", unit="deg", lo=-10.0, hi=89.0,
                          ui_lo=0.0, ui_hi=40.0, ui_step=1.0, group="measurements")
    sigma_m: float = key(33.0, "pseudorange noise 1-sigma: everywhere (error_model "
                         "uniform) or at the zenith (elevation; a recording's auto)",
                         unit="m", lo=SIGMA_MIN_M, hi=1.0e4, ui_lo=0.1, ui_hi=50.0,
                         ui_step=0.1, group="measurements")
    noise: str = key("gaussian", "noise distribution", kind="choice", choices=NOISE_KINDS,
                     group="measurements")
    mixture_eps: float = key(0.1, "outlier share of the Gaussian mixture", lo=0.0,
                             lo_open=True, hi=1.0, hi_open=True, group="measurements")
    mixture_scale: float = key(5.0, "outlier sigma / core sigma of the mixture", lo=0.0,
                               lo_open=True, hi=1.0e3, group="measurements")
    student_nu: float = key(3.0, "degrees of freedom of the Student-t noise", lo=0.0,
                            lo_open=True, hi=1.0e6, group="measurements")
    noise_corr_s: float = key(0.0, "noise correlation time (first-order Gauss-Markov); "
                              "0 = white", unit="s", lo=0.0, hi=1.0e6, ui_lo=0.0,
                              ui_hi=3600.0, ui_step=5.0, group="measurements")
    error_model: str = key("auto", "pseudorange 1-sigma per satellite, assumed by the "
                           "algorithms and drawn by a simulation: uniform (sigma_m), "
                           "elevation (sigma_m at the zenith), rtklib, broadcast (URA + "
                           "tropo + multipath), measured (fitted on a recording), araim "
                           "(ism URE + tropo + user_model); auto: araim under algorithm "
                           "araim, else uniform simulated, elevation on a recording",
                           kind="choice", choices=ERROR_MODELS, group="measurements")
    user_model: str = key("add", "ARAIM airborne multipath + noise (error_model araim, "
                          "algorithm araim): add (ADD / B2012: GPS curve x 2.5883, Galileo "
                          "table) or ed259a (MAAST v5, every system)", kind="choice",
                          choices=USER_MODELS, group="measurements")
    ism: Ism = key(MAAST_ISM, ism_help(), kind="custom", parse=parse_ism,
                   allowed_text='"maast" or a table of systems', group="integrity")
    faults: tuple[Fault, ...] = key((), "injected faults: [[faults]] tables (sat, kind "
                                    "step|ramp, t0_s, t1_s, bias_m | rate_mps); sat a "
                                    "system key (\"GAL\"): a constellation fault, each of "
                                    "its satellites biased by bias x sin(elevation), also "
                                    "written {kind = \"constellation\", system, shape "
                                    "step|ramp, ...}",
                                    kind="custom", parse=_parse_faults,
                                    allowed_text="list of fault tables", group="faults")
    restrict: tuple[Restrict, ...] = key((), "windows tracking only some satellites: "
                                         "[[restrict]] tables (sats, t0_s, t1_s)",
                                         kind="custom", parse=_parse_restrict,
                                         allowed_text="list of tables",
                                         group="measurements")
    baro: bool = key(False, "add a barometric altimeter", group="measurements")
    sigma_baro_m: float = key(50.0, "barometric altitude 1-sigma", unit="m",
                              lo=SIGMA_MIN_M, hi=1.0e4, group="measurements")
    algorithm: str = key("parity", "integrity algorithm (raim list)", kind="custom",
                         parse=_parse_algorithm, allowed_text="a registered algorithm",
                         group="integrity")
    p_fa: float = key(1e-3, "false-alarm probability", lo=0.0, hi=1.0, lo_open=True,
                      hi_open=True, group="integrity")
    p_md: float = key(1e-3, "missed-detection probability", lo=0.0, hi=1.0, lo_open=True,
                      hi_open=True, group="integrity")
    hal_m: float = key(556.0, "horizontal alert limit", unit="m", lo=0.0, lo_open=True,
                       hi=1.0e6, group="integrity")
    val_m: float = key(1000.0, "vertical alert limit", unit="m", lo=0.0, lo_open=True,
                       hi=1.0e6, group="integrity")
    seed: int = key(0, "random seed (same seed, same result)", lo=0, hi=2**32 - 1,
                    group="integrity")
    source: str = key("sim", "where the pseudoranges come from", kind="choice",
                      choices=SOURCES, group="recording")
    obs: str = key("", "observation file: RINEX (source rinex) or an Android GnssLogger "
                   "raw log (source android)", group="recording")
    nav: tuple[str, ...] = key((), "RINEX navigation file(s) of a recording: a path or a "
                               "list of paths (e.g. one per system), merged", kind="custom",
                               parse=_parse_paths, allowed_text="path or list of paths",
                               group="recording")
    signals: tuple[str, ...] = key((), "observation codes to use, e.g. [\"C1C\", \"C2I\"] "
                                   "(empty: the defaults; each corrected with its own "
                                   "broadcast group delay, or a note where the records "
                                   "carry none)", kind="strings", group="recording")
    truth_ecef_m: tuple[float, ...] = key((), "true receiver position [x, y, z] of a "
                                          "recording (empty: the header position)",
                                          unit="m", kind="custom", parse=_parse_truth,
                                          allowed_text="[] or [x, y, z]", group="recording")
    options: tuple[tuple[str, Any], ...] = ()
    notes: tuple[str, ...] = dataclasses.field(default=(), compare=False)

    def __post_init__(self):
        set_ = object.__setattr__
        for name, k in SCENARIO_KEYS.items():
            set_(self, name, k.coerce(getattr(self, name)))
        spec = algorithms.get(self.algorithm)
        given = self.options.items() if isinstance(self.options, dict) else self.options
        try:
            given = dict(given)
        except (TypeError, ValueError):
            raise SchemaError(f"options must be a table of algorithm options, got "
                              f"{self.options!r}") from None
        resolved = spec.resolve_options(given)
        set_(self, "options", tuple(sorted((k, resolved[k]) for k in given)))
        set_(self, "notes", tuple(self.notes))
        _check_together(self)

    # -- convenience -------------------------------------------------------------------
    def replace(self, **changes) -> Scenario:
        """A copy with ``changes`` applied; keys may be fields or algorithm options.

        Changing ``algorithm`` drops the options of the previous algorithm that the new one
        does not take (they would not mean anything to it); options given in ``changes``
        must belong to the new algorithm.
        """
        d = self.to_dict()
        if "algorithm" in changes and changes["algorithm"] != self.algorithm:
            new_keys = algorithms.get(_parse_algorithm("algorithm", changes["algorithm"])
                                      ).option_keys
            for name, _ in self.options:
                if name not in new_keys:
                    d.pop(name, None)
        d.update(changes)
        return from_dict(d, notes=self.notes)

    @property
    def recorded(self) -> bool:
        """True when the pseudoranges are recorded (``source`` "rinex" or "android")."""
        return self.source != "sim"

    def with_faults(self, *faults: Fault) -> Scenario:
        return dataclasses.replace(self, faults=tuple(faults))

    def option(self, key: str, default=None):
        return dict(self.options).get(key, default)

    def algorithm_options(self) -> dict[str, Any]:
        """Every option of the chosen algorithm: its defaults, overridden by this scenario."""
        return algorithms.get(self.algorithm).resolve_options(dict(self.options))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict (TOML-like) form; ``from_dict(s.to_dict()) == s``."""
        d: dict[str, Any] = {}
        for f in fields(self):
            if f.name in ("options", "notes"):
                continue
            v = getattr(self, f.name)
            if f.name in ("faults", "restrict"):
                v = [x.to_dict() for x in v]
            elif f.name == "rename":
                v = dict(v)
            elif f.name == "ism":
                v = v.to_dict()
            elif isinstance(v, tuple):
                v = list(v)
            d[f.name] = v
        d.update(dict(self.options))
        return d


#: The scenario keys, from the field declarations above (name -> Key).
SCENARIO_KEYS: dict[str, Key] = keys_of(Scenario)


def scenario_keys() -> dict[str, Key]:
    """The scenario keys (name -> :class:`~raimcore.schema.Key`)."""
    return dict(SCENARIO_KEYS)


def all_keys() -> dict[str, Key]:
    """Scenario keys and every registered algorithm's options (name -> Key)."""
    out = dict(SCENARIO_KEYS)
    for name in algorithms.names():
        for k in algorithms.get(name).options:
            out.setdefault(k.name, dataclasses.replace(k, group=k.group or name))
    return out


def _option_owners() -> dict[str, list[str]]:
    owners: dict[str, list[str]] = {}
    for name in algorithms.names():
        for k in algorithms.get(name).options:
            owners.setdefault(k.name, []).append(name)
    return owners


def _check_together(s: Scenario) -> None:
    """Checks that involve several keys (each key alone is already valid)."""
    if not s.systems:
        raise SchemaError(f"systems must name at least one of {', '.join(SYSTEMS)}")
    if len(set(s.systems)) != len(s.systems):
        raise SchemaError(f"systems lists a system twice: {list(s.systems)}")
    if s.duration_s / s.step_s > MAX_EPOCHS:
        raise SchemaError(f"duration_s / step_s must be at most {MAX_EPOCHS:,} epochs, got "
                          f"{s.duration_s:g} / {s.step_s:g}")
    if s.recorded and not (s.obs and s.nav):
        what = "a GnssLogger log" if s.source == "android" else "a RINEX observation file"
        raise SchemaError(f"source \"{s.source}\" needs obs and nav ({what} and RINEX "
                          "navigation file paths)" + ("; nav names no file" if s.obs
                                                      else ""))
    if s.source == "sim" and (s.obs or s.nav or s.signals or s.truth_ecef_m):
        used = [k for k in ("obs", "nav", "signals", "truth_ecef_m") if getattr(s, k)]
        raise SchemaError(f"{', '.join(used)} apply to recordings only (source = \"rinex\" "
                          f"or \"android\"); this scenario is simulated")
    if s.source == "sim" and s.error_model == "measured":
        raise SchemaError("error_model \"measured\" fits the errors of a recording (source "
                          "= \"rinex\" or \"android\"); a simulated scenario has none: "
                          "choose auto, uniform, elevation, rtklib, broadcast or araim")
    letters = {SYSTEMS[x] for x in s.systems}
    for f in s.faults:
        if f.system is not None and f.system not in s.systems:
            raise SchemaError(f"faults: constellation fault {f.sat}: {f.sat} is not one of "
                              f"this scenario's systems ({', '.join(s.systems)})")
    for where, names in (("sats", s.sats),
                         ("faults", [f.sat for f in s.faults if f.system is None]),
                         ("restrict", [x for r in s.restrict for x in r.sats])):
        for n in names:
            if n[:1] not in letters:
                raise SchemaError(f"{where}: satellite {n!r} is not of the chosen systems "
                                  f"({', '.join(s.systems)}: names start with "
                                  f"{', '.join(sorted(letters))})")
    if s.source == "sim":
        _check_satellites(s)


def _check_satellites(s: Scenario) -> None:
    """``sats``, ``rename``, ``faults`` and ``restrict`` against the constellation of a
    simulated scenario: every name exists, no two satellites end up with one name."""
    base, what = _constellation_names(s)
    bad = [n for n in s.sats if n not in base]  # sats are chosen before renaming
    if bad:
        raise SchemaError(f"sats: satellite(s) {', '.join(bad)} not in the {what}"
                          f"{did_you_mean(bad[0], base)}")
    if len(set(s.sats)) != len(s.sats):
        twice = sorted({n for n in s.sats if s.sats.count(n) > 1})
        raise SchemaError(f"sats lists {', '.join(twice)} twice")
    pool = s.sats or base
    mapping = dict(s.rename)
    missing = [a for a in mapping if a not in pool]
    if missing:
        raise SchemaError(f"rename: satellite(s) {', '.join(missing)} not "
                          + (f"among sats ({', '.join(s.sats)})" if s.sats else
                             f"in the {what}") + did_you_mean(missing[0], pool))
    known = [mapping.get(n, n) for n in pool]
    clash = sorted({n for n in known if known.count(n) > 1})
    if clash:
        pairs = ", ".join(f"{a} = {b!r}" for a, b in s.rename if b in clash)
        raise SchemaError(f"rename {{{pairs}}} gives two satellites the name(s) "
                          f"{', '.join(clash)}; rename the satellite that has that name too, "
                          "or choose another name")
    for where, names in (("faults", [f.sat for f in s.faults if f.system is None]),
                         ("restrict", [x for r in s.restrict for x in r.sats])):
        bad = [n for n in names if n not in known]
        if bad:
            raise SchemaError(f"{where}: satellite(s) {', '.join(bad)} not in this "
                              f"scenario's satellites ({', '.join(known)})"
                              if s.sats else
                              f"{where}: satellite(s) {', '.join(bad)} not in the {what}"
                              f"{did_you_mean(bad[0], known)}")


def from_dict(d: dict[str, Any], notes: tuple[str, ...] = ()) -> Scenario:
    """Build a :class:`Scenario` from a TOML-like dict: scenario keys and the algorithm's
    options side by side (or under ``options``). Unknown keys raise with a "did you mean".
    """
    if not isinstance(d, dict):
        raise SchemaError(f"a scenario must be a table of keys, got {type(d).__name__}")
    d = dict(d)
    opts = d.pop("options", {}) or {}
    if not isinstance(opts, dict):
        raise SchemaError(f"options must be a table of algorithm options, got {opts!r}")
    opts = dict(opts)
    owners = _option_owners()
    kw: dict[str, Any] = {}
    for k, val in d.items():
        if k in SCENARIO_KEYS:
            kw[k] = val
        elif k in owners:
            opts[k] = val
        else:
            raise SchemaError(f"unknown scenario key {k!r}"
                              f"{did_you_mean(str(k), [*SCENARIO_KEYS, *owners])}; "
                              f"'raim keys' lists every key")
    algorithm = kw.get("algorithm", SCENARIO_KEYS["algorithm"].default)
    spec = algorithms.get(algorithm) if isinstance(algorithm, str) else None
    if spec is not None:
        for k in opts:
            if k not in spec.option_keys:
                takers = ", ".join(owners.get(k, [])) or "no algorithm"
                raise SchemaError(f"option {k!r} does not belong to algorithm "
                                  f"{algorithm!r} (it is an option of {takers}); "
                                  f"{algorithm}'s options: "
                                  f"{', '.join(spec.option_keys) or 'none'}")
    kw["options"] = opts
    return Scenario(**kw, notes=tuple(notes))


# -- named scenarios -------------------------------------------------------------------

def _scenario_dir():
    return resources.files("raimcore") / "scenarios"


def list_scenarios() -> dict[str, str]:
    """Names and one-line descriptions of the built-in scenarios."""
    out = {}
    for entry in sorted(_scenario_dir().iterdir(), key=lambda p: p.name):
        if entry.name.endswith(".toml"):
            d = tomllib.loads(entry.read_text())
            lines = d.get("description", "").strip().splitlines()
            out[entry.name[:-5]] = lines[0] if lines else ""
    return out


def recording_scenario(obs, nav, **overrides) -> Scenario:
    """A :class:`Scenario` for a recording with real-data defaults: every system the
    observation file has (of GPS, BDS, GAL, GLO), the whole recording at its own interval,
    a 10-degree mask and ``sigma_m`` 1 m (a RINEX file of a geodetic receiver), or
    ``error_model`` "measured" and ``sigma_m`` 5 m (a phone's GnssLogger log); ``overrides``
    are scenario keys.

    ``obs`` is a RINEX observation file or a GnssLogger log (``source`` "rinex" or
    "android": from ``overrides``, else told by the file's content), ``nav`` a navigation
    file or a list of them (merged, e.g. an IGS station's ``_GN``, ``_EN``, ``_CN`` and
    ``_RN`` files); plain or compressed (gzip, ``.Z``, zip, Hatanaka ``.crx``)."""
    from .sky.recording import recording_keys

    source = overrides.get("source")
    if source is not None:
        SCENARIO_KEYS["source"].coerce(source)  # the key's own message for a bad one
        if source == "sim":
            raise SchemaError("source \"sim\" is not a recording: a recording scenario "
                              "takes source \"rinex\" or \"android\"")
    d = {**recording_keys(obs, source), "nav": nav}  # nav: a path or a list of paths
    d.update(overrides)
    return from_dict(d)


def report_names() -> list[str]:
    """The reports shipped without a scenario file (``scenarios/NAME.md`` with no
    ``NAME.toml``: the real-data reports ``recordings`` and ``android``)."""
    d = _scenario_dir()
    return sorted(e.name[:-3] for e in d.iterdir() if e.name.endswith(".md")
                  and not (d / f"{e.name[:-3]}.toml").is_file())


def scenario_report(name: str) -> str | None:
    """The Markdown report beside a built-in scenario (``scenarios/NAME.md``), or None."""
    entry = _scenario_dir() / f"{name}.md"
    return entry.read_text() if entry.is_file() else None


def load_scenario(name_or_path, **overrides) -> Scenario:
    """Load a built-in scenario by name or a TOML file by path, then apply ``overrides``.

    When ``overrides`` choose another algorithm, options of the file that the new
    algorithm does not take are left out, and the scenario's ``notes`` say so.

    Raises
    ------
    ValueError for an unknown name (listing the built-in ones), a missing file, a TOML
    syntax error (with its position), an unknown key or a value its key refuses.
    """
    text, where = _scenario_text(name_or_path)
    try:
        d = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SchemaError(f"{where}: invalid TOML: {exc}") from None
    d.setdefault("name", Path(str(name_or_path)).stem)
    notes = []
    new_alg = overrides.get("algorithm")
    if new_alg is not None and new_alg != d.get("algorithm") and isinstance(new_alg, str) \
            and new_alg in algorithms.names():
        owners = _option_owners()
        takes = algorithms.get(new_alg).option_keys
        dropped = [k for k in d if k in owners and k not in SCENARIO_KEYS and k not in takes
                   and k not in overrides]
        for k in dropped:
            d.pop(k)
        if dropped:
            notes.append(f"{where} sets {', '.join(dropped)} for {d.get('algorithm')}; "
                         f"{new_alg} does not take them: left out")
    d.update(overrides)
    try:
        return from_dict(d, notes=tuple(notes))
    except ValueError as exc:
        raise SchemaError(f"{where}: {exc}") from None


def _scenario_text(name_or_path) -> tuple[str, str]:
    s = str(name_or_path)
    if s.endswith(".toml") or "/" in s or Path(s).exists():
        p = Path(s)
        if not p.is_file():
            raise SchemaError(f"scenario file {s!r} does not exist")
        try:
            return p.read_text(), str(p)
        except (OSError, UnicodeDecodeError) as exc:
            raise SchemaError(f"scenario file {s!r} cannot be read: {exc}") from None
    entry = _scenario_dir() / f"{s}.toml"
    if not entry.is_file():
        names = list(list_scenarios())
        raise SchemaError(f"unknown scenario {s!r}{did_you_mean(s, names)}; built-in "
                          f"scenarios: {', '.join(names)} (or give a path to a .toml file)")
    return entry.read_text(), f"scenario {s}"


def parse_value(text: str):
    """Parse a ``--set`` value as a TOML value (numbers, booleans, arrays, tables), else a
    string. ``nan`` and ``inf`` are parsed as numbers (and then refused by the key)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
