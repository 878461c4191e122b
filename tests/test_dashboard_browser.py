"""Real browser tests: Debian's headless Chromium (never a downloaded browser) loads the
dashboard and is driven through the DOM.

- the page renders, reacts to a slider and draws the 3D scene;
- the layout: every plot on screen at its declared height (within 10 %), titles within
  their plots, legends inside their figures, the 3D view at least half of the window, at
  1600x1000 and 1000x700;
- the time slider moves the plots' cursor without any figure being sent again (a few kB
  per step), and a plot redrawn by viser later (a resized window) keeps it.
"""

from __future__ import annotations

import io
import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("viser")
playwright_api = pytest.importorskip("playwright.sync_api")

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]
SHOTS = Path(os.environ.get("RAIM_SCREENSHOT_DIR", "/tmp/raim-dashboard-shots"))
WAIT_MS = 90_000
#: On-screen plot height within this fraction of the declared one.
HEIGHT_TOLERANCE = 0.10

pytestmark = [pytest.mark.browser, pytest.mark.slow]

# The page's plots as the tests read them: key, rectangle, title and legend boxes.
PLOTS_JS = """() => [...document.querySelectorAll('.js-plotly-plot')].map(gd => {
  const r = gd.getBoundingClientRect();
  const box = (e) => { const b = e.getBoundingClientRect();
    return [b.left - r.left, b.right - r.left, b.top - r.top, b.bottom - r.top]; };
  const legend = gd.querySelector('.legend');
  return {key: gd.layout.meta && gd.layout.meta.raim, width: r.width, height: r.height,
          titles: [...gd.querySelectorAll('.gtitle, .gtitle-subtitle')].map(box),
          legend: legend ? box(legend) : null};
})"""

# The drawn "now" line of a plot (SVG path), its layout x0, and a mark on its data.
CURSOR_JS = """(key) => {
  const gd = [...document.querySelectorAll('.js-plotly-plot')]
    .find(p => p.layout.meta && p.layout.meta.raim === key);
  if (!gd) return null;
  const k = (gd.layout.shapes || []).findIndex(s => s.name === 'now');
  const path = gd.querySelector(`.shapelayer path[data-index="${k}"]`);
  return {x0: k >= 0 ? gd.layout.shapes[k].x0 : null,
          d: path ? path.getAttribute('d') : null, mark: gd.data[0].__raimMark || null};
}"""

THUMB_JS = """(label) => [...document.querySelectorAll('[role=slider]')].find(s => {
  for (let e = s, k = 0; e && k < 10; e = e.parentElement, k++)
    if ((e.textContent || '').trim().startsWith(label)) return true;
  return false; })"""


@pytest.fixture(scope="module")
def dash():
    if not Path(CHROMIUM).exists() and shutil.which("chromium") is None:
        pytest.fail("Debian's chromium is missing: apt-get install -y chromium "
                    "(the CI script installs it; this test must run, not skip)")
    from app.server import Dashboard

    d = Dashboard(port=0, verbose=False)
    yield d
    d.stop()


@pytest.fixture(scope="module")
def browser(dash):
    with playwright_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        try:
            yield b
        finally:
            b.close()


def _open(dash, browser, width: int, height: int):
    """A new tab at ``width`` x ``height`` with its plots drawn: (page, session)."""
    known = set(dash.sessions.values())
    page = browser.new_page(viewport={"width": width, "height": height})
    page.goto(dash.url)
    page.wait_for_function("() => [...document.querySelectorAll('.js-plotly-plot')]"
                           ".some(p => (p.textContent||'').includes('Detection'))",
                           timeout=WAIT_MS)
    (session,) = [s for s in dash.wait_for_sessions(len(known) + 1) if s not in known]
    assert session.scheduler.wait_idle(60)
    return page, session


def _close(dash, page, session) -> None:
    page.close()
    t_end = time.monotonic() + 30
    while session in dash.sessions.values() and time.monotonic() < t_end:
        time.sleep(0.05)


