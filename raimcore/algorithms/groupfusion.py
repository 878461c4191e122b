"""Group fault detection with evidence fusion (seed 004), and its two baselines.

Vectorised kernels for multi-fault isolation on a linearised pseudorange model
``y = H x + b + e`` (spec section 4). Shapes follow the package rule, batch axes first:
``(..., N, n)`` geometry rows for ``N`` satellites and ``n = 3 + q`` states (one-hot clock
column per system), ``(..., N)`` measurements, and ``G`` groups of ``r`` satellites given
as an index array ``(G, r)`` shared by the whole batch. Every group of every run is solved
at once (normal equations over a ``(..., G, r, n)`` stack): there is no Python loop per
group or per run.

* :func:`select_groups` - the ``L1 = floor(L / K)`` groups at equal spacing ``K`` in the
  lexicographic list of all ``L = C(N, r)`` groups (seed 004 eqs. 1-2).
* :func:`group_chi2` - per-group residual chi-square ``theta`` and its dof
  ``r - 3 - (systems in the group)`` (seed 004 eqs. 5-7).
* :func:`basic_belief` - the group's m(F) (spec 4 reading of the damaged eq. 8).
* :func:`combine_pair` / :func:`fuse` - weighted distribution of conflict (eqs. 10-12),
  which on the frame {F, N} is the reliability-weighted mean.
* :func:`gf_isolate` - the whole GF method with the adaptive threshold mean + M (eq. 3).
* :func:`rs_isolate` - random search baseline (Chen & Zhang 2011, the paper's ref. [5]).
* :func:`qv_isolate` - quality value / confidence index baseline (Patino-Studencka et al.
  2010, the paper's ref. [6]).
* :func:`parity_isolate` - greedy single exclusion (seed 000) on the same model, for
  reference.

References
----------
Seed 004 (``/work/shared/seeds/004_cb0d2396e5faaa63.txt``): grouped fault detection with
evidence fusion for multi-satellite fault isolation, GPS/BDS. Spec: ALGORITHMS.md section 4.
"""

from __future__ import annotations

import functools
import itertools
import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from .._validate import check_choice, check_int, check_probability, check_range

__all__ = ["select_groups", "group_chi2", "basic_belief", "combine_pair", "fuse",
           "adaptive_isolation", "gf_isolate", "rs_isolate", "qv_isolate", "parity_isolate",
           "GroupStats", "GFResult", "WEIGHTS", "gf_isolate_loop"]

#: Reliability choices p of a group (alpha = 1 / p, seed 004 eq. 11). The paper does not say
#: what p is for a group; "pdop" (default) trusts well-conditioned groups more, "uniform"
#: gives every group the same weight (spec 4: the two differ by 1-2 points).
WEIGHTS = ("pdop", "uniform")

#: PDOP above which a group's geometry is treated as singular (weight 0, no evidence).
PDOP_MAX = 1e4


@functools.lru_cache(maxsize=64)
def _groups_cached(n_sat: int, r: int, n_groups: int) -> np.ndarray:
    total = math.comb(n_sat, r)
    if n_groups >= total:
        step, count = 1, total
    else:
        step = total // n_groups  # seed 004 eq. 2: spacing K
        count = total // step  # L1 = floor(L / K)
    combos = itertools.islice(itertools.combinations(range(n_sat), r), 0, step * count, step)
    out = np.fromiter(itertools.chain.from_iterable(combos), dtype=np.intp, count=count * r)
    out = out.reshape(count, r)
    out.flags.writeable = False
    return out


def select_groups(n_sat: int, r: int, n_groups: int | str | None = None) -> np.ndarray:
    """Groups of ``r`` satellites out of ``n_sat``, at equal spacing (seed 004 eqs. 1-2).

    Parameters
    ----------
    n_sat : number of satellites N (>= r).
    r : group size (4 + q for q systems).
    n_groups : wanted number of groups, ``None`` for N^2 (the paper's choice) or ``"all"``
        for all ``C(N, r)``. With ``K = floor(C(N, r) / n_groups)`` the groups are those at
        ranks 0, K, 2K, ... of the lexicographic list, ``L1 = floor(C(N, r) / K)`` of them
        (so L1 can exceed ``n_groups`` slightly).

    Returns
    -------
    (L1, r) int array of satellite indices, each row increasing (read-only, cached).
    """
    n_sat = check_int("n_sat", n_sat, 1)
    r = check_int("r", r, 1)
    if n_sat < r:
        raise ValueError(f"n_sat must be >= r = {r} to form a group, got {n_sat}")
    total = math.comb(n_sat, r)
    if n_groups is None:
        n_groups = n_sat**2
    elif n_groups == "all":
        n_groups = total
    n_groups = check_int("n_groups", n_groups, 1)
    return _groups_cached(n_sat, r, min(n_groups, total))


