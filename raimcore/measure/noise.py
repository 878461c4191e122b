"""Pseudorange noise models: Gaussian, Gaussian mixture and Student-t, white or time-correlated.

Each model draws samples with an explicit ``np.random.Generator`` and gives the log density
that a particle filter uses as its likelihood. ``sigma_m`` is the core (nominal) 1-sigma;
heavy-tailed models add outliers on top of it. The measure stage builds the model at a
reference scale and gives each pseudorange its own sigma from the scenario's error model
(:mod:`raimcore.measure.error_models`): a simulation draws ``sample() * sigma / sigma_m``.

**Time correlation.** Real pseudorange errors (multipath, residual troposphere and
ionosphere, broadcast orbit and clock) are correlated over minutes (fitted on the
recordings in ``../shared/data``: 236 s on SLAC, 1283 s on ESBC). With ``corr_s > 0`` a model
draws, per satellite, a first-order Gauss-Markov sequence along the epoch axis (axis -2):
``u_k = phi_k u_{k-1} + sqrt(1 - phi_k^2) w_k``, ``phi_k = exp(-(t_k - t_{k-1}) / corr_s)``,
``u_0, w_k ~ N(0, 1)``, mapped through the model's own quantile function
(``e = F^-1(Phi(u))``: a Gaussian copula). Every epoch keeps exactly the model's marginal
distribution, so snapshot tests keep their per-epoch false-alarm rate; what changes is the
dependence between epochs, which tests that sum over a window (PF-LLR) feel. For the
Gaussian model this is exactly the Gauss-Markov process with lag-``dt`` autocorrelation
``exp(-dt / corr_s)``. ``logpdf`` is always the marginal density (the filters treat the
noise as white; that mismatch is the point of studying it).

:class:`Scaled` gives a model a per-satellite scale (the error model's sigma over the
reference scale), and :func:`fit_gauss_markov` fits scale and correlation time to measured
error series.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from .._validate import check_choice, check_positive, check_probability

__all__ = ["Gaussian", "GaussianMixture", "StudentT", "make_noise", "gauss_markov_unit",
           "GaussMarkovFit", "fit_gauss_markov", "Scaled", "scaled", "NOISE_KINDS"]

NOISE_KINDS = ("gaussian", "mixture", "student-t")
_LOG_2PI = math.log(2.0 * math.pi)


def gauss_markov_unit(rng: np.random.Generator, shape, t_s, corr_s: float) -> np.ndarray:
    """Unit-variance first-order Gauss-Markov sequences along axis -2 of ``shape``.

    ``t_s`` holds the epoch times, shape ``(shape[-2],)``; ``corr_s`` > 0 is the
    correlation time. Every element is N(0, 1); the lag-one correlation between epochs
    ``k - 1`` and ``k`` is ``exp(-(t_k - t_{k-1}) / corr_s)``.
    """
    shape = tuple(np.atleast_1d(shape))
    if len(shape) < 2:
        raise ValueError("time-correlated noise needs a shape with an epoch axis (..., E, S)")
    t = np.asarray(t_s, dtype=float).reshape(-1)
    if t.shape[0] != shape[-2]:
        raise ValueError(f"t_s must have one time per epoch ({shape[-2]}), got {t.shape[0]}")
    if t.size > 1 and not np.all(np.diff(t) >= 0):
        raise ValueError("t_s must be non-decreasing")
    w = rng.standard_normal(shape)
    if t.size < 2:
        return w
    phi = np.exp(-np.diff(t) / corr_s)                 # (E - 1,)
    c = np.sqrt(1.0 - phi * phi)
    w = np.moveaxis(w, -2, 0)                          # (E, ..., S), a view
    if np.allclose(phi, phi[0], rtol=0.0, atol=1e-12):
        from scipy.signal import lfilter  # constant step: one C-level recursion

        x = w.copy()
        x[1:] *= c[0]
        u = lfilter([1.0], [1.0, -phi[0]], x, axis=0)
    else:
        u = np.empty_like(w)
        u[0] = w[0]
        for k in range(1, t.size):
            u[k] = phi[k - 1] * u[k - 1] + c[k - 1] * w[k]
    return np.moveaxis(u, 0, -2)


def _check_sample_args(model, shape, t_s):
    if model.corr_s > 0 and t_s is None:
        raise ValueError(f"noise with noise_corr_s = {model.corr_s} s (time-correlated) needs "
                         "the epoch times t_s to draw samples")


@dataclass(frozen=True)
class Gaussian:
    """White Gaussian noise N(0, sigma_m^2)."""

    sigma_m: float
    kind: str = "gaussian"
    corr_s: float = 0.0

    @property
    def std_m(self) -> float:
        """Standard deviation of the noise (m)."""
        return self.sigma_m

    def sample(self, rng: np.random.Generator, shape, t_s=None) -> np.ndarray:
        """Draw noise of ``shape``; with ``corr_s > 0``, correlated along axis -2 over the
        epoch times ``t_s`` (module doc)."""
        _check_sample_args(self, shape, t_s)
        if self.corr_s > 0:
            return self.from_normal(gauss_markov_unit(rng, shape, t_s, self.corr_s))
        return self.sigma_m * rng.standard_normal(shape)

    def from_normal(self, u) -> np.ndarray:
        """The model's quantile of ``Phi(u)``: standard normal ``u`` to this marginal."""
        return self.sigma_m * np.asarray(u)

    def logpdf(self, x_m) -> np.ndarray:
        z = np.asarray(x_m) / self.sigma_m
        return -0.5 * z * z - math.log(self.sigma_m) - 0.5 * _LOG_2PI


