"""The public ARAIM kernel :func:`mhss` and its result classes.

See the package docstring (:mod:`raimcore.araim`) for the inputs, keywords, result
attributes and the batching design; ARAIM.md sections 3-9 for the rules.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from .._validate import check_array, check_batch
from . import _kernel_reference, _params
from .kernel import evaluate, pl_bisect
from .modes import ModeList, determine_modes, mode_keys, restrict_modes

__all__ = ["mhss", "MhssResult", "FaultModes"]

#: Constellations with a prior above this are exclusion candidates (``usr_vhpl_araim.m``).
FDE_CONST_P_MIN = 1e-7
#: Epochs whose key rows are built at once when grouping (memory bound, not a result).
_KEY_CHUNK = 32768
#: Bound on the elements of one (epochs x modes x 3 x satellites) working array (64 MB):
#: larger chunks mean fewer calls and less per-call overhead (four-system recording, 2 h:
#: 4M 3.50 s, 8M 3.14 s, 16M 3.02 s), at the price of the peak memory.
_WORK_ELEMENTS = 8_000_000
_REASONS = np.array(["", "too_few_satellites", "singular_geometry"])


@dataclass(frozen=True)
class FaultModes:
    """The monitored fault modes of every epoch, padded to ``K`` (index 0 fault-free).

    Shapes: batch ``B`` then ``(K, ...)``; padding rows have ``valid`` False, ``sats``
    False, probabilities 0 and NaN statistics.

    Attributes
    ----------
    sats : B + (K, n_sat) bool -- satellites the mode removes (``R_k``), original order.
    consts : B + (K, n_const) bool -- constellation events of the mode's event set.
    p_inst, p_exp : B + (K,) -- prior probabilities (merged modes: summed).
    threshold_m : B + (K, 3) -- ``T_k,q`` (E, N, U); inf where not monitorable.
    sigma_m, bias_m : B + (K, 3) -- ``sigma_q^(k)``, ``b_q^(k)``.
    sigma_ss_m, bias_ss_m : B + (K, 3) -- separation sigma and bias.
    valid : B + (K,) bool -- a real mode (not padding).
    monitored : B + (K,) bool -- valid and monitorable: it enters the protection level.
    separation_m : B + (K, 3) -- ``((S^(k) - S^(0)) y)_q`` (None without ``y``).
    """

    sats: np.ndarray
    consts: np.ndarray
    p_inst: np.ndarray
    p_exp: np.ndarray
    threshold_m: np.ndarray
    sigma_m: np.ndarray
    bias_m: np.ndarray
    sigma_ss_m: np.ndarray
    bias_ss_m: np.ndarray
    valid: np.ndarray
    monitored: np.ndarray
    separation_m: np.ndarray | None


@dataclass(frozen=True)
class MhssResult:
    """ARAIM MHSS outputs for a batch; every array has the batch shape ``B`` first.

    Attributes are documented in :mod:`raimcore.araim` (package docstring): protection
    levels ``hpl_m``, ``vpl_m``, ``hpl1_m``, ``hpl2_m``, ``emt_m``, ``sigma_acc_v_m``,
    ``acc95_v_m``, ``ff_v_m``; ``status`` (``"ok"``/``"unavailable"``) and ``reason``;
    ``n_sats``, ``n_modes``, ``p_not_monitored``, ``k_fa`` (B + (3,)),
    ``phmi_vert_alloc``, ``phmi_hor_alloc``, ``rho``, ``sigma_m``, ``bias_m``; ``modes``
    (:class:`FaultModes` or None); with ``y``: ``dx_enu_m``, ``alarm``, ``alarm_mode``,
    ``test_ratio``; with ``y`` and ``fde``: ``excluded_sat``, ``excluded_const``,
    ``dx_excluded_enu_m``; ``rules`` and ``params``; with ``fde``: ``vpl_set_by``,
    ``hpl_set_by`` (B int: the exclusion candidate whose evaluation gave the VPL / HPL,
    as an event index, satellite ``i`` or ``n_sat + j`` for constellation ``j``; -1 the
    all-in-view), which say why a PL is infinite when the all-in-view one is not.
    """

    hpl_m: np.ndarray
    vpl_m: np.ndarray
    emt_m: np.ndarray
    sigma_acc_v_m: np.ndarray
    hpl1_m: np.ndarray
    hpl2_m: np.ndarray
    acc95_v_m: np.ndarray
    ff_v_m: np.ndarray
    status: np.ndarray
    reason: np.ndarray
    n_sats: np.ndarray
    n_modes: np.ndarray
    p_not_monitored: np.ndarray
    k_fa: np.ndarray
    phmi_vert_alloc: np.ndarray
    phmi_hor_alloc: np.ndarray
    rho: np.ndarray
    sigma_m: np.ndarray
    bias_m: np.ndarray
    modes: FaultModes | None
    dx_enu_m: np.ndarray | None
    alarm: np.ndarray | None
    alarm_mode: np.ndarray | None
    test_ratio: np.ndarray | None
    excluded_sat: np.ndarray | None
    excluded_const: np.ndarray | None
    dx_excluded_enu_m: np.ndarray | None
    rules: str
    params: MappingProxyType
    vpl_set_by: np.ndarray | None = None
    hpl_set_by: np.ndarray | None = None

    @property
    def available(self) -> np.ndarray:
        """``status == "ok"`` (PLs computed; LPV-200 availability also needs the limits)."""
        return self.status == "ok"


# --------------------------------------------------------------------------- inputs


@dataclass
class _Inputs:
    batch: tuple
    g: np.ndarray  # (E, S, 3 + C)
    s_int: np.ndarray  # (E, S)
    s_acc: np.ndarray
    b_int: np.ndarray
    b_acc: np.ndarray
    p_sat: np.ndarray
    p_const: np.ndarray  # (E, C)
    tau_sat: np.ndarray
    tau_const: np.ndarray
    y: np.ndarray | None
    visible: np.ndarray  # (E, S) bool
    cons: np.ndarray  # (E, S) int, constellation of each satellite (-1 not in view)
    present: np.ndarray  # (E, C) bool
    raw: dict  # p_sat, tau_sat, p_const, tau_const as given (before broadcasting)


def _bad(name: str, what: str):
    raise ValueError(f"{name} must be {what} for every satellite in view")


def _check_inputs(G, s_int, s_acc, b_int, b_acc, p_sat, p_const, prm) -> _Inputs:
    g = check_array("G", G, ndim_min=2, last=("n_sat", "3 + n_const"), finite=False)
    n_sat, n_col = g.shape[-2:]
    if n_col < 4:
        raise ValueError(f"G must have 3 + n_const >= 4 columns, got {n_col}")
    n_const = n_col - 3
    match = f"G (..., {n_sat}, {n_col})"
    per_sat = {}
    for name, v in (("sigma_int_m", s_int), ("sigma_acc_m", s_acc), ("b_int_m", b_int),
                    ("b_acc_m", b_acc), ("p_sat", p_sat)):
        per_sat[name] = check_array(name, v, last=(n_sat,), finite=False, match=match)
    pc = check_array("p_const", p_const, last=(n_const,), finite=False, match=match)
    opt_sat = {}
    if prm.get("y") is not None:
        opt_sat["y"] = check_array("y", prm["y"], last=(n_sat,), finite=False, match=match)
    if prm.get("used") is not None:
        u = np.asarray(prm["used"])
        if u.dtype.kind != "b":
            raise ValueError(f"used must be a boolean array, got dtype {u.dtype}")
        if u.ndim < 1 or u.shape[-1] != n_sat:
            raise ValueError(f"used must have shape (..., {n_sat}) to match {match}, "
                             f"got {u.shape}")
        opt_sat["used"] = u
    tau = prm.get("t_exp_over_mfd", 0.0) or 0.0
    tau_s = prm.get("tau_sat")
    tau_c = prm.get("tau_const")
    tau_s = (np.full(n_sat, tau) if tau_s is None else
             check_array("tau_sat", tau_s, last=(n_sat,), finite=False, match=match))
    tau_c = (np.full(n_const, tau) if tau_c is None else
             check_array("tau_const", tau_c, last=(n_const,), finite=False, match=match))
    shapes = {"G": g.shape[:-2]}
    shapes.update({k: v.shape[:-1] for k, v in per_sat.items()})
    shapes["p_const"] = pc.shape[:-1]
    shapes.update({k: v.shape[:-1] for k, v in opt_sat.items()})
    shapes["tau_sat"], shapes["tau_const"] = tau_s.shape[:-1], tau_c.shape[:-1]
    batch = check_batch(shapes)
    e = int(np.prod(batch, dtype=int))

    def flat(a, tail):
        return np.broadcast_to(a, batch + tail).reshape((e,) + tail)

    raw = {"p_sat": per_sat["p_sat"], "tau_sat": tau_s, "p_const": pc, "tau_const": tau_c}
    g = flat(g, (n_sat, n_col))
    arr = {k: flat(v, (n_sat,)) for k, v in per_sat.items()}
    pc = flat(pc, (n_const,))
    tau_s, tau_c = flat(tau_s, (n_sat,)), flat(tau_c, (n_const,))
    used = flat(opt_sat["used"], (n_sat,)) if "used" in opt_sat else True
    y = flat(opt_sat["y"], (n_sat,)) if "y" in opt_sat else None

    vis0 = np.all(np.isfinite(g), axis=-1) & used
    ps = arr["p_sat"]
    with np.errstate(invalid="ignore"):
        if np.any(vis0 & ~((ps >= 0.0) & (ps <= 1.0))):
            _bad("p_sat", "a probability in [0, 1]")
        visible = vis0 & (ps < 1.0)  # p_sat = 1: not used (MAAST)
        checks = (("sigma_int_m", arr["sigma_int_m"] > 0.0, "finite and > 0"),
                  ("sigma_acc_m", arr["sigma_acc_m"] >= 0.0, "finite and >= 0"),
                  ("b_int_m", arr["b_int_m"] >= 0.0, "finite and >= 0"),
                  ("b_acc_m", arr["b_acc_m"] >= 0.0, "finite and >= 0"),
                  ("tau_sat", tau_s >= 0.0, "finite and >= 0"))
        for name, good, what in checks:
            vals = arr.get(name, tau_s)
            if np.any(visible & ~(good & np.isfinite(vals))):
                _bad(name, what)
        if y is not None and np.any(visible & ~np.isfinite(y)):
            _bad("y", "finite")
        if np.any(visible & (ps * (1.0 + tau_s) >= 1.0)):
            _bad("p_sat * (1 + tau_sat)", "< 1")
    clk = g[..., 3:]
    onehot = np.all((clk == 0.0) | (clk == 1.0), axis=-1) & (np.sum(clk, axis=-1) == 1.0)
    if np.any(visible & ~onehot):
        raise ValueError("G clock columns (3 + j) must be one-hot (a single 1) for every "
                         "satellite in view")
    cons = np.where(visible, np.argmax(clk, axis=-1), -1)
    present = np.any(cons[:, :, None] == np.arange(n_const), axis=1)
    with np.errstate(invalid="ignore"):
        good_c = (pc >= 0.0) & (pc < 1.0) & np.isfinite(tau_c) & (tau_c >= 0.0)
        good_c &= pc * (1.0 + tau_c) < 1.0
    if np.any(present & ~good_c):
        raise ValueError("p_const must be a probability in [0, 1), tau_const >= 0 and "
                         "p_const * (1 + tau_const) < 1, for every constellation in view")
    return _Inputs(batch, g, arr["sigma_int_m"], arr["sigma_acc_m"], arr["b_int_m"],
                   arr["b_acc_m"], ps, pc, tau_s, tau_c, y, visible, cons, present, raw)


# ------------------------------------------------------------------------- grouping


def _compaction(visible, width: int):
    """Per epoch: indices of the satellites in view, in their original order, padded to
    ``width`` with 0 (``(E, width)``)."""
    pos = np.cumsum(visible, axis=1) - 1
    idx = np.zeros((visible.shape[0], width), dtype=np.intp)
    r, c = np.nonzero(visible & (pos < width))
    idx[r, pos[r, c]] = c
    return idx


def _codes(raw, batch: tuple, tail: tuple):
    """Small integer codes of the values of ``raw`` (unique over the array as given,
    before broadcasting, so a per-satellite ISM costs nothing), broadcast to the batch."""
    raw = np.asarray(raw, dtype=float)
    vals, inv = np.unique(raw, return_inverse=True)
    e = int(np.prod(batch, dtype=int))
    codes = np.broadcast_to(inv.reshape(raw.shape), batch + tail).reshape((e,) + tail)
    return codes, len(vals)


def _group(inp: _Inputs):
    """Group epochs by visibility pattern: the satellites in view in G-row order, each
    with its constellation, ``p_sat`` and ``tau_sat``, and the ``p_const``, ``tau_const``
    of the constellations in view. Returns ``gid`` (E,) (-1: under 4 satellites), one
    representative epoch per group, and the largest number of satellites in view."""
    e, n_sat = inp.visible.shape
    n_const = inp.p_const.shape[1]
    n_vis_all = inp.visible.sum(axis=1)
    nv = int(n_vis_all.max(initial=0))
    cp, n_p = _codes(inp.raw["p_sat"], inp.batch, (n_sat,))
    ct, n_t = _codes(inp.raw["tau_sat"], inp.batch, (n_sat,))
    kp, n_kp = _codes(inp.raw["p_const"], inp.batch, (n_const,))
    kt, n_kt = _codes(inp.raw["tau_const"], inp.batch, (n_const,))
    gid = np.full(e, -1)
    keys: dict[bytes, int] = {}
    reps: list[int] = []
    for start in range(0, e, _KEY_CHUNK):
        sl = slice(start, min(e, start + _KEY_CHUNK))
        vis = inp.visible[sl]
        n_vis = n_vis_all[sl]
        sat_code = (inp.cons[sl].astype(np.int64) * n_p + cp[sl]) * n_t + ct[sl]
        order = _compaction(vis, nv)
        slot = np.arange(nv)[None, :] < n_vis[:, None]
        const_code = np.where(inp.present[sl], kp[sl].astype(np.int64) * n_kt + kt[sl], -1)
        key = np.concatenate([n_vis[:, None], np.where(
            slot, np.take_along_axis(sat_code, order, axis=1), -1), const_code], axis=1)
        uniq, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
        ids = np.full(len(uniq), -1)
        for u, row in enumerate(uniq):
            if row[0] < 4:  # under 4 satellites: unavailable, no mode list
                continue
            b = row.tobytes()
            if b not in keys:
                keys[b] = len(reps)
                reps.append(start + int(first[u]))
            ids[u] = keys[b]
        gid[sl] = ids[inv.reshape(-1)]
    return gid, reps, nv


@dataclass(frozen=True)
class _Pattern:
    n: int
    pc: np.ndarray  # original indices of the constellations in view
    cons: np.ndarray  # (n,) compact constellation index of each satellite
    p_sat: np.ndarray
    tau_sat: np.ndarray
    p_const: np.ndarray  # (c,)
    tau_const: np.ndarray


def _pattern(inp: _Inputs, ep: int) -> _Pattern:
    """The visibility pattern of epoch ``ep`` (every epoch of its group shares it)."""
    sats = np.flatnonzero(inp.visible[ep])
    pc = np.flatnonzero(inp.present[ep])
    cmap = np.full(inp.present.shape[1], -1)
    cmap[pc] = np.arange(len(pc))
    return _Pattern(len(sats), pc, cmap[inp.cons[ep, sats]], inp.p_sat[ep, sats],
                    inp.tau_sat[ep, sats], inp.p_const[ep, pc], inp.tau_const[ep, pc])


def _modes_for(pat: _Pattern, rules: str, prm: dict, reference: bool = False) -> ModeList:
    kw = dict(rules=rules, phmi=prm["phmi_vert"] + prm["phmi_hor"], reference=reference)
    if rules == "blanch-2012":
        kw.update(p_thres_sat=prm["p_thres_sat"], p_thres_const=prm["p_thres_const"])
    else:
        kw.update(tau_sat=pat.tau_sat, tau_const=pat.tau_const, p_thres=prm["p_thres"],
                  fc_thres=prm["fc_thres"], fde=prm["fde"], p_exc_thres=prm["p_exc_thres"])
    return determine_modes(pat.cons, pat.p_sat, pat.p_const, **kw)


# --------------------------------------------------------------------------- kernel


def mhss(G, sigma_int_m, sigma_acc_m, b_int_m, b_acc_m, p_sat, p_const, *,
         rules: str = "add-v4.2", **params) -> MhssResult:
    """ARAIM multiple hypothesis solution separation (ADD v4.2 baseline), batched.

    Parameters
    ----------
    G : (..., n_sat, 3 + n_const) -- rows ``[-u_E, -u_N, -u_U, one-hot clock]``; a NaN row
        marks a satellite not in view.
    sigma_int_m, sigma_acc_m : (..., n_sat) -- combined integrity / accuracy sigmas (m).
    b_int_m, b_acc_m : (..., n_sat) -- ``b_nom`` and ``b_cont`` (m).
    p_sat : (..., n_sat); p_const : (..., n_const) -- prior fault probabilities.
    rules : ``"add-v4.2"`` or ``"blanch-2012"``.
    **params : constants and options, see :data:`raimcore.araim.PARAMS`.

    Returns
    -------
    MhssResult (attributes: :mod:`raimcore.araim`).

    Raises
    ------
    ValueError
        For an unknown keyword, a bad constant, mismatched shapes, or invalid values of a
        satellite in view (negative sigma, probability outside [0, 1], clock columns not
        one-hot). Too few satellites and singular geometry are statuses, not errors.

    References
    ----------
    ARAIM.md sections 3-9; [ADD] v4.2; [B2012]; MAAST ``usr_vhpl_araim.m``.
    """
    return _mhss(G, sigma_int_m, sigma_acc_m, b_int_m, b_acc_m, p_sat, p_const, rules=rules,
                 reference=False, **params)


def _mhss(G, sigma_int_m, sigma_acc_m, b_int_m, b_acc_m, p_sat, p_const, *,
          rules: str = "add-v4.2", reference: bool = False, **params) -> MhssResult:
    """:func:`mhss`, with a choice of path.

    Parameters
    ----------
    G, sigma_int_m, sigma_acc_m, b_int_m, b_acc_m, p_sat, p_const, rules, **params
        As :func:`mhss`.
    reference : bool
        False: the fast path (:func:`mhss`). True: the plain reference path kept for the
        agreement tests and the benchmarks: the kernel as first written
        (:mod:`raimcore.araim._kernel_reference`), exclusion candidates evaluated one by
        one with every protection level searched, fault-mode lists merged row by row.

    Returns
    -------
    MhssResult
        The same decisions on both paths, numbers equal to rounding.
    """
    prm = _params.resolve(rules, params)
    inp = _check_inputs(G, sigma_int_m, sigma_acc_m, b_int_m, b_acc_m, p_sat, p_const, prm)
    e, n_sat = inp.visible.shape
    n_const = inp.p_const.shape[1]
    gid, reps, nv = _group(inp)
    with_y = inp.y is not None
    fde = prm["fde"]
    want_modes = prm["return_modes"]

    out = _Outputs(e, n_sat, n_const, with_y, fde)
    out.n_sats[:] = inp.visible.sum(axis=1)
    out.reason[:] = 1  # too few satellites unless a group says otherwise
    cache: dict[int, ModeList] = {}
    order = np.argsort(gid, kind="stable")
    bounds = np.searchsorted(gid[order], np.arange(len(reps) + 1))
    group_data = []
    for gi, ep in enumerate(reps):
        pat = _pattern(inp, ep)
        cache[gi] = _modes_for(pat, rules, prm, reference)
        group_data.append(pat)
    k_max = max((len(m) for m in cache.values()), default=1)
    if want_modes:
        out.alloc_modes(k_max)

    for gi, pat in enumerate(group_data):
        eps_all = order[bounds[gi]:bounds[gi + 1]]
        if eps_all.size == 0:
            continue
        modes = cache[gi]
        n, k = pat.n, len(modes)
        cands = _candidates(pat, prm) if fde else []
        rho = 1.0 / (len(cands) + 1) if fde else 1.0
        plan = None if reference or not cands else _candidate_plan(pat, modes, cands)
        sub = max(16, _WORK_ELEMENTS // max(1, k * n * 3))
        if plan is not None:  # every candidate's PL equations (3 x K, 4 arrays) are kept
            sub = min(sub, max(4, _WORK_ELEMENTS // max(1, len(cands) * k * 12)))
        for s0 in range(0, eps_all.size, sub):
            eps = eps_all[s0:s0 + sub]
            if plan is None:
                _run_chunk(inp, eps, pat, modes, cands, rho, prm, rules, out, want_modes,
                           _kernel_reference.evaluate if reference else evaluate)
            else:
                _run_chunk_batched(inp, eps, pat, modes, plan, rho, prm, rules, out,
                                   want_modes)

    return out.result(inp.batch, rules, prm, want_modes)


def _candidates(pat: _Pattern, prm: dict):
    """Exclusion candidates (section 9): each satellite, then each constellation with
    ``P_const > 1e-7`` (if ``fde_const``). Each is ``(kind, compact index, keep mask)``."""
    out = []
    for i in range(pat.n):
        keep = np.ones(pat.n, bool)
        keep[i] = False
        out.append(("sat", i, keep))
    if prm["fde_const"]:
        for j in np.flatnonzero(pat.p_const > FDE_CONST_P_MIN):
            out.append(("const", int(j), pat.cons != j))
    return out


@dataclass(frozen=True)
class _CandidateGroup:
    """Exclusion candidates of one pattern that see the same problem shape: the same
    compacted restricted fault-mode list, constellations and clock columns. They are
    evaluated in one batched call, candidates as an extra batch axis."""

    members: np.ndarray  # (C,) positions in the candidate list
    keep_idx: np.ndarray  # (C, n_c) compact indices of the satellites each keeps
    cols: np.ndarray  # (3 + c_c,) columns of G kept
    cons: np.ndarray  # (n_c,) compact constellation of each kept satellite
    modes: ModeList  # the shared restricted list


@dataclass(frozen=True)
class _CandidatePlan:
    """Everything about a pattern's exclusion candidates that does not depend on the
    geometry, determined once per pattern (section 9)."""

    kinds: tuple  # per candidate: (kind, compact index)
    too_few: np.ndarray  # (N_exc,) bool: leaves 3 satellites or fewer (PLs infinite)
    groups: tuple  # of _CandidateGroup


def _candidate_plan(pat: _Pattern, modes: ModeList, cands) -> _CandidatePlan:
    """Restricted mode lists of every candidate (section 9), grouped by identical
    compacted lists so that each group runs as one batched :func:`evaluate`."""
    by_key: dict[bytes, list] = {}
    too_few = np.zeros(len(cands), bool)
    keys = mode_keys(modes.removed)  # once: each candidate's cut keys are keys & mask
    for ci, (_, _, keep) in enumerate(cands):
        if keep.sum() <= 3:
            too_few[ci] = True
            continue
        mc = restrict_modes(modes, keep, keys=keys)
        pc_left = np.unique(pat.cons[keep])
        cmap = np.full(len(pat.pc), -1)
        cmap[pc_left] = np.arange(len(pc_left))
        cons_c = cmap[pat.cons[keep]]
        cols = np.concatenate([[0, 1, 2], 3 + pc_left])
        key = b"|".join(a.tobytes() for a in (
            np.array(mc.removed.shape), cons_c, cols, mc.removed, mc.p_inst, mc.p_exp))
        entry = by_key.setdefault(key, [[], [], cols, cons_c, mc])
        entry[0].append(ci)
        entry[1].append(np.flatnonzero(keep))
    groups = tuple(_CandidateGroup(np.array(m), np.array(k), cols, cons_c, mc)
                   for m, k, cols, cons_c, mc in by_key.values())
    kinds = tuple((kind, j) for kind, j, _ in cands)
    return _CandidatePlan(kinds, too_few, groups)


#: Outputs of a candidate's evaluation that the exclusion step combines.
_CAND_FIELDS = ("ok", "emt", "sigma_acc_v", "alarm", "test_ratio", "dx")


def _evaluate_group(grp: _CandidateGroup, g, cint, cacc, bnom, bcont, y, p_nm, prm, rules,
                    rho):
    """Evaluate every candidate of ``grp`` on the epochs of a chunk at once: rows
    ``(candidate, epoch)`` flattened, cut to bound the working arrays, protection levels
    deferred. Returns a dict of :data:`_CAND_FIELDS`, each ``(C, E, ...)`` (None where not
    computed), and ``"parts"``: ``(first row, row count, PlBracket)`` per cut."""
    e_s = g.shape[0]
    n_c, kc = grp.keep_idx.shape[1], len(grp.modes)
    c_n = len(grp.members)

    def rows(a):  # (E, n, ...) -> (C * E, n_c, ...)
        t = a[:, grp.keep_idx]  # (E, C, n_c, ...)
        return np.swapaxes(t, 0, 1).reshape((c_n * e_s,) + t.shape[2:])

    gg = rows(g)[..., grp.cols]
    per = [rows(a) for a in (cint, cacc, bnom, bcont)]
    yy = rows(y) if y is not None else None
    pn = np.tile(p_nm, c_n)
    sub = max(16, _WORK_ELEMENTS // max(1, kc * n_c * 3))
    evs, parts = [], []
    for r0 in range(0, c_n * e_s, sub):
        sl = slice(r0, r0 + sub)
        evc = evaluate(gg[sl], *(a[sl] for a in per), grp.cons, grp.modes, prm, rules=rules,
                       rho=rho, drop=False, p_nm=pn[sl], y=None if yy is None else yy[sl],
                       defer_pl=True)
        evs.append(evc)
        parts.append((r0, len(evc.ok), evc.pl))
    out = {}
    for f in _CAND_FIELDS:
        vals = [getattr(p, f) for p in evs]
        out[f] = (None if vals[0] is None else
                  np.concatenate(vals).reshape((c_n, e_s) + vals[0].shape[1:]))
    out["parts"] = parts
    return out


def _candidate_pls(plan: _CandidatePlan, groups_out, ev, e_s: int, prm):
    """Protection levels of the exclusion candidates, searched only where they can matter.

    Every candidate's PL lies in its bracket ``[low, up]`` (section 7). Only the largest
    PL over the all-in-view and the candidates is reported, and the candidate named by
    ``*_set_by`` is the first one reaching it; so a candidate whose ``up`` is below some
    other evaluation's ``low`` (or value) can be neither and its search is skipped (its
    PL is set to ``-inf``). Per epoch, the candidate with the largest lower bound is
    searched first, its value raises the floor, then the rest that can still reach it.
    The reported maxima and ``*_set_by`` are exactly those of searching every candidate.
    Horizontal: both axes of a candidate together, ``hypot`` of the per-axis bounds.

    Returns ``(N_exc, E)`` arrays ``hpl``, ``hpl1``, ``hpl2``, ``vpl``.
    """
    n_exc = len(plan.kinds)
    tol, max_iter = prm["tol_pl_m"], prm["pl_max_iter"]
    low = np.full((n_exc, e_s, 3), -np.inf)
    up = np.full((n_exc, e_s, 3), -np.inf)
    need = np.zeros((n_exc, e_s, 3), bool)
    val = np.full((n_exc, e_s, 3), -np.inf)
    where = []  # (group output, part, candidate indices (m,), epoch indices (m,))
    for grp, res in groups_out:
        for r0, m, br in res["parts"]:
            r = np.arange(r0, r0 + m)
            ci, ei = grp.members[r // e_s], r % e_s
            bad = ~res["ok"].reshape(-1)[r]  # all-in-view of the candidate unavailable
            lo3, up3, ok3 = (a.reshape(3, m).T for a in (br.low, br.up, br.ok))
            exact = ~ok3 | (up3 - lo3 <= tol) | bad[:, None]
            v = np.where(ok3 & ~bad[:, None], up3, np.inf)
            low[ci, ei] = np.where(exact, v, lo3)
            up[ci, ei] = np.where(exact, v, up3)
            val[ci, ei] = np.where(exact, v, np.nan)
            need[ci, ei] = ~exact
            where.append((br, ci, ei, m))

    def search(mask):  # run the search on the (candidate, epoch, axis) cells of mask
        for br, ci, ei, m in where:
            sel = mask[ci, ei]  # (m, 3)
            if not sel.any():
                continue
            out = pl_bisect(br, tol, max_iter, rows=sel.T.reshape(-1)).reshape(3, m).T
            cells = np.nonzero(sel)
            val[ci[cells[0]], ei[cells[0]], cells[1]] = out[cells]
        need[mask] = False
        low[mask] = up[mask] = val[mask]

    def h_bounds():
        lb = np.hypot(np.maximum(low[..., 0], 0.0), np.maximum(low[..., 1], 0.0))
        ub = np.hypot(np.maximum(np.abs(low[..., 0]), np.abs(up[..., 0])),
                      np.maximum(np.abs(low[..., 1]), np.abs(up[..., 1])))
        return np.where(np.isneginf(up[..., 0]), -np.inf, lb), \
            np.where(np.isneginf(up[..., 0]), -np.inf, ub)

    rows = np.arange(e_s)
    for phase in (0, 1):
        lb_h, ub_h = h_bounds()
        floor_v = np.maximum(ev.vpl, np.max(low[..., 2], axis=0, initial=-np.inf))
        floor_h = np.maximum(ev.hpl, np.max(lb_h, axis=0, initial=-np.inf))
        open_v = need[..., 2]
        open_h = need[..., 0] | need[..., 1]
        mask = np.zeros_like(need)
        if phase == 0:  # the most promising candidate of each epoch first
            if n_exc:
                best_v = np.argmax(np.where(open_v, low[..., 2], -np.inf), axis=0)
                best_h = np.argmax(np.where(open_h, lb_h, -np.inf), axis=0)
                mask[best_v, rows, 2] = open_v[best_v, rows]
                mask[best_h, rows, 0] = open_h[best_h, rows]
                mask[best_h, rows, 1] = open_h[best_h, rows]
        else:  # skip those whose upper bound stays below the floor
            mask[..., 2] = open_v & (up[..., 2] >= floor_v)
            keep_h = open_h & (ub_h >= floor_h)
            mask[..., 0] = keep_h
            mask[..., 1] = keep_h
        search(mask & need)
    skip_v = need[..., 2]
    skip_h = need[..., 0] | need[..., 1]
    vpl = np.where(skip_v, -np.inf, val[..., 2])
    hpl1 = np.where(skip_h, np.nan, val[..., 0])
    hpl2 = np.where(skip_h, np.nan, val[..., 1])
    hpl = np.where(skip_h, -np.inf, np.hypot(hpl1, hpl2))
    return hpl, hpl1, hpl2, vpl


def _run_chunk_batched(inp, eps, pat, modes, plan: _CandidatePlan, rho, prm, rules, out,
                       want_modes):
    """:func:`_run_chunk` with the exclusion candidates evaluated group by group in
    batched calls (:func:`_candidate_plan`) and their protection levels searched only
    where they can change the result (:func:`_candidate_pls`); the outputs are combined
    in the candidate order of the reference loop, so every maximum, tie and ``*_set_by``
    is the same."""
    idx, g, cint, cacc, bnom, bcont, y = _gather(inp, eps, pat)
    ev = evaluate(g, cint, cacc, bnom, bcont, pat.cons, modes, prm, rules=rules, rho=rho,
                  drop=True, y=y)
    e_s = len(eps)
    evals: list = [None] * len(plan.kinds)
    groups_out = []
    for grp in plan.groups:
        res = _evaluate_group(grp, g, cint, cacc, bnom, bcont, y, ev.p_nm, prm, rules, rho)
        groups_out.append((grp, res))
        for pos, ci in enumerate(grp.members):
            evals[ci] = {f: (None if res[f] is None else res[f][pos]) for f in _CAND_FIELDS}
    c_hpl, c_hpl1, c_hpl2, c_vpl = _candidate_pls(plan, groups_out, ev, e_s, prm)
    hpl, hpl1, hpl2 = ev.hpl.copy(), ev.hpl1.copy(), ev.hpl2.copy()
    vpl, emt, sacc = ev.vpl.copy(), ev.emt.copy(), ev.sigma_acc_v.copy()
    vpl_by = hpl_by = np.full(e_s, -1)
    best_ratio = np.full(e_s, np.inf)
    best_sat = np.full(e_s, -1)
    best_const = np.full(e_s, -1)
    dx_exc = np.full((e_s, 3), np.nan)
    n_sat = inp.visible.shape[1]
    for ci, (kind, j) in enumerate(plan.kinds):
        event = idx[:, j] if kind == "sat" else np.full(e_s, n_sat + pat.pc[j])
        if plan.too_few[ci]:  # MAAST: such a candidate leaves the PLs infinite
            vpl_by = np.where(np.isfinite(vpl), event, vpl_by)
            hpl_by = np.where(np.isfinite(hpl), event, hpl_by)
            for a in (hpl, hpl1, hpl2, vpl, emt, sacc):
                a[:] = np.inf
            continue
        evc = evals[ci]
        bigger = c_hpl[ci] > hpl
        hpl_by = np.where(bigger, event, hpl_by)
        vpl_by = np.where(c_vpl[ci] > vpl, event, vpl_by)
        hpl1 = np.where(bigger, c_hpl1[ci], hpl1)
        hpl2 = np.where(bigger, c_hpl2[ci], hpl2)
        hpl = np.maximum(hpl, c_hpl[ci])
        vpl = np.maximum(vpl, c_vpl[ci])
        emt = np.maximum(emt, evc["emt"])
        sacc = np.maximum(sacc, evc["sigma_acc_v"])
        if y is not None:
            r = np.where(np.isnan(evc["test_ratio"]), 0.0, evc["test_ratio"])
            passes = evc["ok"] & ~evc["alarm"] & ev.alarm & (r < best_ratio)
            best_ratio = np.where(passes, r, best_ratio)
            if kind == "sat":
                best_sat = np.where(passes, idx[:, j], best_sat)
                best_const = np.where(passes, -1, best_const)
            else:
                best_const = np.where(passes, pat.pc[j], best_const)
                best_sat = np.where(passes, -1, best_sat)
            dx_exc = np.where(passes[:, None], evc["dx"], dx_exc)
    if y is None:
        best_sat = best_const = dx_exc = None
    out.store(eps, ev, hpl, hpl1, hpl2, vpl, emt, sacc, rho, best_sat, best_const, dx_exc)
    out.vpl_by[eps], out.hpl_by[eps] = vpl_by, hpl_by
    if want_modes:
        out.store_modes(eps, idx, pat, modes, ev)


def _gather(inp: _Inputs, eps, pat: _Pattern):
    idx = _compaction(inp.visible[eps], pat.n)  # (E_s, n) original satellite indices
    cols = np.concatenate([[0, 1, 2], 3 + pat.pc])
    rows_ = eps[:, None]
    g = inp.g[rows_, idx][:, :, cols]
    cint = inp.s_int[rows_, idx] ** 2
    cacc = inp.s_acc[rows_, idx] ** 2
    bnom = inp.b_int[rows_, idx]
    bcont = inp.b_acc[rows_, idx]
    y = inp.y[rows_, idx] if inp.y is not None else None
    return idx, g, cint, cacc, bnom, bcont, y


def _run_chunk(inp, eps, pat, modes, cands, rho, prm, rules, out, want_modes, ev_fn):
    """One chunk of epochs of a pattern, exclusion candidates one by one with ``ev_fn``
    (the reference path; without exclusion, the only path)."""
    idx, g, cint, cacc, bnom, bcont, y = _gather(inp, eps, pat)
    ev = ev_fn(g, cint, cacc, bnom, bcont, pat.cons, modes, prm, rules=rules, rho=rho,
               drop=True, y=y)
    hpl, hpl1, hpl2 = ev.hpl.copy(), ev.hpl1.copy(), ev.hpl2.copy()
    vpl, emt, sacc = ev.vpl.copy(), ev.emt.copy(), ev.sigma_acc_v.copy()
    best_sat = best_const = None
    dx_exc = None
    vpl_by = hpl_by = np.full(len(eps), -1)
    if cands:
        e_s = len(eps)
        best_ratio = np.full(e_s, np.inf)
        best_sat = np.full(e_s, -1)
        best_const = np.full(e_s, -1)
        dx_exc = np.full((e_s, 3), np.nan)
        for kind, j, keep in cands:
            event = idx[:, j] if kind == "sat" else np.full(len(eps), inp.visible.shape[1]
                                                              + pat.pc[j])
            if keep.sum() <= 3:  # MAAST: such a candidate leaves the PLs infinite
                vpl_by = np.where(np.isfinite(vpl), event, vpl_by)
                hpl_by = np.where(np.isfinite(hpl), event, hpl_by)
                for a in (hpl, hpl1, hpl2, vpl, emt, sacc):
                    a[:] = np.inf
                continue
            mc = restrict_modes(modes, keep, reference=True)
            pc_left = np.unique(pat.cons[keep])
            cmap = np.full(len(pat.pc), -1)
            cmap[pc_left] = np.arange(len(pc_left))
            cols = np.concatenate([[0, 1, 2], 3 + pc_left])
            evc = ev_fn(g[:, keep][:, :, cols], cint[:, keep], cacc[:, keep],
                           bnom[:, keep], bcont[:, keep], cmap[pat.cons[keep]], mc, prm,
                           rules=rules, rho=rho, drop=False, p_nm=ev.p_nm,
                           y=None if y is None else y[:, keep])
            bigger = evc.hpl > hpl
            hpl_by = np.where(bigger, event, hpl_by)
            vpl_by = np.where(evc.vpl > vpl, event, vpl_by)
            hpl1 = np.where(bigger, evc.hpl1, hpl1)
            hpl2 = np.where(bigger, evc.hpl2, hpl2)
            hpl = np.maximum(hpl, evc.hpl)
            vpl = np.maximum(vpl, evc.vpl)
            emt = np.maximum(emt, evc.emt)
            sacc = np.maximum(sacc, evc.sigma_acc_v)
            if y is not None:
                r = np.where(np.isnan(evc.test_ratio), 0.0, evc.test_ratio)
                passes = evc.ok & ~evc.alarm & ev.alarm & (r < best_ratio)
                best_ratio = np.where(passes, r, best_ratio)
                orig = idx[:, j] if kind == "sat" else np.full(len(eps), pat.pc[j])
                if kind == "sat":
                    best_sat = np.where(passes, orig, best_sat)
                    best_const = np.where(passes, -1, best_const)
                else:
                    best_const = np.where(passes, orig, best_const)
                    best_sat = np.where(passes, -1, best_sat)
                dx_exc = np.where(passes[:, None], evc.dx, dx_exc)
    out.store(eps, ev, hpl, hpl1, hpl2, vpl, emt, sacc, rho, best_sat, best_const, dx_exc)
    if out.fde:
        out.vpl_by[eps], out.hpl_by[eps] = vpl_by, hpl_by
    if want_modes:
        out.store_modes(eps, idx, pat, modes, ev)


class _Outputs:
    """Flat (E, ...) output buffers, filled group by group."""

    def __init__(self, e, n_sat, n_const, with_y, fde):
        self.e, self.n_sat, self.n_const = e, n_sat, n_const
        inf = lambda *s: np.full((e,) + s, np.inf)  # noqa: E731
        nan = lambda *s: np.full((e,) + s, np.nan)  # noqa: E731
        self.hpl, self.hpl1, self.hpl2 = inf(), inf(), inf()
        self.vpl, self.emt, self.sacc = inf(), inf(), inf()
        self.reason = np.zeros(e, dtype=int)
        self.n_sats = np.zeros(e, dtype=int)
        self.n_modes = np.zeros(e, dtype=int)
        self.p_nm = nan()
        self.k_fa = nan(3)
        self.phmi_v, self.phmi_h = nan(), nan()
        self.rho = np.ones(e)
        self.sigma, self.bias = nan(3), nan(3)
        self.with_y, self.fde = with_y, fde
        self.vpl_by = np.full(e, -1)
        self.hpl_by = np.full(e, -1)
        if with_y:
            self.dx = nan(3)
            self.alarm = np.zeros(e, dtype=bool)
            self.alarm_mode = np.full(e, -1)
            self.test_ratio = nan()
            if fde:
                self.exc_sat = np.full(e, -1)
                self.exc_const = np.full(e, -1)
                self.dx_exc = nan(3)
        self.k = 0

    def alloc_modes(self, k):
        e, s, c = self.e, self.n_sat, self.n_const
        self.k = k
        self.m_sats = np.zeros((e, k, s), bool)
        self.m_consts = np.zeros((e, k, c), bool)
        self.m_pi = np.zeros((e, k))
        self.m_pe = np.zeros((e, k))
        self.m_thr = np.full((e, k, 3), np.nan)
        self.m_sig = np.full((e, k, 3), np.nan)
        self.m_bias = np.full((e, k, 3), np.nan)
        self.m_sss = np.full((e, k, 3), np.nan)
        self.m_bss = np.full((e, k, 3), np.nan)
        self.m_valid = np.zeros((e, k), bool)
        self.m_mon = np.zeros((e, k), bool)
        self.m_sep = np.full((e, k, 3), np.nan) if self.with_y else None

    def store(self, eps, ev, hpl, hpl1, hpl2, vpl, emt, sacc, rho, bsat, bconst, dx_exc):
        ok = ev.ok
        self.hpl[eps], self.hpl1[eps], self.hpl2[eps] = hpl, hpl1, hpl2
        self.vpl[eps], self.emt[eps], self.sacc[eps] = vpl, emt, sacc
        self.reason[eps] = ev.reason
        self.n_modes[eps] = ev.n_fm
        self.p_nm[eps] = ev.p_nm
        self.k_fa[eps] = ev.k_fa
        self.phmi_v[eps] = np.where(ok, ev.phmi_v, np.nan)
        self.phmi_h[eps] = np.where(ok, ev.phmi_h, np.nan)
        self.rho[eps] = rho
        self.sigma[eps] = np.where(ok[:, None], ev.sigma0, np.nan)
        self.bias[eps] = np.where(ok[:, None], ev.bias0, np.nan)
        if self.with_y:
            self.dx[eps] = np.where(ok[:, None], ev.dx, np.nan)
            self.alarm[eps] = ev.alarm & ok
            self.alarm_mode[eps] = np.where(ok, ev.alarm_mode, -1)
            self.test_ratio[eps] = np.where(ok, ev.test_ratio, np.nan)
            if self.fde and bsat is not None:
                self.exc_sat[eps] = bsat
                self.exc_const[eps] = bconst
                self.dx_exc[eps] = dx_exc

    def store_modes(self, eps, idx, pat, modes, ev):
        k = len(modes)
        st = ev.stats
        ke = np.arange(k)[None, :, None]
        self.m_sats[eps[:, None, None], ke, idx[:, None, :]] = modes.removed[None]
        if len(pat.pc):
            self.m_consts[eps[:, None, None], ke, pat.pc[None, None, :]] = modes.consts[None]
        self.m_pi[eps, :k] = modes.p_inst
        self.m_pe[eps, :k] = modes.p_exp
        self.m_thr[eps, :k] = ev.threshold
        self.m_sig[eps, :k] = st.sigma
        self.m_bias[eps, :k] = st.bias
        self.m_sss[eps, :k] = st.sigma_ss
        self.m_bss[eps, :k] = st.bias_ss
        self.m_valid[eps, :k] = True
        self.m_mon[eps, :k] = st.monitorable
        if self.m_sep is not None:
            self.m_sep[eps, :k] = st.sep

    def result(self, batch, rules, prm, want_modes) -> MhssResult:
        def b(a):
            return a.reshape(batch + a.shape[1:])

        status = np.where(self.reason == 0, "ok", "unavailable")
        modes = None
        if want_modes:
            modes = FaultModes(b(self.m_sats), b(self.m_consts), b(self.m_pi), b(self.m_pe),
                               b(self.m_thr), b(self.m_sig), b(self.m_bias), b(self.m_sss),
                               b(self.m_bss), b(self.m_valid), b(self.m_mon),
                               b(self.m_sep) if self.m_sep is not None else None)
        y_fields = [None] * 4
        if self.with_y:
            y_fields = [b(self.dx), b(self.alarm), b(self.alarm_mode), b(self.test_ratio)]
        fde_fields = [None] * 3
        if self.with_y and self.fde:
            fde_fields = [b(self.exc_sat), b(self.exc_const), b(self.dx_exc)]
        return MhssResult(
            b(self.hpl), b(self.vpl), b(self.emt), b(self.sacc), b(self.hpl1), b(self.hpl2),
            b(prm["k_acc"] * self.sacc), b(prm["k_ff"] * self.sacc), b(status),
            b(_REASONS[self.reason]), b(self.n_sats), b(self.n_modes), b(self.p_nm),
            b(self.k_fa), b(self.phmi_v), b(self.phmi_h), b(self.rho), b(self.sigma),
            b(self.bias), modes, *y_fields, *fde_fields, rules, _params.frozen(prm),
            b(self.vpl_by) if self.fde else None, b(self.hpl_by) if self.fde else None)
