"""Pseudorange noise models: Gaussian, Gaussian mixture and Student-t.

Each model draws samples with an explicit ``np.random.Generator`` and gives the log density
that a particle filter uses as its likelihood. ``sigma_m`` is the core (nominal) 1-sigma the
snapshot algorithms assume; heavy-tailed models add outliers on top of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import special

from ._validate import check_choice, check_positive, check_probability

__all__ = ["Gaussian", "GaussianMixture", "StudentT", "make_noise", "NOISE_KINDS"]

NOISE_KINDS = ("gaussian", "mixture", "student-t")
_LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True)
class Gaussian:
    """White Gaussian noise N(0, sigma_m^2)."""

    sigma_m: float
    kind: str = "gaussian"

    @property
    def std_m(self) -> float:
        """Standard deviation of the noise (m)."""
        return self.sigma_m

    def sample(self, rng: np.random.Generator, shape) -> np.ndarray:
        return self.sigma_m * rng.standard_normal(shape)

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

    @property
    def std_m(self) -> float:
        return self.sigma_m * math.sqrt((1.0 - self.eps) + self.eps * self.scale**2)

    def sample(self, rng: np.random.Generator, shape) -> np.ndarray:
        z = rng.standard_normal(shape)
        wide = rng.random(shape) < self.eps
        return self.sigma_m * np.where(wide, self.scale * z, z)

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

    @property
    def std_m(self) -> float:
        return self.sigma_m * math.sqrt(self.nu / (self.nu - 2.0)) if self.nu > 2 else math.inf

    def sample(self, rng: np.random.Generator, shape) -> np.ndarray:
        return self.sigma_m * rng.standard_t(self.nu, shape)

    def logpdf(self, x_m) -> np.ndarray:
        nu, s = self.nu, self.sigma_m
        z = np.asarray(x_m) / s
        c = (special.gammaln((nu + 1) / 2) - special.gammaln(nu / 2)
             - 0.5 * math.log(nu * math.pi) - math.log(s))
        return c - 0.5 * (nu + 1) * np.log1p(z * z / nu)


def make_noise(kind: str, sigma_m: float, *, mixture_eps: float = 0.1,
               mixture_scale: float = 5.0, student_nu: float = 3.0):
    """Build a noise model by name.

    Parameters
    ----------
    kind : ``"gaussian"``, ``"mixture"`` or ``"student-t"``.
    sigma_m : core 1-sigma (Gaussian, mixture core) or scale (Student-t), metres, > 0.
    mixture_eps : outlier probability of the mixture, in (0, 1).
    mixture_scale : outlier sigma as a multiple of ``sigma_m``, > 0.
    student_nu : degrees of freedom of the Student-t, > 0.

    Raises
    ------
    ValueError naming the parameter that is out of range.
    """
    check_choice("noise", kind, NOISE_KINDS)
    sigma_m = check_positive("sigma_m", sigma_m)
    if kind == "gaussian":
        return Gaussian(sigma_m)
    if kind == "mixture":
        return GaussianMixture(sigma_m, check_probability("mixture_eps", mixture_eps),
                               check_positive("mixture_scale", mixture_scale))
    return StudentT(sigma_m, check_positive("student_nu", student_nu))