@dataclass(frozen=True)
class GroupStats:
    """Per-group detection results, each of shape ``(..., G)``.

    theta : residual chi-square w^T W w (seed 004 eq. 6), dimensionless.
    dof : r - 3 - (systems present in the group).
    threshold : T = chi2.isf(p_fa, dof) (eq. 7).
    pdop : the group's PDOP (in units of sigma when the rows are whitened); inf if singular.
    ok : bool, non-singular group geometry with dof >= 1.
    """

    theta: np.ndarray
    dof: np.ndarray
    threshold: np.ndarray
    pdop: np.ndarray
    ok: np.ndarray


def group_chi2(h, y, groups, p_fa: float, weights=None) -> GroupStats:
    """Least-squares residual chi-square of every group (seed 004 eqs. 5-7), batched.

    Parameters
    ----------
    h : (..., N, 3 + q) geometry rows ``[-u, clock one-hot]``.
    y : (..., N) measurement minus prediction at any linearisation point (m); a full-set
        post-fit residual is fine since ``(I - P_g) H_g x = 0``.
    groups : (G, r) satellite indices.
    p_fa : false-alarm probability of each group test.
    weights : (..., N) or scalar 1 / sigma^2 (1/m^2); default 1.

    Returns
    -------
    GroupStats with arrays of shape ``(..., G)``.
    """
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    member = membership_matrix(np.asarray(groups), y.shape[-1]).astype(float)
    return _chi2_members(h, y, member, p_fa, weights)


def _chi2_members(h, y, member, p_fa, weights=None) -> GroupStats:
    """group_chi2 for groups given as a 0/1 membership matrix ``(G, N)`` or ``(..., G, N)``.

    Normal equations by sums over members: every satellite contributes ``w h h^T``,
    ``w h y`` and ``w y^2``; one matrix product with the membership matrix gives every
    group's sums at once. The clock columns are one-hot, so the clock block of the normal
    matrix is diagonal (satellite count per system) and is eliminated in closed form
    (Schur complement); the remaining 3 x 3 position block is inverted by its adjugate.
    All of it is element-wise arithmetic on ``(..., G)`` arrays: no per-group solve.
    """
    n_states = h.shape[-1]
    q = n_states - 3
    w = (np.ones_like(y) if weights is None
         else np.broadcast_to(np.asarray(weights, dtype=float), y.shape))
    hw = h * w[..., None]
    pos = h[..., :3]
    # Per-satellite terms: 6 of w u u^T, q x 3 of w c u^T, q of w c, 3 + q of w h y, w y^2.
    iu = ([0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2])
    feats = np.concatenate([
        (hw[..., :3, None] * pos[..., None, :])[..., iu[0], iu[1]],
        (hw[..., 3:, None] * pos[..., None, :]).reshape(y.shape + (3 * q,)),
        hw[..., 3:],
        hw * y[..., None],
        (w * y * y)[..., None],
    ], axis=-1)  # (..., N, F)
    # (..., F, G): every group's normal-equation sums at once, one matrix product; the
    # feature axis first keeps each term contiguous over groups for what follows.
    sums = np.swapaxes(feats, -1, -2) @ np.swapaxes(member, -1, -2)
    sums = np.moveaxis(sums, -2, 0)  # (F, ..., G) view
    a00, a01, a02, a11, a12, a22 = sums[:6]
    bm = np.moveaxis(sums[6:6 + 3 * q].reshape((q, 3) + sums.shape[1:]), (0, 1), (-2, -1))
    d = np.moveaxis(sums[6 + 3 * q:6 + 4 * q], 0, -1)  # clock diagonal: weighted counts
    g = np.moveaxis(sums[6 + 4 * q:6 + 4 * q + n_states], 0, -1)
    yy = sums[-1]
    present = d > 0.0  # a system with no satellite in the group has no clock state
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        dinv = np.where(present, 1.0 / np.where(present, d, 1.0), 0.0)
        # Schur complement S = A - B D^-1 B^T and reduced right-hand side.
        bd = bm * dinv[..., None]  # (..., G, q, 3)
        s_ = [a00, a01, a02, a11, a12, a22]
        for k, (i, j) in enumerate(zip(*iu, strict=True)):
            s_[k] = s_[k] - np.sum(bd[..., i] * bm[..., j], axis=-1)
        a, b, c, dd, e, f = s_
        gc = g[..., 3:]
        gp = g[..., :3] - np.sum(bd * gc[..., None], axis=-2)
        c00, c01, c02 = dd * f - e * e, c * e - b * f, b * e - c * dd
        c11, c12, c22 = a * f - c * c, b * c - a * e, a * dd - b * b
        det = a * c00 + b * c01 + c * c02
        quad = (c00 * gp[..., 0] ** 2 + c11 * gp[..., 1] ** 2 + c22 * gp[..., 2] ** 2
                + 2 * (c01 * gp[..., 0] * gp[..., 1] + c02 * gp[..., 0] * gp[..., 2]
                       + c12 * gp[..., 1] * gp[..., 2])) / det
        theta = yy - np.sum(dinv * gc * gc, axis=-1) - quad
        pdop = np.sqrt((c00 + c11 + c22) / det)
        scale = a * dd * f
        regular = np.isfinite(det) & (det > 1e-12 * np.abs(scale))
    n_sys = np.sum(present, axis=-1)
    dof = np.rint(np.sum(member, axis=-1)).astype(int) - 3 - n_sys  # spec 4: r - 3 - q_g
    ok = regular & (dof >= 1) & np.isfinite(pdop) & (pdop < PDOP_MAX) & (pdop > 0)
    theta = np.where(ok, np.maximum(theta, 0.0), np.nan)
    dof_safe = np.maximum(dof, 1)
    values = np.unique(dof_safe)
    threshold = special.chdtri(values, p_fa)[np.searchsorted(values, dof_safe)]  # eq. 7
    return GroupStats(theta, dof, threshold, np.where(ok, pdop, np.inf), ok)


