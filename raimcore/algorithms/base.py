"""The common interface every RAIM algorithm implements, and the registry.

An algorithm is a module that builds an :class:`AlgorithmSpec` and calls :func:`register`.
The scenario engine hands it one :class:`EpochData` (every epoch of a scenario at once) and
its options, and gets back one :class:`AlgorithmOutput`. The engine, the CLI and the
dashboard find algorithms only through this registry.

Shapes follow the package rule: batch axes first, components last. ``E`` epochs, ``S``
satellites of the scenario (not all visible at every epoch: see ``EpochData.used``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

# Per-epoch status codes, shared by every algorithm (column ``status`` of the result table).
STATUS_OK = "ok"  # detection and isolation available
STATUS_NO_ISOLATION = "detect-only"  # m == n + 1: can detect, cannot isolate
STATUS_UNAVAILABLE = "unavailable"  # too few measurements or singular geometry
STATUS_NOT_ARMED = "not-armed"  # a filter still converging (burn-in), test not armed yet


@dataclass(frozen=True)
class EpochData:
    """Everything an algorithm may use about a scenario, all epochs at once.

    Attributes
    ----------
    t_s : (E,) epoch times, seconds from the scenario start.
    sat_names : (S,) satellite names, e.g. ``"G10"``, ``"C21"``.
    sys_idx : (S,) int system index of each satellite into ``systems``.
    systems : names of the systems, e.g. ``("GPS", "BDS")``.
    pos_sv_ecef_m : (E, S, 3) satellite positions (ECEF, m).
    pr_m : (E, S) pseudoranges (m), NaN where not tracked.
    used : (E, S) bool, tracked and above the elevation mask.
    az_rad, el_rad : (E, S) azimuth and elevation from the true receiver position.
    sigma_m : (E, S) 1-sigma of each pseudorange as the algorithms should assume (m).
    noise : the noise model that generated the pseudoranges (has ``logpdf``), see
        :mod:`raimcore.measure.noise`.
    pos_rx_true_ecef_m : (E, 3) true receiver position (m), for errors only.
    vel_rx_true_ecef_mps : (E, 3) true receiver velocity (m/s).
    fault_bias_m : (E, S) injected fault biases (truth, m); 0 where no fault.
    baro_alt_m : (E,) barometric altitude measurement (m, ellipsoidal) or None when off.
    sigma_baro_m : its 1-sigma (m) or None.
    p_fa, p_md : false-alarm and missed-detection probabilities.
    seed : the scenario seed; algorithms that need randomness use :meth:`rng`.
    notes : remarks about the data for the user (e.g. satellites of a recording left out).
    """

    t_s: np.ndarray
    sat_names: tuple[str, ...]
    sys_idx: np.ndarray
    systems: tuple[str, ...]
    pos_sv_ecef_m: np.ndarray
    pr_m: np.ndarray
    used: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    sigma_m: np.ndarray
    noise: Any
    pos_rx_true_ecef_m: np.ndarray
    vel_rx_true_ecef_mps: np.ndarray
    fault_bias_m: np.ndarray
    p_fa: float
    p_md: float
    seed: int
    baro_alt_m: np.ndarray | None = None
    sigma_baro_m: float | None = None
    hal_m: float = 40.0
    val_m: float = 50.0
    notes: tuple[str, ...] = ()

    @property
    def n_epochs(self) -> int:
        return self.t_s.shape[0]

    @property
    def n_sats(self) -> int:
        return len(self.sat_names)

    def take_sats(self, cols) -> EpochData:
        """The same epochs restricted to the satellites at indices ``cols``."""
        cols = np.asarray(cols, dtype=int)
        changes = {"sat_names": tuple(self.sat_names[c] for c in cols),
                   "sys_idx": self.sys_idx[cols]}
        for name in SAT_AXIS_FIELDS:
            changes[name] = getattr(self, name)[:, cols]
        return dataclasses.replace(self, **changes)

    def rng(self, stream: int = 0) -> np.random.Generator:
        """A generator for the algorithm's own randomness, independent of the noise draw."""
        return np.random.default_rng(np.random.SeedSequence([int(self.seed), 1000 + stream]))


#: EpochData fields of shape (E, S, ...): a new per-satellite field must be listed here.
SAT_AXIS_FIELDS = ("pos_sv_ecef_m", "pr_m", "used", "az_rad", "el_rad", "sigma_m",
                   "fault_bias_m")


