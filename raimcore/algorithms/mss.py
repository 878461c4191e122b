"""Multiple solution separation (MSS) with barometric aiding, and protection levels.

Pure batched kernels on plain arrays (spec section 2, seed 001). The model is linear in a
local level frame: ``z = H dx + e``, ``e ~ N(0, R)``, ``W = R^-1`` diagonal, states
``dx = (dE, dN, dU, clock_1, ..., clock_q)``. Rows of ``H`` are satellites ``[-u_enu, c]``
and optionally one barometric row ``[0, 0, 1, 0, ...]`` (spec section 2, "Model").

Everything is vectorised over epochs (any leading batch axes) and satellites. The
sub-solutions (satellite ``i`` removed, baro kept) are rank-one downdates of the main
solution (Sherman-Morrison), and the sub-sub-solutions (``k`` and ``j`` removed) are
rank-one downdates of the sub-solutions, so nothing loops over satellites:

* leverage ``l_i = w_i h_i^T P0 h_i``, ``v_i = P0 h_i``;
* ``P_i = P0 + w_i v_i v_i^T / (1 - l_i)``, so ``dP_i = P_i - P0 = w_i v_i v_i^T / (1 - l_i)``;
* ``dX_i = X0 - X_i = w_i r_i v_i / (1 - l_i)`` with ``r = z - H X0`` the main residuals.

These equal the spec's ``X_i = S_i Z`` and ``dP_i = (S0 - S_i) R (S0 - S_i)^T`` exactly
(``tests/test_mss.py`` checks it against explicit batched solves).

A consequence worth knowing: removing one measurement moves the solution along the single
direction ``v_i``, so ``dP_i`` has rank one and the horizontal test ``d_i > T_i`` with
``T_i = sqrt(lam_max(dP_i,EN)) k_fa`` is the normalised-residual test
``sqrt(w_i) |r_i| / sqrt(1 - l_i) > k_fa``; the vertical test is the same inequality
whenever ``v_i[U] != 0``. The code nevertheless evaluates the spec's formulas as written.

Two paths compute the same results (issue 17). :func:`mss` and :func:`classic_raim` are the
fast kernels: blocks of epochs sized to stay in cache, ``P0`` from an entry-wise Cholesky
factor of the scaled normal matrix, the sub-sub-solution tests through the rank-one
identity above in whitened form, and the fields of the second identification level
allocated only when an epoch reaches it. :func:`mss_reference` and
:func:`classic_raim_reference` are the plain-numpy implementations they replaced, kept as
the oracle of the agreement tests (alarms, statuses and verdicts identical, numbers to
1e-6 relative) and as the baseline of ``tests/benchmarks/bench_mss.py``; the fast kernels
also hand them the few epochs whose singular-geometry verdict is too close to call.

References
----------
.. [1] Chen W., Yang Z., Gu S., Wang Y., barometric-altimeter-aided aircraft autonomous
   integrity monitoring by multiple solution separation (seed 001, Chinese original).
.. [2] Brown R. G., "A baseline GPS RAIM scheme and a note on the equivalence of three RAIM
   methods", Navigation 39(3), 1992.
.. [3] Walter T., Enge P., "Weighted RAIM for precision approach", ION GPS 1995.
.. [4] Brenner M., "Integrated GPS/inertial fault detection availability", Navigation
   43(2), 1996 (solution separation).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy import optimize, stats

from .._validate import (
    check_array,
    check_batch,
    check_indices,
    check_int,
    check_mask,
    check_positive,
    check_probability,
    check_weights,
    shape_str,
)
from ..lsq import _scaled, _well_conditioned

# Per-epoch status codes (same strings as raimcore.algorithms.base.STATUS_*).
STATUS_OK = "ok"
STATUS_NO_ISOLATION = "detect-only"
STATUS_UNAVAILABLE = "unavailable"

# Identification outcomes (spec section 2, "Identification").
IDENT_NONE = "none"  # no detection, nothing to identify
IDENT_UNIQUE = "unique"  # exactly one candidate passed all its sub-sub tests
IDENT_AMBIGUOUS = "ambiguous"  # several candidates passed
IDENT_MULTIPLE = "multiple-fault"  # no candidate passed
IDENT_UNAVAILABLE = "unavailable"  # detection fired but too few measurements to identify

# A sub-solution whose leverage is this close to 1 is unobservable (its satellite carries
# no redundancy); its separation covariance would be infinite.
_LEVERAGE_TOL = 1e-9
# Singular geometry: the diagonally scaled normal matrix has a reciprocal condition number
# below raimcore.lsq.RCOND_MIN = 1e-12 (the test every kernel shares; scale-free, so the
# units of the states and the size of the weights do not matter).


@dataclass(frozen=True)
class MssResult:
    """Solution separation of every epoch of a batch. Shapes: batch ``B...``, ``M`` rows.

    Attributes
    ----------
    status : (B...) str, ``"ok"``, ``"detect-only"`` or ``"unavailable"``.
    dx0_m : (B..., n) main solution (local frame E, N, U, clocks; m).
    p0_m2 : (B..., n, n) its covariance.
    dx_sep_m : (B..., M, n) separations ``X0 - X_i`` (NaN for rows that are not candidate
        satellites or whose sub-solution is unobservable).
    dp_h_lam_m2, dp_u_m2 : (B..., M) largest eigenvalue of the E/N block of ``dP_i`` and
        its U/U element.
    p_h_lam_m2, p_u_m2 : (B..., M) the same for ``P_i``.
    d_h_m, t_h_m, d_v_m, t_v_m : (B..., M) horizontal/vertical separations and thresholds.
    ratio : (B..., M) ``max(d_h/T_h, d_v/T_v)`` (NaN where not a candidate).
    alarm : (B...) bool, any test failed.
    ident_status : (B...) str, one of the ``IDENT_*`` codes.
    ident_pass : (B..., M) bool, candidate ``k`` passed all its sub-sub tests.
    ident_score : (B..., M) ``max_j max(d_kj/T_kj)`` over H and V (ranking extension).
    ident_unique : (B...) int, row of the unique candidate, -1 otherwise.
    ident_rank : (B...) int, row with the smallest ``ident_score`` when the status is
        unique or ambiguous, -1 otherwise.
    hpl_m, vpl_m : (B...) MSS protection levels (NaN when unavailable).
    k_fa : (B...) ``Q^-1(p_fa / (2 m_sat))``.
    m_sat : (B...) int, number of satellites used; ``n_states`` the states estimated.
    pairs : (P, 2) int, the candidate row pairs of the second identification level.
    pair_pass : (B..., P) bool, after a multiple-fault verdict: the solution without pair
        ``p`` passed every test against its one-more-removed solutions (False elsewhere).
    pair_score : (B..., P) its worst normalised separation (NaN where not tested).
    pair_dx_m : (B..., P, n) the solution without pair ``p`` (NaN where not tested).
    ident_pair_unique, ident_pair_rank : (B...) int, index into ``pairs`` of the unique
        passing pair / of the best-ranked pair when at least one passes; -1 otherwise.

    When no epoch of the batch reached the second level, :func:`mss` returns ``pair_pass``,
    ``pair_score`` and ``pair_dx_m`` as read-only broadcast views of False / NaN (they would
    otherwise be most of the result's memory: ``P (n + 1) + P`` values per epoch).
    """

    status: np.ndarray
    dx0_m: np.ndarray
    p0_m2: np.ndarray
    dx_sep_m: np.ndarray
    dp_h_lam_m2: np.ndarray
    dp_u_m2: np.ndarray
    p_h_lam_m2: np.ndarray
    p_u_m2: np.ndarray
    d_h_m: np.ndarray
    t_h_m: np.ndarray
    d_v_m: np.ndarray
    t_v_m: np.ndarray
    ratio: np.ndarray
    alarm: np.ndarray
    ident_status: np.ndarray
    ident_pass: np.ndarray
    ident_score: np.ndarray
    ident_unique: np.ndarray
    ident_rank: np.ndarray
    hpl_m: np.ndarray
    vpl_m: np.ndarray
    k_fa: np.ndarray
    m_sat: np.ndarray
    n_states: np.ndarray
    pairs: np.ndarray
    pair_pass: np.ndarray
    pair_score: np.ndarray
    pair_dx_m: np.ndarray
    ident_pair_unique: np.ndarray
    ident_pair_rank: np.ndarray


@dataclass(frozen=True)
class ClassicResult:
    """Classic snapshot RAIM (weighted SSE chi-square test) and slope-based PLs.

    Attributes
    ----------
    status : (B...) str, ``"ok"``, ``"detect-only"`` or ``"unavailable"``.
    sse : (B...) weighted sum of squared residuals ``r^T W r`` (chi2(dof) without fault).
    threshold : (B...) ``chi2.isf(p_fa, dof)``.
    alarm : (B...) bool.
    dof : (B...) int, ``m - n``.
    lam_det : (B...) non-centrality detected with probability ``1 - p_md``.
    hslope_m, vslope_m : (B..., M) slopes (m of position error per unit sqrt(noncentrality));
        NaN for non-candidate rows.
    hpl_m, vpl_m : (B...) ``max_i slope_i * sqrt(lam_det)``.
    """

    status: np.ndarray
    sse: np.ndarray
    threshold: np.ndarray
    alarm: np.ndarray
    dof: np.ndarray
    lam_det: np.ndarray
    hslope_m: np.ndarray
    vslope_m: np.ndarray
    hpl_m: np.ndarray
    vpl_m: np.ndarray


def geometry_rows(u_enu, sys_idx, n_sys: int, *, baro: bool) -> np.ndarray:
    """Local-frame geometry ``H`` with an optional barometric row last.

    Parameters
    ----------
    u_enu : (..., S, 3) unit lines of sight receiver -> satellite (ENU).
    sys_idx : (S,) int, system of each satellite (clock column ``3 + sys_idx``).
    n_sys : number of systems (clock states).
    baro : append the row ``[0, 0, 1, 0, ...]`` (spec section 2, "Model").

    Returns
    -------
    (..., S + baro, 3 + n_sys) rows ``[-u, c]`` (and the baro row).

    Raises
    ------
    ValueError naming the argument for a bad shape or a system index outside [0, n_sys).
    """
    u = check_array("u_enu", u_enu, last=("S", 3), finite=False)
    n_sys = check_int("n_sys", n_sys, 1)
    sys_idx = check_indices("sys_idx", sys_idx, length=u.shape[-2], hi=n_sys,
                            match=f"u_enu {shape_str((u.shape[-2], 3))}")
    clock = np.zeros((u.shape[-2], n_sys))
    clock[np.arange(u.shape[-2]), sys_idx] = 1.0
    h = np.concatenate([-u, np.broadcast_to(clock, u.shape[:-1] + (n_sys,))], axis=-1)
    if baro:
        row = np.zeros(3 + n_sys)
        row[2] = 1.0  # He - Hb = dU + e_b (spec section 2)
        h = np.concatenate([h, np.broadcast_to(row, h.shape[:-2] + (1, 3 + n_sys))], axis=-2)
    return h


def _normal_inverse(h, w):
    """``P0 = (H^T W H)^-1`` over the batch, with absent clock states pinned.

    Columns no used row touches (a system with no satellite in view) are decoupled with a
    unit diagonal so the rest stays solvable; their count is removed from ``n_states``.
    Returns ``p0 (B, n, n)``, ``n_states (B,)`` and ``ok (B,)`` (False: singular geometry,
    judged on the diagonally scaled matrix, see :data:`raimcore.lsq.RCOND_MIN`).
    """
    a = np.einsum("bmi,bm,bmj->bij", h, w, h)
    active = np.any((h != 0.0) & (w[..., None] > 0.0), axis=-2)  # (B, n)
    n = h.shape[-1]
    a = a + np.einsum("bi,ij->bij", (~active).astype(float), np.eye(n))
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero diagonal: not finite
        ok = _well_conditioned(_scaled(a)[0])
    a[~ok] = np.eye(n)
    p0 = np.linalg.inv(a)
    p0 = p0 * active[:, :, None] * active[:, None, :]  # pinned states carry no variance
    return p0, active.sum(axis=-1), ok


def _lam_max_2x2(a, b, c):
    """Largest eigenvalue of the symmetric block ``[[a, b], [b, c]]`` (closed form)."""
    return 0.5 * (a + c) + np.sqrt(0.25 * (a - c) ** 2 + b**2)


def _safe_ratio(d, t):
    """``d / t`` with ``0 / 0 = 0`` (a separation with no horizontal or vertical part)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = d / t
    return np.where((t == 0.0) & (d == 0.0), 0.0, r)


def _prepare(h, z_m, w, is_sat):
    """Validate the arguments of :func:`mss` / :func:`classic_raim` and flatten the batch.

    Returns ``batch``, ``h (B, M, n)``, ``z (B, M)``, ``w (B, M)`` and ``is_sat (M,)``, with
    rows that have a non-finite innovation or geometry switched off (weight 0).
    """
    batch, h, z, w, is_sat = _flat_args(h, z_m, w, is_sat)
    return (batch,) + _sanitize(h, z, w) + (is_sat,)


def _flat_args(h, z_m, w, is_sat):
    """:func:`_prepare` without the switching off: the flat arrays may be views of the
    arguments (the fast kernels switch rows off block by block with :func:`_sanitize`)."""
    h = check_array("h", h, last=("M", "n"), finite=False)
    m_rows, n = h.shape[-2:]
    if n < 3:
        raise ValueError(f"h must have shape (..., M, n) with n >= 3 states (E, N, U "
                         f"first), got {h.shape}")
    hdesc = f"h {shape_str((m_rows, n))}"
    z = check_array("z_m", z_m, last=(m_rows,), finite=False, match=hdesc)
    w = check_weights("w", w, last=(m_rows,), match=hdesc)
    is_sat = check_mask("is_sat", is_sat, length=m_rows, match=hdesc)
    batch = check_batch({"h": h.shape[:-2], "z_m": z.shape[:-1], "w": w.shape[:-1]})
    h = np.broadcast_to(h, batch + (m_rows, n)).reshape(-1, m_rows, n)
    z = np.broadcast_to(z, batch + (m_rows,)).reshape(-1, m_rows)
    w = np.broadcast_to(w, batch + (m_rows,)).reshape(-1, m_rows)
    return batch, h, z, w, is_sat


def _sanitize(h, z, w):
    """Switch off (weight 0, zero innovation and geometry) rows with a non-finite
    innovation or geometry; returns new arrays ``h, z, w``."""
    w = np.where(np.isfinite(z) & np.all(np.isfinite(h), axis=-1), w, 0.0)
    z = np.where(w > 0.0, z, 0.0)
    h = np.where(np.isfinite(h), h, 0.0)
    return h, z, w


def mss(h, z_m, w, is_sat, p_fa: float, p_md: float) -> MssResult:
    """Multiple solution separation: detection, identification, exclusion and PLs.

    Parameters
    ----------
    h : (..., M, n) local-frame geometry rows (see :func:`geometry_rows`); columns 0..2 are
        E, N, U.
    z_m : (..., M) innovations (measured minus predicted at the linearisation point, m).
    w : (..., M) weights ``1 / sigma^2`` (1/m^2), >= 0; 0 (or NaN) marks an unused row, as
        does a non-finite innovation or geometry row.
    is_sat : (M,) bool, rows that are satellites (candidates for removal); the baro row is
        never removed (spec section 2: "sub-solution i: satellite i removed, baro kept").
    p_fa, p_md : false-alarm and missed-detection probabilities, in (0, 1).

    The batch shapes of ``h``, ``z_m`` and ``w`` broadcast together.

    Returns
    -------
    MssResult ; an epoch with singular geometry (the diagonally scaled normal matrix has a
    reciprocal condition number below :data:`raimcore.lsq.RCOND_MIN`) or no redundancy is
    ``"unavailable"``: NaN solution, separations and protection levels, no alarm. Its
    neighbours in the batch are computed exactly as without it.

    Raises
    ------
    ValueError naming the argument for bad shapes (``h`` not ``(..., M, n)`` with n >= 3,
    ``z_m`` / ``w`` not ``(..., M)``, ``is_sat`` not ``(M,)``), negative or infinite weights
    or probabilities outside (0, 1).

    See Also
    --------
    mss_reference : the plain-numpy reference path of the same equations; this function
        returns the same alarms, statuses and identification verdicts and the same numbers
        to round-off (``tests/test_mss.py`` compares them).

    Notes
    -----
    Equations (spec section 2): ``T_i = sqrt(lam_max(dP_i,EN)) Q^-1(p_fa / (2 m_sat))``,
    vertical threshold ``sqrt(dP_i,UU) Q^-1(p_fa / (2 m_sat))``; ``HPL = max_i (T_i +
    sqrt(lam_max(P_i,EN)) Q^-1(p_md))``; ``VPL = max_i (sqrt(dP_i,UU) Q^-1(p_fa / (2 m_sat))
    + sqrt(P_i,UU) Q^-1(p_md))``.

    Identification tests each candidate ``k``'s sub-solution against its sub-sub-solutions
    ``(k, j)``, ``j`` over the other used satellites, with the same rule; the false-alarm
    budget of that group is split over its ``m_sat - 1`` tests, i.e. the threshold factor
    is ``Q^-1(p_fa / (2 (m_sat - 1)))`` (the spec says "the same rule"; this is our reading).
    A test whose sub-sub-solution is unobservable makes its candidate fail to pass (it
    cannot be confirmed). With redundancy 1 every sub-sub-solution has fewer measurements
    than states, so every candidate scores ``inf`` (exactly, not by round-off in ``1 -
    l_kj``) and identification is unavailable.

    After a multiple-fault verdict, and when the redundancy is at least 3, identification
    goes one level deeper (spec section 2): for every pair ``(k, l)`` of used satellites the
    solution without both is tested against each solution without ``(k, l, j)``, with the
    factor ``Q^-1(p_fa / (2 (m_sat - 2)))``; see ``pair_*`` and ``ident_pair_*``. Deeper
    levels (three or more faults) are not implemented.

    How it is computed (the reference path evaluates the same quantities the long way):
    epochs are processed in blocks (:data:`BLOCK_ELEMENTS`) so that every work array stays
    in cache and the cost per epoch does not grow with the batch; ``P0`` comes from a
    Cholesky factor of the diagonally scaled normal matrix, whose determinant also decides
    the singular-geometry test (an epoch whose determinant is not clearly above the
    threshold of :func:`raimcore.lsq._well_conditioned` is handed to the reference path,
    so the verdict is the reference's own); the sub-sub-solution tests use the rank-one
    identity of the module docstring, ``max(d_kj / T_kj) = sqrt(w_j / (1 - l_kj)) |r_kj| /
    k_fa``, written with the whitened hat matrix ``A = W^1/2 H P0 H^T W^1/2`` and
    whitened residuals ``e = W^1/2 r``::

        1 - l_kj = (1 - l_j) - A_kj^2 / (1 - l_k),   sqrt(w_j) r_kj = e_j + A_kj e_k / (1 - l_k)

    so identification costs a dozen element-wise operations per (k, j) pair.
    """
    p_fa = check_probability("p_fa", p_fa)
    p_md = check_probability("p_md", p_md)
    batch, h, z, w, is_sat = _flat_args(h, z_m, w, is_sat)
    n_b, m_rows, n = h.shape
    k_fa_tab, k_sub_tab = _k_fa_tables(p_fa, m_rows)
    k_md = _q_inv(p_md)
    sat = _row_selector(is_sat)
    o = _mss_outputs(n_b, m_rows, n)
    redo, deep = [], []
    step = _block_epochs(int(np.count_nonzero(is_sat)))
    for start in range(0, n_b, step):
        blk = slice(start, min(start + step, n_b))
        rows, level2 = _mss_block(*_sanitize(h[blk], z[blk], w[blk]), is_sat, sat, p_fa,
                                  k_fa_tab, k_sub_tab, k_md,
                                  {key: a[blk] for key, a in o.items()})
        redo.append(rows + start)
        if level2 is not None:
            deep.append((level2[0] + start,) + level2[1:])
    o["status"] = _STATUS_NAMES[o["status"]]
    o["ident_status"] = _IDENT_NAMES[o["ident_status"]]
    redo = np.concatenate(redo) if redo else np.zeros(0, dtype=int)
    ref = None
    if redo.size:  # ill-conditioned or singular: the reference decides (see Notes)
        ref = _mss_reference_flat(*_sanitize(h[redo], z[redo], w[redo]), is_sat, p_fa, p_md)
        for key, a in o.items():
            a[redo] = ref[key]
    o.update(_pair_outputs(n_b, m_rows, n, deep, redo, ref))
    o["pairs"] = _pair_indices(m_rows)
    return _mss_result(o, batch)


def _pair_outputs(n_b, m_rows, n, deep, redo, ref):
    """The second-level fields of :func:`mss` from the few epochs that reached it.

    ``deep``: per block, ``(rows, pass, score, dx)`` of its second-level epochs; ``redo``
    and ``ref``: the epochs the reference decided and its fields. When no epoch of the
    batch reached the second level, ``pair_pass``, ``pair_score`` and ``pair_dx_m`` are
    read-only broadcast views of their fill values (False, NaN, NaN), which take no memory.
    """
    n_p = m_rows * (m_rows - 1) // 2
    unique = np.full(n_b, -1, dtype=np.int64)
    rank = np.full(n_b, -1, dtype=np.int64)
    if not deep and (ref is None or not np.any(np.isfinite(ref["pair_score"]))):
        return {"pair_pass": np.broadcast_to(False, (n_b, n_p)),
                "pair_score": np.broadcast_to(np.nan, (n_b, n_p)),
                "pair_dx_m": np.broadcast_to(np.nan, (n_b, n_p, n)),
                "ident_pair_unique": unique, "ident_pair_rank": rank}
    out = {"pair_pass": np.zeros((n_b, n_p), dtype=bool),
           "pair_score": np.full((n_b, n_p), np.nan),
           "pair_dx_m": np.full((n_b, n_p, n), np.nan),
           "ident_pair_unique": unique, "ident_pair_rank": rank}
    for rows, pair_pass, pair_score, pair_dx in deep:
        out["pair_pass"][rows] = pair_pass
        out["pair_score"][rows] = pair_score
        out["pair_dx_m"][rows] = pair_dx
        n_pass = pair_pass.sum(axis=-1)
        unique[rows] = np.where(n_pass == 1, np.argmax(pair_pass, axis=-1), -1)
        rank[rows] = np.where(n_pass >= 1, np.argmin(np.where(pair_pass, pair_score, np.inf),
                                                      axis=-1), -1)
    if ref is not None:
        for key in out:
            out[key][redo] = ref[key]
    return out


#: Work-array size of the fast kernels, in values: a block holds ``BLOCK_ELEMENTS // S^2``
#: epochs (S satellite rows; at least 256, so the ~150 numpy calls of a block stay cheap,
#: and at most 4096), so that its largest arrays, (block, S, S) floats of 512 KiB, stay in
#: cache. Measured with ``tests/benchmarks/bench_mss.py`` on a 4 MiB-L2 Xeon: 10 satellites
#: fastest at 2^16 values (655 epochs), 24 satellites at 227..455 epochs.
BLOCK_ELEMENTS = 2**16


def _block_epochs(n_rows):
    """Epochs per block for ``n_rows`` satellite rows (see :data:`BLOCK_ELEMENTS`)."""
    return int(np.clip(BLOCK_ELEMENTS // max(n_rows * n_rows, 1), 256, 4096))


# An epoch whose scaled normal matrix has a Cholesky determinant above this is well
# conditioned for the reference test too (det > 1e-6 in raimcore.lsq._well_conditioned;
# the two determinants differ by ~1e-9 relative at worst there, the margin is 1e-3).
_DET_SURE = 1e-6 * (1.0 + 1e-3)
_STATUS_NAMES = np.array([STATUS_UNAVAILABLE, STATUS_NO_ISOLATION, STATUS_OK])
_IDENT_NAMES = np.array([IDENT_NONE, IDENT_UNIQUE, IDENT_AMBIGUOUS, IDENT_MULTIPLE,
                         IDENT_UNAVAILABLE])


@lru_cache(maxsize=64)
def _k_fa_tables(p_fa, m_rows):
    """``Q^-1(p_fa / (2 max(m, 1)))`` and ``Q^-1(p_fa / (2 max(m - 1, 1)))`` for m = 0..M.

    Indexed by ``m_sat``; the same element-wise values as evaluating them per epoch.
    Cached (read-only arrays): a scipy call costs as much as a few hundred epochs.
    """
    m = np.arange(m_rows + 1)
    tables = (stats.norm.isf(p_fa / (2.0 * np.maximum(m, 1))),
              stats.norm.isf(p_fa / (2.0 * np.maximum(m - 1, 1))))
    for t in tables:
        t.flags.writeable = False
    return tables


@lru_cache(maxsize=64)
def _q_inv(p):
    """``Q^-1(p)`` (``scipy.stats.norm.isf``), cached."""
    return stats.norm.isf(p)


def _row_selector(is_sat):
    """The satellite rows as a slice when they are contiguous (no copy), else indices."""
    idx = np.flatnonzero(is_sat)
    if idx.size and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _pair_indices(m_rows):
    """All row pairs ``(k, l)``, ``k < l``, of the second identification level, (P, 2)."""
    k_idx, l_idx = np.triu_indices(m_rows, k=1)
    return np.stack([k_idx, l_idx], axis=-1)


# Value of each field of :func:`mss` at an unavailable epoch (status/ident codes: 0).
_MSS_FILL = {"status": 0, "alarm": False, "ident_status": 0, "ident_pass": False,
             "ident_unique": -1, "ident_rank": -1}


def _mss_outputs(n_b, m_rows, n):
    """Flat, uninitialised output arrays of :func:`mss` (every block writes all of its
    slice: see :data:`_MSS_FILL`); the second-level fields come from :func:`_pair_outputs`.
    """
    shapes = {"status": (), "dx0_m": (n,), "p0_m2": (n, n), "dx_sep_m": (m_rows, n),
              "dp_h_lam_m2": (m_rows,), "dp_u_m2": (m_rows,), "p_h_lam_m2": (m_rows,),
              "p_u_m2": (m_rows,), "d_h_m": (m_rows,), "t_h_m": (m_rows,), "d_v_m": (m_rows,),
              "t_v_m": (m_rows,), "ratio": (m_rows,), "alarm": (), "ident_status": (),
              "ident_pass": (m_rows,), "ident_score": (m_rows,), "ident_unique": (),
              "ident_rank": (), "hpl_m": (), "vpl_m": (), "k_fa": (), "m_sat": (),
              "n_states": ()}
    dtypes = {"status": np.int8, "ident_status": np.int8, "alarm": bool, "ident_pass": bool,
              "ident_unique": np.int64, "ident_rank": np.int64, "m_sat": np.int64,
              "n_states": np.int64}
    return {key: np.empty((n_b,) + shape, dtype=dtypes.get(key, float))
            for key, shape in shapes.items()}


def _mss_result(o, batch):
    """:class:`MssResult` from the flat arrays of a batch, reshaped to ``batch``."""
    fields = {key: (a if key == "pairs" else a.reshape(batch + a.shape[1:]))
              for key, a in o.items()}
    return MssResult(**fields)


def _main_covariance(h, w):
    """``P0 = (H^T W H)^-1`` of a block by a Cholesky factor of the scaled normal matrix.

    Parameters
    ----------
    h : (B, M, n) geometry rows, finite.
    w : (B, M) weights, finite, >= 0.

    Returns
    -------
    p0 : (B, n, n) covariance, with the states no used row touches pinned and given no
        variance, as :func:`_normal_inverse` does; identity-based garbage (finite) where
        ``sure`` is False.
    n_states : (B,) int, the states that some used row touches.
    sure : (B,) bool, the determinant of the scaled normal matrix ``D^-1/2 N D^-1/2`` is
        above :data:`_DET_SURE`, so the reference test calls it well conditioned. False
        does not mean singular: the caller hands such epochs to the reference path.

    Notes
    -----
    The factor is computed entry by entry over the block (``n`` is 4..7), which for these
    sizes is far cheaper than batched LAPACK calls; ``det = prod(diag(L))^2``.
    """
    n_b, _, n = h.shape
    # A state is active when some used row touches it: a sum of non-negative terms that is
    # positive exactly when one of them is (the same test as (h != 0) & (w > 0), faster).
    active = np.matmul((w > 0.0).astype(float)[:, None, :], np.abs(h))[:, 0] > 0.0  # (B, n)
    a = np.matmul(h.transpose(0, 2, 1), h * w[..., None])  # H^T W H
    diag = np.arange(n)
    a[:, diag, diag] += ~active  # absent states decoupled with a unit diagonal
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        d = np.sqrt(a[:, diag, diag])
        st = (a / (d[:, :, None] * d[:, None, :])).transpose(1, 2, 0)  # unit diagonal
        low = {}
        inv = []
        det = np.ones(n_b)
        for j in range(n):
            acc = st[j, j] - sum(low[j, k] ** 2 for k in range(j))
            det = det * acc
            inv.append(1.0 / np.sqrt(acc))
            for i in range(j + 1, n):
                low[i, j] = (st[i, j] - sum(low[i, k] * low[j, k] for k in range(j))) * inv[j]
        # L^-1 (lower triangular), row by row.
        li = np.zeros((n, n, n_b))
        for i in range(n):
            li[i, i] = inv[i]
            for j in range(i):
                li[i, j] = -inv[i] * sum(low[i, k] * li[k, j] for k in range(j, i))
    sure = det > _DET_SURE  # NaN (failed factor) is not sure
    if not sure.all():
        li[:, :, ~sure] = np.eye(n)[:, :, None]
        d = np.where(sure[:, None], d, 1.0)
    lib = li.transpose(2, 0, 1)  # (B, n, n)
    s_inv = np.matmul(lib.transpose(0, 2, 1), lib)  # (D^-1/2 N D^-1/2)^-1 = L^-T L^-1
    scale = active / d
    p0 = s_inv * scale[:, :, None] * scale[:, None, :]
    return p0, active.sum(axis=-1), sure


def _mss_block(h, z, w, is_sat, sat, p_fa, k_fa_tab, k_sub_tab, k_md, o):
    """Fast :func:`mss` on one block of epochs, written into the views ``o``.

    Returns the block rows that the reference path must decide (see :func:`mss` Notes)
    and, if some epochs reached the second identification level, ``(rows, pass, score,
    dx)`` of those epochs (else None).
    """
    p0, n_states, sure = _main_covariance(h, w)
    v = np.matmul(h, p0)  # v_i = P0 h_i, (B, M, n)
    dx0 = np.matmul((w * z)[:, None, :], v)[:, 0]  # X0 = P0 H^T W z
    r = z - np.matmul(h, dx0[..., None])[..., 0]  # main residuals
    used = w > 0.0
    cand = used & is_sat[None, :]
    m_sat = cand.sum(axis=-1)
    redundancy = used.sum(axis=-1) - n_states
    valid = sure & (redundancy >= 1)
    redo = np.flatnonzero(~sure & (redundancy >= 1))
    o["m_sat"][:] = m_sat
    o["n_states"][:] = n_states
    k_fa = k_fa_tab[m_sat]
    o["k_fa"][:] = k_fa
    if not valid.any():
        for key, a in o.items():
            if key not in ("m_sat", "n_states", "k_fa"):
                a[...] = _MSS_FILL.get(key, np.nan)
        return redo, None
    o["dx0_m"][:] = np.where(valid[:, None], dx0, np.nan)
    o["p0_m2"][:] = np.where(valid[:, None, None], p0, np.nan)

    # Whitened hat matrix of the satellite rows, A = W^1/2 H P0 H^T W^1/2 (symmetric). Its
    # diagonal is the leverage, but l_i is taken from the row products as in the reference:
    # where 1 - l_i is tiny (a nearly unobservable sub-solution) both then carry the same
    # round-off, which 1 / (1 - l_i) amplifies.
    sq_w = np.sqrt(w[:, sat])
    hs_t = np.ascontiguousarray(h[:, sat].transpose(0, 2, 1))  # (B, n, S)
    hs_t *= sq_w[:, None, :]
    hat = np.matmul(hs_t.transpose(0, 2, 1), np.matmul(p0, hs_t))
    n_s = hat.shape[-1]
    one_m_lev = 1.0 - w * np.sum(h * v, axis=-1)  # 1 - l_i
    om = one_m_lev[:, sat]

    # Sub-solutions by rank-one downdate (Sherman-Morrison), as in the module docstring.
    sub_ok = cand & (one_m_lev > _LEVERAGE_TOL) & valid[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(sub_ok, w / one_m_lev, np.nan)  # w_i / (1 - l_i)
    dx_sep = (gain * r)[..., None] * v  # dX_i = X0 - X_i
    v_e, v_n, v_u = v[..., 0], v[..., 1], v[..., 2]
    dp_h_lam = gain * (v_e * v_e + v_n * v_n)  # dP_i = g v v^T has rank one
    dp_u = gain * (v_u * v_u)
    p_h_lam = _lam_max_2x2(p0[:, None, 0, 0] + gain * (v_e * v_e),
                           p0[:, None, 0, 1] + gain * (v_e * v_n),
                           p0[:, None, 1, 1] + gain * (v_n * v_n))
    p_u = p0[:, None, 2, 2] + dp_u
    d_h = np.sqrt(dx_sep[..., 0] ** 2 + dx_sep[..., 1] ** 2)
    d_v = np.abs(dx_sep[..., 2])
    t_h = np.sqrt(dp_h_lam) * k_fa[:, None]
    t_v = np.sqrt(dp_u) * k_fa[:, None]
    ratio = np.fmax(_safe_ratio(d_h, t_h), _safe_ratio(d_v, t_v))
    alarm = valid & np.any(sub_ok & (ratio > 1.0), axis=-1)
    for key, val in (("dx_sep_m", dx_sep), ("dp_h_lam_m2", dp_h_lam), ("dp_u_m2", dp_u),
                     ("p_h_lam_m2", p_h_lam), ("p_u_m2", p_u), ("d_h_m", d_h),
                     ("t_h_m", t_h), ("d_v_m", d_v), ("t_v_m", t_v), ("ratio", ratio)):
        o[key][:] = val  # NaN wherever the sub-solution is not observable (gain NaN)
    o["alarm"][:] = alarm

    # Protection levels (spec section 2), as in the reference.
    pl_ok = valid & np.all(sub_ok | ~cand, axis=-1) & (m_sat > 0)
    hpl = np.max(np.where(sub_ok, t_h + np.sqrt(p_h_lam) * k_md, -np.inf), axis=-1)
    vpl = np.max(np.where(sub_ok, t_v + np.sqrt(p_u) * k_md, -np.inf), axis=-1)
    o["hpl_m"][:] = np.where(pl_ok, hpl, np.nan)
    o["vpl_m"][:] = np.where(pl_ok, vpl, np.nan)

    # Identification: every (k, j) sub-sub-solution test at once, over satellite rows only,
    # laid out (j, B, k) so that the reductions over j run over the first axis (A is
    # symmetric, so A_kj is read as A_jk).
    e = sq_w * r[:, sat]  # whitened residuals
    ok_s = sub_ok[:, sat]
    with np.errstate(divide="ignore", invalid="ignore"):
        inv_om = np.where(ok_s, 1.0 / om, 0.0)
    a = np.ascontiguousarray(hat.transpose(1, 0, 2))  # (j, B, k)
    num = a * (e * inv_om)[None]
    num += e.T[:, :, None]  # sqrt(w_j) r_kj
    num *= num
    a *= a
    a *= inv_om[None]
    den = np.subtract(om.T[:, :, None], a, out=a)  # 1 - l_kj
    den[np.arange(n_s), :, np.arange(n_s)] = 1.0  # j = k is not a test
    num[np.arange(n_s), :, np.arange(n_s)] = 0.0
    bad = np.any(den <= _LEVERAGE_TOL, axis=0)  # (B, k): some sub-sub-solution unobservable
    bad |= (redundancy < 2)[:, None]  # all of them are (see the reference)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        num /= den
        worst = np.sqrt(num.max(axis=0, initial=0.0)) / k_sub_tab[m_sat][:, None]
    has_pairs = ok_s & (m_sat >= 2)[:, None]
    score_s = np.where(has_pairs, np.where(bad, np.inf, worst), np.nan)
    score = np.full(ratio.shape, np.nan)
    score[:, sat] = score_s
    passed = score <= 1.0  # False for NaN
    can_ident = (valid & (redundancy >= 2) & np.all(~cand | (sub_ok & (m_sat >= 2)[:, None]),
                                                    axis=-1)
                 & ~np.any(ok_s & bad, axis=-1))
    n_pass = passed.sum(axis=-1)
    ident = np.zeros(len(h), dtype=np.int8)  # codes: indices into _IDENT_NAMES
    ident[alarm & ~can_ident] = 4
    ident[alarm & can_ident & (n_pass == 1)] = 1
    ident[alarm & can_ident & (n_pass > 1)] = 2
    ident[alarm & can_ident & (n_pass == 0)] = 3
    o["ident_status"][:] = ident
    o["ident_pass"][:] = passed
    o["ident_score"][:] = score
    o["ident_unique"][:] = np.where(ident == 1, np.argmax(passed, axis=-1), -1)
    ranked = np.argmin(np.where(np.isnan(score), np.inf, score), axis=-1)
    o["ident_rank"][:] = np.where((ident == 1) | (ident == 2), ranked, -1)
    o["status"][:] = np.where(valid, np.where(can_ident, 2, 1), 0)

    deeper = np.flatnonzero((ident == 3) & (redundancy >= 3))
    if deeper.size == 0:
        return redo, None
    _, pair_pass, pair_score, pair_dx = _pair_level(
        h[deeper], z[deeper], w[deeper], cand[deeper], m_sat[deeper],
        np.ones(deeper.size, dtype=bool), p_fa)
    return redo, (deeper, pair_pass, pair_score, pair_dx)


def mss_reference(h, z_m, w, is_sat, p_fa: float, p_md: float) -> MssResult:
    """Reference path of :func:`mss`: the same arguments, equations and result.

    The plain-numpy implementation that :func:`mss` replaced: explicit batched inverses
    and determinants, every work array over the whole batch, sub-sub-solution separations
    and thresholds evaluated component by component as the spec writes them. It is kept
    as the oracle of the agreement tests and as the baseline of
    ``tests/benchmarks/bench_mss.py``, and :func:`mss` hands it the epochs whose
    conditioning is too close to the singular-geometry threshold to decide otherwise.

    Parameters, Returns and Raises as :func:`mss`.
    """
    p_fa = check_probability("p_fa", p_fa)
    p_md = check_probability("p_md", p_md)
    batch, h, z, w, is_sat = _prepare(h, z_m, w, is_sat)
    return _mss_result(_mss_reference_flat(h, z, w, is_sat, p_fa, p_md), batch)


def _mss_reference_flat(h, z, w, is_sat, p_fa, p_md) -> dict:
    """:func:`mss_reference` on prepared flat arrays (see :func:`_prepare`); a dict of the
    :class:`MssResult` fields with batch axis ``B``."""
    m_rows = h.shape[-2]

    p0, n_states, geom_ok = _normal_inverse(h, w)
    dx0 = np.einsum("bij,bmj,bm,bm->bi", p0, h, w, z)
    r = z - np.einsum("bmi,bi->bm", h, dx0)  # main residuals
    used = w > 0.0
    cand = used & is_sat[None, :]
    m_sat = cand.sum(axis=-1)
    m_tot = used.sum(axis=-1)
    redundancy = m_tot - n_states
    valid = geom_ok & (redundancy >= 1)

    # Sub-solutions by rank-one downdate (Sherman-Morrison).
    v = np.einsum("bij,bmj->bmi", p0, h)  # v_i = P0 h_i, (B, M, n)
    c = np.einsum("bmi,bki->bmk", h, v)  # C = H P0 H^T, (B, M, M)
    lev = w * np.diagonal(c, axis1=-2, axis2=-1)
    one_m_lev = 1.0 - lev
    sub_ok = cand & (one_m_lev > _LEVERAGE_TOL) & valid[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(sub_ok, w / one_m_lev, np.nan)  # w_i / (1 - l_i)
    dx_sep = (gain * r)[..., None] * v  # dX_i = X0 - X_i
    dp = gain[..., None, None] * v[..., :, None] * v[..., None, :]  # dP_i = P_i - P0
    p_sub = p0[:, None] + dp
    dp_h_lam = _lam_max_2x2(dp[..., 0, 0], dp[..., 0, 1], dp[..., 1, 1])
    p_h_lam = _lam_max_2x2(p_sub[..., 0, 0], p_sub[..., 0, 1], p_sub[..., 1, 1])
    dp_u = dp[..., 2, 2]
    p_u = p_sub[..., 2, 2]

    with np.errstate(divide="ignore"):
        k_fa = stats.norm.isf(p_fa / (2.0 * np.maximum(m_sat, 1)))  # spec section 2
    k_md = stats.norm.isf(p_md)
    d_h = np.linalg.norm(dx_sep[..., :2], axis=-1)
    d_v = np.abs(dx_sep[..., 2])
    t_h = np.sqrt(dp_h_lam) * k_fa[:, None]
    t_v = np.sqrt(dp_u) * k_fa[:, None]
    ratio = np.fmax(_safe_ratio(d_h, t_h), _safe_ratio(d_v, t_v))
    alarm = valid & np.any(np.where(sub_ok, ratio > 1.0, False), axis=-1)

    # Protection levels (spec section 2). Unavailable unless every used satellite's
    # sub-solution is observable.
    pl_ok = valid & np.all(sub_ok | ~cand, axis=-1) & (m_sat > 0)
    with np.errstate(invalid="ignore"):
        hpl = np.nanmax(np.where(sub_ok, t_h + np.sqrt(p_h_lam) * k_md, -np.inf), axis=-1)
        vpl = np.nanmax(np.where(sub_ok, t_v + np.sqrt(p_u) * k_md, -np.inf), axis=-1)
    hpl = np.where(pl_ok, hpl, np.nan)
    vpl = np.where(pl_ok, vpl, np.nan)

    # Identification through sub-sub-solutions (paper Fig. 1), all (k, j) pairs at once.
    # With g_k = w_k / (1 - l_k): P_k h_j = v_j + g_k C_kj v_k,
    # l_kj = w_j h_j^T P_k h_j = l_j + w_j g_k C_jk^2, r^(k)_j = r_j + g_k r_k C_jk.
    g = np.where(sub_ok, gain, 0.0)
    u_kj = v[:, None, :, :] + (g[:, :, None] * c)[..., None] * v[:, :, None, :]  # (B,K,J,n)
    lev_kj = lev[:, None, :] + w[:, None, :] * g[:, :, None] * c**2
    r_kj = r[:, None, :] + (g * r)[:, :, None] * c
    pair = sub_ok[:, :, None] & cand[:, None, :] & ~np.eye(m_rows, dtype=bool)[None]
    # With redundancy 1 every sub-sub-solution has fewer measurements than states: exactly
    # unobservable (1 - l_kj = 0), whatever round-off says.
    pair_ok = pair & (1.0 - lev_kj > _LEVERAGE_TOL) & (redundancy >= 2)[:, None, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        gain_kj = np.where(pair_ok, w[:, None, :] / (1.0 - lev_kj), np.nan)
    sep_kj = (gain_kj * r_kj)[..., None] * u_kj  # X_k - X_kj
    dp_kj_h = gain_kj[..., None, None] * u_kj[..., :2, None] * u_kj[..., None, :2]
    lam_kj = _lam_max_2x2(dp_kj_h[..., 0, 0], dp_kj_h[..., 0, 1], dp_kj_h[..., 1, 1])
    with np.errstate(divide="ignore"):
        k_fa_sub = stats.norm.isf(p_fa / (2.0 * np.maximum(m_sat - 1, 1)))
    t_kj_h = np.sqrt(lam_kj) * k_fa_sub[:, None, None]
    t_kj_v = np.sqrt(gain_kj) * np.abs(u_kj[..., 2]) * k_fa_sub[:, None, None]
    ratio_kj = np.fmax(
        _safe_ratio(np.linalg.norm(sep_kj[..., :2], axis=-1), t_kj_h),
        _safe_ratio(np.abs(sep_kj[..., 2]), t_kj_v),
    )
    ratio_kj = np.where(pair_ok, ratio_kj, np.where(pair, np.inf, -np.inf))
    n_pairs = pair.sum(axis=-1)
    score = np.where(sub_ok & (n_pairs > 0), ratio_kj.max(axis=-1), np.nan)
    passed = np.where(np.isnan(score), False, score <= 1.0)
    # Identification needs m >= n + 2 and a sub-sub test for every candidate.
    can_ident = valid & (redundancy >= 2) & np.all(~cand | (sub_ok & (n_pairs > 0)), axis=-1)
    can_ident &= np.all(~pair | pair_ok, axis=(-1, -2))
    n_pass = passed.sum(axis=-1)
    ident_status = np.full(h.shape[0], IDENT_NONE, dtype=object)
    ident_status[alarm & ~can_ident] = IDENT_UNAVAILABLE
    ident_status[alarm & can_ident & (n_pass == 1)] = IDENT_UNIQUE
    ident_status[alarm & can_ident & (n_pass > 1)] = IDENT_AMBIGUOUS
    ident_status[alarm & can_ident & (n_pass == 0)] = IDENT_MULTIPLE
    ident_unique = np.where(ident_status == IDENT_UNIQUE, np.argmax(passed, axis=-1), -1)
    ranked = np.argmin(np.where(np.isnan(score), np.inf, score), axis=-1)
    pickable = (ident_status == IDENT_UNIQUE) | (ident_status == IDENT_AMBIGUOUS)
    ident_rank = np.where(pickable, ranked, -1)

    status = np.full(h.shape[0], STATUS_UNAVAILABLE, dtype=object)
    status[valid] = STATUS_NO_ISOLATION
    status[valid & can_ident] = STATUS_OK

    deeper = (ident_status == IDENT_MULTIPLE) & (redundancy >= 3)
    pairs, pair_pass, pair_score, pair_dx = _pair_level(h, z, w, cand, m_sat, deeper, p_fa)
    n_pair_pass = pair_pass.sum(axis=-1)
    pair_unique = np.where(n_pair_pass == 1, np.argmax(pair_pass, axis=-1), -1)
    pair_rank = np.where(n_pair_pass >= 1, np.argmin(
        np.where(pair_pass, pair_score, np.inf), axis=-1), -1)

    nan_rows = ~sub_ok
    return {
        "status": status.astype(str),
        "dx0_m": np.where(valid[:, None], dx0, np.nan),
        "p0_m2": np.where(valid[:, None, None], p0, np.nan),
        "dx_sep_m": np.where(nan_rows[..., None], np.nan, dx_sep),
        "dp_h_lam_m2": np.where(nan_rows, np.nan, dp_h_lam),
        "dp_u_m2": np.where(nan_rows, np.nan, dp_u),
        "p_h_lam_m2": np.where(nan_rows, np.nan, p_h_lam),
        "p_u_m2": np.where(nan_rows, np.nan, p_u),
        "d_h_m": np.where(nan_rows, np.nan, d_h),
        "t_h_m": np.where(nan_rows, np.nan, t_h),
        "d_v_m": np.where(nan_rows, np.nan, d_v),
        "t_v_m": np.where(nan_rows, np.nan, t_v),
        "ratio": np.where(nan_rows, np.nan, ratio),
        "alarm": alarm,
        "ident_status": ident_status.astype(str),
        "ident_pass": passed,
        "ident_score": score,
        "ident_unique": ident_unique,
        "ident_rank": ident_rank,
        "hpl_m": hpl,
        "vpl_m": vpl,
        "k_fa": k_fa,
        "m_sat": m_sat,
        "n_states": n_states,
        "pairs": pairs,
        "pair_pass": pair_pass,
        "pair_score": pair_score,
        "pair_dx_m": pair_dx,
        "ident_pair_unique": pair_unique,
        "ident_pair_rank": pair_rank,
    }


def _pair_level(h, z, w, cand, m_sat, todo, p_fa):
    """Second identification level: remove every candidate pair, test the rest.

    Runs only on the batch rows ``todo`` (multiple-fault verdicts, redundancy >= 3), all
    pairs at once: each pair-removed solution is an explicit batched solve, its one-more
    removals are rank-one downdates as in :func:`mss`. Returns ``pairs (P, 2)``,
    ``pass (B, P)``, ``score (B, P)`` and ``dx (B, P, n)``.
    """
    n_b, m_rows, n = h.shape
    k_idx, l_idx = np.triu_indices(m_rows, k=1)
    pairs = np.stack([k_idx, l_idx], axis=-1)
    n_p = len(pairs)
    passed = np.zeros((n_b, n_p), dtype=bool)
    score = np.full((n_b, n_p), np.nan)
    dx = np.full((n_b, n_p, n), np.nan)
    rows = np.flatnonzero(todo)
    if rows.size == 0 or n_p == 0:
        return pairs, passed, score, dx
    hb, zb, wb, cb = h[rows], z[rows], w[rows], cand[rows]
    pair_ok = cb[:, k_idx] & cb[:, l_idx]  # (b, P)
    w2 = np.repeat(wb[:, None, :], n_p, axis=1)
    w2[:, np.arange(n_p), k_idx] = 0.0
    w2[:, np.arange(n_p), l_idx] = 0.0
    h2 = np.broadcast_to(hb[:, None], w2.shape + (n,)).reshape(-1, m_rows, n)
    p2, _, ok2 = _normal_inverse(h2, w2.reshape(-1, m_rows))
    p2 = p2.reshape(len(rows), n_p, n, n)
    ok2 = ok2.reshape(len(rows), n_p) & pair_ok
    x2 = np.einsum("bpij,bmj,bpm,bm->bpi", p2, hb, w2, zb)
    r2 = zb[:, None, :] - np.einsum("bmi,bpi->bpm", hb, x2)
    v = np.einsum("bpij,bmj->bpmi", p2, hb)  # P_kl h_j
    lev = w2 * np.einsum("bmi,bpmi->bpm", hb, v)
    test = w2 > 0.0
    test &= cb[:, None, :]
    obs = ~test | (1.0 - lev > _LEVERAGE_TOL)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(test & obs, w2 / (1.0 - lev), np.nan)
    sep = (gain * r2)[..., None] * v
    lam = gain * np.sum(v[..., :2] ** 2, axis=-1)  # rank-one dP: its largest eigenvalue
    with np.errstate(divide="ignore"):
        k_fa = stats.norm.isf(p_fa / (2.0 * np.maximum(m_sat[rows] - 2, 1)))[:, None, None]
    ratio = np.fmax(_safe_ratio(np.linalg.norm(sep[..., :2], axis=-1), np.sqrt(lam) * k_fa),
                    _safe_ratio(np.abs(sep[..., 2]), np.sqrt(gain) * np.abs(v[..., 2]) * k_fa))
    ratio = np.where(test, np.where(obs, ratio, np.inf), -np.inf)
    usable = ok2 & np.any(test, axis=-1)
    sc = np.where(usable, ratio.max(axis=-1), np.nan)
    score[rows] = sc
    passed[rows] = usable & (sc <= 1.0)
    dx[rows] = np.where(usable[..., None], x2, np.nan)
    return pairs, passed, score, dx


def lambda_detect(dof: int, p_fa: float, p_md: float) -> float:
    """Non-centrality the chi-square test detects with probability ``1 - p_md``.

    Solves ``ncx2.cdf(chi2.isf(p_fa, dof), dof, lam) = p_md`` for ``lam`` (Brown 1992;
    Walter & Enge 1995 call ``sqrt(lam)`` the "pbias"). ``0`` when ``p_fa + p_md >= 1``
    (the test already detects a zero bias with probability ``1 - p_md``).

    Raises
    ------
    ValueError for ``dof < 1`` or probabilities outside (0, 1).
    """
    return _lambda_detect(check_int("dof", dof, 1), check_probability("p_fa", p_fa),
                          check_probability("p_md", p_md))


@lru_cache(maxsize=256)
def _lambda_detect(dof: int, p_fa: float, p_md: float) -> float:
    t2 = stats.chi2.isf(p_fa, dof)

    def miss(lam):
        return stats.ncx2.cdf(t2, dof, lam) - p_md

    if stats.chi2.cdf(t2, dof) <= p_md:  # 1 - p_fa <= p_md
        return 0.0
    hi = 10.0
    while miss(hi) > 0.0:
        hi *= 2.0
    return float(optimize.brentq(miss, 1e-9, hi, xtol=1e-10, rtol=1e-12))


def classic_raim(h, z_m, w, is_sat, p_fa: float, p_md: float) -> ClassicResult:
    """Classic snapshot RAIM: weighted SSE chi-square detector and slope-based PLs.

    Parameters
    ----------
    h, z_m, w, is_sat : as in :func:`mss` (a baro row, if weighted, is one more
        measurement but never a fault candidate).
    p_fa, p_md : false-alarm and missed-detection probabilities, in (0, 1).

    Returns
    -------
    ClassicResult ; unavailable epochs (singular geometry or dof < 1, as in :func:`mss`)
    have NaN ``sse``, threshold and protection levels and no alarm.

    Raises
    ------
    ValueError as :func:`mss`.

    See Also
    --------
    classic_raim_reference : the plain-numpy reference path (same results to round-off);
        this function computes ``P0`` and the singular-geometry test as :func:`mss` does,
        block by block.

    Notes
    -----
    Test statistic ``SSE = r^T W r ~ chi2(m - n)`` without fault, threshold
    ``chi2.isf(p_fa, m - n)``. A bias ``b`` on measurement ``i`` gives the non-centrality
    ``lam = b^2 w_i (1 - l_i)`` and the position error ``b S[:, i]`` with
    ``S = P0 H^T W``, so (Brown 1992, weighted form of Walter & Enge 1995)::

        Hslope_i = ||S[EN, i]|| / sqrt(w_i (1 - l_i)),   Vslope_i = |S[U, i]| / sqrt(w_i (1 - l_i))
        HPL = max_i Hslope_i sqrt(lam_det),              VPL = max_i Vslope_i sqrt(lam_det)

    where ``lam_det`` solves ``ncx2.cdf(chi2.isf(p_fa, dof), dof, lam_det) = p_md``.
    (``Hslope_i = sqrt(lam_max(dP_i,EN))`` of :func:`mss`: both families share slopes.)
    This PL has no noise term of its own (as in Brown 1992); the MSS PL has one.
    """
    p_fa = check_probability("p_fa", p_fa)
    p_md = check_probability("p_md", p_md)
    batch, h, z, w, is_sat = _flat_args(h, z_m, w, is_sat)
    n_b, m_rows, _ = h.shape
    o = {"status": np.zeros(n_b, dtype=np.int8), "sse": np.full(n_b, np.nan),
         "threshold": np.full(n_b, np.nan), "alarm": np.zeros(n_b, dtype=bool),
         "dof": np.zeros(n_b, dtype=np.int64), "lam_det": np.full(n_b, np.nan),
         "hslope_m": np.full((n_b, m_rows), np.nan), "vslope_m": np.full((n_b, m_rows), np.nan),
         "hpl_m": np.full(n_b, np.nan), "vpl_m": np.full(n_b, np.nan)}
    redo = []
    step = _block_epochs(m_rows)
    for start in range(0, n_b, step):
        blk = slice(start, min(start + step, n_b))
        rows = _classic_block(*_sanitize(h[blk], z[blk], w[blk]), is_sat, p_fa, p_md,
                              {key: a[blk] for key, a in o.items()})
        redo.append(rows + start)
    o["status"] = _STATUS_NAMES[o["status"]]
    redo = np.concatenate(redo) if redo else np.zeros(0, dtype=int)
    if redo.size:  # ill-conditioned or singular: the reference decides
        ref = _classic_reference_flat(*_sanitize(h[redo], z[redo], w[redo]), is_sat, p_fa,
                                      p_md)
        for key, a in o.items():
            a[redo] = ref[key]
    return ClassicResult(**{key: a.reshape(batch + a.shape[1:]) for key, a in o.items()})


@lru_cache(maxsize=256)
def _chi2_threshold(dof: int, p_fa: float) -> float:
    """``chi2.isf(p_fa, dof)``, cached (the same value as the element-wise call)."""
    return float(stats.chi2.isf(p_fa, dof))


def _classic_block(h, z, w, is_sat, p_fa, p_md, o):
    """Fast :func:`classic_raim` on one block, written into the views ``o``.

    Returns the block rows that the reference path must decide.
    """
    p0, n_states, sure = _main_covariance(h, w)
    v = np.matmul(h, p0)
    dx0 = np.matmul((w * z)[:, None, :], v)[:, 0]
    r = z - np.matmul(h, dx0[..., None])[..., 0]
    used = w > 0.0
    cand = used & is_sat[None, :]
    dof = used.sum(axis=-1) - n_states
    valid = sure & (dof >= 1)
    o["dof"][:] = dof
    redo = np.flatnonzero(~sure & (dof >= 1))
    if not valid.any():
        return redo
    o["sse"][:] = np.where(valid, np.sum(w * r * r, axis=-1), np.nan)
    dof_safe = np.maximum(dof, 1)
    uniq = np.unique(dof_safe)
    pos = np.searchsorted(uniq, dof_safe)
    thr = np.array([_chi2_threshold(int(d), p_fa) for d in uniq])[pos]
    lam_det = np.array([_lambda_detect(int(d), p_fa, p_md) for d in uniq])[pos]
    o["threshold"][:] = np.where(valid, thr, np.nan)
    o["lam_det"][:] = np.where(valid, lam_det, np.nan)
    o["alarm"][:] = valid & (o["sse"] > thr)

    one_m_lev = 1.0 - w * np.sum(h * v, axis=-1)
    slope_ok = cand & (one_m_lev > _LEVERAGE_TOL) & valid[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(slope_ok, np.sqrt(w / one_m_lev), np.nan)  # S[:, i] = w_i v_i
    hslope = scale * np.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2)
    vslope = scale * np.abs(v[..., 2])
    o["hslope_m"][:] = hslope
    o["vslope_m"][:] = vslope
    pl_ok = valid & np.all(slope_ok | ~cand, axis=-1) & (cand.sum(axis=-1) > 0)
    sq_lam = np.sqrt(lam_det)
    o["hpl_m"][:] = np.where(pl_ok, np.max(np.where(slope_ok, hslope, -np.inf), axis=-1),
                             np.nan) * sq_lam
    o["vpl_m"][:] = np.where(pl_ok, np.max(np.where(slope_ok, vslope, -np.inf), axis=-1),
                             np.nan) * sq_lam
    o["status"][:] = np.where(valid, np.where(dof >= 2, 2, 1), 0)
    return redo


def classic_raim_reference(h, z_m, w, is_sat, p_fa: float, p_md: float) -> ClassicResult:
    """Reference path of :func:`classic_raim` (explicit batched inverse over the whole
    batch); the same arguments, result and errors. Kept for the agreement tests and the
    benchmark baseline."""
    p_fa = check_probability("p_fa", p_fa)
    p_md = check_probability("p_md", p_md)
    batch, h, z, w, is_sat = _prepare(h, z_m, w, is_sat)
    o = _classic_reference_flat(h, z, w, is_sat, p_fa, p_md)
    return ClassicResult(**{key: a.reshape(batch + a.shape[1:]) for key, a in o.items()})


def _classic_reference_flat(h, z, w, is_sat, p_fa, p_md) -> dict:
    """:func:`classic_raim_reference` on prepared flat arrays; a dict of the fields."""

    p0, n_states, geom_ok = _normal_inverse(h, w)
    dx0 = np.einsum("bij,bmj,bm,bm->bi", p0, h, w, z)
    r = z - np.einsum("bmi,bi->bm", h, dx0)
    used = w > 0.0
    cand = used & is_sat[None, :]
    dof = used.sum(axis=-1) - n_states
    valid = geom_ok & (dof >= 1)
    sse = np.where(valid, np.sum(w * r**2, axis=-1), np.nan)

    dof_safe = np.maximum(dof, 1)
    uniq = np.unique(dof_safe)  # a handful of small integers: one root-find each
    thr_u = stats.chi2.isf(p_fa, uniq)
    lam_u = np.array([_lambda_detect(int(d), p_fa, p_md) for d in uniq])
    pos = np.searchsorted(uniq, dof_safe)
    threshold = np.where(valid, thr_u[pos], np.nan)
    lam_det = np.where(valid, lam_u[pos], np.nan)
    alarm = valid & (sse > threshold)

    v = np.einsum("bij,bmj->bmi", p0, h)
    lev = w * np.einsum("bmi,bmi->bm", h, v)
    slope_ok = cand & (1.0 - lev > _LEVERAGE_TOL) & valid[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(slope_ok, np.sqrt(w / (1.0 - lev)), np.nan)  # S[:, i] = w_i v_i
    hslope = scale * np.linalg.norm(v[..., :2], axis=-1)
    vslope = scale * np.abs(v[..., 2])
    pl_ok = valid & np.all(slope_ok | ~cand, axis=-1) & (cand.sum(axis=-1) > 0)
    hpl = np.where(pl_ok, np.nanmax(np.where(slope_ok, hslope, -np.inf), axis=-1), np.nan)
    vpl = np.where(pl_ok, np.nanmax(np.where(slope_ok, vslope, -np.inf), axis=-1), np.nan)
    hpl = hpl * np.sqrt(lam_det)
    vpl = vpl * np.sqrt(lam_det)

    status = np.full(h.shape[0], STATUS_UNAVAILABLE, dtype=object)
    status[valid] = STATUS_NO_ISOLATION
    status[valid & (dof >= 2)] = STATUS_OK

    return {"status": status.astype(str), "sse": sse, "threshold": threshold, "alarm": alarm,
            "dof": dof, "lam_det": lam_det, "hslope_m": hslope, "vslope_m": vslope,
            "hpl_m": hpl, "vpl_m": vpl}


def availability(hpl_m, vpl_m, hal_m: float, val_m: float) -> np.ndarray:
    """``True`` where both protection levels are finite and within the alert limits.

    ``hal_m`` and ``val_m`` must be finite and > 0 (``ValueError`` otherwise).
    """
    hal_m = check_positive("hal_m", hal_m)
    val_m = check_positive("val_m", val_m)
    hpl = np.asarray(hpl_m, dtype=float)
    vpl = np.asarray(vpl_m, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.isfinite(hpl) & np.isfinite(vpl) & (hpl <= hal_m) & (vpl <= val_m)
