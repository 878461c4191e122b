"""SIR particle filters on the receiver state, vectorised over a bank of filters (seed 002).

Kernels (pure functions, the random generator always an argument) and one class for the
persistent state of a bank (:class:`ParticleBank`). Shapes follow the package rule, batch
axes first: ``(..., N, D)`` particles, ``(..., N)`` weights, where ``...`` is any batch of
filters (the bank of s + 1 filters, times Monte Carlo runs for the threshold calibration).

State layout (``D = 3 + 3 * (model == "cv") + q + drift``): ECEF position (m), then the
ECEF velocity (m/s) for the constant-velocity model, then one receiver clock offset per
system (m), then, with a clock-drift state (``q_drift_mps2`` not None), the receiver clock
drift (m/s), one for all systems: they share one oscillator.

Process models (spec section 3, "Filter"):

- ``"static"``: random walk, ``r_k = r_{k-1} + w``, ``w ~ N(0, q_pos^2 dt I)``;
- ``"cv"``: constant velocity, ``r_k = r_{k-1} + v_{k-1} dt``, ``v_k = v_{k-1} + w``,
  ``w ~ N(0, q_vel^2 dt I)`` (the position also gets the ``q_pos`` random walk);
- the receiver clock, with a drift state, is Brown & Hwang's two-state model (ref. [1],
  section 9.3): offset ``b_s`` of each system and the shared drift ``d``,
  ``b_s,k = b_s,k-1 + d_{k-1} dt + w_b,s + w_bd``, ``d_k = d_{k-1} + w_d``, with the
  white-frequency density ``q_clk^2 = c^2 S_f`` on each offset and the random-walk-frequency
  density ``q_drift^2 = c^2 S_g`` on the drift; over ``dt`` the pair ``(w_bd, w_d)`` has
  the covariance ``q_drift^2 [[dt^3/3, dt^2/2], [dt^2/2, dt]]`` and ``w_b,s`` the
  variance ``q_clk^2 dt`` (ref. [1] section 9.3). The defaults are a TCXO's
  (:data:`Q_CLK_TCXO_MPS`, :data:`Q_DRIFT_TCXO_MPS2`); a free-running receiver clock
  (hundreds of m/s of drift) is a drift to estimate, not process noise. The particle
  filters marginalise the drift (ref. [2]): the likelihood does not see it, so given a
  particle's offset history it is Gaussian; each particle carries its mean, the variance
  is common (:func:`predict`, :func:`drift_step_var`). Without a drift state (the kernel's
  default) the offsets are random walks with ``q_clk``.

Proposal (:func:`propose`, the default of :class:`ParticleBank`): the motion is drawn
from the state equation, the clock offsets close to what each filter's own measurements
say (ref. [3]; a defensive mixture with the prior, ref. [4]), and the weights carry the
ratio prior / proposal (the spec's "predict by the state equation" is the special case
``ParticleBank(..., proposal="prior")``). Over a 30 s interval
(recordings) the TCXO drift spreads the predicted offset by 19 m while the pseudoranges
fix it to decimetres: drawn from the state equation (:func:`predict`, the bootstrap
filter), 1-2 of 100 particles survived each step, the estimate followed them and the
predictive likelihoods behind the LLR became Monte Carlo noise (PF-LLR's tau on ESBC
rose from 100 to 296, above the time-correlated calibration's 279).

Clock jumps (a receiver steering its clock by whole milliseconds, or a reset) are
detected on the common-mode part of the innovations (:func:`clock_jump`) and the clock
offset re-initialised instead of filtered (:func:`run_llr_bank`, :func:`~raimcore.
algorithms.ekf.run_ekf`). Where the receiver itself says its clock restarted
(``clock_reset``: an Android phone's hardware-clock discontinuity, a RINEX "power failure"
flag) the offsets are re-initialised whatever the size of the jump (a duty-cycled phone's
restarts move its clock by tens of metres, far below :data:`CLOCK_JUMP_M`): centred on the
common-mode innovation with the diffuse prior :data:`CLOCK_RESET_SD_M` and decorrelated
from the rest of the state, so that epoch's test sees only the satellite-to-satellite part
of the innovations. The drift restarts with them (:data:`CLOCK_RESET_DRIFT_SD_MPS`) and is
learnt again at the next update, from the clock change since the restart, as at the start
(:func:`reset_epochs`); the offsets of that update are diffuse too. The LLRs of such epochs
leave out the clock's own share (:func:`clock_occam`).

Measurement model: ``rho_i = ||r - s_i|| + c dt_sys(i) + v_i`` with ``v_i`` from the
scenario's noise model (:mod:`raimcore.measure.noise`): the filter's likelihood is its ``logpdf``.

Kernels (:data:`KERNELS`): a bank step with the clock proposal is computed by the
``"reference"`` kernel (the plain numpy code of :func:`propose`), by the ``"fast"`` one,
which draws the same random numbers in the same order and applies the same formulas in
fewer, larger array passes: the (S, N) arrays satellite-major, the median by a
selection network (:func:`median_network`), one system's clock algebra in closed form,
resampling by counting copies, the cloud updated in place in cache-sized blocks; or by
the ``"numba"`` one (the default where numba is installed, the ``fast`` extra), compiled
loops over (filters, particles) doing the fast kernel's per-particle work in one pass
(:mod:`._pf_numba`) from the same random numbers, drawn with numpy. All three agree to
rounding (``tests/test_pf.py``); ``tests/benchmarks/bench_pf.py`` times them. Around them,
a bank keeps the per-filter terms of its last steps by their inputs (:class:`_PrepCache`:
they repeat while the satellites in view and the settled drift variance do), and
:func:`run_llr_bank` screens each epoch for a clock jump before computing it
(:func:`_may_jump`) and takes the LLRs of the whole run at once. The
environment variable ``RAIM_STUDIO_NUMBA=0`` keeps numba out (the ``"fast"`` kernel).
Calibrations are cached in memory and on disk (:func:`cached_samples`, :func:`cached_tau`).

References
----------
.. [1] R. G. Brown, P. Y. C. Hwang, *Introduction to Random Signals and Applied Kalman
   Filtering*, 4th ed., Wiley, 2012, section 9.3 (clock model) and Table 9.1 (Allan
   variance parameters of timing standards).
.. [2] T. Schön, F. Gustafsson, P.-J. Nordlund, "Marginalized particle filters for mixed
   linear/nonlinear state-space models", IEEE Trans. Signal Processing 53(7), 2005.
.. [3] A. Doucet, S. Godsill, C. Andrieu, "On sequential Monte Carlo sampling methods for
   Bayesian filtering", Statistics and Computing 10(3), 2000, 197-208 (section II.D, the
   optimal importance function and its local linearisation).
.. [4] T. C. Hesterberg, "Weighted average importance sampling and defensive mixture
   distributions", Technometrics 37(2), 1995, 185-194.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import special
from scipy.special import logsumexp

from .._validate import check_choice, check_positive
from ..constants import C_MPS
from ..geometry import ecef_to_geodetic, enu_rotation
from ..measure import MS_M
from ..measure.noise import Gaussian, GaussianMixture, Scaled, StudentT, scaled

__all__ = ["PROCESS_MODELS", "ProcessModel", "ParticleBank", "predict", "log_likelihood",
           "normalise_log_weights", "effective_sample_size", "systematic_resample",
           "weighted_mean", "initial_cloud", "clock_jump", "initial_drift", "drift_step_var",
           "propose", "PROPOSALS", "KERNELS", "PROPOSAL_DEFENSIVE", "Q_CLK_TCXO_MPS",
           "Q_DRIFT_TCXO_MPS2", "median_network", "DEFAULT_KERNEL",
           "CLOCK_JUMP_M", "MS_M", "CLOCK_RESET_SD_M", "CLOCK_RESET_DRIFT_SD_MPS",
           "reset_epochs", "clock_occam", "NUMBA_ENV", "numba_enabled", "numba_kernels"]

PROCESS_MODELS = ("static", "cv")
#: Proposals of :class:`ParticleBank`: ``"clock"`` (:func:`propose`, the default) or
#: ``"prior"`` (the state equation, :func:`predict`: the bootstrap filter).
PROPOSALS = ("clock", "prior")
#: Kernels of a :class:`ParticleBank` step: ``"numba"`` (compiled, :mod:`._pf_numba`),
#: ``"fast"`` (plain numpy) or ``"reference"`` (the plain numpy code the other two are
#: checked against); all three from the same random numbers.
KERNELS = ("numba", "fast", "reference")
#: Environment variable that keeps numba out when set to ``0``: the ``"fast"`` kernel runs
#: where ``"numba"`` is asked for or is the default.
NUMBA_ENV = "RAIM_STUDIO_NUMBA"


def numba_enabled() -> bool:
    """Whether the ``"numba"`` kernel may run: numba is installed (looked up, not
    imported: ``import raimcore`` stays light) and ``RAIM_STUDIO_NUMBA`` is not ``0``."""
    import importlib.util
    import os

    return (os.environ.get(NUMBA_ENV, "1").strip() != "0"
            and importlib.util.find_spec("numba") is not None)


@functools.lru_cache(maxsize=1)
def _numba_module():
    """The compiled kernels (:mod:`._pf_numba`), or None where numba does not import."""
    try:
        from . import _pf_numba
    except ImportError:
        return None
    return _pf_numba


def numba_kernels():
    """:mod:`._pf_numba` if the ``"numba"`` kernel can run here (:func:`numba_enabled`
    and numba imports), else None."""
    return _numba_module() if numba_enabled() else None


#: The kernel of a bank made without naming one: ``"numba"`` where numba is installed
#: and not switched off by ``RAIM_STUDIO_NUMBA=0`` at import, else ``"fast"``
#: (benchmarks set it to time the others through the whole pipeline).
DEFAULT_KERNEL = "numba" if numba_enabled() else "fast"
#: Floor of a log weight (the weights' floor 1e-300, as the reference kernel's).
_LOG_W_FLOOR = math.log(1e-300)
#: Particle-satellite pairs per likelihood chunk (about 0.5 MB per float64 temporary).
_CHUNK_ELEMENTS = 65536
#: The same for the fast kernel (ParticleBank(kernel="fast")), tuned on bench_pf.py.
_FAST_CHUNK_ELEMENTS = 32768
#: Constant-velocity start-up: the velocity process noise starts at VEL_BOOST x the start
#: velocity's standard deviation per sqrt(s) and decays like the position's (see
#: run_llr_bank); tuned on seed000-step with model = "cv" (sigma 3 and 33 m).
VEL_BOOST = 1.0

# Receiver clock (Brown & Hwang 2012, ref. [1]): Allan-variance coefficients of a
# temperature-compensated crystal oscillator, Table 9.1 ("compensated crystal").
TCXO_H0_S = 2e-19  # white frequency h_0 (s), ref. [1] Table 9.1
TCXO_HM2_PS = 2e-20  # random-walk frequency h_-2 (1/s), ref. [1] Table 9.1
#: Offset (white-frequency) density ``c sqrt(S_f)``, ``S_f = h_0 / 2`` (ref. [1] section 9.3):
#: 0.095 m / sqrt(s).
Q_CLK_TCXO_MPS = C_MPS * math.sqrt(TCXO_H0_S / 2.0)
#: Drift (random-walk-frequency) density ``c sqrt(S_g)``, ``S_g = 2 pi^2 h_-2`` (ref. [1]
#: section 9.3): 0.19 m/s / sqrt(s).
Q_DRIFT_TCXO_MPS2 = C_MPS * math.sqrt(2.0 * math.pi**2 * TCXO_HM2_PS)
#: A common-mode innovation (median over one system's satellites) above this is a receiver
#: clock jump, not a measurement error: a TCXO's offset is predicted to well under a metre
#: per second and a drift error of the start to tens of m/s, while a jump of a steering
#: receiver is 1 ms (299,792 m) and a reset arbitrary. A common-mode error on every
#: satellite of a system moves no position (the clock absorbs it), so no fault is hidden.
CLOCK_JUMP_M = 1000.0
#: Prior standard deviation (m) of a clock offset re-initialised where the receiver says
#: its clock restarted, after centring it on the common-mode innovation (whose error is
#: metres): diffuse, so the common mode adds about (error / CLOCK_RESET_SD_M)^2 ~ 1e-5 to a
#: test statistic, and the offset is set by this epoch's pseudoranges alone. The jump
#: detector's scale: any larger reset is a detected jump as well.
CLOCK_RESET_SD_M = CLOCK_JUMP_M
#: Prior standard deviation (m/s) of the clock drift from a restart on (diffuse): the drift
#: is learnt again from the next pair of epochs of one clock segment, as at the start
#: (:func:`initial_drift`). A restart may change the oscillator's frequency, and a
#: duty-cycled phone's drift cannot be followed across restarts (214 of the shared log's
#: 222 pairs of epochs straddle one). Measured on seed002 (restarts at 30 % of the epochs,
#: the drift changed by 1-10 m/s at each): kept, the error lands in the next test as a
#: common mode, EKF 26 % and PF-LLR 77 % false alarms; restarted, 2.4 % and 0.1 % (the
#: steady clock's 2.7 % and 0.0 %). Without a drift change, restarting costs no false
#: alarm; the position error grows (3D RMS x1.05 EKF, x1.3 PF-LLR with 30 % flagged).
CLOCK_RESET_DRIFT_SD_MPS = CLOCK_JUMP_M
#: Share of the clock proposal drawn from the state equation (:func:`propose`, a defensive
#: mixture, Hesterberg 1995): the importance ratio prior / proposal never exceeds
#: 1 / PROPOSAL_DEFENSIVE, whatever the tails of the likelihood (a Gaussian proposal
#: narrower than half the prior's variance alone gives the weights an infinite variance
#: under heavy-tailed noise); it costs that share of the particles when the measurements
#: pin the clock far better than the prediction, and nothing when they do not.
PROPOSAL_DEFENSIVE = 0.1


@dataclass(frozen=True)
class ProcessModel:
    """State model of the receiver.

    Attributes
    ----------
    kind : ``"static"`` or ``"cv"`` (constant velocity).
    n_clk : number of clock offset states (one per system).
    q_pos_mps : position random-walk density, m / sqrt(s).
    q_vel_mps2 : velocity random-walk density (``"cv"`` only), m/s / sqrt(s).
    q_clk_mps : clock offset density (white frequency), m / sqrt(s).
    q_drift_mps2 : clock drift random-walk density, m/s / sqrt(s); None: no drift state
        (the offsets are random walks; the kernel default, the algorithms' options carry a
        drift state).
    """

    kind: str = "static"
    n_clk: int = 1
    q_pos_mps: float = 0.1
    q_vel_mps2: float = 0.5
    q_clk_mps: float = 0.1
    q_drift_mps2: float | None = None

    def __post_init__(self):
        check_choice("model", self.kind, PROCESS_MODELS)
        check_positive("q_pos_mps", self.q_pos_mps, allow_zero=True)
        check_positive("q_vel_mps2", self.q_vel_mps2, allow_zero=True)
        check_positive("q_clk_mps", self.q_clk_mps, allow_zero=True)
        if self.q_drift_mps2 is not None:
            check_positive("q_drift_mps2", self.q_drift_mps2, allow_zero=True)

    @property
    def clk0(self) -> int:
        """Index of the first clock state."""
        return 6 if self.kind == "cv" else 3

    @property
    def clocks(self) -> slice:
        """The clock offset states."""
        return slice(self.clk0, self.clk0 + self.n_clk)

    @property
    def has_drift(self) -> bool:
        return self.q_drift_mps2 is not None

    @property
    def drift(self) -> int:
        """Index of the clock drift state (``dim - 1``; meaningful only with one)."""
        return self.clk0 + self.n_clk

    @property
    def dim(self) -> int:
        return self.clk0 + self.n_clk + int(self.has_drift)

    def clock_cov(self, dt_s: float) -> np.ndarray:
        """Process covariance ``(q + 1, q + 1)`` of the offsets and the drift over
        ``dt_s`` (ref. [1] section 9.3; the integrated drift noise is common to all
        offsets, the white-frequency part is per system); ``(q, q)`` without a drift."""
        q, dt = self.n_clk, max(float(dt_s), 0.0)
        if not self.has_drift:
            return self.q_clk_mps**2 * dt * np.eye(q)
        g = self.q_drift_mps2**2
        out = np.zeros((q + 1, q + 1))
        out[:q, :q] = self.q_clk_mps**2 * dt * np.eye(q) + g * dt**3 / 3.0
        out[:q, q] = out[q, :q] = g * dt**2 / 2.0
        out[q, q] = g * dt
        return out


def _move(x, noise, dt_s: float, model: ProcessModel, q_scale: float, q_scale_vel: float):
    """Position and velocity part of a prediction step, in place (standard normal
    ``noise`` (..., N, D), its motion columns used)."""
    sq1 = math.sqrt(max(dt_s, 0.0))
    sq = q_scale * sq1
    if model.kind == "cv":
        x[..., :3] += x[..., 3:6] * dt_s + model.q_pos_mps * sq * noise[..., :3]
        x[..., 3:6] += model.q_vel_mps2 * q_scale_vel * sq1 * noise[..., 3:6]
    else:
        x[..., :3] += model.q_pos_mps * sq * noise[..., :3]


def _condition_drift(x, e, model: ProcessModel, drift_var, dt: float, q_scale: float,
                     reset_var: float = 0.0):
    """Move the drift means of particles ``x`` (..., N, D) to their value given the drawn
    offset noise ``e`` (..., N, q), in place: ``d += c 1^T S^-1 e = c sum(e) / (a + q
    beta)`` (Sherman-Morrison on ``S = a I + beta 1 1^T``, see :func:`predict`)."""
    a, beta, c = _drift_terms(model, drift_var, dt, q_scale, reset_var)
    den = a + model.n_clk * beta
    gain = np.where(den > 0, c / np.where(den > 0, den, 1.0), 0.0)
    x[..., model.drift] += gain[..., None] * e.sum(-1)


def predict(particles, dt_s: float, model: ProcessModel, rng: np.random.Generator,
            q_scale: float = 1.0, q_scale_vel: float = 1.0, drift_var=0.0):
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
    q_scale_vel : the same for the velocity.
    drift_var : (...,) variance of the clock drift given a particle's history (m^2/s^2),
        with a drift state (see :class:`ParticleBank`).

    Returns
    -------
    (..., N, D) states at k (a new array).

    See Also
    --------
    propose : the same step with the clock offsets drawn close to the measurements (the
        filters' proposal).
    """
    x = np.array(particles, dtype=float, copy=True)
    sq = q_scale * math.sqrt(max(dt_s, 0.0))
    noise = rng.standard_normal(x.shape)
    _move(x, noise, dt_s, model, q_scale, q_scale_vel)
    clk = model.clocks
    x[..., clk] += model.q_clk_mps * sq * noise[..., clk]
    if model.has_drift:
        # Two-state clock (ref. [1] section 9.3), the drift marginalised (ref. [2]): each
        # particle carries the mean of its drift given its own offset history, the
        # variance drift_var (V) is common. The offsets move by that mean times dt plus a
        # noise e with covariance S = a I + beta 1 1^T: per system a = (q_clk q_scale)^2 dt,
        # common beta = V dt^2 + q_drift^2 dt^3 / 3 (the drift's uncertainty and its noise
        # integrated over the step); then the drift mean is conditioned on the drawn e,
        # d += c 1^T S^-1 e = c sum(e) / (a + q beta), c = V dt + q_drift^2 dt^2 / 2
        # (Sherman-Morrison). V's update is drift_step_var.
        dt = max(dt_s, 0.0)
        _, beta, _ = _drift_terms(model, drift_var, dt, q_scale)
        common = np.sqrt(beta)[..., None] * noise[..., model.drift]
        e = model.q_clk_mps * sq * noise[..., clk] + common[..., None]
        x[..., clk] += x[..., model.drift, None] * dt + common[..., None]
        _condition_drift(x, e, model, drift_var, dt, q_scale)
    return x


