"""EKF baseline with an innovation chi-square RAIM test and exclusion (seed 002 baseline).

Two Kalman filters with the particle filters' state model run side by side: a plain EKF
that uses every satellite (the paper's baseline: ``pos_before``), and a protected EKF
whose normalised innovation squared is tested against ``chi2.ppf(1 - p_fa, m)``; on an
alarm it leaves the satellite with the largest normalised innovation out of that epoch's
update (``pos_after``, ``excluded``). The filters assume Gaussian noise with the noise
model's standard deviation, so under heavy tails the nominal ``p_fa`` is not met.
"""

from __future__ import annotations

import math

import numpy as np

from .base import (
    STATUS_NOT_ARMED,
    STATUS_OK,
    STATUS_UNAVAILABLE,
    AlgorithmOutput,
    AlgorithmSpec,
    Measurements,
    register,
)
from .ekf import run_ekf
from .pf_llr import PROCESS_OPTIONS, clock_jump_column, noise_scale, process_model

SUMMARY = (
    "A Kalman filter follows the receiver position and clock (offset and drift), assuming "
    "Gaussian noise. "
    "Each epoch it predicts the pseudoranges; the innovations (measured minus predicted), "
    "normalised by their predicted spread, add up to a chi-square statistic with one "
    "degree of freedom per satellite. Above the threshold set by the false-alarm "
    "probability, the satellite with the largest normalised innovation is left out of "
    "the update. Heavy-tailed noise breaks the Gaussian assumption: more false alarms, "
    "and an unprotected filter is dragged by a fault."
)

EQUATIONS = r"""
- State: position, clock offset per system, one clock drift (Brown & Hwang two-state
  clock); a clock jump (common-mode innovation above 1 km), or a restart the receiver
  flags (a phone's hardware-clock discontinuity, a RINEX power failure), re-initialises
  the offset: at a flagged restart it is diffuse, the test keeps the satellite-to-satellite
  part with $m - q$ degrees of freedom and the drift is learnt again
- Predict $\hat x_{k|k-1} = F \hat x_{k-1|k-1}$, $P_{k|k-1} = F P_{k-1|k-1} F^T + Q$
- Innovation $\nu = \rho - h(\hat x_{k|k-1})$, $S = H P_{k|k-1} H^T + R$,
  $R = \mathrm{diag}(\sigma_i^2)$
- Test $\mathrm{NIS} = \nu^T S^{-1} \nu \sim \chi^2_m$, alarm when
  $\mathrm{NIS} > F^{-1}(1 - P_{fa})$ ($F$: the CDF of $\chi^2_m$, $m$ satellites)
- Exclude $\hat\jmath = \mathrm{arg\,max}_i\, |\nu_i| / \sqrt{S_{ii}}$, then
  $K = P_{k|k-1} H^T S^{-1}$, $\hat x_{k|k} = \hat x_{k|k-1} + K \nu$
"""


def run(data: Measurements, options: dict) -> AlgorithmOutput:
    """Run the plain and the protected EKF on every epoch (options: the process model,
    shared with ``pf-llr``: ``model``, ``q_pos_mps``, ``q_vel_mps2``, ``q_clk_mps``,
    ``q_drift_mps2``). Column ``clock_jump_ms``: a receiver clock jump absorbed at that
    epoch (ms; 0: none), at a restart flagged in ``data.clock_reset`` the common-mode
    innovation of the re-initialised clock."""
    model = process_model(options, len(data.systems))
    std = data.noise.std_m
    sigma = std if math.isfinite(std) else data.noise.sigma_m
    scale = noise_scale(data)  # a recording's elevation model, as the snapshot tests use
    if scale is not None:
        sigma = sigma * scale
    args = (data.pos_sv_ecef_m, data.pr_m[None], data.used, data.t_s, data.sys_idx,
            len(data.systems), sigma, model, data.p_fa)
    plain = run_ekf(*args, exclude=False, clock_reset=data.clock_reset)
    prot = run_ekf(*args, exclude=True, clock_reset=data.clock_reset, resume=plain.resume)
    avail = prot.available
    k0 = np.flatnonzero(avail)[:1]
    armed = avail.copy()
    armed[k0] = False  # the first epoch is the least-squares start, nothing to test
    status = np.where(armed, STATUS_OK, np.where(avail, STATUS_NOT_ARMED,
                                                 STATUS_UNAVAILABLE)).astype(object)
    alarm = armed & prot.alarm[0]
    ok = avail[:, None]
    return AlgorithmOutput(
        status=status, statistic=np.where(armed, prot.nis[0], np.nan),
        threshold=np.where(armed, prot.threshold, np.nan), alarm=alarm,
        pos_before_ecef_m=np.where(ok, plain.estimate[0, :, :3], np.nan),
        pos_after_ecef_m=np.where(ok, prot.estimate[0, :, :3], np.nan),
        excluded=prot.excluded[0] & alarm[:, None],
        isolated=np.where(alarm, prot.worst[0], -1),
        per_sat={"norm_innovation": prot.norm_innov[0]},
        columns={"nis_plain": plain.nis[0],
                 "clock_jump_ms": clock_jump_column(prot.clock_jump_m[0])},
    )


SPEC = register(AlgorithmSpec(
    name="ekf",
    label="EKF innovation test (seed 002 baseline)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=PROCESS_OPTIONS,
    reference="Baseline of seed 002: extended Kalman filter with the particle filters' state "
              "model and an innovation chi-square RAIM test.",
))
