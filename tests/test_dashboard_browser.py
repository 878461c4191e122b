"""One real browser test: Debian's headless Chromium (never a downloaded browser) loads the
dashboard, moves a slider through the DOM, waits for a panel to change, and checks that the
3D view is not blank."""

from __future__ import annotations

import io
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
playwright_api = pytest.importorskip("playwright.sync_api")

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]
SHOTS = Path(os.environ.get("RAIM_SCREENSHOT_DIR", "/tmp/raim-dashboard-shots"))

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture(scope="module")
def dash():
    if not Path(CHROMIUM).exists() and shutil.which("chromium") is None:
        pytest.fail("Debian's chromium is missing: apt-get install -y chromium "
                    "(the CI script installs it; this test must run, not skip)")
    from app.server import Dashboard

    d = Dashboard(port=0, verbose=False)
    yield d
    d.stop()


def _plot_signature(page) -> str:
    """The drawn traces of the detection panel (SVG path data), as one string."""
    return page.evaluate("""() => {
        const plots = [...document.querySelectorAll('.js-plotly-plot')];
        const det = plots.find(p => (p.textContent || '').includes('Detection'));
        if (!det) return '';
        return [...det.querySelectorAll('.scatterlayer path.js-line')]
            .map(p => p.getAttribute('d') || '').join('|');
    }""")


def test_page_loads_reacts_to_a_slider_and_draws_the_scene(dash):
    import imageio.v3 as iio

    SHOTS.mkdir(parents=True, exist_ok=True)
    with playwright_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1500, "height": 950})
            outside = []
            page.on("request", lambda r: outside.append(r.url)
                    if r.url.startswith("http") and not r.url.startswith(dash.url) else None)
            page.goto(dash.url)
            # The panels arrive over the websocket after the first recompute.
            page.wait_for_function("() => [...document.querySelectorAll('.js-plotly-plot')]"
                                   ".some(p => (p.textContent||'').includes('Detection'))",
                                   timeout=90_000)
            page.wait_for_timeout(1500)
            before = _plot_signature(page)
            assert before, "detection panel has no drawn traces"
            (session,) = dash.wait_for_sessions(1)
            assert session.scheduler.wait_idle(60)
            sigma0 = session.sigma.value
            n0 = session.timing.n_recomputes

            # Move the "Noise sigma (m)" slider with the keyboard, like a user.
            thumb = page.get_by_role("slider").first
            thumb.focus()
            for _ in range(10):
                page.keyboard.press("ArrowRight")
            page.wait_for_function(
                "(before) => { const plots = [...document.querySelectorAll('.js-plotly-plot')];"
                " const det = plots.find(p => (p.textContent||'').includes('Detection'));"
                " if (!det) return false;"
                " const now = [...det.querySelectorAll('.scatterlayer path.js-line')]"
                ".map(p => p.getAttribute('d') || '').join('|');"
                " return now && now !== before; }", arg=before, timeout=90_000)
            assert session.scheduler.wait_idle(60)
            moved = sigma0 + 10 * session.sigma.step  # ten arrow presses, one step each
            assert session.sigma.value == pytest.approx(moved)
            assert session.result.scenario.sigma_m == pytest.approx(moved)
            assert session.timing.n_recomputes > n0
            page.wait_for_timeout(1500)
            page.screenshot(path=str(SHOTS / "dashboard.png"))

            # The 3D view is not blank: the canvas shows Earth, orbits and satellites.
            canvas = page.locator("canvas").first
            png = canvas.screenshot(path=str(SHOTS / "scene.png"))
            img = iio.imread(io.BytesIO(png)).astype(float)[..., :3]
            assert img.std() > 10.0, f"3D view looks blank (pixel std {img.std():.1f})"
            n_colours = len(np.unique((img // 16).reshape(-1, 3), axis=0))
            assert n_colours > 20, f"3D view has only {n_colours} colours"
            assert outside == [], f"the page fetched from elsewhere: {outside[:5]}"
        finally:
            browser.close()