def propose(particles, dt_s: float, model: ProcessModel, rng: np.random.Generator,
            pos_sv_ecef_m, pr_m, mask, sys_idx, noise, q_scale: float = 1.0,
            q_scale_vel: float = 1.0, drift_var=0.0):
    """Draw the predicted particles from the filters' proposal: the state equation for the
    motion, the clock offsets drawn close to what this epoch's measurements say.

    A receiver clock is predicted far less well than a pseudorange measures it when the
    epochs are far apart: a TCXO's drift (``q_drift`` 0.19 m/s/sqrt(s), ref. [1]) spreads
    the offset by ``q_drift dt^(3/2) / sqrt(3)`` = 19 m over a 30 s interval, while
    10-20 pseudoranges of a recording fix it to a few decimetres. Drawn from the state
    equation (:func:`predict`, the bootstrap proposal), one or two of 100 particles land
    where the likelihood is: the filter degenerates (N_eff about 1.5), its estimate follows
    those few particles (their position errors included) and its predictive likelihood
    ``p(y | Y_{k-1})``, the LLR's ingredient, is a Monte Carlo lottery.

    The proposal here is the locally optimal one for the clock (ref. [3], section II.D),
    approximated: given a particle's moved position, the residuals ``rho_i - |s_i - r|``
    of each system's satellites in ``mask`` (this filter's own measurements) measure its
    offset; their median (robust to a fault on a minority) with the precision
    ``sum_i w_i / (pi / 2)`` (``w_i = 1 / std_i^2``, the median's efficiency) is combined
    with the offsets' Gaussian prior ``N(b + d dt, S)`` (:func:`predict`) into a Gaussian
    ``N(mu, P)`` per particle; the offsets are drawn from the defensive mixture
    ``(1 - alpha) N(mu, P) + alpha N(b + d dt, S)``, ``alpha =``
    :data:`PROPOSAL_DEFENSIVE` (ref. [4]), so the importance ratio
    ``r = p(x_k | x_{k-1}) / q(x_k | x_{k-1}, y_k)`` is at most ``1 / alpha`` and the
    weights keep a finite variance under heavy-tailed noise. When the prediction is much
    tighter than the measurements (1 s epochs), ``N(mu, P)`` is nearly the prior and ``r``
    nearly 1. The
    drift is then conditioned on the drawn offsets as in :func:`predict` (the marginalised
    drift needs only the sampled offset path, however it was drawn). Filters without a
    measurement, or without offset noise (``q_clk dt == 0``), draw from the state equation
    (``r = 1``).

    Parameters
    ----------
    particles, dt_s, model, rng, q_scale, q_scale_vel, drift_var : as :func:`predict`.
    pos_sv_ecef_m, pr_m, mask, sys_idx, noise : as :func:`log_likelihood` (the
        measurements each filter scores).

    Returns
    -------
    x : (..., N, D) states at k (a new array).
    log_ratio : (..., N) ``ln p(x_k | x_{k-1}) - ln q(x_k | x_{k-1}, y_k)``, to add to the
        log-likelihood in the weights and in the predictive likelihood.
    """
    x, log_ratio, _ = _propose(particles, dt_s, model, rng, pos_sv_ecef_m, pr_m, mask,
                               sys_idx, noise, q_scale, q_scale_vel, drift_var)
    return x, log_ratio


