"""Broadcast-ephemeris single-point positioning (SPP) of real code pseudoranges.

:func:`correct` turns a RINEX observation + navigation pair into satellite positions at
transmission (rotated into the Earth-fixed frame at reception: Sagnac) and pseudoranges
corrected for the satellite clock (incl. relativistic term and TGD/BGD), the Klobuchar
ionosphere and a standard troposphere. :func:`solve` is a batched weighted least squares
over all epochs (``raimcore.lsq.wls``), one receiver clock per system, weights from
:func:`elevation_sigma`. Atmospheric corrections and elevations are computed at a
first-pass solution, then refined once, so no prior position is needed.

Systems: GPS, BeiDou, Galileo and GLONASS (``ALL_SYSTEM_LETTER``). One receiver clock per
system absorbs the system time offsets (GST - GPST, GLONASS time - GPST beyond the leap
seconds, BDT) and, for GLONASS, the mean of the receiver's inter-channel biases; what is
left of those biases (FDMA channels differ by up to metres in some receivers) stays in the
GLONASS pseudoranges.

Ionosphere: the broadcast GPS Klobuchar model (BeiDou's own coefficients for BeiDou when
the file has them) scaled by ``(f_ref / f)^2`` to each satellite's carrier ``f``:
Galileo E1 is on L1 (scale 1; the Galileo NeQuick-G coefficients are not used), GLONASS
L1 channel ``k`` is at 1602 + 0.5625 k MHz, with ``k`` from the satellite's navigation
record (the observation header's ``GLONASS SLOT / FRQ #`` is not read).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import timedelta

import numpy as np

from ..constants import (
    C_MPS,
    DF_GLO_G1_HZ,
    DF_GLO_G2_HZ,
    F_B1I_HZ,
    F_B3I_HZ,
    F_E5_HZ,
    F_E5B_HZ,
    F_E6_HZ,
    F_GLO_G1_HZ,
    F_GLO_G2_HZ,
    F_GLO_G3_HZ,
    F_L1_HZ,
    F_L2_HZ,
    F_L5_HZ,
    OMEGA_E_RADPS,
)
from ..geometry import az_el, ecef_to_geodetic
from ..lsq import LsqResult, wls
from .constellations import SYSTEM_PREFIX
from .ephemeris import ephemeris_notes, from_nav, sat_pos_clock
from .rinex import _GPS_EPOCH, NavFile, ObsFile

__all__ = ["Corrected", "correct", "solve", "spp", "klobuchar", "troposphere",
           "elevation_sigma", "carrier_hz", "group_delay_s", "ALL_SYSTEM_LETTER",
           "SYSTEM_LETTER", "DEFAULT_SIGNALS"]

#: Every system :func:`correct` positions with, and the first letter of its satellites:
#: the one table of the project (``constellations.SYSTEM_PREFIX``, ``scenario.SYSTEMS``).
ALL_SYSTEM_LETTER = SYSTEM_LETTER = SYSTEM_PREFIX
#: Preferred code signals per system, first found wins (RINEX 3 and RINEX 2 names): GPS
#: L1 C/A, BeiDou B1I (``C1I`` is its RINEX 3.02 name), Galileo E1 (pilot C or B+C; the
#: clock and BGD of the I/NAV record), GLONASS L1 C/A.
DEFAULT_SIGNALS = {"GPS": ("C1C", "C1"), "BDS": ("C2I", "C2X", "C1I"),
                   "GAL": ("C1C", "C1X", "C1"), "GLO": ("C1C", "C1")}
# Carrier of each RINEX frequency band (the code's 2nd character), RINEX 3.05 table 4.
_BAND_HZ = {"G": {"1": F_L1_HZ, "2": F_L2_HZ, "5": F_L5_HZ},
            "E": {"1": F_L1_HZ, "5": F_L5_HZ, "7": F_E5B_HZ, "8": F_E5_HZ, "6": F_E6_HZ},
            "C": {"2": F_B1I_HZ, "1": F_L1_HZ, "5": F_L5_HZ, "7": F_E5B_HZ, "8": F_E5_HZ,
                  "6": F_B3I_HZ},
            "R": {"3": F_GLO_G3_HZ, "4": 1600.995e6, "6": 1248.06e6}}  # G1a, G2a: RINEX 3.05


def carrier_hz(letter: str, code: str, fcn=0) -> np.ndarray:
    """Carrier frequency (Hz) of observation ``code`` (RINEX 3 "C1C" or RINEX 2 "C1") of
    system ``letter``; ``fcn`` is the GLONASS FDMA channel k (array or int) for bands 1
    and 2 (GLONASS ICD ed. 5.1, 3.3.1.4). BeiDou band 1 is B1I for the RINEX 3.02 codes
    ``C1I``/``C1Q`` and B1C otherwise. NaN for an unknown band.

    >>> float(carrier_hz("R", "C1C", -7)) / 1e6
    1598.0625
    """
    band = code[1:2]
    if letter == "R" and band in ("1", "2"):
        base, step = (F_GLO_G1_HZ, DF_GLO_G1_HZ) if band == "1" else (F_GLO_G2_HZ,
                                                                     DF_GLO_G2_HZ)
        return base + step * np.asarray(fcn, dtype=float)
    if letter == "C" and code[:3] in ("C1I", "C1Q"):
        band = "2"
    f = _BAND_HZ.get(letter, {}).get(band, np.nan)
    return np.full(np.shape(fcn), f)


def klobuchar(lat_rad, lon_rad, az_rad, el_rad, t_gps_s, alpha, beta) -> np.ndarray:
    """Klobuchar ionospheric delay on L1 (m), IS-GPS-200 20.3.3.5.2.5 (figure 20-4).

    Angles in radians (converted to semicircles inside); broadcasting over all inputs.
    """
    phi_u = np.asarray(lat_rad) / np.pi
    lam_u = np.asarray(lon_rad) / np.pi
    e = np.asarray(el_rad) / np.pi
    a = np.asarray(az_rad)
    psi = 0.0137 / (e + 0.11) - 0.022  # earth-centred angle (semicircles)
    phi_i = np.clip(phi_u + psi * np.cos(a), -0.416, 0.416)
    lam_i = lam_u + psi * np.sin(a) / np.cos(phi_i * np.pi)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * np.pi)  # geomagnetic latitude
    t = np.mod(4.32e4 * lam_i + np.asarray(t_gps_s), 86400.0)
    f = 1.0 + 16.0 * (0.53 - e) ** 3  # obliquity factor
    amp = np.maximum(sum(alpha[n] * phi_m**n for n in range(4)), 0.0)
    per = np.maximum(sum(beta[n] * phi_m**n for n in range(4)), 72000.0)
    x = 2.0 * np.pi * (t - 50400.0) / per
    delay = np.where(np.abs(x) < 1.57, f * (5e-9 + amp * (1.0 - x**2 / 2.0 + x**4 / 24.0)),
                     f * 5e-9)
    return C_MPS * delay


def troposphere(lat_rad, h_m, el_rad) -> np.ndarray:
    """Slant tropospheric delay (m): Saastamoinen zenith delay with a standard atmosphere
    (as in RTKLIB ``tropmodel``: 1013.25 hPa, 15 C, 70 % humidity at sea level) and the
    Black & Eisner mapping ``1.001 / sqrt(0.002001 + sin^2 el)`` (RTCA DO-229 A.4.2.4)."""
    h = np.clip(np.asarray(h_m, dtype=float), -100.0, 1e4)
    pres = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568
    temp = 15.0 - 6.5e-3 * h + 273.16
    e_w = 6.108 * 0.7 * np.exp((17.15 * temp - 4684.0) / (temp - 38.45))
    zhd = 0.0022768 * pres / (1.0 - 0.00266 * np.cos(2.0 * np.asarray(lat_rad))
                              - 0.00028 * h / 1e3)
    zwd = 0.002277 * (1255.0 / temp + 0.05) * e_w
    m = 1.001 / np.sqrt(0.002001 + np.sin(np.asarray(el_rad)) ** 2)
    return (zhd + zwd) * m


def elevation_sigma(el_rad, sigma_m) -> np.ndarray:
    """Pseudorange 1-sigma (m) by elevation: ``sigma_m * sqrt((1 + 1/sin^2 el) / 2)``, i.e.
    ``sigma_m`` at the zenith and ~``sigma_m / (sqrt 2 sin el)`` near the horizon (the
    RTKLIB-style a + b / sin el model with a = b)."""
    s = np.maximum(np.sin(np.asarray(el_rad)), np.sin(np.radians(2.0)))
    return sigma_m * np.sqrt(0.5 * (1.0 + 1.0 / s**2))


@dataclass(frozen=True)
class Corrected:
    """Satellite positions and corrected pseudoranges of a recording.

    Attributes
    ----------
    t_gps_s : (E,) epoch times (GPS s). sat_names : (S,). sys_idx : (S,) into ``systems``.
    signals : system -> code used (e.g. {"GPS": "C1C", "BDS": "C2I"}).
    pos_sv_ecef_m : (E, S, 3) at transmission, in the ECEF frame at reception (finite
        everywhere: untracked satellites are placed with a nominal 75 ms travel time).
    pr_raw_m : (E, S) measured pseudoranges (NaN where not tracked).
    clock_m : (E, S) c * satellite clock (incl. relativity, minus TGD).
    tracked : (E, S) observed; usable : (E, S) with a healthy ephemeris in its validity.
    iono_m, tropo_m : (E, S) model delays at the current receiver estimate.
    rx_ecef_m : (E, 3) the position at which the delays and elevations were computed.
    freq_hz : (E, S) carrier frequency of the signal used (GLONASS: its FDMA channel).
    ura_m : (E, S) broadcast URA / SISA of the record used (m; NaN where not broadcast).
    notes : human-readable remarks (satellites without ephemeris, records not used, ...).
    """

    t_gps_s: np.ndarray
    sat_names: tuple[str, ...]
    sys_idx: np.ndarray
    systems: tuple[str, ...]
    signals: dict[str, str]
    pos_sv_ecef_m: np.ndarray
    pr_raw_m: np.ndarray
    clock_m: np.ndarray
    tracked: np.ndarray
    usable: np.ndarray
    iono_m: np.ndarray
    tropo_m: np.ndarray
    rx_ecef_m: np.ndarray
    freq_hz: np.ndarray
    ura_m: np.ndarray
    notes: list[str] = field(default_factory=list)

    @property
    def pr_m(self) -> np.ndarray:
        """Corrected pseudoranges (m), NaN where not tracked or not usable."""
        pr = self.pr_raw_m + self.clock_m - self.iono_m - self.tropo_m
        return np.where(self.tracked & self.usable, pr, np.nan)


#: RINEX 3 codes of BeiDou B1I and B2I (B1C, B2a, B2b and B3 share bands 1, 5 and 7).
_BDS_B1I = ("C2I", "C2Q", "C2X", "C1I", "C1Q")
_BDS_B2I = ("C7I", "C7Q", "C7X")


def group_delay_s(letter: str, code: str, tgd_s, tgd2_s):
    """The broadcast group delay (s) a single-frequency user of code ``code`` subtracts
    from the broadcast clock, from the records' ``tgd_s`` (the default signal's, see
    :class:`~raimcore.sky.ephemeris.Ephemerides`) and ``tgd2_s``; returns ``(delay_s,
    note)``, ``note`` None where the delay is the signal's own:

    - GPS: L1 (C/A, P(Y)) ``TGD``; L2 ``gamma TGD``, ``gamma = (f_L1 / f_L2)^2``
      (IS-GPS-200 20.3.3.3.3.2; for L2C the LNAV user's value);
    - BeiDou: B1I ``TGD1``, B2I ``TGD2``, B3I 0 (the clock refers to B3I; BDS-SIS-ICD
      B1I 3.0, 5.2.4.10);
    - Galileo: E1 the record's BGD (I/NAV: BGD(E1, E5b)); E5b
      ``(f_E1 / f_E5b)^2 BGD(E1, E5b)`` (OS SIS ICD 2.0, 5.1.5);
    - GLONASS: L1 0 (tau_n refers to L1).

    Any other signal (GPS L5, BeiDou B1C/B2a/B2b, Galileo E5a/E5/E6, GLONASS L2/L3): no
    group delay of its own in the records read here (CNAV ISCs, F/NAV clocks, Delta tau_n);
    the default signal's is kept and the note says so (an error of a few ns, about 1 m).
    A missing ``tgd2_s`` counts 0, said in the note."""
    band = code[1] if len(code) > 1 else ""
    tgd = np.asarray(tgd_s, dtype=float)
    tgd2 = np.asarray(tgd2_s, dtype=float)
    second = None
    if (letter in "GER" and band == "1") or (letter == "C" and code in _BDS_B1I):
        return tgd, None
    if letter == "G" and band == "2":
        return (F_L1_HZ / F_L2_HZ) ** 2 * tgd, None
    if letter == "C" and band == "6":
        return np.zeros_like(tgd), None
    if letter == "C" and code in _BDS_B2I:
        second = tgd2
    elif letter == "E" and band == "7":
        second = (F_L1_HZ / F_E5B_HZ) ** 2 * tgd2
    if second is not None:
        missing = ~np.isfinite(second)
        note = (f"{code}: the group delay field is missing in {int(missing.sum())} "
                "record uses; 0 taken there" if missing.any() else None)
        return np.where(missing, 0.0, second), note
    return tgd, (f"{code}: no broadcast group delay for this signal in the records read "
                 "here; the default signal's is applied (an error of a few ns, ~1 m, per "
                 "satellite)")


def _pick_signal(obs: ObsFile, system: str, signals) -> str:
    letter = ALL_SYSTEM_LETTER[system]
    have = obs.obs_types.get(letter, ())
    prefs = tuple(signals) if signals else DEFAULT_SIGNALS[system]
    for code in prefs:
        if code in have and code in obs.codes:
            return code
    codes = [c for c in have if c[0] in "CP"]
    raise ValueError(f"{obs.path}: signals must name a code of {system} in this file "
                     f"({', '.join(codes) or 'none'}); tried {', '.join(prefs)}")


def correct(obs: ObsFile, nav: NavFile, systems=("GPS", "BDS"), signals=(),
            rx_ecef_m=None) -> Corrected:
    """Satellite positions/clocks and atmospheric corrections for every epoch.

    Parameters
    ----------
    obs, nav : the recording. systems : names of ``ALL_SYSTEM_LETTER`` ("GPS", "BDS", "GAL",
        "GLO"; systems absent from either file are left out with a note; ``nav`` must have
        been read with their letters, e.g. ``read_nav(path, systems="GCER")``).
        signals : preferred code types (first found per system wins); empty =
        ``DEFAULT_SIGNALS``.
    rx_ecef_m : (3,) or (E, 3) receiver position for the delays; None = solve for it
        (first pass without atmosphere, then one refinement).

    Raises
    ------
    ValueError for an unknown system, a signal not in the file or of an unknown band, or
    no satellite with both pseudoranges and a usable ephemeris.
    """
    unknown = [x for x in systems if x not in ALL_SYSTEM_LETTER]
    if unknown:
        raise ValueError(f"systems must be among {', '.join(ALL_SYSTEM_LETTER)}, got "
                         f"{', '.join(map(str, unknown))}")
    eph = from_nav(nav)
    notes: list[str] = []
    names: list[str] = []
    sys_of: list[int] = []
    used_systems: list[str] = []
    chosen: dict[str, str] = {}
    pr_cols = []
    for system in systems:
        letter = ALL_SYSTEM_LETTER[system]
        sats = [n for n in obs.sat_names if n[0] == letter]
        if not sats:
            notes.append(f"{system}: no satellites in {obs.path}")
            continue
        if letter not in nav.records:
            notes.append(f"{system}: no navigation records in {nav.path}; left out")
            continue
        code = _pick_signal(obs, system, signals)
        if np.isnan(carrier_hz(letter, code)):
            raise ValueError(f"signals: no carrier frequency known for {system} {code}")
        chosen[system] = code
        pr_all = obs.pseudorange(letter, code)
        col = {n: k for k, n in enumerate(obs.sat_names)}
        have_eph = set(eph.sat[eph.healthy].tolist())
        for n in sats:
            if not np.isfinite(pr_all[:, col[n]]).any():
                continue
            if n not in have_eph:
                notes.append(f"{n}: no healthy {system} ephemeris in {nav.path}; left out")
                continue
            if system not in used_systems:
                used_systems.append(system)
            names.append(n)
            sys_of.append(used_systems.index(system))
            pr_cols.append(pr_all[:, col[n]])
    if not names:
        raise ValueError(f"{obs.path}: no satellite of {', '.join(systems)} with both "
                         f"pseudoranges and an ephemeris")
    # Records not used (unhealthy, incomplete, F/NAV): the notes on the satellites this
    # recording observes and the system-wide ones ("GAL: ...").
    about = set(obs.sat_names) | set(used_systems)
    letters_used = "".join(ALL_SYSTEM_LETTER[x] for x in used_systems)
    notes += [n for n in ephemeris_notes(nav, letters_used) if n.split(":")[0] in about]
    t = obs.t_gps_s
    pr = np.stack(pr_cols, axis=1)
    tracked = np.isfinite(pr)
    e_sel, usable = eph.select(names, t)
    if not (tracked & usable).any():
        raise ValueError(_no_valid_ephemeris(obs, nav, eph, t))
    stale = tracked & ~usable
    if stale.any():
        per = {names[k]: int(c) for k, c in enumerate(stale.sum(0)) if c}
        notes.append("no ephemeris within its validity at some epochs (left out there): "
                     + ", ".join(f"{k} {v}" for k, v in per.items()))
    tau = np.where(tracked, pr / C_MPS, 0.075)  # nominal travel time for untracked ones
    t_tx = t[:, None] - tau
    _, clk = sat_pos_clock(e_sel, t_tx)
    t_tx = t_tx - clk  # satellite clock (IS-GPS-200 20.3.3.3.3.1: t = t_sv - dt_sv)
    pos, clk = sat_pos_clock(e_sel, t_tx)
    letters = np.array([n[0] for n in names])
    for system in used_systems:  # the group delay of the signal used (clk has the default's)
        cols = letters == ALL_SYSTEM_LETTER[system]
        delay, note = group_delay_s(ALL_SYSTEM_LETTER[system], chosen[system],
                                    e_sel.tgd_s[:, cols], e_sel.tgd2_s[:, cols])
        clk[:, cols] += e_sel.tgd_s[:, cols] - delay
        if note:
            notes.append(f"{system} {note}")
    # Earth rotation during the signal travel (Sagnac): rotate by -we * tau about Z.
    ang = OMEGA_E_RADPS * (t[:, None] - t_tx)
    ca, sa = np.cos(ang), np.sin(ang)
    pos = np.stack([ca * pos[..., 0] + sa * pos[..., 1], -sa * pos[..., 0] + ca * pos[..., 1],
                    pos[..., 2]], axis=-1)
    pos = np.where(np.isfinite(pos), pos, 0.0)
    e_n, s_n = pr.shape
    zero = np.zeros((e_n, s_n))
    freq = np.zeros((e_n, s_n))
    for system in used_systems:
        cols = letters == ALL_SYSTEM_LETTER[system]
        freq[:, cols] = carrier_hz(ALL_SYSTEM_LETTER[system], chosen[system], e_sel.fcn[:, cols])
    corr = Corrected(t, tuple(names), np.array(sys_of, dtype=int), tuple(used_systems), chosen,
                     pos, np.where(tracked, pr, np.nan), C_MPS * clk, tracked, usable, zero,
                     zero, np.full((e_n, 3), np.nan), freq, e_sel.ura_m, notes)
    if rx_ecef_m is None:
        first = solve(corr, mask_deg=-90.0)
        rx = _fill(first.pos_ecef_m, obs.approx_pos_ecef_m)
        corr = with_atmosphere(corr, nav, rx)
        rx = _fill(solve(corr).pos_ecef_m, rx)
    else:
        rx = np.broadcast_to(np.asarray(rx_ecef_m, dtype=float), (e_n, 3))
    return with_atmosphere(corr, nav, rx)


def _no_valid_ephemeris(obs: ObsFile, nav: NavFile, eph, t) -> str:
    """The message for a recording whose navigation file has no record valid at any
    observation epoch (typically files of different days)."""
    def span(x) -> str:
        x = np.asarray(x, dtype=float)
        if x.size == 0:
            return "none"
        lo, hi = (_GPS_EPOCH + timedelta(seconds=float(v)) for v in (x.min(), x.max()))
        return f"{lo:%Y-%m-%d %H:%M} to {hi:%Y-%m-%d %H:%M}"

    return (f"no ephemeris of the navigation file is valid within 4 h of the observation "
            f"epochs: {obs.path} observes {span(t)}, {nav.path} has records for "
            f"{span(eph.toe_gps_s[eph.healthy])} (GPS time); give the navigation file of "
            "the same day")


def _fill(pos, fallback) -> np.ndarray:
    """Epochs without a solution take the median solution (or ``fallback``, (3,) or
    (E, 3))."""
    ok = np.isfinite(pos).all(-1)
    if ok.any():
        fb = np.median(pos[ok], axis=0)
    else:
        fb = np.asarray(fallback, dtype=float)
    return np.where(ok[:, None], pos, np.broadcast_to(fb, pos.shape))


def with_atmosphere(corr: Corrected, nav: NavFile, rx_ecef_m) -> Corrected:
    """``corr`` with the Klobuchar and tropospheric delays recomputed at ``rx_ecef_m``:
    each system's delay is scaled by ``(f_ref / f)^2`` from the coefficients' reference
    carrier (GPS L1, or BeiDou B1I for BeiDou's own) to the satellite's ``freq_hz``."""
    rx = np.asarray(rx_ecef_m, dtype=float)
    lat, lon, h = ecef_to_geodetic(rx)
    az, el = az_el(corr.pos_sv_ecef_m, rx)
    alpha = nav.iono.get("GPSA", np.zeros(4))
    beta = nav.iono.get("GPSB", np.zeros(4))
    iono = np.zeros(el.shape)
    for k, system in enumerate(corr.systems):
        cols = corr.sys_idx == k
        if system == "BDS" and "BDSA" in nav.iono and "BDSB" in nav.iono:
            # BDS broadcasts its own Klobuchar coefficients for B1I (BDS ICD 5.2.4.7);
            # the GPS algorithm is applied to them (the BDS variant differs in the pierce
            # point geometry only).
            a_s, b_s, f_ref = nav.iono["BDSA"], nav.iono["BDSB"], F_B1I_HZ
        else:
            # GPS coefficients give the L1 delay (Galileo E1 is on L1; GLONASS L1 FDMA
            # and BeiDou B1I are scaled).
            a_s, b_s, f_ref = alpha, beta, F_L1_HZ
        if np.any(a_s):
            scale = (f_ref / corr.freq_hz[:, cols]) ** 2
            iono[:, cols] = scale * klobuchar(lat[:, None], lon[:, None], az[:, cols],
                                              el[:, cols], corr.t_gps_s[:, None], a_s, b_s)
    tropo = troposphere(lat[:, None], h[:, None], el)
    return Corrected(**{**corr.__dict__, "iono_m": iono, "tropo_m": tropo,
                        "rx_ecef_m": rx})


def solve(corr: Corrected, *, mask_deg: float = 10.0, sigma_m: float = 1.0,
          used=None) -> LsqResult:
    """Batched WLS over all epochs, one clock per system; elevations from
    ``corr.rx_ecef_m`` (all satellites when it is unknown)."""
    pr = corr.pr_m
    ok = np.isfinite(pr) if used is None else used & np.isfinite(pr)
    if np.isfinite(corr.rx_ecef_m).all():
        _, el = az_el(corr.pos_sv_ecef_m, corr.rx_ecef_m)
        ok &= el >= np.radians(mask_deg)
        w = 1.0 / elevation_sigma(el, sigma_m) ** 2
    else:
        w = np.full(pr.shape, 1.0 / sigma_m**2)
    w = np.where(ok, w, 0.0)
    return wls(corr.pos_sv_ecef_m, pr, w, corr.sys_idx, len(corr.systems))


def spp(obs: ObsFile, nav: NavFile, systems=("GPS", "BDS"), signals=(), *,
        mask_deg: float = 10.0, sigma_m: float = 1.0) -> tuple[LsqResult, Corrected]:
    """Single-point positions of every epoch: ``(LsqResult, Corrected)``."""
    corr = correct(obs, nav, systems, signals)
    return solve(corr, mask_deg=mask_deg, sigma_m=sigma_m), corr
