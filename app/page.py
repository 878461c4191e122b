"""What the dashboard does in the browser page itself: panel sizes from the window, and
time updates applied to the plots already drawn.

**Sizes.** viser's client draws a Plotly panel ``width`` wide and ``width * aspect`` tall
(``PlotlyComponent.tsx``: ``height: width * aspectRatio``, although its docstring says
width/height), so a plot of ``h`` pixels in a panel whose plots are ``w`` wide gets
``aspect = h / w`` (:func:`plot_aspect`). The side panels take their widths from the
window's (:func:`side_panel_widths`): the 3D view keeps at least half of it. viser does
not tell the server the window's size; the page tells it through its local storage
(:meth:`PageScript.probe_viewport`: a script stores ``innerWidth``/``innerHeight``, the
server reads the value back with viser's ``local_storage.get_item``).

**Time.** Moving the time slider must not re-send whole figures (hundreds of kB and a
full redraw of every plot per step). The session sends one small time update instead
(:meth:`PageScript.send_time`): the cursor's time and, for the figures with a dynamic
part (the sky plot's "now" markers, the particle cloud), their dynamic traces. A script
installed once in the page (:data:`HELPER_JS`) applies it:

- the ``"now"`` line of every plot is moved in the SVG (``Plotly.relayout`` of a shape
  would recalculate and redraw the whole figure: 15-60 ms a plot); the line also follows
  the time slider in the page as soon as it moves, before the server answers;
- ``Plotly.react`` swaps the dynamic traces, only in a figure whose static part is the
  one the update was made for (``layout.meta.rev``);
- viser may redraw a figure later from the JSON it holds (a resize, a figure re-sent by a
  recompute): the script wraps ``Plotly.react`` so that every redraw is followed by the
  latest time update, unless the figure was made at that time or later
  (``layout.meta.seq``);
- a plot already drawn but scrolled out of view is redrawn when it comes into view again
  (an ``IntersectionObserver``), so that a recompute first redraws what is on screen; a
  new size is drawn at once (the page's layout never changes while scrolling).

The update travels as the content of a hidden HTML element (:meth:`PageScript.attach`):
viser applies a batch of GUI messages at once, while a batch holding 3D-scene messages
(or a script) waits for the next frame of the 3D view, which a software-rendered WebGL
draws a few times a second. The helper itself reaches the page once, through viser's
``RunJavascriptMessage`` (the message viser ships plotly.js with).
"""

from __future__ import annotations

import functools
import html
import json
import logging
import threading
from pathlib import Path

log = logging.getLogger(__name__)

#: Width (px) of the plot panel lost to its padding, border and scroll bar: a plot in a
#: panel ``W`` wide is ``W - PLOT_PANEL_PAD_PX`` wide (measured in Chromium: 500 -> 459).
PLOT_PANEL_PAD_PX = 41
#: Control panel (left) and plot panel (right) widths (px): at least, at most.
CONTROLS_PX = (220, 340)
PLOTS_PX = (270, 520)
#: Share of the window width the side panels may take together.
SIDE_SHARE = 0.48
#: The window assumed until the page says (px).
DEFAULT_WINDOW = (1600, 1000)
VIEWPORT_KEY = "raim-studio-viewport"
#: The local-storage key where the page counts the time updates it has painted
#: (:meth:`PageScript.painted_count`).
DRAWN_KEY = "raim-studio-painted"
#: The prefix viser's client puts before the keys the server reads
#: (``LOCAL_STORAGE_PREFIX`` in its ``MessageHandler.tsx``).
LOCAL_STORAGE_PREFIX = "viser-user:"
#: How long the server waits for the page's answer (s).
PROBE_TIMEOUT_S = 20.0
#: The attribute of the hidden element that carries the time update.
CARRIER_ATTR = "data-raim-time"


