"""Stage 1 of the pipeline, sky sources: where the satellites and the receiver are.

A sky source turns a scenario into a :class:`Sky`: epoch times, satellite positions, the
true receiver trajectory and which satellites could be tracked. Two sources:

- :mod:`raimcore.sky.simulated`: nominal GPS, BeiDou, Galileo and GLONASS constellations or
  a YUMA or SEM almanac (:mod:`~raimcore.sky.constellations`) and a trajectory
  (:mod:`~raimcore.sky.trajectories`);
- :mod:`raimcore.sky.recording`: a RINEX recording or an Android GnssLogger log
  (:mod:`~raimcore.sky.android`) and one or more navigation files
  (:mod:`~raimcore.sky.rinex`, broadcast
  ephemerides :mod:`~raimcore.sky.ephemeris`, corrections :mod:`~raimcore.sky.spp`), whose
  real pseudoranges come with it.

The next stage, :func:`raimcore.measure.measure`, makes the measurements from a sky.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Sky", "build_sky"]


@dataclass(frozen=True)
class Sky:
    """What a sky source gives the measure stage (``E`` epochs, ``S`` satellites).

    Attributes
    ----------
    t_s : (E,) epoch times, seconds from the scenario start.
    sat_names, sys_idx, systems : satellite names, their system index, the system names.
    pos_sv_ecef_m : (E, S, 3) satellite positions (ECEF, m).
    pos_rx_ecef_m, vel_rx_ecef_mps : (E, 3) true receiver position and velocity.
    h_rx_m : (E,) true ellipsoidal height of the receiver (m; the altimeter measures it).
    range_m : (E, S) true geometric ranges (m).
    az_rad, el_rad : (E, S) azimuth and elevation seen from the true position.
    trackable : (E, S) bool, healthy and tracked (before mask and restrictions).
    pr_m : (E, S) real corrected pseudoranges of a recording (NaN where absent), or None
        for a simulated sky (the measure stage draws them).
    notes : what the source wants the user to know.
    ura_m : (E, S) broadcast URA / SISA of the navigation record of each satellite (m;
        NaN where the record gives none), or None (a simulated sky): the ``broadcast``
        error model (:mod:`raimcore.measure.error_models`) reads it.
    clock_reset : (E,) bool, True where the receiver itself says its clock restarted since
        the previous epoch of the sky (an Android log's HardwareClockDiscontinuityCount
        changed, a RINEX epoch flag 1 "power failure"; the first epoch False), or None
        (a simulated sky: never). The filters re-initialise their clock state there
        (:attr:`raimcore.measure.Measurements.clock_reset`).
    """

    t_s: np.ndarray
    sat_names: tuple[str, ...]
    sys_idx: np.ndarray
    systems: tuple[str, ...]
    pos_sv_ecef_m: np.ndarray
    pos_rx_ecef_m: np.ndarray
    vel_rx_ecef_mps: np.ndarray
    h_rx_m: np.ndarray
    range_m: np.ndarray
    az_rad: np.ndarray
    el_rad: np.ndarray
    trackable: np.ndarray
    pr_m: np.ndarray | None = None
    notes: tuple[str, ...] = ()
    ura_m: np.ndarray | None = None
    clock_reset: np.ndarray | None = None

    @property
    def recorded(self) -> bool:
        """True for a recording (real pseudoranges), False for a simulated sky."""
        return self.pr_m is not None


def build_sky(s) -> Sky:
    """The :class:`Sky` of scenario ``s`` from its source (``s.source``)."""
    if s.source != "sim":  # "rinex" or "android": one chain, two readers
        from .recording import recording_sky

        return recording_sky(s)
    from .simulated import simulated_sky

    return simulated_sky(s)