@dataclass(frozen=True)
class GaussianMixture:
    """(1 - eps) N(0, sigma^2) + eps N(0, (scale sigma)^2): a core plus rare wide outliers."""

    sigma_m: float
    eps: float = 0.1
    scale: float = 5.0
    kind: str = "mixture"
    corr_s: float = 0.0

    @property
    def std_m(self) -> float:
        return self.sigma_m * math.sqrt((1.0 - self.eps) + self.eps * self.scale**2)

    def sample(self, rng: np.random.Generator, shape, t_s=None) -> np.ndarray:
        """Draw noise of ``shape``; with ``corr_s > 0``, correlated along axis -2 over the
        epoch times ``t_s`` (module doc)."""
        _check_sample_args(self, shape, t_s)
        if self.corr_s > 0:
            return self.from_normal(gauss_markov_unit(rng, shape, t_s, self.corr_s))
        z = rng.standard_normal(shape)
        wide = rng.random(shape) < self.eps
        return self.sigma_m * np.where(wide, self.scale * z, z)

    def from_normal(self, u) -> np.ndarray:
        """The model's quantile of ``Phi(u)``: standard normal ``u`` to this marginal.

        The mixture has no closed-form quantile: it is solved by bisection on the lower
        tail ``log F(x) = log ndtr(-|u|)`` (64 halvings of [-40 scale sigma, 0]) on a grid
        of 4,097 values of |u| in [0, 38], and interpolated (the map is smooth; the grid
        error is below 1e-4 sigma).
        """
        u = np.asarray(u, dtype=float)
        grid = np.linspace(0.0, 38.0, 4097)
        p = special.log_ndtr(-grid)
        s1, s2 = self.sigma_m, self.sigma_m * self.scale
        lo = np.full(grid.shape, -40.0 * s2)
        hi = np.zeros(grid.shape)
        log_a, log_b = math.log1p(-self.eps), math.log(self.eps)
        for _ in range(64):
            mid = 0.5 * (lo + hi)
            log_f = np.logaddexp(log_a + special.log_ndtr(mid / s1),
                                 log_b + special.log_ndtr(mid / s2))
            below = log_f < p
            lo = np.where(below, mid, lo)
            hi = np.where(below, hi, mid)
        x_abs = -0.5 * (lo + hi)                      # quantile magnitude at each |u|
        return np.sign(u) * np.interp(np.abs(u), grid, x_abs)

    def logpdf(self, x_m) -> np.ndarray:
        x = np.asarray(x_m)
        s1, s2 = self.sigma_m, self.sigma_m * self.scale
        a = math.log1p(-self.eps) - 0.5 * (x / s1) ** 2 - math.log(s1)
        b = math.log(self.eps) - 0.5 * (x / s2) ** 2 - math.log(s2)
        return np.logaddexp(a, b) - 0.5 * _LOG_2PI


