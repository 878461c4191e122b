"""Make the README's dashboard screenshots: the default view and a lesson, in Debian's
headless Chromium at 1600x1000.

Run from the repository root (it needs the test extra: playwright and ``/usr/bin/chromium``)::

    python tests/dashboard_shots.py [--out assets] [--lesson 03-detection-isolation]

The dashboard runs in this process on a free port. The default view is taken once its
plots are drawn; the lesson is picked in the Lessons tab, set up, answered with the
controls as a student would (the lesson's own answer from its ``[test]`` table) and
checked, then taken.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIZE = (1600, 1000)


def make_shots(out_dir, lesson_id: str = "03-detection-isolation", *, dash=None,
               browser=None) -> list[Path]:
    """Write ``dashboard.png`` and ``lesson.png`` into ``out_dir``; their paths.

    ``dash`` and ``browser`` (a running :class:`app.server.Dashboard` and a Playwright
    Chromium) are started here and stopped after, unless given."""
    sys.path.insert(0, str(ROOT))
    sys.path.insert(0, str(ROOT / "tests"))
    import test_dashboard_browser as tb
    from playwright.sync_api import sync_playwright

    from app.lessons import load_lessons
    from app.server import Dashboard

    lesson = {x.id: x for x in load_lessons()}.get(lesson_id)
    if lesson is None:
        raise SystemExit(f"--lesson: no built-in lesson {lesson_id!r}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "dashboard.png", out / "lesson.png"]
    if dash is None:
        dash = Dashboard(port=0, verbose=False)
        try:
            return make_shots(out_dir, lesson_id, dash=dash, browser=browser)
        finally:
            dash.stop()
    if browser is None:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=tb.CHROMIUM, args=tb.ARGS)
            try:
                return make_shots(out_dir, lesson_id, dash=dash, browser=browser)
            finally:
                browser.close()
    page, session = tb._open(dash, browser, *SIZE)
    try:
        page.wait_for_timeout(2500)  # the plots and the 3D view settled
        _close_notices(page)
        page.screenshot(path=str(paths[0]))
        page.get_by_role("tab", name="Lessons").click()
        tab = session.lessons_tab
        label = next(x for x in tab.labels if tab._by_label[x].id == lesson_id)
        tb._enter(page, tab.pick, label, "Lessons")
        page.get_by_role("button", name="Set up").click()
        t_end = time.monotonic() + 120
        while (session.result is None or session.result.scenario.name
               != lesson.scenario_name) and time.monotonic() < t_end:
            time.sleep(0.1)
        session.scheduler.wait_idle(120)
        for handle, value, folder in tb._student_edits(session, lesson.test_pass[0]):
            tb._enter(page, handle, value, folder)
            page.wait_for_timeout(300)
        want = lesson.scenario(**lesson.test_pass[0])
        while session.scenario != want and time.monotonic() < t_end:
            time.sleep(0.1)
        session.scheduler.wait_idle(120)
        tb._answer(page, session)
        page.wait_for_timeout(2500)
        _close_notices(page)
        page.screenshot(path=str(paths[1]))
    finally:
        tb._close(dash, page, session)
    return paths


def _close_notices(page) -> None:
    """Close viser's notices (headless Chromium draws WebGL in software, and viser says
    so in a toast over the 3D view): a screenshot shows the dashboard, not the test rig."""
    for button in page.locator(".mantine-Notification-closeButton").all():
        button.click()
    page.wait_for_timeout(500)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "assets"), help="folder for the PNG files")
    ap.add_argument("--lesson", default="03-detection-isolation", help="built-in lesson id")
    args = ap.parse_args(argv)
    for path in make_shots(args.out, args.lesson):
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} kB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