def basic_belief(theta, dof, p_fa: float):
    """Basic belief m(F) of a group from its statistic (spec 4 reading of seed 004 eq. 8).

    ``m(F) = 0.5 F(theta) / F(T)`` for ``theta <= T`` and
    ``0.5 + 0.5 (1 - sf(theta) / sf(T))`` above, with ``F`` the chi2(dof) CDF, ``sf = 1 - F``
    and ``T = chi2.isf(p_fa, dof)``; ``m(N) = 1 - m(F)``. So m(F) = 0.5 at theta = T,
    increasing from 0 (theta = 0) to 1 (theta -> inf). The upper branch uses survival
    functions only (spec 4 numerics: ``1 - F`` near 1 loses every digit at p_fa = 1e-5/3600).

    Parameters
    ----------
    theta : (...) group statistics (NaN propagates).
    dof : (...) int degrees of freedom (>= 1).
    p_fa : the false-alarm probability that sets T.

    Returns
    -------
    m_f : (...) in [0, 1].
    """
    theta = np.asarray(theta, dtype=float)
    dof = np.asarray(dof)
    theta, dof = np.broadcast_arrays(theta, dof)
    out = np.full(theta.shape, np.nan)
    for d in np.unique(dof):  # a handful of dof values: closed forms for 1 and 2
        sel = dof == d
        x = theta[sel]
        t = float(special.chdtri(d, p_fa))
        cdf, sf = _chi2_cdf_sf(x, int(d))
        cdf_t, sf_t = _chi2_cdf_sf(np.array(t), int(d))
        out[sel] = np.where(x <= t, 0.5 * cdf / cdf_t, 0.5 + 0.5 * (1.0 - sf / sf_t))
    return out if out.ndim else float(out)


def _chi2_cdf_sf(x, dof: int):
    """chi2(dof) CDF and survival function, each computed directly (no 1 - F)."""
    if dof == 1:
        z = np.sqrt(0.5 * np.maximum(x, 0.0))
        return special.erf(z), special.erfc(z)
    if dof == 2:
        return -np.expm1(-0.5 * x), np.exp(-0.5 * x)
    return special.chdtr(dof, x), special.chdtrc(dof, x)


