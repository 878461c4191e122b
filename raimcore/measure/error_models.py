"""Pseudorange error models: the 1-sigma of every pseudorange, per satellite and epoch.

The scenario key ``error_model`` chooses a model. The measure stage sets
``Measurements.sigma_m`` (E, S) from it, which every algorithm assumes; on a simulated sky
it also draws the noise with that sigma (the noise's distribution and time correlation
stay those of the ``noise`` keys, :mod:`raimcore.measure.noise`), so a simulation and
the algorithms agree unless the user makes them differ.

Models (``el`` the elevation, ``theta`` the same in degrees, ``s`` the satellite's system;
the elevation is floored at 2 degrees as in :func:`raimcore.sky.spp.elevation_sigma`):

``uniform``
    ``sigma_m`` for every pseudorange (the RAIM papers' simulations, e.g. 33 m of SA).
``elevation``
    ``sigma_m * sqrt((1 + 1/sin^2 el) / 2)``: ``sigma_m`` at the zenith
    (:func:`raimcore.sky.spp.elevation_sigma`).
``rtklib``
    ``sigma^2 = F_s^2 (a^2 + b^2 / sin^2 el)``, ``a = b = 100 x 0.003 m = 0.3 m``: RTKLIB's
    code error model with its default options (:func:`rtklib_sigma` has the sources).
``broadcast``
    ``sigma^2 = URA^2 + sigma_tropo^2 + sigma_user^2``: the broadcast URA / SISA of the
    navigation record (``Sky.ura_m``; a simulated sky, or a record without one, takes
    :data:`URA_DEFAULT_M`), the troposphere residual and the multipath + noise of
    ``../shared/ARAIM.md`` section 2 (:func:`broadcast_sigma`).
``measured``
    ``a_s + b_s / sin el`` per system, fitted on the recording itself
    (:func:`fit_elevation_sigma`, :func:`measured_fits`); recordings only.
``araim``
    ``sigma^2 = sigma_URE^2 + sigma_tropo^2 + sigma_user^2``: ARAIM's nominal accuracy
    model (``../shared/ARAIM.md`` section 2, ``C_acc``) with the scenario's integrity
    support message (key ``ism``, :class:`Ism`) and airborne user model (key
    ``user_model``, :func:`araim_user_sigma`). A simulation draws its noise with this
    sigma; the ``araim`` algorithm bounds it with ``sigma_URA`` (``C_int``,
    :func:`araim_sigmas`).
``auto`` (the default)
    ``araim`` when the algorithm is ``araim``; otherwise ``uniform`` on a simulated sky,
    ``elevation`` on a recording: what every run did before the key existed.

``sigma_m`` sets the scale of ``uniform`` and ``elevation`` only; the other models set
every sigma themselves.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import nnls

from ..araim.error_model import (
    GAL_USER_SIGMA_M,
    sigma_mp_noise_m,
    sigma_tropo_m,
    sigma_user_add_m,
    sigma_user_ed259a_m,
)
from ..araim.error_model import IF_FACTOR as IONO_FREE_FACTOR
from ..sky.spp import elevation_sigma
from .errors import clock_free_errors

__all__ = ["ERROR_MODELS", "resolve_model", "uniform_sigma", "elevation_sigma",
           "rtklib_sigma", "tropo_sigma", "user_sigma", "broadcast_sigma", "ElevationFit",
           "fit_elevation_sigma", "measured_fits", "model_sigma", "URA_DEFAULT_M",
           "RTKLIB_EFACT", "MEASURED_BIN_EDGES_DEG", "USER_MODELS", "IsmEntry", "Ism",
           "MAAST_ISM", "parse_ism", "araim_user_sigma", "araim_sigmas",
           "GAL_USER_SIGMA_M", "ism_help", "ISM_FIELDS"]

#: The choices of the scenario key ``error_model`` (module doc).
ERROR_MODELS = ("auto", "uniform", "elevation", "rtklib", "broadcast", "measured", "araim")
#: The choices of the scenario key ``user_model`` (ARAIM's airborne multipath + noise).
USER_MODELS = ("add", "ed259a")

#: Lowest elevation a model is evaluated at (rad): as :func:`~raimcore.sky.spp.elevation_sigma`.
EL_FLOOR_RAD = math.radians(2.0)

# RTKLIB 2.4.2 / 2.4.3 (github.com/tomojitakasu/RTKLIB), default processing options.
RTKLIB_ERATIO = 100.0  # src/rtkcmn.c prcopt_default: eratio[0], code/phase error ratio L1
RTKLIB_ERR_A_M = 0.003  # src/rtkcmn.c prcopt_default: err[1], phase error factor a (m)
RTKLIB_ERR_B_M = 0.003  # src/rtkcmn.c prcopt_default: err[2], phase error factor b (m)
#: Error factor per system, src/rtklib.h EFACT_GPS 1.0, EFACT_GLO 1.5, EFACT_GAL 1.0,
#: EFACT_CMP 1.0 (src/rtkpos.c varerr applies EFACT_GLO, EFACT_SBS, else EFACT_GPS).
RTKLIB_EFACT = {"GPS": 1.0, "GLO": 1.5, "GAL": 1.0, "BDS": 1.0}

# The ARAIM.md section 2 formulas (troposphere, multipath + noise, the iono-free factor,
# the Galileo table) have one home, raimcore.araim.error_model; the models here floor the
# elevation at EL_FLOOR_RAD before calling them.
#: Broadcast URA (m) assumed where the navigation record gives none (a simulated sky;
#: GLONASS records of RINEX 3, which carry no F_T): GPS 2.4 m and Galileo 6 m are the
#: MAAST example ISD values of ARAIM.md section 10 (sigma_URA); BeiDou takes the GPS
#: value (its URA index table is the GPS one, BDS-SIS-ICD-B1I 3.0 5.2.4.5, and its
#: satellites broadcast index 0, ~2 m); GLONASS, without an ISM there, takes Galileo's
#: conservative 6 m.
URA_DEFAULT_M = {"GPS": 2.4, "GAL": 6.0, "BDS": 2.4, "GLO": 6.0}

#: Elevation bins (deg) of the ``measured`` fit: 5-degree bins low, where sigma changes
#: fast, wider ones high.
MEASURED_BIN_EDGES_DEG = (0.0, 10.0, 15.0, 20.0, 25.0, 30.0, 40.0, 50.0, 60.0, 75.0, 90.0)
#: Fewest errors in a bin for its scale to enter the fit (the MAD's relative standard
#: error is ~1.2 / sqrt(n): 20% at 30).
MEASURED_MIN_PER_BIN = 30
#: Re-weightings of the ``measured`` fit (the clock of each epoch is removed with the
#: weights of the previous fit; two steps already change the coefficients by < 1 cm).
MEASURED_ITERATIONS = 3
#: Normal consistency factor of the median absolute deviation.
MAD_TO_SIGMA = 1.4826


def resolve_model(name: str, recorded: bool, algorithm: str | None = None) -> str:
    """The model ``auto`` stands for (``araim`` under the ``araim`` algorithm, else
    ``elevation`` on a recording and ``uniform`` on a simulated sky); any other name
    unchanged."""
    if name == "auto":
        if algorithm == "araim":
            return "araim"
        return "elevation" if recorded else "uniform"
    return name


def _sin_el(el_rad) -> np.ndarray:
    return np.maximum(np.sin(np.asarray(el_rad, dtype=float)), math.sin(EL_FLOOR_RAD))


def _floored(el_rad) -> np.ndarray:
    """The elevation, at least :data:`EL_FLOOR_RAD` (rad)."""
    return np.arcsin(_sin_el(el_rad))


def uniform_sigma(el_rad, sigma_m: float) -> np.ndarray:
    """``sigma_m`` in the shape of ``el_rad``."""
    return np.full(np.shape(el_rad), float(sigma_m))


def rtklib_sigma(el_rad, efact=1.0, *, eratio: float = RTKLIB_ERATIO,
                 a_m: float = RTKLIB_ERR_A_M, b_m: float = RTKLIB_ERR_B_M) -> np.ndarray:
    """RTKLIB's code (pseudorange) 1-sigma (m): ``F sqrt(a^2 + b^2 / sin^2 el)`` with
    ``a = eratio a_m``, ``b = eratio b_m`` (0.3 m each with the defaults).

    ``efact`` (scalar or broadcasting with ``el_rad``) is the system's error factor
    (:data:`RTKLIB_EFACT`). This is ``varerr()`` of RTKLIB's ``src/rtkpos.c`` for a code
    observation (``fact = eratio[0] * EFACT``, ``a = fact * err[1]``, ``b = fact * err[2]``,
    ``a*a + b*b/sinel/sinel``) for one receiver: the factor 2 there is for a single
    difference of two receivers, and the iono-free factor 3 does not apply to the
    single-frequency pseudoranges used here. Defaults from ``src/rtkcmn.c``
    ``prcopt_default`` (``eratio {100, 100}``, ``err {100, 0.003, 0.003, 0, 1}``; RTKLIB
    manual 2.4.2, options ``stats-eratio1``, ``stats-errphase``, ``stats-errphaseel``).
    RTKLIB's single-point positioning (``src/pntpos.c`` ``varerr()``) writes its code
    variance as ``EFACT^2 err[0]^2 (err[1]^2 + err[2]^2 / sin el)`` instead, with ``sin el``
    not squared (1.0x at the zenith, 0.45x at 10 degrees of this model), and adds the
    broadcast ephemeris, ionosphere and troposphere variances; this model is the
    measurement term alone.

    >>> print(f"{float(rtklib_sigma(math.radians(90.0))):.4f} m at the zenith")
    0.4243 m at the zenith
    """
    s = _sin_el(el_rad)
    a, b = eratio * a_m, eratio * b_m
    return np.asarray(efact, dtype=float) * np.sqrt(a * a + b * b / (s * s))


def tropo_sigma(el_rad) -> np.ndarray:
    """Troposphere residual 1-sigma (m): ``0.12 * 1.001 / sqrt(0.002001 + sin^2 el)``
    (ARAIM.md section 2, MAAST ``af_trpmops.m``; RTCA DO-229 A.4.2.4 mapping)."""
    return sigma_tropo_m(_floored(el_rad))


def user_sigma(el_rad, *, iono_free: bool = False) -> np.ndarray:
    """Airborne multipath + receiver noise 1-sigma (m) by elevation, ARAIM.md section 2
    (B2012 / the ADD, GPS): ``sqrt(sigma_MP^2 + sigma_N^2)`` with
    ``sigma_MP = 0.13 + 0.53 exp(-theta/10)``, ``sigma_N = 0.15 + 0.43 exp(-theta/6.9)``.

    ``iono_free`` multiplies by the L1/L5 iono-free factor :data:`IONO_FREE_FACTOR`
    (2.5883), as ARAIM.md's dual-frequency user does; the pseudoranges of this project are
    single-frequency (L1 C/A, B1I, E1, GLONASS L1), so the ``broadcast`` model leaves it
    out.
    """
    out = sigma_mp_noise_m(_floored(el_rad))
    return out * IONO_FREE_FACTOR if iono_free else out


def broadcast_sigma(el_rad, ura_m) -> np.ndarray:
    """``sqrt(URA^2 + sigma_tropo^2 + sigma_user^2)`` (m), ARAIM.md section 2's
    ``C_int`` diagonal with the broadcast URA as ``sigma_URA`` (:func:`tropo_sigma`,
    :func:`user_sigma`, single-frequency). The single-frequency ionosphere residual
    (Klobuchar) is not part of this (dual-frequency) model."""
    ura = np.asarray(ura_m, dtype=float)
    return np.sqrt(ura * ura + tropo_sigma(el_rad) ** 2 + user_sigma(el_rad) ** 2)


# -- ARAIM: the integrity support message and the nominal user model (ARAIM.md sections 1, 2)


#: The per-system fields of the ISM: (name, unit, lo, hi, help), the one declaration that
#: the parser, the messages and the docs read.
ISM_FIELDS = (
    ("sigma_ura_m", "m", 0.0, 1.0e3, "integrity 1-sigma of the orbit and clock error"),
    ("sigma_ure_m", "m", 0.0, 1.0e3, "accuracy (continuity) 1-sigma of the orbit and clock "
                                     "error"),
    ("b_nom_m", "m", 0.0, 1.0e2, "nominal bias bound, integrity"),
    ("b_cont_m", "m", 0.0, 1.0e2, "nominal bias bound, accuracy and continuity"),
    ("p_sat", "", 0.0, 1.0e-3, "prior probability of a satellite fault (above 1e-3 the "
                               "fault modes to monitor grow combinatorially)"),
    ("p_const", "", 0.0, 1.0e-2, "prior probability of a constellation-wide fault"),
    ("mfd_sat_s", "s", 0.0, 1.0e7, "mean duration of a satellite fault (with the option "
                                   "t_exp_s)"),
    ("mfd_const_s", "s", 0.0, 1.0e7, "mean duration of a constellation fault"),
)
_ISM_NAMES = tuple(f[0] for f in ISM_FIELDS)


@dataclass(frozen=True)
class IsmEntry:
    """The ISM of one constellation (ARAIM.md section 1): every satellite of it gets
    ``sigma_ura_m``, ``sigma_ure_m``, ``b_nom_m``, ``b_cont_m``, ``p_sat``; the
    constellation ``p_const``. ``mfd_*_s`` (mean fault durations) set the exposure factor
    ``tau = t_exp / MFD`` of the ``araim`` option ``t_exp_s`` (0 in the LPV-200 baseline).
    """

    sigma_ura_m: float
    sigma_ure_m: float
    b_nom_m: float
    b_cont_m: float
    p_sat: float
    p_const: float
    mfd_sat_s: float
    mfd_const_s: float


#: MAAST's example ISD (ARAIM.md section 10; ``maast_for_araim_2`` ``main_maast_araim.m``,
#: "based on current draft of ICAO Annex 10 default ISD (June 2024)"; P = rate x MFD):
#: GPS sigma_URA 2.4 m, sigma_URE 2.4 m, b_nom 0, P_sat 1e-5, P_const 1e-8, MFD 1 h / 1 h;
#: Galileo 6 m, 4 m, 0, 3e-5, 2e-4, MFD 1.5 h / 2 h; GLONASS (same file) 9 m, 8 m, 0,
#: 3.4e-5/h x 3 h = 1.02e-4, 1e-5/h x 10 h = 1e-4, MFD 3 h / 10 h; b_cont 0 (absent).
#: MAAST gives BeiDou sigma_URA = inf (not used): BeiDou takes the Galileo values here, an
#: assumption of this project (a constellation fault is then a monitored mode).
#: These are H-ARAIM-grade values: with them the vertical LPV-200 criteria are not met
#: (VPL about 45 m, sigma_acc about 4 m for GPS + Galileo).
MAAST_ISM_VALUES = {
    "GPS": IsmEntry(2.4, 2.4, 0.0, 0.0, 1e-5, 1e-8, 3600.0, 3600.0),
    "GAL": IsmEntry(6.0, 4.0, 0.0, 0.0, 3e-5, 2e-4, 5400.0, 7200.0),
    "BDS": IsmEntry(6.0, 4.0, 0.0, 0.0, 3e-5, 2e-4, 5400.0, 7200.0),
    "GLO": IsmEntry(9.0, 8.0, 0.0, 0.0, 1.02e-4, 1e-4, 10800.0, 36000.0),
}
#: Systems of the ISM, in the order of the scenario's systems key.
ISM_SYSTEMS = ("GPS", "BDS", "GAL", "GLO")
_SYSTEM_ALIASES = {"GALILEO": "GAL", "GLONASS": "GLO", "BEIDOU": "BDS", "NAVSTAR": "GPS",
                   "E": "GAL", "R": "GLO", "C": "BDS", "G": "GPS"}


def _fmt(x: float) -> str:
    return repr(float(x))  # exact, and a TOML float


@dataclass(frozen=True)
class Ism:
    """An integrity support message: one :class:`IsmEntry` per system (GPS, BDS, GAL,
    GLO), the value of the scenario key ``ism``.

    ``ism["GAL"]`` gives a system's entry; :meth:`to_dict` the TOML table
    (``{GPS = {sigma_ura_m = 2.4, ...}, ...}``) that :func:`parse_ism` reads back;
    ``str()`` is ``maast`` for :data:`MAAST_ISM`, else the entries that differ from it.
    """

    entries: tuple[tuple[str, IsmEntry], ...]

    def __getitem__(self, system: str) -> IsmEntry:
        return dict(self.entries)[system]

    def to_dict(self) -> dict[str, dict[str, float]]:
        return {s: dataclasses.asdict(e) for s, e in self.entries}

    def per_sat(self, systems, sys_idx) -> dict[str, np.ndarray]:
        """Each field as a per-satellite array ``(S,)`` (``sys_idx`` into ``systems``)."""
        rows = [self[systems[j]] for j in np.asarray(sys_idx, dtype=int)]
        return {n: np.array([getattr(r, n) for r in rows], dtype=float) for n in _ISM_NAMES}

    def per_system(self, systems) -> dict[str, np.ndarray]:
        """Each field as a per-system array ``(len(systems),)``."""
        return {n: np.array([getattr(self[s], n) for s in systems], dtype=float)
                for n in _ISM_NAMES}

    def __str__(self) -> str:
        base = dict(MAAST_ISM.entries)
        diff = []
        for s, e in self.entries:
            changed = [f"{n} = {_fmt(getattr(e, n))}" for n in _ISM_NAMES
                       if getattr(e, n) != getattr(base[s], n)]
            if changed:
                diff.append(f"{s} = {{{', '.join(changed)}}}")
        return "maast" if not diff else "{" + ", ".join(diff) + "}"


MAAST_ISM = Ism(tuple((s, MAAST_ISM_VALUES[s]) for s in ISM_SYSTEMS))


def parse_ism(name: str, value) -> Ism:
    """The scenario key ``ism``: ``"maast"`` (MAAST's example, :data:`MAAST_ISM`) or a table
    ``{GAL = {sigma_ura_m = 4.0, p_const = 1e-4}, ...}`` whose values replace those of the
    MAAST example (systems and fields not given keep it); an :class:`Ism` unchanged.

    Raises
    ------
    SchemaError
        An unknown system or field (with a "did you mean"), or a value outside its range
        (:data:`ISM_FIELDS`); one line naming ``ism.SYSTEM.field``.
    """
    from ..schema import SchemaError, coerce_float, did_you_mean

    if isinstance(value, Ism):
        return value
    if isinstance(value, str):
        if value.strip().lower() == "maast":
            return MAAST_ISM
        raise SchemaError(f"{name} must be \"maast\" or a table such as {{GAL = "
                          f"{{sigma_ura_m = 4.0}}}}, got {value!r}")
    if not isinstance(value, dict):
        raise SchemaError(f"{name} must be \"maast\" or a table of systems, e.g. {{GAL = "
                          f"{{sigma_ura_m = 4.0}}}}, got {value!r}"[:200])
    out = {s: dataclasses.asdict(e) for s, e in MAAST_ISM.entries}
    bounds = {f[0]: f for f in ISM_FIELDS}
    for system, fields_ in value.items():
        if system not in out:
            alias = _SYSTEM_ALIASES.get(str(system).upper())
            hint = f" (did you mean {alias!r}?)" if alias else did_you_mean(str(system), out)
            raise SchemaError(f"{name}: unknown system {system!r}; systems: "
                              f"{', '.join(ISM_SYSTEMS)}{hint}")
        if isinstance(fields_, IsmEntry):
            fields_ = dataclasses.asdict(fields_)
        if not isinstance(fields_, dict):
            raise SchemaError(f"{name}.{system} must be a table of ISM values, e.g. "
                              f"{{sigma_ura_m = 4.0}}, got {fields_!r}"[:200])
        for field_name, v in fields_.items():
            if field_name not in bounds:
                raise SchemaError(f"{name}.{system}: unknown field {field_name!r}; fields: "
                                  f"{', '.join(_ISM_NAMES)}"
                                  f"{did_you_mean(str(field_name), bounds)}")
            _, unit, lo, hi, _ = bounds[field_name]
            out[system][field_name] = coerce_float(f"{name}.{system}.{field_name}", v, lo,
                                                   hi, unit=unit)
    return Ism(tuple((s, IsmEntry(**out[s])) for s in ISM_SYSTEMS))


def ism_help() -> str:
    """The fields of the ``ism`` key and the default, in words (the key's help)."""
    fields_ = ", ".join(f"{n} [{u}]" if u else n for n, u, *_ in ISM_FIELDS)
    g, e, r = (MAAST_ISM_VALUES[s] for s in ("GPS", "GAL", "GLO"))
    return (f"ARAIM integrity support message per system, {{GPS = {{...}}, GAL = {{...}}}}, "
            f"fields {fields_}; given values replace MAAST's example (\"maast\": sigma_URA "
            f"GPS {g.sigma_ura_m:g} / GAL {e.sigma_ura_m:g} m, sigma_URE {g.sigma_ure_m:g} / "
            f"{e.sigma_ure_m:g} m, b 0, P_sat {g.p_sat:g} / {e.p_sat:g}, P_const "
            f"{g.p_const:g} / {e.p_const:g}, MFD sat {g.mfd_sat_s:g} / {e.mfd_sat_s:g} s, "
            f"const {g.mfd_const_s:g} / {e.mfd_const_s:g} s; GLO {r.sigma_ura_m:g}, "
            f"{r.sigma_ure_m:g} m, {r.p_sat:g}, {r.p_const:g}; BDS as GAL, assumed)")


def araim_user_sigma(el_rad, system, user_model: str = "add") -> np.ndarray:
    """Airborne multipath + noise 1-sigma (m) of the dual-frequency ARAIM user
    (ARAIM.md section 2), ``el_rad`` any shape (floored at 2 deg, as every model here).

    ``user_model``:

    ``"add"``
        B2012 / the ADD: GPS ``2.5883 sqrt(sigma_MP^2 + sigma_N^2)`` (:func:`user_sigma`
        with the L1/L5 iono-free factor); Galileo the E1/E5a table
        :data:`GAL_USER_SIGMA_M`, linear in the elevation in degrees (held at its ends).
        BeiDou and GLONASS take the GPS curve (as MAAST's ``usrprocess_araim.m`` does).
    ``"ed259a"``
        MAAST v5 (``af_cnmp_259a.m`` x GAMMA_L1_L5 + ``sig_uire_df``), every system:
        ``sigma^2 = 0.4^2 + (0.34 + 0.40 exp(-theta/14))^2 + (40/(261 + theta^2) + 0.018)^2``.

    >>> print(f"{float(araim_user_sigma(math.radians(90.0), 'GAL')):.4f}")
    0.2277
    """
    el = _floored(el_rad)
    if user_model == "ed259a":
        return sigma_user_ed259a_m(el)
    if user_model != "add":
        raise ValueError(f"user_model must be one of {', '.join(USER_MODELS)}, got "
                         f"{user_model!r}")
    return sigma_user_add_m(el, "GAL" if system == "GAL" else "GPS")


def araim_sigmas(el_rad, systems, sys_idx, ism: Ism = MAAST_ISM,
                 user_model: str = "add") -> tuple[np.ndarray, np.ndarray]:
    """ARAIM's nominal 1-sigmas (m) of every pseudorange, ARAIM.md section 2.

    Parameters
    ----------
    el_rad : (..., S) elevations; ``sys_idx`` (S,) into ``systems`` (system names).
    ism : the integrity support message; ``user_model`` ``"add"`` or ``"ed259a"``
        (:func:`araim_user_sigma`).

    Returns
    -------
    sigma_int_m, sigma_acc_m : (..., S), ``sqrt(sigma_URA^2 + sigma_tropo^2 +
    sigma_user^2)`` (the diagonal of C_int) and the same with ``sigma_URE`` (C_acc).
    """
    el = np.asarray(el_rad, dtype=float)
    sys_idx = np.asarray(sys_idx, dtype=int)
    local = np.zeros(el.shape)
    for j, name in enumerate(systems):
        col = sys_idx == j
        if col.any():
            local[..., col] = araim_user_sigma(el[..., col], name, user_model) ** 2
    local += tropo_sigma(el) ** 2
    p = ism.per_sat(systems, sys_idx)
    return (np.sqrt(p["sigma_ura_m"] ** 2 + local), np.sqrt(p["sigma_ure_m"] ** 2 + local))


@dataclass(frozen=True)
class ElevationFit:
    """``sigma(el) = a_m + b_m / sin(el)`` fitted to robust scales in elevation bins.

    Attributes
    ----------
    a_m, b_m : coefficients (m), both >= 0.
    bins_deg : ((lo, hi), ...) the elevation bins (deg) that entered the fit.
    bin_sigma_m : robust 1-sigma of each bin (``1.4826 median |error|``, m).
    bin_n : errors in each bin.
    n_samples : errors in all (including those of bins too thin to enter).
    """

    a_m: float
    b_m: float
    bins_deg: tuple[tuple[float, float], ...]
    bin_sigma_m: tuple[float, ...]
    bin_n: tuple[int, ...]
    n_samples: int

    def sigma(self, el_rad) -> np.ndarray:
        """The fitted 1-sigma (m) at elevations ``el_rad`` (any shape)."""
        return self.a_m + self.b_m / _sin_el(el_rad)

    def describe(self) -> str:
        """``sigma = a + b/sin(el) m`` and the bins, for a note."""
        bins = ", ".join(f"{lo:g}-{hi:g} deg {s:.2f} m (n {n})" for (lo, hi), s, n
                         in zip(self.bins_deg, self.bin_sigma_m, self.bin_n, strict=True))
        return f"sigma = {self.a_m:.3f} + {self.b_m:.3f}/sin(el) m; bins: {bins}"


def fit_elevation_sigma(err_m, el_rad, *, edges_deg=MEASURED_BIN_EDGES_DEG,
                        min_per_bin: int = MEASURED_MIN_PER_BIN) -> ElevationFit:
    """Fit ``sigma(el) = a + b / sin el`` to zero-mean errors, robustly.

    Parameters
    ----------
    err_m : (N,) errors (m), each with the variance of the error itself (e.g. from
        :func:`raimcore.measure.errors.clock_free_errors`); non-finite values are ignored.
    el_rad : (N,) their elevations (rad).
    edges_deg : increasing bin edges (deg).
    min_per_bin : fewest errors for a bin to enter the fit.

    Each bin's scale is ``1.4826 median |e|`` (about zero: a satellite's slowly varying
    bias is error a test sees). ``a, b >= 0`` minimise
    ``sum_k n_k (s_k - a - b x_k)^2 / s_k^2`` (``x_k`` the median ``1/sin el`` of bin
    ``k``: a relative least squares weighted by the count, non-negative least squares).
    With a single bin, ``b = 0`` and ``a`` is its scale.

    Raises
    ------
    ValueError
        No bin has ``min_per_bin`` errors.
    """
    e = np.asarray(err_m, dtype=float).reshape(-1)
    el = np.asarray(el_rad, dtype=float).reshape(-1)
    ok = np.isfinite(e) & np.isfinite(el)
    e, el = e[ok], el[ok]
    deg = np.degrees(el)
    bins, scales, counts, xs = [], [], [], []
    for lo, hi in zip(edges_deg[:-1], edges_deg[1:], strict=True):
        inb = (deg >= lo) & ((deg < hi) if hi < edges_deg[-1] else (deg <= hi))
        n = int(inb.sum())
        if n < min_per_bin:
            continue
        s = MAD_TO_SIGMA * float(np.median(np.abs(e[inb])))
        if not s > 0:
            continue
        bins.append((float(lo), float(hi)))
        scales.append(s)
        counts.append(n)
        xs.append(float(np.median(1.0 / _sin_el(el[inb]))))
    if not bins:
        raise ValueError(f"fit_elevation_sigma needs at least {min_per_bin} errors in one "
                         f"elevation bin; got {e.size} errors in all")
    s, n, x = np.array(scales), np.array(counts, dtype=float), np.array(xs)
    if len(bins) == 1:
        a, b = float(s[0]), 0.0
    else:
        w = np.sqrt(n) / s
        (a, b), _ = nnls(np.column_stack([w, w * x]), w * s)
        a, b = float(a), float(b)
    return ElevationFit(a, b, tuple(bins), tuple(scales), tuple(int(c) for c in counts),
                        int(e.size))


def measured_fits(err_m, valid, el_rad, sys_idx, systems) -> tuple[dict[int, ElevationFit],
                                                                     list[str]]:
    """The ``measured`` model: one :class:`ElevationFit` per system on clock-free errors.

    Parameters
    ----------
    err_m : (E, S) pseudoranges minus the true ranges (m), fault free.
    valid : (E, S) bool, the errors to use (used and finite).
    el_rad : (E, S) elevations; ``sys_idx`` (S,) into ``systems``.

    Returns
    -------
    ``{system index: fit}`` for every system with enough errors (a system with too few
    takes the fit of all systems pooled, said in the messages) and messages for the user.
    The receiver clock of each epoch and system is removed as the weighted mean of its
    errors (:func:`raimcore.measure.errors.clock_free_errors`), first with the weights of
    the elevation model, then :data:`MEASURED_ITERATIONS` times with those of the fit.

    Raises
    ------
    ValueError
        Too few errors for any fit, even pooled.
    """
    sys_idx = np.asarray(sys_idx)
    sig = elevation_sigma(el_rad, 1.0)
    fits: dict[int, ElevationFit] = {}
    msgs: list[str] = []
    for _ in range(MEASURED_ITERATIONS):
        r = clock_free_errors(err_m, valid, sig, sys_idx, len(systems))
        ok = np.isfinite(r)
        pooled = fit_elevation_sigma(r[ok], np.asarray(el_rad)[ok])
        fits, msgs = {}, []
        for j, name in enumerate(systems):
            col = sys_idx == j
            if not col.any():
                continue
            rj, ej = r[:, col], np.asarray(el_rad)[:, col]
            okj = np.isfinite(rj)
            try:
                fits[j] = fit_elevation_sigma(rj[okj], ej[okj])
            except ValueError:
                fits[j] = pooled
                msgs.append(f"measured error model: {name} has {int(okj.sum())} fault-free "
                            "errors, too few for its own fit: the fit of all systems is used")
        sig = np.ones_like(sig)
        for j, f in fits.items():
            col = sys_idx == j
            sig[:, col] = f.sigma(np.asarray(el_rad)[:, col])
    return fits, msgs


def model_sigma(model: str, sky, used, sigma_m: float, *, ism: Ism = None,
                user_model: str = "add") -> tuple[np.ndarray, tuple[str, ...]]:
    """Per-pseudorange 1-sigma (E, S) of ``model`` (resolved: not ``auto``) on ``sky``.

    ``used`` (E, S) are the measurements the receiver uses (the ``measured`` fit and the
    notes look at these only); ``sigma_m`` the scenario's scale (``uniform``,
    ``elevation``); ``ism`` (None: :data:`MAAST_ISM`) and ``user_model`` those of
    ``araim``, whose sigma is the accuracy model (``sigma_URE``, :func:`araim_sigmas`).
    Returns the sigmas and notes for the user.

    Raises
    ------
    ValueError
        ``measured`` on a simulated sky (it has no real errors to fit).
    """
    el = sky.el_rad
    names = [sky.systems[j] for j in sky.sys_idx]
    if model == "uniform":
        return uniform_sigma(el, sigma_m), ()
    if model == "elevation":
        return elevation_sigma(el, sigma_m), ()
    if model == "rtklib":
        efact = np.array([RTKLIB_EFACT.get(n, 1.0) for n in names])
        sig = rtklib_sigma(el, efact[None, :])
        fs = ", ".join(f"{n} {RTKLIB_EFACT.get(n, 1.0):g}" for n in sky.systems)
        return sig, (f"error model rtklib (RTKLIB rtkpos.c varerr, default options): sigma "
                     f"= F sqrt(0.3^2 + 0.3^2/sin^2 el) m, F: {fs}; sigma_m is not used",)
    if model == "broadcast":
        return _broadcast(sky, used, names)
    if model == "araim":
        ism = MAAST_ISM if ism is None else ism
        _, acc = araim_sigmas(el, sky.systems, sky.sys_idx, ism, user_model)
        present = [sky.systems[j] for j in sorted(set(np.asarray(sky.sys_idx)[used.any(0)]))]
        ure = ", ".join(f"{n} {ism[n].sigma_ure_m:g} m" for n in present) or "none used"
        return acc, (f"error model araim (ARAIM.md section 2, accuracy model C_acc): sigma^2 "
                     f"= sigma_URE^2 + tropo^2 + user({user_model})^2, sigma_URE {ure} "
                     f"(ism {ism}); sigma_m is not used",)
    if model == "measured":
        if sky.pr_m is None:
            raise ValueError("error_model \"measured\" fits the errors of a recording; a "
                             "simulated sky has none: choose uniform, elevation, rtklib, "
                             "broadcast or araim")
        return _measured(sky, used, sigma_m)
    raise ValueError(f"error_model must be one of {', '.join(ERROR_MODELS)}, got {model!r}")


def _broadcast(sky, used, names) -> tuple[np.ndarray, tuple[str, ...]]:
    shape = sky.el_rad.shape
    ura = (np.full(shape, np.nan) if getattr(sky, "ura_m", None) is None
           else np.array(sky.ura_m, dtype=float))
    default = np.array([URA_DEFAULT_M.get(n, max(URA_DEFAULT_M.values())) for n in names])
    missing = ~(np.isfinite(ura) & (ura > 0))
    ura = np.where(missing, default[None, :], ura)
    parts = []
    for j, name in enumerate(sky.systems):
        col = np.asarray(sky.sys_idx) == j
        u = used[:, col]
        if not u.any():
            continue
        miss = missing[:, col][u]
        vals = ura[:, col][u]
        if miss.all():
            parts.append(f"{name} {URA_DEFAULT_M.get(name, default.max()):g} m (assumed: "
                         + ("a simulated sky" if sky.pr_m is None else "none broadcast")
                         + ")")
        else:
            lo, hi = float(vals[~miss].min()), float(vals[~miss].max())
            txt = f"{lo:g}" if lo == hi else f"{lo:g}-{hi:g}"
            parts.append(f"{name} {txt} m" + (f" ({100 * miss.mean():.0f}% assumed "
                                             f"{URA_DEFAULT_M.get(name, default.max()):g} m)"
                                             if miss.any() else ""))
    note = ("error model broadcast (ARAIM.md section 2): sigma^2 = URA^2 + (0.12 m tropo "
            "mapping)^2 + multipath/noise(el)^2; URA " + ("; ".join(parts) or "none used")
            + "; sigma_m is not used")
    return broadcast_sigma(sky.el_rad, ura), (note,)


def _measured(sky, used, sigma_m) -> tuple[np.ndarray, tuple[str, ...]]:
    err = sky.pr_m - sky.range_m
    valid = used & np.isfinite(err)
    try:
        fits, msgs = measured_fits(err, valid, sky.el_rad, sky.sys_idx, sky.systems)
    except ValueError:
        n = int(valid.sum())
        return elevation_sigma(sky.el_rad, sigma_m), (
            f"warning: measured error model: {n} fault-free errors, fewer than "
            f"{MEASURED_MIN_PER_BIN} in any elevation bin: the elevation model (sigma_m "
            f"{sigma_m:g} m) is used instead",)
    sig = elevation_sigma(sky.el_rad, sigma_m)
    notes = list(msgs)
    for j, f in fits.items():
        col = np.asarray(sky.sys_idx) == j
        sig[:, col] = f.sigma(sky.el_rad[:, col])
        notes.append(f"measured error model, {sky.systems[j]} (fitted on this recording's "
                     f"fault-free errors against the station, clock removed, "
                     f"1.4826 x median |error| per bin): {f.describe()}")
    return sig, tuple(notes)
