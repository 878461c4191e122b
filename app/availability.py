"""The availability map as a Plotly figure, HTML and PNG, and the ``raim availability``
subcommand (:func:`add_subcommand`, :func:`run`).

The numbers come from :func:`raimcore.studies.availability.availability` (ARAIM, MSS or
classic RAIM protection levels); this module draws them: a heatmap over longitude /
latitude (one cell per user, colour = share of available epochs in %, NaN outside the
region), the coastlines as the 0.5 contour of the dashboard's 1-degree land mask
(``app/assets/land_mask_1deg.npz``, nothing fetched), the contour of the target
availability (99.5 % by default, MAAST's ``avail_contour4.m`` draws it), and the coverage
in the title. HTML is self-contained (plotly.js inline, no CDN); the PNG is rendered by a
headless Chromium as :func:`app.stanford.write_png` does.

The subcommand lives here; ``app.cli.add`` registers it with ``raim``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # numpy, and the study's scipy: not for `raim --help`
    import numpy as np

    from raimcore.studies.availability import AvailabilityResult

#: Size of the standalone figure, px.
WIDTH_PX = 1200
HEIGHT_PX = 680
#: Availability classes (%, lower edges) and their colours, as MAAST's contour plots band
#: them: differences near 99-100 % matter, those below 90 % hardly.
LEVELS_PCT = (0.0, 50.0, 75.0, 90.0, 95.0, 99.0, 99.5, 99.9)
LEVEL_COLORS = ("#67000d", "#d7301f", "#fc8d59", "#fee08b", "#d9ef8b", "#91cf60",
                "#1a9850", "#006837")


def level_index(pct) -> np.ndarray:
    """Class of each availability (%) in :data:`LEVELS_PCT` (NaN stays NaN)."""
    import numpy as np

    pct = np.asarray(pct, dtype=float)
    idx = np.digitize(pct, LEVELS_PCT[1:]).astype(float)
    return np.where(np.isfinite(pct), idx, np.nan)


def _discrete_scale() -> list:
    n = len(LEVEL_COLORS)
    return [[k / n, c] for i, c in enumerate(LEVEL_COLORS) for k in (i, i + 1)]


def _level_labels() -> list[str]:
    lo = LEVELS_PCT
    return ([f"< {lo[1]:g} %"] + [f"{lo[i]:g}-{lo[i + 1]:g} %" for i in range(1, len(lo) - 1)]
            + [f">= {lo[-1]:g} %"])


def coastline_trace() -> dict:
    """The coastlines: the 0.5 contour of the 1-degree land mask (lines only)."""
    import numpy as np

    from .scene import land_mask

    land = land_mask()[::-1].astype(float)  # rows south -> north
    n_lat, n_lon = land.shape
    lat = -90.0 + 180.0 / n_lat * (np.arange(n_lat) + 0.5)
    lon = -180.0 + 360.0 / n_lon * (np.arange(n_lon) + 0.5)
    return {"type": "contour", "z": land.tolist(), "x": lon.tolist(), "y": lat.tolist(),
            "contours": {"start": 0.5, "end": 0.5, "size": 1.0, "coloring": "none"},
            "line": {"color": "rgba(20,20,20,0.8)", "width": 1.0}, "showscale": False,
            "hoverinfo": "skip", "name": "coastline", "showlegend": False}


#: Name of each algorithm in the figure title.
ALGORITHM_TITLES = {"araim": "ARAIM", "mss": "MSS (solution separation)",
                    "classic": "classic RAIM"}


def title_text(res: AvailabilityResult) -> str:
    s = res.settings
    alg = s.get("algorithm", "araim")
    src = s["constellation"]
    if src not in ("nominal", "almanac"):
        src = "almanac " + Path(src).name
    return (f"{ALGORITHM_TITLES.get(alg, alg)} LPV-200 availability, "
            f"{'+'.join(s['systems'])} ({src}), ISM {s['ism']}: coverage "
            f"{res.coverage_pct:.1f} % of users at {100 * res.target:g} % availability "
            "(cos-lat weighted)")


def criteria_text(res: AvailabilityResult) -> str:
    """What "available" meant (EMT and sigma_acc only for ARAIM)."""
    s = res.settings
    text = f"VPL <= {s['val_m']:g} m, HPL <= {s['hal_m']:g} m"
    if s.get("emt_max_m") is not None:
        return (f"{text}, EMT <= {s['emt_max_m']:g} m, sigma_acc <= "
                f"{s['sigma_acc_max_m']:g} m")
    return (f"{text} (EMT, sigma_acc do not apply to {s.get('algorithm')}; p_fa "
            f"{s.get('p_fa', float('nan')):g}, p_md {s.get('p_md', float('nan')):g})")


def map_figure(res: AvailabilityResult, *, width_px: int = WIDTH_PX,
               height_px: int = HEIGHT_PX) -> dict:
    """The availability map as a Plotly figure dict."""
    import numpy as np

    s = res.settings
    z = 100.0 * res.grid("availability")
    vpl = res.grid("vpl_median_m")
    custom = np.stack([z, vpl, res.grid("vpl_p99_m"), res.grid("hpl_median_m")], axis=-1)
    level = level_index(z)
    n = len(LEVEL_COLORS)
    heat = {"type": "heatmap", "x": res.lon_axis_deg.tolist(), "y": res.lat_axis_deg.tolist(),
            "z": np.where(np.isfinite(level), level, None).tolist(),
            "customdata": np.where(np.isfinite(custom), custom, None).tolist(),
            "zmin": -0.5, "zmax": n - 0.5, "colorscale": _discrete_scale(),
            "name": "availability",
            "colorbar": {"title": {"text": "available<br>epochs"},
                         "tickvals": list(range(n)), "ticktext": _level_labels()},
            "hovertemplate": "lat %{y:g} deg, lon %{x:g} deg<br>availability "
                             "%{customdata[0]:.2f} %<br>VPL median %{customdata[1]:.1f} m, "
                             "99th pct %{customdata[2]:.1f} m<br>HPL median "
                             "%{customdata[3]:.1f} m<extra></extra>"}
    data = [heat]
    if z.shape[0] >= 2 and z.shape[1] >= 2 and np.isfinite(z).any():
        t = 100.0 * res.target
        data.append({"type": "contour", "x": res.lon_axis_deg.tolist(),
                     "y": res.lat_axis_deg.tolist(),
                     "z": np.where(np.isfinite(z), z, None).tolist(),
                     "contours": {"start": t, "end": t, "size": 1.0, "coloring": "none",
                                  "showlabels": True},
                     "line": {"color": "#08306b", "width": 2.5, "dash": "dash"},
                     "showscale": False, "hoverinfo": "skip",
                     "name": f"{t:g} % availability", "showlegend": True})
    data.append(coastline_trace())
    lon_pad = s["lon_step_deg"] / 2.0
    lat_pad = s["lat_step_deg"] / 2.0
    layout = {
        "title": {"text": title_text(res), "x": 0.01, "font": {"size": 15}},
        "width": width_px, "height": height_px, "template": "plotly_white",
        "margin": {"l": 60, "r": 20, "t": 60, "b": 90},
        "xaxis": {"title": {"text": "longitude (deg)"}, "range":
                  [float(res.lon_axis_deg.min()) - lon_pad,
                   float(res.lon_axis_deg.max()) + lon_pad],
                  "ticksuffix": "°", "showgrid": False, "zeroline": False},
        "yaxis": {"title": {"text": "latitude (deg)"}, "range":
                  [float(res.lat_axis_deg.min()) - lat_pad,
                   float(res.lat_axis_deg.max()) + lat_pad],
                  "ticksuffix": "°", "scaleanchor": "x", "scaleratio": 1.0,
                  "showgrid": False, "zeroline": False},
        "legend": {"orientation": "h", "x": 0.0, "y": -0.12},
        "annotations": [{
            "text": (f"{s['t_step_s']:g} s epochs over {s['duration_s']:g} s, "
                     f"{s['lat_step_deg']:g} x {s['lon_step_deg']:g} deg, mask "
                     f"{s['mask_deg']:g} deg; available: {criteria_text(res)}"),
            "xref": "paper", "yref": "paper", "x": 1.0, "y": -0.15, "xanchor": "right",
            "showarrow": False, "font": {"size": 11}}],
    }
    return {"data": data, "layout": layout}


def write_html(fig: dict, path) -> Path:
    """Self-contained HTML (plotly.js inline, no CDN)."""
    from . import stanford

    return stanford.write_html(fig, path)


def write_png(fig: dict, path) -> Path:
    """PNG rendered by a headless Chromium (:func:`app.stanford.write_png`)."""
    from . import stanford

    return stanford.write_png(fig, path)


# --------------------------------------------------------------------------------------
# raim availability

EPILOG = """\
examples:
  raim availability                                  # MAAST's world: 10 deg, 24 h, 300 s
  raim availability --systems GPS,GAL --ism maast --png world.png
  raim availability --step 5 --region "30,-20;72,-20;72,45;30,45" --csv europe.csv
  raim availability --almanac GPS=almmops.txt GAL=gal_week703.alm --workers 2
  raim availability --algorithm mss --p-md 1e-3 --csv mss.csv
  raim availability --fde --ledger runs/fde   # Ctrl-C, then the same command resumes

