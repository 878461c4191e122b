"""Particle-filter RAIM with windowed log-likelihood ratios (seed 002, spec section 3).

A bank of s + 1 SIR particle filters (:mod:`raimcore.algorithms.pf`): the main filter uses every
satellite, auxiliary filter j every satellite but j. Each epoch, each filter scores its
own measurement set with its predictive likelihood; the LLR of "satellite j faulty" is
``s_j(k) = ln p_aux_j(y^(-j)) - ln p_main(y)``, summed over a sliding window of W epochs.
``beta(k) = max_j S_j(k)`` is compared with a threshold ``tau`` calibrated by fault-free
Monte Carlo runs of the same bank (cached per configuration, in memory and on disk:
:func:`~raimcore.algorithms.pf.cached_samples`); on an alarm the satellite
``argmax_j S_j`` is named and excluded: the position after exclusion is auxiliary filter
j's estimate. Where the receiver says its clock restarted (``Measurements.clock_reset``)
the filters re-initialise their clock offsets from that epoch's measurements, so the LLRs
compare only the satellite-to-satellite part (:func:`~raimcore.algorithms.pf.run_llr_bank`).
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict

import numpy as np

from ..measure.noise import scaled
from ..schema import option
from . import pf
from .base import (
    STATUS_NOT_ARMED,
    STATUS_OK,
    STATUS_UNAVAILABLE,
    AlgorithmOutput,
    AlgorithmSpec,
    Measurements,
    register,
)
from .pf import (
    MS_M,
    PROCESS_MODELS,
    ProcessModel,
    cached_samples,
    calibrate_tau,
    calibration_key,
    robust_fix,
    run_llr_bank,
    threshold_from_samples,
)

SUMMARY = (
    "A particle filter follows the receiver position and clock with a cloud of $N$ candidate "
    "states, weighted by how well each explains the pseudoranges under the real, "
    "heavy-tailed noise model, so an outlier pulls it far less than a Kalman filter. A bank "
    "of filters runs side by side: one with every satellite and one without each "
    "satellite. When satellite $j$ is faulty, the filter without $j$ predicts the "
    "measurements it sees much better than the main filter predicts all of them: the "
    r"log-likelihood ratio $s_j$ grows. Summed over a window of $W$ epochs, the largest "
    r"ratio $\beta$ is compared with a threshold $\tau$ found by simulating fault-free "
    "runs; above it the satellite with the largest ratio is named and excluded. Because "
    "the window adds $W$ epochs, errors that persist from epoch to epoch (real multipath "
    "and atmosphere: try Noise correlation) add up too; the fault-free simulations then use "
    r"the same correlation, and $\tau$ rises: fewer false alarms, later detection."
)

EQUATIONS = r"""
- State $x = [r, c\,\delta t_s, c\,\dot{\delta t}]$ (one clock offset per system, one
  drift), static: $r_k = r_{k-1} + w_k$, $c\,\delta t_{s,k} = c\,\delta t_{s,k-1}
  + c\,\dot{\delta t}\,\Delta t + w$; pseudorange
  $\rho_i = \lVert r - s_i \rVert + c\,\delta t + v_i$, $v_i$ heavy-tailed
- Particles drawn from a proposal $q$: the motion from the state equation, the clock
  offsets near what the filter's own pseudoranges say (their median per system);
  $r^{(i)} = p(x_k^{(i)} \mid x_{k-1}^{(i)}) / q(x_k^{(i)} \mid x_{k-1}^{(i)}, y_k)$
- Weights $w_k^{(i)} \propto w_{k-1}^{(i)}\, p(y_k \mid x_k^{(i)})\, r^{(i)}$,
  $N_{eff} = 1 / \sum_i (w_k^{(i)})^2$, resample when $N_{eff} < 2N/3$
- Predictive likelihood
  $p(y_k \mid Y_{k-1}) \approx \sum_i w_{k-1}^{(i)}\, p(y_k \mid x_k^{(i)})\, r^{(i)}$
