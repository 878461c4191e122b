"""Advanced RAIM: multiple hypothesis solution separation (MHSS) of the ARAIM ADD v4.2.

One public kernel, :func:`mhss`, batched over any leading axes (epochs, users, runs). It
implements ``shared/ARAIM.md`` sections 3-9 (fault probabilities, fault modes, subset
solutions, thresholds, protection levels, EMT, accuracy, exclusion), rule for rule as
Stanford MAAST (``maast_for_araim_2``) codes them; every constant of section 10 is a keyword.

    from raimcore.araim import mhss
    res = mhss(G, sigma_int_m, sigma_acc_m, b_int_m, b_acc_m, p_sat, p_const)
    res.vpl_m, res.hpl_m, res.emt_m, res.sigma_acc_v_m, res.status

Inputs (shape rule: batch axes first, components last; all arrays broadcast together)
------------------------------------------------------------------------------------
G : ``(..., n_sat, 3 + n_const)``
    Rows ``[-u_E, -u_N, -u_U, one-hot clock]`` (``u`` the unit line of sight user ->
    satellite in ENU, so ``G[..., 2] = -sin(el)``); the clock columns say each satellite's
    constellation (column ``3 + j`` is constellation ``j``). **A satellite not in view at an
    epoch has a NaN row** (any non-finite entry); the keyword ``used`` (bool
    ``(..., n_sat)``) removes satellites as well. A satellite with ``p_sat == 1`` is not
    used either (MAAST's rule). Constellations with no satellite in view are dropped.
sigma_int_m, sigma_acc_m : ``(..., n_sat)``, m
    Per-satellite *combined* one-sigma pseudorange errors for integrity and for
    accuracy/continuity (``C_int(i,i) = sigma_int_m**2 = sigma_URA^2 + sigma_tropo^2 +
    sigma_user^2``, ``C_acc`` with ``sigma_URE``; section 2). :mod:`raimcore.araim.error_model`
    has the tropo and airborne models to build them. Values of satellites not in view are
    ignored (may be NaN).
b_int_m, b_acc_m : ``(..., n_sat)``, m
    ``b_nom`` (integrity bias) and ``b_cont`` (continuity bias, 0 if absent).
p_sat : ``(..., n_sat)``; p_const : ``(..., n_const)``
    Prior (instantaneous) fault probabilities ``P_sat,i`` and ``P_const,j`` (MAAST: rate x
    mean fault duration).

Keywords (``**params``; unknown names raise a one-line ``ValueError`` listing the allowed
ones; the full table with defaults, units and sources is :data:`PARAMS`, and
:func:`defaults` gives the values of one rule set)
----------------------------------------------------------------------------------------
rules : ``"add-v4.2"`` (default: sections 3-8 baseline, LPV-200 constants) or
    ``"blanch-2012"`` (B2012 worked-example rules: separate satellite / constellation
    thresholds ``p_thres_sat``, ``p_thres_const``, no mixed sets, no consolidation, exact
    ``P_nm``, the 2012 EMT form; no exposure ``tau``).
Constants: ``phmi_vert``, ``phmi_hor``, ``p_fa_vert``, ``p_fa_hor``, ``p_thres`` (ADD) or
    ``p_thres_sat`` / ``p_thres_const`` (B2012), ``fc_thres`` (ADD), ``p_emt``,
    ``tol_pl_m``, ``n_es_int``, ``n_es_cont``, ``max_pmd``, ``k_acc``, ``k_ff``,
    ``p_exc_thres``; exposure (ADD only): ``t_exp_over_mfd`` (scalar tau for every event)
    or ``tau_sat`` ``(..., n_sat)`` / ``tau_const`` ``(..., n_const)``.
Options: ``y`` ``(..., n_sat)`` measured minus predicted pseudoranges (m) -> the
    solution-separation test; ``used``; ``fde`` (bool, section 9 exclusion);
    ``fde_const`` (bool, default True: constellations with ``P_const > 1e-7`` are exclusion
    candidates too); ``pl_max_iter`` (bisection cap, 0 = until ``tol_pl_m``; MAAST 10);
    ``return_modes`` (bool, default True; False skips the per-epoch mode table, for big
    availability studies).

Result: :class:`MhssResult` (frozen), arrays of the batch shape ``B``
--------------------------------------------------------------------
hpl_m, vpl_m, emt_m, sigma_acc_v_m : ``B`` -- HPL = sqrt(hpl1^2 + hpl2^2), VPL, EMT,
    vertical accuracy sigma of the all-in-view (``inf`` where unavailable).
hpl1_m, hpl2_m : ``B`` -- east and north protection levels (with ``fde``: those of the
    evaluation that gave the largest HPL).
acc95_v_m, ff_v_m : ``B`` -- ``k_acc * sigma_acc_v_m`` (95 %) and ``k_ff * sigma_acc_v_m``
    (fault-free 1e-7 vertical error).
status : ``B`` str -- ``"ok"`` or ``"unavailable"``; reason : ``B`` str -- ``""``,
    ``"too_few_satellites"`` (fewer than 4, or fewer than 3 + N_const) or
    ``"singular_geometry"`` (``cond(G^T W G) >= 1e7``). Unavailable epochs have infinite
    PLs, EMT and sigma_acc, never an exception.
n_sats : ``B`` int -- satellites used; n_modes : ``B`` int -- ``N_fm``, monitored and
    monitorable fault modes (fault-free not counted).
p_not_monitored : ``B`` -- ``P_nm`` after dropping unmonitorable modes.
k_fa : ``B + (3,)`` -- ``K_fa,q`` for east, north, up (NaN where ``N_fm = 0``).
phmi_vert_alloc, phmi_hor_alloc : ``B`` -- ``PHMI_V'`` and ``PHMI_H'`` (with rho).
sigma_m, bias_m : ``B + (3,)`` -- all-in-view ``sigma_q^(0)`` and ``b_q^(0)`` (E, N, U).
rho : ``B`` -- integrity allocation to the all-in-view (1 for FD, ``1/(N_exc+1)`` with fde).
modes : :class:`FaultModes` or None (``return_modes=False``) -- the monitored fault
    modes, padded to ``K`` = the largest count in the batch; index 0 is fault-free:
    ``sats`` ``B + (K, n_sat)`` bool (satellites the mode removes, original order),
    ``consts`` ``B + (K, n_const)`` bool (constellation events of the mode's event set),
    ``p_inst``, ``p_exp`` ``B + (K,)``, ``threshold_m`` ``B + (K, 3)`` (``T_k,q``; inf where
    not monitorable), ``sigma_m``, ``sigma_ss_m``, ``bias_m``, ``bias_ss_m`` ``B + (K, 3)``,
    ``valid`` ``B + (K,)`` (a real mode, not padding), ``monitored`` ``B + (K,)`` (valid
    and monitorable: in the PL sum), ``separation_m`` ``B + (K, 3)`` (with ``y``) or None.
With ``y`` (else None): ``dx_enu_m`` ``B + (3,)`` the all-in-view position correction
    ``(S^(0) y)[:3]``; ``alarm`` ``B`` bool (some ``|((S^(k) - S^(0)) y)_q| > T_k,q``);
    ``alarm_mode`` ``B`` int, the mode index (into ``modes``) with the largest normalised
    separation ``|dx_k,q| / T_k,q`` (-1 if no mode); ``test_ratio`` ``B`` that largest ratio.
With ``y`` and ``fde`` (else None): ``excluded_sat`` / ``excluded_const`` ``B`` int (-1:
    none): the exclusion candidate (section 9: each satellite, then each constellation
    with ``P_const > 1e-7``) whose own fault-mode list (the all-in-view list restricted to
    its satellites) passes every separation test, only where ``alarm``; if several pass,
    the smallest largest normalised separation wins. ``dx_excluded_enu_m`` ``B + (3,)``
    its position correction (NaN if none).
With ``fde`` (else None): ``vpl_set_by``, ``hpl_set_by`` ``B`` int -- the evaluation that
    gave the VPL / HPL: -1 the all-in-view, else the exclusion candidate as an event index
    (satellite ``i``, or ``n_sat + j`` for constellation ``j``). An infinite PL whose
    candidate is not -1 comes from that candidate (e.g. after excluding a constellation a
    mode left unmonitorable spends more than the candidate's budget ``rho PHMI'``).
rules, params : the rule set and the effective constants (a read-only mapping).

Exclusion (``fde=True``, section 9, as MAAST's ``usr_vhpl_araim.m`` evaluates it): the
all-in-view runs with ``rho = 1/(N_exc + 1)``; each candidate runs on the all-in-view mode
list restricted to its satellites (modes left removing nothing merge into the fault-free),
with the all-in-view ``P_nm`` and ``rho``, its unmonitorable modes spending ``p_inst a`` of
the budget; ``hpl_m``, ``vpl_m``, ``emt_m``, ``sigma_acc_v_m`` are the maxima over the
all-in-view and the candidates (a candidate leaving 3 satellites or fewer makes them
infinite, as in MAAST). ``modes``, ``alarm`` and ``k_fa`` stay those of the all-in-view.

Batching
--------
The fault-mode list depends only on which satellites are in view (in G-row order, with
their constellation and probabilities) and on the constellation probabilities, not on the
geometry. Epochs are grouped by that pattern (satellites in view compacted in their
original order), each pattern's list is determined once (cached), and every
geometry-dependent step runs vectorised over the epochs of a group: subset solutions by
closed-form down-dates of the all-in-view solution for one- and two-satellite modes (and of
a constellation's solution for a constellation plus one or two satellites), by normal
equations for the others, thresholds, the protection-level bisection on all epochs and axes
at once, EMT. No Python loop runs over epochs.

With ``fde``, the exclusion candidates of a pattern whose restricted mode lists coincide
(after compaction: same list, constellations and clock columns, e.g. every satellite of one
constellation with the same priors) run as one batched evaluation, candidates as an extra
batch axis; the candidates' lists are determined once per pattern. Their protection levels
are searched only where they can be the largest: each search stays inside MAAST's bracket,
so a candidate whose upper end lies below another evaluation's lower end (or value) can
set neither the PL nor ``*_set_by`` and is not searched. Results equal, decision for
decision, those of the plain per-candidate path kept as a reference
(``raimcore.araim.mhss._mhss(..., reference=True)``, ``tests/test_araim.py``).

Modules
-------
mhss        the public kernel and its result classes
modes       fault-mode determination (sections 3-4), usable on its own
kernel      subset solutions, thresholds, protection levels, EMT (sections 5-8)
_kernel_reference  the same as first written (the reference path of the agreement tests)
error_model nominal tropo and airborne error models (section 2), MAAST's example ISM
_params     the parameter table (declare once: defaults, ranges, units, help)

References
----------
.. [ADD] EU-US WG-C ARAIM TSG, "ARAIM Airborne Algorithm Description Document" v4.2, 2022.
.. [B2012] Blanch J. et al., "Advanced RAIM user algorithm description: integrity support
   message processing, fault detection, exclusion and protection level calculation",
   ION GNSS 2012.
.. [B2015] Blanch J. et al., "Baseline advanced RAIM user algorithm and possible
   improvements", IEEE TAES 51(1), 2015.
.. [MAAST] Stanford GPS Lab, ``maast_for_araim_2`` (MATLAB), ``usr_vhpl_araim.m``,
   ``mhss_raim_baseline_v5.m`` and helpers.
"""

from ._params import PARAMS, RULES, Param, defaults
from .error_model import (
    MAAST_EXAMPLE_ISM,
    sigma_tropo_m,
    sigma_user_add_m,
    sigma_user_ed259a_m,
)
from .mhss import FaultModes, MhssResult, mhss
from .modes import ModeList, determine_modes, p_at_least

__all__ = [
    "mhss",
    "MhssResult",
    "FaultModes",
    "PARAMS",
    "RULES",
    "Param",
    "defaults",
    "ModeList",
    "determine_modes",
    "p_at_least",
    "sigma_tropo_m",
    "sigma_user_add_m",
    "sigma_user_ed259a_m",
    "MAAST_EXAMPLE_ISM",
]
