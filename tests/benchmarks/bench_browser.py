"""Dashboard latencies as a user sees them: Debian's headless Chromium drives the page.

Run from the repository root::

    python tests/benchmarks/bench_browser.py [--viewport 1600x1000] [--repeat 12]
                                             [--scenario default] [--loads 4]

The dashboard runs in its own process (``python -m app``), as a user starts it; Chromium
(``/usr/bin/chromium``, never a downloaded browser) loads the page and presses keys. By
default Chromium renders WebGL and composites with SwiftShader in its GPU process, as a
machine with a GPU does; ``--software-compositing`` uses the browser tests' flags
(``--disable-gpu``), where each frame of the 3D view costs the page's main thread a
readback of the canvas (~130 ms at 1600x1000) and dominates every latency. Times
are taken inside the page (``performance.now()``): a key's ``keydown`` event to the DOM
mutation of the plots, seen by a ``MutationObserver``. Printed (medians):

* first plot: navigation start -> the first Plotly trace drawn (first page load: cold
  server; the others: a new tab on a running server);
* key press -> plots redrawn: an arrow key on the "Noise sigma" slider (a new value each
  time: a real recompute) -> the detection panel's traces change, and -> the last plot
  mutation (every panel redrawn);
* time step -> redrawn: an arrow key on the "t (s)" slider -> the detection panel's time
  cursor moved, and -> the last plot mutation (the sky plot's markers included);
* Play: the rate at which the detection panel's cursor moves, against the rate the
  dashboard announces (it paces Play to what the page paints, at most PLAY_FPS);
* websocket bytes received per key press and per time step (compressed, as sent).

Not a test: nothing here asserts a time.
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = "/usr/bin/chromium"
COMMON_ARGS = ["--headless", "--no-sandbox", "--disable-background-networking",
               "--disable-component-update", "--disable-sync", "--no-first-run"]
# SwiftShader as the GPU (WebGL and compositing in the GPU process, as with a real GPU).
GPU_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--ignore-gpu-blocklist"]
# The browser tests' flags: no GPU process, software compositing; every WebGL frame of
# the 3D view is then read back on the page's main thread (glReadPixels, ~130 ms at
# 1600x1000), which delays everything else on the page.
SOFTWARE_ARGS = ["--disable-gpu"]
ARGS = COMMON_ARGS + GPU_ARGS

# Installed in the page before any of its scripts.
BENCH_JS = r"""
(() => {
  const B = window.__bench = {kd: null, firstPlot: null};
  addEventListener('keydown', () => { B.kd = performance.now(); }, true);
  const plots = () => [...document.querySelectorAll('.js-plotly-plot')];
  const drawn = () => plots().some(
    p => p.querySelector('.scatterlayer path, .scatterlayer .point'));
  new MutationObserver(() => {
    if (B.firstPlot === null && drawn()) B.firstPlot = performance.now();
  }).observe(document, {subtree: true, childList: true});
  B.plot = (title) => plots().find(p => {
    const t = p.layout && p.layout.title;
    return ((t && (t.text || t)) || '').toString().includes(title);
  });
  // Drawn traces of a plot (SVG path data).
  B.sig = (title) => {
    const p = B.plot(title);
    return p ? [...p.querySelectorAll('.scatterlayer path.js-line')]
        .map(e => e.getAttribute('d') || '').join('|') : '';
  };
  // The drawn time cursor of a plot: the shape named "now".
  B.cursor = (title) => {
    const p = B.plot(title);
    if (!p || !p._fullLayout) return '';
    const k = (p._fullLayout.shapes || []).findIndex(s => s.name === 'now');
    if (k < 0) return '';
    const e = p.querySelector(`.shapelayer path[data-index="${k}"]`);
    return e ? e.getAttribute('d') || '' : '';
  };
  // Resolve when what(title) differs from `before` ({changed, last}: the first change
  // and the last plot mutation before `quiet` ms without one), or null after timeout.
  B.waitChange = (what, title, before, quiet, timeout) => new Promise(resolve => {
    let changed = null, last = null, timer = null;
    const done = (v) => {
      obs.disconnect(); clearTimeout(timer); clearTimeout(guard); resolve(v); };
    const settle = () => {
      clearTimeout(timer); timer = setTimeout(() => done({changed, last}), quiet); };
    const obs = new MutationObserver(records => {
      if (!records.some(r => r.target.closest && r.target.closest('.js-plotly-plot'))) return;
      const now = performance.now();
      if (changed === null && B[what](title) !== before) changed = now;
      if (changed !== null) { last = now; settle(); }
    });
    obs.observe(document.body, {subtree: true, childList: true, attributes: true,
                                characterData: true});
    const guard = setTimeout(() => done(null), timeout);
  });
  // Count cursor moves for `ms` milliseconds: the times of each change.
  B.countMoves = (title, ms) => new Promise(resolve => {
    const times = []; let prev = B.cursor(title);
    const obs = new MutationObserver(() => {
      const c = B.cursor(title);
      if (c !== prev) { prev = c; times.push(performance.now()); }
    });
    obs.observe(document.body, {subtree: true, childList: true, attributes: true});
    setTimeout(() => { obs.disconnect(); resolve(times); }, ms);
  });
  // The slider thumb of the GUI row labelled `label`.
  B.thumb = (label) => [...document.querySelectorAll('[role=slider]')].find(s => {
    let e = s;
    for (let k = 0; k < 10 && e; k++, e = e.parentElement)
      if ((e.textContent || '').trim().startsWith(label)) return true;
    return false;
  });
})();
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_port(port: int, timeout_s: float = 60.0) -> None:
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", port)) == 0:
                return
        time.sleep(0.1)
    raise TimeoutError(f"dashboard did not listen on {port}")


