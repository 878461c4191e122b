"""Group fault detection with evidence fusion (seed 004), and its two baselines.

Vectorised kernels for multi-fault isolation on a linearised pseudorange model
``y = H x + b + e`` (spec section 4). Shapes follow the package rule, batch axes first:
``(..., N, n)`` geometry rows for ``N`` satellites and ``n = 3 + q`` states (one-hot clock
column per system), ``(..., N)`` measurements, and ``G`` groups of ``r`` satellites given
as an index array ``(G, r)`` shared by the whole batch. Every group of every run is solved
at once (normal-equation sums of all groups in one matrix product, then a closed-form solve
on cache-sized blocks): there is no Python loop per group or per run.

Speed (issue 17). The kernels keep their pre-issue plain-numpy versions as a reference path
(``reference=True`` of :func:`group_chi2`, :func:`gf_isolate`, :func:`qv_isolate`,
:func:`rs_isolate`); the agreement tests hold the fast path to the same decisions and to
the reference statistics to 1e-9 relative (theta relative to the larger of itself and the
group's pre-fit sum of squares, from which both paths form it by subtraction). What made
it fast: no large temporaries (the solve works on blocks of 8192 groups), products cut so
that BLAS never starts threads (they only spun against the other workers of a process
pool), GF's group statistics reused by QV on the same runs, and RS growing its consistent
set by adding one satellite's terms to the set's normal-equation sums instead of solving
the whole set again, every step of a run up to its next failure at once (running sums).
For the full Table 2 of seed 004 in under 60 s on two workers, RS also tests its random
draws lazily (the first few of every run; all of them only where none of those passes) and
forms its running sums by one array addition a step rather than ``np.cumsum`` (slow along
an axis this short): the same numbers, bit for bit.

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
    if total < 2**62:
        out = _unrank_combinations(n_sat, r, np.arange(count, dtype=np.int64) * step)
    else:  # beyond int64 ranks: walk the list (never met with real constellations)
        combos = itertools.islice(itertools.combinations(range(n_sat), r), 0,
                                  step * count, step)
        out = np.fromiter(itertools.chain.from_iterable(combos), dtype=np.intp,
                          count=count * r).reshape(count, r)
    out.flags.writeable = False
    return out


def _unrank_combinations(n: int, r: int, ranks: np.ndarray) -> np.ndarray:
    """The combinations of ``r`` out of ``range(n)`` at lexicographic ``ranks`` (the order
    of ``itertools.combinations``), ``(len(ranks), r)``: position by position, the
    candidate element advances while the rank is at least the number of combinations
    that start with it (the combinatorial number system). Walking the list instead costs
    C(n, r) steps: 77 million for 40 satellites of four systems (r = 8)."""
    binom = np.array([[math.comb(a, b) for b in range(r + 1)] for a in range(n + 1)],
                     dtype=np.int64)
    m = np.asarray(ranks, dtype=np.int64).copy()
    x = np.zeros(m.shape, dtype=np.int64)
    out = np.empty(m.shape + (r,), dtype=np.intp)
    for i in range(r):
        k = r - i - 1
        while True:
            c = binom[np.maximum(n - x - 1, 0), k]
            adv = m >= c
            if not adv.any():
                break
            m -= np.where(adv, c, 0)
            x += adv
        out[:, i] = x
        x += 1
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


def group_chi2(h, y, groups, p_fa: float, weights=None, *,
               reference: bool = False) -> GroupStats:
    """Least-squares residual chi-square of every group (seed 004 eqs. 5-7), batched.

    Parameters
    ----------
    h : (..., N, 3 + q) geometry rows ``[-u, clock one-hot]``.
    y : (..., N) measurement minus prediction at any linearisation point (m); a full-set
        post-fit residual is fine since ``(I - P_g) H_g x = 0``.
    groups : (G, r) satellite indices.
    p_fa : false-alarm probability of each group test.
    weights : (..., N) or scalar 1 / sigma^2 (1/m^2); default 1.
    reference : use the plain-numpy reference kernel (:func:`_chi2_members_reference`,
        slower; kept for the agreement tests and the benchmark) instead of the fast one.
        Both make the same decisions and agree to round-off (see :func:`_chi2_members`).

    Returns
    -------
    GroupStats with arrays of shape ``(..., G)``.
    """
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    member = membership_matrix(np.asarray(groups), y.shape[-1]).astype(float)
    kernel = _chi2_members_reference if reference else _chi2_members
    return kernel(h, y, member, p_fa, weights)


#: Largest number of group statistics (runs x groups) kept by :func:`_group_chi2_memo`
#: (a Monte Carlo chunk of 250 runs x 484 groups is 121,000; 2^18 of each array is 2 MB).
_MEMO_MAX = 1 << 18
_memo: tuple | None = None


def _same(a, b) -> bool:
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and a.dtype == b.dtype and np.array_equal(a, b)


def _group_chi2_memo(h, y, groups, p_fa: float, weights, member=None) -> GroupStats:
    """:func:`group_chi2`, remembering the last answer (``member``: the groups' float
    :func:`membership_matrix` if the caller has it, else built here).

    GF and QV test the same groups on the same runs (a Monte Carlo chunk runs both on the
    same ``h``, ``y``), so the second asks for exactly the statistics the first computed.
    The inputs are compared by value (a copy is kept), so a changed array is never served
    stale statistics; the arrays returned are read-only. Small batches only
    (:data:`_MEMO_MAX`), so a long recording is not held in memory.
    """
    global _memo
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    groups = np.asarray(groups)
    w = None if weights is None else np.asarray(weights, dtype=float)
    m = _memo
    if (m is not None and m[3] == p_fa and _same(m[0], h) and _same(m[1], y)
            and _same(m[2], groups) and _same(m[4], w)):
        return m[5]
    if member is None:
        member = membership_matrix(groups, y.shape[-1]).astype(float)
    stats = _chi2_members(h, y, member, p_fa, w)
    if stats.theta.size <= _MEMO_MAX:
        for v in vars(stats).values():
            v.flags.writeable = False
        _memo = (h.copy(), y.copy(), groups.copy(), p_fa, None if w is None else w.copy(),
                 stats)
    return stats


def _chi2_members(h, y, member, p_fa, weights=None) -> GroupStats:
    """group_chi2 for groups given as a 0/1 membership matrix ``(G, N)`` or ``(..., G, N)``.

    Normal equations by sums over members: every satellite contributes ``w h h^T``,
    ``w h y`` and ``w y^2`` (:func:`_features`); one matrix product with the membership
    matrix gives every group's sums at once (:func:`_member_sums`). The clock columns are
    one-hot, so the clock block of the normal matrix is diagonal (satellite count per
    system) and is eliminated in closed form (Schur complement); the remaining 3 x 3
    position block is inverted by its adjugate (:func:`_solve_sums`). All of it is
    element-wise arithmetic on cache-sized blocks of the ``(..., G)`` arrays: no per-group
    solve, no large temporaries. Agrees with :func:`_chi2_members_reference` to round-off.
    """
    h = np.asarray(h, dtype=float)
    y = np.asarray(y, dtype=float)
    member = np.asarray(member, dtype=float)
    q = h.shape[-1] - 3
    batch = np.broadcast_shapes(h.shape[:-1], y.shape)
    y = np.broadcast_to(y, batch)
    w = (np.ones(batch) if weights is None
         else np.broadcast_to(np.asarray(weights, dtype=float), batch))
    sums = _member_sums(_features(h, y, w), member)  # (F, ..., G)
    shape = sums.shape[1:]
    theta, pdop, regular, n_sys = (v.reshape(shape) for v in
                                   _solve_sums(sums.reshape(len(sums), -1), q))
    dof = np.rint(np.sum(member, axis=-1)).astype(int) - 3 - n_sys  # spec 4: r - 3 - q_g
    ok = regular & (dof >= 1) & np.isfinite(pdop) & (pdop < PDOP_MAX) & (pdop > 0)
    theta = np.where(ok, np.maximum(theta, 0.0), np.nan)
    return GroupStats(theta, dof, _thresholds(dof, p_fa), np.where(ok, pdop, np.inf), ok)


def _thresholds(dof, p_fa):
    """T = chi2.isf(p_fa, max(dof, 1)) (eq. 7), one scipy call per dof value."""
    dof_safe = np.maximum(dof, 1)
    if dof_safe.size == 0:
        return np.zeros(dof_safe.shape)
    table = special.chdtri(np.arange(1, int(dof_safe.max()) + 1), p_fa)
    return table[dof_safe - 1]


#: Index pairs (i <= j) of the symmetric 3 x 3 position block of the normal matrix.
_IU = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))

#: Elements of the (..., G) arrays handled at once by the closed-form solve: about 40 of
#: them stay in a core's L2 cache (8192 x 8 B = 64 kB each) instead of streaming the whole
#: batch through memory once per arithmetic operation.
_BLOCK = 8192

#: Most rows of one product of :func:`_matmul_rows`.
_TILE_ROWS = 96


def _features(h, y, w):
    """Per-satellite terms of the normal equations, ``(F, ..., N)``, ``F = 10 + 5 q``.

    Rows: the 6 upper-triangle products ``w u_i u_j``; for each system k the 3 ``w c_k u_j``
    and then the q ``w c_k``; the ``3 + q`` of ``w h y``; ``w y^2``.
    """
    n = h.shape[-1]
    q = n - 3
    ht = np.moveaxis(h, -1, 0)  # (n, ..., N) view
    hw = ht * w
    f = np.empty((10 + 5 * q,) + y.shape)
    for k, (i, j) in enumerate(_IU):
        np.multiply(hw[i], ht[j], out=f[k])
    for c in range(q):
        for j in range(3):
            np.multiply(hw[3 + c], ht[j], out=f[6 + 3 * c + j])
    f[6 + 3 * q:6 + 4 * q] = hw[3:]
    np.multiply(hw, y, out=f[6 + 4 * q:9 + 5 * q])
    np.multiply(w * y, y, out=f[9 + 5 * q])
    return f


def _matmul_rows(a, b):
    """``a (..., K) @ b (K, P)`` in tiles small enough that BLAS keeps each product on one
    thread (OpenBLAS threads a product once ``m n k`` exceeds about 2^18).

    Threads do not pay on products this thin (K and P are tens to hundreds), and in a
    process pool of one worker per core their spin-waiting takes the other workers' cores:
    unblocked, the two products of :func:`fuse` took a third of a Monte Carlo chunk's CPU
    time. A tile is up to :data:`_TILE_ROWS` rows of ``a`` by as many columns of ``b`` as
    keep ``m n k`` under that bound: BLAS packs both operands of every product, and blocks
    of a few rows by all ``P`` columns (``b`` packed again for every handful of rows) spent
    more time packing than multiplying.
    """
    k, p = b.shape
    flat = np.ascontiguousarray(a).reshape(-1, k)
    m = flat.shape[0]
    out = np.empty((m, p))
    per_product = max(1, (1 << 18) // max(k, 1))  # output elements of one product
    rows = max(1, min(m, _TILE_ROWS, per_product))
    cols = max(1, per_product // rows)
    for i in range(0, m, rows):
        for j in range(0, p, cols):
            np.matmul(flat[i:i + rows], b[:, j:j + cols], out=out[i:i + rows, j:j + cols])
    return out.reshape(a.shape[:-1] + (p,))


def _member_sums(f, member):
    """Every group's normal-equation sums ``(F, ..., G)`` from the features ``(F, ..., N)``.

    ``member`` is ``(G, N)``, shared by the batch: one matrix product (:func:`_matmul_rows`),
    or ``(..., G, N)``, one small product per run.
    """
    if member.ndim == 2:
        return _matmul_rows(f, member.T)
    sums = np.matmul(np.moveaxis(f, 0, -2), np.swapaxes(member, -1, -2))  # (..., F, G)
    return np.ascontiguousarray(np.moveaxis(sums, -2, 0))


def _solve_sums(s, q):
    """Closed-form group solve from normal-equation sums ``s`` ``(F, M)`` (contiguous rows).

    Eliminates the diagonal clock block (Schur complement) and inverts the 3 x 3 position
    block by its adjugate. Returns ``theta, pdop, regular, n_sys`` each ``(M,)`` (theta not
    yet clamped, pdop possibly non-finite).
    """
    m = s.shape[1]
    theta = np.empty(m)
    pdop = np.empty(m)
    regular = np.empty(m, dtype=bool)
    n_sys = np.zeros(m, dtype=np.int64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for lo in range(0, m, _BLOCK):
            sl = slice(lo, lo + _BLOCK)
            blk = s[:, sl]
            # Position block and right-hand side, then their Schur complements (the first
            # clock's update makes new arrays, the next ones work in place).
            a = list(blk[:6])
            gp = list(blk[6 + 4 * q:9 + 4 * q])
            th = blk[9 + 5 * q]
            for c in range(q):
                d = blk[6 + 3 * q + c]
                present = d > 0.0
                n_sys[sl] += present
                dinv = np.divide(1.0, d, out=np.zeros_like(d), where=present)
                b = blk[6 + 3 * c:9 + 3 * c]
                gc = blk[9 + 4 * q + c]
                bd = b * dinv
                for k, (i, j) in enumerate(_IU):
                    if c:
                        a[k] -= bd[i] * b[j]
                    else:
                        a[k] = a[k] - bd[i] * b[j]
                for i in range(3):
                    if c:
                        gp[i] -= bd[i] * gc
                    else:
                        gp[i] = gp[i] - bd[i] * gc
                th = th - dinv * gc * gc
            a00, a01, a02, a11, a12, a22 = a
            c00 = a11 * a22 - a12 * a12
            c01 = a02 * a12 - a01 * a22
            c02 = a01 * a12 - a02 * a11
            c11 = a00 * a22 - a02 * a02
            c12 = a01 * a02 - a00 * a12
            c22 = a00 * a11 - a01 * a01
            det = a00 * c00 + a01 * c01 + a02 * c02
            g0, g1, g2 = gp
            quad = (c00 * g0 * g0 + c11 * g1 * g1 + c22 * g2 * g2
                    + 2.0 * (c01 * g0 * g1 + c02 * g0 * g2 + c12 * g1 * g2))
            np.subtract(th, quad / det, out=theta[sl])
            np.sqrt((c00 + c11 + c22) / det, out=pdop[sl])
            regular[sl] = np.isfinite(det) & (det > 1e-12 * np.abs(a00 * a11 * a22))
    return theta, pdop, regular, n_sys


def _chi2_members_reference(h, y, member, p_fa, weights=None) -> GroupStats:
    """The plain-numpy reference of :func:`_chi2_members` (the kernel before issue 17).

    Kept for the agreement tests and the benchmark. Groups given as a 0/1 membership
    matrix ``(G, N)`` or ``(..., G, N)``.

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
    values = _distinct(dof)
    for d in values:  # a handful of dof values: closed forms for 1 and 2
        sel = dof == d if len(values) > 1 else Ellipsis  # one value: no gather, no scatter
        x = theta[sel]
        t = float(special.chdtri(d, p_fa))
        cdf_t, sf_t = _chi2_cdf(np.array(t), int(d)), _chi2_sf(np.array(t), int(d))
        m_f = np.asarray(0.5 * _chi2_cdf(x, int(d)) / cdf_t)
        upper = ~(x <= t)  # and NaN; the survival function only where it is used
        if upper.any():
            m_f[upper] = 0.5 + 0.5 * (1.0 - _chi2_sf(x[upper], int(d)) / sf_t)
        out[sel] = m_f
    return out if out.ndim else float(out)


