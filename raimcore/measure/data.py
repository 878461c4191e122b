"""What the measure stage hands on: :class:`Measurements` (to the algorithm) and
:class:`Truth` (to scoring and display, never to an algorithm).

Shapes follow the package rule: ``E`` epochs, ``S`` satellites of the scenario (not all
used at every epoch: see ``Measurements.used``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Measurements", "Truth", "SAT_AXIS_FIELDS"]


@dataclass(frozen=True)
class Measurements:
    """Everything an algorithm may use about a scenario, all epochs at once: what a
    receiver has (no true position, no knowledge of the injected faults).

    Attributes
    ----------
    t_s : (E,) epoch times, seconds from the scenario start.
    sat_names : (S,) satellite names, e.g. ``"G10"``, ``"C21"``.
    sys_idx : (S,) int system index of each satellite into ``systems``.
    systems : names of the systems, e.g. ``("GPS", "BDS")``.
    pos_sv_ecef_m : (E, S, 3) satellite positions (ECEF, m).
    pr_m : (E, S) pseudoranges (m), NaN where not used.
    used : (E, S) bool, tracked, healthy, above the elevation mask and not restricted.
    az_rad, el_rad : (E, S) azimuth and elevation of each satellite (the receiver knows
        them to far better than a degree from its own fix; they set the mask and the
        elevation error model).
    sigma_m : (E, S) 1-sigma of each pseudorange as the algorithms should assume (m),
        from the scenario's error model (:mod:`raimcore.measure.error_models`).
    noise : the assumed noise model (has ``logpdf``), see :mod:`raimcore.measure.noise`.
    p_fa, p_md : false-alarm and missed-detection probabilities.
    hal_m, val_m : horizontal and vertical alert limits (m).
    seed : the scenario seed; algorithms that need randomness use :meth:`rng`.
    baro_alt_m : (E,) barometric altitude measurement (m, ellipsoidal) or None when off.
    sigma_baro_m : its 1-sigma (m) or None.
    notes : remarks about the data for the user (e.g. satellites of a recording left out).
    error_model : the error model that set ``sigma_m`` (``"uniform"``, ``"elevation"``,
        ``"rtklib"``, ``"broadcast"``, ``"measured"``, ``"araim"``), or None when not named.
    ism : the scenario's ARAIM integrity support message
        (:class:`~raimcore.measure.error_models.Ism`; None: MAAST's example) and
        ``user_model`` its airborne user model (``"add"`` or ``"ed259a"``): what the
        ``araim`` algorithm builds C_int and C_acc from.
    clock_reset : (E,) bool, True where the receiver says its clock restarted since the
        previous epoch (:attr:`raimcore.sky.Sky.clock_reset`: a phone's hardware-clock
        discontinuity, a RINEX "power failure" flag); all False by default (simulated
        skies). The filters re-initialise their clock offsets there instead of testing the
        clock's jump (:func:`raimcore.algorithms.ekf.run_ekf`).
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
    p_fa: float
    p_md: float
    hal_m: float
    val_m: float
    seed: int
    baro_alt_m: np.ndarray | None = None
    sigma_baro_m: float | None = None
    notes: tuple[str, ...] = ()
    error_model: str | None = None
    ism: Any = None
    user_model: str = "add"
    clock_reset: np.ndarray | None = None

    def __post_init__(self):
        flags = (np.zeros(len(self.t_s), dtype=bool) if self.clock_reset is None
                 else np.asarray(self.clock_reset, dtype=bool))
        object.__setattr__(self, "clock_reset", flags)

    @property
    def n_epochs(self) -> int:
        return self.t_s.shape[0]

    @property
    def n_sats(self) -> int:
        return len(self.sat_names)

    def take_sats(self, cols) -> Measurements:
        """The same epochs restricted to the satellites at indices ``cols``."""
        cols = np.asarray(cols, dtype=int)
        changes = {"sat_names": tuple(self.sat_names[c] for c in cols),
                   "sys_idx": self.sys_idx[cols]}
        for name in SAT_AXIS_FIELDS:
            changes[name] = getattr(self, name)[:, cols]
        return dataclasses.replace(self, **changes)

    def take_epochs(self, rows) -> Measurements:
        """The epochs at indices ``rows`` (all satellites)."""
        rows = np.asarray(rows, dtype=int)
        changes = {name: getattr(self, name)[rows] for name in SAT_AXIS_FIELDS}
        changes["t_s"] = self.t_s[rows]
        # A restart anywhere since the previous row taken (rows in time order).
        n_resets = np.concatenate([[0], np.cumsum(self.clock_reset)])
        changes["clock_reset"] = np.diff(n_resets[rows + 1],
                                         prepend=n_resets[rows[:1]]) != 0
        if self.baro_alt_m is not None:
            changes["baro_alt_m"] = self.baro_alt_m[rows]
        return dataclasses.replace(self, **changes)

    def rng(self, stream: int = 0) -> np.random.Generator:
        """A generator for the algorithm's own randomness, independent of the noise draw."""
        return np.random.default_rng(np.random.SeedSequence([int(self.seed), 1000 + stream]))


#: Measurements fields of shape (E, S, ...): a new per-satellite field must be listed here.
SAT_AXIS_FIELDS = ("pos_sv_ecef_m", "pr_m", "used", "az_rad", "el_rad", "sigma_m")


@dataclass(frozen=True)
class Truth:
    """What only the simulation (or the surveyed station) knows: for scoring and display.

    Attributes
    ----------
    pos_rx_ecef_m : (E, 3) true receiver position (m).
    vel_rx_ecef_mps : (E, 3) true receiver velocity (m/s).
    fault_bias_m : (E, S) injected fault biases (m); 0 where no fault acts.
    used : (E, S) the satellites the receiver used (the same as ``Measurements.used``).
    """

    pos_rx_ecef_m: np.ndarray
    vel_rx_ecef_mps: np.ndarray
    fault_bias_m: np.ndarray
    used: np.ndarray

    @property
    def faulted(self) -> np.ndarray:
        """(E, S) bool: a fault acts on a satellite the receiver uses. The one definition
        of "faulted" (a bias on a satellite out of view harms nobody)."""
        return (self.fault_bias_m != 0) & self.used

    @property
    def faulted_epochs(self) -> np.ndarray:
        """(E,) bool: at least one used satellite is faulted."""
        return self.faulted.any(axis=-1)

    def take_sats(self, cols) -> Truth:
        cols = np.asarray(cols, dtype=int)
        return dataclasses.replace(self, fault_bias_m=self.fault_bias_m[:, cols],
                                   used=self.used[:, cols])