def _plot_signature(page) -> str:
    """The drawn traces of the detection panel (SVG path data), as one string."""
    return page.evaluate("""() => {
        const plots = [...document.querySelectorAll('.js-plotly-plot')];
        const det = plots.find(p => (p.textContent || '').includes('Detection'));
        if (!det) return '';
        return [...det.querySelectorAll('.scatterlayer path.js-line')]
            .map(p => p.getAttribute('d') || '').join('|');
    }""")


def test_page_loads_reacts_to_a_slider_and_draws_the_scene(dash, browser):
    import imageio.v3 as iio

    SHOTS.mkdir(parents=True, exist_ok=True)
    page = browser.new_page(viewport={"width": 1500, "height": 950})
    try:
        outside = []
        page.on("request", lambda r: outside.append(r.url)
                if r.url.startswith("http") and not r.url.startswith(dash.url) else None)
        known = set(dash.sessions.values())
        page.goto(dash.url)
        # The panels arrive over the websocket after the first recompute.
        page.wait_for_function("() => [...document.querySelectorAll('.js-plotly-plot')]"
                               ".some(p => (p.textContent||'').includes('Detection'))",
                               timeout=WAIT_MS)
        page.wait_for_timeout(1500)
        before = _plot_signature(page)
        assert before, "detection panel has no drawn traces"
        (session,) = [s for s in dash.wait_for_sessions(len(known) + 1) if s not in known]
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
            " return now && now !== before; }", arg=before, timeout=WAIT_MS)
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
        page.close()


@pytest.mark.parametrize(("width", "height"), [(1600, 1000), (1000, 700)])
def test_plots_have_their_heights_and_the_3d_view_keeps_half(dash, browser, width, height):
    from app import page as app_page

    page, session = _open(dash, browser, width, height)
    try:
        # The page reports its window; the session sizes the side panels from it.
        t_end = time.monotonic() + 30
        while session.window_px != (width, height) and time.monotonic() < t_end:
            time.sleep(0.05)
        assert session.window_px == (width, height)
        assert (session.controls_px, session.plots_px) == app_page.side_panel_widths(width)
        intended = {f.key: f.height_px for f in session.figures.values()}
        # viser redraws the plots at their new aspect: wait until they settle.
        page.wait_for_function(
            """([intended, tol]) => { const plots = [...document.querySelectorAll(
                 '.js-plotly-plot')];
               return plots.length === Object.keys(intended).length && plots.every(gd => {
                 const h = intended[gd.layout.meta.raim];
                 return Math.abs(gd.getBoundingClientRect().height - h) <= tol * h; }); }""",
            arg=[intended, HEIGHT_TOLERANCE], timeout=30_000)
        plots = page.evaluate(PLOTS_JS)
        assert {p["key"] for p in plots} == set(intended)
        for p in plots:
            h = intended[p["key"]]
            assert abs(p["height"] - h) <= HEIGHT_TOLERANCE * h, (p["key"], p["height"], h)
            for left, right, top, _bottom in p["titles"]:  # titles fit their plot
                assert left >= 0 and right <= p["width"] + 1 and top >= 0, p
            if p["legend"] is not None:  # legends inside their figure
                left, right, top, bottom = p["legend"]
                assert left >= 0 and right <= p["width"] + 1, p
                assert 0 <= top and bottom <= p["height"] + 1, p
        canvas = page.evaluate("() => document.querySelector('canvas')"
                               ".getBoundingClientRect().width")
        assert canvas >= width / 2, f"3D view {canvas:.0f} px of a {width} px window"
        SHOTS.mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(SHOTS / f"layout-{width}x{height}.png"))
    finally:
        _close(dash, page, session)


