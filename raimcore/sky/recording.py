"""The recording sky source: RINEX observation + navigation -> :class:`~raimcore.sky.Sky`.

A scenario with ``source = "rinex"`` names an observation file and one or more navigation
files (merged: :func:`~raimcore.sky.rinex.read_nav`), plain or compressed (gzip, ``.Z``,
zip, Hatanaka ``.crx``: :mod:`raimcore.sky.compressed`). GPS, BeiDou, Galileo and GLONASS
are read. The pseudoranges of the chosen signals are corrected for the satellite clock
(relativity, TGD/BGD), the Klobuchar ionosphere and the troposphere
(:mod:`raimcore.sky.spp`), so that every registered algorithm sees the same kind of data as
from a simulation: satellite positions and pseudoranges whose only unknowns are the
receiver position and one clock per system (``Sky.sys_idx``). Faults are added to the real
pseudoranges by the measure stage; the truth for the error columns is the header position
of the (static) station, or ``truth_ecef_m``.

Epochs sit on the recording's grid: its nominal interval (:func:`nominal_interval_s`) from
the median time tag; a tag within a quarter interval of a grid time belongs to it (a
receiver's 29.999 s is 30 s). ``step_s`` keeps every n-th grid time. A tag off the grid or a
second tag of one grid time is dropped and counted in a note, never silently.

Phone logs. ``source = "android"`` is the same chain with one difference, where the
observation file is read: ``obs`` names an Android GnssLogger raw log, read by
:func:`~raimcore.sky.android.read_android_log`. A phone measures on its own schedule, not
on a grid of GPS time (the shared log: 0.93-1.42 s apart, the hardware clock restarting
between epochs), so its epochs are taken as they are: none is snapped to a grid, thinning
keeps epochs at least ``step_s`` apart less a quarter of the nominal interval (at the
default step, every epoch), and a log has no header position (``truth_ecef_m``, else the
median single-point solution with a note). Which reader a file needs is told by its content
(:func:`observation_source`); a file given to the wrong one is refused with a message
naming the right one.

The sky's notes say what the user should know: records the navigation files' reader
dropped (``NavFile.notes``), records rejected for the observed satellites with their reason
(:func:`~raimcore.sky.ephemeris.ephemeris_notes`), satellites with no usable ephemeris
(left out), epochs dropped from the grid.
"""

from __future__ import annotations

import bz2
import dataclasses
import gzip
import math
import os
import zipfile
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..geometry import az_el, ecef_to_geodetic
from . import Sky
from .android import AndroidLog, AndroidLogError, read_android_log
from .compressed import RinexError, read_bytes
from .rinex import NavFile, ObsFile, read_nav, read_obs
from .spp import DEFAULT_SIGNALS, SYSTEM_LETTER, Corrected, correct, solve

__all__ = ["recording_sky", "recording_keys", "load_recording", "receiver_ecef_m",
           "nominal_interval_s", "observation_source", "RECORDED_SOURCES"]

#: The scenario sources whose pseudoranges are recorded: a RINEX observation file, an
#: Android GnssLogger log.
RECORDED_SOURCES = ("rinex", "android")
#: Defaults for real data (scenario keys): code noise of a geodetic receiver at the zenith,
#: a 10-degree mask against multipath.
REAL_DATA_DEFAULTS = {"sigma_m": 1.0, "mask_deg": 10.0}
#: Defaults for a phone log: the ``measured`` error model (sigma by elevation fitted on the
#: log itself: no published model describes a phone's code errors, and the receiver models
#: are 2-13x too small for the shared log, ``rtklib`` 0.42 m and ``broadcast`` ~2.4 m at
#: the zenith, mostly its URA), and ``sigma_m`` 5 m at the zenith for ``elevation`` /
#: ``uniform``: the shared 2016 log's robust zenith sigma is 5.35 m (``measured`` fit
#: ``4.67 / sin el`` m), its median horizontal single-point error 8.2 m.
PHONE_DEFAULTS = {"sigma_m": 5.0, "mask_deg": 10.0, "error_model": "measured"}
#: Bytes read from the start of a file to tell its kind (:func:`observation_source`): a
#: GnssLogger header is a few hundred bytes to a few kB.
_HEAD_BYTES = 65536
#: The option of ``raim run`` and the scenario source of each kind of file, for messages.
_GIVE_AS = {"rinex": '--obs (source = "rinex")', "android": '--android (source = "android")',
            "rinex-nav": "--nav (a navigation file)"}


