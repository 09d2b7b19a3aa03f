"""A window mean's cost per request, before and after the running sums, in one process on the same cycles (issue 28
item 2): the demo log looped at full speed until ``--cycles`` results are held, then for each window length the
median CPU time of

- before: every cycle of the window read again (window_figures.figures_from_cycles, what the route did until
  h-bounded) and the reply built;
- after: the running sums read (LatestState.window) and the reply built.

    .venv/bin/python -m bench.bench_window_request [--cycles 2000] [--repeat 5]

Ratios are what to quote on a shared box (both paths suffer the same load); absolute figures only with `uptime`.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from frictionwatch.drivers.source import open_source
from frictionwatch.drivers.timebase import Clocks
from frictionwatch.service import api_views as views
from frictionwatch.service.engine_service import EngineService
from frictionwatch.service.pipeline import resolve_model
from frictionwatch.service.window_figures import figures_from_cycles

from bench.bench_service_load import ROOT


def engine(history: int) -> EngineService:
    url = f"mcap:{ROOT / 'replay_logs' / 'demo.mcap'}?loop=1"
    src = open_source(url, Clocks())
    model = resolve_model(src.engine_toml, None, "demo", src.info)
    return EngineService("demo", model, src.info, {"log": src}, urls=[url], history_cycles=history)


def filled_engine(cycles: int) -> EngineService:
    """``engine(cycles)`` run until its window sums hold ``cycles`` cycles, then stopped (nothing changes after)."""
    svc = engine(cycles).start()
    try:
        while svc.state.sums.count < cycles:
            time.sleep(0.5)
    finally:
        svc.stop()
    return svc


def cpu_median(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.process_time()
        fn()
        times.append(time.process_time() - t)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--cycles", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    svc = filled_engine(args.cycles)
    rows = []
    for w in sorted({10, 100, 1000, args.cycles}):
        def before(w=w):
            last, ring = svc.state.snapshot(w)
            return views.losses_window("demo", last, figures_from_cycles(ring), svc.term_names)

        def after(w=w):
            last, figures = svc.state.window(w)
            return views.losses_window("demo", last, figures, svc.term_names)

        b, a = cpu_median(before, args.repeat), cpu_median(after, args.repeat)
        rows.append({"window_cycles": w, "before_ms": 1e3 * b, "after_ms": 1e3 * a, "ratio": b / a if a else None})
    print(json.dumps({"cycles_held": svc.state.sums.count, "loadavg": os.getloadavg(), "windows": rows}, indent=1))


if __name__ == "__main__":
    main()
