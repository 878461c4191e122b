"""Nominal pseudorange error models of ARAIM (ARAIM.md section 2) and MAAST's example ISM.

Integrity and accuracy variances per satellite are (``usrprocess_araim.m``)::

    C_int(i,i) = sigma_URA,i^2 + sigma_tropo,i^2 + sigma_user,i^2
    C_acc(i,i) = sigma_URE,i^2 + sigma_tropo,i^2 + sigma_user,i^2

so ``sigma_int_m = sqrt(C_int)`` and ``sigma_acc_m = sqrt(C_acc)`` are what
:func:`raimcore.araim.mhss` takes. Elevations in radians, vectorised, any shape.
"""

from __future__ import annotations

import numpy as np

from ..constants import F_L1_HZ, F_L5_HZ

__all__ = ["sigma_tropo_m", "sigma_mp_noise_m", "sigma_user_add_m", "sigma_user_ed259a_m",
           "MAAST_EXAMPLE_ISM", "IF_FACTOR", "GAL_USER_SIGMA_M", "TROPO_ZENITH_SIGMA_M"]

TROPO_ZENITH_SIGMA_M = 0.12  # troposphere residual at the zenith (m), RTCA DO-229 A.4.2.4
#: Iono-free (L1-L5) noise amplification, sqrt((f1^4 + f5^4) / (f1^2 - f5^2)^2) = 2.5883
#: (ARAIM.md section 2: variance factor 6.6994).
IF_FACTOR = float(np.sqrt((F_L1_HZ**4 + F_L5_HZ**4) / (F_L1_HZ**2 - F_L5_HZ**2) ** 2))

#: Galileo E1/E5a airborne sigma (m) at 5, 10, ..., 90 deg (B2012 / ADD; ARAIM.md
#: section 2), linearly interpolated in the elevation in degrees (held at its ends).
GAL_USER_SIGMA_M = (0.4529, 0.3553, 0.3063, 0.2638, 0.2593, 0.2555, 0.2504, 0.2438, 0.2396,
                    0.2359, 0.2339, 0.2302, 0.2295, 0.2278, 0.2297, 0.2310, 0.2274, 0.2277)
_GAL_EL_DEG = np.arange(5.0, 91.0, 5.0)


def sigma_tropo_m(el_rad):
    """Residual troposphere sigma (m): ``0.12 * 1.001 / sqrt(0.002001 + sin(el)^2)``.

    References: RTCA DO-229 A.4.2.4 (``af_trpmops.m``); ARAIM.md section 2.
    """
    s = np.sin(np.asarray(el_rad, dtype=float))
    return TROPO_ZENITH_SIGMA_M * 1.001 / np.sqrt(0.002001 + s * s)


def sigma_mp_noise_m(el_rad):
    """Single-frequency airborne multipath + noise sigma (m) of B2012 / the ADD (GPS
    curve): ``sqrt(sigma_MP^2 + sigma_N^2)``, ``sigma_MP = 0.13 + 0.53 exp(-theta/10)``,
    ``sigma_N = 0.15 + 0.43 exp(-theta/6.9)`` (theta in deg)."""
    theta = np.degrees(np.asarray(el_rad, dtype=float))
    return np.hypot(0.13 + 0.53 * np.exp(-theta / 10.0), 0.15 + 0.43 * np.exp(-theta / 6.9))


def sigma_user_add_m(el_rad, system):
    """Airborne dual-frequency (L1/E1-L5/E5a iono-free) user sigma of B2012 / the ADD (m).

    Parameters
    ----------
    el_rad : array, elevation (rad).
    system : ``"GPS"`` or ``"GAL"`` (a string, or an array of them broadcast with
        ``el_rad``). GPS: ``2.5883 sqrt(sigma_MP^2 + sigma_N^2)``, ``sigma_MP = 0.13 +
        0.53 exp(-theta/10)``, ``sigma_N = 0.15 + 0.43 exp(-theta/6.9)`` (theta in deg);
        Galileo: linear interpolation of the 5-deg table (clamped to 5..90 deg).

    Raises
    ------
    ValueError for another system.
    """
    theta = np.degrees(np.asarray(el_rad, dtype=float))
    sysv = np.asarray(system)
    bad = ~np.isin(sysv, ("GPS", "GAL"))
    if np.any(bad):
        raise ValueError(f"system must be GPS or GAL, got {np.unique(sysv[bad])!r}")
    gps = IF_FACTOR * sigma_mp_noise_m(el_rad)
    gal = np.interp(theta, _GAL_EL_DEG, GAL_USER_SIGMA_M)
    return np.where(sysv == "GPS", gps, gal)


def sigma_user_ed259a_m(el_rad):
    """ED-259A dual-frequency airborne sigma (m), every constellation (MAAST v5).

    ``sigma^2 = 0.4^2 + (0.34 + 0.40 exp(-theta/14))^2 + (40/(261 + theta^2) + 0.018)^2``
    (theta in deg; ``af_cnmp_259a.m`` x GAMMA_L1_L5 plus ``sig_uire_df`` of
    ``usrprocess_araim.m``).
    """
    theta = np.degrees(np.asarray(el_rad, dtype=float))
    cnmp = 0.4**2 + (0.34 + 0.40 * np.exp(-theta / 14.0)) ** 2
    iono = (40.0 / (261.0 + theta**2) + 0.018) ** 2
    return np.sqrt(cnmp + iono)


#: MAAST's example ISD (``main_maast_araim.m``; ARAIM.md section 10), per constellation:
#: sigma_URA / sigma_URE (m), b_nom (m), P_sat = R_sat x MFD_sat, P_const = R_const x
#: MFD_const, and the mean fault durations (s) for tau = T_exp / MFD.
MAAST_EXAMPLE_ISM = {
    "GPS": {"sigma_ura_m": 2.4, "sigma_ure_m": 2.4, "b_nom_m": 0.0, "p_sat": 1e-5,
            "p_const": 1e-8, "mfd_sat_s": 3600.0, "mfd_const_s": 3600.0},
    "GAL": {"sigma_ura_m": 6.0, "sigma_ure_m": 4.0, "b_nom_m": 0.0, "p_sat": 3e-5,
            "p_const": 2e-4, "mfd_sat_s": 5400.0, "mfd_const_s": 7200.0},
}
