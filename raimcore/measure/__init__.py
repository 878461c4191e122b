"""Stage 2 of the pipeline, measure: from a :class:`~raimcore.sky.Sky` to what a receiver
has (:class:`Measurements`) and what only the study knows (:class:`Truth`).

One implementation for both sky sources, in this order: elevation mask, ``restrict``
windows, the 1-sigma of every pseudorange from the scenario's ``error_model``
(:mod:`raimcore.measure.error_models`), the pseudoranges (a simulated sky: geometric range
+ receiver clock + noise of that sigma (:mod:`raimcore.measure.noise`); a recording: its
real corrected pseudoranges), the recording's measured-error note (before any fault), the
faults (:mod:`raimcore.measure.faults`), the barometric altimeter.

Random streams (noise, receiver clock, baro) are spawned from ``s.seed`` with
``SeedSequence``, so each is reproducible on its own.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..constants import C_MPS
from ..lsq import clock_columns
from .data import Measurements, Truth
from .error_models import model_sigma, resolve_model
from .errors import error_statistics
from .faults import Fault, fault_bias, fault_biases, fault_columns
from .noise import make_noise

__all__ = ["measure", "Measurements", "Truth", "apply_restrict", "fault_notes",
           "error_statistics", "receiver_clock_m"]

#: Keys that shape a simulated sky only: on a recording, a value other than the default
#: has no effect and is said so.
SIMULATION_ONLY_KEYS = ("constellation", "rename", "trajectory", "lat_deg", "lon_deg",
                        "height_m", "speed_mps", "heading_deg", "climb_mps",
                        "cruise_speed_mps", "cruise_alt_m", "climb_s", "turn_start_s",
                        "turn_rate_dps", "turn_deg", "clock_drift_mps", "clock_jumps_s")
#: One millisecond of receiver clock as a range (m): the step of a clock-steering receiver.
MS_M = 1e-3 * C_MPS


def measure(sky, s) -> tuple[Measurements, Truth]:
    """The measurements and the truth of scenario ``s`` on ``sky``."""
    t, names = sky.t_s, sky.sat_names
    used = sky.trackable & (sky.el_rad >= math.radians(s.mask_deg))
    apply_restrict(used, t, names, s.restrict)
    sat_systems = np.asarray(sky.systems, dtype=object)[sky.sys_idx]
    bias = fault_biases(s.faults, t, names, sat_systems, sky.el_rad)
    model = resolve_model(s.error_model, sky.recorded, s.algorithm)
    sigma, model_notes = model_sigma(model, sky, used, s.sigma_m, ism=s.ism,
                                     user_model=s.user_model)
    sigma_ref = _reference_sigma(model, sigma, used, s.sigma_m)
    noise = make_noise(s.noise, sigma_ref, mixture_eps=s.mixture_eps,
                       mixture_scale=s.mixture_scale, student_nu=s.student_nu,
                       corr_s=s.noise_corr_s)
    noise_ss, clock_ss, baro_ss = np.random.SeedSequence(int(s.seed)).spawn(3)
    notes = list(sky.notes) + list(model_notes)
    if sky.pr_m is None:
        # The noise model's draw (its shape and correlation) at the model's sigma.
        eps = noise.sample(np.random.default_rng(noise_ss), sky.range_m.shape, t_s=t) \
            * (sigma / sigma_ref)
        cc = clock_columns(sky.sys_idx, len(sky.systems))
        clk0 = np.random.default_rng(clock_ss).uniform(-3e5, 3e5, len(sky.systems))
        drift = receiver_clock_m(t, s.clock_drift_mps, s.clock_jumps_s)
        clock = clk0[None, :] + drift[:, None]
        clean = sky.range_m + clock @ cc.T + eps
        if s.clock_jumps_s:
            notes.append(f"simulated receiver clock: drift {s.clock_drift_mps:g} m/s, 1 ms "
                         f"jumps at t = {', '.join(f'{x:g}' for x in s.clock_jumps_s)} s")
    else:
        clean = sky.pr_m
        notes += _ignored_on_recording(s)
    baro_alt = None
    if s.baro:
        baro_alt = sky.h_rx_m + s.sigma_baro_m * np.random.default_rng(baro_ss) \
            .standard_normal(len(t))
    pr = np.where(used, clean + bias, np.nan)
    meas = Measurements(
        t_s=t, sat_names=tuple(names), sys_idx=sky.sys_idx, systems=tuple(sky.systems),
        pos_sv_ecef_m=sky.pos_sv_ecef_m, pr_m=pr, used=used, az_rad=sky.az_rad,
        el_rad=sky.el_rad, sigma_m=sigma, noise=noise, p_fa=s.p_fa, p_md=s.p_md,
        hal_m=s.hal_m, val_m=s.val_m, seed=int(s.seed), baro_alt_m=baro_alt,
        sigma_baro_m=s.sigma_baro_m if s.baro else None, error_model=model,
        ism=s.ism, user_model=s.user_model,
        clock_reset=sky.clock_reset)  # None (a simulated sky): never
    truth = Truth(pos_rx_ecef_m=sky.pos_rx_ecef_m, vel_rx_ecef_mps=sky.vel_rx_ecef_mps,
                  fault_bias_m=bias, used=used)
    if sky.pr_m is not None:  # a recording: measure its errors before any fault is added
        clean_meas = dataclasses.replace(meas, pr_m=np.where(used, clean, np.nan))
        no_fault = dataclasses.replace(truth, fault_bias_m=np.zeros_like(bias))
        note = _error_note(clean_meas, no_fault, s)
        if note:
            notes.append(note)
    notes += fault_notes(s.faults, truth, names, t, sat_systems, sky.el_rad)
    return dataclasses.replace(meas, notes=tuple(notes)), truth


def _reference_sigma(model: str, sigma, used, sigma_m: float) -> float:
    """The scale of the noise model (``Measurements.noise.sigma_m``): ``sigma_m`` for the
    models it scales (``uniform``, ``elevation``), else the median sigma of the used
    measurements, so that the per-satellite factors ``sigma / noise.sigma_m`` the filters
    apply stay near 1."""
    if model in ("uniform", "elevation"):
        return float(sigma_m)
    pick = sigma[used] if np.any(used) else sigma.reshape(-1)
    pick = pick[np.isfinite(pick) & (pick > 0)]
    return float(np.median(pick)) if pick.size else float(sigma_m)


def receiver_clock_m(t_s, drift_mps: float, jumps_s=()) -> np.ndarray:
    """A free-running receiver clock (E,) in metres, relative to its value at t = 0.

    ``drift_mps * t`` plus a 1 ms jump (:data:`MS_M`) at each time of ``jumps_s``, against
    the drift (a receiver that steers its clock by whole milliseconds brings it back
    toward system time; forward when the drift is 0), from that epoch on.
    """
    t = np.asarray(t_s, dtype=float)
    step = -MS_M if drift_mps > 0 else MS_M
    n_jumps = (t[:, None] >= np.asarray(jumps_s, dtype=float)[None, :]).sum(-1)
    return drift_mps * t + step * n_jumps


def apply_restrict(used, t, sat_names, restrict) -> None:
    """Clear ``used`` (E, S) in place outside each restriction's satellites and window."""
    for r in restrict:
        unknown = [x for x in r.sats if x not in sat_names]
        if unknown:
            raise ValueError(f"restrict: unknown satellite(s) {', '.join(unknown)}; this "
                             f"scenario has {', '.join(sat_names)}")
        window = (t >= r.t0_s) & (t < r.t1_s)
        keep = np.isin(np.array(sat_names), list(r.sats))
        used[window] &= keep[None, :]


