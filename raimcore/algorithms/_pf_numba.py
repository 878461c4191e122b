"""Compiled kernels of a particle-bank step (``ParticleBank(kernel="numba")``, :mod:`.pf`).

One pass over the filters does the per-particle work of the numpy fast kernel
(:func:`raimcore.algorithms.pf._propose_fast`), each step a loop over a filter's particles
held particle-last in small buffers (loops the compiler vectorises): the motion, the
drift's prior mean, the residuals, each system's masked median (a comparator network),
the clock proposal and its importance ratio, the drift conditioning and the
log-likelihood; a second pass
normalises the weights (log normaliser, ``N_eff``, weighted mean) and a third resamples
the filters that need it by counting copies (:func:`raimcore.algorithms.pf._resample_fast`).

Every random number is drawn by the caller with numpy, in the fast kernel's order, and
passed in; every formula is the fast kernel's, term for term (``fastmath=False``: no
reassociation), so the results differ from it by rounding only (sums taken in another
order, a Student-t likelihood's ``sum ln(1 + t^2)`` as the log of a product: measured
below 2e-8 m on the states and 2e-8 nepers on the weights, a few units in the last place
of an ECEF coordinate; ``tests/test_pf.py``). The importance ratio's ``logaddexp`` and
the Student-t logarithm are finished by the caller in numpy's vectorised loops (a scalar
``exp`` and ``log1p`` per particle cost more than the rest of its proposal).
Kernels trust their inputs: C-contiguous float64 arrays shaped as documented, validated
by :class:`~raimcore.algorithms.pf.ParticleBank`.

Compiled once per machine with an on-disk cache (``cache=True``, numba's ``__pycache__``
beside this file, or its user cache directory when that is read-only); :func:`warm_up`
compiles or loads them on a tiny bank (the dashboard calls it in a background thread at
start-up).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["propose_rows", "normalise_rows", "resample_rows", "student_t_ll",
           "common_mode_screen", "NOISE_GAUSSIAN",
           "NOISE_STUDENT_T", "NOISE_MIXTURE", "warm_up"]

#: Noise-model codes of :func:`propose_rows` (the base model of a ``Scaled`` one).
NOISE_GAUSSIAN, NOISE_STUDENT_T, NOISE_MIXTURE = 0, 1, 2
_LOG_2PI = math.log(2.0 * math.pi)
_LOG_2 = math.log(2.0)


@njit(cache=True, fastmath=False, error_model="numpy")
def _logaddexp(a, b):
    """``ln(e^a + e^b)`` as numpy's ``logaddexp`` computes it."""
    if a == b:
        return a + _LOG_2
    t = a - b
    if t > 0:
        return a + math.log1p(math.exp(-t))
    if t <= 0:
        return b + math.log1p(math.exp(t))
    return t  # NaN


@njit(cache=True, fastmath=False, error_model="numpy")
def _logpdf(x, noise_kind, sigma, nu, eps, mix_scale, const):
    """``noise.logpdf(x)`` of the base model (:mod:`raimcore.measure.noise`), one value."""
    if noise_kind == NOISE_GAUSSIAN:
        z = x / sigma
        return -0.5 * z * z - math.log(sigma) - 0.5 * _LOG_2PI
    if noise_kind == NOISE_STUDENT_T:
        z = x / sigma
        return const - 0.5 * (nu + 1) * math.log1p(z * z / nu)
    s2 = sigma * mix_scale
    a = math.log1p(-eps) - 0.5 * (x / sigma) ** 2 - math.log(sigma)
    b = math.log(eps) - 0.5 * (x / s2) ** 2 - math.log(s2)
    return _logaddexp(a, b) - 0.5 * _LOG_2PI


def _median_networks(largest):
    """Comparator networks that put the two middle order statistics of ``k`` values,
    ``(k - 1) // 2`` and ``k // 2``, in those positions, for ``k = 0 .. largest``:
    Batcher's merge exchange (Knuth, TAOCP vol. 3, 5.2.2, Algorithm M) pruned to the
    comparators those two outputs depend on. Returns ``(pairs, first)``: the comparators
    ``(a, b)``, ``a < b`` (the smaller value to ``a``), of ``k`` values at
    ``pairs[first[k]:first[k + 1]]``."""
    pairs, first = [], [0]
    for k in range(largest + 1):
        net = []
        t = max(1, (k - 1).bit_length())
        p = 1 << (t - 1)
        while p > 0 and k > 1:
            q, r, d = 1 << (t - 1), 0, p
            while d > 0:
                net += [(i, i + d) for i in range(k - d) if i & p == r]
                d, q, r = q - p, q >> 1, p
            p >>= 1
        need, kept = {(k - 1) // 2, k // 2}, []
        for a, b in reversed(net):
            if a in need or b in need:
                kept.append((a, b))
                need |= {a, b}
        pairs += kept[::-1]
        first.append(len(pairs))
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), np.array(first, dtype=np.int64)