def side_panel_widths(window_w: float) -> tuple[int, int]:
    """(controls, plots) panel widths (px) for a window ``window_w`` wide.

    The controls take 22 % of the window within :data:`CONTROLS_PX`; the plots what is
    left of :data:`SIDE_SHARE` within :data:`PLOTS_PX`; so the 3D view keeps at least
    half of any window from about 1000 px up (1000 -> 220 + 270, 1600 -> 340 + 428,
    1920 -> 340 + 520).
    """
    w = float(window_w)
    left = min(max(0.22 * w, CONTROLS_PX[0]), CONTROLS_PX[1])
    right = min(max(SIDE_SHARE * w - left, PLOTS_PX[0]), PLOTS_PX[1])
    return int(round(left)), int(round(right))


def plot_width(panel_px: float) -> float:
    """Width (px) of a plot in a plot panel ``panel_px`` wide."""
    return max(float(panel_px) - PLOT_PANEL_PAD_PX, 50.0)


def plot_aspect(height_px: float, panel_px: float) -> float:
    """viser's ``aspect`` that draws a plot ``height_px`` tall in a panel ``panel_px``
    wide (viser: ``height = width * aspect``)."""
    return float(height_px) / plot_width(panel_px)


def carrier_html(state: dict | None) -> str:
    """The hidden element that carries a time update to the page."""
    payload = "" if state is None else json.dumps(state, separators=(",", ":"),
                                                  allow_nan=False)
    return f'<div hidden {CARRIER_ATTR}="{html.escape(payload, quote=True)}"></div>'


def carried_state(content: str) -> dict | None:
    """The time update a carrier's HTML holds (tests read what the page receives)."""
    start = content.find(f'{CARRIER_ATTR}="')
    if start < 0:
        return None
    start += len(CARRIER_ATTR) + 2
    payload = html.unescape(content[start:content.index('"', start)])
    return json.loads(payload) if payload else None