- LLR $s_j(k) = \ln\, p_{aux,j}(y_k^{(-j)} \mid Y_{k-1}) - \ln\, p_{main}(y_k \mid Y_{k-1})$
- Window $S_j(k) = \sum_{t=k-W+1}^{k} s_j(t)$, $\beta(k) = \max_j S_j(k)$
- Alarm $\beta(k) > \tau$; faulty $\hat\jmath = \mathrm{arg\,max}_j\, S_j(k)$, excluded
"""

#: Monte Carlo size of the threshold calibration (runs x armed epochs per run).
CALIBRATION_RUNS = 32
CALIBRATION_ARMED_EPOCHS = 60
#: Seed of the calibration runs: fixed, so a configuration always gets the same tau.
CALIBRATION_SEED = 2002
#: Particles of the main filter kept per epoch for display (``extras``), and the budget
#: (epochs x particles) that caps it on long runs.
CLOUD_PARTICLES = 200
CLOUD_BUDGET = 2_000_000


#: Bank runs kept for reuse (:func:`_bank_run`): a change of the threshold options alone
#: (``tau``, ``p_fa_window``, ``tau_sets``, ``tau_cache``) re-tests the same run. At most
#: this many runs, of at most BANK_RUN_CACHE_BYTES together (a longer run is not kept).
BANK_RUN_CACHE_SIZE = 4
BANK_RUN_CACHE_BYTES = 64 * 2**20
_BANK_RUNS: OrderedDict[str, object] = OrderedDict()


#: Process-model options, shared with ``ekf`` (one declaration, one meaning).
PROCESS_OPTIONS = (
    option("model", "choice", "static", "process model of the filters' state",
           choices=PROCESS_MODELS),
    option("q_pos_mps", float, 0.1, "position process noise (static model)", unit="m/s",
           lo=0.0, hi=1.0e4),
    option("q_vel_mps2", float, 0.5, "velocity process noise (constant-velocity model)",
           unit="m/s^2", lo=0.0, hi=1.0e4),
    option("q_clk_mps", float, 0.1, "receiver clock offset process noise (white "
           "frequency; a TCXO: 0.095, Brown & Hwang 2012 Table 9.1)", unit="m/s", lo=0.0,
           hi=1.0e6),
    option("q_drift_mps2", float, 0.2, "receiver clock drift process noise (random-walk "
           "frequency; a TCXO: 0.19, Brown & Hwang 2012 Table 9.1)", unit="m/s^2", lo=0.0,
           hi=1.0e3),
)

#: Options (scenario keys) of PF-LLR.
OPTIONS = (
    option("n_particles", int, 100, "particles per filter (N)", lo=2, hi=1_000_000),
    option("window", int, 30, "LLR window (W epochs)", lo=1, hi=100_000),
    option("burn_in", int, 30, "epochs after the first fix before LLRs are accumulated",
           lo=0, hi=100_000),
    option("tau", "float_or_auto", "auto", "threshold of the windowed LLR; \"auto\" = "
           "calibrated by fault-free Monte Carlo runs"),
    option("p_fa_window", float, 1e-3, "calibration target: false alarms per window",
           lo=0.0, hi=1.0, lo_open=True, hi_open=True),
    option("tau_cache", "choice", "disk", "where calibrated thresholds are kept",
           choices=("memory", "disk", "off")),
    option("tau_sets", "choice", "first", "calibrate once for the satellites in view at "
           "the first armed epoch (first), or once per satellite set in view (each)",
           choices=("first", "each")),
    *PROCESS_OPTIONS,
)


def process_model(options: dict, n_clk: int) -> ProcessModel:
    """The :class:`ProcessModel` named by the (resolved) options (shared with ``ekf``):
    always with the clock-drift state (a free-running receiver clock drifts by hundreds of
    m/s; a steady one estimates a drift near 0)."""
    return ProcessModel(kind=options["model"], n_clk=n_clk, q_pos_mps=options["q_pos_mps"],
                        q_vel_mps2=options["q_vel_mps2"], q_clk_mps=options["q_clk_mps"],
                        q_drift_mps2=options["q_drift_mps2"])


def clock_jump_column(jump_m) -> np.ndarray:
    """The result table's ``clock_jump_ms`` (E,) from a filter's jumps (E, q) in m: the
    largest jump over the systems, in milliseconds of receiver clock (0: none)."""
    j = np.asarray(jump_m, dtype=float)
    pick = np.take_along_axis(j, np.argmax(np.abs(j), axis=-1)[..., None], axis=-1)[..., 0]
    return pick / MS_M


def noise_scale(data: Measurements):
    """Per-satellite factor ``data.sigma_m / noise.sigma_m`` (E, S): the elevation model of
    a recording, so that the filters weigh satellites as the snapshot algorithms do; None
    when it is 1 everywhere (simulated scenarios)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        k = np.asarray(data.sigma_m, dtype=float) / data.noise.sigma_m
    k = np.where(np.isfinite(k) & (k > 0), k, 1.0)
    return None if np.all(k == 1.0) else k


