"""The ``raim dashboard``, ``raim stanford`` and ``raim availability`` subcommands,
registered with the ``raim`` command line through the ``raim.commands`` entry point (so
:mod:`raimcore` never imports :mod:`app`): its function :func:`add` adds them.

Everything a user can get wrong is checked before the server starts, each with one line
and a non-zero exit: the port (0-65535; busy -> refused when given explicitly, the next free
one announced when none was given), the host (an address of this machine), the scenario or
recording.
"""

from __future__ import annotations

import argparse
import socket
from pathlib import Path

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
#: Ports tried after the default one when no --port was given.
AUTO_PORT_TRIES = 20


def add(sub) -> None:
    """Add the ``dashboard``, ``stanford`` and ``availability`` subcommands to the ``raim``
    subparsers ``sub``."""
    from raimcore.cli import _add_recording_args

    p = sub.add_parser("dashboard", help="start the web dashboard",
                       description="Start the RAIM Studio web dashboard (viser + plotly) and "
                       "print its address. It listens on 127.0.0.1 (this machine only) "
                       "unless --host names another interface; it works offline.")
    add_arguments(p)
    _add_recording_args(p)
    p.set_defaults(func=run)
    add_stanford(sub)
    from .availability import add_subcommand as add_availability

    add_availability(sub)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default=DEFAULT_HOST,
                   help="interface to listen on (default %(default)s, this machine only; "
                        "give another address explicitly to expose the dashboard)")
    p.add_argument("--port", type=port_number, default=None,
                   help=f"port, 0-65535 (default {DEFAULT_PORT}, or the next free one "
                        "when it is busy; an explicit busy port is an error)")
    p.add_argument("--scenario", default="default",
                   help="built-in scenario name or .toml file to start from "
                        "(default %(default)s)")
    p.add_argument("--lessons", metavar="DIR", action="append", default=[],
                   help="folder of extra lessons (Markdown + TOML front matter), shown "
                        "after the built-in ones in the Lessons tab; repeatable")


def port_number(text: str) -> int:
    """argparse type: a TCP port 0-65535 (0: any free port)."""
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"port must be an integer 0-65535, got {text!r}") \
            from None
    if not 0 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port must be in 0-65535, got {port}")
    return port


def check_host(host: str) -> None:
    """Refuse a host that is not an address of this machine (ValueError, one line)."""
    try:
        infos = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        raise ValueError(f"--host {host!r} is not a valid address or known host name "
                         f"({exc})") from None
    for family, _, _, _, addr in infos:
        try:
            with socket.socket(family, socket.SOCK_STREAM) as s:
                s.bind((addr[0], 0))
            return
        except OSError:
            continue
    raise ValueError(f"--host {host!r} is not an address of this machine: cannot listen on "
                     "it (use 127.0.0.1 or another address of this machine)")


def port_free(host: str, port: int) -> bool:
    """True when nothing listens on ``host:port`` and we may bind it."""
    family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


def choose_port(host: str, port: int | None) -> tuple[int, str | None]:
    """The port to serve on and, when it is not the one asked for, a line saying so.

    An explicit port must be free (ValueError otherwise: a user who typed it must not land
    on someone else's server). Without one, the default or the next free port."""
    if port is not None:
        if port != 0 and not port_free(host, port):
            raise ValueError(f"--port {port}: the port is busy on {host} (another program "
                             "listens there); choose another with --port, or stop it")
        return port, None
    for p in range(DEFAULT_PORT, DEFAULT_PORT + AUTO_PORT_TRIES):
        if port_free(host, p):
            note = None if p == DEFAULT_PORT else (
                f"port {DEFAULT_PORT} is busy: using port {p}")
            return p, note
    raise ValueError(f"ports {DEFAULT_PORT}-{DEFAULT_PORT + AUTO_PORT_TRIES - 1} are all "
                     "busy; choose one with --port")