def combine_pair(m1_f, alpha1, m2_f, alpha2):
    """Weighted distribution of conflict for two evidences on {F, N} (seed 004 eqs. 10-12).

    Agreeing products go to their common focal element; each conflicting product
    ``m1(A) m2(C)`` (A and C disjoint) is split ``omega`` to A and ``1 - omega`` to C with
    ``omega = alpha1 / (alpha1 + alpha2)`` (eq. 11). The combined evidence has reliability
    ``alpha1 + alpha2`` (eq. 12). Written out literally (not through the closed form) so that
    a test can check the closed form of :func:`fuse` against it.

    Returns ``(m_f, alpha)`` of the combined evidence.
    """
    m1_n, m2_n = 1.0 - np.asarray(m1_f), 1.0 - np.asarray(m2_f)
    omega = alpha1 / (alpha1 + alpha2)
    agree_f = m1_f * m2_f  # F ∩ F = F
    # eq. 10 for A = F: conflicting pairs (F, N) and (N, F).
    conflict_f = omega * m1_f * m2_n + (1.0 - omega) * m1_n * m2_f
    return agree_f + conflict_f, alpha1 + alpha2


def fuse(m_f, alpha, membership):
    """Fuse every satellite's group evidences (seed 004 eqs. 10-12, closed form).

    On the two-element frame {F, N} the pairwise rule of :func:`combine_pair` is exactly the
    alpha-weighted mean, so fusing all groups of a satellite in any order gives
    ``sum_g alpha_g m_g(F) / sum_g alpha_g`` over the groups the satellite belongs to.

    Parameters
    ----------
    m_f : (..., G) group m(F); alpha : (..., G) reliabilities (0 = no evidence).
    membership : (G, N) bool, satellite j is in group g.

    Returns
    -------
    (..., N) fused m(F); NaN for a satellite in no (usable) group.
    """
    member = np.asarray(membership, dtype=float)
    a = np.where(alpha > 0, alpha, 0.0)
    num = np.where(a > 0, a * m_f, 0.0) @ member
    den = a @ member
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan)


def adaptive_isolation(score, margin: float):
    """Isolate every satellite whose score exceeds mean + M (seed 004 eq. 3).

    score : (..., N), NaN entries are ignored (never isolated, not in the mean).
    Returns ``(isolated (..., N) bool, threshold (...))``.
    """
    with np.errstate(invalid="ignore"):
        thr = np.nanmean(np.where(np.isfinite(score), score, np.nan), axis=-1) + margin
        iso = score > thr[..., None]
    return iso & np.isfinite(score), thr


def membership_matrix(groups, n_sat: int) -> np.ndarray:
    """(G, N) bool: satellite j belongs to group g."""
    m = np.zeros((groups.shape[0], n_sat), dtype=bool)
    m[np.arange(groups.shape[0])[:, None], groups] = True
    return m


@dataclass(frozen=True)
class GFResult:
    """GF isolation of a batch.

    m_f : (..., N) fused m(F) per satellite; threshold : (...) mean + M;
    isolated : (..., N) bool; groups : GroupStats (..., G); group_m_f : (..., G).
    """

    m_f: np.ndarray
    threshold: np.ndarray
    isolated: np.ndarray
    groups: GroupStats
    group_m_f: np.ndarray


def _check_common(p_fa, margin, weights):
    check_probability("p_fa", p_fa)
    check_range("margin", margin, 0.0, 1.0)
    check_choice("weights", weights, WEIGHTS)


def _alpha(stats: GroupStats, weights: str):
    if weights == "uniform":
        return np.where(stats.ok, 1.0, 0.0)
    return np.where(stats.ok, 1.0 / np.where(stats.ok, stats.pdop, 1.0), 0.0)  # alpha = 1/p


def gf_isolate(h, y, groups, p_fa: float, *, weights_lsq=None, margin: float = 0.1,
               weights: str = "pdop") -> GFResult:
    """Group detection + evidence fusion + adaptive threshold (seed 004), batched.

    Parameters
    ----------
    h : (..., N, 3 + q) rows; y : (..., N) measurements (m); groups : (G, r) indices
        (see :func:`select_groups`); p_fa : per-group false-alarm probability.
    weights_lsq : (..., N) or scalar 1 / sigma^2 (1/m^2).
    margin : M of eq. 3 (paper 0.1 .. 0.2; spec default 0.1).
    weights : reliability p of a group, one of :data:`WEIGHTS`.

    Returns
    -------
    GFResult
    """
    _check_common(p_fa, margin, weights)
    stats = group_chi2(h, y, groups, p_fa, weights_lsq)
    m_f = basic_belief(stats.theta, stats.dof, p_fa)
    alpha = _alpha(stats, weights)
    fused = fuse(m_f, alpha, membership_matrix(groups, np.shape(y)[-1]))
    iso, thr = adaptive_isolation(fused, margin)
    return GFResult(fused, thr, iso, stats, m_f)


