"""The dashboard's own plotly.js bundle (app/assets/plotly): it holds every trace type a
panel draws, and the session sends it in place of viser's full bundle."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

pytest.importorskip("viser")
pytest.importorskip("plotly")

from app import page, panels  # noqa: E402
from app.session import _run_scenario, run_view  # noqa: E402
from raimcore.scenario import load_scenario  # noqa: E402

ENTRY_JS = Path(page.__file__).parent / "assets" / "plotly" / "entry.js"


def _trace_types(fig: dict) -> set[str]:
    return {t.get("type", "scatter") for t in fig["data"]}


def test_the_bundle_registers_exactly_the_listed_trace_types():
    modules = set(re.findall(r"require\('plotly\.js/lib/(\w+)'\)", ENTRY_JS.read_text()))
    assert modules - {"core"} | {"scatter"} == page.PLOTLY_TRACE_TYPES


def test_the_bundle_is_the_plotly_js_major_version_plotly_py_ships():
    import plotly

    full = (Path(plotly.__file__).parent / "package_data" / "plotly.min.js").read_text()[:300]
    ours = page.plotly_js()
    assert ours is not None and ours.endswith("window.Plotly = Plotly;\n")
    v_full = re.search(r"plotly\.js v(\d+)\.", full).group(1)
    v_ours = re.search(r"plotly\.js v(\d+)\.", ours[:300]).group(1)
    assert v_ours == v_full


@pytest.mark.parametrize("name, algorithm", [
    ("default", None), ("default", "mss"), ("default", "gf"), ("default", "pf-llr"),
    ("default", "ekf"), ("araim", None), ("seed004-multi", None), ("seed002", None),
])
def test_every_panel_draws_only_bundled_trace_types(name, algorithm):
    s = load_scenario(name)
    s = s.replace(duration_s=min(s.duration_s, 400.0),
                  **({"algorithm": algorithm} if algorithm else {}))
    view = run_view(_run_scenario(s))
    built = panels.panels_for(view)
    assert built
    for key, build in built:
        fig = build(view)
        for i in (0, len(view.table["t_s"]) - 1):
            used = _trace_types(fig.to_dict(i))
            assert used <= page.PLOTLY_TRACE_TYPES, (key, used - page.PLOTLY_TRACE_TYPES)


def test_the_availability_map_draws_only_bundled_trace_types():
    from app.availability import map_figure
    from raimcore.studies.availability import availability

    res = availability(("GPS", "GAL"), lat_step_deg=60.0, lon_step_deg=90.0,
                       t_step_s=3600.0, duration_s=7200.0)
    fig = map_figure(res)
    fig = fig.to_dict() if hasattr(fig, "to_dict") else fig
    assert _trace_types(fig) <= page.PLOTLY_TRACE_TYPES


class _Interface:
    def __init__(self):
        self.sent = []

    def queue_message(self, message):
        self.sent.append(message)


class _Gui:
    def __init__(self, flag=False):
        if flag is not None:
            self._setup_plotly_js = flag
        self._websock_interface = _Interface()


class _Client:
    def __init__(self, gui):
        self.gui = gui


def test_send_plotly_replaces_viser_bundle_once():
    gui = _Gui()
    script = page.PageScript(_Client(gui))
    assert script.send_plotly(gui) is True
    assert gui._setup_plotly_js is True  # viser's add_plotly then sends nothing more
    (msg,) = gui._websock_interface.sent
    assert msg.source.startswith("/* plotly.js v") and "partial bundle" in msg.source[:300]
    assert script.send_plotly(gui) is False  # already there
    assert len(gui._websock_interface.sent) == 1


def test_send_plotly_leaves_an_unknown_viser_alone():
    gui = _Gui(flag=None)  # a viser without the flag: it sends its own bundle
    assert page.PageScript(_Client(gui)).send_plotly(gui) is False
    assert gui._websock_interface.sent == []


def test_viser_keeps_the_flag_send_plotly_sets():
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        assert server.gui._setup_plotly_js is False
    finally:
        server.stop()
