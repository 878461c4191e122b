"""Dashboard update latency, server side, for the 600-epoch snapshot scenario ("default").

Run from the repository root::

    python tests/benchmarks/bench_dashboard.py [--repeat 15] [--scenario NAME] [--vary seed]

(``--scenario seed002 --vary seed`` measures PF-LLR: its threshold calibration depends on
sigma, so moving the seed shows the recompute with the calibration cached.)

A websocket client is connected (so every message is really serialised and sent) and one
session is driven in-process. Measured per control change (noise sigma moved):

* incremental (what the dashboard does): engine run + figures built as plain dicts with
  typed-array JSON + only the changed scene nodes updated, until the messages are flushed;
* naive full rebuild (baseline, same process): engine run + every figure rebuilt through
  ``plotly.graph_objects`` validation and ``to_json`` + every plot element and the whole
  3D scene (Earth included) removed and re-created.

Also the time-slider step (scene + time markers, no recompute). Prints medians in ms.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def _connect(url: str):
    import msgspec
    import viser
    from websockets.sync.client import connect

    ws = connect(url.replace("http", "ws"), subprotocols=[f"viser-v{viser.__version__}"],
                 max_size=None)

    def drain():
        try:
            while True:
                ws.recv()
        except Exception:  # noqa: BLE001 - closed at the end
            return

    threading.Thread(target=drain, daemon=True).start()
    ws.send(msgspec.msgpack.encode({
        "type": "ViewerCameraMessage", "wxyz": [1.0, 0.0, 0.0, 0.0],
        "position": [0.0, 0.0, 60.0], "fov": 1.0, "near": 0.05, "far": 2000.0,
        "image_height": 800, "image_width": 1200, "look_at": [0.0, 0.0, 0.0],
        "up_direction": [0.0, 0.0, 1.0]}))
    return ws


def _ms(xs) -> str:
    return f"{1e3 * statistics.median(xs):7.1f} ms (min {1e3 * min(xs):6.1f})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--scenario", default="default", help="scenario name (default: default)")
    ap.add_argument("--algorithm", default=None, help="algorithm (default: the scenario's)")
    ap.add_argument("--vary", choices=("sigma", "seed"), default="sigma",
                    help="the control moved between recomputes")
    ap.add_argument("--budget-ms", type=float, default=50.0,
                    help="server-side budget per control change (50 ms: issue 3's, for the "
                         "600-epoch snapshot scenario; 300 ms for seed002)")
    args = ap.parse_args(argv)

    from app import panels
    from app.scene import SkyScene
    from app.server import Dashboard
    from app.session import run_view, scene_run
    from raimcore.pipeline import run_scenario
    from raimcore.scenario import load_scenario

    start = load_scenario(args.scenario)
    if args.algorithm:
        start = start.replace(algorithm=args.algorithm)
    dash = Dashboard(port=0, scenario=start, verbose=False)
    ws = _connect(dash.url)
    (s,) = dash.wait_for_sessions(1)
    s.scheduler.wait_idle(60)
    client = s.client
    n_ep = len(s.result.measurements.t_s)
    print(f"scenario {s.scenario.name!r}: {n_ep} epochs, {len(s.result.measurements.sat_names)} "
          f"satellites, algorithm {s.scenario.algorithm}, panels {list(s.figures)}")

    # Incremental path: the real session, one control change at a time.
    total, run, figs, push = [], [], [], []
    def move(k: int) -> None:  # a new value each time: no result-cache hit
        if args.vary == "sigma":
            s.sigma.value = 3.5 + 0.5 * k
        else:
            s.seed.value = 100 + k

    for k in range(args.repeat):
        move(k)
        s.scheduler.wait_idle(60)
        t0 = time.perf_counter()
        client.flush()
        flush_s = time.perf_counter() - t0
        tm = s.timing
        total.append(tm.total_s + flush_s)
        run.append(tm.run_s)
        figs.append(tm.figures_s)
        push.append(tm.push_s + flush_s)

    # Going back to a recent setting reuses the session's cached run.
    hits = []
    for k in range(args.repeat):
        move(args.repeat - 1 - (k % 4))
        s.scheduler.wait_idle(60)
        t0 = time.perf_counter()
        client.flush()
        hits.append(s.timing.total_s + time.perf_counter() - t0)

    # Time-slider step.
    steps = []
    for k in range(args.repeat * 3):
        t0 = time.perf_counter()
        s.time.value = float(10 * (k + 1) % n_ep)
        s.scheduler.wait_idle(60)
        client.flush()
        steps.append(time.perf_counter() - t0)

    # Naive full rebuild baseline (same process, same client).
    base_total, base_dash = [], []
    scenario = s.current_scenario()
    plot_handles = []
    scene = None
    for k in range(max(3, args.repeat // 3)):
        t0 = time.perf_counter()
        res = run_scenario(scenario.replace(sigma_m=4.0 + 0.5 * k))
        t1 = time.perf_counter()
        view = run_view(res)
        go_figs = [build(view).to_plotly(0) for _, build in panels.panels_for(view)]
        for h in plot_handles:
            h.remove()
        plot_handles = [client.gui.add_plotly(f, aspect=1.5) for f in go_figs]
        if scene is not None:
            for name in ("/earth", "/sats", "/rx", "/orbits", "/trajectory", "/los", "/lights"):
                client.scene.remove_by_name(name)
        scene = SkyScene(client.scene)
        scene.set_run(scene_run(res, view))
        client.flush()
        t2 = time.perf_counter()
        base_total.append(t2 - t0)
        base_dash.append(t2 - t1)
    for h in plot_handles:
        h.remove()

    inc_dash = [a - b for a, b in zip(total, run, strict=True)]
    print("\nper control change (median of", args.repeat, "):")
    print(f"  incremental total        {_ms(total)}")
    print(f"    engine run_scenario    {_ms(run)}")
    print(f"    figures (dict+JSON)    {_ms(figs)}")
    print(f"    push (scene+plots)     {_ms(push)}")
    print(f"    dashboard own work     {_ms(inc_dash)}")
    print(f"  naive full rebuild total {_ms(base_total)}")
    print(f"    dashboard own work     {_ms(base_dash)}")
    print(f"  speed-up of the dashboard's own work: "
          f"{statistics.median(base_dash) / statistics.median(inc_dash):.1f}x; "
          f"total: {statistics.median(base_total) / statistics.median(total):.1f}x")
    print(f"back to a recent setting (cached run): {_ms(hits)}")
    print(f"time-slider step (scene + markers): {_ms(steps)}")
    budget = args.budget_ms / 1000.0
    verdict = "within" if statistics.median(total) <= budget else "OVER"
    print(f"budget {args.budget_ms:g} ms per control change: {verdict} "
          f"(engine alone {1e3 * statistics.median(run):.0f} ms)")
    ws.close()
    dash.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