Users on MAAST's grid (init_usrdata.m) of the region polygon (default: the world), height
0; epochs 0, T, ... < duration of the nominal constellations or the almanacs (YUMA or SEM;
FILE alone is GPS, SYS=FILE another system; unhealthy satellites are left out and named).
Coverage = cos(latitude)-weighted share of users available at least 99.5 % of the time
(evaluate_coverage.m).

--algorithm araim (default): the ARAIM MHSS protection levels (ADD v4.2, LPV-200 constants;
--fde: exclusion, the PLs are the worst over the exclusion candidates); an epoch is
available when VPL <= 35 m, HPL <= 40 m, EMT <= 15 m and sigma_acc <= 1.87 m.
--algorithm mss / classic: the single-fault solution-separation / chi-square slope PLs of
the baro paper (raimcore.algorithms.mss), one sigma per pseudorange (the ARAIM sigma_int of
the ISM), --p-fa (default {p_fa:g}) and --p-md (default {p_md:g}); available when
VPL <= 35 m and HPL <= 40 m: EMT and sigma_acc are ARAIM outputs and do not apply.

ISM: b2012 (default; sigma_URA 0.75 m, sigma_URE 0.5 m, b_nom 0.5 m, MAAST's priors) or
maast (MAAST's example ISD, sigma_URA GPS 2.4 / GAL 6 m: H-ARAIM grade, its vertical
accuracy sigma is about 3.3 m > 1.87 m, so the ARAIM LPV-200 coverage is 0 %).

--ledger DIR keeps every finished chunk of users in DIR (manifest.json + chunk_*.npz): the
same command again (--resume, the default) skips the finished chunks and gives the same
numbers, so an interrupted run resumes. A ledger written with other parameters is refused
(the message names them); --no-resume deletes it and starts afresh. --target, --workers,
--dask and the output files do not enter the ledger.
The HTML is one self-contained file (plotly.js inline, no CDN); --png needs a headless
Chromium or Chrome on PATH.
"""

#: Parameters of :func:`~raimcore.studies.availability.availability` -> the option that
#: sets them (for the one-line messages).
OPTION_NAMES = {"lat_step_deg": "--step", "lon_step_deg": "--step", "t_step_s": "--t-step",
                "duration_s": "--duration", "height_m": "--height", "mask_deg": "--mask",
                "workers": "--workers", "region": "--region", "systems": "--systems",
                "constellation": "--almanac", "dask": "--dask", "p_fa": "--p-fa",
                "p_md": "--p-md", "ledger_dir": "--ledger", "algorithm": "--algorithm",
                "fde": "--fde"}


def add_subcommand(sub) -> argparse.ArgumentParser:
    """Add the ``availability`` subcommand to the ``raim`` subparsers ``sub``."""
    from raimcore.studies._availability_defaults import ALGORITHMS, PL_P_FA, PL_P_MD

    p = sub.add_parser("availability", help="LPV-200 availability map of a user grid",
                       description="LPV-200 availability of ARAIM (or MSS, classic RAIM) "
                       "over a latitude/longitude grid of users during a day (MAAST's "
                       "study): coverage, a world map (HTML, PNG) and the grid as CSV.",
                       epilog=EPILOG.format(p_fa=PL_P_FA, p_md=PL_P_MD),
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--systems", default="GPS,GAL", metavar="SYS,SYS",
                   help="constellations, of GPS, GAL, BDS, GLO (default %(default)s)")
    p.add_argument("--step", type=float, default=10.0, metavar="DEG",
                   help="grid step in latitude and longitude (default %(default)g deg)")
    p.add_argument("--t-step", type=float, default=300.0, metavar="S",
                   help="time step (default %(default)g s)")
    p.add_argument("--duration", type=float, default=86400.0, metavar="S",
                   help="time span from t = 0 (default %(default)g s)")
    p.add_argument("--height", type=float, default=0.0, metavar="M",
                   help="user height (default %(default)g m)")
    p.add_argument("--mask", type=float, default=5.0, metavar="DEG",
                   help="elevation mask (default %(default)g deg)")
    p.add_argument("--region", metavar="LAT,LON;LAT,LON;...",
                   help="polygon of at least 3 vertices in degrees (default: the world); "
                        "write --region=-30,... when it starts with a minus sign")
    p.add_argument("--almanac", nargs="+", metavar="[SYS=]FILE",
                   help="YUMA or SEM almanacs instead of the nominal constellations")
    p.add_argument("--algorithm", default="araim", choices=ALGORITHMS,
                   help="protection levels (default %(default)s; see below)")
    p.add_argument("--fde", action="store_true",
                   help="araim: with exclusion (PLs over the exclusion candidates)")
    p.add_argument("--p-fa", type=float, metavar="P",
                   help=f"mss, classic: false-alarm probability (default {PL_P_FA:g})")
    p.add_argument("--p-md", type=float, metavar="P",
                   help=f"mss, classic: missed-detection probability (default {PL_P_MD:g})")
    p.add_argument("--ism", default="b2012", choices=("b2012", "maast"),
                   help="integrity support message (default %(default)s; see below)")
    p.add_argument("--user-model", default="ed259a", choices=("ed259a", "add"),
                   help="airborne multipath + noise model (default %(default)s, MAAST v5)")
    p.add_argument("--target", type=float, default=99.5, metavar="PCT",
                   help="availability a user needs to be covered (default %(default)g %%)")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="processes (default 1: this process)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on Dask: 'local' (a LocalCluster of --workers processes) or "
                        "a scheduler address")
    p.add_argument("--ledger", type=Path, metavar="DIR",
                   help="keep finished chunks in DIR so that the same command resumes an "
                        "interrupted run (created if missing; see below)")
    p.add_argument("--resume", action=argparse.BooleanOptionalAction, default=True,
                   help="with --ledger: reuse its finished chunks (default); --no-resume "
                        "deletes the ledger and starts afresh")
    p.add_argument("--out", type=Path, metavar="FILE.html",
                   help="write the map as HTML (default availability.html when neither "
                        "--png nor --csv is given)")
    p.add_argument("--png", type=Path, metavar="FILE.png",
                   help="also write a PNG (needs a Chromium or Chrome browser on PATH)")
    p.add_argument("--csv", type=Path, metavar="FILE.csv", help="write the grid as CSV")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)
    return p


def parse_region(text: str | None):
    """``"lat,lon;lat,lon;..."`` -> a list of (lat, lon) vertices, or a ValueError."""
    if text is None:
        return None
    pts = []
    for item in filter(None, (x.strip() for x in text.split(";"))):
        parts = item.split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            pts.append((float(parts[0]), float(parts[1])))
        except ValueError:
            raise ValueError(f"--region must be LAT,LON;LAT,LON;... in degrees, got "
                             f"{item!r} in {text!r}") from None
    if len(pts) < 3:
        raise ValueError(f"--region needs at least 3 vertices LAT,LON;LAT,LON;LAT,LON, got "
                         f"{text!r}")
    return pts


class ProgressBar:
    """A one-line text progress bar on stderr: ``bar(done, total)``."""

    def __init__(self, enabled: bool):
        import time

        self.enabled, self.t0, self.last = enabled, time.perf_counter(), 0.0

    def __call__(self, done: int, total: int) -> None:
        import sys
        import time

        now = time.perf_counter()
        if not self.enabled or (now - self.last < 0.25 and done < total):
            return
        self.last = now
        frac = done / max(total, 1)
        el = now - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        sys.stderr.write(f"\ravailability [{'#' * int(30 * frac):<30}] {100 * frac:5.1f}% "
                         f"{done}/{total} user-epochs, {el:5.1f} s, eta {eta:5.1f} s")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _study_kwargs(args) -> dict:
    """The keywords of the study from the parsed options (option-level checks here)."""
    from raimcore._validate import check_range

    if args.algorithm == "araim":
        for opt, v in (("--p-fa", args.p_fa), ("--p-md", args.p_md)):
            if v is not None:
                raise ValueError(f"{opt} applies to --algorithm mss or classic; araim "
                                 "takes its ADD v4.2 budgets")
    elif args.fde:
        raise ValueError(f"--fde applies to --algorithm araim, not {args.algorithm}")
    if args.ledger is None and not args.resume:
        raise ValueError("--no-resume needs --ledger DIR (there is no ledger to start "
                         "afresh)")
    kw = dict(lat_step_deg=args.step, lon_step_deg=args.step, region=parse_region(args.region),
              t_step_s=args.t_step, duration_s=args.duration, height_m=args.height,
              mask_deg=args.mask, ism=args.ism, user_model=args.user_model,
              target=check_range("--target", args.target, 0.0, 100.0) / 100.0,
              workers=args.workers, dask=args.dask, algorithm=args.algorithm,
              constellation=args.almanac if args.almanac else "nominal",
              ledger_dir=args.ledger, resume=args.resume)
    if args.fde:
        kw["fde"] = True
    for name in ("p_fa", "p_md"):
        if getattr(args, name) is not None:
            kw[name] = getattr(args, name)
    return kw


def run(args) -> int:
    """``raim availability``: check the inputs and outputs, run the study, write files.

    Every refused input is a ``ValueError`` naming the option (the ``raim`` command prints
    it on one line and exits with 2); Ctrl-C leaves the ledger's finished chunks.
    """
    from raimcore.studies.availability import availability

    from .cli import _check_file

    _check_file(args.out, "--out", ".html")
    _check_file(args.png, "--png", ".png")
    _check_file(args.csv, "--csv", ".csv")
    if args.out is not None or args.png is not None or args.csv is None:
        try:
            import plotly  # noqa: F401
        except ImportError as exc:
            raise ValueError(f"the map needs plotly: pip install 'raim-studio[app]' "
                             f"({exc}); --csv alone works without it") from None
    from . import stanford

    if args.png is not None and stanford.find_browser() is None:
        raise ValueError(f"cannot write {str(args.png)!r}: {stanford.png_requirement()}")
    kw = _study_kwargs(args)
    systems = [s.strip().upper() for s in args.systems.split(",") if s.strip()]
    out = args.out
    if out is None and args.png is None and args.csv is None:
        out = Path("availability.html")
    try:
        res = availability(systems, progress=ProgressBar(not args.quiet), **kw)
    except ValueError as exc:
        msg = str(exc)
        for key, opt in OPTION_NAMES.items():
            if msg.startswith(key + " ") or msg.startswith(key + ":"):
                msg = opt + msg[len(key):]
                break
        raise ValueError(msg.replace("resume=False (--no-resume)", "--no-resume")) from None
    for line in res.summary_lines():
        print(line)
    rate = res.n_user_epochs / res.wall_s if res.wall_s > 0 else float("nan")
    where = f"Dask {args.dask}" if args.dask else (
        f"{args.workers} processes" if args.workers > 1 else "in-process")
    print(f"time {res.wall_s:.1f} s ({rate:.0f} user-epochs/s, {where})")
    if args.csv is not None:
        res.to_csv(args.csv)
        print(f"grid written to {args.csv}")
    if out is not None or args.png is not None:
        fig = map_figure(res)
        if out is not None:
            write_html(fig, out)
            print(f"map written to {out}")
        if args.png is not None:
            write_png(fig, args.png)
            print(f"picture written to {args.png}")
    return 0