# Installed once per page. ``R.state`` is the latest time update; ``R.apply(gd)`` brings
# one plot to it; every Plotly.react made by viser is followed by ``R.apply``.
HELPER_JS = r"""
((timeLabel, attr, drawnKey) => {
  const R = window.__raimStudio = window.__raimStudio || {state: null};
  R.timeLabel = timeLabel;
  if (R.installed || R.hooked) return;
  // Sent before the first figure: installed the moment plotly.js defines window.Plotly,
  // before any figure is drawn.
  if (!window.Plotly) {
    R.hooked = true;
    Object.defineProperty(window, 'Plotly', {configurable: true, enumerable: true,
      get() { return undefined; },
      set(v) {
        Object.defineProperty(window, 'Plotly', {value: v, writable: true,
                                                 configurable: true, enumerable: true});
        install(v);
      }});
    return;
  }
  install(window.Plotly);
  function install(P) {
    if (R.installed) return;
    R.installed = true;
    R.react = P.react.bind(P);
    R.relayout = P.relayout.bind(P);
    R.applied = new WeakMap();  // dynamic trace object -> the update it shows
    const meta = (gd) => gd && gd.layout && gd.layout.meta && gd.layout.meta.raim !== undefined
      ? gd.layout.meta : null;
    // Move shape k (a vertical line) to x = t. Plotly.relayout would recalculate and
    // redraw the whole figure (a shape may set the axis range): 15-60 ms a plot. Instead
    // the line's SVG path is moved and the layout objects are updated in place, so that
    // plotly's next full redraw draws it there too.
    R.moveLine = (gd, k, t) => {
      const shape = gd.layout.shapes[k];
      shape.x0 = t; shape.x1 = t;
      const fl = gd._fullLayout, xa = fl && fl.xaxis;
      const full = fl && fl.shapes && fl.shapes[k];
      if (full) { full.x0 = t; full.x1 = t; }
      const path = gd.querySelector(`.shapelayer path[data-index="${k}"]`);
      const d = path && path.getAttribute('d');
      const m = d && /^M([^,]+),([^L]+)L([^,]+),(.+)$/.exec(d);
      if (!xa || !xa.c2p || !m) return false;
      const x = xa._offset + xa.c2p(t);
      if (!isFinite(x)) return false;
      path.setAttribute('d', `M${x},${m[2]}L${x},${m[4]}`);
      return true;
    };
    R.cursor = (gd, t) => {
      const shapes = (gd.layout && gd.layout.shapes) || [];
      const k = shapes.findIndex(sh => sh && sh.name === 'now');
      if (k >= 0 && t !== null && shapes[k].x0 !== t && !R.moveLine(gd, k, t)) {
        R.relayout(gd, {[`shapes[${k}].x0`]: t, [`shapes[${k}].x1`]: t});
      }
    };
    R.apply = (gd) => {
      const s = R.state, m = meta(gd);
      if (!s || !m || !gd.data) return;
      const d = s.dyn[m.raim];
      if (d && d.rev === m.rev) {
        const first = gd.data[m.n];
        const seen = (first && R.applied.get(first)) ?? m.seq ?? -1;
        if (seen < s.seq) {
          const data = gd.data.slice(0, m.n).concat(d.traces.map(t => ({...t})));
          if (data.length > m.n) R.applied.set(data[m.n], s.seq);
          R.react(gd, data, {...gd.layout, ...d.layout});
        }
      }
      R.cursor(gd, s.t);
    };
    R.each = (f) => document.querySelectorAll('.js-plotly-plot').forEach(gd => {
      try { f(gd); } catch (e) { console.warn('raim time update', e); }
    });
    // Several updates before the page could draw (Play while the page is busy): only the
    // last one is drawn.
    R.set = (state) => {
      if (R.state && state.seq < R.state.seq) return;
      R.state = state;
      if (R.pending) return;
      R.pending = true;
      queueMicrotask(() => {
        R.pending = false;
        R.each(R.apply);
        // Count the updates painted (Play reads the count to match the page's pace).
        requestAnimationFrame(() => setTimeout(() => {
          R.painted = (R.painted || 0) + 1;
          try { localStorage.setItem(drawnKey, String(R.painted)); } catch (e) {}
        }, 0));
      });
    };
    // The cursor follows the time slider in the page, before the server answers: t
    // snapped to the run's epochs as the server does (the first epoch at or after t).
    R.snap = (t) => {
      const g = R.state && R.state.grid;
      if (!g) return t;
      const i = Math.min(Math.max(Math.ceil((t - 1e-9 - g.t0) / g.dt), 0), g.n - 1);
      return g.t0 + i * g.dt;
    };
    R.follow = (value) => {
      const t = R.snap(parseFloat(value));
      if (!R.state || !isFinite(t) || t === R.state.t) return;
      R.state = {...R.state, t: t};
      R.each(gd => R.cursor(gd, t));
    };
    R.isTimeThumb = (el) => {
      for (let e = el, k = 0; e && k < 10; e = e.parentElement, k++) {
        const text = (e.textContent || '').trim();
        if (text.startsWith(R.timeLabel)) return true;
        if (text.length > 200) return false;
      }
      return false;
    };
    R.read = (el) => {
      const raw = el.getAttribute(attr);
      if (raw) R.set(JSON.parse(raw));
    };
    new MutationObserver(records => {
      for (const r of records) {
        const el = r.target;
        if (r.type === 'attributes') {
          if (el.getAttribute('role') === 'slider' && R.timeLabel &&
              (el === R.timeThumb || (R.isTimeThumb(el) && (R.timeThumb = el)))) {
            R.follow(el.getAttribute('aria-valuenow'));
          }
        } else {
          for (const n of r.addedNodes) {
            if (n.nodeType !== 1) continue;
            // The carrier itself (a new update), or a GUI element holding it (mounted).
            const c = n.hasAttribute(attr) ? n
              : (n.firstElementChild && !n.closest('.js-plotly-plot')
                 ? n.querySelector(`[${attr}]`) : null);
            if (c) R.read(c);
          }
        }
      }
    }).observe(document.body, {subtree: true, childList: true, attributes: true,
                               attributeFilter: ['aria-valuenow']});
    const carrier = document.querySelector(`[${attr}]`);
    if (carrier) R.read(carrier);
    // A plot scrolled out of view is redrawn when it comes back into view, not while the
    // visible ones are being drawn (a recompute re-sends every figure at once).
    R.visible = new WeakMap();
    R.deferred = new WeakMap();
    R.redraw = (gd, args) => {
      const out = R.react(gd, ...args);
      const after = () => { try { R.apply(gd); } catch (e) { console.warn(e); } return gd; };
      return out && out.then ? out.then(after) : after();
    };
    R.seen = new IntersectionObserver(entries => {
      for (const e of entries) {
        R.visible.set(e.target, e.isIntersecting);
        const args = e.isIntersecting && R.deferred.get(e.target);
        if (args) { R.deferred.delete(e.target); R.redraw(e.target, args); }
      }
    });
    R.draw = (gd, rest) => {
      if (gd) R.deferred.delete(gd);
      if (gd && !R.visible.has(gd)) { R.visible.set(gd, true); R.seen.observe(gd); }
      return R.redraw(gd, rest);
    };
    // A plot's first drawing: one per task, the first at once, so that the page paints
    // the top plot before it draws the others (a page's first figures arrive together).
    R.firstJobs = new Map();  // plot -> [arguments, resolvers]
    R.first = (gd, rest) => new Promise(resolve => {
      const job = R.firstJobs.get(gd);
      if (job) { job[0] = rest; job[1].push(resolve); return; }  // only its latest size
      R.firstJobs.set(gd, [rest, [resolve]]);
      if (!R.firstBusy) R.pump();
    });
    R.pump = () => {
      const next = R.firstJobs.entries().next();
      if (next.done) { R.firstBusy = false; return; }
      R.firstBusy = true;
      const [gd, [rest, resolvers]] = next.value;
      R.firstJobs.delete(gd);
      let out = gd;
      if (gd.isConnected) {
        try { out = R.draw(gd, rest); } catch (e) { console.warn('raim first draw', e); }
      }
      Promise.resolve(out).then(v => resolvers.forEach(r => r(v)),
                                () => resolvers.forEach(r => r(gd)));
      requestAnimationFrame(() => setTimeout(R.pump, 0));
    };
    // viser redraws a plot from its JSON (a new figure, a resize): then the latest time.
    P.react = function (gd, ...rest) {
      const fl = gd && gd._fullLayout, lay = rest[1] || {};
      // viser's first call comes before the plot's box is measured (width 0): the call
      // with the measured width follows at once, and only that one is drawn.
      if (gd && !lay.width && !fl) return Promise.resolve(gd);
      if (fl && R.visible.get(gd) === false && lay.width === fl.width &&
          lay.height === fl.height) {
        // Drawn before, out of view now, same size (the page keeps its layout): drawn
        // when it is seen again.
        R.deferred.set(gd, rest);
        return Promise.resolve(gd);
      }
      if (gd && !fl) return R.first(gd, rest);
      return R.draw(gd, rest);
    };
  }
})(%s, %s, %s);
"""

