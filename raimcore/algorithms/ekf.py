"""Extended Kalman filter on the receiver state with an innovation chi-square RAIM test.

The baseline of seed 002 (spec section 3, "Baseline"): the same state and process model as
the particle filters (:class:`raimcore.algorithms.pf.ProcessModel`: ECEF position, optional
velocity, one clock offset per system, optional shared clock drift), the measurement noise
taken as Gaussian with the noise model's standard deviation. Batched over a leading axis of
independent realisations ``R``.

Receiver clock: the drift starts from the clock change between the first two epochs
(:func:`~raimcore.algorithms.pf.initial_drift`); a clock jump (the common-mode innovation
of a system above :data:`~raimcore.algorithms.pf.CLOCK_JUMP_M`,
:func:`~raimcore.algorithms.pf.clock_jump`) re-initialises that system's offset (the
prediction moved by the jump, its variance increased by the jump estimate's) before the
innovations are tested, so the test sees only the differential part. Where the receiver
itself says its clock restarted (``clock_reset``, :func:`~raimcore.algorithms.pf.
reset_epochs`), whatever the size of the jump: the offsets are centred on the common-mode
innovation, their covariance with the rest of the state dropped and their variance set to
the diffuse :data:`~raimcore.algorithms.pf.CLOCK_RESET_SD_M` squared, so the NIS is the
satellite-to-satellite part, tested with ``m - q`` degrees of freedom (``q`` the systems
in view); the drift is restarted too (:data:`~raimcore.algorithms.pf.
CLOCK_RESET_DRIFT_SD_MPS`, learnt again from the next pair of epochs).

Test: the normalised innovation squared ``NIS = nu^T S^-1 nu`` with ``S = H P H^T + R`` is
chi-square with ``m`` degrees of freedom without a fault (Gaussian noise); alarm when it
exceeds ``chi2.ppf(1 - p_fa, m)``. With ``exclude=True`` the satellite with the largest
normalised innovation ``|nu_i| / sqrt(S_ii)`` is left out of that epoch's update.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..lsq import clock_columns, wls
from .pf import (
    CLOCK_JUMP_M,
    CLOCK_RESET_DRIFT_SD_MPS,
    CLOCK_RESET_SD_M,
    ProcessModel,
    availability,
    clock_jump,
    cov_enu_to_ecef,
    initial_drift,
    jump_variance,
    reset_epochs,
)

__all__ = ["EkfRun", "run_ekf"]


@dataclass(frozen=True)
class EkfRun:
    """An EKF run over ``E`` epochs for ``R`` realisations, ``S`` satellites.

    Attributes
    ----------
    estimate : (R, E, D) state after the update (NaN before the first fix).
    nis : (R, E) normalised innovation squared over the used satellites (NaN where no test).
    threshold : (E,) ``chi2.ppf(1 - p_fa, m)`` (``m - q`` at a clock restart and, with the
        drift restarted, at the update after it: the offsets are diffuse there).
    norm_innov : (R, E, S) ``|nu_i| / sqrt(S_ii)`` (NaN where unused).
    alarm : (R, E) bool, ``nis > threshold``.
    worst : (R, E) int, the satellite with the largest normalised innovation (-1 if none).
    excluded : (R, E, S) bool, left out of the update (``exclude=True`` only).
    available : (E,) bool, ``m >= n + 1`` and the filter started.
    clock_jump_m : (R, E, q) receiver clock jumps detected and absorbed (m, per system;
        0 where none; at a flagged restart the common-mode innovation, whatever its size).
    reset : (E,) bool, the epochs at which a flagged clock restart was applied.
    resume : of a plain run (``exclude=False``): what a protected run of the same inputs
        takes over (``run_ekf(..., exclude=True, resume=...)``); None otherwise.
    """

    estimate: np.ndarray
    nis: np.ndarray
    threshold: np.ndarray
    norm_innov: np.ndarray
    alarm: np.ndarray
    worst: np.ndarray
    excluded: np.ndarray
    available: np.ndarray
    clock_jump_m: np.ndarray
    reset: np.ndarray
    resume: PlainRun | None = None


def _transition(model: ProcessModel, dt_s: float):
    """State transition F (D, D) and process covariance Q (D, D) of ``model`` over ``dt_s``
    (the clock block: :meth:`ProcessModel.clock_cov`)."""
    d = model.dim
    f = np.eye(d)
    q = np.zeros((d, d))
    q[:3, :3] = model.q_pos_mps**2 * dt_s * np.eye(3)
    if model.kind == "cv":
        f[:3, 3:6] = dt_s * np.eye(3)
        q[3:6, 3:6] = model.q_vel_mps2**2 * dt_s * np.eye(3)
    if model.has_drift:
        f[model.clocks, model.drift] = dt_s
    q[model.clk0:, model.clk0:] = model.clock_cov(dt_s)
    return f, q


@dataclass(frozen=True)
class PlainRun:
    """What a protected run needs of the plain run of the same inputs (see :func:`run_ekf`).

    key : :func:`_fingerprint` of the inputs.
    k_div : the first epoch at which the protected run excludes a satellite (``E``: none).
    before : the outputs ``estimate, nis, norm_innov, worst, clock_jump_m`` of the epochs
        before ``k_div``.
    state : ``(x, P, jumped, k_prev)`` at the start of epoch ``k_div`` (None if none).
    """

    key: tuple
    k_div: int
    before: tuple
    state: tuple | None


def _fingerprint(*values) -> tuple:
    """A key equal only for bit-identical inputs: each array as its shape, type and bytes,
    anything else as itself."""
    return tuple((v.shape, v.dtype.str, np.ascontiguousarray(v).tobytes())
                 if isinstance(v, np.ndarray) else v for v in values)


def run_ekf(pos_sv_ecef_m, pr_m, used, t_s, sys_idx, n_sys: int, sigma_m,
            model: ProcessModel, p_fa: float, *, exclude: bool,
            init_inflate: float = 3.0, jump_m: float = CLOCK_JUMP_M, clock_reset=None,
            reset_drift: bool = True, resume: PlainRun | None = None) -> EkfRun:
    """Run the EKF and its innovation test over every epoch.

    Parameters
    ----------
    pos_sv_ecef_m : (E, S, 3) satellite positions (m).
    pr_m : (R, E, S) pseudoranges (m), NaN where unused.
    used : (E, S) bool.
    t_s : (E,) epoch times (s).
    sys_idx : (S,) system index; n_sys : number of clocks (``model.n_clk``).
    sigma_m : measurement standard deviation the filter assumes (m): a number, or (E, S)
        per satellite (a recording's elevation model); ``R = diag(sigma_m^2)``.
    model : process model.
    p_fa : false-alarm probability per epoch of the chi-square test.
    exclude : on an alarm, leave the satellite with the largest normalised innovation out
        of the update.
    init_inflate : factor on the first fix's standard deviations for the initial P (and on
        the start drift's).
    jump_m : clock jump threshold on the common-mode innovation (m).
    clock_reset : optional (E,) bool, the receiver says its clock restarted there
        (:attr:`raimcore.measure.Measurements.clock_reset`); None: never.
    reset_drift : at a restart, restart the drift too; False keeps its estimate and
        variance (an oscillator running through the restart).

    Returns
    -------
    EkfRun. The filter starts at the first epoch with ``m >= n + 1`` from a weighted least
    squares fix (the drift, if any, from the next epoch: :func:`initial_drift`); epochs with
    too few satellites only predict. A clock jump at two available epochs in a row is a
    wrong drift (a reset, or a jump between the first two epochs): the drift is corrected
    by the second jump / dt and its variance restarted.

    Until its first exclusion a protected run (``exclude=True``) is the plain run's
    computation: given ``resume``, the ``resume`` of a plain run of the same inputs (as the
    ``ekf`` algorithm runs the two, :mod:`raimcore.algorithms.ekf_nis`), it takes that run's
    outputs up to the first epoch at which the protected filter would exclude a satellite
    and its state there, and goes on from it. The inputs are compared bit for bit
    (:func:`_fingerprint`): a ``resume`` of other inputs is not used.
    """
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    pr = np.asarray(pr_m, dtype=float)
    used = np.asarray(used, dtype=bool)
    r_n, e_n, s_n = pr.shape
    d = model.dim
    var = np.broadcast_to(np.asarray(sigma_m, dtype=float) ** 2, (e_n, s_n))
    cc = clock_columns(sys_idx, n_sys)
    n_states, available = availability(used, sys_idx, n_sys)
    dof = used.sum(-1)
    threshold = np.where(available, stats.chi2.isf(p_fa, np.maximum(dof, 1)), np.nan)
    est = np.full((r_n, e_n, d), np.nan)
    nis = np.full((r_n, e_n), np.nan)
    norm_innov = np.full((r_n, e_n, s_n), np.nan)
    worst = np.full((r_n, e_n), -1)
    excluded = np.zeros((r_n, e_n, s_n), dtype=bool)
    jumps = np.zeros((r_n, e_n, n_sys))

    def fix_at(k):
        return wls(np.broadcast_to(sv[k], (r_n, s_n, 3)), pr[:, k],
                   np.broadcast_to(np.where(used[k], 1.0 / var[k], 0.0), (r_n, s_n)),
                   sys_idx, n_sys)

    k0 = -1
    for k in np.flatnonzero(available):
        fix = fix_at(k)
        if fix.available.all():
            k0 = int(k)
            break
    if k0 < 0:
        return EkfRun(est, nis, threshold, norm_innov, np.zeros((r_n, e_n), bool), worst,
                      excluded, np.zeros(e_n, bool), jumps, np.zeros(e_n, bool))
    available[:k0] = False
    reset_at, relearn_at = reset_epochs(
        np.zeros(e_n, bool) if clock_reset is None else clock_reset, available, k0)
    if not (reset_drift and model.has_drift):
        relearn_at[:] = False
    # At a restart, and at the next update while the restarted drift is unknown, the q
    # offsets in view are free: the satellite-to-satellite part has m - q dof.
    threshold = np.where(reset_at | relearn_at,
                         stats.chi2.isf(p_fa, np.maximum(dof - n_states + 3, 1)), threshold)
    x = np.zeros((r_n, d))
    x[:, :3] = fix.pos_ecef_m
    x[:, model.clocks] = np.nan_to_num(fix.clock_m)
    # Initial P: the fix's covariance (ENU + clocks, rotated to ECEF), inflated.
    c = cov_enu_to_ecef(fix.pos_ecef_m, fix.cov_enu) * init_inflate**2
    p = np.zeros((r_n, d, d))
    idx = np.r_[0:3, model.clocks]
    p[:, idx[:, None], idx[None, :]] = c
    if model.kind == "cv":
        p[:, 3:6, 3:6] = np.eye(3) * 100.0  # (10 m/s)^2: velocity unknown at start
    drift_var0 = np.zeros(r_n)
    if model.has_drift:
        # Start drift: the clock change between the first two epochs (robust).
        later = np.flatnonzero(available[k0 + 1:])
        if later.size:
            k1 = k0 + 1 + int(later[0])
            both = used[k0] & used[k1]
            drift, sd = initial_drift(sv[k0], sv[k1], pr[:, k0], pr[:, k1], both, sys_idx,
                                      n_sys, fix.pos_ecef_m, t_s[k1] - t_s[k0],
                                      np.where(both, 1.0 / var[k0], 0.0),
                                      solve_motion=model.kind == "cv")
            x[:, model.drift] = drift
            drift_var0 = np.where(np.isfinite(sd), (init_inflate * sd)**2, 0.0)
        p[:, model.drift, model.drift] = drift_var0
    est[:, k0] = x
    eye = np.eye(d)
    ck = np.asarray(sys_idx, dtype=int)
    clocks = model.clocks
    prz = np.nan_to_num(pr)
    sats = np.arange(s_n)
    cc_used = np.where(used[:, :, None], cc, 0.0)  # (E, S, q): H's clock columns
    no_jump = np.zeros((r_n, n_sys))
    no_hit = np.zeros((r_n, n_sys), dtype=bool)
    transitions = {}  # F, F^T, Q by time step: computed once per distinct step
    jumped = no_hit  # a jump at the previous available epoch
    k_prev = k0
    start = k0 + 1
    # A protected run goes on from the plain run of the same inputs (see the docstring).
    memo = resume if exclude else None
    track = not exclude
    key = (_fingerprint(sv, pr, used, t_s, ck, n_sys, var, model, p_fa, init_inflate, jump_m,
                        reset_at, reset_drift) if track or memo is not None else None)
    if memo is not None and memo.key == key:
        start = memo.k_div
        for out, kept in zip((est, nis, norm_innov, worst, jumps), memo.before, strict=True):
            out[:, :start] = kept
        if start < e_n:
            x, p, jumped = (v.copy() for v in memo.state[:3])
            k_prev = memo.state[3]
    k_div, state = e_n, None
    for k in range(start, e_n):
        state_k = (x, p, jumped, k_prev)  # not modified in place below: rebound
        dt = t_s[k] - t_s[k - 1]
        if dt not in transitions:
            f, q = _transition(model, dt)
            transitions[dt] = f, f.T, q
        f, ft, q = transitions[dt]
        x = x @ ft
        p = f @ p @ ft + q
        if not available[k]:
            est[:, k] = x
            continue
        dvec = sv[k][None] - x[:, None, :3]
        rng_m = np.linalg.norm(dvec, axis=-1)
        u = np.broadcast_to(used[k], (r_n, s_n))
        h = np.zeros((r_n, s_n, d))
        h[..., :3] = np.where(u[..., None], -dvec / rng_m[..., None], 0.0)
        h[..., clocks] = cc_used[k]
        nu = np.where(u, prz[:, k] - rng_m - x[:, clocks] @ cc.T, 0.0)
        if reset_at[k]:
            # The receiver says its clock restarted: new offsets, centred on the
            # common-mode innovation, diffuse and independent of the rest of the state.
            jump = clock_jump(nu, u, ck, n_sys, 0.0)  # (R, q), every system's median
            jumps[:, k] = jump
            x[:, clocks] += jump
            nu = np.where(u, nu - jump @ cc.T, 0.0)
            free = np.arange(model.clk0, model.clk0 + n_sys)
            if model.has_drift and reset_drift:
                free = np.append(free, model.drift)
            p[:, free, :] = 0.0
            p[:, :, free] = 0.0
            p[:, free, free] = np.where(free == model.drift, CLOCK_RESET_DRIFT_SD_MPS**2,
                                        CLOCK_RESET_SD_M**2)
            hit = no_hit  # no evidence of a wrong drift
        elif (u & (np.abs(nu) > jump_m)).any():
            # A receiver clock jump: re-initialise the offset from the common-mode
            # innovation (no innovation above jump_m: no median above it, no jump).
            jump = clock_jump(nu, u, ck, n_sys, jump_m)  # (R, q)
            hit = jump != 0.0
        else:
            jump, hit = no_jump, no_hit
        if hit.any():
            jumps[:, k] = jump
            vj = jump_variance(np.where(u, 1.0 / var[k], 0.0), ck, n_sys) * init_inflate**2
            x[:, clocks] += jump
            nu = np.where(u, nu - jump @ cc.T, 0.0)
            diag = np.arange(model.clk0, model.clk0 + n_sys)
            p[:, diag, diag] += np.where(hit, vj, 0.0)
            if model.has_drift:
                again = hit & jumped
                n_again = again.sum(-1)
                dt_a = max(t_s[k] - t_s[k_prev], 1e-9)
                x[:, model.drift] += np.where(
                    n_again > 0, np.where(again, jump, 0.0).sum(-1) / np.maximum(n_again, 1)
                    / dt_a, 0.0)
                restart = n_again > 0
                if restart.any():
                    dd = model.drift
                    p[restart, dd, :] = 0.0
                    p[restart, :, dd] = 0.0
                    p[restart, dd, dd] = np.maximum(drift_var0[restart],
                                                    vj.max(-1)[restart] / dt_a**2)
        jumped = hit
        k_prev = k
        ht = np.swapaxes(h, -1, -2)
        s_mat = h @ p @ ht + np.diag(var[k])
        s_inv = np.linalg.inv(s_mat)
        nis[:, k] = np.einsum("rs,rst,rt->r", nu, s_inv, nu)
        ni = np.abs(nu) / np.sqrt(np.diagonal(s_mat, axis1=1, axis2=2))
        norm_innov[:, k] = np.where(u, ni, np.nan)
        worst[:, k] = np.argmax(np.where(u, ni, -1.0), axis=-1)
        if exclude or (track and state is None):
            # An alarm excludes a satellite if that leaves m >= n for the update.
            alarmed = (nis[:, k] > threshold[k]) & (u.sum(-1) - 1 >= n_states[k])
            if alarmed.any() and not exclude:
                k_div, state = k, state_k  # where a protected run first excludes
            elif alarmed.any():
                drop = alarmed[:, None] & (sats == worst[:, k:k + 1])
                excluded[:, k] = drop
                u = u & ~drop
                nu = np.where(u, nu, 0.0)
                h = np.where(u[..., None], h, 0.0)
                ht = np.swapaxes(h, -1, -2)
                s_mat = h @ p @ ht + np.diag(var[k])
                s_inv = np.linalg.inv(s_mat)
        gain = p @ ht @ s_inv
        x = x + np.einsum("rds,rs->rd", gain, nu)
        ikh = eye - gain @ h
        # Joseph form keeps P symmetric positive definite.
        p = ikh @ p @ np.swapaxes(ikh, -1, -2) + (gain * var[k]) @ np.swapaxes(gain, -1, -2)
        est[:, k] = x
    plain = None
    if not exclude:
        plain = PlainRun(
            key, k_div, tuple(a[:, :k_div].copy() for a in (est, nis, norm_innov, worst, jumps)),
            None if state is None else tuple(v.copy() for v in state[:3]) + (state[3],))
    alarm = available[None] & (nis > threshold[None])
    return EkfRun(est, nis, threshold, norm_innov, alarm, worst, excluded, available, jumps,
                  reset_at, plain)
