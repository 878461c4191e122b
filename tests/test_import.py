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