VIEWPORT_JS = (
    "try { localStorage.setItem(%s, JSON.stringify([window.innerWidth, "
    "window.innerHeight])); } catch (e) {}"
)


#: The dashboard's plotly.js: plotly.js with only the trace types of the panels
#: (app/assets/plotly/README.md). The page evaluates it in ~0.1 s, the full bundle viser
#: sends in ~0.8 s, before it can draw the first plot.
PLOTLY_JS_PATH = Path(__file__).parent / "assets" / "plotly-raim.min.js"
#: The trace types in that bundle (app/assets/plotly/entry.js).
PLOTLY_TRACE_TYPES = frozenset({"scatter", "bar", "heatmap", "contour", "scatterpolar"})


@functools.cache
def plotly_js() -> str | None:
    """The text of :data:`PLOTLY_JS_PATH` (None if the file is missing)."""
    try:
        return PLOTLY_JS_PATH.read_text(encoding="utf-8")
    except OSError as exc:
        log.warning("dashboard plotly.js not read (%s): viser sends its full bundle", exc)
        return None


class PageScript:
    """The dashboard's script in one page: the time updates and the window's size.

    Parameters
    ----------
    client : viser ``ClientHandle`` (a ``ViserServer`` works too, for every page at once,
        but cannot say the window's size: :attr:`live` is False).
    """

    def __init__(self, client) -> None:
        self.client = client
        self.live = _is_client(client)
        self._installed = False
        self._lock = threading.Lock()
        self.carrier = None
        self.last_state: dict | None = None

    def attach(self, gui, time_label: str | None = None) -> None:
        """Create the hidden element that carries the time updates, in ``gui``'s
        current container; with ``time_label``, also send :data:`HELPER_JS` now, ahead of
        plotly.js (it installs itself when plotly.js has run, before the first figure)."""
        self.carrier = gui.add_html(carrier_html(None))
        if time_label is not None:
            self.install_helper(time_label)
        self.send_plotly(gui)

    def send_plotly(self, gui) -> bool:
        """Send the dashboard's plotly.js (:data:`PLOTLY_JS_PATH`) now, ahead of the first
        figure, in place of the full bundle viser sends with the first ``add_plotly``.

        Returns False, and viser sends its own bundle as usual, when ``gui`` does not
        keep viser 1.x's "sent" flag (``_setup_plotly_js``), it is already set, or the
        file is missing."""
        if getattr(gui, "_setup_plotly_js", None) is not False:
            return False
        source = plotly_js()
        if source is None:
            return False
        self.run(source)
        gui._setup_plotly_js = True
        return True

    def run(self, source: str) -> None:
        """Run ``source`` in the page (in order with the other messages)."""
        from viser import _messages

        self.client.gui._websock_interface.queue_message(
            _messages.RunJavascriptMessage(source=source))

    def install_helper(self, time_label: str) -> None:
        """Send :data:`HELPER_JS` to the page once (it installs itself when Plotly is
        there); ``time_label`` names the time slider the plots' cursor follows."""
        with self._lock:
            if not self._installed:
                self.run(HELPER_JS % (json.dumps(time_label), json.dumps(CARRIER_ATTR),
                                      json.dumps(LOCAL_STORAGE_PREFIX + DRAWN_KEY)))
                self._installed = True

    def send_time(self, state: dict) -> None:
        """Bring the page's plots to ``state`` (``seq``, ``t``, ``grid``, ``dyn``: see
        the module doc); kept in :attr:`last_state`."""
        self.last_state = state
        if self.carrier is not None:
            self.carrier.content = carrier_html(state)

    def painted_count(self, timeout_s: float = 2.0) -> int | None:
        """How many time updates the page has painted (several arriving before a paint
        count once); None: no page, no answer, or none painted yet. One round trip."""
        if not self.live:
            return None
        try:
            raw = self.client.local_storage.get_item(DRAWN_KEY, timeout=timeout_s)
        except (RuntimeError, TimeoutError):
            return None
        try:
            return int(raw) if raw else None
        except (TypeError, ValueError):
            return None

    def probe_viewport(self, timeout_s: float = PROBE_TIMEOUT_S) -> tuple[int, int] | None:
        """The page's window size (px), or None (no page, no answer, closed).

        Blocks up to ``timeout_s``: call it off the event loop and off the session's
        worker (the session runs it on a short-lived thread)."""
        if not self.live:
            return None
        self.run(VIEWPORT_JS % json.dumps(LOCAL_STORAGE_PREFIX + VIEWPORT_KEY))
        try:
            raw = self.client.local_storage.get_item(VIEWPORT_KEY, timeout=timeout_s)
        except (RuntimeError, TimeoutError) as exc:
            log.debug("viewport not reported: %s", exc)
            return None
        try:
            w, h = json.loads(raw) if raw else (None, None)
            return (int(w), int(h)) if w and h else None
        except (TypeError, ValueError):
            return None


def _is_client(client) -> bool:
    try:
        import viser
    except ImportError:  # pragma: no cover - the dashboard needs viser
        return False
    return isinstance(client, viser.ClientHandle)
