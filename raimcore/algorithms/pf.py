"""SIR particle filters on the receiver state, vectorised over a bank of filters (seed 002).

Kernels (pure functions, the random generator always an argument) and one class for the
persistent state of a bank (:class:`ParticleBank`). Shapes follow the package rule, batch
axes first: ``(..., N, D)`` particles, ``(..., N)`` weights, where ``...`` is any batch of
filters (the bank of s + 1 filters, times Monte Carlo runs for the threshold calibration).

State layout (``D = 3 + 3 * (model == "cv") + q``): ECEF position (m), then the ECEF
velocity (m/s) for the constant-velocity model, then one receiver clock per system (m).

Process models (spec section 3, "Filter"):

- ``"static"``: random walk, ``r_k = r_{k-1} + w``, ``w ~ N(0, q_pos^2 dt I)``;
- ``"cv"``: constant velocity, ``r_k = r_{k-1} + v_{k-1} dt``, ``v_k = v_{k-1} + w``,
  ``w ~ N(0, q_vel^2 dt I)`` (the position also gets the ``q_pos`` random walk);
- the clocks are random walks with ``q_clk`` (no clock-drift state: the simulated clocks
  drift by ``clock_drift_mps``, 0 in the shipped scenarios; use a larger ``q_clk`` for a
  drifting clock).

Measurement model: ``rho_i = ||r - s_i|| + c dt_sys(i) + v_i`` with ``v_i`` from the
scenario's noise model (:mod:`raimcore.measure.noise`): the filter's likelihood is its ``logpdf``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from .._validate import check_choice, check_positive
from ..geometry import ecef_to_geodetic, enu_rotation
from ..measure.noise import scaled

__all__ = ["PROCESS_MODELS", "ProcessModel", "ParticleBank", "predict", "log_likelihood",
           "normalise_log_weights", "effective_sample_size", "systematic_resample",
           "weighted_mean", "initial_cloud"]

PROCESS_MODELS = ("static", "cv")
#: Particle-satellite pairs per likelihood chunk (about 0.5 MB per float64 temporary).
_CHUNK_ELEMENTS = 65536
#: Constant-velocity start-up: the velocity process noise starts at VEL_BOOST x the start
#: velocity's standard deviation per sqrt(s) and decays like the position's (see
#: run_llr_bank); tuned on seed000-step with model = "cv" (sigma 3 and 33 m).
VEL_BOOST = 1.0


@dataclass(frozen=True)
class ProcessModel:
    """State model of the receiver.

    Attributes
    ----------
    kind : ``"static"`` or ``"cv"`` (constant velocity).
    n_clk : number of clock states (one per system).
    q_pos_mps : position random-walk density, m / sqrt(s).
    q_vel_mps2 : velocity random-walk density (``"cv"`` only), m/s / sqrt(s).
    q_clk_mps : clock random-walk density, m / sqrt(s).
    """

    kind: str = "static"
    n_clk: int = 1
    q_pos_mps: float = 0.1
    q_vel_mps2: float = 0.5
    q_clk_mps: float = 0.1

    def __post_init__(self):
        check_choice("model", self.kind, PROCESS_MODELS)
        check_positive("q_pos_mps", self.q_pos_mps, allow_zero=True)
        check_positive("q_vel_mps2", self.q_vel_mps2, allow_zero=True)
        check_positive("q_clk_mps", self.q_clk_mps, allow_zero=True)

    @property
    def clk0(self) -> int:
        """Index of the first clock state."""
        return 6 if self.kind == "cv" else 3

    @property
    def dim(self) -> int:
        return self.clk0 + self.n_clk


def predict(particles, dt_s: float, model: ProcessModel, rng: np.random.Generator,
            q_scale: float = 1.0, q_scale_vel: float = 1.0):
    """Draw the predicted particles from the state equation (spec section 3, "Filter").

    Parameters
    ----------
    particles : (..., N, D) states at k - 1.
    dt_s : time step (s), >= 0.
    model : the process model.
    rng : random generator.
    q_scale : factor on the position and clock process-noise densities (start-up
        annealing; the velocity noise keeps its density, see
        :func:`run_llr_bank`).

    Returns
    -------
    (..., N, D) states at k (a new array).
    """
    x = np.array(particles, dtype=float, copy=True)
    sq1 = math.sqrt(max(dt_s, 0.0))
    sq = q_scale * sq1
    noise = rng.standard_normal(x.shape)
    if model.kind == "cv":
        x[..., :3] += x[..., 3:6] * dt_s + model.q_pos_mps * sq * noise[..., :3]
        x[..., 3:6] += model.q_vel_mps2 * q_scale_vel * sq1 * noise[..., 3:6]
    else:
        x[..., :3] += model.q_pos_mps * sq * noise[..., :3]
    x[..., model.clk0:] += model.q_clk_mps * sq * noise[..., model.clk0:]
    return x


def log_likelihood(particles, pos_sv_ecef_m, pr_m, mask, sys_idx, noise, model: ProcessModel):
    """Log-likelihood of each particle given the pseudoranges it scores.

    Parameters
    ----------
    particles : (..., N, D) states.
    pos_sv_ecef_m : (..., S, 3) satellite positions (broadcast against the batch).
    pr_m : (..., S) pseudoranges (m); may be NaN where ``mask`` is False.
    mask : (..., S) bool, the measurements this filter scores.
    sys_idx : (S,) system index of each satellite.
    noise : noise model with ``logpdf`` (:mod:`raimcore.measure.noise`).
    model : the process model (for the state layout).

    Returns
    -------
    (..., N) ``sum_i mask_i ln p(rho_i | x)``.
    """
    x = np.asarray(particles)
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    pr = np.asarray(pr_m, dtype=float)
    n, s_n = x.shape[-2], sv.shape[-2]
    batch = np.broadcast_shapes(x.shape[:-2], sv.shape[:-2], pr.shape[:-1], mask.shape[:-1])
    rows = int(np.prod(batch, dtype=int))
    chunk = max(1, _CHUNK_ELEMENTS // max(n * s_n, 1))
    if rows > chunk:
        # Large banks in chunks of filters: the (N, S) temporaries stay in cache, so a
        # big batch is never slower than a loop over its filters.
        flat = [np.broadcast_to(a, batch + a.shape[-k:]).reshape((rows,) + a.shape[-k:])
                for a, k in ((x, 2), (sv, 2), (pr, 1), (mask, 1))]
        out = np.empty((rows, n))
        for i in range(0, rows, chunk):
            sl = slice(i, i + chunk)
            out[sl] = log_likelihood(flat[0][sl], flat[1][sl], flat[2][sl], flat[3][sl],
                                     sys_idx, noise, model)
        return out.reshape(batch + (n,))
    # ||s - r||^2 = |s|^2 + |r|^2 - 2 s.r as one matmul: no (..., N, S, 3) temporary.
    # Relative to a point near the receiver the cancellation error is below 1e-8 m.
    ref = x[(0,) * (x.ndim - 1)][:3]
    pos = x[..., :3] - ref
    sv = sv - ref
    r2 = (np.einsum("...nk,...nk->...n", pos, pos)[..., None]
          + np.einsum("...sk,...sk->...s", sv, sv)[..., None, :]
          - 2.0 * pos @ np.swapaxes(sv, -1, -2))
    rng_m = np.sqrt(r2)
    clk = x[..., model.clk0 + np.asarray(sys_idx, dtype=int)]
    pr = np.where(mask, np.nan_to_num(pr), 0.0)
    resid = pr[..., None, :] - rng_m - clk
    lp = noise.logpdf(resid)
    return np.einsum("...ns,...s->...n", lp, mask.astype(float))


def normalise_log_weights(log_w):
    """Normalised weights and the log of the normaliser.

    Parameters
    ----------
    log_w : (..., N) unnormalised log weights.

    Returns
    -------
    w : (..., N) weights summing to one along the last axis.
    log_norm : (...,) ``ln sum_i exp(log_w_i)``.
    """
    log_norm = logsumexp(log_w, axis=-1)
    return np.exp(log_w - log_norm[..., None]), log_norm


def effective_sample_size(weights):
    """``N_eff = 1 / sum_i w_i^2`` of normalised weights ``(..., N)`` -> ``(...,)``."""
    w = np.asarray(weights)
    return 1.0 / np.einsum("...n,...n->...", w, w)


def systematic_resample(weights, rng: np.random.Generator):
    """Systematic resampling: the indices of the particles to keep.

    One uniform draw ``u ~ U[0, 1/N)`` per filter; particle ``i`` is copied once for every
    point ``u + k/N`` (``k = 0..N-1``) that falls in its slice of the cumulative weights, so
    it is copied ``floor(N w_i)`` or ``ceil(N w_i)`` times (expected count ``N w_i``).

    Parameters
    ----------
    weights : (..., N) normalised weights.
    rng : random generator.

    Returns
    -------
    (..., N) int indices into the last axis, sorted along it.
    """
    w = np.asarray(weights, dtype=float)
    n = w.shape[-1]
    batch = w.shape[:-1]
    c = np.cumsum(w, axis=-1)
    c /= c[..., -1:]
    c[..., -1] = 1.0  # guard against rounding: every point lands inside
    u = (rng.random(batch + (1,)) + np.arange(n)) / n
    # One searchsorted on a flattened, offset array handles every filter of the batch.
    rows = np.arange(int(np.prod(batch, dtype=int))).reshape(batch + (1,)).astype(float)
    idx = np.searchsorted((c + rows).reshape(-1), (u + rows).reshape(-1), side="right")
    idx = idx.reshape(batch + (n,)) - n * rows.astype(int)
    return np.minimum(idx, n - 1)


def weighted_mean(particles, weights):
    """Weighted-mean estimate ``(..., D)`` of particles ``(..., N, D)``."""
    return np.einsum("...nd,...n->...d", particles, weights)


def cov_enu_to_ecef(pos_ecef_m, cov_enu):
    """A fix covariance ``(..., 3 + q, 3 + q)`` in ENU + clocks rotated to ECEF + clocks
    about the fix ``pos_ecef_m`` ``(..., 3)`` (symmetrised)."""
    pos = np.asarray(pos_ecef_m, dtype=float)
    cov = np.asarray(cov_enu, dtype=float)
    n = cov.shape[-1]
    lat, lon, _ = ecef_to_geodetic(pos)
    t = np.zeros(pos.shape[:-1] + (n, n))
    t[..., :3, :3] = np.swapaxes(enu_rotation(lat, lon), -1, -2)  # ECEF = R^T ENU
    t[..., 3:, 3:] = np.eye(n - 3)
    out = t @ cov @ np.swapaxes(t, -1, -2)
    return 0.5 * (out + np.swapaxes(out, -1, -2))


def availability(used, sys_idx, n_sys: int):
    """Per epoch: the number of states ``n = 3 + systems in view`` ``(E,)`` and whether
    ``m >= n + 1`` (a filter can update and be tested) ``(E,)`` for ``used`` ``(E, S)``."""
    from ..lsq import clock_columns

    used = np.asarray(used, dtype=bool)
    cc = clock_columns(sys_idx, n_sys)
    n_states = 3 + (used[:, :, None] & (cc[None] > 0)).any(axis=1).sum(-1)
    return n_states, used.sum(-1) >= n_states + 1


def initial_cloud(pos_ecef_m, clock_m, cov_enu, n_particles: int, model: ProcessModel,
                  rng: np.random.Generator, *, batch=(), vel_mean_mps=None,
                  vel_sigma_mps: float = 1.0, inflate: float = 1.0):
    """Particles drawn around a least-squares fix.

    Parameters
    ----------
    pos_ecef_m : (R, 3) fix; clock_m : (R, q) clocks (NaN clocks become 0).
    cov_enu : (R, 3 + q, 3 + q) fix covariance in ENU + clocks (m^2), as from
        :func:`raimcore.lsq.wls`.
    n_particles : N.
    model : the process model (velocity states, if any, start at ``vel_mean_mps`` (R, 3),
        default 0, +- ``vel_sigma_mps``).
    rng : random generator.
    batch : extra batch axes inserted after ``R`` (e.g. ``(Q,)`` filters of a bank).
    inflate : factor on the standard deviations.

    Returns
    -------
    (R, *batch, N, D) particles.
    """
    pos = np.asarray(pos_ecef_m, dtype=float)
    r_n = pos.shape[0]
    q = model.n_clk
    cov = cov_enu_to_ecef(pos, cov_enu) + 1e-9 * np.eye(3 + q)
    chol = np.linalg.cholesky(cov) * inflate
    shape = (r_n,) + tuple(batch) + (n_particles, 3 + q)
    z = rng.standard_normal(shape)
    extra = (slice(None),) + (None,) * (len(batch) + 1)
    mean = np.concatenate([pos, np.nan_to_num(np.asarray(clock_m, dtype=float))], axis=-1)
    draw = mean[extra] + np.einsum("r...ij,r...nj->r...ni",
                                   chol.reshape((r_n,) + (1,) * len(batch) + chol.shape[1:]), z)
    out = np.zeros(shape[:-1] + (model.dim,))
    out[..., :3] = draw[..., :3]
    out[..., model.clk0:] = draw[..., 3:]
    if model.kind == "cv":
        v0 = np.zeros((r_n, 3)) if vel_mean_mps is None else np.asarray(vel_mean_mps, float)
        out[..., 3:6] = v0[extra] + vel_sigma_mps * rng.standard_normal(shape[:-1] + (3,))
    return out


@dataclass(frozen=True)
class StepResult:
    """One filter-bank step.

    Attributes
    ----------
    log_pred : (...,) ``ln p(y | Y_{k-1})`` of each filter, approximated from its predicted
        particles and previous weights: ``ln sum_i w_{k-1}^(i) p(y | x_k^(i))`` (with equal
        weights after a resampling this is the spec's ``ln (1/N) sum_i p(y | x_k^(i))``).
    n_eff : (...,) effective sample size after the update, before resampling.
    estimate : (..., D) weighted-mean state after the update.
    resampled : (...,) bool.
    """

    log_pred: np.ndarray
    n_eff: np.ndarray
    estimate: np.ndarray
    resampled: np.ndarray


class ParticleBank:
    """A batch of SIR particle filters sharing one process model (persistent cloud state).

    Parameters
    ----------
    particles : (..., N, D) initial cloud (equal weights).
    model : the process model.
    n_threshold : resample when ``N_eff`` falls below it (default ``2N/3``, seed 002).
    """

    def __init__(self, particles, model: ProcessModel, n_threshold: float | None = None):
        self.particles = np.asarray(particles, dtype=float)
        self.model = model
        n = self.particles.shape[-2]
        self.log_w = np.full(self.particles.shape[:-1], -math.log(n))
        self.n_threshold = 2.0 * n / 3.0 if n_threshold is None else float(n_threshold)

    @property
    def n_particles(self) -> int:
        return self.particles.shape[-2]

    def step(self, dt_s, pos_sv_ecef_m, pr_m, mask, sys_idx, noise,
             rng: np.random.Generator, q_scale: float = 1.0,
             q_scale_vel: float = 1.0) -> StepResult:
        """Predict, weight by the likelihood, normalise, estimate, resample if needed.

        ``mask`` (..., S) says which measurements each filter scores (all False: predict
        only, ``log_pred = 0``). See :func:`log_likelihood` for the other arguments.
        """
        self.particles = predict(self.particles, dt_s, self.model, rng, q_scale, q_scale_vel)
        ll = log_likelihood(self.particles, pos_sv_ecef_m, pr_m, mask, sys_idx, noise,
                            self.model)
        # seed 002 eq. (weights): w_k = w_{k-1} p(z_k | x_k), then normalise.
        w, log_pred = normalise_log_weights(self.log_w + ll)
        n_eff = effective_sample_size(w)
        est = weighted_mean(self.particles, w)

        self.log_w = np.log(np.maximum(w, 1e-300))
        # Resample when N_eff < N_th = 2N/3 (seed 002, section 1).
        need = n_eff < self.n_threshold
        if need.any():
            # Only the filters that need it (flattened batch, rows picked by index).
            n, d = self.particles.shape[-2:]
            flat = self.particles.reshape(-1, n, d)
            rows = np.flatnonzero(need.reshape(-1))
            idx = systematic_resample(w.reshape(-1, n)[rows], rng)
            flat[rows] = np.take_along_axis(flat[rows], idx[..., None], axis=-2)
            log_w = self.log_w.reshape(-1, n)
            log_w[rows] = -math.log(n)
            self.particles = flat.reshape(self.particles.shape)
            self.log_w = log_w.reshape(self.log_w.shape)
        return StepResult(log_pred, n_eff, est, need)


# -- the bank of s + 1 filters and its log-likelihood ratios (seed 002 section 2) --------

@dataclass(frozen=True)
class BankRun:
    """A bank of s + 1 particle filters run over a scenario (``R`` data realisations).

    Filter 0 is the main filter (all used satellites); filter ``1 + j`` drops satellite
    ``j``. ``E`` epochs, ``S`` satellites, ``Q = S + 1`` filters.

    Attributes
    ----------
    estimate : (R, E, Q, D) weighted-mean states (NaN before the first fix).
    n_eff : (R, E, Q) effective sample sizes (NaN where no update).
    llr : (R, E, S) per-epoch LLR ``s_j(k)`` (0 where not scored).
    cum_llr : (R, E, S) ``S_j(k)``, the sum of ``s_j`` over the last ``window`` epochs
        (NaN for satellites not used at ``k``).
    beta : (R, E) ``max_j S_j(k)`` (NaN where not armed).
    argmax : (E,) / (R, E) int, the satellite achieving ``beta`` (-1 where not armed).
    available : (E,) bool, enough satellites to update and compare (m >= n + 1).
    armed : (E,) bool, available and the window filled after the burn-in.
    cloud : (E, K, D) K particles (every N/K-th) of the main filter of realisation 0 after
        each epoch's update and any resampling, NaN before the first fix; None unless
        asked for (``keep_cloud``).
    cloud_weight : (E, K) their weights, renormalised over the K, or None.
    """

    estimate: np.ndarray
    n_eff: np.ndarray
    llr: np.ndarray
    cum_llr: np.ndarray
    beta: np.ndarray
    argmax: np.ndarray
    available: np.ndarray
    armed: np.ndarray
    cloud: np.ndarray | None = None
    cloud_weight: np.ndarray | None = None


def _noise_weight(noise):
    """Least-squares weight 1/std^2 (1/m^2) of a noise model (scale if the std is
    infinite); per satellite for a :class:`~raimcore.measure.noise.Scaled` model."""
    std = np.asarray(noise.std_m, dtype=float)
    scale = getattr(noise, "scale", 1.0)
    return 1.0 / np.where(np.isfinite(std), std * std, (noise.sigma_m * scale) ** 2)


def robust_fix(pos_sv_ecef_m, pr_m, used, sys_idx, n_sys: int, noise, n_iter: int = 6):
    """The start fix: multi-start iteratively reweighted least squares under the noise model.

    A heavy-tailed outlier at the first epoch can put the plain least-squares fix tens of
    metres off (mostly along the poorly observed height-clock direction), and a particle
    cloud spread around it then takes minutes to move to the truth (spec section 3,
    "Start-up"). Starting from the all-in fix and from every leave-one-out fix, each
    iteration weights satellite ``i`` by the M-estimator weight of its residual under
    ``noise``, ``w_i = -(d ln p / dr)(r_i) / r_i`` (Student-t: ``(nu + 1) / (nu s^2 + r^2)``;
    Gaussian: ``1 / sigma^2``); of these local optima the one with the largest
    log-likelihood of all used residuals is kept.

    Parameters
    ----------
    pos_sv_ecef_m : (S, 3); pr_m : (R, S); used : (S,) bool; sys_idx : (S,).

    Returns
    -------
    LsqResult with batch shape (R,); its covariance uses the nominal ``1 / std^2`` weights.
    """
    from ..lsq import clock_columns, normal_solve, wls

    pr1 = np.asarray(pr_m, dtype=float)
    r_n, s_n = pr1.shape
    keep = np.vstack([np.ones(s_n, dtype=bool), ~np.eye(s_n, dtype=bool)]) & used  # (Q, S)
    pr = np.broadcast_to(pr1[:, None, :], (r_n,) + keep.shape)
    sv = np.broadcast_to(np.asarray(pos_sv_ecef_m, dtype=float), pr.shape + (3,))
    w0 = np.broadcast_to(np.where(used, _noise_weight(noise), 0.0), pr.shape)
    cc = clock_columns(sys_idx, n_sys)
    fix = wls(sv, pr, np.where(keep, w0, 0.0), sys_idx, n_sys)
    h_m = 1e-3 * noise.sigma_m

    def residuals(f):
        rng_m = np.linalg.norm(sv - np.nan_to_num(f.pos_ecef_m)[..., None, :], axis=-1)
        return np.where(used, np.nan_to_num(pr) - rng_m - np.nan_to_num(f.clock_m) @ cc.T,
                        0.0)

    for _ in range(n_iter):
        r = residuals(fix)
        r = np.where(np.abs(r) < h_m, h_m, r)
        slope = (noise.logpdf(r - h_m) - noise.logpdf(r + h_m)) / (2.0 * h_m)
        w = np.where(used, np.maximum(slope / r, 1e-12), 0.0)
        w = np.where(fix.available[..., None], w, 0.0)
        fix = wls(sv, pr, w, sys_idx, n_sys, x0_ecef_m=np.nan_to_num(fix.pos_ecef_m))
    score = np.where(used, noise.logpdf(residuals(fix)), 0.0).sum(-1)
    best = np.argmax(np.where(fix.available & np.isfinite(score), score, -np.inf), axis=-1)
    pick = lambda a: a[np.arange(r_n), best]  # noqa: E731
    out = type(fix)(*(pick(getattr(fix, f)) for f in fix.__dataclass_fields__))
    cov, _, _ = normal_solve(out.h_enu, w0[:, 0])
    return dataclasses.replace(out, cov_enu=np.where(out.available[..., None, None], cov,
                                                    np.nan))


def run_llr_bank(pos_sv_ecef_m, pr_m, used, t_s, sys_idx, n_sys: int, noise,
                 model: ProcessModel, *, n_particles: int, window: int, burn_in: int,
                 rng: np.random.Generator, scale=None, keep_cloud: int = 0) -> BankRun:
    """Run the bank of s + 1 SIR filters and the windowed LLR test (spec section 3).

    Parameters
    ----------
    pos_sv_ecef_m : (E, S, 3) satellite positions (m).
    pr_m : (R, E, S) pseudoranges of ``R`` independent realisations (m), NaN where unused.
    used : (E, S) bool, satellites tracked at each epoch (shared by the realisations).
    t_s : (E,) epoch times (s).
    sys_idx : (S,) system index of each satellite; n_sys : number of clock states.
    noise : the noise model (the filters' likelihood).
    model : the process model (``model.n_clk == n_sys``).
    n_particles, window, burn_in : N, W (epochs) and the epochs after the first fix whose
        LLRs are not accumulated (the cloud converging from the least-squares start).
    rng : random generator.
    scale : optional (E, S) per-satellite factor on the noise (the elevation model of a
        recording, :class:`~raimcore.measure.noise.Scaled`); None: the same noise for all.
    keep_cloud : keep this many particles of the main filter (realisation 0) per epoch
        for display (``BankRun.cloud``); 0: none.

    Returns
    -------
    BankRun. The filters start at the first epoch with ``m >= n + 1`` from a weighted
    least-squares fix of that epoch (spread by its covariance); until then everything is
    NaN / not available. Epochs with too few satellites only predict.
    """

    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    pr = np.asarray(pr_m, dtype=float)
    used = np.asarray(used, dtype=bool)
    r_n, e_n, s_n = pr.shape
    q_n = s_n + 1
    _, available = availability(used, sys_idx, n_sys)
    estimate = np.full((r_n, e_n, q_n, model.dim), np.nan)
    n_eff = np.full((r_n, e_n, q_n), np.nan)
    llr = np.zeros((r_n, e_n, s_n))
    # Filter masks: main = all, auxiliary j = all but j.
    drop = np.vstack([np.ones(s_n, dtype=bool), ~np.eye(s_n, dtype=bool)])  # (Q, S)
    if scale is not None:
        scale = np.where(used, np.broadcast_to(np.asarray(scale, dtype=float), used.shape), 1.0)

    def noise_at(k):
        return noise if scale is None else scaled(noise, scale[k])

    k0 = -1
    for k in np.flatnonzero(available):
        fix = robust_fix(sv[k], pr[:, k], used[k], sys_idx, n_sys, noise_at(k))
        if fix.available.all():
            k0 = int(k)
            break
    if k0 < 0:
        nan = np.full((r_n, e_n), np.nan)
        return BankRun(estimate, n_eff, llr, np.full((r_n, e_n, s_n), np.nan), nan,
                       np.full((r_n, e_n), -1), np.zeros(e_n, bool), np.zeros(e_n, bool))
    available[:k0] = False
    vel0, vel_sd = None, 1.0
    if model.kind == "cv":
        # Start velocity: difference of two robust fixes about 5 s apart.
        later = np.flatnonzero(available & (t_s >= t_s[k0] + 5.0))
        if later.size:
            k1 = int(later[0])
            fix1 = robust_fix(sv[k1], pr[:, k1], used[k1], sys_idx, n_sys, noise_at(k1))
            dt = t_s[k1] - t_s[k0]
            vel0 = np.nan_to_num((fix1.pos_ecef_m - fix.pos_ecef_m) / dt)
            vel_sd = 2.0 * math.sqrt(np.nanmax(np.trace(fix.cov_enu[:, :3, :3], axis1=1,
                                                         axis2=2))) / dt
    bank = ParticleBank(initial_cloud(fix.pos_ecef_m, fix.clock_m, fix.cov_enu, n_particles,
                                      model, rng, batch=(q_n,), vel_mean_mps=vel0,
                                      vel_sigma_mps=vel_sd, inflate=3.0), model)
    k_keep = min(int(keep_cloud), n_particles)
    cloud = cloud_w = None
    if k_keep > 0:
        pick = np.linspace(0, n_particles - 1, k_keep).round().astype(int)
        cloud = np.full((e_n, k_keep, model.dim), np.nan)
        cloud_w = np.full((e_n, k_keep), np.nan)
        cloud[k0] = bank.particles[0, 0][pick]
        cloud_w[k0] = 1.0 / k_keep
    est0 = np.zeros((r_n, model.dim))
    est0[:, :3] = fix.pos_ecef_m
    est0[:, model.clk0:] = np.nan_to_num(fix.clock_m)
    estimate[:, k0] = est0[:, None, :]
    first_llr = k0 + 1 + burn_in
    # Start-up annealing (spec section 3, "Start-up"): the process noise starts at about
    # the noise scale per step and decays to the model's over the burn-in, so a cloud
    # started around a poor first fix moves to the truth within the burn-in instead of
    # drifting there at q_pos (minutes) while the test is armed.
    boost = max(noise.sigma_m / max(model.q_pos_mps, 1e-3), 1.0)
    boost_vel = max(VEL_BOOST * vel_sd / max(model.q_vel_mps2, 1e-3), 1.0)
    for k in range(k0 + 1, e_n):
        frac = min((k - k0 - 1) / max(burn_in, 1), 1.0)
        q_scale = 1.0 + (boost - 1.0) * (1.0 - frac) ** 2
        q_scale_vel = 1.0 + (boost_vel - 1.0) * (1.0 - frac) ** 2
        mask = drop & used[k][None, :] if available[k] else np.zeros((q_n, s_n), bool)
        res = bank.step(t_s[k] - t_s[k - 1], sv[k][None, None], pr[:, k][:, None, :],
                        mask[None], sys_idx, noise_at(k), rng, q_scale, q_scale_vel)
        estimate[:, k] = res.estimate
        if cloud is not None:  # the posterior sample after the update (and any resampling)
            cloud[k] = bank.particles[0, 0][pick]
            wk = np.exp(bank.log_w[0, 0][pick])
            cloud_w[k] = wk / wk.sum()
        if available[k]:
            n_eff[:, k] = res.n_eff
            if k >= first_llr:
                # seed 002 LLR as the spec reads it: each filter scores its own set,
                # s_j(k) = ln p_aux_j(y^(-j) | Y_{k-1}) - ln p_main(y | Y_{k-1}).
                llr[:, k] = np.where(used[k], res.log_pred[:, 1:] - res.log_pred[:, :1], 0.0)
    # Sliding-window sum S_j(k) = sum_{t = k-W+1..k} s_j(t) (seed 002 section 2.2).
    c = np.concatenate([np.zeros((r_n, 1, s_n)), np.cumsum(llr, axis=1)], axis=1)
    lo = np.maximum(np.arange(e_n) + 1 - window, 0)
    cum = c[:, 1:] - c[:, lo]
    armed = available & (np.arange(e_n) >= first_llr + window - 1)
    cum = np.where(used[None], cum, np.nan)
    scored = np.where(used[None] & armed[None, :, None], cum, -np.inf)
    arg = np.argmax(scored, axis=-1)
    beta = np.take_along_axis(scored, arg[..., None], axis=-1)[..., 0]
    beta = np.where(armed[None], beta, np.nan)
    arg = np.where(armed[None], arg, -1)
    return BankRun(estimate, n_eff, llr, cum, beta, arg, available, armed, cloud, cloud_w)


# -- threshold calibration (spec section 3: "tau has no closed form") --------------------

#: In-memory cache of calibrated thresholds, keyed by :func:`calibration_key`.
_TAU_CACHE: dict[str, float] = {}


@dataclass(frozen=True)
class Calibration:
    """A Monte Carlo threshold calibration.

    Attributes
    ----------
    tau : the threshold for ``p_fa_window`` from the fault-free ``beta`` samples
        (:func:`threshold_from_samples`).
    beta : (R, M) the fault-free ``beta`` samples (M armed epochs per run).
    p_fa_window : target false-alarm probability per window (per armed epoch).
    """

    tau: float
    beta: np.ndarray
    p_fa_window: float


def calibrate_tau(pos_sv_ecef_m, pos_rx_ecef_m, sys_idx, n_sys: int, noise,
                  model: ProcessModel, *, n_particles: int, window: int, burn_in: int,
                  p_fa_window: float, n_runs: int, n_armed: int,
                  rng: np.random.Generator, dt_s: float = 1.0,
                  scale=None) -> Calibration:
    """Calibrate ``tau`` by fault-free Monte Carlo runs of the same bank.

    The geometry is frozen (satellites ``(S, 3)`` and receiver ``(3,)`` at one epoch: the
    lines of sight turn by well under a degree over a calibration run at 1 s epochs, a few
    degrees at 30 s); ``n_runs`` independent realisations of the noise are filtered at once
    (one more batch axis of the bank), each ``1 + burn_in + window + n_armed`` epochs long
    at the scenario's epoch interval ``dt_s`` (the process noise and a time-correlated
    noise model, ``noise.corr_s``, both depend on it); ``tau`` comes from the pooled
    ``beta(k)`` of the ``n_armed`` armed epochs of every run
    (:func:`threshold_from_samples`). ``scale`` (S,), optional: per-satellite noise factor
    (elevation model), used both to draw the noise and in the filters' likelihood.
    """
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    s_n = sv.shape[0]
    e_n = 1 + burn_in + window + n_armed
    t = np.arange(e_n, dtype=float) * check_positive("dt_s", dt_s)
    rng_m = np.linalg.norm(sv - np.asarray(pos_rx_ecef_m, dtype=float), axis=-1)
    noise = scaled(noise, scale)
    pr = rng_m + noise.sample(rng, (n_runs, e_n, s_n), t_s=t)
    run = run_llr_bank(np.broadcast_to(sv, (e_n, s_n, 3)), pr, np.ones((e_n, s_n), bool),
                       t, sys_idx, n_sys, noise, model,
                       n_particles=n_particles, window=window, burn_in=burn_in, rng=rng)
    beta = run.beta[:, run.armed]
    return Calibration(threshold_from_samples(beta, p_fa_window, window), beta, p_fa_window)


def threshold_from_samples(beta, p_fa: float, window: int = 1) -> float:
    """``tau`` with ``P(beta > tau) = p_fa`` from fault-free samples ``beta`` (R, M).

    A normal tail fitted on the centre of the sample (median, and the 50-90 % quantile
    spread / 1.2816): a window sum of 30 LLRs is close to normal (in seed 002 the 90, 95
    and 99 % quantiles sit at 1.28, 1.64 and 2.33 fitted standard deviations), and the fit
    extrapolates to a small ``p_fa`` that a few thousand correlated samples cannot
    resolve. Where the sample does resolve it (at least 5 expected exceedances among the
    ``R M / window`` roughly independent windows), the empirical ``1 - p_fa`` quantile is
    used if larger (a tail heavier than normal).
    """
    from scipy import stats

    b = np.asarray(beta, dtype=float)
    n_indep = b.size / max(window, 1)
    b = b[np.isfinite(b)]
    q50, q90 = np.quantile(b, [0.5, 0.9])
    tau = q50 + stats.norm.isf(p_fa) * (q90 - q50) / stats.norm.isf(0.1)
    if p_fa * n_indep >= 5:
        tau = max(tau, np.quantile(b, 1.0 - p_fa))
    return float(tau)


def calibration_key(pos_sv_ecef_m, pos_rx_ecef_m, sys_idx, noise, model: ProcessModel,
                    **config) -> str:
    """A string naming one calibration configuration.

    It holds the noise model, the process model, ``config`` (N, W, burn-in, p_fa, run
    counts) and the geometry as rounded local lines of sight (0.02 rad), so a scenario
    that changes only its faults, seed or duration reuses the same threshold.
    """
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    rx = np.asarray(pos_rx_ecef_m, dtype=float)
    lat, lon, _ = ecef_to_geodetic(rx)
    los = (sv - rx) @ enu_rotation(lat, lon).T
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    order = np.lexsort(los.T)
    geo = ",".join(f"{int(s)}:{int(round(a / 0.02))}:{int(round(b / 0.02))}:"
                   f"{int(round(c / 0.02))}"
                   for s, (a, b, c) in zip(np.asarray(sys_idx)[order], los[order], strict=True))
    cfg = ",".join(f"{k}={config[k]!r}" for k in sorted(config))
    return f"{noise!r}|{model!r}|{cfg}|{geo}"


def default_cache_path():
    """The optional on-disk threshold cache: ``$XDG_CACHE_HOME/raimcore/pf_llr_tau.json``
    (``~/.cache/raimcore/pf_llr_tau.json`` when ``XDG_CACHE_HOME`` is not set)."""
    import os
    from pathlib import Path

    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "raimcore" / "pf_llr_tau.json"


def cached_tau(key: str, compute, *, cache: str = "memory", path=None) -> float:
    """``tau`` for ``key`` from the cache, else ``compute()`` (a float) stored in it.

    Parameters
    ----------
    cache : ``"memory"`` (default: this process only), ``"disk"`` (also a JSON file at
        ``path``, default :func:`default_cache_path`, shared between processes and runs)
        or ``"off"`` (always recompute).
    """
    import json
    from pathlib import Path

    check_choice("tau_cache", cache, ("memory", "disk", "off"))
    if cache == "off":
        return float(compute())
    if key in _TAU_CACHE:
        return _TAU_CACHE[key]
    file = Path(path) if path is not None else default_cache_path()
    stored: dict[str, float] = {}
    if cache == "disk" and file.is_file():
        try:
            stored = json.loads(file.read_text())
        except (OSError, ValueError):
            stored = {}  # an unreadable cache is rebuilt, never trusted
        if key in stored:
            _TAU_CACHE[key] = float(stored[key])
            return _TAU_CACHE[key]
    tau = float(compute())
    _TAU_CACHE[key] = tau
    if cache == "disk":
        stored[key] = tau
        file.parent.mkdir(parents=True, exist_ok=True)
        file.write_text(json.dumps(stored, indent=0))
    return tau
