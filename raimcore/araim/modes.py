"""Fault probabilities and the fault modes to monitor (ARAIM.md sections 3-4).

A fault-mode list depends on the satellites in view (their constellation and prior
probabilities) and the constellation priors, never on the geometry, so
:func:`raimcore.araim.mhss` determines it once per visibility pattern. Pure Python and
small numpy arrays; nothing here is batched.

Events are the satellites ``0..n-1`` (G row order) then the constellations ``0..c-1``
(column order), independent, with probabilities ``p``; ``q = p / (1 - p)``,
``P0 = prod(1 - p)``, and exactly the event set ``E`` occurs with probability
``P0 prod_{e in E} q_e`` (section 3).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ModeList", "p_at_least", "determine_modes", "restrict_modes", "mode_keys"]


@dataclass(frozen=True)
class ModeList:
    """Fault modes of one visibility pattern. Row 0 is the fault-free mode.

    Attributes
    ----------
    removed : (K, n) bool -- satellites each mode removes (``R_k``).
    consts : (K, c) bool -- constellation events of the mode's (first) event set.
    p_inst, p_exp : (K,) -- prior of the mode, instantaneous and over the exposure
        (merged modes: the sums; fault-free: 1 and ``P0_exp``).
    p_nm : float -- ``P_not_monitored`` of the determination (section 4 steps 5-6, or the
        B2012 formula), before subsets that cannot be monitored are dropped.
    n_max : tuple -- ``(N_max,)`` (ADD) or ``(N_sat,max, N_const,max)`` (B2012).
    """

    removed: np.ndarray
    consts: np.ndarray
    p_inst: np.ndarray
    p_exp: np.ndarray
    p_nm: float
    n_max: tuple

    def __len__(self) -> int:
        return len(self.p_inst)


def p_at_least(p, r: int) -> float:
    """Probability that ``r`` or more of the independent events ``p`` occur.

    Exact for ``r <= 3`` (q-sums), the bound ``(sum p)^r / r!`` for ``r >= 4``
    (``compute_p_not_monitored.m``; ARAIM.md section 3). ``r <= 0`` gives 1.
    """
    p = np.asarray(p, dtype=float)
    if r <= 0:
        return 1.0
    if r >= 4:
        return float(np.sum(p)) ** r / math.factorial(r)
    q = p / (1.0 - p)
    p0 = float(np.prod(1.0 - p))
    s1 = float(np.sum(q))
    if r == 1:
        return 1.0 - p0
    if r == 2:
        return 1.0 - p0 * (1.0 + s1)
    s2 = float(np.sum(q * q))
    return 1.0 - p0 * (1.0 + s1 + 0.5 * (s1 * s1 - s2))


def _n_max(p, p_thres: float) -> int:
    """``(smallest r >= 1 with P(>= r) <= p_thres) - 1``, r at most ``len(p) + 1``
    (``determine_nmax.m``)."""
    n = len(p)
    r, pnm = 0, 1.0
    while pnm > p_thres and r < n + 1:
        r += 1
        pnm = p_at_least(p, r)
    return r - 1


def _combos(n_events: int, sizes) -> list[np.ndarray]:
    """Index arrays (C_r, r) of every event set of each size, lexicographic."""
    out = []
    for r in sizes:
        if 1 <= r <= n_events:
            out.append(np.array(list(itertools.combinations(range(n_events), r)),
                                dtype=int).reshape(-1, r))
    return out


#: Removed sets of at most this many satellites are merged through one integer key per
#: mode (a bit per satellite) instead of a row-wise ``np.unique``; same groups, same order.
_KEY_BITS = 62


def mode_keys(removed):
    """(K,) int64: bit ``i`` of row ``k`` set where mode ``k`` removes satellite ``i``
    (equal keys, equal removed sets), or None where ``n > 62``."""
    k, n = removed.shape
    if n > _KEY_BITS:
        return None
    bits = np.int64(1) << np.arange(n, dtype=np.int64)
    return np.bitwise_or.reduce(np.where(removed, bits, np.int64(0)), axis=1,
                                initial=np.int64(0))


def _row_groups(removed, reference: bool = False, keys=None):
    """``first`` and ``inverse`` of ``np.unique(removed, axis=0)`` (bool ``(K, n)``),
    through 64-bit keys (:func:`mode_keys`, or ``keys`` if given) when ``n <= 62``
    (``reference``: always row-wise)."""
    k, n = removed.shape
    if keys is None and not reference:
        keys = mode_keys(removed)
    if reference or keys is None or k == 0:
        _, first, inverse = np.unique(removed, axis=0, return_index=True,
                                      return_inverse=True)
        return first, inverse.reshape(-1)
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return first, inverse.reshape(-1)


def _merge(removed, consts, p_inst, p_exp, reference: bool = False, keys=None):
    """Merge modes with identical removed sets: keep the first, sum the probabilities
    (``find_unique_subsets.m``, section 4 step 7). ``keys``: the rows' :func:`mode_keys`
    if the caller has them. The sums add the members in row order (``np.add.at``, or
    ``np.bincount``, which adds in the same order)."""
    first, inverse = _row_groups(removed, reference, keys)
    order = np.argsort(first, kind="stable")  # unique rows in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    grp = rank[inverse]
    k = len(order)
    if reference:
        pi = np.zeros(k)
        pe = np.zeros(k)
        np.add.at(pi, grp, p_inst)
        np.add.at(pe, grp, p_exp)
    else:
        pi = np.bincount(grp, weights=p_inst, minlength=k)
        pe = np.bincount(grp, weights=p_exp, minlength=k)
    keep = first[order]
    return removed[keep], consts[keep], pi, pe


def determine_modes(cons, p_sat, p_const, *, rules: str = "add-v4.2", tau_sat=None,
                    tau_const=None, p_thres: float = 8e-8, p_thres_sat: float = 4e-8,
                    p_thres_const: float = 4e-8, fc_thres: float = 0.01,
                    phmi: float = 1e-7, fde: bool = False,
                    p_exc_thres: float = 1.0, reference: bool = False) -> ModeList:
    """The fault modes to monitor for one set of satellites in view.

    Parameters
    ----------
    cons : (n,) int -- constellation of each satellite, in ``[0, c)``; every constellation
        has at least one satellite.
    p_sat : (n,); p_const : (c,) -- instantaneous priors, in [0, 1).
    rules : ``"add-v4.2"`` (section 4 baseline, ``determine_subsets_v5.m``) or
        ``"blanch-2012"`` (section 4, B2012 rule).
    tau_sat, tau_const : exposure ``T_exp / MFD`` (ADD; default 0): ``p_exp = p (1 + tau)``.
    phmi : total integrity budget (``PHMI_VERT + PHMI_HOR``); modes above it are
        monitored whatever ``P_nm`` (step 5).
    fde, p_exc_thres : with exclusion, modes sharing no satellite with some exclusion
        option (a mode with ``p_inst > p_exc_thres``) are not taken in step 6.
    reference : merge identical removed sets row by row (the plain reference path of
        the agreement tests) rather than through integer keys; same result.

    Returns
    -------
    ModeList
    """
    cons = np.asarray(cons, dtype=int)
    p_sat = np.asarray(p_sat, dtype=float)
    p_const = np.asarray(p_const, dtype=float)
    n, c = len(cons), len(p_const)
    member = cons[None, :] == np.arange(c)[:, None]  # (c, n)
    # Incidence event -> satellites it removes.
    inc = np.concatenate([np.eye(n, dtype=bool), member], axis=0)  # (n + c, n)
    if rules == "blanch-2012":
        return _determine_b2012(n, c, member, p_sat, p_const, p_thres_sat, p_thres_const,
                                reference)
    tau_sat = np.zeros(n) if tau_sat is None else np.broadcast_to(tau_sat, (n,))
    tau_const = np.zeros(c) if tau_const is None else np.broadcast_to(tau_const, (c,))
    p_inst_e = np.concatenate([p_sat, p_const])
    p_exp_e = p_inst_e * (1.0 + np.concatenate([tau_sat, tau_const]))
    n_e = n + c
    p0_inst = float(np.prod(1.0 - p_inst_e))
    p0_exp = float(np.prod(1.0 - p_exp_e))
    q_inst = p_inst_e / (1.0 - p_inst_e)
    q_exp = p_exp_e / (1.0 - p_exp_e)

    # Step 1: the largest event set to enumerate (determine_nmax.m), at least 2.
    n_max = min(max(_n_max(p_exp_e, p_thres), 2), n_e)
    # Step 2: every event set of 1..N_max events, by size then lexicographic.
    rem, cst, pin, pex = [], [], [], []
    for comb in _combos(n_e, range(1, n_max + 1)):
        rem.append(inc[comb].any(axis=1))
        ev = np.zeros((len(comb), n_e), dtype=bool)
        np.put_along_axis(ev, comb, True, axis=1)
        cst.append(ev[:, n:])
        pin.append(p0_inst * np.prod(q_inst[comb], axis=1))
        pex.append(p0_exp * np.prod(q_exp[comb], axis=1))
    removed = np.concatenate(rem) if rem else np.zeros((0, n), bool)
    consts = np.concatenate(cst) if cst else np.zeros((0, c), bool)
    p_inst = np.concatenate(pin) if pin else np.zeros(0)
    p_exp = np.concatenate(pex) if pex else np.zeros(0)
    size = removed.sum(axis=1)

    # Step 3: consolidation into constellation modes (the single event {const j} is the
    # row n + j of the size-1 block, which comes first).
    alive = np.ones(len(p_inst), dtype=bool)
    for j in range(c):
        cj = n + j
        limit = fc_thres * p_inst[cj]  # value before this step
        inside = (size > 0) & ~np.any(removed & ~member[j], axis=1)
        gone = alive & inside & (p_inst < limit)
        gone[cj] = False
        p_inst[cj] += p_inst[gone].sum()
        p_exp[cj] += p_exp[gone].sum()
        alive &= ~gone
    removed, consts = removed[alive], consts[alive]
    p_inst, p_exp, size = p_inst[alive], p_exp[alive], size[alive]

    # Fault-free first, then step 4: stable sort by the number of satellites removed.
    removed = np.concatenate([np.zeros((1, n), bool), removed])
    consts = np.concatenate([np.zeros((1, c), bool), consts])
    p_inst = np.concatenate([[1.0], p_inst])
    p_exp = np.concatenate([[p0_exp], p_exp])
    size = np.concatenate([[0], size])
    order = np.argsort(size, kind="stable")
    removed, consts, p_inst, p_exp = removed[order], consts[order], p_inst[order], p_exp[order]

    # Step 5: every mode above the integrity budget is monitored (fault-free always).
    large = p_exp > phmi
    large[0] = True
    p_nm = 1.0 - float(p_exp[large].sum())
    # Step 6: walk the others in sorted order while P_nm > P_THRES.
    skip = np.zeros(len(p_exp), dtype=bool)
    if fde and p_exc_thres < 1.0:
        options = ~removed[p_inst > p_exc_thres]  # kept satellites of exclusion options
        if len(options):
            shared = (~removed).astype(int) @ options.T.astype(int)  # (K, n_options)
            skip = np.min(shared, axis=1) == 0
    taken = []
    for k in np.flatnonzero(~large):
        if p_nm <= p_thres:
            break
        if p_exp[k] <= 0.0 or skip[k]:
            continue
        taken.append(k)
        p_nm -= float(p_exp[k])
    sel = np.concatenate([np.flatnonzero(large), np.array(taken, dtype=int)])
    # Step 7: merge identical removed sets.
    removed, consts, p_inst, p_exp = _merge(removed[sel], consts[sel], p_inst[sel], p_exp[sel],
                                            reference)
    return ModeList(removed, consts, p_inst, p_exp, max(p_nm, 0.0), (n_max,))


def _determine_b2012(n, c, member, p_sat, p_const, p_thres_sat, p_thres_const,
                     reference=False):
    """B2012 rule: satellite sets and constellation sets apart, no mixed sets, no
    consolidation, ``P_nm`` = exact tails of each (ARAIM.md section 4)."""
    n_sat_max = min(_n_max(p_sat, p_thres_sat), n)
    n_const_max = min(_n_max(p_const, p_thres_const), c)
    rem, cst, prob = [np.zeros((1, n), bool)], [np.zeros((1, c), bool)], [np.ones(1)]
    for comb in _combos(n, range(1, n_sat_max + 1)):
        r = np.zeros((len(comb), n), dtype=bool)
        np.put_along_axis(r, comb, True, axis=1)
        rem.append(r)
        cst.append(np.zeros((len(comb), c), bool))
        prob.append(np.prod(p_sat[comb], axis=1))
    for comb in _combos(c, range(1, n_const_max + 1)):
        ev = np.zeros((len(comb), c), dtype=bool)
        np.put_along_axis(ev, comb, True, axis=1)
        rem.append((ev.astype(int) @ member.astype(int)) > 0)
        cst.append(ev)
        prob.append(np.prod(p_const[comb], axis=1))
    removed, consts, p = np.concatenate(rem), np.concatenate(cst), np.concatenate(prob)
    p_exp = p.copy()
    p_exp[0] = float(np.prod(1.0 - p_sat) * np.prod(1.0 - p_const))
    p_nm = (p_at_least(p_sat, n_sat_max + 1) + p_at_least(p_const, n_const_max + 1))
    removed, consts, p_inst, p_exp = _merge(removed, consts, p, p_exp, reference)
    return ModeList(removed, consts, p_inst, p_exp, p_nm, (n_sat_max, n_const_max))


def restrict_modes(modes: ModeList, keep, *, reference: bool = False,
                   keys=None) -> ModeList:
    """The mode list seen by an exclusion candidate that keeps the satellites ``keep``.

    Each mode's removed set is cut to the kept satellites (columns ``keep``); modes that
    then remove nothing merge into the fault-free row, identical ones merge (their
    probabilities add); ``p_nm`` is kept (ARAIM.md section 9, ``usr_vhpl_araim.m``; the
    kernel uses the all-in-view's final ``P_nm``, after unmonitorable modes are dropped).
    ``reference``: merge row by row (see :func:`determine_modes`). ``keys``: the
    :func:`mode_keys` of ``modes.removed``, for a caller restricting one list many times
    (the cut sets' keys are then ``keys & mask``, not recomputed).
    """
    keep = np.asarray(keep, dtype=bool)
    removed = modes.removed[:, keep]
    cut = None
    if keys is not None and not reference:
        cut = keys & (np.int64(1) << np.flatnonzero(keep).astype(np.int64)).sum()
    r, cst, pi, pe = _merge(removed, modes.consts, modes.p_inst, modes.p_exp, reference,
                            cut)
    return ModeList(r, cst, pi, pe, modes.p_nm, modes.n_max)