def _distinct(values) -> np.ndarray:
    """The distinct values of an array, sorted (a bincount for small integers)."""
    if values.size and values.dtype.kind in "iu":
        lo = int(values.min())
        if int(values.max()) - lo < 4096:
            return np.flatnonzero(np.bincount((values - lo).ravel())) + lo
    return np.unique(values)


def _chi2_cdf(x, dof: int):
    """chi2(dof) CDF, closed forms for 1 and 2 degrees of freedom."""
    if dof == 1:
        return special.erf(np.sqrt(0.5 * np.maximum(x, 0.0)))
    if dof == 2:
        return -np.expm1(-0.5 * x)
    return special.chdtr(dof, x)


def _chi2_sf(x, dof: int):
    """chi2(dof) survival function, computed directly (never 1 - CDF)."""
    if dof == 1:
        return special.erfc(np.sqrt(0.5 * np.maximum(x, 0.0)))
    if dof == 2:
        return np.exp(-0.5 * x)
    return special.chdtrc(dof, x)


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
    num = _matmul_rows(np.where(a > 0, a * m_f, 0.0), member)
    den = _matmul_rows(a, member)
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
               weights: str = "pdop", reference: bool = False) -> GFResult:
    """Group detection + evidence fusion + adaptive threshold (seed 004), batched.

    Parameters
    ----------
    h : (..., N, 3 + q) rows; y : (..., N) measurements (m); groups : (G, r) indices
        (see :func:`select_groups`); p_fa : per-group false-alarm probability.
    weights_lsq : (..., N) or scalar 1 / sigma^2 (1/m^2).
    margin : M of eq. 3 (paper 0.1 .. 0.2; spec default 0.1).
    weights : reliability p of a group, one of :data:`WEIGHTS`.
    reference : group statistics from the plain-numpy reference kernel (see
        :func:`group_chi2`); the default fast kernel makes the same decisions.

    Returns
    -------
    GFResult
    """
    _check_common(p_fa, margin, weights)
    member = membership_matrix(np.asarray(groups), np.shape(y)[-1]).astype(float)
    stats = (group_chi2(h, y, groups, p_fa, weights_lsq, reference=True) if reference
             else _group_chi2_memo(h, y, groups, p_fa, weights_lsq, member))
    m_f = basic_belief(stats.theta, stats.dof, p_fa)
    alpha = _alpha(stats, weights)
    fused = fuse(m_f, alpha, member)
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
    return _chi2_members_reference(h, y, member, p_fa, weights_lsq)


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
               n_draws: int = 50, size: int | None = None, reference: bool = False):
    """Random search (Chen & Zhang 2011, seed 004's ref. [5]), batched over runs.

    Reading (the paper gives no detail, spec 4 "under-specified"): draw ``n_draws`` random
    subsets of ``size`` (default ``r = 4 + q``) satellites per run, keeping only subsets with
    >= 2 satellites of each system (else an added satellite could be the only one of its
    system, and its residual would be zero); the first subset that passes the chi-square
    test is presumed fault-free (if none passes, the one with the smallest theta / T).
    The other satellites are then added one at a time in random order to the growing
    consistent set: a satellite whose addition makes the test fail is isolated (and left
    out), otherwise it joins the set.

    The chi-square of a set grown by one satellite comes from the set's normal-equation
    sums plus that satellite's terms (the closed-form solve of :func:`_chi2_members`), not
    from a new solve of the whole set; the steps up to a run's next failure are tested
    together (:func:`_grow_sets`). The draws are tested lazily: the first
    :data:`_RS_HEAD_DRAWS` of every run, and all of them only for the runs where none of
    those passes (all are drawn first, so the random numbers are those of testing all).

    Parameters
    ----------
    h : (B, N, 3 + q); y : (B, N); rng : random generator.
    weights_lsq : (B, N) or scalar 1 / sigma^2 (1/m^2); default 1.
    n_draws : random subsets drawn per run; size : satellites in each (default 4 + q).
    reference : run the pre-issue-17 path (each grown set solved again from scratch);
        same random draws, same decisions. For the agreement tests and the benchmark.

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
    if reference:
        return _rs_isolate_reference(h, y, p_fa, rng, weights_lsq, n_draws, size)
    q = h.shape[-1] - 3
    w = (np.ones_like(y) if weights_lsq is None
         else np.broadcast_to(np.asarray(weights_lsq, dtype=float), y.shape))
    keys = rng.random((b, n_draws, n))
    feats = _features(h, y, w)  # (F, B, N)
    clk = h[..., 3:]
    # The first few draws of every run (nearly every run has a passing one among them),
    # then every draw of the runs that have none (their first ones again, same results).
    ratio, member, sums = _test_draws(keys[:, :_RS_HEAD_DRAWS], feats, clk, size, q, p_fa)
    passing = ratio <= 1.0
    rows = np.arange(b)
    first = np.argmax(passing, axis=-1)
    consistent = member[rows, first] > 0.0
    set_sums = sums[:, rows, first]  # (F, B) of the consistent sets
    rest = np.flatnonzero(~passing.any(axis=-1))
    if rest.size:
        ratio, member, sums = _test_draws(keys[rest], feats[:, rest], clk[rest], size, q,
                                          p_fa)
        passing = ratio <= 1.0
        first = np.where(passing.any(axis=-1), np.argmax(passing, axis=-1),
                         np.argmin(ratio, axis=-1))
        consistent[rest] = member[np.arange(rest.size), first] > 0.0
        set_sums[:, rest] = sums[:, np.arange(rest.size), first]
    isolated = np.zeros((b, n), dtype=bool)
    order = np.argsort(np.where(consistent, np.inf, rng.random((b, n))), axis=-1)
    n_set = np.full(b, size)
    steps = n - size
    added = order[:, :steps]  # (B, steps) the satellite each step adds, per run
    step_feats = feats[:, rows[:, None], added]  # (F, B, steps)
    table = special.chdtri(np.arange(1, n + 1), p_fa)  # T by dof (eq. 7)
    isolated[rows[:, None], added] = _grow_sets(set_sums, n_set, step_feats, q, table)
    return isolated


#: Draws of every run RS tests first (:func:`rs_isolate`): one passes in nearly every run.
_RS_HEAD_DRAWS = 4


def _test_draws(keys, feats, clk, size, q, p_fa):
    """RS's random subsets of ``size`` satellites, those of the smallest ``keys (R, D, N)``,
    tested: ``theta / T`` ``(R, D)`` (inf where the subset is singular or has fewer than 2
    satellites of a system present), the membership ``(R, D, N)`` and the normal-equation
    sums ``(F, R, D)``. ``feats (F, R, N)``: :func:`_features`; ``clk (R, N, q)``."""
    r, d, _ = keys.shape
    member = (keys <= np.partition(keys, size - 1, axis=-1)[..., size - 1:size]).astype(float)
    sums = _member_sums(feats, member)  # (F, R, D)
    theta, pdop, regular, n_sys = (v.reshape(r, d) for v in
                                   _solve_sums(sums.reshape(len(sums), -1), q))
    dof = size - 3 - n_sys
    ok = regular & (dof >= 1) & np.isfinite(pdop) & (pdop < PDOP_MAX) & (pdop > 0)
    # >= 2 satellites of every system present in the run (see rs_isolate).
    count = member @ clk  # (R, D, q)
    present = clk.sum(axis=-2) > 0
    sys_ok = np.all((count >= 2) | ~present[:, None, :], axis=-1)
    ratio = np.where(ok & sys_ok, np.maximum(theta, 0.0) / _thresholds(dof, p_fa), np.inf)
    return ratio, member, sums


def _grow_sets(set_sums, n_set, step_feats, q, table):
    """RS's growing of the consistent sets: which added satellites fail, ``(B, S)`` bool.

    Parameters
    ----------
    set_sums : (F, B) normal-equation sums of each run's consistent set (modified).
    n_set : (B,) its number of satellites.
    step_feats : (F, B, S) the terms (:func:`_features`) of the satellite step s adds.
    q : number of clocks; table : chi-square thresholds by dof (``table[dof - 1]``).

    Step s tests the set plus its satellite; the satellite joins unless the test fails.
    Until a satellite fails, the sums of each step's trial are the running sums of the set
    and the satellites so far, a cumulative sum (the same additions in the same order as
    one step at a time), so every remaining step of every run is tested at once; a run
    with a failure takes up again after the first one, from the sums before it. At most a
    pass per failure of the run with the most, plus one (fault-free runs: one pass).
    """
    f_n, b, steps = step_feats.shape
    fails = np.zeros((b, steps), dtype=bool)
    start = np.zeros(b, dtype=np.intp)  # each run's first step not decided yet
    n_set = np.array(n_set)
    runs = np.arange(b)
    while runs.size and steps:
        pos = np.arange(steps - start[runs].min())
        step = start[runs, None] + pos  # (R, L); past a run's last step: padding
        valid = step < steps
        # (F, L + 1, R): the set's sums, then each step's terms, made running sums by
        # one addition a step (np.cumsum along an axis is much slower on arrays this thin)
        running = np.empty((f_n, pos.size + 1, runs.size))
        running[:, 0] = set_sums[:, runs]
        running[:, 1:] = step_feats[:, runs[None, :], np.minimum(step, steps - 1).T]
        for s in range(1, pos.size + 1):  # running[:, l + 1]: the trial of step l
            np.add(running[:, s - 1], running[:, s], out=running[:, s])
        stat, _, regular, n_sys = (v.reshape(step.shape[::-1]).T for v in _solve_sums(
            running[:, 1:].reshape(f_n, -1), q))
        dof = n_set[runs, None] + pos + 1 - 3 - n_sys  # (clipped: padding goes beyond)
        fail = valid & regular & (stat > table[np.clip(dof, 1, len(table)) - 1])
        hit = fail.any(axis=-1)
        first = np.argmax(fail, axis=-1)[hit]  # the first failing step of a run, if any
        again = runs[hit]
        fails[again, start[again] + first] = True
        set_sums[:, again] = running[:, first, np.flatnonzero(hit)]  # the sums before it
        n_set[again] += first
        start[again] += first + 1
        runs = again[start[again] < steps]
    return fails


def _rs_isolate_reference(h, y, p_fa, rng, weights_lsq, n_draws, size):
    """:func:`rs_isolate` as it was before issue 17: every test of a growing set solved
    again from scratch (``_masked_chi2``). Reference for the agreement tests."""
    b, n = y.shape
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
               norm: str = "share", reference: bool = False):
    """Quality value / confidence index (Patino-Studencka et al. 2010, seed 004's ref. [6]).

    Reading (spec 4): test the same groups as GF; only failing groups give their members a
    confidence index (1 per failing group), summed per satellite. To give the mean + M rule
    of eq. 3 a scale, the sums are normalised: ``norm="share"`` (default) divides by the number of
    groups the satellite is in (the share of its groups that fail), ``norm="max"`` by the
    largest sum of the run (much worse: 24% vs 84% for N = 18, one fault at 1.5 P_bias).
    Isolate with mean + M. ``reference`` as in :func:`gf_isolate`.

    Returns ``(isolated (..., N) bool, score (..., N), threshold (...))``.
    """
    check_probability("p_fa", p_fa)
    check_range("margin", margin, 0.0, 1.0)
    member = membership_matrix(np.asarray(groups), np.shape(y)[-1]).astype(float)
    st = (group_chi2(h, y, groups, p_fa, weights_lsq, reference=True) if reference
          else _group_chi2_memo(h, y, groups, p_fa, weights_lsq, member))
    fail = np.where(st.ok, (st.theta > st.threshold).astype(float), 0.0)
    check_choice("norm", norm, ("max", "share"))
    if norm == "share":
        score = fuse(fail, st.ok.astype(float), member)
    else:
        total = fail @ member
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