@dataclass(frozen=True)
class StudentT:
    """Student-t noise with ``nu`` degrees of freedom and scale ``sigma_m``."""

    sigma_m: float
    nu: float = 3.0
    kind: str = "student-t"
    corr_s: float = 0.0

    @property
    def std_m(self) -> float:
        return self.sigma_m * math.sqrt(self.nu / (self.nu - 2.0)) if self.nu > 2 else math.inf

    def sample(self, rng: np.random.Generator, shape, t_s=None) -> np.ndarray:
        """Draw noise of ``shape``; with ``corr_s > 0``, correlated along axis -2 over the
        epoch times ``t_s`` (module doc)."""
        _check_sample_args(self, shape, t_s)
        if self.corr_s > 0:
            return self.from_normal(gauss_markov_unit(rng, shape, t_s, self.corr_s))
        return self.sigma_m * rng.standard_t(self.nu, shape)

    def from_normal(self, u) -> np.ndarray:
        """The model's quantile of ``Phi(u)``: standard normal ``u`` to this marginal
        (through the lower tail, so that |u| up to about 37 keeps full precision)."""
        u = np.asarray(u, dtype=float)
        return -np.sign(u) * self.sigma_m * special.stdtrit(self.nu, special.ndtr(-np.abs(u)))

    def logpdf(self, x_m) -> np.ndarray:
        nu, s = self.nu, self.sigma_m
        z = np.asarray(x_m) / s
        c = (special.gammaln((nu + 1) / 2) - special.gammaln(nu / 2)
             - 0.5 * math.log(nu * math.pi) - math.log(s))
        return c - 0.5 * (nu + 1) * np.log1p(z * z / nu)


class Scaled:
    """A noise model with a per-satellite scale: ``e_i = k_i e`` with ``e`` from ``base``.

    On a recording the snapshot algorithms assume ``sigma_i = sigma_m k(el_i)`` (the
    elevation model); a filter's likelihood uses this wrapper to agree with them:
    ``logpdf(x) = base.logpdf(x / k) - ln k``, broadcast along the last (satellite) axis.
    ``sigma_m`` and ``corr_s`` stay the base model's.
    """

    def __init__(self, base, scale):
        self.base = base
        self.scale = np.asarray(scale, dtype=float)
        self._log_scale = np.log(self.scale)

    @property
    def kind(self) -> str:
        return self.base.kind

    @property
    def sigma_m(self) -> float:
        return self.base.sigma_m

    @property
    def corr_s(self) -> float:
        return self.base.corr_s

    @property
    def std_m(self):
        """Per-satellite standard deviation (m), shape of ``scale``."""
        return self.base.std_m * self.scale

    def sample(self, rng: np.random.Generator, shape, t_s=None) -> np.ndarray:
        return self.base.sample(rng, shape, t_s=t_s) * self.scale

    def logpdf(self, x_m) -> np.ndarray:
        return self.base.logpdf(np.asarray(x_m) / self.scale) - self._log_scale

    def __repr__(self) -> str:  # stable, short: it is part of PF-LLR's calibration key
        k = ",".join(f"{v:.2f}" for v in self.scale.reshape(-1))
        return f"Scaled({self.base!r}, scale=[{k}])"


def scaled(noise, scale):
    """``noise`` with per-satellite ``scale`` (:class:`Scaled`), or ``noise`` itself when
    ``scale`` is None or all ones (simulated scenarios: nothing changes)."""
    if scale is None:
        return noise
    k = np.asarray(scale, dtype=float)
    if np.all(k == 1.0):
        return noise
    if not np.all(np.isfinite(k) & (k > 0)):
        raise ValueError("noise scale must be finite and > 0 for every satellite")
    return Scaled(noise.base if isinstance(noise, Scaled) else noise,
                  k * (noise.scale if isinstance(noise, Scaled) else 1.0))