def gf_isolate_loop(h, y, groups, p_fa: float, *, weights_lsq=None, margin: float = 0.1,
                    weights: str = "pdop") -> GFResult:
    """The same as :func:`gf_isolate` with a Python loop over groups (batched over runs).

    Reference implementation for the agreement test and the benchmark only.
    """
    _check_common(p_fa, margin, weights)
    parts = [group_chi2(h, y, groups[g:g + 1], p_fa, weights_lsq) for g in range(len(groups))]
    stats = GroupStats(*(np.concatenate([getattr(p, f) for p in parts], axis=-1)
                         for f in ("theta", "dof", "threshold", "pdop", "ok")))
    m_f = basic_belief(stats.theta, stats.dof, p_fa)
    alpha = _alpha(stats, weights)
    fused = fuse(m_f, alpha, membership_matrix(groups, np.shape(y)[-1]))
    iso, thr = adaptive_isolation(fused, margin)
    return GFResult(fused, thr, iso, stats, m_f)


def _systems_ok(h, idx):
    """(..., D) bool: the index sets ``idx (..., D, k)`` contain >= 2 satellites of every
    system present in the whole set (so that adding one satellite can be tested)."""
    clk = h[..., 3:]  # (..., N, q)
    sub = np.take_along_axis(clk[..., None, :, :], idx[..., None], axis=-2)  # (..., D, k, q)
    count = sub.sum(axis=-2)
    present = clk.sum(axis=-2) > 0  # (..., q)
    return np.all((count >= 2) | ~present[..., None, :], axis=-1)


def _gather_chi2(h, y, idx, p_fa, weights_lsq):
    """group_chi2 for per-run index sets ``idx (B, D, k)`` (groups that differ per run)."""
    b, d, _ = idx.shape
    member = np.zeros((b, d, y.shape[-1]))
    np.put_along_axis(member, idx, 1.0, axis=-1)
    return _chi2_members(h, y, member, p_fa, weights_lsq)


def _masked_chi2(h, y, w, mask, p_fa):
    """Full-set chi-square of the satellites in ``mask (B, N)``: (stat, dof, T, inv, x, res)."""
    we = np.where(mask, w, 0.0)
    hw = h * we[..., None]
    nm = np.swapaxes(hw, -1, -2) @ h
    present = np.diagonal(nm, axis1=-2, axis2=-1) > 0
    nm = nm + (~present)[..., None, :] * np.eye(h.shape[-1])
    inv = np.linalg.inv(nm)
    x = np.einsum("...ij,...sj,...s->...i", inv, hw, y)
    res = y - np.einsum("...sn,...n->...s", h, x)
    stat = np.sum(we * res**2, axis=-1)
    dof = np.sum(mask, axis=-1) - 3 - np.sum(present[..., 3:], axis=-1)
    return stat, dof, special.chdtri(np.maximum(dof, 1), p_fa), inv, res, we


def rs_isolate(h, y, p_fa: float, rng: np.random.Generator, *, weights_lsq=None,
               n_draws: int = 50, size: int | None = None):
    """Random search (Chen & Zhang 2011, seed 004's ref. [5]), batched over runs.

    Reading (the paper gives no detail, spec 4 "under-specified"): draw ``n_draws`` random
    subsets of ``size`` (default ``r = 4 + q``) satellites per run, keeping only subsets with
    >= 2 satellites of each system (else an added satellite could be the only one of its
    system, and its residual would be zero); the first subset that passes the chi-square
    test is presumed fault-free (if none passes, the one with the smallest theta / T).
    The other satellites are then added one at a time in random order to the growing
    consistent set: a satellite whose addition makes the test fail is isolated (and left
    out), otherwise it joins the set.

    Parameters
    ----------
    h : (B, N, 3 + q); y : (B, N); rng : random generator.

    Returns
    -------
    isolated : (B, N) bool.
    """
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    check_probability("p_fa", p_fa)
    n_draws = check_int("n_draws", n_draws, 1, 10_000)
    b, n = y.shape
    size = h.shape[-1] + 1 if size is None else check_int("size", size, 2, n - 1)
    w = (np.ones_like(y) if weights_lsq is None
         else np.broadcast_to(np.asarray(weights_lsq, dtype=float), y.shape))
    keys = rng.random((b, n_draws, n))
    idx = np.sort(np.argsort(keys, axis=-1)[..., :size], axis=-1)  # (B, D, size)
    st = _gather_chi2(h, y, idx, p_fa, weights_lsq)
    ratio = np.where(st.ok & _systems_ok(h, idx), st.theta / st.threshold, np.inf)
    passing = ratio <= 1.0
    first = np.where(passing.any(axis=-1), np.argmax(passing, axis=-1),
                     np.argmin(ratio, axis=-1))
    rows = np.arange(b)
    consistent = np.zeros((b, n), dtype=bool)
    consistent[rows[:, None], idx[rows, first]] = True
    isolated = np.zeros((b, n), dtype=bool)
    order = np.argsort(np.where(consistent, np.inf, rng.random((b, n))), axis=-1)
    for step in range(n - size):  # one satellite per run per step, all runs at once
        j = order[:, step]
        trial = consistent.copy()
        trial[rows, j] = True
        stat, _, thr, *_ = _masked_chi2(h, y, w, trial, p_fa)
        fail = stat > thr
        isolated[rows, j] = fail
        consistent[rows, j] = ~fail
    return isolated