def fault_notes(faults: tuple[Fault, ...], truth: Truth, sat_names, t_s, sat_systems=None,
                el_rad=None) -> list[str]:
    """A warning for each fault that never acts on a used measurement, saying why.

    ``sat_systems`` (S,) and ``el_rad`` (E, S) are needed for constellation faults (see
    :func:`~raimcore.measure.faults.fault_bias`); such a fault never acts when no satellite
    of its system is used while it is on."""
    out = []
    t = np.asarray(t_s, dtype=float)
    t_end = float(t[-1]) if t.size else 0.0
    for f in faults:
        cols = fault_columns(f, sat_names, sat_systems)
        bias = fault_bias(f, t, sat_names, sat_systems, el_rad)[:, cols]
        used = truth.used[:, cols]
        if ((bias != 0) & used).any():
            continue
        window = (t >= f.t0_s) & (t < f.t1_s)
        # "G10 is never used" / "no GAL satellite is ever used"
        who, never, not_ = ((f.sat, "never", "not ") if f.system is None
                            else (f"no {f.sat} satellite", "ever", ""))
        if not window.any():
            why = (f"its window [{f.t0_s:g}, {f.t1_s:g}) s lies outside the run "
                   f"[0, {t_end:g}] s")
        elif cols.size == 0:
            why = f"this run has no {f.sat} satellite"
        elif not used.any():
            why = f"{who} is {never} used (below the mask, unhealthy or restricted)"
        elif not used[window].any():
            why = f"{who} is {not_}used while the fault is on"
        else:
            why = "its bias is 0 at every used epoch"
        out.append(f"warning: fault {f.target} {f.kind} from t = {f.t0_s:g} s never acts: "
                   f"{why}")
    return out


def _ignored_on_recording(s) -> list[str]:
    defaults = {f.name: f.default for f in dataclasses.fields(s)}
    set_ = [k for k in SIMULATION_ONLY_KEYS if getattr(s, k) != defaults[k]]
    if not set_:
        return []
    return [f"{', '.join(set_)} shape simulated skies only; on a recording they have no "
            "effect"]


def _error_note(meas: Measurements, truth: Truth, s) -> str | None:
    try:
        fit = error_statistics(meas, truth)
    except ValueError:  # too few satellites for an estimate: nothing to say
        return None
    note = (f"measured pseudorange errors against the station position: sigma "
            f"{fit.sigma_m:.2f} m at the zenith (robust; scenario sigma_m {s.sigma_m:g}), "
            f"correlation {fit.rho:.2f} over {fit.dt_s:g} s")
    if 0 < fit.corr_s < math.inf:
        note += (f" (Gauss-Markov time {fit.corr_s:.0f} s; scenario noise_corr_s "
                 f"{s.noise_corr_s:g}: PF-LLR calibrates its threshold on these two keys)")
    return note