def _stamp(path, key: str) -> tuple[str, int, int]:
    """The cache key of a file (resolved path, time, size); ``key`` names it in errors."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"{key}: file {str(path)!r} does not exist or is not a file")
    st = p.stat()
    return str(p.resolve()), st.st_mtime_ns, st.st_size


def _head(path) -> bytes:
    """The first :data:`_HEAD_BYTES` of ``path``'s content, decompressed (gzip, bzip2 and
    zip stream the start only; Unix ``.Z`` is read whole)."""
    with open(path, "rb") as fh:
        data = fh.read(_HEAD_BYTES)
    try:
        if data.startswith(b"\x1f\x8b"):
            with gzip.open(path, "rb") as fh:
                return fh.read(_HEAD_BYTES)
        if data.startswith(b"BZh"):
            with bz2.open(path, "rb") as fh:
                return fh.read(_HEAD_BYTES)
        if data.startswith(b"PK\x03\x04"):
            with zipfile.ZipFile(path) as z:
                names = [n for n in z.namelist() if not n.endswith("/")]
                with z.open(names[0]) as fh:
                    return fh.read(_HEAD_BYTES)
        if data.startswith(b"\x1f\x9d"):
            return read_bytes(path)[:_HEAD_BYTES]
    except (OSError, EOFError, IndexError, ValueError, zipfile.BadZipFile):
        return b""  # a broken archive: the reader names the problem
    return data


def observation_source(path) -> str:
    """What kind of file ``path`` is, told by its content (plain or compressed):

    ``"rinex"`` a RINEX (or Compact RINEX) observation file; ``"rinex-nav"`` another RINEX
    file (navigation, meteorological, ...); ``"android"`` a GnssLogger log (a ``# Raw,``
    header line); ``""`` neither (the reader of the chosen source then says what is wrong).

    >>> observation_source(__file__)
    ''
    """
    head = _head(path)
    first = head.split(b"\n", 1)[0]
    label = first[60:80].rstrip()
    if label in (b"RINEX VERSION / TYPE", b"CRINEX VERS   / TYPE"):
        return "rinex" if label.startswith(b"CRINEX") or first[20:21] == b"O" else "rinex-nav"
    for line in head.splitlines():
        body = line.lstrip(b"\xef\xbb\xbf").strip()  # a byte-order mark, then "# Raw,"
        if body.startswith(b"#") and body.lstrip(b"# \t").startswith(b"Raw,"):
            return "android"
    return ""


def _refuse_kind(path, source: str, exc: ValueError) -> ValueError:
    """The error for ``path`` that the ``source`` reader refused with ``exc``: when its
    content is another kind of file, one that names the option that reads it."""
    kind = observation_source(path)
    if kind and kind != source:
        what = {"rinex": "a RINEX observation file", "android": "an Android GnssLogger log",
                "rinex-nav": "a RINEX navigation (or other non-observation) file"}[kind]
        want = {"rinex": "a RINEX observation file",
                "android": "an Android GnssLogger log"}[source]
        return RinexError(path, None, f"this is {what}, not {want}: give it with "
                          f"{_GIVE_AS[kind]}")
    return exc


@lru_cache(maxsize=4)
def _read_log(stamp) -> AndroidLog:
    try:
        return read_android_log(stamp[0])
    except AndroidLogError as exc:
        raise _refuse_kind(stamp[0], "android", exc) from None


@lru_cache(maxsize=4)
def _read_obs(stamp, source: str = "rinex") -> ObsFile:
    """The observations of ``stamp``'s file, read by the reader of ``source``."""
    if source == "android":
        return _read_log(stamp).obs
    try:
        return read_obs(stamp[0])
    except RinexError as exc:
        raise _refuse_kind(stamp[0], "rinex", exc) from None


def _nav_stamps(nav) -> tuple[tuple[str, int, int], ...]:
    """The cache keys of the navigation file(s) ``nav`` (a path or a list of paths); a
    missing one is named ``nav`` (one file) or ``nav[i]`` (several)."""
    paths = [nav] if isinstance(nav, str | os.PathLike) else list(nav)
    if not paths:
        raise ValueError("nav must name at least one RINEX navigation file, got none")
    if len(paths) == 1:
        return (_stamp(paths[0], "nav"),)
    return tuple(_stamp(p, f"nav[{i}]") for i, p in enumerate(paths))


@lru_cache(maxsize=4)
def _read_nav(nav_stamps) -> NavFile:
    return read_nav([st[0] for st in nav_stamps])  # GPS, BeiDou, Galileo and GLONASS


