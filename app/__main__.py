"""``python -m app [--host 127.0.0.1] [--port 8080] [--scenario NAME|FILE]``."""

from __future__ import annotations

import argparse
import sys

from .server import DEFAULT_HOST, DEFAULT_PORT, DEFAULT_SCENARIO, serve


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m app",
                                description="RAIM Studio web dashboard (viser + plotly)")
    add_arguments(p)
    return p


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--host", default=DEFAULT_HOST,
                   help="interface to listen on (default %(default)s, this machine only; "
                        "give another address explicitly to expose the dashboard)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help="port (default %(default)s)")
    p.add_argument("--scenario", default=DEFAULT_SCENARIO,
                   help="built-in scenario name or TOML file (default %(default)s)")


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    serve(args.host, args.port, args.scenario)
    return 0


if __name__ == "__main__":
    sys.exit(main())
