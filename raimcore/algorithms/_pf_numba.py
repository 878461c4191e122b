"""Compiled kernels of a particle-bank step (``ParticleBank(kernel="numba")``, :mod:`.pf`).

One pass over ``(filters, particles)`` does the per-particle work of the numpy fast kernel
(:func:`raimcore.algorithms.pf._propose_fast`) without temporaries: the motion, the
drift's prior mean, the residuals, each system's masked median, the clock proposal and
its importance ratio, the drift conditioning and the log-likelihood; a second pass
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


@njit(cache=True, fastmath=False, error_model="numpy")
def propose_rows(x, noise_std, z, pick, sv, pr, mask, sys_idx, n_clk, clk0, cv, dt_s,
                 c_pos, c_vel, has_drift, drift, dt, informative, chol_s, gain, chol_p,
                 s_inv, p_inv, hls, hlp, drift_gain, alpha, log_1ma, noise_kind,
                 scaled, sigma, nu, eps, mix_scale, const, scale, log_scale, log_s, log_p, ll,
                 ll_prod):
    """The clock proposal of every particle of every filter, in place
    (:func:`raimcore.algorithms.pf._propose_fast`, the same draws and formulas).

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
    rows, n, _ = x.shape
    s_n = sv.shape[1]
    mode = 2
    inv_s = 1.0
    if not scaled and noise_kind == NOISE_GAUSSIAN:
        mode, inv_s = 0, 1.0 / sigma
    elif not scaled and noise_kind == NOISE_STUDENT_T:
        mode, inv_s = 1, 1.0 / (sigma * math.sqrt(nu))
    resid = np.zeros(s_n)
    buf = np.empty(s_n)
    bufj = np.empty(s_n, dtype=np.int64)
    used = np.empty(s_n, dtype=np.int64)  # the row's satellites in mask, system by system
    order = np.empty(s_n, dtype=np.int64)  # the same, each system's in the last sort's order
    start = np.zeros(n_clk + 1, dtype=np.int64)
    m2s = np.empty((s_n, 3))
    ss = np.empty(s_n)
    centre = np.empty(n_clk)
    ec = np.empty(n_clk)
    et = np.empty(n_clk)
    mu = np.empty(n_clk)
    dv = np.empty(n_clk)
    for r in range(rows):
        k = 0
        for s in range(n_clk):
            start[s] = k
            for j in range(s_n):
                if mask[r, j] and sys_idx[j] == s:
                    used[k] = j
                    k += 1
        start[n_clk] = k
        order[:k] = used[:k]
        for j in range(s_n):
            s0, s1, s2 = sv[r, j, 0], sv[r, j, 1], sv[r, j, 2]
            m2s[j, 0], m2s[j, 1], m2s[j, 2] = -2.0 * s0, -2.0 * s1, -2.0 * s2
            ss[j] = s0 * s0 + s1 * s1 + s2 * s2
        inf = informative[r]
        for p in range(n):
            # No array views in this loop (each would count references): x[r, p, i].
            # Motion (pf._move / _move_fast).
            if cv:
                for i in range(3):
                    x[r, p, i] += x[r, p, 3 + i] * dt_s + c_pos * noise_std[r, p, i]
                for i in range(3):
                    x[r, p, 3 + i] += c_vel * noise_std[r, p, 3 + i]
            else:
                for i in range(3):
                    x[r, p, i] += noise_std[r, p, i] * c_pos
            if has_drift:  # the prior mean b + d dt
                for i in range(n_clk):
                    x[r, p, clk0 + i] += x[r, p, drift] * dt
            # Residuals (pf._residuals_fast: |s - r|^2 = -2 s.r + |r|^2 + |s|^2), of the
            # satellites in mask only: the others are never read (weight 0, no median).
            x0, x1, x2 = x[r, p, 0], x[r, p, 1], x[r, p, 2]
            xx = x0 * x0 + x1 * x1 + x2 * x2
            for i in range(k):
                j = used[i]
                r2 = m2s[j, 0] * x0 + m2s[j, 1] * x1 + m2s[j, 2] * x2
                r2 += xx
                r2 += ss[j]
                resid[j] = pr[r, j] - math.sqrt(r2) - x[r, p, clk0 + sys_idx[j]]
            # The state equation's draw e = chol(S) z.
            for i in range(n_clk):
                acc = 0.0
                for c in range(n_clk):
                    acc += chol_s[r, i, c] * z[r, p, c]
                ec[i] = acc
            ls = 0.0
            lp = 0.0
            if inf:
                for s in range(n_clk):  # each system's median
                    # Insertion sort, the satellites taken in the order that sorted the
                    # previous particle's residuals: the particles of a filter are close,
                    # so that order nearly sorts these too (few moves, branches that the
                    # processor predicts); the kept order is then this particle's.
                    kk = start[s + 1] - start[s]
                    for i in range(kk):
                        j = order[start[s] + i]
                        v = resid[j]
                        c = i
                        while c > 0 and buf[c - 1] > v:
                            buf[c] = buf[c - 1]
                            bufj[c] = bufj[c - 1]
                            c -= 1
                        buf[c] = v
                        bufj[c] = j
                    for i in range(kk):
                        order[start[s] + i] = bufj[i]
                    # The mean of the order statistics (k - 1) // 2 and k // 2, as the
                    # fast kernel's; 0 without a satellite.
                    centre[s] = (buf[(kk - 1) // 2] + buf[kk // 2]) * 0.5 if kk > 0 else 0.0
                for i in range(n_clk):
                    acc_mu = 0.0
                    acc_p = 0.0
                    for c in range(n_clk):
                        acc_mu += gain[r, i, c] * centre[c]
                        acc_p += chol_p[r, i, c] * z[r, p, c]
                    mu[i] = acc_mu
                    et[i] = acc_p + acc_mu
                if pick[r, p] < alpha:
                    for i in range(n_clk):
                        et[i] = ec[i]
                for i in range(n_clk):
                    dv[i] = mu[i] - et[i]
                qs = 0.0
                qp = 0.0
                for i in range(n_clk):
                    as_ = 0.0
                    ap = 0.0
                    for c in range(n_clk):
                        as_ += s_inv[r, i, c] * et[c]
                        ap += p_inv[r, i, c] * dv[c]
                    qs += as_ * et[i]
                    qp += ap * dv[i]
                ls = qs * -0.5 - hls[r]
                lp = qp * -0.5 - hlp[r] + log_1ma
                for i in range(n_clk):
                    ec[i] = et[i]
            log_s[r, p] = ls
            log_p[r, p] = lp
            esum = 0.0
            for i in range(n_clk):
                x[r, p, clk0 + i] += ec[i]
                esum += ec[i]
            if has_drift:
                x[r, p, drift] += drift_gain[r] * esum
            for i in range(k):
                j = used[i]
                resid[j] -= ec[sys_idx[j]]
            # Log-likelihood, written out here (a call per particle costs more than it).
            acc = 0.0
            if mode == 0:  # Gaussian: pf._log_likelihood_rows's form
                for i in range(k):
                    t = resid[used[i]] * inv_s
                    acc += t * t
                acc = acc * -0.5 - const * k
            elif mode == 1:
                # Student-t: sum ln(1 + t^2) as the log of a product, one logarithm per
                # particle instead of one per satellite (the same value to rounding),
                # taken early only before the product could overflow; the last one by the
                # caller, for all particles at once (student_t_ll).
                prod = 1.0
                for i in range(k):
                    t = resid[used[i]] * inv_s
                    f = 1.0 + t * t
                    if prod > 1e150 or f > 1e150:  # the product stays below 1e300
                        acc += math.log(prod)
                        prod = f
                    else:
                        prod *= f
                ll_prod[r, p] = prod
            else:  # noise.logpdf element by element (Scaled: base.logpdf(r / k) - ln k)
                for i in range(k):
                    j = used[i]
                    acc += (_logpdf(resid[j] / scale[r, j], noise_kind, sigma, nu, eps,
                                    mix_scale, const) - log_scale[r, j])
            ll[r, p] = acc


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