@lru_cache(maxsize=4)
def _corrected(obs_stamp, nav_stamps, systems, signals, source="rinex") -> Corrected:
    obs = _read_obs(obs_stamp, source)  # first: a wrong kind of obs file is named first
    nav = _read_nav(nav_stamps)
    corr = correct(obs, nav, systems, signals)
    # correct() names the rejected records of the observed satellites
    # (ephemeris.ephemeris_notes); the readers' notes (records skipped or conflicting,
    # phone measurements rejected) too.
    log_notes = list(_read_log(obs_stamp).notes) if source == "android" else []
    return dataclasses.replace(corr, notes=[*nav.notes, *log_notes, *corr.notes])


def _check_source(source: str) -> str:
    if source not in RECORDED_SOURCES:
        raise ValueError(f"source must be one of {', '.join(RECORDED_SOURCES)} for a "
                         f"recording, got {source!r}")
    return source


def load_recording(obs, nav, systems=tuple(SYSTEM_LETTER), signals=(),
                   source: str = "rinex") -> Corrected:
    """Read and correct a recording: ``obs`` an observation file (``source`` "rinex") or
    a GnssLogger log ("android"), ``nav`` a navigation file or a list of them (merged),
    plain or compressed. Cached on every file's path, size and modification time.
    ``Corrected.notes`` start with the navigation reader's (``NavFile.notes``), then the
    phone log's (``AndroidLog.notes``), then those of :func:`~raimcore.sky.spp.correct`.

    Raises
    ------
    ValueError naming ``obs``, ``nav`` or ``nav[i]`` for a file that does not exist, or the
    reader's :class:`~raimcore.sky.compressed.RinexError` (file and line); an ``obs`` of
    the other kind (a log given as RINEX, or RINEX as a log) is refused with the option
    that reads it.
    """
    return _corrected(_stamp(obs, "obs"), _nav_stamps(nav), tuple(systems), tuple(signals),
                      _check_source(source))


def nominal_interval_s(t_s) -> float:
    """The nominal epoch interval (s) of time tags ``t_s``: the median of the positive
    differences between consecutive tags (1 s with fewer than two distinct tags)."""
    d = np.diff(np.sort(np.asarray(t_s, dtype=float)))
    d = d[d > 0.0]
    return float(np.median(d)) if d.size else 1.0


def recording_keys(obs, source: str | None = None) -> dict:
    """Scenario keys that fit the recording ``obs`` (see
    :func:`raimcore.scenario.recording_scenario`): its name, its source (``source``, or
    told by the file's content: :func:`observation_source`), every system it observes with
    a default signal (:data:`~raimcore.sky.spp.DEFAULT_SIGNALS`) among GPS, BDS, GAL and
    GLO, the whole recording at its nominal interval, and the real-data defaults
    (:data:`REAL_DATA_DEFAULTS`; a phone: :data:`PHONE_DEFAULTS`)."""
    stamp = _stamp(obs, "obs")
    if source is None:
        source = "android" if observation_source(stamp[0]) == "android" else "rinex"
    o = _read_obs(stamp, _check_source(source))
    systems = [s for s, letter in SYSTEM_LETTER.items()
               if any(n[0] == letter for n in o.sat_names)
               and any(c in o.obs_types.get(letter, ()) and c in o.codes
                       for c in DEFAULT_SIGNALS[s])] or ["GPS"]
    t = o.t_gps_s - o.t_gps_s[0] if len(o.t_gps_s) else np.zeros(1)
    step = nominal_interval_s(t)
    return {"name": Path(obs).name.split(".")[0],
            "description": f"{'phone log' if source == 'android' else 'recording'} "
                           f"{Path(obs).name}", "source": source, "obs": str(obs),
            "systems": systems, "duration_s": float(t[-1]), "step_s": step,
            **(PHONE_DEFAULTS if source == "android" else REAL_DATA_DEFAULTS)}


def receiver_ecef_m(s) -> np.ndarray:
    """(3,) the receiver position of a recording scenario: ``truth_ecef_m``, else the
    header position (zeros when the file has none)."""
    if s.truth_ecef_m:
        return np.array(s.truth_ecef_m, dtype=float)
    return np.array(_read_obs(_stamp(s.obs, "obs"), s.source).approx_pos_ecef_m, dtype=float)


#: Thinning keeps every n-th grid epoch, n = ceil(step / interval), with this relative
#: slack (a step of 30 s on a 29.999 s grid keeps every epoch).
_STEP_SLACK = 1e-3
#: Dropped epochs listed by time in a note (the rest are counted).
_LISTED = 5