@dataclass(frozen=True)
class AlgorithmOutput:
    """What an algorithm returns for all epochs of a scenario.

    Attributes
    ----------
    status : (E,) str, one of the ``STATUS_*`` codes.
    statistic, threshold : (E,) the detection statistic and its threshold (NaN when
        unavailable); ``alarm`` is ``statistic > threshold`` (or the algorithm's own rule).
    alarm : (E,) bool.
    pos_before_ecef_m : (E, 3) position from all used measurements (NaN if unavailable).
    pos_after_ecef_m : (E, 3) position after exclusion (equal to before when nothing was
        excluded).
    excluded : (E, S) bool, satellites the algorithm excluded at that epoch.
    isolated : (E,) int, index of the satellite the algorithm names as faulty (its best
        candidate, also when it does not exclude), -1 for none.
    per_sat : extra per-satellite arrays (E, S), e.g. ``"isolation"`` (the isolation
        statistic of each satellite, NaN where unused), ``"isolability"``.
    columns : extra per-epoch columns (E,), e.g. ``"hpl_m"``, ``"vpl_m"``, ``"n_eff"``.
    extras : other per-epoch arrays (E, ...) for displays, not in the result table, e.g.
        ``"particles_enu_m"`` (E, K, 3) and ``"particle_weight"`` (E, K) of ``pf-llr``.
    """

    status: np.ndarray
    statistic: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    pos_before_ecef_m: np.ndarray
    pos_after_ecef_m: np.ndarray
    excluded: np.ndarray
    isolated: np.ndarray
    per_sat: Mapping[str, np.ndarray] = field(default_factory=dict)
    columns: Mapping[str, np.ndarray] = field(default_factory=dict)
    extras: Mapping[str, np.ndarray] = field(default_factory=dict)

    def expand_sats(self, cols, n_sats: int) -> AlgorithmOutput:
        """Map an output computed on the satellites ``cols`` back to ``n_sats`` satellites.

        Satellites not in ``cols`` get ``False`` (excluded), NaN (float arrays), ``""``
        (strings) in the per-satellite arrays; ``isolated`` indices are translated.
        """
        cols = np.asarray(cols, dtype=int)

        def widen(a):
            a = np.asarray(a)
            if a.dtype == bool:
                fill = False
            elif a.dtype.kind in "fc":
                fill = np.nan
            elif a.dtype.kind in "iu":
                fill = -1
            else:
                fill = ""
            full = np.full((a.shape[0], n_sats) + a.shape[2:], fill, dtype=a.dtype)
            full[:, cols] = a
            return full

        iso = np.asarray(self.isolated)
        return dataclasses.replace(
            self, excluded=widen(self.excluded),
            isolated=np.where(iso >= 0, cols[np.maximum(iso, 0)], -1),
            per_sat={k: widen(v) for k, v in self.per_sat.items()})


@dataclass(frozen=True)
class AlgorithmSpec:
    """A registered algorithm.

    Attributes
    ----------
    name : short key used on the CLI and in scenario files (``"parity"``).
    label : human name for menus.
    summary : one paragraph, plain words, for the dashboard's teaching panel.
    equations : the key equations (Markdown with ``$...$`` math) for the teaching panel.
    run : ``run(data: EpochData, options: dict) -> AlgorithmOutput``.
    options : option names and defaults this algorithm accepts (scenario keys).
    reference : the paper it implements.
    """

    name: str
    label: str
    summary: str
    equations: str
    run: Callable[[EpochData, dict[str, Any]], AlgorithmOutput]
    options: Mapping[str, Any] = field(default_factory=dict)
    reference: str = ""


_REGISTRY: dict[str, AlgorithmSpec] = {}


def register(spec: AlgorithmSpec) -> AlgorithmSpec:
    """Add ``spec`` to the registry (re-registering the same name replaces it)."""
    _REGISTRY[spec.name] = spec
    return spec


def get(name: str) -> AlgorithmSpec:
    """Return the algorithm called ``name`` or raise ``ValueError`` listing the choices."""
    from . import _load_all

    _load_all()
    if name not in _REGISTRY:
        raise ValueError(f"algorithm must be one of {', '.join(sorted(_REGISTRY))}; got {name!r}")
    return _REGISTRY[name]


def names() -> list[str]:
    """Names of all registered algorithms, in registration order."""
    from . import _load_all

    _load_all()
    return list(_REGISTRY)