def _threshold(data: Measurements, model: ProcessModel, n: int, window: int, burn_in: int,
               p_fa: float, cache: str, ref: int, scale=None) -> float:
    """Calibrated tau for the satellites and geometry of epoch ``ref`` (see module doc)."""
    u = data.used[ref]
    fix = robust_fix(data.pos_sv_ecef_m[ref], data.pr_m[ref][None], u, data.sys_idx,
                     len(data.systems), scaled(data.noise, None if scale is None
                                               else scale[ref]))
    noise = scaled(data.noise, None if scale is None else scale[ref][u])
    rx = np.nan_to_num(fix.pos_ecef_m[0])
    sv, sys_idx = data.pos_sv_ecef_m[ref][u], data.sys_idx[u]
    steps = np.diff(np.asarray(data.t_s, dtype=float))
    steps = steps[steps > 0]
    dt = float(np.median(steps)) if steps.size else 1.0  # the scenario's epoch interval
    config = dict(n_particles=n, window=window, burn_in=burn_in,
                  n_runs=CALIBRATION_RUNS, n_armed=CALIBRATION_ARMED_EPOCHS, dt_s=dt)
    # The fault-free beta samples are cached, not tau: they do not depend on p_fa_window.
    key = calibration_key(sv, rx, sys_idx, noise, model, seed=CALIBRATION_SEED,
                          kept="beta samples", **config)

    def compute():
        rng = np.random.default_rng(CALIBRATION_SEED)
        return calibrate_tau(sv, rx, sys_idx, len(data.systems), noise, model, rng=rng,
                             p_fa_window=p_fa, **config).beta

    return threshold_from_samples(cached_samples(key, compute, cache=cache), p_fa, window)