def run(args) -> int:
    """``raim dashboard``: check everything, then serve until Ctrl-C."""
    from raimcore.cli import _recording_scenario
    from raimcore.scenario import load_scenario

    try:
        import plotly  # noqa: F401
        import viser  # noqa: F401
    except ImportError as exc:
        raise ValueError(f"the dashboard needs its optional dependencies: pip install "
                         f"'raim-studio[app]' ({exc})") from None
    check_host(args.host)
    if args.obs or args.android or args.nav:  # a recording (RINEX or a phone log): read
        from raimcore.sky.recording import load_recording  # it now, errors before serving

        args.scenario = None if args.scenario == "default" else args.scenario
        scenario = _recording_scenario(args, {})  # --nav may be repeated: merged
        load_recording(scenario.obs, scenario.nav, scenario.systems, scenario.signals,
                       scenario.source)
    else:
        load_scenario(args.scenario)  # fail early, with the scenario error, before serving
        scenario = args.scenario
    from .lessons import check_lesson_dirs

    check_lesson_dirs(args.lessons)  # a bad lesson file: one line naming it, exit 2
    port, note = choose_port(args.host, args.port)
    if note:
        print(note, flush=True)
    from .server import serve

    serve(args.host, port, scenario, lesson_dirs=args.lessons)
    return 0


# ---------------------------------------------------------------------------------------
# raim stanford

STANFORD_EPILOG = """\
examples:
  raim stanford default --algorithm mss --set hal_m=40 --set val_m=50
  raim stanford seed001-flight --algorithm mss --pl classic --png flight.png
  raim stanford result.csv --set hal_m=40 --set val_m=50 --out result.html
  raim stanford --obs STATION.rnx --nav BRDC.rnx --algorithm mss --bin 0.5

The input is a result CSV of 'raim run ... --out result.csv' (of an algorithm that gives
protection levels) or a scenario, which is run first (a built-in name, a .toml file, or a
recording with --obs/--android and --nav; --set, --fault, --seed, --algorithm and
--error-model as in 'raim run'). A CSV keeps no alert limits: give them with --set hal_m=...
--set val_m=... (default: the scenario defaults).

Regions (gLAB's): nominal PE < PL < AL; MI PE >= PL, PE < AL; HMI PE >= PL, PE >= AL,
PL < AL; unavailable PL >= AL or no solution. The HTML is one self-contained file
(plotly.js inline, no CDN). --png renders that page with a headless Chromium or Chrome
found on PATH (Debian: apt-get install chromium); without one, --png is refused.
"""