def make_noise(kind: str, sigma_m: float, *, mixture_eps: float = 0.1,
               mixture_scale: float = 5.0, student_nu: float = 3.0, corr_s: float = 0.0):
    """Build a noise model by name.

    Parameters
    ----------
    kind : ``"gaussian"``, ``"mixture"`` or ``"student-t"``.
    sigma_m : core 1-sigma (Gaussian, mixture core) or scale (Student-t), metres, > 0.
    mixture_eps : outlier probability of the mixture, in (0, 1).
    mixture_scale : outlier sigma as a multiple of ``sigma_m``, > 0.
    student_nu : degrees of freedom of the Student-t, > 0.
    corr_s : correlation time (s) of the time-correlated version (module doc), >= 0;
        0 (default) is white noise. The scenario key is ``noise_corr_s``.

    Raises
    ------
    ValueError naming the parameter that is out of range.
    """
    check_choice("noise", kind, NOISE_KINDS)
    sigma_m = check_positive("sigma_m", sigma_m)
    corr_s = check_positive("noise_corr_s", corr_s, allow_zero=True)
    if kind == "gaussian":
        return Gaussian(sigma_m, corr_s=corr_s)
    if kind == "mixture":
        return GaussianMixture(sigma_m, check_probability("mixture_eps", mixture_eps),
                               check_positive("mixture_scale", mixture_scale), corr_s=corr_s)
    return StudentT(sigma_m, check_positive("student_nu", student_nu), corr_s=corr_s)


@dataclass(frozen=True)
class GaussMarkovFit:
    """White-noise scale and first-order Gauss-Markov correlation fitted to error series.

    Attributes
    ----------
    sigma_m : robust scale, 1.4826 x the median absolute value (m, or units of the input).
    std_m : plain standard deviation (outliers included).
    rho : pooled correlation between consecutive epochs of the same satellite.
    dt_s : the epoch interval ``rho`` refers to (median step).
    corr_s : correlation time with ``exp(-dt_s / corr_s) = rho``; 0 when ``rho <= 0``
        (white), ``inf`` when ``rho >= 1``.
    n_samples, n_pairs : errors and consecutive pairs used.
    """

    sigma_m: float
    std_m: float
    rho: float
    dt_s: float
    corr_s: float
    n_samples: int
    n_pairs: int


#: Relative deviation from the median step within which two epochs are consecutive.
STEP_JITTER = 0.01


def fit_gauss_markov(errors, t_s) -> GaussMarkovFit:
    """Fit white scale and Gauss-Markov correlation to zero-mean error series.

    Parameters
    ----------
    errors : (E, S) errors, one column per satellite, NaN where there is none.
    t_s : (E,) epoch times (s), increasing. Pairs are consecutive rows one median step
        apart, within 1% (a gap breaks the pair; a receiver's jittered time tags, a phone's
        29.999 s and 30.001 s steps, do not).

    The correlation is pooled over satellites without removing each series' mean: a
    satellite's slowly varying bias (multipath, residual delays) is correlated error, which
    is what a windowed test feels.
    """
    z = np.asarray(errors, dtype=float)
    t = np.asarray(t_s, dtype=float).reshape(-1)
    if z.ndim != 2 or z.shape[0] != t.shape[0]:
        raise ValueError(f"errors must be (E, S) with E = len(t_s) = {t.shape[0]}, got "
                         f"{z.shape}")
    ok = np.isfinite(z)
    vals = z[ok]
    if vals.size < 2:
        raise ValueError("fit_gauss_markov needs at least 2 finite errors")
    sigma = float(1.4826 * np.median(np.abs(vals)))
    std = float(np.sqrt(np.mean(vals * vals)))
    steps = np.diff(t)
    dt = float(np.median(steps)) if steps.size else math.nan
    pair = ok[:-1] & ok[1:] & (np.abs(steps - dt) <= STEP_JITTER * dt)[:, None]
    a, b = z[:-1][pair], z[1:][pair]
    rho = float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b))) if a.size else math.nan
    if not np.isfinite(rho):
        corr = math.nan
    elif rho <= 0:
        corr = 0.0
    elif rho >= 1:
        corr = math.inf
    else:
        corr = -dt / math.log(rho)
    return GaussMarkovFit(sigma, std, rho, dt, corr, int(vals.size), int(a.size))
