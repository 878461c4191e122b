"""The ``raim dashboard`` subcommand, registered with the ``raim`` command line through the
``raim.commands`` entry point (so :mod:`raimcore` never imports :mod:`app`).

Everything a user can get wrong is checked before the server starts, each with one line
and a non-zero exit: the port (0-65535; busy -> refused when given explicitly, the next free
one announced when none was given), the host (an address of this machine), the scenario or
recording.
"""

from __future__ import annotations

import argparse
import socket

DEFAULT_HOST = "127.0.0.1"
DEFAULT_PORT = 8080
#: Ports tried after the default one when no --port was given.
AUTO_PORT_TRIES = 20


def add(sub) -> None:
    """Add the ``dashboard`` subcommand to the ``raim`` subparsers ``sub``."""
    from raimcore.cli import _add_recording_args

    p = sub.add_parser("dashboard", help="start the web dashboard",
                       description="Start the RAIM Studio web dashboard (viser + plotly) and "
                       "print its address. It listens on 127.0.0.1 (this machine only) "
                       "unless --host names another interface; it works offline.")
    add_arguments(p)
    _add_recording_args(p)
    p.set_defaults(func=run)


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
