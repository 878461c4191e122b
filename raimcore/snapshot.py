"""Array-level snapshot fault detection and exclusion: :func:`fde`.

One call runs a snapshot FDE algorithm on every epoch of plain arrays (no scenario, no
:class:`~raimcore.measure.Measurements`): satellite positions ``(T, n, 3)`` in the
receive-time ECEF frame, pseudoranges ``(T, n)`` with NaN for a satellite not tracked.
Every algorithm runs the implementation the scenario engine runs (one implementation):

* ``parity``: the kernel :func:`_parity_fde` below, which the registered ``parity``
  (:mod:`raimcore.algorithms.parity_fde`) calls;
* ``mss``, ``gf``, ``rs``, ``qv``: the registered algorithm itself, through the engine's
  :func:`raimcore.pipeline.run_algorithm`, on a :class:`~raimcore.measure.Measurements`
  made of the arrays (:func:`_measurements`);
* ``araim``: the kernel :func:`raimcore.araim.mhss` on the geometry and residuals of the
  all-in-view weighted least squares, as :mod:`raimcore.algorithms.araim` does, with the
  nominal sigmas and ISM values given as arrays (that adapter derives them from the
  elevation and the scenario's ISM, which arrays do not have).

The parity kernel (seed 000; Liao & Huang 1996) makes exactly the decisions of the plain
numpy path it replaces, :func:`_parity_fde_reference` (batched :func:`raimcore.lsq.wls`,
:func:`raimcore.algorithms.parity.parity_statistics` and a greedy exclusion loop), which is
kept as the reference that ``tests/test_fde.py`` compares it with. It is faster because:

* the receiver clocks (one per system, one-hot columns) are eliminated in closed form: the
  position step solves the 3 x 3 normal equations of the system-centred lines of sight,
  ``S3 dp = -sum_j w_j c_j dz_j`` with ``c_j = u_j - ubar_s(j)`` (``ubar_s`` the weighted
  mean line of sight of system ``s``) and ``S3 = sum_j w_j c_j c_j^T``; the clock of
  system ``s`` is then ``mean_s(dz) + ubar_s . dp``. No ``inv``/``det``/``eigvalsh`` of
  batched matrices: ``S3^-1`` is its adjugate over its determinant;
* the singular-geometry test of :data:`raimcore.lsq.RCOND_MIN` uses
  ``det(D^-1/2 N D^-1/2) = det(S3) / prod(diag N_pos)``, and for the final (ENU-frame,
  strict) test the frame-free lower bound ``27 det(S3) / (sum_j w_j)^3`` (AM-GM on the
  diagonal, whose trace is ``sum_j w_j`` because ``|u_j| = 1``); the few epochs where the
  bound does not decide are judged by the reference test itself;
* Gauss-Newton starts from a closed-form Bancroft solution (of the system with the most
  satellites: Bancroft has one clock, and inter-system clock offsets reach tens of km), so
  it converges in two steps instead of five from the Earth's centre, and the final
  geometry is the last iterate's (the last step is below ``tol_m = 1e-4`` m: the residuals
  are updated linearly, an error below 1e-15 m). The re-solve after an exclusion starts
  from the linearised solution without the excluded satellite (Sherman-Morrison): one step;
* the post-fit whitened residual is ``S r`` itself, and ``S_jj = 1 - w_j (1 / W_s +
  c_j^T S3^-1 c_j)``; the isolability matrix and protection levels are computed only when
  asked (``outputs``);
* epochs are processed in cache-sized chunks with the epoch axis last (contiguous), so time
  and memory per epoch do not grow with the number of epochs.

Epochs are independent: an epoch's result does not depend on the rest of the batch, except
with ``rs``, whose random draws are keyed by the rank of the epoch's set of tracked
satellites among the batch's sets (as in the scenario engine, see :func:`fde`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._validate import check_array, check_choice, check_int, check_probability
from .algorithms.base import STATUS_NO_ISOLATION, STATUS_OK, STATUS_UNAVAILABLE
from .lsq import RCOND_MIN, _clock_columns, _geometry_rows, _normal_solve

__all__ = ["fde", "FdeResult", "FDE_ALGORITHMS", "FDE_OUTPUTS", "FDE_ALGORITHM_OUTPUTS"]

#: Algorithms :func:`fde` runs: the registry's snapshot algorithms (the filters ``ekf``,
#: ``ekf-nis``, ``pf-llr`` carry state from epoch to epoch and are not snapshot FDE).
FDE_ALGORITHMS = ("parity", "mss", "gf", "rs", "qv", "araim")
#: Optional outputs of ``parity`` (``outputs=`` option) and what they are.
FDE_OUTPUTS = {
    "isolation": "(T, n) DF_I_j of each used satellite before exclusion (NaN elsewhere)",
    "fault_size_m": "(T, n) ML bias estimate of each used satellite (m)",
    "isolability": "(T, n) largest |cos| between a satellite's parity column and another's",
    "hpl_m": "(T,) classic slope-based horizontal protection level (m), Brown 1992",
    "vpl_m": "(T,) classic slope-based vertical protection level (m), Brown 1992",
}
#: Optional outputs of every algorithm (``outputs=`` option), as the scenario engine's
#: result columns of the same name (``(T,)``) or per-satellite arrays (``(T, n)``).
FDE_ALGORITHM_OUTPUTS = {
    "parity": FDE_OUTPUTS,
    "mss": {
        "hpl_m": "(T,) MSS horizontal protection level (m), seed 001 (no baro)",
        "vpl_m": "(T,) MSS vertical protection level (m), seed 001 (no baro)",
        "hpl_classic_m": "(T,) classic slope-based HPL of the chi-square detector (m)",
        "vpl_classic_m": "(T,) classic slope-based VPL of the chi-square detector (m)",
        "sep_ratio": "(T, n) separation over threshold of each sub-solution (NaN unused)",
    },
    "gf": {
        "mf": "(T, n) fused evidence m(F) that each satellite is faulty (NaN unused)",
        "mf_threshold": "(T,) isolation threshold on m(F): mean m(F) + gf_margin",
    },
    "rs": {"rs_isolated": "(T, n) 1 where random search isolates the satellite, else 0"},
    "qv": {
        "qv_score": "(T, n) confidence index of each satellite (NaN unused)",
        "qv_threshold": "(T,) isolation threshold on it: mean index + qv_margin",
    },
    "araim": {
        "hpl_m": "(T,) ARAIM horizontal protection level (m), ADD v4.2",
        "vpl_m": "(T,) ARAIM vertical protection level (m), ADD v4.2",
        "emt_m": "(T,) effective monitor threshold (m)",
        "sigma_acc_v_m": "(T,) vertical accuracy sigma of the all-in-view solution (m; the "
                         "engine's column sigma_acc_m)",
    },
}
#: Epochs per chunk by default. The working set is about 190 B per satellite and epoch
#: (1.9 kB per epoch with 10 satellites), so a chunk stays near the L2 cache; 1024 to 3072
#: measured alike with 10 to 40 satellites (tests/benchmarks/bench_fde.py).
CHUNK_EPOCHS = 2048

_MAX_ITER = 12  # Gauss-Newton limit and step tolerance: those of raimcore.lsq.wls
_TOL_M = 1e-4
_SJJ_MIN = 1e-9  # raimcore.algorithms.parity._SJJ_MIN: no redundancy for that satellite
_DET_SURE = 1e-6  # raimcore.lsq._well_conditioned: det > 1e-6 decides "well conditioned"
_R_EARTH_M = 6.371e6  # picks the Bancroft root (mean Earth radius, IUGG)
_DUMMY_M = 3.0e7  # position and range given to unused satellites (never a zero range)
_P_FA = 1e-3  # default false-alarm probability of fde()
_NO_LIMIT_M = 1.0e9  # alert limits handed to the engine: no output of fde() depends on them
_STATUS_DTYPE = np.array([STATUS_OK, STATUS_NO_ISOLATION, STATUS_UNAVAILABLE]).dtype

# Options of fde(): name -> (default, help, algorithms it applies to). Declared once;
# _options() checks against it. The algorithm-specific options of the registered
# algorithms (mss_ident_rule, gf_groups, ...) are declared by their own option keys
# (raimcore.algorithms.<module>.SPEC.options) and checked by them (_ENGINE_OPTIONS).
_ALL = FDE_ALGORITHMS
_OPTIONS = {
    "outputs": ((), "names of optional outputs to compute, from FDE_ALGORITHM_OUTPUTS", _ALL),
    "p_md": (1e-3, "missed-detection probability of the protection levels, in (0, 1)",
             ("parity", "mss")),
    "chunk_epochs": (CHUNK_EPOCHS, "epochs processed per chunk (memory is flat in T)",
                     ("parity",)),
    "path": ("fast", "'fast' (the kernel) or 'reference' (the plain numpy path it replaces)",
             ("parity",)),
    "seed": (0, "integer seed of the random draws (a scenario's seed gives its draws)",
             ("rs",)),
    "sigma_acc_m": (None, "scalar or (T, n) accuracy 1-sigma (m; default sigma_m)",
                    ("araim",)),
    "b_nom_m": (0.0, "scalar, (n,) or (T, n) nominal integrity bias b_nom (m)", ("araim",)),
    "b_cont_m": (0.0, "scalar, (n,) or (T, n) continuity bias b_cont (m)", ("araim",)),
    "p_sat": (1e-5, "scalar, (n,) or (T, n) prior satellite fault probability", ("araim",)),
    "p_const": (1e-8, "scalar or (q,) prior constellation fault probability per system",
                ("araim",)),
}
# Options of the registered algorithms that fde() passes on (araim: emt_max_m and
# sigma_acc_max_m only set LPV-200 availability, t_exp_s needs mean fault durations).
_ENGINE_OPTIONS = {
    "parity": (), "mss": ("mss_ident_rule",), "gf": ("gf_groups", "gf_margin", "gf_weights"),
    "rs": ("rs_draws",), "qv": ("qv_groups", "qv_margin", "qv_norm"),
    "araim": ("araim_rules", "araim_fde", "araim_constants"),
}


@dataclass(frozen=True)
class FdeResult:
    """Snapshot FDE of every epoch (from :func:`fde`). ``T`` epochs, ``n`` satellites.

    ``alarm``, ``excluded``, ``pos_ecef_m`` and ``status`` mean the same for every
    algorithm; the statistic and its threshold are each algorithm's own.

    Attributes
    ----------
    algorithm : the algorithm that ran.
    status : (T,) str, ``"ok"`` (detection and isolation available), ``"detect-only"``
        (detection only: one redundant measurement; gf/rs/qv: fewer than 5 + q
        satellites, too few for two groups) or ``"unavailable"`` (too few satellites,
        singular geometry, no convergence: NaN statistic and position, no alarm).
    statistic : (T,) detection statistic before exclusion, NaN where unavailable. parity,
        gf, rs, qv: the chi-square of the weighted residuals r^T W r; mss: the largest
        separation over its threshold; araim: the largest normalised separation.
    threshold : (T,) its threshold (chi-square: chi2.isf(p_fa, dof); mss, araim: 1), NaN
        where unavailable.
    alarm : (T,) bool, the algorithm's detection test fails (``statistic >= threshold``
        for parity, ``>`` for the others), never where unavailable.
    dof : (T,) int, redundancy m - (3 + clocks) of the all-satellite solution.
    isolated : (T,) int, satellite the algorithm names faulty where an alarm is raised
        (parity: largest isolation statistic; mss: the identified or best-ranked
        sub-solution; gf, qv: largest score; rs: an isolated satellite; araim: the
        excluded satellite or the satellite of the mode explaining the alarm), -1
        otherwise and where none is named.
    excluded : (T, n) bool, satellites excluded, at most ``max_exclusions`` at one epoch.
    pos_ecef_m : (T, 3) position after exclusion (equal to ``pos_before_ecef_m`` where
        nothing was excluded; NaN where the epoch is unavailable, which includes 4
        satellites and no redundancy, or where the solution after exclusion is).
    pos_before_ecef_m : (T, 3) position from all tracked satellites (NaN where
        unavailable).
    clock_m : (T, q) receiver clock of each system before exclusion (m; NaN for a system
        with no satellite tracked and where unavailable). parity only: NaN for the other
        algorithms, whose engine output has no clock.
    statistic_after : (T,) detection statistic of the last solution after exclusion.
        parity only: NaN for the other algorithms.
    outputs : the optional outputs asked for (``outputs=`` option), by name, see
        :data:`FDE_ALGORITHM_OUTPUTS`.
    """

    algorithm: str
    status: np.ndarray
    statistic: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    dof: np.ndarray
    isolated: np.ndarray
    excluded: np.ndarray
    pos_ecef_m: np.ndarray
    pos_before_ecef_m: np.ndarray
    clock_m: np.ndarray
    statistic_after: np.ndarray
    outputs: Mapping[str, np.ndarray] = field(default_factory=dict)


def fde(pos_sv_ecef_m, pr_m, sigma_m, *, algorithm: str = "parity", sys_idx=None,
        p_fa: float | None = None, max_exclusions: int = 1, **options: Any) -> FdeResult:
    """Snapshot fault detection and exclusion on arrays, every epoch at once.

    Parameters
    ----------
    pos_sv_ecef_m : (T, n, 3) satellite positions (m) in the ECEF frame at receive time
        (Earth rotation during the signal flight already applied); may be NaN for a
        satellite not tracked.
    pr_m : (T, n) pseudoranges (m), corrected for the satellite clock and the atmosphere;
        NaN = not tracked at that epoch.
    sigma_m : scalar or (T, n) 1-sigma of each pseudorange (m), finite and > 0 wherever
        ``pr_m`` is finite (araim: ``sigma_int``, the integrity sigma).
    algorithm : one of :data:`FDE_ALGORITHMS`, each running the implementation of the
        registered algorithm of that name:

        * ``"parity"`` (seed 000): chi-square test of the parity vector, isolation by the
          largest DF_I, exclusion and re-solve, greedily up to ``max_exclusions``;
        * ``"mss"`` (seed 001): multiple solution separation, identification by
          sub-sub-solutions, exclusion of one satellite or (after a multiple-fault verdict)
          a pair. Barometric aiding is off (no altimeter in the arrays);
        * ``"gf"``, ``"rs"``, ``"qv"`` (seed 004): chi-square detection, then multi-fault
          isolation by group evidence fusion, random search or quality value; every
          isolated satellite is excluded;
        * ``"araim"`` (ARAIM ADD v4.2): multiple hypothesis solution separation; the
          exclusion is a satellite or a whole constellation.
    sys_idx : (n,) int system index of each satellite (one receiver clock per system);
        default all 0 (one system).
    p_fa : false-alarm probability of the detection test, in (0, 1); default 1e-3. Not
        for araim, whose false-alarm budgets are the constants ``p_fa_vert`` and
        ``p_fa_hor`` of its rule set (``araim_constants``).
    max_exclusions : satellites that may be excluded at one epoch, >= 0 (0: detect only;
        parity: in [0, 10], excluded greedily one after another). For the others it caps the
        algorithm's own exclusion: where it would exclude more satellites (an mss pair, a
        gf/rs/qv set, an araim constellation) nothing is excluded, the alarm stands and
        ``pos_ecef_m`` is the all-satellite position; the scenario engine's decisions are
        those of a cap at least the number of satellites.
    **options : by algorithm (any other is refused, naming those that apply):

        * all: ``outputs``, a tuple of names from ``FDE_ALGORITHM_OUTPUTS[algorithm]``
          (default none);
        * parity: ``p_md`` (protection levels, default 1e-3), ``chunk_epochs`` (default
          2048), ``path`` (``"fast"``, default, or ``"reference"``: the plain numpy path
          the kernel replaces, same decisions, for checking);
        * mss: ``p_md`` (protection levels, default 1e-3), ``mss_ident_rule``
          (``"unique"``, default, or ``"rank"``);
        * gf: ``gf_groups`` (0 = N^2, default), ``gf_margin`` (0.1), ``gf_weights``
          (``"pdop"``); qv: ``qv_groups``, ``qv_margin``, ``qv_norm``;
        * rs: ``rs_draws`` (50) and ``seed`` (int, default 0: with a scenario's seed the
          draws are the scenario engine's). The draws of an epoch are keyed by the rank of
          its set of tracked satellites among the batch's sets, so they may change with
          the rest of the batch;
        * araim: ``araim_rules`` (``"add-v4.2"``, default, or ``"blanch-2012"``),
          ``araim_fde`` (exclusion, default True), ``araim_constants`` (a dict of kernel
          constants, e.g. ``{"phmi_vert": 1e-9}``), and the integrity support message as
          arrays: ``sigma_acc_m`` (accuracy sigma, default ``sigma_m``: sigma_int =
          sigma_acc), ``b_nom_m`` and ``b_cont_m`` (biases, default 0), ``p_sat``
          (default 1e-5) and ``p_const`` (per system, default 1e-8; both MAAST's GPS
          values). :func:`raimcore.measure.error_models.araim_sigmas` gives the sigmas
          the scenario engine derives from elevations and an ISM. An epoch without
          redundancy is "unavailable", as for every algorithm here (the registered araim
          calls it "detect-only", its statistic NaN or rounding noise).

        The algorithm-specific options are declared once, by the registered algorithm
        (``raimcore.algorithms.get(name).options``), and checked by it.

    Returns
    -------
    FdeResult ; an epoch with too few satellites or singular geometry is
    ``status = "unavailable"`` with NaN values and no alarm (no exception).

    Raises
    ------
    ValueError naming the argument: bad shapes, non-positive sigma, p_fa outside (0, 1),
    an algorithm that is not supported, an option unknown or not of this algorithm, an
    option value out of range, an output the algorithm does not have.

    Notes
    -----
    The fast parity path makes the decisions of the reference path (``tests/test_fde.py``)
    with one exception that is not a decision: two satellites alone in their system have
    parallel parity columns (isolability 1) and exactly equal isolation statistics, so
    which of them the largest DF_I names is decided by rounding, in both paths.

    References
    ----------
    Liao X., Huang S. (1996), parity vector method for GPS fault detection and isolation
    (seed 000). Bancroft S. (1985), An algebraic solution of the GPS equations, IEEE
    Trans. AES 21(1). Seeds 001 (MSS) and 004 (GF, RS, QV); ARAIM ADD v4.2 (2022): see
    the registered algorithms.

    Examples
    --------
    >>> import numpy as np, raimcore
    >>> rng = np.random.default_rng(1)
    >>> u = rng.normal(size=(1, 8, 3)); u[..., 2] = np.abs(u[..., 2])
    >>> u /= np.linalg.norm(u, axis=-1, keepdims=True)
    >>> rx = np.array([0.0, 0.0, 6.371e6])
    >>> sv = rx + 2.2e7 * u
    >>> pr = np.linalg.norm(sv - rx, axis=-1) + rng.normal(0, 1.0, (1, 8))
    >>> pr[0, 3] += 80.0
    >>> r = raimcore.fde(sv, pr, 1.0)
    >>> bool(r.alarm[0]), np.flatnonzero(r.excluded[0]).tolist(), str(r.status[0])
    (True, [3], 'ok')
    >>> bool(np.linalg.norm(r.pos_ecef_m[0] - rx) < 5.0)
    True
    >>> m = raimcore.fde(sv, pr, 1.0, algorithm="mss")
    >>> bool(m.alarm[0]), np.flatnonzero(m.excluded[0]).tolist(), str(m.status[0])
    (True, [3], 'ok')
    """
    if algorithm not in FDE_ALGORITHMS:
        raise ValueError(f"algorithm must be one of {', '.join(FDE_ALGORITHMS)}; got "
                         f"{algorithm!r}")
    opts, engine_opts = _options(algorithm, options)
    sv, pr, w, sys_idx, n_sys = _check_inputs(pos_sv_ecef_m, pr_m, sigma_m, sys_idx)
    if p_fa is not None and algorithm == "araim":
        raise ValueError("p_fa does not apply to algorithm 'araim': its false-alarm budgets "
                         "are the constants p_fa_vert and p_fa_hor (option araim_constants)")
    p_fa = check_probability("p_fa", _P_FA if p_fa is None else p_fa)
    max_excl = check_int("max_exclusions", max_exclusions, 0,
                         10 if algorithm == "parity" else None)
    if algorithm != "parity":
        sigma = _sigma_array(sigma_m, w)
        if algorithm == "araim":
            out = _araim(sv, pr, w, sigma, sys_idx, n_sys, opts, engine_opts)
        else:
            data = _measurements(sv, pr, w, sigma, sys_idx, n_sys, p_fa, opts["p_md"],
                                 opts["seed"])
            out = _run_registered(algorithm, data, engine_opts)
        return _from_output(algorithm, out, w, sys_idx, n_sys, max_excl, opts["outputs"])
    run = _parity_fde if opts["path"] == "fast" else _parity_fde_reference
    kw = {} if opts["path"] != "fast" else {"chunk_epochs": opts["chunk_epochs"]}
    out = run(sv, pr, w, sys_idx, n_sys, p_fa, max_excl, outputs=opts["outputs"],
              p_md=opts["p_md"], **kw)
    valid = out["valid"]
    status = np.where(~valid, STATUS_UNAVAILABLE,
                      np.where(out["dof"] >= 2, STATUS_OK, STATUS_NO_ISOLATION))
    # An unavailable epoch has no position either (as the scenario engine reports it),
    # even when 4 satellites fix one without redundancy.
    nan = lambda a: np.where(valid[:, None], a, np.nan)  # noqa: E731
    return FdeResult(
        algorithm=algorithm, status=status, statistic=out["statistic"],
        threshold=out["threshold"], alarm=out["alarm"], dof=out["dof"],
        isolated=np.where(out["alarm"], out["best"], -1), excluded=out["excluded"],
        pos_ecef_m=nan(out["pos_after"]), pos_before_ecef_m=nan(out["pos_before"]),
        clock_m=nan(out["clock"]), statistic_after=out["statistic_after"],
        outputs={k: out[k] for k in opts["outputs"]})


def _options(algorithm, options):
    """Validate ``**options`` of :func:`fde` for ``algorithm``.

    Returns ``(opts, engine_opts)``: the options of :data:`_OPTIONS` (defaults filled)
    and those of the registered algorithm, resolved by its option keys.
    """
    mine = [k for k, v in _OPTIONS.items() if algorithm in v[2]]
    engine_names = _ENGINE_OPTIONS[algorithm]
    allowed = mine + list(engine_names)
    for name in options:
        if name in allowed:
            continue
        where = [a for a in FDE_ALGORITHMS
                 if a in _OPTIONS.get(name, ((), "", ()))[2] or name in _ENGINE_OPTIONS[a]]
        if where:
            raise ValueError(f"option {name!r} does not apply to algorithm {algorithm!r} "
                             f"(only to {', '.join(where)}); options of {algorithm}: "
                             f"{', '.join(allowed)}")
        raise ValueError(f"unknown option {name!r} for raimcore.fde; options: "
                         f"{', '.join(allowed)} (algorithm {algorithm!r})")
    opts = {k: options.get(k, d) for k, (d, _, _) in _OPTIONS.items()}
    outs = opts["outputs"]
    outs = (outs,) if isinstance(outs, str) else tuple(outs)
    have = FDE_ALGORITHM_OUTPUTS[algorithm]
    for o in outs:
        if o not in have:
            raise ValueError(f"outputs must name some of {', '.join(have)} (algorithm "
                             f"{algorithm!r}); got {o!r}")
    opts["outputs"] = tuple(dict.fromkeys(outs))
    opts["p_md"] = check_probability("p_md", opts["p_md"])
    opts["chunk_epochs"] = check_int("chunk_epochs", opts["chunk_epochs"], 1)
    opts["seed"] = check_int("seed", opts["seed"], 0)
    check_choice("path", opts["path"], ("fast", "reference"))
    engine_opts = {}
    if engine_names:
        from .algorithms import get

        engine_opts = get(algorithm).resolve_options(
            {k: v for k, v in options.items() if k in engine_names})
    return opts, engine_opts


def _sigma_array(sigma_m, w):
    """``sigma_m`` as a (T, n) array: the values given where tracked (``w > 0``), 1 elsewhere
    (checked by :func:`_check_inputs`)."""
    sig = np.broadcast_to(np.asarray(sigma_m, dtype=float), w.shape)
    return np.where(w > 0, sig, 1.0)


def _measurements(sv, pr, w, sigma, sys_idx, n_sys, p_fa, p_md, seed):
    """The arrays as the :class:`~raimcore.measure.Measurements` a registered algorithm
    takes: tracked = ``w > 0``, no altimeter, no elevations (NaN: the snapshot algorithms
    wired here do not read them), alert limits that no output of :func:`fde` reads."""
    from .measure.data import Measurements

    t_n, s_n = pr.shape
    used = w > 0
    # A satellite without a position is not tracked; the engine always has positions.
    sv = np.where(np.isfinite(sv).all(axis=-1, keepdims=True), sv, _DUMMY_M)
    unknown = np.full((t_n, s_n), np.nan)
    return Measurements(
        t_s=np.arange(t_n, dtype=float), sat_names=tuple(f"SV{j}" for j in range(s_n)),
        sys_idx=sys_idx, systems=tuple(f"SYS{k}" for k in range(n_sys)), pos_sv_ecef_m=sv,
        pr_m=np.where(used, pr, np.nan), used=used, az_rad=unknown, el_rad=unknown,
        sigma_m=sigma, noise=None, p_fa=p_fa, p_md=p_md, hal_m=_NO_LIMIT_M,
        val_m=_NO_LIMIT_M, seed=seed)


def _run_registered(algorithm, data, engine_opts):
    """The registered ``algorithm`` on ``data``, as the scenario engine runs it."""
    from .algorithms import get
    from .pipeline import run_algorithm

    return run_algorithm(get(algorithm), data, engine_opts)


def _araim(sv, pr, w, sigma, sys_idx, n_sys, opts, engine_opts):
    """ARAIM MHSS on the arrays: the orchestration of :func:`raimcore.algorithms.araim.run`
    with the sigmas and ISM values given as arrays; returns an ``AlgorithmOutput``.

    As :func:`raimcore.pipeline.run_algorithm` does, the satellites never tracked are
    dropped first and put back (not excluded) at the end: the kernel's choice between two
    modes with equal separations follows the column order, so this keeps the engine's.
    """
    t_n, s_n = pr.shape
    used = w > 0
    sig_acc = sigma if opts["sigma_acc_m"] is None else _ism_array(
        "sigma_acc_m", opts["sigma_acc_m"], (t_n, s_n), used, positive=True)
    ism = (sig_acc, _ism_array("b_nom_m", opts["b_nom_m"], (t_n, s_n), used),
           _ism_array("b_cont_m", opts["b_cont_m"], (t_n, s_n), used),
           _ism_array("p_sat", opts["p_sat"], (t_n, s_n), used, hi=1.0))
    p_const = _ism_array("p_const", opts["p_const"], (n_sys,), None, hi=1.0)
    cols = np.flatnonzero(used.any(axis=0))
    if cols.size == 0:
        from .pipeline import unavailable_output

        return unavailable_output(_measurements(sv, pr, w, sigma, sys_idx, n_sys, _P_FA,
                                                1e-3, 0))
    out = _araim_kernel(sv[:, cols], pr[:, cols], w[:, cols], sigma[:, cols], sys_idx[cols],
                        n_sys, *(a[:, cols] for a in ism), p_const, engine_opts)
    return out.expand_sats(cols, s_n)


def _araim_kernel(sv, pr, w, sigma, sys_idx, n_sys, sig_acc, b_nom, b_cont, p_sat, p_const,
                  engine_opts):
    """:func:`_araim` on the tracked satellites: the registered algorithm's decisions
    (:func:`raimcore.algorithms.araim.solve`), with its sigmas and ISM as arrays."""
    from .algorithms.araim import solve
    from .algorithms.base import AlgorithmOutput

    used = w > 0
    sol = solve(sv, pr, used, np.where(used, sigma, np.nan), np.where(used, sig_acc, np.nan),
                b_nom, b_cont, p_sat, p_const, sys_idx, n_sys,
                rules=engine_opts["araim_rules"], fde=engine_opts["araim_fde"],
                params=engine_opts["araim_constants"].as_dict())
    res, avail = sol.res, sol.avail
    return AlgorithmOutput(
        status=sol.status, statistic=np.where(avail, res.test_ratio, np.nan),
        threshold=np.where(avail, 1.0, np.nan), alarm=sol.alarm,
        pos_before_ecef_m=sol.pos_before, pos_after_ecef_m=sol.pos_after,
        excluded=sol.excluded, isolated=sol.isolated,
        columns={"hpl_m": res.hpl_m, "vpl_m": res.vpl_m, "emt_m": res.emt_m,
                 "sigma_acc_v_m": res.sigma_acc_v_m})


def _ism_array(name, value, shape, used, *, positive=False, hi=None):
    """An ARAIM option as an array of ``shape`` ((T, n) accepts a scalar, (n,) or (T, n);
    (q,) a scalar or (q,)): finite, >= 0 (> 0 if ``positive``) and <= ``hi`` where
    ``used`` (everywhere if None), or a one-line ValueError."""
    a = np.asarray(value, dtype=float)
    allowed = [(), shape[-1:], shape]
    if a.shape not in allowed:
        shapes = " or ".join(str(s) for s in allowed[1:])
        raise ValueError(f"{name} must be a scalar or have shape {shapes}, got {a.shape}")
    a = np.broadcast_to(a, shape)
    vals = a if used is None else a[used]
    lo_ok = vals > 0.0 if positive else vals >= 0.0
    if not (np.isfinite(vals).all() and lo_ok.all() and (hi is None or (vals <= hi).all())):
        rng = ("> 0" if positive else ">= 0") + ("" if hi is None else f" and <= {hi:g}")
        where = "" if used is None else " wherever pr_m is finite"
        raise ValueError(f"{name} must be finite and {rng}{where}")
    return a


def _from_output(algorithm, out, w, sys_idx, n_sys, max_excl, outputs):
    """An :class:`FdeResult` from a registered algorithm's ``AlgorithmOutput``: the
    exclusion capped at ``max_excl`` satellites, NaN and no alarm where unavailable."""
    status = np.asarray(out.status, dtype=_STATUS_DTYPE)
    valid = status != STATUS_UNAVAILABLE
    t_n = len(status)
    alarm = np.asarray(out.alarm, dtype=bool) & valid
    excluded = np.asarray(out.excluded, dtype=bool) & valid[:, None]
    excluded[excluded.sum(axis=-1) > max_excl] = False  # capped: nothing excluded there
    nan_rows = ~valid[:, None]
    pos_before = np.where(nan_rows, np.nan, out.pos_before_ecef_m)
    pos_after = np.where(excluded.any(axis=-1)[:, None], out.pos_after_ecef_m, pos_before)
    used = w > 0
    n_present = (used.astype(float) @ _clock_columns(sys_idx, n_sys) > 0).sum(axis=-1)
    extra = {**out.columns, **out.per_sat}
    return FdeResult(
        algorithm=algorithm, status=status,
        statistic=np.where(valid, np.asarray(out.statistic, dtype=float), np.nan),
        threshold=np.where(valid, np.asarray(out.threshold, dtype=float), np.nan),
        alarm=alarm, dof=used.sum(axis=-1) - 3 - n_present,
        isolated=np.where(alarm, np.asarray(out.isolated), -1), excluded=excluded,
        pos_ecef_m=np.where(nan_rows, np.nan, pos_after), pos_before_ecef_m=pos_before,
        clock_m=np.full((t_n, n_sys), np.nan), statistic_after=np.full(t_n, np.nan),
        outputs={k: np.asarray(extra[k]) for k in outputs})


def _check_inputs(pos_sv_ecef_m, pr_m, sigma_m, sys_idx):
    """Shapes and values of :func:`fde`'s arrays; returns ``sv, pr, w, sys_idx, n_sys``.

    ``w`` is ``1 / sigma^2`` where the pseudorange and the satellite position are finite,
    else 0 (not tracked).
    """
    sv = check_array("pos_sv_ecef_m", pos_sv_ecef_m, last=("n", 3), finite=False)
    if sv.ndim != 3:
        raise ValueError(f"pos_sv_ecef_m must have shape (T, n, 3), got {sv.shape}")
    t_n, s_n = sv.shape[:2]
    pr = check_array("pr_m", pr_m, last=(s_n,), finite=False,
                     match=f"pos_sv_ecef_m (T, {s_n}, 3)")
    if pr.shape != (t_n, s_n):
        raise ValueError(f"pr_m must have shape ({t_n}, {s_n}) to match pos_sv_ecef_m "
                         f"{sv.shape}, got {pr.shape}")
    sig = check_array("sigma_m", sigma_m, ndim_min=0, finite=False)
    if sig.shape not in ((), (t_n, s_n)):
        raise ValueError(f"sigma_m must be a scalar or have shape ({t_n}, {s_n}), got "
                         f"{sig.shape}")
    with np.errstate(invalid="ignore", over="ignore"):  # x + y + z: NaN if one is not finite
        tracked = np.isfinite(pr + np.einsum("tnk->tn", sv))
    if sig.ndim:
        ok = np.isfinite(sig) & (sig > 0.0)
        if not ok[tracked].all():
            raise ValueError("sigma_m must be finite and > 0 wherever pr_m is finite")
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(tracked, 1.0 / sig**2, 0.0)
    else:
        if not (np.isfinite(sig) and sig > 0.0):
            raise ValueError("sigma_m must be finite and > 0 wherever pr_m is finite")
        w = tracked * (1.0 / float(sig) ** 2)
    if sys_idx is None:
        sys_idx = np.zeros(s_n, dtype=int)
    else:
        a = np.asarray(sys_idx)
        if a.shape != (s_n,) or a.dtype.kind not in "iu" or (s_n and a.min() < 0):
            raise ValueError(f"sys_idx must be an integer array of shape ({s_n},) with "
                             f"values >= 0, got {a!r}")
        sys_idx = a.astype(int)
    n_sys = int(sys_idx.max()) + 1 if s_n else 1
    return sv, pr, w, sys_idx, n_sys


# --------------------------------------------------------------------------------------
# The fast kernel
# --------------------------------------------------------------------------------------

def _thresholds(p_fa, n_max):
    """chi2.isf(p_fa, d) for d = 0..n_max (NaN for d = 0): one table, looked up by dof."""
    from scipy import stats

    d = np.arange(n_max + 1)
    return np.where(d >= 1, stats.chi2.isf(p_fa, np.maximum(d, 1)), np.nan)


def _parity_fde(sv, pr, w, sys_idx, n_sys, p_fa, max_excl, *, outputs=(), p_md=1e-3,
                chunk_epochs=CHUNK_EPOCHS):
    """Parity FDE of every epoch, chunk by chunk (trusted inputs; see :func:`fde`).

    Parameters
    ----------
    sv : (T, n, 3); pr : (T, n); w : (T, n) weights 1 / sigma^2, 0 for an unused satellite
        (a used satellite with a non-finite pseudorange or position makes the epoch
        unavailable); sys_idx : (n,) in [0, n_sys); p_fa, max_excl : as in :func:`fde`.
    outputs : names from :data:`FDE_OUTPUTS` to compute as well.

    Returns
    -------
    dict of (T, ...) arrays: ``valid`` (available and dof >= 1), ``dof``, ``statistic``,
    ``threshold``, ``alarm``, ``best`` (largest DF_I where an alarm is raised or
    ``isolation`` is asked for, else -1), ``excluded``,
    ``pos_before``, ``clock``, ``pos_after``, ``statistic_after`` and the ``outputs``.
    """
    t_n, s_n = pr.shape
    thr_tab = _thresholds(p_fa, s_n)
    onehot = _clock_columns(sys_idx, n_sys).T.copy()  # (q, n)
    out = {
        "valid": np.zeros(t_n, bool), "dof": np.zeros(t_n, int),
        "statistic": np.full(t_n, np.nan), "threshold": np.full(t_n, np.nan),
        "alarm": np.zeros(t_n, bool), "best": np.full(t_n, -1),
        "excluded": np.zeros((t_n, s_n), bool), "pos_before": np.full((t_n, 3), np.nan),
        "clock": np.full((t_n, n_sys), np.nan), "pos_after": np.full((t_n, 3), np.nan),
        "statistic_after": np.full(t_n, np.nan)}
    per_sat = [k for k in ("isolation", "fault_size_m", "isolability") if k in outputs]
    for k in per_sat:
        out[k] = np.full((t_n, s_n), np.nan)
    pl = "hpl_m" in outputs or "vpl_m" in outputs
    if pl:
        out["hpl_m"] = np.full(t_n, np.nan)
        out["vpl_m"] = np.full(t_n, np.nan)
    ctx = _Ctx(sys_idx, onehot, thr_tab)
    # Unavailable epochs divide by zero on their way to NaN; they are flagged explicitly.
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for c0 in range(0, t_n, chunk_epochs):
            c1 = min(c0 + chunk_epochs, t_n)
            _chunk(ctx, sv, pr, w, c0, c1, max_excl, per_sat, pl, p_fa, p_md, out)
    return out


class _Ctx:
    """Per-call constants of the kernel."""

    def __init__(self, sys_idx, onehot, thr_tab):
        self.sys_idx = sys_idx
        self.onehot = onehot
        self.q = onehot.shape[0]
        self.thr_tab = thr_tab


def _chunk(ctx, sv, pr, w, c0, c1, max_excl, per_sat, pl, p_fa, p_md, out):
    """Run the kernel on epochs ``c0:c1`` and write into ``out``."""
    # Epoch axis last and contiguous: every element-wise operation is one vector loop.
    g = np.ascontiguousarray(sv[c0:c1].transpose(2, 1, 0))  # (3, n, R)
    p = np.ascontiguousarray(pr[c0:c1].T)
    wt = np.ascontiguousarray(w[c0:c1].T)
    used = wt > 0.0
    fin = np.isfinite(p) & np.isfinite(g).all(axis=0)
    broken = np.any(used & ~fin, axis=0)  # a used measurement that is not a number
    if not fin.all():
        g[:, ~fin] = _DUMMY_M
        p[~fin] = _DUMMY_M
    if broken.any():
        wt[:, broken] = 0.0
    s = _solve(ctx, g, p, wt, None, None, per_sat=per_sat, excl=max_excl > 0)  # isolates
    r_n = c1 - c0
    sl = slice(c0, c1)
    valid = s["valid"]
    out["valid"][sl] = valid
    out["dof"][sl] = s["dof"]
    out["statistic"][sl] = s["stat"]
    out["threshold"][sl] = s["thr"]
    out["alarm"][sl] = s["alarm"]
    out["best"][sl] = s["best"]
    avail = s["available"]
    pos = np.where(avail, s["x"], np.nan).T
    out["pos_before"][sl] = pos
    out["clock"][sl] = np.where(avail & (s["w_sys"] > 0.0), s["clk"], np.nan).T
    out["pos_after"][sl] = pos
    out["statistic_after"][sl] = s["stat"]
    for k in per_sat:
        out[k][sl] = s[k].T
    if pl:
        _protection_levels(ctx, sv[c0:c1], pr[c0:c1], w[c0:c1], s, avail, p_fa, p_md,
                           out, sl)
    # Greedy exclusion: re-solve only the epochs that alarm and can isolate, started from
    # the linearised solution without the isolated satellite (seed 000 section 1.3).
    act = s["alarm"] & (s["best"] >= 0)
    drop = s["best"]
    rows = np.arange(r_n)
    excl = np.zeros(wt.shape, bool)
    x, ck = s["x_excl"], s["clk_excl"]
    for k in range(max_excl):
        sel = np.flatnonzero(act)
        if sel.size == 0:
            break
        rows = rows[sel]
        excl[drop[sel], rows] = True
        w_sub = np.where(excl[:, rows], 0.0, wt[:, rows])
        sub = _solve(ctx, g[:, :, rows], p[:, rows], w_sub, x[:, sel], ck[:, sel],
                     isolate=k + 1 < max_excl, excl=k + 1 < max_excl)
        x, ck = sub["x_excl"], sub["clk_excl"]
        out["pos_after"][c0 + rows] = np.where(sub["available"], sub["x"], np.nan).T
        out["statistic_after"][c0 + rows] = sub["stat"]
        act = sub["alarm"] & (sub["best"] >= 0)
        drop = sub["best"]
    out["excluded"][sl] = excl.T


def _bancroft_start(ctx, g, p, wt):
    """Bancroft start (:func:`_bancroft`) from the system with the most satellites (if it
    has 4: Bancroft has one clock, and inter-system clock offsets reach tens of km), the
    Earth's centre where Bancroft has no solution: ``(3, R)``, ``(q, R)``."""
    q, sys_idx, onehot = ctx.q, ctx.sys_idx, ctx.onehot
    r_n = wt.shape[1]
    wb = wt
    if q > 1:
        cnt = onehot @ (wt > 0.0)
        main = np.argmax(cnt, axis=0)
        one = cnt[main, np.arange(r_n)] >= 4
        wb = np.where((sys_idx[:, None] == main) | ~one, wt, 0.0)
    x, b = _bancroft(g, p, wb)
    good = np.all(np.isfinite(x), axis=0) & np.isfinite(b)
    x = np.where(good, x, 0.0)
    return x, np.broadcast_to(np.where(good, b, 0.0), (q, r_n)).copy()


def _bancroft(g, p, wt):
    """Closed-form position and one common clock (Bancroft 1985), weighted.

    ``g (3, n, R)`` satellite positions, ``p (n, R)`` pseudoranges, ``wt (n, R)`` weights.
    Returns ``(3, R)`` position and ``(R,)`` clock (m), NaN where the solution does not
    exist (fewer than 4 satellites, singular system).
    """
    sc = 1e-7  # scale to O(1) numbers
    a = np.empty((4,) + p.shape)
    np.multiply(g, sc, out=a[:3])
    np.multiply(p, sc, out=a[3])
    alpha = 0.5 * (np.einsum("knr,knr->nr", a[:3], a[:3]) - a[3] * a[3])
    gm4 = np.einsum("knr,lnr,nr->klr", a, a, wt)  # B^T W B
    b1 = np.einsum("knr,nr->kr", a, wt)  # B^T W 1
    alpha *= wt
    b2 = np.einsum("knr,nr->kr", a, alpha)  # B^T W alpha
    gm = [[gm4[i, j] for j in range(i + 1)] for i in range(4)]
    u, v = _chol_solve(gm, [list(b1), list(b2)])
    uu = u[0] ** 2 + u[1] ** 2 + u[2] ** 2 - u[3] ** 2
    uv = u[0] * v[0] + u[1] * v[1] + u[2] * v[2] - u[3] * v[3]
    vv = v[0] ** 2 + v[1] ** 2 + v[2] ** 2 - v[3] ** 2
    disc = np.sqrt(np.maximum((uv - 1.0) ** 2 - uu * vv, 0.0))
    best = None
    for sgn in (1.0, -1.0):
        lam = (1.0 - uv + sgn * disc) / uu
        y = [v[k] + lam * u[k] for k in range(4)]
        err = np.abs(np.sqrt(y[0] ** 2 + y[1] ** 2 + y[2] ** 2) - _R_EARTH_M * sc)
        if best is None:
            best, berr = y, err
        else:
            pick = err < berr
            best = [np.where(pick, y[k], best[k]) for k in range(4)]
    return np.stack(best[:3]) / sc, -best[3] / sc


def _chol_solve(gm, rhs):
    """Solve ``G z = b`` for symmetric positive definite ``G`` given as its lower triangle
    ``gm[i][j]`` (i >= j) of (R,) arrays, for each right-hand side (list of (R,) arrays).
    NaN where ``G`` is not positive definite."""
    k = len(gm)
    ll = [[None] * k for _ in range(k)]
    for j in range(k):
        d = gm[j][j] - sum((ll[j][m] ** 2 for m in range(j)), 0.0)
        ll[j][j] = np.sqrt(np.where(d > 0.0, d, np.nan))
        for i in range(j + 1, k):
            ll[i][j] = (gm[i][j] - sum((ll[i][m] * ll[j][m] for m in range(j)), 0.0)
                        ) / ll[j][j]
    sols = []
    for b in rhs:
        y = [None] * k
        for i in range(k):
            y[i] = (b[i] - sum((ll[i][m] * y[m] for m in range(i)), 0.0)) / ll[i][i]
        z = [None] * k
        for i in reversed(range(k)):
            z[i] = (y[i] - sum((ll[m][i] * z[m] for m in range(i + 1, k)), 0.0)) / ll[i][i]
        sols.append(z)
    return sols


# Packed symmetric 3 x 3 (a, b, c, d, e, f) = (s00, s01, s02, s11, s12, s22): the cofactor
# of each entry is P * Q - U * V (indices into the packed form), and the full matrix back.
_PACK = [0, 1, 2, 4, 5, 8]
_COF = ([3, 2, 1, 0, 1, 0], [5, 4, 4, 5, 2, 3], [4, 1, 2, 2, 0, 1], [4, 5, 3, 2, 4, 1])
_UNPACK = [0, 1, 2, 1, 3, 4, 2, 4, 5]


def _adjugate(sm):
    """Adjugate ``(3, 3, R)`` and determinant ``(R,)`` of symmetric 3 x 3 matrices."""
    r_n = sm.shape[-1]
    s6 = sm.reshape(9, r_n)[_PACK]
    p, q, u, v = _COF
    a6 = s6[p] * s6[q] - s6[u] * s6[v]
    det = np.einsum("kr,kr->r", s6[:3], a6[:3])
    return a6[_UNPACK].reshape(3, 3, r_n), det


def _solve(ctx, g, p, wt, x0, clk0, *, per_sat=(), isolate=True, excl=True):
    """Gauss-Newton solution and parity statistics of R epochs.

    Parameters
    ----------
    g : (3, n, R) satellite positions; p : (n, R) pseudoranges; wt : (n, R) weights (0:
        unused; unused entries of ``g`` and ``p`` finite).
    x0, clk0 : (3, R), (q, R) start; None: Bancroft.
    per_sat : per-satellite outputs to compute for every valid epoch.
    isolate : compute ``best`` where an alarm is raised (otherwise ``best`` is -1 except
        where ``per_sat`` asks for isolation).
    excl : also the start of the re-solve without ``best`` (``x_excl``, ``clk_excl``).

    Returns
    -------
    dict: ``x (3, R)``, ``clk (q, R)``, ``available``, ``valid``, ``dof``, ``stat``,
    ``thr``, ``alarm``, ``best`` (R,), ``w_sys (q, R)``, ``x_excl``, ``clk_excl`` and the
    ``per_sat`` outputs ``(n, R)``.
    """
    s_n, r_n = wt.shape
    q, sys_idx, onehot = ctx.q, ctx.sys_idx, ctx.onehot
    used = wt > 0.0
    w_sys = onehot @ wt  # (q, R): W_s, total weight of each system
    n_used = np.count_nonzero(used, axis=0)
    n_states = 3 + np.count_nonzero(w_sys > 0.0, axis=0)
    if x0 is None:
        x, clk = _bancroft_start(ctx, g, p, wt)
    else:
        x, clk = x0.copy(), clk0.copy()
    inv_ws = np.where(w_sys > 0.0, 1.0 / w_sys, 0.0)
    res = {"x": x, "clk": clk, "available": np.zeros(r_n, bool), "w_sys": w_sys,
           "stat": np.full(r_n, np.nan), "best": np.full(r_n, -1),
           "x_excl": np.full((3, r_n), np.nan), "clk_excl": np.full((q, r_n), np.nan),
           "dof": n_used - n_states}
    for k in per_sat:
        res[k] = np.full((s_n, r_n), np.nan)
    act = np.arange(r_n)  # rows still iterating
    full = True  # act == all rows (no gather needed)
    a_g, a_p, a_w, a_iws = g, p, wt, inv_ws
    for _ in range(_MAX_ITER):
        xa, ca = (x, clk) if full else (x[:, act], clk[:, act])
        d = a_g - xa[:, None, :]
        rng = np.einsum("knr,knr->nr", d, d)
        np.sqrt(rng, out=rng)
        inv = 1.0 / rng
        dz = a_p - rng
        dz -= ca[sys_idx]
        u = d
        u *= inv  # lines of sight, receiver to satellite (in place: d is not used again)
        del d, rng, inv  # (working memory per epoch is what bounds the chunk)
        wu = u * a_w
        nuu = np.einsum("knr,lnr->klr", wu, u)  # sum w u u^T
        grad = np.einsum("knr,nr->kr", wu, dz)  # sum w u dz
        wmu = onehot @ wu  # (3, q, A): W_s ubar_s
        del wu
        mu = wmu * a_iws  # ubar_s, the mean line of sight of system s
        mdz = (onehot @ (a_w * dz)) * a_iws  # (q, A): mean_s(dz)
        # S3 dp = -sum w c dz, c = u - ubar_s (clocks eliminated); S3^-1 = adj / det.
        s3 = nuu - np.einsum("kqr,lqr->klr", wmu, mu)
        rhs = np.einsum("kqr,qr->kr", wmu, mdz) - grad
        adj, det = _adjugate(s3)
        del s3
        # lsq._well_conditioned(strict=False) in the ECEF frame, as wls iterates.
        ok = np.isfinite(det) & (det / (nuu[0, 0] * nuu[1, 1] * nuu[2, 2]) > RCOND_MIN)
        del nuu
        idet = 1.0 / det
        dp = np.einsum("klr,lr->kr", adj, rhs) * idet
        dclk = mdz + np.einsum("kqr,kr->qr", mu, dp)  # (q, A)
        now = ok & (np.einsum("kr,kr->r", dp, dp) < _TOL_M * _TOL_M)
        if full and ok.all():
            x += dp
            clk += dclk
        else:
            step = np.flatnonzero(ok)
            rows = act[step]
            x[:, rows] += dp[:, step]
            clk[:, rows] += dclk[:, step]
        if now.any():
            f = np.flatnonzero(now)
            f = None if f.size == act.size else f
            # Residual at the new iterate, linearised (the step is below 0.1 mm).
            uf = _take(u, f)
            r = _take(dz, f) + np.einsum("knr,kr->nr", uf, _take(dp, f))
            r -= _take(dclk, f)[sys_idx]
            _statistics(ctx, res, _take(act, f), _take(a_w, f), r, uf, _take(mu, f),
                        _take(a_iws, f), _take(adj * idet, f),
                        _take(det / a_w.sum(0) ** 3, f), per_sat, isolate, excl, g)
        keep = np.flatnonzero(ok & ~now)
        if keep.size == 0:
            break
        if keep.size < act.size:
            act = act[keep]
            full = False
            a_g, a_p, a_w, a_iws = a_g[:, :, keep], a_p[:, keep], a_w[:, keep], a_iws[:, keep]
    res["valid"] = valid = res["available"] & (res["dof"] >= 1)
    res["thr"] = np.where(valid, ctx.thr_tab[np.clip(res["dof"], 0, None)], np.nan)
    res["stat"] = np.where(valid, res["stat"], np.nan)
    res["alarm"] = valid & (res["stat"] >= res["thr"])
    return res


def _take(a, f):
    """``a[..., f]``, or ``a`` itself when ``f`` is None (all rows)."""
    return a if f is None else a[..., f]


def _statistics(ctx, res, rows, w, r, u, mu, inv_ws, a3, det_bound, per_sat, isolate,
                excl, g):
    """Parity statistics of converged rows (``rows`` into the (R,) results), seed 000.

    ``w, r (n, F)`` weights and post-fit residuals, ``u (3, n, F)`` lines of sight,
    ``mu (3, q, F)`` their system means, ``inv_ws (q, F)`` 1 / W_s, ``a3 (3, 3, F)``
    ``S3^-1``, ``det_bound (F,)`` ``det(S3) / (sum w)^3``.
    """
    sys_idx, q = ctx.sys_idx, ctx.q
    used = w > 0.0
    n_used = np.count_nonzero(used, axis=0)
    dof = res["dof"][rows]
    n_states = n_used - dof
    # Final strict test (lsq._well_conditioned, ENU frame): decided by the frame-free lower
    # bound of the scaled determinant where it is conclusive, else by the reference test.
    ok = det_bound * 27.0 > _DET_SURE
    unsure = np.flatnonzero(~ok & (n_used >= n_states))
    if unsure.size:
        rr = rows[unsure]
        h, _ = _geometry_rows(g[:, :, rr].transpose(2, 1, 0), res["x"][:, rr].T,
                              _clock_columns(sys_idx, q), "enu")
        wu = w[:, unsure].T
        ok[unsure] = _normal_solve(np.where(wu[..., None] > 0.0, h, 0.0), wu,
                                   strict=True)[2]
    available = ok & (n_used >= n_states)
    res["available"][rows] = available
    wr = w * r
    stat = np.einsum("nr,nr->r", wr, r)  # DF_D = r^T W r = p^T p (seed 000 eq. 8)
    res["stat"][rows] = stat
    valid = available & (dof >= 1)
    can_iso = valid & (dof >= 2)
    # Isolation only where it is used: alarms (exclusion, `isolated`) or asked for.
    if per_sat:
        need = can_iso
    elif isolate or excl:
        need = can_iso & (stat >= ctx.thr_tab[np.clip(dof, 0, None)])
    else:
        return
    sel = np.flatnonzero(need)
    if sel.size == 0:
        return
    if sel.size < need.size:
        rows, w, r, wr, u, mu, inv_ws, a3, used = (
            rows[sel], w[:, sel], r[:, sel], wr[:, sel], u[..., sel], mu[..., sel],
            inv_ws[:, sel], a3[..., sel], used[:, sel])
    c = u  # in place (the caller does not use u again)
    c -= mu[:, sys_idx]  # (3, n, F): lines of sight minus their system mean
    ac = np.einsum("klr,lnr->knr", a3, c)  # S3^-1 c_j
    iw = inv_ws[sys_idx]
    sjj = 1.0 - w * (iw + np.einsum("knr,knr->nr", c, ac))  # 1 - leverage = v_j^T v_j
    use_iso = used & (sjj > _SJJ_MIN)
    iso = np.where(use_iso, wr * r / sjj, np.nan)  # seed 000 eq. 23: (S r)_j^2 / S_jj
    best = np.argmax(np.where(use_iso, iso, -np.inf), axis=0)
    best = np.where(use_iso.any(axis=0), best, -1)
    res["best"][rows] = best
    if "isolation" in per_sat:
        res["isolation"][:, rows] = iso
    if "fault_size_m" in per_sat:
        res["fault_size_m"][:, rows] = np.where(use_iso, r / sjj, np.nan)
    if "isolability" in per_sat:
        # S_jk = -sqrt(w_j w_k) (delta_sys / W_s + c_j^T S3^-1 c_k), j != k.
        cac = np.einsum("knr,kmr->nmr", c, ac)
        same = (sys_idx[:, None] == sys_idx[None, :])[..., None]
        sw = np.sqrt(w)
        s_jk = -sw[:, None] * sw[None, :] * (same * iw[None, :] + cac)
        cos = np.abs(s_jk) / np.sqrt(sjj[:, None] * sjj[None, :])
        pair = used[:, None] & used[None, :] & ~np.eye(w.shape[0], dtype=bool)[..., None]
        res["isolability"][:, rows] = np.where(
            use_iso, np.max(np.where(pair, cos, 0.0), axis=1), np.nan)
    if not excl:
        return
    # Start of the re-solve without the best candidate j: the linearised solution without
    # it (Sherman-Morrison, as raimcore.algorithms.mss): x_j = x + k S3^-1 c_j, clock_s =
    # clock_s - k (delta_s / W_s - ubar_s . S3^-1 c_j), k = w_j r_j / S_jj.
    cols = np.arange(w.shape[1])
    bj = np.maximum(best, 0)
    k = np.where(best >= 0, (wr / sjj)[bj, cols], 0.0)
    z = ac[:, bj, cols]  # (3, F)
    res["x_excl"][:, rows] = res["x"][:, rows] + k * z
    dclk = np.einsum("kqr,kr->qr", mu, z) - (sys_idx[bj] == np.arange(q)[:, None]) * inv_ws
    res["clk_excl"][:, rows] = res["clk"][:, rows] + k * dclk


def _protection_levels(ctx, sv, pr, w, s, avail, p_fa, p_md, out, sl):
    """Classic slope-based HPL/VPL (:func:`raimcore.algorithms.mss.classic_raim`) of a
    chunk, at the all-satellite solution; NaN where unavailable."""
    from .algorithms.mss import classic_raim

    x = np.where(avail, s["x"], 0.0).T
    h, rng = _geometry_rows(sv, x, _clock_columns(ctx.sys_idx, ctx.q), "enu")
    clk = s["clk"].T[:, ctx.sys_idx]
    used = (w > 0.0) & avail[:, None]
    resid = np.where(used, pr - rng - clk, np.nan)
    cl = classic_raim(h, resid, np.where(used, w, 0.0), np.ones(w.shape[-1], dtype=bool),
                      p_fa, p_md)
    valid = s["valid"]
    out["hpl_m"][sl] = np.where(valid, cl.hpl_m, np.nan)
    out["vpl_m"][sl] = np.where(valid, cl.vpl_m, np.nan)


# --------------------------------------------------------------------------------------
# The reference path: the plain numpy parity FDE the kernel replaces (kept for checking)
# --------------------------------------------------------------------------------------

def _parity_fde_reference(sv, pr, w, sys_idx, n_sys, p_fa, max_excl, *, outputs=(),
                          p_md=1e-3):
    """Parity FDE as the scenario engine ran it before the kernel: batched
    :func:`raimcore.lsq.wls` from the Earth's centre, masked
    :func:`~raimcore.algorithms.parity.parity_statistics`, greedy exclusion. Same
    arguments and returned dict as :func:`_parity_fde`."""
    from .algorithms.mss import classic_raim
    from .algorithms.parity import parity_statistics
    from .lsq import wls

    before = wls(sv, pr, w, sys_idx, n_sys)
    st = parity_statistics(before.h_enu, before.resid_m, w, p_fa, before.dof)
    excluded = np.zeros(w.shape, dtype=bool)
    after_pos = before.pos_ecef_m.copy()
    after_stat = st.statistic.copy()
    act = st.alarm & (st.best >= 0)
    drop = st.best
    for _ in range(max_excl):
        rows = np.flatnonzero(act)
        if rows.size == 0:
            break
        excluded[rows, drop[rows]] = True
        w_rows = np.where(excluded[rows], 0.0, w[rows])
        sub = wls(sv[rows], pr[rows], w_rows, sys_idx, n_sys, x0_ecef_m=after_pos[rows])
        sub_st = parity_statistics(sub.h_enu, sub.resid_m, w_rows, p_fa, sub.dof)
        after_pos[rows] = sub.pos_ecef_m
        after_stat[rows] = sub_st.statistic
        act = np.zeros_like(act)
        act[rows] = sub_st.alarm & (sub_st.best >= 0)
        drop = np.full_like(drop, -1)
        drop[rows] = sub_st.best
    out = {"valid": before.available & (before.dof >= 1), "dof": before.dof,
           "statistic": st.statistic, "threshold": st.threshold, "alarm": st.alarm,
           "best": st.best, "excluded": excluded, "pos_before": before.pos_ecef_m,
           "clock": before.clock_m, "pos_after": after_pos, "statistic_after": after_stat,
           "isolation": st.isolation, "fault_size_m": st.fault_size_m,
           "isolability": st.isolability}
    if "hpl_m" in outputs or "vpl_m" in outputs:
        pl = classic_raim(before.h_enu, before.resid_m, w, np.ones(w.shape[-1], dtype=bool),
                          p_fa, p_md)
        out["hpl_m"], out["vpl_m"] = pl.hpl_m, pl.vpl_m
    return out