def _med(xs) -> str:
    xs = [x for x in xs if x is not None]
    if not xs:
        return "   n/a"
    return f"{statistics.median(xs):7.0f} ms (min {min(xs):5.0f}, max {max(xs):5.0f}, n={len(xs)})"


class Bytes:
    """Websocket bytes received by the page (payloads as sent, compressed)."""

    def __init__(self) -> None:
        self.total = 0
        self.frames = 0

    def attach(self, page) -> None:
        page.on("websocket", lambda ws: ws.on("framereceived", self._on_frame))

    def _on_frame(self, payload) -> None:
        self.total += len(payload)
        self.frames += 1


def _press_and_time(page, thumb_label: str, what: str, title: str, key: str,
                    quiet_ms: int = 400, timeout_ms: int = 30_000):
    before = page.evaluate(f"() => __bench.{what}({title!r})")
    page.evaluate(f"() => __bench.thumb({thumb_label!r}).focus()")
    # Started before the key press, awaited after it (evaluate awaits a promise).
    page.evaluate("([w, t, b, q, to]) => { __bench.pending = __bench.waitChange(w, t, b, q, to); }",
                  [what, title, before, quiet_ms, timeout_ms])
    page.keyboard.press(key)
    res = page.evaluate("() => __bench.pending")
    kd = page.evaluate("() => __bench.kd")
    if not res or res.get("changed") is None:
        return None, None
    return res["changed"] - kd, res["last"] - kd


