"""The common interface every RAIM algorithm implements, and the registry.

An algorithm is a module that builds an :class:`AlgorithmSpec` and calls :func:`register`.
The pipeline hands it one :class:`~raimcore.measure.Measurements` (every epoch of a
scenario at once: what a receiver has, never the truth) and its options (validated against
the option keys it declares, defaults filled in), and gets back one
:class:`AlgorithmOutput`. The engine, the CLI and the dashboard find algorithms only through
this registry.

Shapes follow the package rule: batch axes first, components last. ``E`` epochs, ``S``
satellites of the scenario (not all visible at every epoch: see ``Measurements.used``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..measure.data import Measurements
from ..schema import Key, SchemaError, did_you_mean

# Per-epoch status codes, shared by every algorithm (column ``status`` of the result table).
STATUS_OK = "ok"  # detection and isolation available
STATUS_NO_ISOLATION = "detect-only"  # m == n + 1: can detect, cannot isolate
STATUS_UNAVAILABLE = "unavailable"  # too few measurements or singular geometry
STATUS_NOT_ARMED = "not-armed"  # a filter still converging (burn-in), test not armed yet


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
        ``"particles_ecef_m"`` (E, K, 3) and ``"particle_weight"`` (E, K) of ``pf-llr``.
    p_fa : the false-alarm probability per epoch the algorithm's test is built for, when
        it is not the scenario's ``p_fa`` (``araim``: its own budgets); None: the
        scenario's. The summary sets the fault-free alarm share against it, and the run
        notes that the scenario's ``p_fa`` has no effect.
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
    p_fa: float | None = None

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
    summary : one paragraph, plain words (Markdown; symbols as ``$...$`` math), for the
        dashboard's teaching panel.
    equations : the key equations (Markdown with ``$...$`` math) for the teaching panel.
    run : ``run(data: Measurements, options: dict) -> AlgorithmOutput``; ``options`` holds
        every declared option, validated, defaults filled in.
    options : the option keys (:class:`~raimcore.schema.Key`, made with
        :func:`raimcore.schema.option`) this algorithm accepts: declared once, read by the
        scenario check, the CLI, the dashboard and the docs.
    reference : the paper it implements.
    """

    name: str
    label: str
    summary: str
    equations: str
    run: Callable[[Measurements, dict[str, Any]], AlgorithmOutput]
    options: Sequence[Key] = ()
    reference: str = ""

    def __post_init__(self):
        keys = tuple(self.options)
        if any(not isinstance(k, Key) for k in keys):
            raise TypeError(f"algorithm {self.name!r}: options must be schema Keys "
                            "(raimcore.schema.option)")
        object.__setattr__(self, "options", keys)

    @property
    def option_keys(self) -> dict[str, Key]:
        """The option keys by name."""
        return {k.name: k for k in self.options}

    @property
    def defaults(self) -> dict[str, Any]:
        """Every option's default."""
        return {k.name: k.default for k in self.options}

    def resolve_options(self, given: Mapping[str, Any]) -> dict[str, Any]:
        """Defaults overridden by ``given``, each value checked by its key.

        Raises
        ------
        SchemaError
            An option this algorithm does not take (with a "did you mean"), or a value its
            key refuses.
        """
        keys = self.option_keys
        out = self.defaults
        for name, value in given.items():
            if name not in keys:
                allowed = ", ".join(keys) or "none"
                raise SchemaError(f"option {name!r} does not belong to algorithm "
                                  f"{self.name!r}{did_you_mean(name, keys)}; its options: "
                                  f"{allowed}")
            out[name] = keys[name].coerce(value)
        return out


_REGISTRY: dict[str, AlgorithmSpec] = {}


def register(spec: AlgorithmSpec) -> AlgorithmSpec:
    """Add ``spec`` to the registry (re-registering the same name replaces it).

    An option name shared by several algorithms (the process model of ``pf-llr`` and
    ``ekf``) must be declared identically, so that one ``--set`` means one thing.
    """
    for other in _REGISTRY.values():
        if other.name == spec.name:
            continue
        for name, k in spec.option_keys.items():
            o = other.option_keys.get(name)
            if o is not None and o != k:
                raise ValueError(f"algorithm {spec.name!r}: option {name!r} differs from "
                                 f"the one of {other.name!r}; share one declaration")
    _REGISTRY[spec.name] = spec
    return spec


def get(name: str) -> AlgorithmSpec:
    """Return the algorithm called ``name`` or raise ``ValueError`` listing the choices
    (and why a module that failed to load is missing)."""
    from . import _load_all, failed

    _load_all()
    if name not in _REGISTRY:
        why = failed()
        extra = (f" ({name!r} failed to load: {why[name]})" if name in why else
                 did_you_mean(str(name), _REGISTRY))
        raise SchemaError(f"algorithm must be one of {', '.join(names())}; got "
                          f"{name!r}{extra}")
    return _REGISTRY[name]


def names() -> list[str]:
    """Names of all registered algorithms: the built-in ones in the order of
    ``raimcore.algorithms._MODULES`` (whichever module imported them first), then any
    other in registration order."""
    from . import _MODULES, _load_all

    _load_all()
    rank = {f"{__package__}.{m}": k for k, m in enumerate(_MODULES)}
    key = {n: (rank.get(getattr(s.run, "__module__", ""), len(rank)), i)
           for i, (n, s) in enumerate(_REGISTRY.items())}
    return sorted(_REGISTRY, key=key.__getitem__)