def test_time_slider_moves_the_cursor_without_resending_figures(dash, browser):
    page, session = _open(dash, browser, 1600, 1000)
    received = []
    try:
        page.wait_for_function("() => window.__raimStudio && window.__raimStudio.installed"
                               " && window.__raimStudio.state", timeout=30_000)
        page.wait_for_timeout(1500)  # the first figures settled
        page.evaluate("""() => document.querySelectorAll('.js-plotly-plot').forEach(
            gd => { gd.data[0].__raimMark = gd.layout.meta.raim; })""")
        before = page.evaluate(CURSOR_JS, "detection")
        assert before["x0"] == 0.0 and before["mark"] == "detection"
        cdp = page.context.new_cdp_session(page)
        cdp.send("Network.enable")
        cdp.on("Network.webSocketFrameReceived",
               lambda e: received.append(len(e["response"]["payloadData"])))

        page.evaluate_handle(THUMB_JS, "t (s)").as_element().focus()
        for _ in range(5):
            page.keyboard.press("ArrowRight")
            page.wait_for_timeout(150)
        t_end = time.monotonic() + 30
        while session.i_epoch != 5 and time.monotonic() < t_end:
            time.sleep(0.05)
        assert session.scheduler.wait_idle(30) and session.i_epoch == 5
        seq = session.page.last_state["seq"]
        page.wait_for_function("(seq) => window.__raimStudio.state.seq >= seq", arg=seq,
                               timeout=30_000)
        page.wait_for_timeout(500)

        after = page.evaluate(CURSOR_JS, "detection")
        assert after["x0"] == 5.0 and after["d"] != before["d"]  # the cursor moved
        assert after["mark"] == "detection"  # the figure was not drawn anew from JSON
        for fig in session.figures.values():
            assert page.evaluate(CURSOR_JS, fig.key)["mark"] == fig.key, fig.key
        # Five steps cost a few kB (base64 frames as the page got them), not figures.
        assert sum(received) < 5 * 12_000, received
        # The sky plot's "now" markers are the session's at t = 5 s.
        state = session.time_state(5)
        used = next(tr for tr in state["dyn"]["sky"]["traces"] if tr["name"] == "used")
        shown = page.evaluate("""() => { const gd = [...document.querySelectorAll(
            '.js-plotly-plot')].find(p => p.layout.meta.raim === 'sky');
            const tr = gd.data.find(t => t.name === 'used'); return tr.text; }""")
        assert sorted(shown) == sorted(used["text"])

        # viser draws the plots again from their JSON when the window changes size:
        # the cursor stays where the slider is.
        page.set_viewport_size({"width": 1300, "height": 1000})
        page.wait_for_timeout(2500)
        resized = page.evaluate(CURSOR_JS, "detection")
        assert resized["x0"] == 5.0
    finally:
        _close(dash, page, session)


# -- lessons walked in the browser -----------------------------------------------------

def _row(page, handle):
    """The on-page row (label and input) of the viser control ``handle``."""
    return page.locator(f'label[for="{handle._impl.uuid}"]').locator("xpath=../../..")


def _reveal(page, handle, folder: str) -> None:
    """Open the control panel folder ``folder`` when ``handle``'s row is hidden in it."""
    label = page.locator(f'label[for="{handle._impl.uuid}"]')
    if label.count() and label.first.is_visible():
        return
    page.get_by_text(folder, exact=True).first.click()
    label.first.wait_for(state="visible", timeout=10_000)


def _enter(page, handle, value, folder: str) -> None:
    """Type, pick or tick ``value`` in the control ``handle`` as a student would, and see
    that the dashboard got it (an entry made while the page was busy is made again)."""
    handles = _viser_handles()
    for _attempt in range(3):
        _reveal(page, handle, folder)
        row = _row(page, handle)
        if isinstance(handle, handles.GuiDropdownHandle):
            row.locator("input").first.click()
            page.get_by_role("option", name=str(value), exact=True).click()
        elif isinstance(handle, handles.GuiCheckboxHandle):
            row.locator("input").first.set_checked(bool(value))
        else:
            box = row.locator("input").last  # a slider's number box, a number or text
            box.click()
            box.press("Control+a")
            box.press_sequentially(f"{value:g}" if isinstance(value, float) else str(value))
            box.press("Enter")
            box.blur()
        t_end = time.monotonic() + 10
        while time.monotonic() < t_end:
            if _shows(handle.value, value):
                return
            time.sleep(0.05)
    raise AssertionError(f"{handle.label}: entered {value!r}, the dashboard has "
                         f"{handle.value!r}")


def _shows(held, value) -> bool:
    """Does a control holding ``held`` stand for the entered ``value``?"""
    if isinstance(value, bool) or isinstance(held, bool):
        return bool(held) == bool(value)
    if isinstance(value, int | float) and isinstance(held, int | float):
        return abs(float(held) - float(value)) <= 1e-9 * max(1.0, abs(float(value)))
    return str(held).strip().lower() == str(value).strip().lower()


