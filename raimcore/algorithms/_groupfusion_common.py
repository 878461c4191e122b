"""Shared scenario driver of the multi-fault isolation methods of seed 004 (GF, RS, QV).

Each epoch is solved once with all used satellites (:func:`raimcore.lsq.wls`); the groups
then work on the linearised model at that solution, ``y = post-fit residual`` and ``h`` the
ENU geometry rows, which gives exactly the group least-squares residuals since
``(I - P_g) H_g dx = 0`` (spec 4). Epochs are batched by visible set (a loop over distinct
sets of used satellites, never over groups). Isolation acts only when the full-set
chi-square test alarms (the paper isolates after detection); the excluded satellites are
the isolated set, and the position is solved again without them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import special

from ..lsq import wls
from .base import (
    STATUS_NO_ISOLATION,
    STATUS_OK,
    STATUS_UNAVAILABLE,
    AlgorithmOutput,
    Measurements,
)

#: ``isolate(h (B, N, n), y (B, N), w (B, N), p_fa, rng) -> (isolated (B, N) bool,
#: score (B, N) float, threshold (B,) float)``.
Isolator = Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]


def run_multi_fault(data: Measurements, isolate: Isolator, score_name: str,
                    threshold_name: str) -> AlgorithmOutput:
    """Run ``isolate`` on every epoch of ``data`` and package the common output.

    ``per_sat[score_name]`` is the per-satellite score the method thresholds (NaN where
    unused); ``columns[threshold_name]`` its isolation threshold per epoch.
    """
    w = np.where(data.used, 1.0 / data.sigma_m**2, 0.0)
    n_sys = len(data.systems)
    before = wls(data.pos_sv_ecef_m, data.pr_m, w, data.sys_idx, n_sys)
    e, s = w.shape
    dof = before.dof
    available = before.available & (dof >= 1)
    resid = np.nan_to_num(before.resid_m)
    stat = np.where(available, np.sum(w * resid**2, axis=-1), np.nan)
    thr = np.where(available, special.chdtri(np.maximum(dof, 1), data.p_fa), np.nan)
    alarm = available & (stat > thr)
    # Groups of r = 4 + q satellites need at least r + 1 satellites for two groups.
    r = 4 + (before.n_states - 3)
    can_isolate = available & (before.n_used >= r + 1)
    status = np.where(~available, STATUS_UNAVAILABLE,
                      np.where(can_isolate, STATUS_OK, STATUS_NO_ISOLATION)).astype(object)
    score = np.full((e, s), np.nan)
    iso_thr = np.full(e, np.nan)
    isolated_set = np.zeros((e, s), dtype=bool)
    rows_ok = np.flatnonzero(can_isolate)
    if rows_ok.size:
        patterns, inverse = np.unique(data.used[rows_ok], axis=0, return_inverse=True)
        for p, pattern in enumerate(patterns):  # one batch per distinct visible set
            rows = rows_ok[inverse.reshape(-1) == p]
            cols = np.flatnonzero(pattern)
            h = before.h_enu[rows][:, cols]
            keep = np.abs(h[..., 3:]).sum(axis=(0, 1)) > 0  # clocks of systems present
            h = np.concatenate([h[..., :3], h[..., 3:][..., keep]], axis=-1)
            iso, sc, th = isolate(h, resid[rows][:, cols], w[rows][:, cols], data.p_fa,
                                  data.rng(p))
            isolated_set[rows[:, None], cols[None, :]] = iso
            score[rows[:, None], cols[None, :]] = sc
            iso_thr[rows] = th
    excluded = isolated_set & alarm[:, None]
    after = before.pos_ecef_m.copy()
    changed = np.flatnonzero(excluded.any(axis=-1))
    if changed.size:
        sub = wls(data.pos_sv_ecef_m[changed], data.pr_m[changed],
                  np.where(excluded[changed], 0.0, w[changed]), data.sys_idx, n_sys,
                  x0_ecef_m=before.pos_ecef_m[changed])
        after[changed] = sub.pos_ecef_m
    best = np.where(np.isfinite(score), score, -np.inf).argmax(axis=-1)
    return AlgorithmOutput(
        status=status, statistic=stat, threshold=thr, alarm=alarm,
        pos_before_ecef_m=before.pos_ecef_m, pos_after_ecef_m=after, excluded=excluded,
        isolated=np.where(alarm & can_isolate, best, -1),
        per_sat={score_name: score},
        columns={threshold_name: iso_thr, "dof": dof.astype(float)},
    )


def groups_option(name: str):
    """The number-of-groups option ``name`` (0: the paper's N^2)."""
    from ..schema import option

    return option(name, int, 0, "number of satellite groups (0 = the paper's N^2)", lo=0,
                  hi=100_000)


def as_groups(value: int) -> int | None:
    """The groups option's value as ``select_groups`` takes it (None: the paper's N^2)."""
    return None if value == 0 else value