def qv_isolate(h, y, groups, p_fa: float, *, weights_lsq=None, margin: float = 0.1,
               norm: str = "share"):
    """Quality value / confidence index (Patino-Studencka et al. 2010, seed 004's ref. [6]).

    Reading (spec 4): test the same groups as GF; only failing groups give their members a
    confidence index (1 per failing group), summed per satellite. To give the mean + M rule
    of eq. 3 a scale, the sums are normalised: ``norm="share"`` (default) divides by the number of
    groups the satellite is in (the share of its groups that fail), ``norm="max"`` by the
    largest sum of the run (much worse: 24% vs 84% for N = 18, one fault at 1.5 P_bias).
    Isolate with mean + M.

    Returns ``(isolated (..., N) bool, score (..., N), threshold (...))``.
    """
    check_probability("p_fa", p_fa)
    check_range("margin", margin, 0.0, 1.0)
    st = group_chi2(h, y, groups, p_fa, weights_lsq)
    fail = np.where(st.ok, (st.theta > st.threshold).astype(float), 0.0)
    check_choice("norm", norm, ("max", "share"))
    member = membership_matrix(groups, np.shape(y)[-1])
    if norm == "share":
        score = fuse(fail, st.ok.astype(float), member)
    else:
        total = fail @ member.astype(float)
        top = total.max(axis=-1, keepdims=True)
        score = np.where(top > 0, total / np.where(top > 0, top, 1.0), 0.0)
    iso, thr = adaptive_isolation(score, margin)
    return iso, score, thr


def parity_isolate(h, y, p_fa: float, *, weights_lsq=None, max_exclusions: int = 3):
    """Greedy single exclusion (seed 000 style) on the linear model, for reference.

    While the full-set chi-square test fails and exclusions remain, exclude the satellite
    with the largest normalised residual ``w_j^2 / S_jj`` (the parity DF_I of seed 000) and
    test again. Batched over runs.

    Returns isolated : (B, N) bool.
    """
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    check_probability("p_fa", p_fa)
    max_exclusions = check_int("max_exclusions", max_exclusions, 0, 10)
    w = np.ones_like(y) if weights_lsq is None else np.broadcast_to(
        np.asarray(weights_lsq, dtype=float), y.shape).copy()
    excluded = np.zeros(y.shape, dtype=bool)
    active = np.ones(y.shape[:-1], dtype=bool)
    for _ in range(max_exclusions + 1):
        stat, dof, thr, inv, res, we = _masked_chi2(h, y, w, ~excluded, p_fa)
        alarm = active & (stat > thr) & (dof >= 2)
        if not alarm.any() or _ >= max_exclusions:
            break
        # S_jj = 1 - w_j h_j^T N^-1 h_j (weighted residual projector diagonal)
        s_jj = 1.0 - we * np.einsum("...sn,...nm,...sm->...s", h, inv, h)
        with np.errstate(invalid="ignore", divide="ignore"):
            dfi = np.where(excluded | (s_jj <= 1e-9), -np.inf, we * res**2 / s_jj)
        best = np.argmax(dfi, axis=-1)
        rows = np.flatnonzero(alarm)
        excluded[rows, best[rows]] = True
        active = alarm
    return excluded