def _bank_run(data: Measurements, model: ProcessModel, n: int, window: int, burn_in: int,
              scale):
    """:func:`~raimcore.algorithms.pf.run_llr_bank` on ``data``, or the same run kept from
    a recent call with equal inputs (the measurements' arrays and seed, the noise and
    process models, N, W, burn-in: everything the run reads; not the threshold options,
    which it does not read). Returns the run and whether it is kept (shared: not to be
    changed)."""
    h = hashlib.sha256()
    for arr in (data.pos_sv_ecef_m, data.pr_m, data.used, data.t_s, data.sys_idx,
                data.clock_reset, scale):
        a = np.ascontiguousarray(np.asarray(arr if arr is not None else np.nan))
        h.update(f"{a.dtype}{a.shape}".encode())
        h.update(a.tobytes())
    h.update(repr((data.noise, model, n, window, burn_in, int(data.seed),
                   len(data.systems), pf.DEFAULT_KERNEL)).encode())
    key = h.hexdigest()
    if key in _BANK_RUNS:
        _BANK_RUNS.move_to_end(key)
        return _BANK_RUNS[key], True
    e_n = data.pr_m.shape[0]
    keep = min(CLOUD_PARTICLES, CLOUD_BUDGET // max(e_n, 1))
    bank = run_llr_bank(data.pos_sv_ecef_m, data.pr_m[None], data.used, data.t_s,
                        data.sys_idx, len(data.systems), data.noise, model, n_particles=n,
                        window=window, burn_in=burn_in, rng=data.rng(0), scale=scale,
                        keep_cloud=keep, clock_reset=data.clock_reset)
    size = lambda run: sum(getattr(run, f).nbytes for f in run.__dataclass_fields__  # noqa: E731
                           if isinstance(getattr(run, f), np.ndarray))
    if size(bank) > BANK_RUN_CACHE_BYTES:
        return bank, False
    _BANK_RUNS[key] = bank
    while (len(_BANK_RUNS) > BANK_RUN_CACHE_SIZE
           or sum(size(r) for r in _BANK_RUNS.values()) > BANK_RUN_CACHE_BYTES):
        _BANK_RUNS.popitem(last=False)
    return bank, True


def run(data: Measurements, options: dict) -> AlgorithmOutput:
    """Run the bank of particle filters and the windowed LLR test on every epoch.

    Options: ``n_particles`` (N), ``window`` (W epochs), ``burn_in`` (epochs after the
    first fix before LLRs are accumulated), ``tau`` (threshold; ``"auto"`` or ``None``:
    calibrated),
    ``p_fa_window`` (calibration target, false alarms per window), ``tau_cache``
    (``"disk"``, the default: kept across sessions and runs; ``"memory"``, ``"off"``),
    ``tau_sets`` (``"first"``: calibrate once, for the satellites in view at the first
    armed epoch; ``"each"``: once per satellite set in view, each armed epoch tested
    against its own set's tau), ``model``, ``q_pos_mps``,
    ``q_vel_mps2``, ``q_clk_mps``, ``q_drift_mps2`` (process model,
    :class:`raimcore.algorithms.pf.ProcessModel`). Column ``clock_jump_ms``: a receiver
    clock jump absorbed at that epoch (ms; 0: none), at a restart flagged in
    ``data.clock_reset`` the common-mode innovation of the re-initialised clock.
    """
    n, window, burn_in = options["n_particles"], options["window"], options["burn_in"]
    p_fa, cache, tau_sets = options["p_fa_window"], options["tau_cache"], options["tau_sets"]
    tau_opt = None if options["tau"] == "auto" else float(options["tau"])
    model = process_model(options, len(data.systems))
    e_n, s_n = data.pr_m.shape
    scale = noise_scale(data)
    bank, kept = _bank_run(data, model, n, window, burn_in, scale)
    own = (lambda a: a.copy()) if kept else (lambda a: a)  # noqa: E731
    armed = bank.armed
    extras = {}
    if bank.cloud is not None:
        # The main filter's cloud (ECEF, m); displays show it around the true position.
        extras = {"particles_ecef_m": own(bank.cloud[..., :3]),
                  "particle_weight": own(bank.cloud_weight)}
    tau = np.full(e_n, np.nan)
    if tau_opt is not None:
        tau[:] = tau_opt
    elif armed.any() and tau_sets == "first":
        tau[:] = _threshold(data, model, n, window, burn_in, p_fa, cache,
                            int(np.flatnonzero(armed)[0]), scale)
    elif armed.any():
        # One calibration per satellite set in view (at its first armed epoch): the max
        # over more LLRs, and another geometry, give another tau.
        idx = np.flatnonzero(armed)
        _, first, which = np.unique(data.used[idx], axis=0, return_index=True,
                                    return_inverse=True)
        for g, ref in enumerate(idx[first]):
            tau[idx[which.reshape(-1) == g]] = _threshold(data, model, n, window, burn_in,
                                                          p_fa, cache, int(ref), scale)
    beta = bank.beta[0]
    alarm = armed & (beta > tau)
    faulty = np.where(alarm, bank.argmax[0], -1)
    status = np.where(armed, STATUS_OK, np.where(bank.available, STATUS_NOT_ARMED,
                                                 STATUS_UNAVAILABLE)).astype(object)
    pos_before = np.where(bank.available[:, None], bank.estimate[0, :, 0, :3], np.nan)
    aux = bank.estimate[0, np.arange(e_n), 1 + np.maximum(faulty, 0), :3]
    pos_after = np.where(alarm[:, None], aux, pos_before)
    excluded = np.zeros((e_n, s_n), dtype=bool)
    excluded[np.flatnonzero(alarm), faulty[alarm]] = True
    return AlgorithmOutput(
        status=status, statistic=np.where(armed, beta, np.nan),
        threshold=np.where(armed, tau, np.nan), alarm=alarm,
        pos_before_ecef_m=pos_before, pos_after_ecef_m=pos_after, excluded=excluded,
        isolated=faulty,
        per_sat={"llr": np.where(armed[:, None], bank.cum_llr[0], np.nan)},
        columns={"beta": np.where(armed, beta, np.nan), "n_eff": own(bank.n_eff[0, :, 0]),
                 "memory_epochs": np.full(e_n, window),
                 "clock_jump_ms": clock_jump_column(bank.clock_jump_m[0])},
        extras=extras,
    )


SPEC = register(AlgorithmSpec(
    name="pf-llr",
    label="Particle filter + LLR (seed 002)",
    summary=SUMMARY,
    equations=EQUATIONS,
    run=run,
    options=OPTIONS,
    reference="Particle filter and log-likelihood ratio RAIM (seed 002): SIR particle "
              "filter bank, windowed cumulative LLR, N = 100, W = 30.",
))
