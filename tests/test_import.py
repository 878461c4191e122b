"""The core stays headless: importing it never pulls in a GUI library."""

import subprocess
import sys


def test_import_raimcore_does_not_import_gui_libraries():
    code = (
        "import sys, raimcore, raimcore.scenario, raimcore.pipeline, raimcore.algorithms,"
        " raimcore.cli;"
        "raimcore.algorithms.names();"
        "bad = [m for m in ('viser', 'plotly', 'app') if m in sys.modules];"
        "print(','.join(bad))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == ""


def test_raim_help_imports_no_numpy_scipy_numba_or_gui():
    """`raim --help` (with the app's subcommands registered) stays fast: it never imports
    numpy, scipy, numba, viser or plotly (issue 17: <= 0.5 s)."""
    code = (
        "import sys\n"
        "from raimcore.cli import main\n"
        "try:\n"
        "    main(['--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "heavy = ('numpy', 'scipy', 'numba', 'viser', 'plotly')\n"
        "print('LOADED=' + ','.join(m for m in heavy if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert "availability" in out.stdout  # the app's subcommands were registered
    assert out.stdout.strip().splitlines()[-1] == "LOADED="