#: The median networks of :func:`_medians` (a system with more satellites takes
#: :func:`_medians_sorted`); numba keeps these global arrays as constants of the kernel.
_NET_LARGEST = 32
_NET_PAIRS, _NET_FIRST = _median_networks(_NET_LARGEST)


@njit(cache=True, fastmath=False, error_model="numpy")
def _medians_sorted(res, lo, kk, order, buf, bufj, out):
    """:func:`_medians` by an insertion sort, particle by particle (any input, NaN
    included: the previous kernel's sort, where a NaN keeps its place). The rows are taken
    in the order that sorted the previous particle's values, ``order[lo:lo + kk]`` (kept
    across the calls of a filter): its particles are close, so that order nearly sorts
    theirs too."""
    for p in range(res.shape[1]):
        for i in range(kk):
            j = order[lo + i]
            v = res[j, p]
            c = i
            while c > 0 and buf[c - 1] > v:
                buf[c] = buf[c - 1]
                bufj[c] = bufj[c - 1]
                c -= 1
            buf[c] = v
            bufj[c] = j
        for i in range(kk):
            order[lo + i] = bufj[i]
        out[p] = (buf[(kk - 1) // 2] + buf[kk // 2]) * 0.5


@njit(cache=True, fastmath=False, error_model="numpy")
def _medians(res, lo, kk, order, buf, bufj, srt, out):
    """``out`` (n,): for every particle (column) of ``res`` (k, n), the mean of the order
    statistics ``(kk - 1) // 2`` and ``kk // 2`` of its rows ``lo .. lo + kk`` (the fast
    kernel's median; 0 when ``kk`` is 0).

    A comparator network (:data:`_NET_PAIRS`) on a copy in ``srt`` (k, n), each comparator
    applied to all the particles at once (a loop without branches, vectorised): the values
    of any sort but for the sign of a zero, which the sums that use the medians never see
    (they start at +0, and ``+0 + -0 = +0``). A NaN among the values, or more than
    :data:`_NET_LARGEST` of them: :func:`_medians_sorted` (``order``, ``buf``, ``bufj``
    (k,) its work arrays)."""
    n = res.shape[1]
    if kk == 0:
        for p in range(n):
            out[p] = 0.0
        return
    nan = 0
    for i in range(kk):
        for p in range(n):
            v = res[lo + i, p]
            srt[i, p] = v
            nan += v != v
    if nan or kk > _NET_LARGEST:
        _medians_sorted(res, lo, kk, order, buf, bufj, out)
        return
    for m in range(_NET_FIRST[kk], _NET_FIRST[kk + 1]):
        a, b = _NET_PAIRS[m, 0], _NET_PAIRS[m, 1]
        for p in range(n):
            u = srt[a, p]
            v = srt[b, p]
            srt[a, p] = v if v < u else u
            srt[b, p] = u if v < u else v
    a, b = (kk - 1) // 2, kk // 2
    for p in range(n):
        out[p] = (srt[a, p] + srt[b, p]) * 0.5


@njit(cache=True, fastmath=False, error_model="numpy")
def propose_rows(x, noise_std, z, pick, sv, pr, mask, sys_idx, n_clk, clk0, cv, dt_s,
                 c_pos, c_vel, has_drift, drift, dt, informative, chol_s, gain, chol_p,
                 s_inv, p_inv, hls, hlp, drift_gain, alpha, log_1ma, noise_kind,
                 scaled, sigma, nu, eps, mix_scale, const, scale, log_scale, log_s, log_p, ll,
                 ll_prod):
    """The clock proposal of every particle of every filter, in place
    (:func:`raimcore.algorithms.pf._propose_fast`, the same draws and formulas).

    Filter by filter, the particles' states, draws and residuals are copied to buffers
    with the particle last (one row of n per state, satellite or clock), so that each
    step below is a loop over the particles that the compiler vectorises; every
    particle's sums keep the order (and so the rounding) of the per-particle loops they
    replace. The filter's satellites in ``mask`` are gathered system by system first
    (the others are never read: weight 0, no median).

    Parameters
    ----------
    x : (R, N, D) particles at k - 1, moved to k in place.
    noise_std : (R, N, D) standard normal draws (the motion columns are used).
    z : (R, N, q) standard normal draws of the clock offsets.
    pick : (R, N) uniform draws; below ``alpha``: the prior component.
    sv : (R, S, 3) satellite positions (m); pr : (R, S) pseudoranges, 0 where unused or
        NaN; mask : (R, S) bool, the measurements each filter scores.
    sys_idx : (S,) int system index; n_clk, clk0 : clock states and the first's index.
    cv : constant-velocity model; dt_s : the step (s); c_pos, c_vel : the motion noise
        factors (m and m/s per unit draw); has_drift, drift : a drift state and its index;
        dt : ``max(dt_s, 0)``.
    informative : (R,) bool; chol_s, gain, chol_p, s_inv, p_inv : (R, q, q); hls, hlp :
        (R,) the clock proposal's Gaussians (:func:`raimcore.algorithms.pf._clock_terms`);
        drift_gain : (R,) the drift's gain on the offset noise.
    alpha, log_1ma : the defensive share and ``log(1 - alpha)``.
    noise_kind, scaled, sigma, nu, eps, mix_scale, const, scale, log_scale : the noise
        model (``NOISE_*``; per-satellite ``scale`` (R, S) and its log when ``scaled``).
    log_s, log_p, ll : (R, N) outputs: the two terms of the importance ratio
        ``ln r = log_s - logaddexp(log_p, log_s + log_a)`` (0 where not ``informative``;
        the caller takes the exponential and logarithm for all particles at once, in
        numpy's vectorised loops), and the log-likelihoods; for a Student-t model
        (not scaled) ``ll`` holds ``sum ln(1 + t_j^2)`` less ``ln ll_prod`` (R, N), the
        rest of the sum as a product, and the caller finishes it (:func:`student_t_ll`).
    """
    rows, n, d = x.shape
    s_n = sv.shape[1]
    q = n_clk
    mode = 2
    inv_s = 1.0
    if not scaled and noise_kind == NOISE_GAUSSIAN:
        mode, inv_s = 0, 1.0 / sigma
    elif not scaled and noise_kind == NOISE_STUDENT_T:
        mode, inv_s = 1, 1.0 / (sigma * math.sqrt(nu))
    elif noise_kind == NOISE_GAUSSIAN:  # scaled: _logpdf's Gaussian written out
        mode = 3
    log_sigma = math.log(sigma)
    half_log_2pi = 0.5 * _LOG_2PI
    # The satellites in mask, system by system (start: each system's first), as
    # -2 s, |s|^2, the pseudorange and the scale.
    used = np.empty(s_n, dtype=np.int64)
    start = np.zeros(n_clk + 1, dtype=np.int64)
    m2s = np.empty((s_n, 3))
    ss = np.empty(s_n)
    prc = np.empty(s_n)
    scc = np.empty(s_n)
    lsc = np.empty(s_n)
    order = np.empty(s_n, dtype=np.int64)  # _medians_sorted's kept order
    buf = np.empty(s_n)
    bufj = np.empty(s_n, dtype=np.int64)
    # Particle-last buffers: one row of n particles per state, satellite or clock (the
    # inner index a loop counter: no negative-index fix-up, loops the compiler vectorises).
    xt = np.empty((d, n))  # the states
    res = np.empty((s_n, n))  # the residuals of the gathered satellites
    srt = np.empty((s_n, n))  # _medians' copy
    zt = np.empty((q, n))
    ec = np.empty((q, n))  # the offset noise e (chol(S) z, or the proposal's draw)
    centre = np.empty((q, n))
    mu = np.empty((q, n))
    et = np.empty((q, n))
    dv = np.empty((q, n))
    xx = np.empty(n)
    acc = np.empty(n)
    acc2 = np.empty(n)
    qs = np.empty(n)
    qp = np.empty(n)
    for r in range(rows):
        k = 0
        for s in range(n_clk):
            start[s] = k
            for j in range(s_n):
                if mask[r, j] and sys_idx[j] == s:
                    used[k] = j
                    k += 1
        start[n_clk] = k
        for i in range(k):
            j = used[i]
            s0, s1, s2 = sv[r, j, 0], sv[r, j, 1], sv[r, j, 2]
            m2s[i, 0], m2s[i, 1], m2s[i, 2] = -2.0 * s0, -2.0 * s1, -2.0 * s2
            ss[i] = s0 * s0 + s1 * s1 + s2 * s2
            prc[i] = pr[r, j]
            scc[i] = scale[r, j]
            lsc[i] = log_scale[r, j]
            order[i] = i
        for p in range(n):  # element by element: no array views (reference counts)
            for i in range(d):
                xt[i, p] = x[r, p, i]
            for i in range(q):
                zt[i, p] = z[r, p, i]
        # Motion (pf._move / _move_fast).
        if cv:
            for i in range(3):
                for p in range(n):
                    xt[i, p] += xt[3 + i, p] * dt_s + c_pos * noise_std[r, p, i]
            for i in range(3):
                for p in range(n):
                    xt[3 + i, p] += c_vel * noise_std[r, p, 3 + i]
        else:
            for i in range(3):
                for p in range(n):
                    xt[i, p] += noise_std[r, p, i] * c_pos
        if has_drift:  # the prior mean b + d dt
            for i in range(n_clk):
                for p in range(n):
                    xt[clk0 + i, p] += xt[drift, p] * dt
        # Residuals (pf._residuals_fast: |s - r|^2 = -2 s.r + |r|^2 + |s|^2).
        for p in range(n):
            xx[p] = xt[0, p] * xt[0, p] + xt[1, p] * xt[1, p] + xt[2, p] * xt[2, p]
        for s in range(n_clk):
            for i in range(start[s], start[s + 1]):
                a0, a1, a2, ssi, pri = m2s[i, 0], m2s[i, 1], m2s[i, 2], ss[i], prc[i]
                for p in range(n):
                    r2 = a0 * xt[0, p] + a1 * xt[1, p] + a2 * xt[2, p]
                    r2 += xx[p]
                    r2 += ssi
                    res[i, p] = pri - math.sqrt(r2) - xt[clk0 + s, p]
        # The state equation's draw e = chol(S) z.
        for i in range(q):
            for p in range(n):
                ec[i, p] = 0.0
            for c in range(q):
                f = chol_s[r, i, c]
                for p in range(n):
                    ec[i, p] += f * zt[c, p]
        if informative[r]:
            for s in range(n_clk):  # each system's median
                _medians(res, start[s], start[s + 1] - start[s], order, buf, bufj, srt,
                         centre[s])
            for i in range(q):
                for p in range(n):
                    mu[i, p] = 0.0
                    et[i, p] = 0.0
                for c in range(q):
                    g, h = gain[r, i, c], chol_p[r, i, c]
                    for p in range(n):
                        mu[i, p] += g * centre[c, p]
                        et[i, p] += h * zt[c, p]
                for p in range(n):
                    et[i, p] = et[i, p] + mu[i, p]
                    if pick[r, p] < alpha:  # the prior component
                        et[i, p] = ec[i, p]
                    dv[i, p] = mu[i, p] - et[i, p]
            for p in range(n):
                qs[p] = 0.0
                qp[p] = 0.0
            for i in range(q):
                for p in range(n):
                    acc[p] = 0.0
                    acc2[p] = 0.0
                for c in range(q):
                    fs, fp = s_inv[r, i, c], p_inv[r, i, c]
                    for p in range(n):
                        acc[p] += fs * et[c, p]
                        acc2[p] += fp * dv[c, p]
                for p in range(n):
                    qs[p] += acc[p] * et[i, p]
                    qp[p] += acc2[p] * dv[i, p]
            hs, hp = hls[r], hlp[r]
            for p in range(n):
                log_s[r, p] = qs[p] * -0.5 - hs
                log_p[r, p] = qp[p] * -0.5 - hp + log_1ma
            for i in range(q):
                for p in range(n):
                    ec[i, p] = et[i, p]
        else:
            for p in range(n):
                log_s[r, p] = 0.0
                log_p[r, p] = 0.0
        for p in range(n):
            acc[p] = 0.0  # the sum of e
        for i in range(q):
            for p in range(n):
                xt[clk0 + i, p] += ec[i, p]
                acc[p] += ec[i, p]
        if has_drift:
            g = drift_gain[r]
            for p in range(n):
                xt[drift, p] += g * acc[p]
        for s in range(n_clk):
            for i in range(start[s], start[s + 1]):
                for p in range(n):
                    res[i, p] -= ec[s, p]
        # Log-likelihood, written out here (a call per particle costs more than it).
        for p in range(n):
            acc[p] = 0.0
        if mode == 0:  # Gaussian: pf._log_likelihood_rows's form
            for i in range(k):
                for p in range(n):
                    t = res[i, p] * inv_s
                    acc[p] += t * t
            for p in range(n):
                ll[r, p] = acc[p] * -0.5 - const * k
        elif mode == 1:
            # Student-t: sum ln(1 + t^2) as the log of a product, one logarithm per
            # particle instead of one per satellite (the same value to rounding), taken
            # early only before the product could overflow; the last one by the caller,
            # for all particles at once (student_t_ll).
            for p in range(n):
                acc2[p] = 1.0
            for i in range(k):
                for p in range(n):
                    t = res[i, p] * inv_s
                    f = 1.0 + t * t
                    if acc2[p] > 1e150 or f > 1e150:  # the product stays below 1e300
                        acc[p] += math.log(acc2[p])
                        acc2[p] = f
                    else:
                        acc2[p] *= f
            for p in range(n):
                ll[r, p] = acc[p]
                ll_prod[r, p] = acc2[p]
        else:  # noise.logpdf element by element (Scaled: base.logpdf(r / k) - ln k)
            for i in range(k):
                sc, ls = scc[i], lsc[i]
                if mode == 3:  # a scaled Gaussian: _logpdf's terms in its order
                    for p in range(n):
                        t = res[i, p] / sc / sigma
                        acc[p] += -0.5 * t * t - log_sigma - half_log_2pi - ls
                else:
                    for p in range(n):
                        acc[p] += (_logpdf(res[i, p] / sc, noise_kind, sigma, nu, eps,
                                           mix_scale, const) - ls)
            for p in range(n):
                ll[r, p] = acc[p]
        for p in range(n):
            for i in range(d):
                x[r, p, i] = xt[i, p]


@njit(cache=True, fastmath=False, error_model="numpy")
def normalise_rows(log_w, ll, log_ratio, x, log_w_floor, n_threshold, log_norm, n_eff, est,
                   need):
    """Weights of one step (:meth:`raimcore.algorithms.pf.ParticleBank._step_fast`).

    ``log_w`` (R, N): the previous log weights, replaced by the normalised new ones
    (floored at ``log_w_floor``); ``ll`` (R, N): the log-likelihoods, replaced by the
    normalised weights; ``log_ratio`` (R, N); ``x`` (R, N, D) particles. Outputs:
    ``log_norm``, ``n_eff`` (R,), ``est`` (R, D) the weighted mean, ``need`` (R,) bool
    ``n_eff < n_threshold``.
    """
    rows, n, d = x.shape
    for r in range(rows):
        top = -np.inf
        nan = False
        for p in range(n):
            v = ll[r, p] + log_w[r, p] + log_ratio[r, p]
            log_w[r, p] = v
            if v > top:
                top = v
            elif v != v:
                nan = True
        if nan or not math.isfinite(top):
            top = 0.0
        total = 0.0
        for p in range(n):
            w = math.exp(log_w[r, p] - top)
            ll[r, p] = w
            total += w
        lnorm = top + math.log(total)
        ss = 0.0
        for i in range(d):
            est[r, i] = 0.0
        for p in range(n):
            w = ll[r, p] / total
            ll[r, p] = w
            ss += w * w
            for i in range(d):
                est[r, i] += w * x[r, p, i]
            lw = log_w[r, p] - lnorm
            log_w[r, p] = lw if lw >= log_w_floor or lw != lw else log_w_floor
        log_norm[r] = lnorm
        n_eff[r] = 1.0 / ss
        need[r] = n_eff[r] < n_threshold


@njit(cache=True, fastmath=False, error_model="numpy")
def resample_rows(x, w, log_w, rows, u):
    """Systematic resampling of filters ``rows`` (G,) of ``x`` (R, N, D) in place, by
    counting each particle's copies ``ceil(N c_i - u) - ceil(N c_{i-1} - u)``
    (:func:`raimcore.algorithms.pf._resample_fast`, the same uniform draws ``u`` (G,));
    their log weights ``log_w`` (R, N) set to ``-ln N``."""
    _, n, d = x.shape
    c = np.empty(n)
    old = np.empty((n, d))
    for g in range(rows.shape[0]):
        r = rows[g]
        acc = 0.0
        for p in range(n):
            acc += w[r, p]
            c[p] = acc
        last = c[n - 1]
        for p in range(n):
            c[p] /= last
        c[n - 1] = 1.0
        for p in range(n):
            v = math.ceil(c[p] * n - u[g])
            c[p] = min(max(v, 0.0), float(n))
        for p in range(n):  # element by element: no array views (reference counts)
            for i in range(d):
                old[p, i] = x[r, p, i]
        k = 0
        prev = 0.0
        for p in range(n):
            copies = int(c[p] - prev)
            prev = c[p]
            for _ in range(copies):
                for i in range(d):
                    x[r, k, i] = old[p, i]
                k += 1
        lw = -math.log(n)
        for p in range(n):
            log_w[r, p] = lw


@njit(cache=True, fastmath=False, error_model="numpy")
def common_mode_screen(x, log_w, sv, pr, used, sys_idx, clk0, cv, has_drift, drift, dt_step,
                       threshold_m):
    """Whether :func:`raimcore.algorithms.pf._common_mode` may see a clock jump: the main
    filter's (``x[:, 0]``, ``log_w[:, 0]``) weighted-mean state, moved ``dt_step`` ahead,
    and its predicted residuals, as there; True where any used satellite's residual is
    above ``threshold_m`` less a margin of 1 m plus 1e-9 of the magnitudes involved (far
    above the rounding of these sums taken in another order), so that False means the
    exact computation finds no residual above ``threshold_m``: no jump.

    ``x`` (R, Q, N, D), ``log_w`` (R, Q, N), ``sv`` (S, 3), ``pr`` (R, S) (NaN: 0, as
    there), ``used`` (S,) bool, ``sys_idx`` (S,) int64.
    """
    rows, _, n, d = x.shape
    m = np.empty(d)
    for r in range(rows):
        for i in range(d):
            m[i] = 0.0
        for p in range(n):
            w = math.exp(log_w[r, 0, p])
            for i in range(d):
                m[i] += x[r, 0, p, i] * w
        p0, p1, p2 = m[0], m[1], m[2]
        if cv:
            p0 += m[3] * dt_step
            p1 += m[4] * dt_step
            p2 += m[5] * dt_step
        for j in range(sv.shape[0]):
            if not used[j]:
                continue
            clk = m[clk0 + sys_idx[j]]
            if has_drift:
                clk += m[drift] * dt_step
            y = pr[r, j]
            if y != y:
                y = 0.0
            e0, e1, e2 = sv[j, 0] - p0, sv[j, 1] - p1, sv[j, 2] - p2
            rng_m = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
            res = y - rng_m - clk
            if res != res:
                continue  # NaN: no jump there (pf.clock_jump)
            size = abs(y) + rng_m + abs(clk)
            if abs(res) > threshold_m - 1.0 - 1e-9 * size:
                return True
    return False


def student_t_ll(ll, ll_prod, mask, nu, const):
    """Finish :func:`propose_rows`'s Student-t log-likelihoods in place: ``ll`` (R, N)
    ``+= ln ll_prod``, times ``-(nu + 1) / 2``, plus ``const`` per satellite in ``mask``
    (R, S) (:func:`raimcore.algorithms.pf._log_likelihood_rows`'s form)."""
    np.log(ll_prod, out=ll_prod)
    ll += ll_prod
    ll *= -0.5 * (nu + 1)
    ll += const * mask.sum(-1)[:, None]
    return ll


def warm_up() -> None:
    """Compile (or load from the on-disk cache) the kernels for the argument types a bank
    step passes, on a tiny bank: a later first real step pays nothing."""
    from ..measure.noise import StudentT
    from .pf import ParticleBank, ProcessModel, _may_jump

    rng = np.random.default_rng(0)
    sv = np.array([[2.0e7, 0.0, 0.0], [0.0, 2.0e7, 0.0], [0.0, 0.0, 2.0e7],
                   [1.2e7, 1.2e7, 1.2e7]])
    x = np.zeros((2, 3, 8, 5))
    x[..., 4] = rng.normal(0.0, 0.1, x.shape[:-1])
    pr = np.linalg.norm(sv, axis=-1)
    for model in (ProcessModel("static", 1, q_drift_mps2=0.2), ProcessModel("cv", 2)):
        y = np.zeros(x.shape[:-1] + (model.dim,))
        bank = ParticleBank(y, model, n_threshold=8.0, kernel="numba")
        sys_idx = np.array([0, 0, 1, 1]) % model.n_clk
        bank.step(1.0, sv, pr, np.ones(4, bool), sys_idx, StudentT(3.0), rng)
        _may_jump(bank, 1.0, sv, np.tile(pr, (2, 1)), np.ones(4, bool), sys_idx)