def _times(t) -> str:
    """``"t = 45.2, 100.001 s"`` (ms resolution), the first :data:`_LISTED` of ``t``."""
    shown = ", ".join(f"{x:.3f}".rstrip("0").rstrip(".") for x in t[:_LISTED])
    return f"t = {shown}{', ...' if len(t) > _LISTED else ''} s"


def _window(t_rel, t0, duration, step, grid: bool = True) -> tuple[np.ndarray, list[str]]:
    """The epochs of a recording in the window [t0, t0 + duration] on its epoch grid,
    thinned to at least ``step`` apart, and notes on the epochs dropped.

    Parameters
    ----------
    t_rel : (E,) time tags (s from the first one), in file order.
    t0, duration, step : the scenario's ``t_start_s``, ``duration_s``, ``step_s`` (s).
    grid : False for epochs on no grid (a phone, :func:`_window_free`).

    Returns
    -------
    rows : (K,) indices into ``t_rel`` in time order.
    notes : one line per kind of dropped epoch, with the count and the times (from t0).

    The grid is ``anchor + k * dt``: ``dt`` is :func:`nominal_interval_s`, ``anchor`` the
    first tag moved by the median offset of all tags from its grid (so one late first tag
    does not shift the grid). A tag within ``dt / 4`` of a grid time belongs to it; the
    window and the thinning are on grid times, so jitter never drops an epoch. Thinning
    keeps grid times ``k0, k0 + n, ...`` from the first one in the window, ``n =
    ceil(step / dt)``, whether or not the epochs between are present. Dropped, and counted
    in ``notes``: tags more than ``dt / 4`` from the grid, and the later tags of one grid
    time (a duplicated epoch; the first in the file is kept).
    """
    t = np.asarray(t_rel, dtype=float)
    if t.size == 0:
        return np.zeros(0, dtype=int), []
    dt = nominal_interval_s(t)
    if not grid:
        return _window_free(t, dt, t0, duration, step)
    off = np.mod(t - t[0] + dt / 2.0, dt) - dt / 2.0  # each tag from the first one's grid
    anchor = t[0] + float(np.median(off))
    k = np.round((t - anchor) / dt).astype(np.int64)
    on_grid = np.abs(t - anchor - k * dt) <= dt / 4.0
    k_lo = math.ceil((t0 - anchor) / dt - 0.25)
    k_hi = math.floor((t0 + duration - anchor) / dt + 0.25)
    in_window = (k >= k_lo) & (k <= k_hi)
    n = max(1, math.ceil(step / dt * (1.0 - _STEP_SLACK)))
    notes = []
    off_idx = np.flatnonzero(in_window & ~on_grid)
    if off_idx.size:
        notes.append(f"{off_idx.size} epoch{'s' if off_idx.size > 1 else ''} off the "
                     f"{dt:g} s grid dropped (more than {dt / 4:g} s from it): "
                     + _times(t[off_idx] - t0))
    cand = np.flatnonzero(in_window & on_grid)
    _, first = np.unique(k[cand], return_index=True)  # sorted by k; the first of each
    dup = np.setdiff1d(cand, cand[first])
    if dup.size:
        notes.append(f"{dup.size} duplicated epoch{'s' if dup.size > 1 else ''} dropped (a "
                     f"second time tag for one grid time; the first is kept): "
                     + _times(t[dup] - t0))
    rows = cand[first]
    rows = rows[(k[rows] - k_lo) % n == 0]
    if n > 1 and abs(n * dt - step) > _STEP_SLACK * step:
        notes.append(f"step_s {step:g} s is not a multiple of the recording's {dt:g} s "
                     f"interval: one epoch in {n} kept ({n * dt:g} s apart)")
    return rows, notes


def _window_free(t, dt, t0, duration, step) -> tuple[np.ndarray, list[str]]:
    """:func:`_window` for epochs on no grid (``dt`` their nominal interval): every tag
    within ``dt / 4`` of the window [t0, t0 + duration] is in it; thinning keeps, in time
    order, each epoch at least ``step - dt / 4`` after the last one kept (``step = dt``, the
    default: every epoch of a log ~dt apart). An epoch closer than ``3 dt / 4`` to the last
    one kept is dropped and counted in a note whatever the step; one dropped by a larger
    step is thinned on purpose, as on a grid."""
    tol = dt / 4.0
    cand = np.flatnonzero((t >= t0 - tol) & (t <= t0 + duration + tol))
    cand = cand[np.argsort(t[cand], kind="stable")]
    keep, close = [], []
    last = -math.inf
    for i in cand:
        if t[i] - last >= max(step, dt) - tol:
            keep.append(i)
            last = t[i]
        elif t[i] - last < dt - tol:
            close.append(i)
    notes = []
    if close:
        notes.append(f"{len(close)} epoch{'s' if len(close) > 1 else ''} less than "
                     f"{dt - tol:g} s after the one before dropped (the log's interval "
                     f"is {dt:g} s): " + _times(t[close] - t0))
    return np.array(keep, dtype=int), notes