def _choose(page, label: str, option: str) -> None:
    """Pick ``option`` in the GUI dropdown labelled ``label``."""
    page.get_by_label(label, exact=True).click()
    page.get_by_role("option", name=option, exact=True).click()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--viewport", default="1600x1000")
    ap.add_argument("--repeat", type=int, default=12, help="key presses per measurement")
    ap.add_argument("--loads", type=int, default=4, help="page loads for the first-plot time")
    ap.add_argument("--scenario", default="default")
    ap.add_argument("--play-s", type=float, default=6.0, help="seconds of Play measured")
    ap.add_argument("--play-speed", default="20x", help="Play's speed while measured")
    ap.add_argument("--software-compositing", action="store_true",
                    help="the browser tests' flags (--disable-gpu) instead of SwiftShader "
                         "as the GPU")
    args = ap.parse_args(argv)
    chrome_args = COMMON_ARGS + (SOFTWARE_ARGS if args.software_compositing else GPU_ARGS)
    width, height = (int(v) for v in args.viewport.split("x"))

    from playwright.sync_api import sync_playwright

    sys.path.insert(0, str(ROOT))

    port = _free_port()
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env = dict(os.environ, PYTHONPATH=path)
    server = subprocess.Popen([sys.executable, "-m", "app", "--port", str(port),
                               "--scenario", args.scenario], cwd=ROOT, env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        _wait_port(port)
        url = f"http://127.0.0.1:{port}"
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=chrome_args)
            try:
                firsts = []
                for _ in range(args.loads):
                    page = browser.new_page(viewport={"width": width, "height": height})
                    page.add_init_script(BENCH_JS)
                    page.goto(url)
                    first = page.wait_for_function("() => window.__bench.firstPlot",
                                                   timeout=120_000).json_value()
                    firsts.append(first)
                    page.wait_for_timeout(1500)
                    page.close()

                page = browser.new_page(viewport={"width": width, "height": height})
                nbytes = Bytes()
                nbytes.attach(page)
                page.add_init_script(BENCH_JS)
                page.goto(url)
                page.wait_for_function("() => window.__bench.firstPlot && "
                                       "__bench.cursor('Detection')", timeout=120_000)
                page.wait_for_timeout(3000)  # the first push settled

                key_first, key_last, key_bytes = [], [], []
                for _ in range(args.repeat):
                    b0 = nbytes.total
                    a, b = _press_and_time(page, "Noise sigma", "sig", "Detection",
                                           "ArrowRight")
                    page.wait_for_timeout(600)
                    key_first.append(a)
                    key_last.append(b)
                    key_bytes.append(nbytes.total - b0)

                step_first, step_last, step_bytes = [], [], []
                for _ in range(args.repeat * 2):
                    b0 = nbytes.total
                    a, b = _press_and_time(page, "t (s)", "cursor", "Detection",
                                           "ArrowRight", quiet_ms=250)
                    page.wait_for_timeout(300)
                    step_first.append(a)
                    step_last.append(b)
                    step_bytes.append(nbytes.total - b0)

                # Play: the cursor's rate on screen, at a speed that moves more than
                # PLAY_FPS epochs a second (at 5x and 1 s epochs only 5 epochs a second
                # differ, whatever the frame rate).
                _choose(page, "Speed", args.play_speed)
                page.get_by_label("Play", exact=True).check()
                page.wait_for_timeout(1000)
                b0 = nbytes.total
                times = page.evaluate("([t, ms]) => __bench.countMoves(t, ms)",
                                      ["Detection", int(args.play_s * 1000)])
                play_bytes = nbytes.total - b0
                announced = page.get_by_text("Playing at").first.text_content(timeout=5000)
                page.get_by_label("Play", exact=True).uncheck()
                fps = ((len(times) - 1) / ((times[-1] - times[0]) / 1000.0)
                       if len(times) > 2 else 0.0)
            finally:
                browser.close()
    finally:
        server.terminate()
        server.wait(timeout=30)

    kb = [x / 1024 for x in key_bytes]
    sb = [x / 1024 for x in step_bytes]
    mode = "software compositing" if args.software_compositing else "SwiftShader GPU"
    print(f"browser benchmark: scenario {args.scenario!r}, viewport {width}x{height}, "
          f"Debian Chromium headless ({mode})")
    print(f"first plot after page load     cold {firsts[0]:7.0f} ms; "
          f"warm {_med(firsts[1:])}")
    print(f"key press -> detection redrawn {_med(key_first)}")
    print(f"key press -> all plots redrawn {_med(key_last)}")
    print(f"time step -> cursor moved      {_med(step_first)}")
    print(f"time step -> all plots redrawn {_med(step_last)}")
    print(f"Play at {args.play_speed}: cursor moves at {fps:4.1f} frames/s on screen; "
          f"the page says {announced.strip()!r}; "
          f"{play_bytes / 1024 / max(args.play_s, 1e-9):.0f} kB/s received")
    print(f"websocket per key press        {statistics.median(kb):8.1f} kB (median)")
    print(f"websocket per time step        {statistics.median(sb):8.1f} kB (median)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
