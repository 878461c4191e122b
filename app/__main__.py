"""``python -m app [--host 127.0.0.1] [--port 8080] [--scenario NAME|FILE]``: the same as
``raim dashboard``."""

from __future__ import annotations

import sys

from raimcore.cli import main as raim_main


def main(argv=None) -> int:
    return raim_main(["dashboard", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