def recording_sky(s) -> Sky:
    """The :class:`~raimcore.sky.Sky` of a recorded scenario ``s`` (``source`` "rinex" or
    "android"): the epochs in its window, the satellites of its systems with a usable
    ephemeris (``s.sats`` when given), their positions and corrected pseudoranges, the
    station as the truth."""
    stamp = _stamp(s.obs, "obs")
    corr = load_recording(s.obs, s.nav, s.systems, s.signals, s.source)
    obs_file = _read_obs(stamp, s.source)
    notes = list(corr.notes)
    t_rel = corr.t_gps_s - corr.t_gps_s[0] if len(corr.t_gps_s) else corr.t_gps_s
    rows, grid_notes = _window(t_rel, s.t_start_s, s.duration_s, s.step_s,
                               grid=s.source != "android")
    notes += grid_notes
    # The receiver's own word that its clock restarted between two kept epochs: a phone's
    # HardwareClockDiscontinuityCount changed, a RINEX epoch flag 1 (power failure).
    if s.source == "android":
        segment = _read_log(stamp).clock_count
    else:
        segment = np.cumsum(obs_file.epoch_flag == 1)
    clock_reset = np.diff(segment[rows], prepend=segment[rows[:1]]) != 0
    if s.source == "android" and rows.size > 1:
        n_reset = int(np.count_nonzero(clock_reset))
        if n_reset:
            notes.append(f"the phone's hardware clock restarted between {n_reset} of "
                         f"{rows.size - 1} pairs of consecutive epochs "
                         "(HardwareClockDiscontinuityCount, duty cycling): its receiver "
                         "clock is referenced anew at each, so the clock bias may jump")
    if rows.size == 0:
        raise ValueError(f"t_start_s {s.t_start_s:g} / duration_s {s.duration_s:g} select no "
                         f"epoch of {s.obs} (it spans 0 to {t_rel[-1] if len(t_rel) else 0:g} s)")
    names = list(corr.sat_names)
    cols = np.arange(len(names))
    if s.sats:
        unknown = [x for x in s.sats if x not in names]
        if unknown:
            raise ValueError(f"sats: {', '.join(unknown)} not in this recording; choose from "
                             f"{', '.join(names)}")
        cols = np.array([names.index(x) for x in s.sats], dtype=int)
    names = [names[c] for c in cols]
    for f in s.faults:
        if f.system is None and f.sat not in names:
            raise ValueError(f"faults: satellite {f.sat!r} is not in this recording (with "
                             f"a usable ephemeris); choose from {', '.join(names)}")
    ix = np.ix_(rows, cols)
    t = t_rel[rows] - s.t_start_s
    if s.truth_ecef_m:
        truth = np.array(s.truth_ecef_m, dtype=float)
    elif np.any(obs_file.approx_pos_ecef_m):
        truth = obs_file.approx_pos_ecef_m
    else:
        sol = solve(corr, mask_deg=s.mask_deg).pos_ecef_m
        ok = np.isfinite(sol).all(-1)
        if not ok.any():
            raise ValueError(f"{s.obs}: no header position, no truth_ecef_m and no epoch "
                             "with a single-point solution: give truth_ecef_m")
        truth = np.median(sol[ok], axis=0)
        notes.append("no header position and no truth_ecef_m: truth is the median "
                     "single-point solution")
    sv = corr.pos_sv_ecef_m[ix]
    truth_e = np.broadcast_to(truth, (len(rows), 3)).copy()
    az, el = az_el(sv, truth_e)
    return Sky(t_s=t, sat_names=tuple(names), sys_idx=corr.sys_idx[cols],
               systems=tuple(corr.systems), pos_sv_ecef_m=sv, pos_rx_ecef_m=truth_e,
               vel_rx_ecef_mps=np.zeros_like(truth_e),
               h_rx_m=ecef_to_geodetic(truth_e)[2],
               range_m=np.linalg.norm(sv - truth_e[:, None, :], axis=-1), az_rad=az,
               el_rad=el, trackable=corr.tracked[ix] & corr.usable[ix], pr_m=corr.pr_m[ix],
               notes=tuple(notes), ura_m=corr.ura_m[ix], clock_reset=clock_reset)