def _viser_handles():
    import viser._gui_handles as handles

    return handles


def _student_edits(session, overrides: dict) -> list[tuple[object, object, str]]:
    """The control entries that turn the set-up lesson into its ``overrides``:
    ``(handle, value, folder)``, in the order a student makes them."""
    edits = []
    for name, value in overrides.items():
        if name == "faults":
            (want,) = value  # the lessons' answers edit the one fault they set up
            have = session.scenario.faults[0]
            if want["sat"] != have.sat:
                edits.append((session.fault_sat, want["sat"], "Faults"))
            for field, v in want.items():
                if field != "sat" and getattr(have, field) != v:
                    edits.append((session.fault_controls[field].handle, v, "Faults"))
        elif name == "algorithm":
            edits.append((session.algorithm, value, "Scenario"))
        elif name in session.controls:
            edits.append((session.controls[name].handle, value, "Scenario"))
        else:
            edits.append((session.option_controls[name].handle, value, "Algorithm options"))
    return edits


def _answer(page, session) -> str:
    """Press "Check my answer"; the answer as the page shows it."""
    tab = session.lessons_tab
    old = tab.answer_md.content
    page.get_by_role("button", name="Check my answer").click()
    t_end = time.monotonic() + 120
    while tab.answer_md.content == old and time.monotonic() < t_end:
        time.sleep(0.05)
    shown = tab.answer_md.content.split(" ", 1)[0]  # the mark
    page.get_by_text(shown).first.wait_for(timeout=30_000)
    return tab.answer_md.content


def test_every_lesson_walks_to_its_check_in_the_browser(dash, browser):
    """Each built-in lesson, as a student meets it: pick it in the Lessons tab, Set up,
    Check (not answered yet), make the answer's edits with the controls, Check again."""
    from app.lessons import load_lessons

    lessons = [x for x in load_lessons() if x.available]
    assert len(lessons) >= 10
    page, session = _open(dash, browser, 1600, 1000)
    try:
        page.get_by_role("tab", name="Lessons").click()
        tab = session.lessons_tab
        for lesson, label in zip(lessons, [x for x in tab.labels
                                           if tab._by_label[x].available], strict=True):
            _enter(page, tab.pick, label, "Lessons")
            page.get_by_role("button", name="Set up").click()
            t_end = time.monotonic() + 120
            while (session.result is None or session.result.scenario.name
                   != lesson.scenario_name) and time.monotonic() < t_end:
                time.sleep(0.1)
            assert session.scheduler.wait_idle(120), lesson.id
            assert session.preset.value == lesson.scenario_name
            first = _answer(page, session)
            assert first.startswith("✘"), (lesson.id, first)

            (answer,) = lesson.test_pass[:1]
            for handle, value, folder in _student_edits(session, answer):
                _enter(page, handle, value, folder)
                page.wait_for_timeout(300)
            want = lesson.scenario(**answer)
            t_end = time.monotonic() + 180
            while session.scenario != want and time.monotonic() < t_end:
                time.sleep(0.1)
            assert session.scenario == want, (
                lesson.id, [(h.label, v, h.value) for h, v, _ in
                            _student_edits(session, answer)], session.scenario, want)
            assert session.scheduler.wait_idle(180), lesson.id
            final = _answer(page, session)
            assert final.startswith("✔"), (lesson.id, final)
        page.screenshot(path=str(SHOTS / "lesson.png"))
    finally:
        _close(dash, page, session)


def test_the_screenshot_script_makes_the_readme_pictures(dash, browser, tmp_path):
    """``tests/dashboard_shots.py`` (the README's pictures) runs and writes two pictures
    of the window's size."""
    import dashboard_shots
    import imageio.v3 as iio

    paths = dashboard_shots.make_shots(tmp_path, dash=dash, browser=browser)
    assert [p.name for p in paths] == ["dashboard.png", "lesson.png"]
    for p in paths:
        assert iio.imread(p).shape[:2] == dashboard_shots.SIZE[::-1]