def add_stanford(sub) -> None:
    """Add the ``stanford`` subcommand to the ``raim`` subparsers ``sub``."""
    from raimcore.cli import _add_scenario_args

    p = sub.add_parser("stanford", help="draw the Stanford-ESA integrity diagram of a run",
                       description="Draw the Stanford-ESA integrity diagram of a result "
                       "CSV or of a scenario run:\nposition error vs protection level, "
                       "horizontal and vertical, the nominal, MI, HMI and\nunavailable "
                       "regions counted; as HTML and optionally PNG.",
                       epilog=STANFORD_EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    _add_scenario_args(p)
    for action in p._actions:  # the same positional as 'raim run', which also takes a CSV
        if action.dest == "scenario":
            action.metavar = "RESULT.csv|SCENARIO"
            action.help = ("a result CSV of 'raim run --out', or a built-in scenario name "
                           "or .toml file to run (optional with --obs or --android)")
    p.add_argument("--algorithm", "-a", help="algorithm to run (one that gives protection "
                   "levels: see 'raim list')")
    p.add_argument("--out", type=Path, metavar="FILE.html",
                   help="write the diagram as HTML (default: NAME-stanford.html when "
                        "--png is not given)")
    p.add_argument("--png", type=Path, metavar="FILE.png",
                   help="also write a PNG; needs a Chromium or Chrome browser on PATH "
                        "(chromium, google-chrome; Debian: apt-get install chromium), "
                        "no Python package")
    p.add_argument("--error", choices=("before", "after"), default="before",
                   help="position errors of the full-set solution the protection levels "
                        "are computed for (before, default) or of the solution after "
                        "exclusion (after)")
    p.add_argument("--pl", default="", metavar="VARIANT",
                   help="protection levels hpl_VARIANT_m and vpl_VARIANT_m instead of "
                        "hpl_m and vpl_m (mss: classic, nobaro)")
    p.add_argument("--bin", type=float, default=None, dest="bin_m", metavar="M",
                   help="histogram bin in metres (default 0.1, gLAB's)")
    p.add_argument("--max", type=float, default=None, dest="max_m", metavar="M",
                   help="histogram range in metres (default: past the largest error or "
                        "protection level); larger values are drawn in the last bin")
    p.set_defaults(func=run_stanford)


def _check_file(path: Path | None, option: str, suffix: str) -> None:
    """Refuse an output path before any work: ``suffix``, a folder that exists."""
    if path is None:
        return
    if path.suffix.lower() != suffix:
        raise ValueError(f"{option} must end in {suffix}, got {str(path)!r}")
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ValueError(f"{option}: folder {str(folder)!r} does not exist (create it first)")
    if path.is_dir():
        raise ValueError(f"{option}: {str(path)!r} is a folder; give a file name")


def _csv_alert_limits(args) -> tuple[float, float, list[str]]:
    """HAL and VAL for a result CSV: from ``--set hal_m= / val_m=`` or the scenario
    defaults (with a note saying so); any other scenario option is refused."""
    from raimcore.scenario import SCENARIO_KEYS, parse_value

    other = [opt for opt, given in (("--obs", args.obs), ("--android", args.android),
                                    ("--nav", args.nav), ("--fault", args.faults),
                                    ("--seed", args.seed is not None),
                                    ("--algorithm", args.algorithm),
                                    ("--error-model", args.error_model)) if given]
    if other:
        raise ValueError(f"{', '.join(other)}: a result CSV is not run again; it takes only "
                         "--set hal_m=... and --set val_m=...")
    limits = {}
    for item in args.sets:
        key, sep, val = item.partition("=")
        key = key.strip()
        if not sep or key not in ("hal_m", "val_m"):
            raise ValueError(f"--set {item!r}: a result CSV takes only --set hal_m=... and "
                             "--set val_m=... (its alert limits)")
        limits[key] = SCENARIO_KEYS[key].coerce(parse_value(val.strip()))
    notes = []
    missing = [k for k in ("hal_m", "val_m") if k not in limits]
    for k in missing:
        limits[k] = SCENARIO_KEYS[k].default
    if missing:
        notes.append("a result CSV keeps no alert limits: "
                     + ", ".join(f"{k} {limits[k]:g} m" for k in missing)
                     + " (the scenario default; --set " + "=... --set ".join(missing)
                     + "=... to choose)")
    return limits["hal_m"], limits["val_m"], notes


def run_stanford(args) -> int:
    """``raim stanford``: check the inputs and outputs, make the diagram, write the files."""
    from raimcore._validate import check_positive

    try:
        import plotly  # noqa: F401
    except ImportError as exc:
        raise ValueError(f"raim stanford needs plotly: pip install 'raim-studio[app]' "
                         f"({exc})") from None
    from raimcore.scoring.stanford import DEFAULT_BIN_M, pl_columns, stanford_from_csv

    from . import stanford

    _check_file(args.out, "--out", ".html")
    _check_file(args.png, "--png", ".png")
    if args.png is not None and stanford.find_browser() is None:
        raise ValueError(f"cannot write {str(args.png)!r}: {stanford.png_requirement()}")
    bin_m = check_positive("--bin", DEFAULT_BIN_M if args.bin_m is None else args.bin_m)
    max_m = None if args.max_m is None else check_positive("--max", args.max_m)
    pl_columns(args.pl)  # a bad variant, before any run
    kw = dict(error=args.error, pl=args.pl, bin_m=bin_m, max_m=max_m)
    notes: list[str] = []
    if args.scenario and args.scenario.lower().endswith(".csv"):
        hal_m, val_m, notes = _csv_alert_limits(args)
        diagram = stanford_from_csv(args.scenario, hal_m, val_m, **kw)
        stem = Path(args.scenario).stem
    else:
        from raimcore.cli import _overrides, _recording_scenario
        from raimcore.pipeline import run_scenario
        from raimcore.scenario import load_scenario
        from raimcore.scoring.stanford import stanford_from_result

        over = _overrides(args)
        scenario = _recording_scenario(args, over) or load_scenario(args.scenario, **over)
        result = run_scenario(scenario)
        notes = list(result.summary.notes)
        diagram = stanford_from_result(result, **kw)
        stem = Path(scenario.name).stem or "stanford"
    fig = stanford.diagram_figure(diagram)
    out = args.out
    if out is None and args.png is None:
        out = Path(f"{stem}-stanford.html")
    for note in notes:
        print(f"note: {note}")
    print(f"Stanford-ESA diagram of {diagram.source} (errors {diagram.error} exclusion, "
          f"{diagram.pl_columns[0]}, {diagram.pl_columns[1]}):")
    for line in diagram.summary_lines():
        print(f"  {line}")
    if out is not None:
        stanford.write_html(fig, out)
        print(f"diagram written to {out}")
    if args.png is not None:
        stanford.write_png(fig, args.png)
        print(f"picture written to {args.png}")
    return 0