def _propose(particles, dt_s, model, rng, pos_sv_ecef_m, pr_m, mask, sys_idx, noise,
             q_scale, q_scale_vel, drift_var, reset_var: float = 0.0):
    """:func:`propose`, also returning the log-likelihood (..., N) of the drawn particles
    (:func:`log_likelihood`, from the residuals the proposal computed anyway).
    ``reset_var`` (m^2): at a clock restart, the offsets' prior variance about their
    prediction (:data:`CLOCK_RESET_SD_M` squared; 0 otherwise): they are then drawn from
    what the measurements say."""
    x = np.array(particles, dtype=float, copy=True)
    batch, n, q = x.shape[:-2], x.shape[-2], model.n_clk
    dt = max(float(dt_s), 0.0)
    sys_idx = np.asarray(sys_idx, dtype=int)
    # Every random number first, for the whole batch: the chunking below changes nothing.
    noise_std = rng.standard_normal(x.shape)
    z = rng.standard_normal(batch + (n, q))
    pick = rng.random(batch + (n,))  # < PROPOSAL_DEFENSIVE: the prior component
    _move(x, noise_std, dt_s, model, q_scale, q_scale_vel)
    clk = model.clocks
    a = (model.q_clk_mps * q_scale)**2 * dt + reset_var
    beta = np.zeros(batch)
    if model.has_drift:
        x[..., clk] += x[..., model.drift, None] * dt  # the prior mean b + d dt
        beta = np.broadcast_to(_drift_terms(model, drift_var, dt, q_scale)[1], batch)
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    s_n = sv.shape[-2]
    sv = np.broadcast_to(sv, batch + (s_n, 3))
    pr = np.broadcast_to(np.asarray(pr_m, dtype=float), batch + (s_n,))
    mask = np.broadcast_to(np.asarray(mask, dtype=bool), batch + (s_n,))
    t = _clock_terms(a, beta, mask, sys_idx, q, noise)
    informative, chol_s = t.informative, t.chol_s
    gain, chol_p, s_inv, p_inv = t.gain, t.chol_p, t.s_inv, t.p_inv
    half_logdet_s, half_logdet_p = t.half_logdet_s, t.half_logdet_p
    rows = int(np.prod(batch, dtype=int))
    flat = lambda arr, k: arr.reshape((rows,) + arr.shape[arr.ndim - k:])  # noqa: E731
    xf, svf, prf, mf = flat(x, 2), flat(sv, 2), flat(pr, 1), flat(mask, 1)
    zf, pick_f, inff, cs = flat(z, 2), flat(pick, 1), flat(informative, 0), flat(chol_s, 2)
    e = np.empty((rows, n, q))
    log_ratio = np.zeros((rows, n))
    ll = np.empty((rows, n))
    chunk = max(1, _CHUNK_ELEMENTS // max(n * s_n, 1))  # (N, S) temporaries in cache
    for i in range(0, rows, chunk):
        sl = slice(i, i + chunk)
        resid = _residuals(xf[sl], svf[sl], prf[sl], mf[sl], sys_idx, model)
        ec = np.einsum("rij,rnj->rni", cs[sl], zf[sl])  # the state equation's draw
        inf = inff[sl]
        if inf.any():
            centre = _system_median(resid, mf[sl], sys_idx, q)
            mu = np.einsum("rij,rnj->rni", flat(gain, 2)[sl], centre)
            alpha = PROPOSAL_DEFENSIVE
            eg = mu + np.einsum("rij,rnj->rni", flat(chol_p, 2)[sl], zf[sl])
            et = np.where((pick_f[sl] < alpha)[..., None], ec, eg)
            # ln r = ln N(e; 0, S) - ln((1 - alpha) N(e; mu, P) + alpha N(e; 0, S)),
            # at most -ln alpha (ref. [4]).
            d = et - mu
            log_s = (-flat(half_logdet_s, 0)[sl, None]
                     - 0.5 * np.einsum("rni,rij,rnj->rn", et, flat(s_inv, 2)[sl], et))
            log_p = (-flat(half_logdet_p, 0)[sl, None]
                     - 0.5 * np.einsum("rni,rij,rnj->rn", d, flat(p_inv, 2)[sl], d))
            lr = log_s - np.logaddexp(math.log1p(-alpha) + log_p, math.log(alpha) + log_s)
            ec = np.where(inf[:, None, None], et, ec)
            log_ratio[sl] = np.where(inf[:, None], lr, 0.0)
        e[sl] = ec
        resid -= ec[..., sys_idx]
        ll[sl] = np.einsum("rns,rs->rn", noise.logpdf(resid), mf[sl].astype(float))
    e = e.reshape(batch + (n, q))
    x[..., clk] += e
    if model.has_drift:
        _condition_drift(x, e, model, drift_var, dt, q_scale, reset_var)
    return x, log_ratio.reshape(batch + (n,)), ll.reshape(batch + (n,))


@dataclass(frozen=True)
class _ClockTerms:
    """Per filter, the Gaussians of the clock proposal (:func:`_propose`), batch shape
    ``(...)``: ``informative`` (...) bool; ``chol_s``, ``gain``, ``chol_p``, ``s_inv``,
    ``p_inv`` (..., q, q); ``half_logdet_s``, ``half_logdet_p`` (...) (None where ``a`` is
    0: nothing is informative then)."""

    informative: np.ndarray
    chol_s: np.ndarray
    gain: np.ndarray | None = None
    chol_p: np.ndarray | None = None
    s_inv: np.ndarray | None = None
    p_inv: np.ndarray | None = None
    half_logdet_s: np.ndarray | None = None
    half_logdet_p: np.ndarray | None = None


def _clock_terms(a: float, beta, mask, sys_idx, q: int, noise,
                 closed_form: bool = False) -> _ClockTerms:
    """The per-filter part of the clock proposal (:func:`_propose`): the prior of the offset
    noise ``e ~ N(0, S)``, ``S = a I + beta 1 1^T`` (``beta`` (...)), the precision ``lam``
    of each system's median residual (0 where the filter sees none of it, ``mask`` (..., S))
    and the Gaussian posterior ``N(mu = gain m, P)`` of ``e`` given the medians ``m``;
    ``closed_form``: one system's scalars without the matrix functions (the fast kernel)."""
    batch = np.shape(beta)
    lam = _median_precision(mask, sys_idx, q, noise)
    informative = (lam > 0).any(-1) & (a > 0)
    if not a > 0:  # no per-system noise: e is the common (drift) part, from the prior
        chol_s = np.zeros(batch + (q, q))
        chol_s[..., :, 0] = np.sqrt(beta)[..., None]
        return _ClockTerms(informative, chol_s)
    if q == 1 and closed_form:
        # The same in closed form (scalars per filter): P = S / (1 + lam S).
        s1 = a + np.asarray(beta, dtype=float)
        lam1 = lam[..., 0]
        den = 1.0 + lam1 * s1
        p1 = s1 / den
        col = lambda v: v[..., None, None]  # noqa: E731
        return _ClockTerms(informative, col(np.sqrt(s1)), col(s1 * lam1 / den),
                           col(np.sqrt(p1)), col(1.0 / s1), col(1.0 / p1),
                           0.5 * np.log(s1), 0.5 * np.log(p1))
    s_cov = a * np.eye(q) + np.asarray(beta)[..., None, None] * np.ones((q, q))
    chol_s = np.linalg.cholesky(s_cov)
    # Gaussian posterior of e given the medians m ~ N(e, diag(lam)^-1), in a form that
    # allows lam = 0: G = diag(sqrt(lam)), M = I + G S G, mu = S G M^-1 G m,
    # P = S - S G M^-1 G S.
    g = np.sqrt(lam)
    sg = s_cov * g[..., None, :]
    m_inv = np.linalg.inv(np.eye(q) + g[..., :, None] * sg)
    gain = sg @ m_inv * g[..., None, :]
    p_cov = s_cov - sg @ m_inv @ np.swapaxes(sg, -1, -2)
    chol_p = np.linalg.cholesky(0.5 * (p_cov + np.swapaxes(p_cov, -1, -2)))
    s_inv, p_inv = np.linalg.inv(s_cov), np.linalg.inv(p_cov)
    half_logdet_s = np.log(np.diagonal(chol_s, axis1=-2, axis2=-1)).sum(-1)
    half_logdet_p = np.log(np.diagonal(chol_p, axis1=-2, axis2=-1)).sum(-1)
    return _ClockTerms(informative, chol_s, gain, chol_p, s_inv, p_inv, half_logdet_s,
                       half_logdet_p)



def _median_precision(mask, sys_idx, q: int, noise):
    """``lam`` (..., q) of :func:`_clock_terms`: the precision ``sum_i w_i / (pi / 2)`` of
    each system's median residual over the satellites in ``mask`` (..., S)."""
    w = np.where(mask, _noise_weight(noise), 0.0)
    return w @ (sys_idx[:, None] == np.arange(q)).astype(float) / (math.pi / 2.0)


def _checked_sys_idx(sys_idx, q: int) -> np.ndarray:
    """``sys_idx`` as the compiled loops take it (C-contiguous, writeable int64), checked to
    lie in ``0..q - 1`` (they index the clock states by it, unchecked); the last few
    checked index arrays are kept (a bank steps with the same one epoch after epoch)."""
    key = (np.asarray(sys_idx).tobytes(), np.asarray(sys_idx).dtype.str, q)
    hit = _SYS_IDX.get(key)
    if hit is not None:
        return hit
    out = np.require(sys_idx, np.int64, ["C", "W"])
    if out.size and not 0 <= out.min() <= out.max() < q:
        raise ValueError(f"sys_idx must lie in 0..{q - 1} (the model's clock states)")
    out = out.copy()  # kept: never the caller's array
    if len(_SYS_IDX) >= 8:
        _SYS_IDX.clear()
    _SYS_IDX[key] = out
    return out


_SYS_IDX: dict[tuple, np.ndarray] = {}


@functools.lru_cache(maxsize=8)
def _unit_scale(rows: int, s_n: int):
    """(rows, S) ones and zeros: the per-satellite noise factor of a model that has none,
    and its logarithm (read-only for the compiled loops, never written)."""
    return np.ones((rows, s_n)), np.zeros((rows, s_n))


# -- the fast kernel of a bank step (ParticleBank(kernel="fast")) ----------------------------
# The same random numbers in the same order and the same formulas as the reference
# (_propose, normalise_log_weights, ...), with fewer and larger array operations: the
# per-filter algebra in closed form for one system, the median by a selection network
# instead of a sort of every particle's residuals, matrix products instead of einsum,
# temporaries reused in place. Results agree with the reference to rounding
# (tests/test_pf.py, the agreement tests).

#: Largest number of a system's satellites whose median uses a selection network (above
#: it: a sort, as the reference).
_NETWORK_MAX = 24
#: Below this many values a sort is quicker than a network's per-comparator overhead
#: (measured on 6 satellites: 4,200 values, 7 filters x 100 particles, network 15 us, sort
#: 28 us; 1,260 values 11 and 9 us).
_NETWORK_MIN_VALUES = 4096


def _batcher_pairs(lo: int, hi: int):
    """Comparators of Batcher's odd-even merge sort of wires ``lo..hi`` (inclusive, a
    power of two of them)."""
    if hi - lo >= 1:
        mid = lo + (hi - lo) // 2
        yield from _batcher_pairs(lo, mid)
        yield from _batcher_pairs(mid + 1, hi)
        yield from _batcher_merge(lo, hi, 1)


def _batcher_merge(lo: int, hi: int, r: int):
    step = 2 * r
    if step < hi - lo:
        yield from _batcher_merge(lo, hi, step)
        yield from _batcher_merge(lo + r, hi, step)
        yield from ((i, i + r) for i in range(lo + r, hi - r, step))
    else:
        yield (lo, lo + r)


@functools.lru_cache(maxsize=256)
def median_network(n_wires: int, outputs: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
    """A selection network: the comparators ``(i, j)`` (``i < j``; min to ``i``, max to
    ``j``) that put the values ranked ``outputs`` (0-based) of ``n_wires`` values on those
    wires.

    Batcher's odd-even merge sort on the next power of two (K. E. Batcher, "Sorting networks
    and their applications", AFIPS 1968), the wires from ``n_wires`` on held at +inf (their
    comparators do nothing and are dropped), pruned backwards to the comparators that
    decide ``outputs``. Masked values set to +inf sort last, so the median of the first
    ``k`` of them is read on wires ``(k - 1) // 2`` and ``k // 2``.

    >>> median_network(3, (1,))  # Batcher's 4-wire sort without the wire 3
    ((0, 1), (0, 2), (1, 2))
    """
    size = 1 << max(n_wires - 1, 0).bit_length()
    net = [(i, j) for i, j in _batcher_pairs(0, size - 1) if j < n_wires]
    need, keep = set(outputs), []
    for i, j in reversed(net):
        if i in need or j in need:
            keep.append((i, j))
            need |= {i, j}
    return tuple(reversed(keep))


def _median_plan(mask, sys_idx, n_sys: int):
    """Per system, what :func:`_masked_median` needs of ``mask`` (R, S) and ``sys_idx``
    alone, or None for a system no filter sees: its satellites ``cols`` (all of them:
    None), the masked-out entries (R, S_s), the counts (R,) > 0, the order statistics
    ``lo``, ``hi`` (R,) and whether they are the same for every filter. The last few
    masks' plans are kept (a bank's masks change only when the satellites in view do)."""
    key = (mask.shape, mask.tobytes(), sys_idx.tobytes(), n_sys)
    plan = _MEDIAN_PLANS.get(key)
    if plan is not None:
        return plan
    plan = []
    for s in range(n_sys):
        cols = np.flatnonzero(sys_idx == s)
        m = mask[:, cols]
        cnt = m.sum(-1)
        if cols.size == 0 or not cnt.any():
            plan.append(None)
            continue
        lo, hi = np.maximum((cnt - 1) // 2, 0), cnt // 2
        uniform = bool((lo == lo[0]).all() and (hi == hi[0]).all())
        outputs = tuple(sorted(set(lo.tolist()) | set(hi.tolist())))
        every = cols.size == sys_idx.size  # one system: no gather needed
        plan.append((None if every else cols, ~m, cnt[:, None] > 0, lo, hi, uniform,
                     outputs, cols.size))
    if len(_MEDIAN_PLANS) >= 16:
        _MEDIAN_PLANS.clear()
    _MEDIAN_PLANS[key] = plan
    return plan


_MEDIAN_PLANS: dict[tuple, list] = {}


def _masked_median(resid, mask, sys_idx, n_sys: int):
    """:func:`_system_median` in the fast kernel's layout: ``resid`` (R, S, N) (satellite
    before particle), ``mask`` (R, S) -> (R, n_sys, N). The same values (the same order
    statistics, averaged the same way), by a selection network over the satellites
    (:func:`median_network`): each comparator is one pass over (R, N) values; by a sort
    along the satellites for few values (below :data:`_NETWORK_MIN_VALUES`) or many
    satellites (above :data:`_NETWORK_MAX`)."""
    r_n, _, n = resid.shape
    out = np.zeros((r_n, n_sys, n))
    for s, plan in enumerate(_median_plan(mask, np.asarray(sys_idx), n_sys)):
        if plan is None:
            continue
        cols, off, seen, lo, hi, uniform, outputs, size = plan
        if size > _NETWORK_MAX or r_n * size * n <= _NETWORK_MIN_VALUES:
            buf = resid[:, cols, :] if cols is not None else resid.copy()
            buf[off] = np.inf
            buf.sort(axis=1)
            if uniform:
                med = buf[:, lo[0]] + buf[:, hi[0]]
            else:
                rows = np.arange(r_n)
                med = buf[rows, lo] + buf[rows, hi]
        else:
            # The wires (S_s, R, N), each a contiguous (R, N) array.
            buf = (resid[:, cols, :] if cols is not None else resid).transpose(1, 0, 2).copy()
            buf[off.T] = np.inf
            wires = list(buf)
            for i, j in median_network(size, outputs):
                a, b = wires[i], wires[j]
                wires[i] = np.minimum(a, b)
                np.maximum(a, b, out=b)
            if uniform:
                med = wires[lo[0]] + wires[hi[0]]
            else:
                rows = np.arange(r_n)
                st = np.stack(wires)
                med = st[lo, rows] + st[hi, rows]
        med *= 0.5
        out[:, s] = np.where(seen, med, 0.0)
    return out


def _residuals_fast(x, sv, pr, mask, sys_idx, model: ProcessModel):
    """:func:`_residuals` in the fast kernel's layout: ``x`` (R, N, D), ``sv`` (R, S, 3),
    ``pr``, ``mask`` (R, S) -> (R, S, N), satellite before particle, so that every
    array operation runs along the particles. ``|s - r|^2 = |r|^2 - 2 s.r + |s|^2`` as one
    matrix product in ECEF (the rounding of the squared range, 0.1 m^2 at 2e7 m, is below
    1e-8 m of range, as in the reference); where ``mask`` is False the values are finite
    and never used (the likelihood weighs them by 0, the median skips them)."""
    d = x.shape[-1]
    m = np.zeros(sv.shape[:-1] + (d,))
    m[..., :3] = -2.0 * sv
    r2 = m @ np.swapaxes(x, -1, -2)  # (R, S, N)
    xx = np.square(x)
    r2 += (xx @ _unit_rows(d, 3))[:, None, :]
    r2 += np.einsum("rsk,rsk->rs", sv, sv)[:, :, None]
    np.sqrt(r2, out=r2)
    np.subtract(np.where(mask & np.isfinite(pr), pr, 0.0)[:, :, None], r2, out=r2)
    if model.n_clk == 1:
        r2 -= x[:, None, :, model.clk0]
    else:
        r2 -= np.moveaxis(x[..., model.clk0 + sys_idx], -1, 1)
    return r2


@functools.lru_cache(maxsize=16)
def _unit_rows(d: int, k: int) -> np.ndarray:
    """(d,) ones on the first ``k`` entries, zeros after."""
    out = np.zeros(d)
    out[:k] = 1.0
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=4)
def _motion_pattern(size: int, d: int, k: int) -> np.ndarray:
    """(size * d,) flat pattern: 1 on the first ``k`` components of each of ``size``
    states, 0 on the rest (a contiguous multiplier in place of a strided slice)."""
    out = np.tile(_unit_rows(d, k), size)
    out.flags.writeable = False
    return out


def _move_fast(x, noise, dt_s: float, model: ProcessModel, q_scale: float,
               q_scale_vel: float):
    """:func:`_move` on a C-contiguous ``x`` (..., N, D): for the static model the position
    noise is added as one contiguous pass over the states (the slice ``[..., :3]`` makes
    numpy loop over 3 values at a time), the same values; the constant-velocity model uses
    :func:`_move`. ``noise`` is overwritten."""
    if model.kind != "static" or not (x.flags.c_contiguous and noise.flags.c_contiguous):
        _move(x, noise, dt_s, model, q_scale, q_scale_vel)
        return
    flat = noise.reshape(-1)
    flat *= _motion_pattern(flat.size // x.shape[-1], x.shape[-1], 3)
    flat *= model.q_pos_mps * (q_scale * math.sqrt(max(dt_s, 0.0)))  # as _move's
    x.reshape(-1)[...] += flat


def _log_likelihood_rows(noise, resid, mask_f):
    """``sum_s mask_s ln p(resid_s)`` (R, N) for ``resid`` (R, S, N) (overwritten) and
    ``mask_f`` (R, 1, S) float: the noise model's ``logpdf``, in place for a Gaussian and a
    Student-t model (the same formula, its constant added once per filter), else the
    model's own ``logpdf``."""
    count = mask_f[:, 0, :].sum(-1)[:, None]
    if type(noise) is StudentT:
        nu, s = noise.nu, noise.sigma_m
        c = (special.gammaln((nu + 1) / 2) - special.gammaln(nu / 2)
             - 0.5 * math.log(nu * math.pi) - math.log(s))  # noise.StudentT.logpdf
        resid *= 1.0 / (s * math.sqrt(nu))
        np.square(resid, out=resid)
        np.log1p(resid, out=resid)
        out = (mask_f @ resid)[:, 0]
        out *= -0.5 * (nu + 1)
        out += c * count
        return out
    if type(noise) is Gaussian:
        s = noise.sigma_m
        resid *= 1.0 / s
        np.square(resid, out=resid)
        out = (mask_f @ resid)[:, 0]
        out *= -0.5
        out -= (math.log(s) + 0.5 * math.log(2.0 * math.pi)) * count
        return out
    if isinstance(noise, Scaled):  # the scale is per satellite: move it to the last axis
        return (mask_f @ np.swapaxes(noise.logpdf(np.swapaxes(resid, -1, -2)), -1, -2))[:, 0]
    return (mask_f @ noise.logpdf(resid))[:, 0]


def _rows_times(mat, v):
    """``v @ mat^T`` for rows: ``mat`` (R, q, q), ``v`` (R, N, q) -> (R, N, q)
    (``einsum("rij,rnj->rni")``)."""
    return v @ np.swapaxes(mat, -1, -2)


def _quad(v, mat):
    """``v^T mat v`` for rows: ``v`` (R, N, q), ``mat`` (R, q, q) -> (R, N)."""
    return np.einsum("rni,rni->rn", v @ np.swapaxes(mat, -1, -2), v)


def _blocks(rows: int, n: int, s_n: int):
    """Blocks ``(row slice, particle slice)`` of a bank's per-particle work of about
    :data:`_FAST_CHUNK_ELEMENTS` particle-satellite pairs: whole filters while they fit,
    else one filter at a time in runs of particles (every particle is independent there)."""
    per_row = max(n * s_n, 1)
    if per_row <= _FAST_CHUNK_ELEMENTS:
        step = _FAST_CHUNK_ELEMENTS // per_row
        for i in range(0, rows, step):
            yield slice(i, i + step), slice(None)
        return
    run = max(1, _FAST_CHUNK_ELEMENTS // max(s_n, 1))
    for i in range(rows):
        for j in range(0, n, run):
            yield slice(i, i + 1), slice(j, j + run)


class _PrepCache:
    """Per-filter terms of a bank's last few steps (:func:`_fast_terms`,
    :meth:`ParticleBank._prep_numba`), by their inputs and for one noise model (kept
    alive, compared by identity). They depend on the masks, the noise model, the step and
    the drift variance only: between changes of the satellites in view, and once the drift
    variance has settled (its Riccati step reaches a fixed point within tens of epochs), a
    bank's steps repeat them."""

    def __init__(self, size: int = 4):
        self.size, self.noise, self.items = size, None, {}

    def get(self, key, noise):
        return self.items.get(key) if noise is self.noise else None

    def put(self, key, noise, value) -> None:
        if noise is not self.noise:
            self.noise, self.items = noise, {}
        if len(self.items) >= self.size:
            self.items.clear()
        self.items[key] = value


def _fast_terms(model: ProcessModel, batch, mask_b, sys_idx, noise, dt_s: float,
                q_scale: float, drift_var, reset_var: float):
    """The per-filter inputs of :func:`_propose_fast`, flattened over the filters (rows):
    masks (rows, S) and as floats (rows, 1, S), the clock proposal's terms
    (:func:`_clock_terms`), whether any filter is informative, the drift's gain and the
    drift variance after the step (:func:`drift_step_var`; None without a drift state)."""
    q = model.n_clk
    dt = max(float(dt_s), 0.0)
    rows = math.prod(batch)
    s_n = mask_b.shape[-1]
    a = (model.q_clk_mps * q_scale)**2 * dt + reset_var
    beta = np.zeros(batch)
    drift_gain = drift_var_next = None
    if model.has_drift:
        drift_var_next = drift_step_var(model, drift_var, dt_s, q_scale, reset_var)
        beta = np.broadcast_to(_drift_terms(model, drift_var, dt, q_scale)[1], batch)
        # _condition_drift's gain per filter, applied block by block (_propose_fast).
        a_d, beta_d, c_d = _drift_terms(model, np.broadcast_to(drift_var, batch), dt, q_scale,
                                        reset_var)
        den = a_d + q * beta_d
        drift_gain = np.where(den > 0, c_d / np.where(den > 0, den, 1.0), 0.0).reshape(rows)

    def flat(arr, k):  # (rows, *last k axes of arr), broadcast over the batch
        tail = arr.shape[arr.ndim - k:]
        if arr.shape[:arr.ndim - k] != batch:
            arr = np.broadcast_to(arr, batch + tail)
        return arr.reshape((rows,) + tail)

    t = _clock_terms(a, beta, mask_b, sys_idx, q, noise, closed_form=True)
    mf = mask_b.reshape(rows, s_n).copy()  # kept: never a view of the caller's masks
    inff, cs = flat(t.informative, 0), flat(t.chol_s, 2)
    any_inf = bool(inff.any())
    gain = chol_p = s_inv = p_inv = hls = hlp = None
    if any_inf:
        gain, chol_p = flat(t.gain, 2), flat(t.chol_p, 2)
        s_inv, p_inv = flat(t.s_inv, 2), flat(t.p_inv, 2)
        hls, hlp = flat(t.half_logdet_s, 0), flat(t.half_logdet_p, 0)
    return (mf, mf.astype(float)[:, None, :], inff, cs, any_inf, gain, chol_p, s_inv,
            p_inv, hls, hlp, drift_gain, drift_var_next)


def _propose_fast(x, dt_s, model, rng, pos_sv_ecef_m, pr_m, mask, sys_idx, noise,
                  q_scale, q_scale_vel, drift_var, reset_var: float = 0.0, cache=None):
    """:func:`_propose` on C-contiguous particles ``x`` (..., N, D), updated in place: the
    same draws and formulas, the (S, N) arrays satellite-major, one system's clock in
    scalars, every per-particle step (move, residuals, proposal, likelihood, drift) done
    block by block (:func:`_blocks`); returns ``(log_ratio, ll)`` (..., N) and the drift
    variance after the step (:func:`drift_step_var`; None without a drift state).
    ``cache``: a :class:`_PrepCache` keeping the per-filter terms (:func:`_fast_terms`)
    across steps."""
    batch, n, q, d = x.shape[:-2], x.shape[-2], model.n_clk, x.shape[-1]
    dt = max(float(dt_s), 0.0)
    sys_idx = np.asarray(sys_idx, dtype=int)
    # One draw for both standard normal arrays (a Generator fills an array element by
    # element in C order: the same numbers as two draws one after the other).
    rows = math.prod(batch)
    size_x = rows * n * d
    normals = rng.standard_normal(size_x + rows * n * q)
    noise_std, z = normals[:size_x].reshape(x.shape), normals[size_x:]
    pick = rng.random(rows * n)
    clk = model.clocks
    xf, noise_f = x.reshape((rows, n, d)), noise_std.reshape((rows, n, d))
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    s_n = sv.shape[-2]
    mask = np.asarray(mask, dtype=bool)
    mask_b = mask if mask.shape == batch + (s_n,) else np.broadcast_to(mask, batch + (s_n,))
    key = (mask_b.shape, mask_b.tobytes(), sys_idx.tobytes(), float(dt_s), q_scale,
           reset_var, np.shape(drift_var), np.asarray(drift_var).tobytes())
    terms = None if cache is None else cache.get(key, noise)
    if terms is None:
        terms = _fast_terms(model, batch, mask_b, sys_idx, noise, dt_s, q_scale, drift_var,
                            reset_var)
        if cache is not None:
            cache.put(key, noise, terms)
    (mf, mwf, inff, cs, any_inf, gain, chol_p, s_inv, p_inv, hls, hlp, drift_gain,
     drift_var_next) = terms
    svf = np.empty((rows, s_n, 3))
    svf.reshape(batch + (s_n, 3))[...] = sv
    prf = np.asarray(pr_m, dtype=float)
    if prf.shape != batch + (s_n,):
        prf = np.broadcast_to(prf, batch + (s_n,))
    prf = prf.reshape(rows, s_n)
    zf, pick_f = z.reshape(rows, n, q), pick.reshape(rows, n)
    log_ratio = np.zeros((rows, n))
    ll = np.empty((rows, n))
    alpha = PROPOSAL_DEFENSIVE
    log_a, log_1ma = math.log(alpha), math.log1p(-alpha)
    for sl, sp in _blocks(rows, n, s_n):
        pp = (sl, sp)  # (rows, particles) of this block: its arrays stay in cache
        xb = xf[pp]  # a contiguous view: whole filters, or a run of one filter's particles
        _move_fast(xb, noise_f[pp], dt_s, model, q_scale, q_scale_vel)
        if model.has_drift:  # the prior mean b + d dt
            if q == 1:
                xb[..., model.clk0] += xb[..., model.drift] * dt
            else:
                xb[..., clk] += xb[..., model.drift, None] * dt
        resid = _residuals_fast(xb, svf[sl], prf[sl], mf[sl], sys_idx, model)
        inf = inff[sl]
        if q == 1:  # scalars per particle: (r, N) arrays
            zc = zf[sl, sp, 0]
            ec = cs[sl, 0] * zc  # the state equation's draw
            if any_inf and inf.any():
                mu = _masked_median(resid, mf[sl], sys_idx, 1)[:, 0]
                mu *= gain[sl, 0]
                et = chol_p[sl, 0] * zc
                et += mu
                np.copyto(et, ec, where=pick_f[pp] < alpha)
                log_s = np.square(et)
                log_s *= -0.5 * s_inv[sl, 0]
                log_s -= hls[sl, None]
                mu -= et  # -d: the quadratic form does not see the sign
                log_p = np.square(mu)
                log_p *= -0.5 * p_inv[sl, 0]
                log_p -= hlp[sl, None]
                log_p += log_1ma
                lr = log_s - np.logaddexp(log_p, log_s + log_a)
                ec = et if inf.all() else np.where(inf[:, None], et, ec)
                log_ratio[pp] = lr if inf.all() else np.where(inf[:, None], lr, 0.0)
            xb[..., model.clk0] += ec
            if model.has_drift:
                xb[..., model.drift] += drift_gain[sl, None] * ec
            resid -= ec[:, None, :]
        else:
            ec = _rows_times(cs[sl], zf[pp])
            if any_inf and inf.any():
                centre = np.swapaxes(_masked_median(resid, mf[sl], sys_idx, q), -1, -2)
                mu = _rows_times(gain[sl], centre)
                et = _rows_times(chol_p[sl], zf[pp])
                et += mu
                np.copyto(et, ec, where=(pick_f[pp] < alpha)[..., None])
                log_s = _quad(et, s_inv[sl])
                log_s *= -0.5
                log_s -= hls[sl, None]
                mu -= et
                log_p = _quad(mu, p_inv[sl])
                log_p *= -0.5
                log_p -= hlp[sl, None]
                log_p += log_1ma
                lr = log_s - np.logaddexp(log_p, log_s + log_a)
                ec = np.where(inf[:, None, None], et, ec)
                log_ratio[pp] = np.where(inf[:, None], lr, 0.0)
            xb[..., clk] += ec
            if model.has_drift:
                xb[..., model.drift] += drift_gain[sl, None] * ec.sum(-1)
            resid -= np.moveaxis(ec, -1, 1)[:, sys_idx, :]
        ll[pp] = _log_likelihood_rows(noise, resid, mwf[sl])
    return log_ratio.reshape(batch + (n,)), ll.reshape(batch + (n,)), drift_var_next


def _resample_fast(w, rng: np.random.Generator):
    """:func:`systematic_resample` of rows ``w`` (G, N), as flat indices into (G * N): the
    same uniform draw, each particle's copies counted instead of searched: the points
    ``(u + k) / N`` below a cumulative weight ``c`` number ``ceil(N c - u)``, so particle
    ``i`` is copied ``ceil(N c_i - u) - ceil(N c_{i-1} - u)`` times (``np.repeat``: linear
    in N, no binary search)."""
    g, n = w.shape
    u = rng.random((g, 1))
    c = np.cumsum(w, axis=-1)
    c /= c[:, -1:]
    c[:, -1] = 1.0
    c *= n
    c -= u
    np.ceil(c, out=c)
    np.maximum(c, 0.0, out=c)  # np.clip's values (up to the sign of a zero), quicker
    np.minimum(c, n, out=c)
    c[:, 1:] -= c[:, :-1].copy()  # the copies of each particle
    return np.repeat(np.arange(g * n), c.astype(np.intp).reshape(-1))


def _drift_terms(model: ProcessModel, drift_var, dt: float, q_scale: float,
                 reset_var: float = 0.0):
    """``a`` (per-system offset noise), ``beta`` (common offset noise) and ``c`` (drift -
    offset covariance) of one prediction step (see :func:`predict`), shaped like
    ``drift_var``; ``reset_var`` (m^2): the prior variance of offsets re-initialised at a
    clock restart, independent of everything else (it adds to ``a``)."""
    v = np.asarray(drift_var, dtype=float)
    g = model.q_drift_mps2**2
    a = (model.q_clk_mps * q_scale)**2 * dt + reset_var
    return a, v * dt**2 + g * dt**3 / 3.0, v * dt + g * dt**2 / 2.0


def drift_step_var(model: ProcessModel, drift_var, dt_s: float, q_scale: float = 1.0,
                   reset_var: float = 0.0):
    """The drift variance after a :func:`predict` step (the Riccati step of the
    marginalised drift, ref. [2]): ``V + q_drift^2 dt - q c^2 / (a + q beta)`` (a clock
    restart's ``reset_var`` in ``a``: the offsets then say nothing about the drift)."""
    dt = max(float(dt_s), 0.0)
    a, beta, c = _drift_terms(model, drift_var, dt, q_scale, reset_var)
    den = a + model.n_clk * beta
    red = np.where(den > 0, model.n_clk * c * c / np.where(den > 0, den, 1.0), 0.0)
    return np.maximum(np.asarray(drift_var, float) + model.q_drift_mps2**2 * dt - red, 0.0)


def _in_chunks(kernel, particles, pos_sv_ecef_m, pr_m, mask, tail=()):
    """``kernel(x, sv, pr, mask)`` -> (..., N, *tail) over the broadcast batch, in chunks of
    filters when it is large: the (N, S) temporaries stay in cache, so a big batch is never
    slower than a loop over its filters."""
    x = np.asarray(particles)
    sv = np.asarray(pos_sv_ecef_m, dtype=float)
    mask = np.asarray(mask, dtype=bool)
    pr = np.asarray(pr_m, dtype=float)
    n, s_n = x.shape[-2], sv.shape[-2]
    batch = np.broadcast_shapes(x.shape[:-2], sv.shape[:-2], pr.shape[:-1], mask.shape[:-1])
    rows = int(np.prod(batch, dtype=int))
    chunk = max(1, _CHUNK_ELEMENTS // max(n * s_n, 1))
    if rows <= chunk:
        return kernel(x, sv, pr, mask)
    flat = [np.broadcast_to(a, batch + a.shape[-k:]).reshape((rows,) + a.shape[-k:])
            for a, k in ((x, 2), (sv, 2), (pr, 1), (mask, 1))]
    out = np.empty((rows, n) + tuple(tail))
    for i in range(0, rows, chunk):
        sl = slice(i, i + chunk)
        out[sl] = kernel(flat[0][sl], flat[1][sl], flat[2][sl], flat[3][sl])
    return out.reshape(batch + (n,) + tuple(tail))


def _residuals(x, sv, pr, mask, sys_idx, model: ProcessModel):
    """``rho_i - |s_i - r| - b_sys(i)`` (..., N, S) of particles ``x`` (..., N, D) (0 where
    ``mask`` is False or the pseudorange NaN)."""
    # ||s - r||^2 = |s|^2 + |r|^2 - 2 s.r as one matmul: no (..., N, S, 3) temporary.
    # Relative to a point near the receiver the cancellation error is below 1e-8 m.
    ref = x[(0,) * (x.ndim - 1)][:3]
    pos = x[..., :3] - ref
    sv = sv - ref
    r2 = (np.einsum("...nk,...nk->...n", pos, pos)[..., None]
          + np.einsum("...sk,...sk->...s", sv, sv)[..., None, :]
          - 2.0 * pos @ np.swapaxes(sv, -1, -2))
    clk = x[..., model.clk0 + np.asarray(sys_idx, dtype=int)]
    pr = np.where(mask, np.nan_to_num(pr), 0.0)
    return np.where(mask[..., None, :], pr[..., None, :] - np.sqrt(r2) - clk, 0.0)


def _system_median(resid, mask, sys_idx, n_sys: int):
    """Per particle and system, the median of the residuals ``resid`` (..., N, S) over the
    system's satellites in ``mask`` (..., S) -> (..., N, n_sys); 0 where there is none."""
    sys_idx = np.asarray(sys_idx, dtype=int)
    mask = np.broadcast_to(np.asarray(mask, dtype=bool)[..., None, :], resid.shape)
    out = np.zeros(resid.shape[:-1] + (n_sys,))
    for s in range(n_sys):
        cols = np.flatnonzero(sys_idx == s)
        if cols.size == 0:
            continue
        m = mask[..., cols]
        v = np.sort(np.where(m, resid[..., cols], np.inf), axis=-1)
        k = m.sum(-1, keepdims=True)
        med = 0.5 * (np.take_along_axis(v, np.maximum((k - 1) // 2, 0), -1)
                     + np.take_along_axis(v, k // 2, -1))[..., 0]
        out[..., s] = np.where(k[..., 0] > 0, med, 0.0)
    return out


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
    def kernel(x, sv, pr, mask):
        lp = noise.logpdf(_residuals(x, sv, pr, mask, sys_idx, model))
        return np.einsum("...ns,...s->...n", lp, mask.astype(float))

    return _in_chunks(kernel, particles, pos_sv_ecef_m, pr_m, mask)


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
                  vel_sigma_mps: float = 1.0, inflate: float = 1.0, drift_mps=None):
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
    drift_mps : (R,) clock drift (m/s, default 0) of a model with a drift state
        (:func:`initial_drift`): the drift slot (conditional mean) of every particle; its
        variance is kept by :class:`ParticleBank`.

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
    out[..., model.clocks] = draw[..., 3:]
    if model.kind == "cv":
        v0 = np.zeros((r_n, 3)) if vel_mean_mps is None else np.asarray(vel_mean_mps, float)
        out[..., 3:6] = v0[extra] + vel_sigma_mps * rng.standard_normal(shape[:-1] + (3,))
    if model.has_drift:
        d0 = np.broadcast_to(0.0 if drift_mps is None else np.asarray(drift_mps, float),
                             (r_n,))
        out[..., model.drift] = d0[extra]
    return out


def initial_drift(pos_sv0_ecef_m, pos_sv1_ecef_m, pr0_m, pr1_m, used, sys_idx, n_sys: int,
                  pos_rx_ecef_m, dt_s: float, weights, vel_rx_ecef_mps=None,
                  solve_motion: bool = False):
    """Receiver clock drift from the first two epochs ``dt_s`` apart: the difference of
    their clock estimates, each solved with the first fix's position (moved by the start
    velocity, if any), robustly.

    For a receiver that stays put (or moves as predicted) the range change is known, so
    each satellite seen at both epochs gives the clock change
    ``(rho_1 - |s_1 - r_1|) - (rho_0 - |s_0 - r_0|)``; the median over a system's
    satellites is robust to an outlier at either epoch (the difference of two snapshot
    fixes is not: one heavy-tailed error moves a fix's clock by tens of metres, and the
    drift by tens of m/s), and the position error of the first fix cancels to first order.

    Parameters
    ----------
    pos_sv0_ecef_m, pos_sv1_ecef_m : (S, 3) satellite positions at the two epochs (m).
    pr0_m, pr1_m : (R, S) pseudoranges (m).
    used : (S,) bool, satellites used at both epochs.
    sys_idx : (S,) system index; n_sys : number of systems.
    pos_rx_ecef_m : (R, 3) the first fix (m).
    dt_s : time between the epochs (s), > 0.
    weights : (S,) or (R, S) ``1 / sigma^2`` of one pseudorange (1/m^2).
    vel_rx_ecef_mps : (R, 3) start velocity, or None (static).
    solve_motion : a moving receiver of unknown velocity: solve the position change and
        the clock changes from the differences by weighted least squares (weights
        ``w / 2``) instead (not robust; less precise by the geometry's dilution).

    Returns
    -------
    drift_mps : (R,) inverse-variance weighted mean over the systems of the median clock
        change / dt (0 where no satellite is common).
    sigma_mps : (R,) its standard deviation, ``sqrt(2 (pi / 2) / sum w) / dt`` of the best
        system (the median's efficiency under Gaussian noise; inf where none).
    """
    r0 = np.asarray(pos_rx_ecef_m, dtype=float)
    r1 = r0 if vel_rx_ecef_mps is None else r0 + np.asarray(vel_rx_ecef_mps, float) * dt_s
    rho0 = np.linalg.norm(np.asarray(pos_sv0_ecef_m, float)[None] - r0[:, None], axis=-1)
    rho1 = np.linalg.norm(np.asarray(pos_sv1_ecef_m, float)[None] - r1[:, None], axis=-1)
    change = (np.asarray(pr1_m, float) - rho1) - (np.asarray(pr0_m, float) - rho0)
    used = np.asarray(used, dtype=bool)
    sys_idx = np.asarray(sys_idx, dtype=int)
    w = np.broadcast_to(np.asarray(weights, dtype=float), change.shape)
    drift = np.zeros((change.shape[0], n_sys))
    var = np.full((change.shape[0], n_sys), np.inf)
    solved = False
    if solve_motion:
        from ..lsq import clock_columns, normal_solve

        los = np.asarray(pos_sv1_ecef_m, float)[None] - r0[:, None]
        a = np.concatenate([-los / np.linalg.norm(los, axis=-1, keepdims=True),
                            np.broadcast_to(clock_columns(sys_idx, n_sys),
                                            los.shape[:-1] + (n_sys,))], axis=-1)
        wd = np.where(used, 0.5 * w, 0.0)
        n_inv, present, ok = normal_solve(a, wd)
        if ok.all():
            x = np.einsum("rij,rsj,rs,rs->ri", n_inv, a, wd, np.where(used, change, 0.0))
            pres = present[:, 3:]
            drift = np.where(pres, x[:, 3:] / dt_s, 0.0)
            var = np.where(pres, np.diagonal(n_inv, axis1=-2, axis2=-1)[:, 3:] / dt_s**2,
                           np.inf)
            solved = True  # else singular geometry: the median (static) estimate below
    for s in range(0 if solved else n_sys):
        m = used & (sys_idx == s)
        if not m.any():
            continue
        drift[:, s] = np.median(change[:, m], axis=-1) / dt_s
        var[:, s] = 2.0 * (math.pi / 2.0) / w[:, m].sum(-1) / dt_s**2
    inv = np.where(np.isfinite(var), 1.0 / var, 0.0)
    tot = inv.sum(-1)
    out = np.where(tot > 0, (inv * drift).sum(-1) / np.maximum(tot, 1e-300), 0.0)
    return out, np.sqrt(var.min(-1))


def clock_jump(resid_m, mask, sys_idx, n_sys: int, threshold_m: float = CLOCK_JUMP_M):
    """Receiver clock jumps seen in the predicted residuals of one epoch.

    The common-mode part of the residuals (measured minus predicted pseudoranges) of each
    system is their median over the system's satellites in ``mask``: robust to a fault on
    a minority of them, and a clock jump (a receiver steering its clock by whole
    milliseconds, or a reset) moves every one of them by the same amount while the
    differential part stays normal. Above ``threshold_m`` (:data:`CLOCK_JUMP_M`) it is a
    jump, and the filter re-initialises that system's clock offset by it instead of
    testing it (a common-mode error moves no position, so no fault is hidden).

    Parameters
    ----------
    resid_m : (..., S) predicted residuals (m).
    mask : (..., S) bool, the satellites used.
    sys_idx : (S,) system index; n_sys : number of systems.
    threshold_m : jump threshold (m).

    Returns
    -------
    (..., n_sys) the jump of each system's clock (m), 0 where none (or no satellite).
    """
    r = np.asarray(resid_m, dtype=float)
    mask = np.asarray(mask, dtype=bool) & ~np.isnan(r)
    sys_idx = np.asarray(sys_idx, dtype=int)
    out = np.zeros(np.broadcast_shapes(r.shape, mask.shape)[:-1] + (n_sys,))
    if not (mask & (np.abs(r) > threshold_m)).any():
        return out  # no residual above the threshold: no median above it either
    for s in range(n_sys):
        m = mask & (sys_idx == s)
        if not m.any():
            continue
        # The median of each row's satellites in m (nanmedian's values, without its cost):
        # the others sorted last as +inf, the middle order statistics averaged.
        v = np.sort(np.where(m, r, np.inf), axis=-1)
        k = m.sum(-1, keepdims=True)
        med = 0.5 * (np.take_along_axis(v, np.maximum((k - 1) // 2, 0), -1)
                     + np.take_along_axis(v, k // 2, -1))[..., 0]
        med = np.nan_to_num(np.where(k[..., 0] > 0, med, 0.0))  # none: no jump
        out[..., s] = np.where(np.abs(med) > threshold_m, med, 0.0)
    return out


def reset_epochs(clock_reset, available, k0: int) -> tuple[np.ndarray, np.ndarray]:
    """Where a filter started at ``k0`` re-initialises its clock.

    Parameters
    ----------
    clock_reset : (E,) bool, the receiver says its clock restarted
        (:attr:`raimcore.measure.Measurements.clock_reset`).
    available : (E,) bool, the epochs the filter updates at.
    k0 : the filter's first epoch.

    Returns
    -------
    reset : (E,) bool, the available epochs after ``k0`` with a restart flagged at them or
        since the previous available epoch (a restart during an outage is applied at the
        next update; one at or before ``k0`` is the start's): new clock offsets.
    relearn : (E,) bool, the first available epoch after a run of ``reset`` epochs that
        is not one: where a restarted drift is learnt again, from the clock change since
        the reset epoch before it (as the start's, :func:`initial_drift`).

    >>> reset, relearn = reset_epochs([0, 1, 0, 1, 0, 0, 1, 1, 0], [1] * 3 + [0] + [1] * 5, 0)
    >>> reset.astype(int), relearn.astype(int)
    (array([0, 1, 0, 0, 1, 0, 1, 1, 0]), array([0, 0, 1, 0, 0, 1, 0, 0, 1]))
    """
    flags = np.asarray(clock_reset, dtype=bool)
    reset = np.zeros(flags.shape, dtype=bool)
    relearn = np.zeros(flags.shape, dtype=bool)
    idx = np.flatnonzero(np.asarray(available, dtype=bool) & (np.arange(flags.size) > k0))
    if idx.size:
        count = np.cumsum(flags)
        prev = np.r_[k0, idx[:-1]]
        reset[idx] = count[idx] != count[prev]
        relearn[idx] = reset[prev] & ~reset[idx]
    return reset, relearn


def clock_occam(used, sys_idx, n_sys: int, noise) -> tuple[np.ndarray, np.ndarray]:
    """What the LLRs ``s_j`` of an epoch whose clock offsets are drawn anew carry that says
    nothing about satellite ``j``.

    The main filter integrates each system's offset out over that system's satellites, a
    factor ``sqrt(2 pi / W_s)`` (Gaussian; ``W_s`` the sum of the weights ``1 / std^2`` of
    the system's used satellites), auxiliary filter ``j`` over one satellite fewer,
    ``sqrt(2 pi / (W_s - w_j))``: ``s_j`` gains ``0.5 ln(W_s / (W_s - w_j))`` (0.09 for six
    equal satellites) that a known clock does not give, so the windowed LLRs would creep
    above those of the steady clock the threshold is calibrated on at each restart.

    Returns
    -------
    occam : (S,) ``0.5 ln(W_s / (W_s - w_j))``, to subtract (0 for unused satellites).
    alone : (S,) bool, the only used satellite of its system: nothing else sees its clock,
        so it is not tested at such an epoch (``s_j = 0``, as for an unused satellite).

    >>> occam, alone = clock_occam([1, 1, 1, 1, 1, 1, 0, 1], [0] * 6 + [1, 1], 2,
    ...                            type("N", (), {"std_m": 2.0, "sigma_m": 2.0})())
    >>> np.round(occam, 3)
    array([0.091, 0.091, 0.091, 0.091, 0.091, 0.091, 0.   , 0.   ])
    >>> alone.astype(int)
    array([0, 0, 0, 0, 0, 0, 0, 1])
    """
    used = np.asarray(used, dtype=bool)
    cc = (np.asarray(sys_idx, dtype=int)[:, None] == np.arange(n_sys)[None, :]).astype(float)
    w = np.where(used, np.broadcast_to(_noise_weight(noise), used.shape), 0.0)
    w_sys = (w @ cc) @ cc.T  # (S,) the W_s of each satellite's system
    rest = w_sys - w
    alone = used & (rest <= 0.0)
    tested = used & ~alone
    occam = np.where(tested, 0.5 * np.log(np.where(tested, w_sys, 1.0)
                                          / np.where(tested, rest, 1.0)), 0.0)
    return occam, alone


def jump_variance(weights, sys_idx, n_sys: int):
    """Variance (..., n_sys) of the median common-mode estimate of :func:`clock_jump`:
    ``(pi / 2) / sum_i w_i`` over each system's satellites (the median's asymptotic
    efficiency under Gaussian noise), ``w_i = 1 / sigma_i^2`` (..., S), 0 for unused."""
    w = np.asarray(weights, dtype=float)
    cc = np.asarray(sys_idx, dtype=int)[:, None] == np.arange(n_sys)[None, :]
    wsum = w @ cc.astype(float)
    return np.where(wsum > 0, (math.pi / 2.0) / np.maximum(wsum, 1e-300), 0.0)


@dataclass(frozen=True)
class StepResult:
    """One filter-bank step.

    Attributes
    ----------
    log_pred : (...,) ``ln p(y | Y_{k-1})`` of each filter, approximated from its predicted
        particles and previous weights: ``ln sum_i w_{k-1}^(i) p(y | x_k^(i)) r^(i)``, with
        ``r = p(x_k | x_{k-1}) / q(x_k | x_{k-1}, y)`` the proposal's importance ratio (1 for
        the state equation; with equal weights after a resampling this is the spec's
        ``ln (1/N) sum_i p(y | x_k^(i))``, an unbiased estimate either way).
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
    drift_var : (...,) or a number: the variance (m^2/s^2) of the clock drift given a
        particle's history, common to the particles of a filter (a model with a drift
        state; the particles' drift slot holds each one's conditional mean, :func:`predict`).
    proposal : ``"clock"`` (default): the clock offsets drawn close to each filter's own
        measurements and the weights corrected by prior / proposal (:func:`propose`);
        ``"prior"``: drawn from the state equation (:func:`predict`, the bootstrap filter,
        which degenerates when the clock is predicted much less well than it is measured).
    kernel : ``"numba"``, ``"fast"`` or ``"reference"`` (:data:`KERNELS`; None:
        :data:`DEFAULT_KERNEL`): how a step with the clock proposal is computed. All draw
        the same random numbers in the same order and agree to rounding (the agreement
        tests in ``tests/test_pf.py``); the fast kernel updates the cloud in place with
        fewer array passes, the numba kernel in compiled loops (:mod:`._pf_numba`), the
        reference is the plain numpy code both are checked against. ``"numba"`` where
        numba is missing or switched off (:func:`numba_kernels`) is ``"fast"``; a noise
        model the compiled loops do not know (other than Gaussian, Student-t, the
        Gaussian mixture, or one of those scaled per satellite) is stepped by ``"fast"``.

    Attributes
    ----------
    kernel : the kernel that runs (after any fall-back from ``"numba"``).

    The cloud is copied: stepping a bank never changes the array it was made from.
    """

    def __init__(self, particles, model: ProcessModel, n_threshold: float | None = None,
                 drift_var=0.0, proposal: str = "clock", kernel: str | None = None):
        self.particles = np.array(particles, dtype=float, order="C", copy=True)
        self.model = model
        self.proposal = check_choice("proposal", proposal, PROPOSALS)
        self.kernel = check_choice("kernel", DEFAULT_KERNEL if kernel is None else kernel,
                                   KERNELS)
        if self.kernel == "numba" and numba_kernels() is None:
            self.kernel = "fast"
        n = self.particles.shape[-2]
        self.log_w = np.full(self.particles.shape[:-1], -math.log(n))
        self.n_threshold = 2.0 * n / 3.0 if n_threshold is None else float(n_threshold)
        self.drift_var = np.array(np.broadcast_to(np.asarray(drift_var, dtype=float),
                                                  self.particles.shape[:-2]))
        # The per-filter terms of the last few steps (_fast_terms, _prep_numba).
        self._prep = _PrepCache()

    @property
    def n_particles(self) -> int:
        return self.particles.shape[-2]

    def step(self, dt_s, pos_sv_ecef_m, pr_m, mask, sys_idx, noise,
             rng: np.random.Generator, q_scale: float = 1.0,
             q_scale_vel: float = 1.0, reset_var: float = 0.0) -> StepResult:
        """Predict, weight by the likelihood, normalise, estimate, resample if needed.

        ``mask`` (..., S) says which measurements each filter scores (all False: predict
        only, ``log_pred = 0``). See :func:`log_likelihood` for the other arguments.
        ``reset_var`` > 0: the receiver clock restarted, the offsets' prior variance about
        their prediction (m^2, :func:`_propose`); such a step always uses the clock
        proposal (drawn from a diffuse prior, no particle would land on the measurements).
        """
        clock = self.proposal == "clock" or reset_var != 0.0
        if self.kernel == "numba" and clock:
            nb = _numba_module()
            codes = _noise_codes(noise)
            if codes is not None:
                return self._step_numba(nb, codes, dt_s, pos_sv_ecef_m, pr_m, mask, sys_idx,
                                        noise, rng, q_scale, q_scale_vel, reset_var)
        if self.kernel != "reference" and clock:
            return self._step_fast(dt_s, pos_sv_ecef_m, pr_m, mask, sys_idx, noise, rng,
                                   q_scale, q_scale_vel, reset_var)
        drift_var = self.drift_var
        if self.proposal == "prior" and reset_var == 0.0:
            self.particles = predict(self.particles, dt_s, self.model, rng, q_scale,
                                     q_scale_vel, drift_var)
            log_ratio = 0.0
        else:
            self.particles, log_ratio, ll = _propose(
                self.particles, dt_s, self.model, rng, pos_sv_ecef_m, pr_m, mask, sys_idx,
                noise, q_scale, q_scale_vel, drift_var, reset_var)
        if self.model.has_drift:
            self.drift_var = drift_step_var(self.model, drift_var, dt_s, q_scale, reset_var)
        if self.proposal == "prior" and reset_var == 0.0:
            ll = log_likelihood(self.particles, pos_sv_ecef_m, pr_m, mask, sys_idx, noise,
                                self.model)
        # seed 002 eq. (weights): w_k = w_{k-1} p(z_k | x_k), then normalise; drawn from
        # the proposal q, times p(x_k | x_{k-1}) / q(x_k | x_{k-1}, z_k) (ref. [3] eq. 6).
        w, log_pred = normalise_log_weights(self.log_w + ll + log_ratio)
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

    def _step_fast(self, dt_s, pos_sv_ecef_m, pr_m, mask, sys_idx, noise, rng, q_scale,
                   q_scale_vel, reset_var) -> StepResult:
        """:meth:`step` with the fast kernel (:func:`_propose_fast`): the same random
        numbers, the cloud updated in place, the weights normalised by one max / exp /
        sum, the resampled filters gathered at once (:func:`systematic_resample` over the
        flattened bank: one cumsum and one searchsorted)."""
        x = self.particles
        drift_var = self.drift_var
        log_ratio, ll, drift_var_next = _propose_fast(
            x, dt_s, self.model, rng, pos_sv_ecef_m, pr_m, mask, sys_idx, noise, q_scale,
            q_scale_vel, drift_var, reset_var, cache=self._prep)
        if drift_var_next is not None:
            self.drift_var = drift_var_next.copy()  # changed in place by jumps and restarts
        # seed 002 eq. (weights), as in step: w_k = w_{k-1} p(z_k | x_k) r, normalised.
        log_w = ll
        log_w += self.log_w
        log_w += log_ratio
        top = log_w.max(-1, keepdims=True)
        top = np.where(np.isfinite(top), top, 0.0)
        w = log_w - top
        np.exp(w, out=w)
        total = w.sum(-1, keepdims=True)
        w /= total
        log_norm = top + np.log(total)
        n_eff = 1.0 / np.einsum("...n,...n->...", w, w)
        est = (w[..., None, :] @ x)[..., 0, :]
        log_w -= log_norm
        np.maximum(log_w, _LOG_W_FLOOR, out=log_w)
        need = n_eff < self.n_threshold
        if need.any():
            n, d = x.shape[-2:]
            flat = x.reshape(-1, n, d)
            rows = np.flatnonzero(need.reshape(-1))
            idx = _resample_fast(w.reshape(-1, n)[rows], rng)
            idx += np.repeat((rows - np.arange(rows.size)) * n, n)  # rows of the bank
            picked = np.take(flat.reshape(-1, d), idx, axis=0)
            if rows.size == flat.shape[0]:
                flat.reshape(-1, d)[...] = picked
            else:
                flat[rows] = picked.reshape(-1, n, d)
            log_w.reshape(-1, n)[rows] = -math.log(n)
        self.log_w = log_w
        return StepResult(log_norm[..., 0], n_eff, est, need)

    def _prep_numba(self, key, mask_b, sys_idx, noise, dt_s, q_scale, reset_var, batch,
                    s_n: int):
        """The per-filter inputs of :meth:`_step_numba` (kept under ``key`` for ``noise``):
        the masks (rows, S), the clock proposal's terms (:func:`_clock_terms`) flattened
        over the filters, whether each filter is informative (rows,), the drift's gain
        (rows,) and the drift variance after the step (None without a drift state)."""
        model, q = self.model, self.model.n_clk
        rows = math.prod(batch)
        dt = max(float(dt_s), 0.0)
        a = (model.q_clk_mps * q_scale)**2 * dt + reset_var
        drift_var = self.drift_var
        beta = np.zeros(batch)
        drift_gain = np.zeros(rows)
        drift_var_next = None
        if model.has_drift:
            # _drift_terms once for the proposal's beta (it does not depend on reset_var),
            # the drift's gain (_propose_fast) and its variance after the step
            # (drift_step_var): the same operations on the same values.
            _, beta_d, c_d = _drift_terms(model, drift_var if np.shape(drift_var) == batch
                                          else np.broadcast_to(drift_var, batch), dt,
                                          q_scale, reset_var)
            beta = beta_d
            den = a + q * beta_d
            pos = den > 0
            safe = np.where(pos, den, 1.0)
            drift_gain = np.where(pos, c_d / safe, 0.0).reshape(rows)
            red = np.where(pos, q * c_d * c_d / safe, 0.0)
            drift_var_next = np.maximum(np.asarray(drift_var, float)
                                        + model.q_drift_mps2**2 * dt - red, 0.0)

        def flat(arr, k, dtype=float):  # (rows, *last k axes), broadcast, contiguous
            tail = arr.shape[arr.ndim - k:]
            if (arr.shape == batch + tail and arr.dtype == dtype and arr.flags.c_contiguous
                    and arr.flags.writeable):
                return arr.reshape((rows,) + tail)
            out = np.empty((rows,) + tail, dtype)
            out.reshape(batch + tail)[...] = arr
            return out

        t = _clock_terms(a, beta, mask_b, sys_idx, q, noise, closed_form=True)
        mf = flat(mask_b, 1, bool).copy()  # kept: never a view of the caller's masks
        if any(m is None for m in (t.gain, t.half_logdet_s)):
            zeros_qq, zeros_r = np.zeros((rows, q, q)), np.zeros(rows)
        mats = [zeros_qq if m is None else flat(m, 2)
                for m in (t.gain, t.chol_p, t.s_inv, t.p_inv)]
        hls, hlp = (zeros_r if v is None else flat(v, 0)
                    for v in (t.half_logdet_s, t.half_logdet_p))
        terms = (flat(t.informative, 0, bool), flat(t.chol_s, 2), *mats, hls, hlp)
        prep = (mf, terms, t.informative.reshape(rows), drift_gain, drift_var_next)
        self._prep.put(key, noise, prep)
        return prep

    def _step_numba(self, nb, codes, dt_s, pos_sv_ecef_m, pr_m, mask, sys_idx, noise, rng,
                    q_scale, q_scale_vel, reset_var) -> StepResult:
        """:meth:`_step_fast` by the compiled loops (:mod:`._pf_numba`): the same random
        numbers drawn in the same order here, the same per-filter terms
        (:func:`_clock_terms`), the per-particle work in one compiled pass."""
        model = self.model
        x = self.particles
        if not (x.flags.c_contiguous and x.flags.writeable and x.dtype == np.float64):
            x = np.require(x, float, ["C", "W"])
        batch, n, q, d = x.shape[:-2], x.shape[-2], model.n_clk, x.shape[-1]
        rows = math.prod(batch)
        dt = max(float(dt_s), 0.0)
        # Every array the compiled loops see is C-contiguous and writeable (one compiled
        # signature: a read-only view would be another type, compiled again).
        sys_idx = _checked_sys_idx(sys_idx, q)
        # The fast kernel's draws, in its order (_propose_fast): the two standard normal
        # arrays as one draw (a Generator fills an array element by element in C order, so
        # one draw of both sizes is the two draws one after the other: the same numbers).
        size_x, size_z = rows * n * d, rows * n * q
        normals = rng.standard_normal(size_x + size_z)
        noise_std, z = normals[:size_x], normals[size_x:]
        pick = rng.random(rows * n)
        sv = np.asarray(pos_sv_ecef_m, dtype=float)
        s_n = sv.shape[-2]
        mask = np.asarray(mask, dtype=bool)
        mask_b = (mask if mask.shape == batch + (s_n,)
                  else np.broadcast_to(mask, batch + (s_n,)))
        drift_var = self.drift_var
        # The per-filter terms, kept across steps by their inputs (_PrepCache).
        key = (mask_b.shape, mask_b.tobytes(), sys_idx.tobytes(), float(dt_s), q_scale,
               reset_var, np.shape(drift_var), np.asarray(drift_var).tobytes())
        prep = self._prep.get(key, noise)
        if prep is None:
            prep = self._prep_numba(key, mask_b, sys_idx, noise, dt_s, q_scale, reset_var,
                                    batch, s_n)
        mf, terms, inf, drift_gain, drift_var_next = prep
        if drift_var_next is not None:
            self.drift_var = drift_var_next.copy()  # changed in place by jumps and restarts
        kind, is_scaled, sigma, nu, eps, mix_scale, const, scale = codes
        if is_scaled:
            scale_f = np.empty((rows, s_n))
            scale_f[...] = scale
            log_scale_f = np.log(scale_f)
        else:  # ones and their logarithm, never written by the compiled loops
            scale_f, log_scale_f = _unit_scale(rows, s_n)
        prf = np.empty((rows, s_n))
        prf.reshape(batch + (s_n,))[...] = pr_m
        prf = np.where(mf & np.isfinite(prf), prf, 0.0)
        svf = np.empty((rows, s_n, 3))
        svf.reshape(batch + (s_n, 3))[...] = sv
        sq1 = math.sqrt(max(dt_s, 0.0))
        c_pos = model.q_pos_mps * (q_scale * sq1)
        c_vel = model.q_vel_mps2 * q_scale_vel * sq1
        alpha = PROPOSAL_DEFENSIVE
        xf = x.reshape(rows, n, d)
        log_s, log_p, ll, ll_prod = (np.empty((rows, n)) for _ in range(4))
        nb.propose_rows(xf, noise_std.reshape(rows, n, d), z.reshape(rows, n, q),
                        pick.reshape(rows, n), svf, prf, mf, sys_idx, q,
                        model.clk0, model.kind == "cv", float(dt_s), c_pos, c_vel,
                        model.has_drift, model.drift, dt, *terms, drift_gain, alpha,
                        math.log1p(-alpha), kind, is_scaled, sigma, nu, eps, mix_scale, const,
                        scale_f, log_scale_f, log_s, log_p, ll, ll_prod)
        if kind == 1 and not is_scaled:
            nb.student_t_ll(ll, ll_prod, mf, nu, const)
        # ln r = log_s - logaddexp(log_p, log_s + ln alpha) (_propose_fast), numpy's
        # logaddexp written out so that exp and log1p run vectorised.
        log_b = log_s + math.log(alpha)
        top = np.maximum(log_p, log_b)
        log_p -= log_b
        np.abs(log_p, out=log_p)
        np.negative(log_p, out=log_p)
        np.exp(log_p, out=log_p)
        np.log1p(log_p, out=log_p)
        log_p += top
        log_ratio = np.subtract(log_s, log_p, out=log_s)
        if not inf.all():
            log_ratio[~inf] = 0.0
        log_w = self.log_w
        if np.shape(log_w) != batch + (n,):
            log_w = np.array(np.broadcast_to(log_w, batch + (n,)), dtype=float)
        elif not (log_w.flags.c_contiguous and log_w.flags.writeable
                  and log_w.dtype == np.float64):
            log_w = np.require(log_w, float, ["C", "W"])
        log_w = log_w.reshape(rows, n)
        log_norm, n_eff = np.empty(rows), np.empty(rows)
        est, need = np.empty((rows, d)), np.empty(rows, dtype=bool)
        nb.normalise_rows(log_w, ll, log_ratio, xf, _LOG_W_FLOOR, float(self.n_threshold),
                          log_norm, n_eff, est, need)
        if need.any():  # ll holds the normalised weights
            rows_idx = np.flatnonzero(need)
            u = rng.random((rows_idx.size, 1))  # as _resample_fast's draw
            nb.resample_rows(xf, ll, log_w, rows_idx, u[:, 0])
        self.particles = x
        self.log_w = log_w.reshape(batch + (n,))
        return StepResult(log_norm.reshape(batch), n_eff.reshape(batch),
                          est.reshape(batch + (d,)), need.reshape(batch))


def _noise_codes(noise):
    """The noise model as :func:`._pf_numba.propose_rows` takes it: ``(kind, scaled,
    sigma, nu, eps, mix_scale, const, scale)``, or None for a model it does not know
    (kept for the last few models: a bank steps with the same one epoch after epoch)."""
    key = id(noise)
    hit = _NOISE_CODES.get(key)
    if hit is not None and hit[0] is noise:
        return hit[1]
    codes = _noise_codes_of(noise)
    if len(_NOISE_CODES) >= 8:
        _NOISE_CODES.clear()
    _NOISE_CODES[key] = (noise, codes)  # the model kept alive: its id is not reused
    return codes


#: :func:`_noise_codes` of recent noise models, by identity (a Scaled model is not hashable
#: by value).
_NOISE_CODES: dict[int, tuple] = {}


def _noise_codes_of(noise):
    base, scale, is_scaled = noise, np.ones(1), False
    if isinstance(noise, Scaled):
        base, scale, is_scaled = noise.base, noise.scale, True
    sigma, nu, eps, mix_scale, const = float(base.sigma_m), 0.0, 0.0, 1.0, 0.0
    if type(base) is Gaussian:
        kind = 0
        const = math.log(sigma) + 0.5 * math.log(2.0 * math.pi)
    elif type(base) is StudentT:
        kind, nu = 1, float(base.nu)
        const = float(special.gammaln((nu + 1) / 2) - special.gammaln(nu / 2)
                      - 0.5 * math.log(nu * math.pi) - math.log(sigma))
    elif type(base) is GaussianMixture:
        kind, eps, mix_scale = 2, float(base.eps), float(base.scale)
    else:
        return None
    return kind, is_scaled, sigma, nu, eps, mix_scale, const, scale


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
    clock_jump_m : (R, E, q) receiver clock jumps detected and absorbed (m, per system;
        0 where none, :func:`clock_jump`), or None.
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
    clock_jump_m: np.ndarray | None = None


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
                 rng: np.random.Generator, scale=None, keep_cloud: int = 0,
                 clock_reset=None, reset_drift: bool = True,
                 kernel: str | None = None) -> BankRun:
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
    clock_reset : optional (E,) bool, the receiver says its clock restarted there
        (:attr:`raimcore.measure.Measurements.clock_reset`); None: never.
    reset_drift : at a restart, restart the drift too and learn it again at the next
        update (:func:`_restart_drift`, :data:`CLOCK_RESET_DRIFT_SD_MPS`); False keeps its
        estimate and variance (an oscillator running through the restart).
    kernel : the bank's step kernel, ``"numba"``, ``"fast"`` or ``"reference"``
        (:class:`ParticleBank`; None: :data:`DEFAULT_KERNEL`).

    Returns
    -------
    BankRun. The filters start at the first epoch with ``m >= n + 1`` from a weighted
    least-squares fix of that epoch (spread by its covariance); until then everything is
    NaN / not available. With a drift state, the drift starts from the clock change
    between the first two epochs (:func:`initial_drift`). Epochs with too few satellites
    only predict.
    Before each update, a receiver clock jump seen by the main filter
    (:func:`clock_jump`) shifts the clock offsets of every filter of that realisation by
    it (spread by the jump estimate's variance); a jump at two available epochs in a row
    is a wrong drift (a reset, or a jump between the first two epochs) and corrects the
    drift by the second jump / dt. At a flagged restart (:func:`reset_epochs`) every
    filter's offsets are instead centred on the main filter's common-mode innovation,
    whatever its size, and drawn from this epoch's measurements (prior variance
    :data:`CLOCK_RESET_SD_M` squared: the LLRs then compare only the satellite-to-satellite
    part, less the clock's share :func:`clock_occam`), the drift is not conditioned on
    them and, with ``reset_drift``, restarted: the next update draws its offsets the same
    way and then sets every filter's drift from the clock change since the restart.
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
                       np.full((r_n, e_n), -1), np.zeros(e_n, bool), np.zeros(e_n, bool),
                       clock_jump_m=np.zeros((r_n, e_n, n_sys)))
    available[:k0] = False
    reset_at, relearn_at = reset_epochs(
        np.zeros(e_n, bool) if clock_reset is None else clock_reset, available, k0)
    if not (reset_drift and model.has_drift):
        relearn_at[:] = False
    fresh = reset_at | relearn_at  # clock offsets drawn anew from the measurements
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
    drift0, drift_sd = np.zeros(r_n), np.zeros(r_n)
    if model.has_drift:
        # Start drift: the clock change between the first two epochs (a clock jump
        # between them is caught below as two jumps in a row).
        later = np.flatnonzero(available[k0 + 1:])
        if later.size:
            k1 = k0 + 1 + int(later[0])
            both = used[k0] & used[k1]
            drift0, drift_sd = initial_drift(
                sv[k0], sv[k1], pr[:, k0], pr[:, k1], both, sys_idx, n_sys,
                fix.pos_ecef_m, t_s[k1] - t_s[k0],
                np.where(both, _noise_weight(noise_at(k0)), 0.0), vel_rx_ecef_mps=vel0,
                solve_motion=model.kind == "cv" and vel0 is None)
        drift_sd = np.where(np.isfinite(drift_sd), drift_sd, 0.0)
    # The start drift's variance is not inflated like the fix's: its spread moves every
    # offset of the cloud at each step, and 3x cost convergence on seed002 and on
    # seed000-step with model "cv" (sigma 33 m); the marginalised drift learns fast.
    bank = ParticleBank(initial_cloud(fix.pos_ecef_m, fix.clock_m, fix.cov_enu, n_particles,
                                      model, rng, batch=(q_n,), vel_mean_mps=vel0,
                                      vel_sigma_mps=vel_sd, inflate=3.0, drift_mps=drift0),
                        model, drift_var=drift_sd[:, None]**2, kernel=kernel)
    jumps = np.zeros((r_n, e_n, n_sys))
    jumped = np.zeros((r_n, n_sys), dtype=bool)  # a jump at the previous available epoch
    k_prev = k0
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
    est0[:, model.clocks] = np.nan_to_num(fix.clock_m)
    if model.has_drift:
        est0[:, model.drift] = drift0
    estimate[:, k0] = est0[:, None, :]
    first_llr = k0 + 1 + burn_in
    # Start-up annealing (spec section 3, "Start-up"): the process noise starts at about
    # the noise scale per step and decays to the model's over the burn-in, so a cloud
    # started around a poor first fix moves to the truth within the burn-in instead of
    # drifting there at q_pos (minutes) while the test is armed.
    boost = max(noise.sigma_m / max(model.q_pos_mps, 1e-3), 1.0)
    boost_vel = max(VEL_BOOST * vel_sd / max(model.q_vel_mps2, 1e-3), 1.0)
    # Everything of the loop below that does not depend on the filters, once for the run:
    # the filters' masks (1, Q, S) per epoch (none where not available), the steps, and
    # the predictive likelihoods kept for the LLRs (taken after the loop).
    masks = (drop[None] & used[:, None, :]) & available[:, None, None]
    dt_step = np.diff(np.asarray(t_s, dtype=float), prepend=np.nan).tolist()
    t_list = np.asarray(t_s, dtype=float).tolist()
    avail, fresh_l, relearn_l = available.tolist(), fresh.tolist(), relearn_at.tolist()
    log_pred = np.zeros((r_n, e_n, q_n))
    sys_idx = np.asarray(sys_idx)
    for k in range(k0 + 1, e_n):
        frac = min((k - k0 - 1) / max(burn_in, 1), 1.0)
        q_scale = 1.0 + (boost - 1.0) * (1.0 - frac) ** 2
        q_scale_vel = 1.0 + (boost_vel - 1.0) * (1.0 - frac) ** 2
        noise_k = noise_at(k)
        svk, prk = sv[k], pr[:, k]
        k_last = k_prev
        if fresh_l[k]:
            _centre_clock(bank, k, dt_step[k], svk, prk, used[k], sys_idx, n_sys, jumps)
            jumped = np.zeros_like(jumped)  # a restart is no evidence of a wrong drift
            k_prev = k
        elif avail[k]:
            jumped = _absorb_clock_jump(bank, k, t_list[k] - t_list[k_prev], dt_step[k], svk,
                                        prk, used[k], sys_idx, n_sys, noise_k, jumped, jumps,
                                        rng)
            k_prev = k
        res = bank.step(dt_step[k], svk[None, None], prk[:, None, :], masks[k][None],
                        sys_idx, noise_k, rng, q_scale, q_scale_vel,
                        reset_var=CLOCK_RESET_SD_M**2 if fresh_l[k] else 0.0)
        if relearn_l[k]:
            _restart_drift(bank, k_last, k, t_s, sv, pr, used, sys_idx, n_sys,
                           noise_at(k_last))
        estimate[:, k] = res.estimate
        if cloud is not None:  # the posterior sample after the update (and any resampling)
            cloud[k] = bank.particles[0, 0][pick]
            wk = np.exp(bank.log_w[0, 0][pick])
            cloud_w[k] = wk / wk.sum()
        if avail[k]:
            n_eff[:, k] = res.n_eff
            log_pred[:, k] = res.log_pred
    # seed 002 LLR as the spec reads it: each filter scores its own set,
    # s_j(k) = ln p_aux_j(y^(-j) | Y_{k-1}) - ln p_main(y | Y_{k-1}), from the first
    # available epoch after the burn-in on.
    scored = available & (np.arange(e_n) >= max(first_llr, k0 + 1))
    llr[:] = np.where(used[None] & scored[None, :, None],
                      log_pred[:, :, 1:] - log_pred[:, :, :1], 0.0)
    for k in np.flatnonzero(scored & fresh):  # the clock's share, not evidence about j
        occam, alone = clock_occam(used[k], sys_idx, n_sys, noise_at(k))
        llr[:, k] = np.where(alone, 0.0, llr[:, k] - occam)
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
    return BankRun(estimate, n_eff, llr, cum, beta, arg, available, armed, cloud, cloud_w,
                   jumps)


def _common_mode(bank: ParticleBank, dt_step: float, sv, pr, used, sys_idx, n_sys: int,
                 threshold_m: float):
    """:func:`clock_jump` (R, q) of the main filter's predicted residuals at an epoch
    ``dt_step`` after the particles' (``threshold_m`` 0: every system's median)."""
    resid = _predicted_residuals(bank, dt_step, sv, pr, sys_idx)
    return clock_jump(resid, used[None], sys_idx, n_sys, threshold_m)


def _predicted_residuals(bank: ParticleBank, dt_step: float, sv, pr, sys_idx) -> np.ndarray:
    """(R, n) residuals of the main filter's weighted mean predicted ``dt_step`` ahead
    (untracked satellites: ``-range - clock``, masked by the callers)."""
    model = bank.model
    m = weighted_mean(bank.particles[:, 0], np.exp(bank.log_w[:, 0]))  # (R, D), at k - 1
    pos = m[:, :3] + (m[:, 3:6] * dt_step if model.kind == "cv" else 0.0)
    clk = m[:, model.clocks]
    if model.has_drift:
        clk = clk + m[:, model.drift, None] * dt_step
    rng_m = np.linalg.norm(sv[None] - pos[:, None], axis=-1)
    return np.where(np.isnan(pr), 0.0, pr) - rng_m - clk[:, np.asarray(sys_idx, dtype=int)]


def _may_jump(bank: ParticleBank, dt_step: float, sv, pr, used, sys_idx) -> bool:
    """False where :func:`_common_mode` at :data:`CLOCK_JUMP_M` is certainly all 0 (no
    predicted residual of the main filter above it: :func:`clock_jump` then finds no jump),
    found without its array passes: by the compiled screen
    (:func:`._pf_numba.common_mode_screen`, with a margin over the rounding) for a numba
    bank, else by :func:`_common_mode`'s residuals (:func:`_predicted_residuals`). True:
    compute the jumps."""
    model = bank.model
    if bank.kernel == "numba":
        req = _c_writeable
        return bool(_numba_module().common_mode_screen(
            req(bank.particles), req(bank.log_w), req(sv), req(pr), req(used, np.bool_),
            _checked_sys_idx(sys_idx, model.n_clk), model.clk0, model.kind == "cv",
            model.has_drift, model.drift, float(dt_step), CLOCK_JUMP_M))
    resid = _predicted_residuals(bank, dt_step, sv, pr, sys_idx)
    return bool((used & (np.abs(resid) > CLOCK_JUMP_M)).any())  # clock_jump's first test


def _c_writeable(a, dtype=np.float64) -> np.ndarray:
    """``a`` as a C-contiguous writeable array of ``dtype`` (itself if it is one already:
    one compiled signature for the compiled loops)."""
    if (isinstance(a, np.ndarray) and a.dtype == dtype and a.flags.c_contiguous
            and a.flags.writeable):
        return a
    return np.require(a, dtype, ["C", "W"])


def _centre_clock(bank: ParticleBank, k: int, dt_step: float, sv, pr, used, sys_idx,
                  n_sys: int, jumps):
    """A flagged clock restart at epoch ``k``: shift every filter's offsets by the main
    filter's common-mode innovation (written into ``jumps[:, k]``); the step that follows
    draws them from the measurements (:func:`run_llr_bank`)."""
    jump = _common_mode(bank, dt_step, sv, pr, used, sys_idx, n_sys, 0.0)
    jumps[:, k] = jump
    bank.particles[..., bank.model.clocks] += jump[:, None, None, :]


def _restart_drift(bank: ParticleBank, k_reset: int, k: int, t_s, sv, pr, used, sys_idx,
                   n_sys: int, noise):
    """The drift after a clock restart at ``k_reset``, learnt at the next update ``k`` as
    the start's (:func:`initial_drift`: the robust clock change between the two epochs,
    the main filter's position): every particle of every filter gets it, its variance the
    common one (:func:`run_llr_bank`). Drawn from each particle's own pair of offsets
    instead, 100 particles carried drifts a few m/s apart that the following epochs
    pruned: PF-LLR alarmed at 2.4 % of seed002's fault-free epochs with restarts at 30 %
    of them (0.0 % without restarts)."""
    model = bank.model
    m = weighted_mean(bank.particles[:, 0], np.exp(bank.log_w[:, 0]))  # (R, D) at k
    dt = t_s[k] - t_s[k_reset]
    vel = m[:, 3:6] if model.kind == "cv" else None
    pos0 = m[:, :3] - (vel * dt if vel is not None else 0.0)
    both = used[k_reset] & used[k]
    drift, sd = initial_drift(sv[k_reset], sv[k], pr[:, k_reset], pr[:, k], both, sys_idx,
                              n_sys, pos0, dt, np.where(both, _noise_weight(noise), 0.0),
                              vel_rx_ecef_mps=vel)
    bank.particles[..., model.drift] = drift[:, None, None]
    var = np.where(np.isfinite(sd), sd**2, CLOCK_RESET_DRIFT_SD_MPS**2)
    bank.drift_var[...] = var.reshape((-1,) + (1,) * (bank.drift_var.ndim - 1))


def _absorb_clock_jump(bank: ParticleBank, k: int, dt_avail: float, dt_step: float, sv,
                       pr, used, sys_idx, n_sys: int, noise, jumped, jumps, rng):
    """Detect a receiver clock jump at epoch ``k`` on the main filter's prediction and
    shift the clock offsets of every filter by it (:func:`run_llr_bank`); returns the
    per-system "jumped" flags (R, q) and writes the jumps into ``jumps[:, k]``."""
    model = bank.model
    if not _may_jump(bank, dt_step, sv, pr, used, sys_idx):
        return np.zeros_like(jumped)
    jump = _common_mode(bank, dt_step, sv, pr, used, sys_idx, n_sys, CLOCK_JUMP_M)  # (R, q)
    hit = jump != 0.0
    if not hit.any():
        return np.zeros_like(jumped)
    jumps[:, k] = jump
    var = jump_variance(np.where(used, _noise_weight(noise), 0.0)[None], sys_idx, n_sys)
    spread = np.sqrt(var)[:, None, None, :] * rng.standard_normal(
        bank.particles.shape[:-1] + (n_sys,))
    shift = jump
    if model.has_drift:
        # Two jumps in a row: the drift is wrong (a reset, or a jump before the start).
        # The particles are still at k - 1: the corrected drift moves this prediction too,
        # so the offsets move by the rest of the jump.
        again = hit & jumped
        n_again = again.sum(-1)
        corr = np.where(n_again > 0, np.where(again, jump, 0.0).sum(-1)
                        / np.maximum(n_again, 1) / max(dt_avail, 1e-9), 0.0)
        bank.particles[..., model.drift] += corr[:, None, None]
        restart = n_again > 0
        floor = np.broadcast_to(var.max(-1) / max(dt_avail, 1e-9)**2, restart.shape)
        bank.drift_var[restart] = np.maximum(bank.drift_var[restart],
                                             floor[restart, None])
        shift = jump - corr[:, None] * dt_step
    bank.particles[..., model.clocks] += np.where(hit[:, None, None, :],
                                                 shift[:, None, None, :] + spread, 0.0)
    return hit


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
                  scale=None, kernel: str | None = None) -> Calibration:
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
    ``kernel``: the bank's step kernel (:class:`ParticleBank`; the same tau either way, to
    rounding).
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
                       n_particles=n_particles, window=window, burn_in=burn_in, rng=rng,
                       kernel=kernel)
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
    counts, epoch interval, seed), the geometry as rounded local lines of sight (0.02 rad),
    so a scenario that changes only its faults, seed or duration reuses the same
    threshold, and the version of the code that computes it (:func:`calibration_code_version`):
    a threshold kept on disk is never reused by code that would compute another one.
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
    return f"{noise!r}|{model!r}|{cfg}|{geo}|code={calibration_code_version()}"


@functools.lru_cache(maxsize=1)
def calibration_code_version() -> str:
    """A fingerprint of what a calibrated ``tau`` depends on besides its key's fields: the
    source of the filters (this module and its compiled kernels, :mod:`._pf_numba`, read
    as a file: numba is not imported for it), of the noise models and of the
    least-squares start, and the numpy version (its random streams). 16 hex digits of a
    SHA-256. (The kernels agree to rounding, so the kernel that ran is not part of it.)"""
    import hashlib
    import sys
    from pathlib import Path

    from .. import lsq
    from ..measure import noise as noise_module

    h = hashlib.sha256(np.__version__.encode())
    here = sys.modules[__name__].__file__
    for path in (here, str(Path(here).with_name("_pf_numba.py")), noise_module.__file__,
                 lsq.__file__):
        with open(path, "rb") as f:
            h.update(f.read())
    return h.hexdigest()[:16]


#: Where the on-disk threshold cache lives when ``RAIM_STUDIO_CACHE_DIR`` is not set:
#: ``$XDG_CACHE_HOME/raim-studio`` (``~/.cache/raim-studio`` without ``XDG_CACHE_HOME``).
CACHE_APP_DIR = "raim-studio"
#: Most calibrations kept on disk (a few kB to 40 kB each); the oldest go first.
CACHE_MAX_FILES = 500
_DISK_WARNED: set[str] = set()


def default_cache_path():
    """The on-disk threshold cache directory: ``$RAIM_STUDIO_CACHE_DIR/pf_llr_tau`` if set,
    else ``$XDG_CACHE_HOME/raim-studio/pf_llr_tau`` (``~/.cache/raim-studio/pf_llr_tau``).
    One small JSON file per calibration (:func:`cached_tau`)."""
    import os
    from pathlib import Path

    root = os.environ.get("RAIM_STUDIO_CACHE_DIR")
    if not root:
        base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
        root = str(Path(base) / CACHE_APP_DIR)
    return Path(root) / "pf_llr_tau"


def _disk_file(directory, key: str):
    import hashlib

    return directory / (hashlib.sha256(key.encode()).hexdigest()[:32] + ".json")


def _disk_read(directory, key: str, field: str, parse):
    """The value stored for ``key`` under ``directory`` (its ``field``, through ``parse``),
    or None: absent, unreadable, another key or not a valid value, never trusted."""
    import json

    try:
        with open(_disk_file(directory, key), encoding="utf-8") as f:
            entry = json.load(f)
        return parse(entry[field]) if entry.get("key") == key else None
    except (OSError, ValueError, TypeError, KeyError, AttributeError):
        return None


def _disk_write(directory, key: str, field: str, value) -> None:
    """Store ``value`` (JSON) for ``key`` atomically (a temporary file renamed over the entry, so
    concurrent processes never read half a file); a directory that cannot be written
    leaves the threshold in memory only, with one warning per directory."""
    import json
    import os
    import tempfile

    try:
        directory.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=".tau-", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump({"key": key, field: value}, f)
            os.replace(tmp, _disk_file(directory, key))
        except BaseException:
            os.unlink(tmp)
            raise
        _disk_prune(directory)
    except OSError as exc:
        if str(directory) not in _DISK_WARNED:
            _DISK_WARNED.add(str(directory))
            warnings.warn(f"PF-LLR threshold cache {directory} is not writable ({exc}); "
                          "calibrated thresholds are kept in memory only", UserWarning,
                          stacklevel=3)


def _disk_prune(directory) -> None:
    """Keep the newest :data:`CACHE_MAX_FILES` entries (a code change makes new keys: the
    old entries would otherwise pile up)."""
    def mtime(f):
        try:
            return f.stat().st_mtime
        except OSError:  # removed meanwhile by another process
            return -math.inf

    try:
        entries = sorted(directory.glob("*.json"), key=mtime)
        for old in entries[:max(len(entries) - CACHE_MAX_FILES, 0)]:
            old.unlink(missing_ok=True)
    except OSError:
        pass  # pruning is housekeeping: the entry just written is in place


def _finite_float(value) -> float:
    tau = float(value)
    if not math.isfinite(tau):
        raise ValueError("not a finite threshold")
    return tau


def _float_samples(value) -> np.ndarray:
    beta = np.asarray(value, dtype=float)
    if beta.ndim != 2 or beta.size == 0:
        raise ValueError("not a (R, M) sample")
    return beta


def _cached(key: str, compute, cache: str, path, field: str, parse, dump):
    """The memory / disk cache behind :func:`cached_tau` and :func:`cached_samples`."""
    from pathlib import Path

    check_choice("tau_cache", cache, ("memory", "disk", "off"))
    if cache == "off":
        return parse(compute())
    if key in _TAU_CACHE:
        return _TAU_CACHE[key]
    directory = Path(path) if path is not None else default_cache_path()
    if cache == "disk":
        value = _disk_read(directory, key, field, parse)
        if value is not None:
            _TAU_CACHE[key] = value
            return value
    value = parse(compute())
    _TAU_CACHE[key] = value
    if cache == "disk":
        _disk_write(directory, key, field, dump(value))
    return value


def cached_tau(key: str, compute, *, cache: str = "disk", path=None) -> float:
    """``tau`` for ``key`` from the cache, else ``compute()`` (a float) stored in it.

    Parameters
    ----------
    key : the calibration's name (:func:`calibration_key`).
    compute : callable returning the threshold (the Monte Carlo calibration).
    cache : ``"disk"`` (default: in memory and in a directory shared between sessions,
        processes and runs, ``path`` or :func:`default_cache_path`, one small JSON file per
        key written atomically; if it cannot be written, in memory only, one warning),
        ``"memory"`` (this process only) or ``"off"`` (always recompute).
    path : the cache directory (default :func:`default_cache_path`).

    Returns
    -------
    float, the threshold.

    See Also
    --------
    cached_samples : the same for the fault-free ``beta`` samples behind a threshold.
    """
    return _cached(key, compute, cache, path, "tau", _finite_float, float)


def cached_samples(key: str, compute, *, cache: str = "disk", path=None) -> np.ndarray:
    """The fault-free ``beta`` samples (R, M) of a calibration (:attr:`Calibration.beta`)
    for ``key`` from the cache, else ``compute()`` stored in it (as :func:`cached_tau`).

    The samples do not depend on the false-alarm target: kept instead of ``tau``, a
    change of ``p_fa_window`` needs only :func:`threshold_from_samples`, no new Monte
    Carlo runs.
    """
    return _cached(key, compute, cache, path, "beta", _float_samples,
                   lambda beta: beta.tolist())
