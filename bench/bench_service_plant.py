"""A plant on one `frictionwatch serve` (issue 28 checks): several genset-v20 at real time (the demo log looped,
speed=1, one engine per --source), then one of two loads:

- ``mix``: ``--rate`` requests/s for ``--seconds`` s of a dashboard mix that includes window means (100, 1000 and 5000
  cycles) and the large speed history; reports cycles analysed against the real-time need (each engine's speed / 120
  times the wall seconds) and what the server missed (dropped, skipped, left queued: ``accounting``; a looped
  replay delivers a little less than the need, its seams restart the pacing), the client's p50 / p99, the server's
  histogram's, and the replies by status. ``--probe FILE``: serve under bench/serve_probe.py, and a timeline of
  where the slow requests' time went (``timeline``).
- ``idle``: no requests; the server's CPU over ``--seconds`` s (from /proc: all its threads) per wall second, per
  engine and per cycle analysed, its threads' context switches per cycle, and the cycles it analysed against those
  offered; from the CPU per cycle, how many genset-v20 one core would hold at real time at this cost
  (``gensets_per_core``: one core over the CPU seconds a genset's cycles take a second, at the engines' speed;
  issue 28 item 7's target ``TARGET_PER_CORE``).
  Per cycle, not per wall second: a looped replay's passes each start their clock again, so two checkouts
  offer a few per cent different cycles in the same wall time. Run it with ``--cpu 1`` (one core's figure).
- ``lag``: no requests; polls /health every 0.5 s and reports when each engine first shows ``behind`` (and the
  status 'degraded'), the largest queue seen, what was dropped, and the server's RSS each second (memory bounded:
  it must stop growing once the queues are full).

    .venv/bin/python -m bench.bench_service_plant mix --engines 4 --rate 200 --seconds 60
    .venv/bin/python -m bench.bench_service_plant lag --engines 12 --seconds 60 --cpu 1   # the server on one core
    .venv/bin/python -m bench.bench_service_plant idle --engines 4 --seconds 60 --cpu 1
    .venv/bin/python -m bench.bench_service_plant same --against ../base --seconds 40 --cpu 1

- ``same``: whether two checkouts' serve store the same numbers (a cut of serve's cost must change none): each
  checkout serves the four replay logs (looped, as fast as they can be read: nothing dropped) to a --data-dir of
  its own for ``--seconds`` s after every engine's first result, then SIGTERM; every cycle, estimate, alert and baseline both stored (the cycles
  the slower one reached) compared, numbers within rtol 1e-12, NaN as NaN, text equal; write times left out.

Minutes of wall time; not part of `make bench` nor the tests. On a shared box quote `uptime` beside the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import numpy as np
from prometheus_client.parser import text_string_to_metric_families

from bench.bench_service_load import cpu_s, hist_quantile, load

ROOT = Path(__file__).resolve().parents[1]
CYCLE_REVS = 2.0  # four-stroke: a cycle is two revolutions
TARGET_PER_CORE = 25  # genset-v20 per core at real time, one process (issue 28 item 7)


def mix_routes(engines: list[str]) -> list[str]:
    per = []
    for e in engines:
        base = f"/api/v1/engines/{e}"
        per += [f"{base}/losses", f"{base}/losses?window_cycles=100", f"{base}/losses?window_cycles=1000",
                f"{base}/losses?window_cycles=5000", f"{base}/cycles/latest", f"{base}/cycles/latest",
                f"{base}/speed", f"{base}/friction-torque", f"{base}/speed?cycles=5000"]
    return per + ["/api/v1/health", "/api/v1/engines", "/metrics"]


def counters(client: httpx.Client) -> dict:
    fams = {f.name: f for f in text_string_to_metric_families(client.get("/metrics").text)}
    out = {"processed": 0.0, "dropped_records": 0.0, "skipped": 0.0, "requests_hist": {}}
    for s in fams["frictionwatch_http_request_seconds"].samples:  # all routes together, cumulative by bound
        if s.name.endswith("_bucket"):
            le = float(s.labels["le"])
            out["requests_hist"][le] = out["requests_hist"].get(le, 0.0) + s.value
    for name, key in (("frictionwatch_cycles_processed", "processed"), ("frictionwatch_cycles_skipped", "skipped"),
                      ("frictionwatch_ingest_dropped_records", "dropped_records")):
        out[key] = sum(s.value for s in fams[name].samples if s.name.endswith("_total"))
    return out


def replay_state(client: httpx.Client) -> dict:
    """Summed over the engines: the cycles queued for analysis (/health's backlog, at the newest result's speed),
    the seconds the newest analysed data is behind, and the looped replays' seams so far (/api/v1/engines)."""
    health = client.get("/api/v1/health").json()["engines"]
    engines = client.get("/api/v1/engines").json()
    return {"queued_cycles": sum(r["queued_cycles"] or 0.0 for r in health),
            "behind_s_max": max((r["behind_s"] or 0.0) for r in health),
            "dropped_cycles": sum(r["dropped_cycles"] or 0.0 for r in health),
            "loop_seams": sum(int(e["restarts"].get("loop_restart", 0)) for e in engines)}


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def start_server(n: int, cpu: int | None, history: int, probe: str | None = None,
                 switch_s: float | None = None, api_other: bool = False) -> tuple[subprocess.Popen, str]:
    head = ["bench.serve_probe", probe] if probe else ["frictionwatch.service.cli"]  # bench/serve_probe.py's timeline
    if probe and switch_s is not None:
        head += ["--switch-interval", str(switch_s)]
    if probe and api_other:
        head += ["--api-default-policy"]
    cmd = [sys.executable, "-m", *head, "serve", "--port", "0", "--history-cycles", str(history)]
    for i in range(n):
        cmd += ["--source", f"mcap:replay_logs/demo.mcap?loop=1&speed=1#g{i + 1}"]
    if cpu is not None:
        cmd = ["taskset", "-c", str(cpu), *cmd]
    return launched(cmd, ROOT, timeout_s=600)


def launched(cmd: list[str], cwd: Path, timeout_s: float) -> tuple[subprocess.Popen, str]:
    """Start ``serve`` and wait for the line with its dashboard URL: (process, URL)."""
    proc = subprocess.Popen(cmd, cwd=cwd, text=True, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True).start()
    proc.lines = lines  # type: ignore[attr-defined]  # what serve prints later (its stop lines)
    while True:
        m = re.search(r"dashboard at (\S+)", lines.get(timeout=timeout_s))
        if m:
            return proc, m[1]


def wait_first_results(client: httpx.Client, engines: list[str]) -> float:
    t0 = time.monotonic()
    while not all(client.get(f"/api/v1/engines/{e}/cycles/latest").status_code == 200 for e in engines):
        time.sleep(0.5)
    return time.monotonic() - t0


def run_mix(args, client: httpx.Client, url: str, pid: int, engines: list[str]) -> dict:
    time.sleep(args.settle)
    c0, cpu0, w0, r0 = counters(client), cpu_s(pid), time.monotonic(), replay_state(client)
    sent = mix_routes(engines)
    lat = load(url, args.rate, args.seconds, sent, tag=bool(args.probe))
    time.sleep(2.0)  # the cycles whose data came during the load
    c1, cpu1, w1, r1 = counters(client), cpu_s(pid), time.monotonic(), replay_state(client)
    ms = lat["latency_s"] * 1e3
    rpm = [client.get(f"/api/v1/engines/{e}/cycles/latest").json()["rpm_mean"] for e in engines]
    offered = sum(r / 60.0 / CYCLE_REVS for r in rpm) * (w1 - w0)
    codes, counts = np.unique(lat["status"], return_counts=True)
    # which routes make the tail: each route (the engine's id taken out) with its share of the requests beyond the
    # overall p99, and its own p50 / p99 (the client's clock: its sends and its parsing are in it)
    routes = np.array([re.sub(r"/engines/[^/]+", "/engines/{id}", sent[i % len(sent)])
                       for i in range(lat["n"])])
    slow = ms > np.nanpercentile(ms, 99)
    by_route = {r: {"p50": float(np.nanpercentile(ms[routes == r], 50)), "p99": float(np.nanpercentile(ms[routes == r], 99)),
                    "share_of_slowest_1pct": float(np.mean(routes[slow] == r)) if slow.any() else 0.0}
                for r in sorted(set(routes.tolist()))}
    return {"_lat": lat if args.probe else None, "requests": lat["n"],
            "by_status": {str(k): int(v) for k, v in zip(codes, counts)},
            "latency_ms_by_route": by_route,
            "latency_ms": {"p50": float(np.nanpercentile(ms, 50)), "p99": float(np.nanpercentile(ms, 99)),
                           "max": float(np.nanmax(ms))},
            "client_send_late_ms_p99": float(np.percentile(lat["send_late_s"] * 1e3, 99)),
            "server_request_s": {f"p{q}_le": hist_quantile(c0["requests_hist"], c1["requests_hist"], q / 100)
                                 for q in (50, 99)},
            "cycles_analysed": c1["processed"] - c0["processed"], "cycles_offered": offered,
            "cycles_skipped": c1["skipped"] - c0["skipped"],
            "records_dropped_by_the_bounded_queue": c1["dropped_records"] - c0["dropped_records"],
            **accounting(c1["processed"] - c0["processed"], offered, c1["skipped"] - c0["skipped"], r0, r1),
            "server_cpu_s_per_wall_s": (cpu1 - cpu0) / (w1 - w0)}


def accounting(analysed: float, offered: float, skipped: float, r0: dict, r1: dict) -> dict:
    """Where the offered cycles went. ``offered`` is the real-time need (each engine's speed / 120 x the wall
    seconds), but a looped replay delivers less than that: each pass restarts its pacing at the seam, so a pass of
    demo.mcap (40 cycles, 3.200 s of data) takes 3.24 s of wall time read alone, longer when the reader thread wakes
    late on a busy box. So what the server missed is counted from what it said: cycles dropped by the bounded queue,
    skipped, or queued at the window's end beyond its start (``missed_by_the_server``); the rest of the shortfall is
    the replay's (``short_of_real_time_by_the_replay``). ``analysed_per_seam``: the demo's 40 when every pass was
    analysed whole (give or take a pass per engine at the window's ends)."""
    more_queued = r1["queued_cycles"] - r0["queued_cycles"]
    missed = (r1["dropped_cycles"] - r0["dropped_cycles"]) + skipped + max(more_queued, 0.0)
    seams = r1["loop_seams"] - r0["loop_seams"]
    return {"queued_cycles_start_end": [r0["queued_cycles"], r1["queued_cycles"]],
            "behind_s_max_end": r1["behind_s_max"], "loop_seams": seams,
            "analysed_per_seam": analysed / seams if seams else None, "missed_by_the_server": missed,
            "short_of_real_time_by_the_replay": offered - analysed - missed}


def timeline(lat: dict, probe: Path) -> dict:
    """Where the slow requests' time went: the client's send -> the server's ASGI entry (the client's threads, the
    kernel, the event loop reaching the socket, uvicorn's parsing), the server's own span (the /metrics histogram's),
    the server's exit -> the client's read done; and what overlapped the slowest 1 % (a gc pass, a late wake-up of a
    thread that waits on nothing but the GIL)."""
    rec = json.loads(probe.read_text())
    srv = {rid: (route, t0, t1) for rid, route, t0, t1 in rec["req"] if 0 <= rid < lat["n"]}
    ids = np.array(sorted(srv))
    cs, cd = lat["sent"][ids], lat["done"][ids]
    s0 = np.array([srv[i][1] for i in ids])
    s1 = np.array([srv[i][2] for i in ids])
    total, inside = (cd - cs) * 1e3, (s1 - s0) * 1e3
    before, after = (s0 - cs) * 1e3, (cd - s1) * 1e3
    slow = total >= np.percentile(total, 99)
    gcs = np.array([(t, d) for t, d, gen, _ in rec["gc"] if gen == 2] or np.zeros((0, 2)))
    wakes = np.array([(t, x) for t, x, _ in rec["wake"]] or np.zeros((0, 2)))
    window = (cs.min(), cd.max())
    in_win = (wakes[:, 0] >= window[0]) & (wakes[:, 0] <= window[1]) if len(wakes) else np.zeros(0, bool)

    def overlaps(spans: np.ndarray, lo: np.ndarray, hi: np.ndarray, min_s: float) -> float:
        big = spans[spans[:, 1] >= min_s] if len(spans) else spans
        if not len(big):
            return 0.0
        return float(np.mean([np.any((big[:, 0] < h) & (big[:, 0] + big[:, 1] > lo_)) for lo_, h in zip(lo, hi)]))

    def q(x: np.ndarray) -> dict:
        return {"p50": float(np.percentile(x, 50)), "p99": float(np.percentile(x, 99)), "max": float(np.max(x))}

    culprits: dict[str, int] = {}
    for t, x, frames in rec["wake"]:
        if window[0] <= t <= window[1] and x > 0.02:
            for name, stack in frames.items():
                if name.startswith("live-ingest") or name.startswith("listener"):
                    key = f"{name.split('-')[0]}:{stack[-1] if stack else '?'}"
                    culprits[key] = culprits.get(key, 0) + 1
    return {"matched": int(len(ids)), "client_ms": q(total), "server_ms": q(inside),
            "client_send_to_server_entry_ms": q(before), "server_exit_to_client_read_ms": q(after),
            "slowest_1pct_median_ms": {"client": float(np.median(total[slow])),
                                       "server": float(np.median(inside[slow])),
                                       "before_server": float(np.median(before[slow])),
                                       "after_server": float(np.median(after[slow]))},
            "slowest_1pct_overlapping_gen2_gc_ge_10ms": overlaps(gcs, cs[slow], cd[slow], 0.010),
            "slowest_1pct_overlapping_a_wake_late_ge_20ms": overlaps(wakes, cs[slow], cd[slow], 0.020),
            "gen2_gc_during_load": {"n": int(np.sum((gcs[:, 0] >= window[0]) & (gcs[:, 0] <= window[1]))) if len(gcs)
                                    else 0, "ms_max": float(gcs[:, 1].max() * 1e3) if len(gcs) else 0.0},
            "wake_late_ms_during_load": {"n_over_3ms": int(in_win.sum()),
                                         "over_20ms": int(np.sum(wakes[in_win, 1] > 0.02)) if len(wakes) else 0,
                                         "max": float(wakes[in_win, 1].max() * 1e3) if in_win.any() else 0.0,
                                         "per_s": float(in_win.sum() / (window[1] - window[0]))},
            "threads_running_at_a_wake_late_ge_20ms": dict(sorted(culprits.items(), key=lambda kv: -kv[1])[:12]),
            "switch_interval_s": rec["switch_interval_s"],
            "window_documents_asked_made": rec.get("window_documents"), "losses_now": rec.get("losses_now"),
            "window_replies_asked_made": rec.get("window_replies")}  # all of serve's run, not the load's only


def context_switches(pid: int) -> tuple[int, int]:
    """(voluntary, involuntary) context switches of the live threads of ``pid`` so far. Voluntary: a thread went to
    sleep (a queue, a lock, the GIL); involuntary: the kernel took its core (another thread or process)."""
    vol = invol = 0
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            text = Path(f"/proc/{pid}/task/{tid}/status").read_text()
        except OSError:  # the thread ended meanwhile
            continue
        vol += int(re.search(r"^voluntary_ctxt_switches:\s+(\d+)", text, re.M)[1])
        invol += int(re.search(r"^nonvoluntary_ctxt_switches:\s+(\d+)", text, re.M)[1])
    return vol, invol


def run_idle(args, client: httpx.Client, pid: int, engines: list[str]) -> dict:
    time.sleep(args.settle)
    c0, cpu0, w0, x0 = counters(client), cpu_s(pid), time.monotonic(), context_switches(pid)
    time.sleep(args.seconds)
    c1, cpu1, w1, x1 = counters(client), cpu_s(pid), time.monotonic(), context_switches(pid)
    rpm = [client.get(f"/api/v1/engines/{e}/cycles/latest").json()["rpm_mean"] for e in engines]
    offered = sum(r / 60.0 / CYCLE_REVS for r in rpm) * (w1 - w0)
    share = (cpu1 - cpu0) / (w1 - w0)
    analysed = c1["processed"] - c0["processed"]
    per_cycle_s = (cpu1 - cpu0) / analysed if analysed > 0 else float("nan")
    cycles_per_s = float(np.mean(rpm)) / 60.0 / CYCLE_REVS  # one genset's
    return {"server_cpu_s_per_wall_s": share, "cpu_share_per_engine": share / len(engines),
            "cpu_ms_per_cycle": 1e3 * per_cycle_s, "gensets_per_core": 1.0 / (per_cycle_s * cycles_per_s),
            "target_per_core": TARGET_PER_CORE, "cycles_analysed": analysed, "cycles_offered": offered,
            "context_switches_per_cycle": {"voluntary": (x1[0] - x0[0]) / analysed,
                                           "involuntary": (x1[1] - x0[1]) / analysed} if analysed > 0 else None,
            "cycles_skipped": c1["skipped"] - c0["skipped"],
            "records_dropped_by_the_bounded_queue": c1["dropped_records"] - c0["dropped_records"]}


def run_lag(args, client: httpx.Client, pid: int, engines: list[str]) -> dict:
    t0 = time.monotonic()
    first_behind: dict[str, float] = {}
    degraded_at, rss, max_queued = None, [], dict.fromkeys(engines, 0.0)
    while time.monotonic() - t0 < args.seconds:
        doc = client.get("/api/v1/health").json()
        now = time.monotonic() - t0
        if doc["status"] == "degraded" and degraded_at is None:
            degraded_at = now
        for row in doc["engines"]:
            max_queued[row["engine_id"]] = max(max_queued[row["engine_id"]], row["queued_s"])
            if row["behind"] and row["engine_id"] not in first_behind:
                first_behind[row["engine_id"]] = now
        rss.append((round(now, 1), round(rss_mb(pid))))
        time.sleep(0.5)
    end = {r["engine_id"]: r for r in client.get("/api/v1/health").json()["engines"]}
    return {"degraded_after_s": degraded_at, "first_behind_s": first_behind,
            "max_queued_s": max(max_queued.values()), "dropped_records": sum(r["dropped_records"] for r in end.values()),
            "dropped_cycles": sum(r["dropped_cycles"] or 0 for r in end.values()),
            "rss_mb_first_last_max": (rss[0][1], rss[-1][1], max(m for _, m in rss)), "rss_mb_every_5s": rss[::10]}


SAME_LOGS = ("demo", "k9k-4cyl", "maruti-3cyl", "deutz-1cyl")
WRITE_TIMES = {"written_at", "updated_at", "saved_at"}


def serve_to(checkout: Path, data_dir: Path, seconds: float, cpu: int | None) -> None:
    """``checkout``'s serve of SAME_LOGS (looped at max speed) into ``data_dir`` for ``seconds``, then SIGTERM."""
    cmd = [str(checkout / ".venv" / "bin" / "python"), "-m", "frictionwatch.service.cli", "serve", "--port", "0",
           "--data-dir", str(data_dir)]
    for name in SAME_LOGS:
        cmd += ["--source", f"mcap:replay_logs/{name}.mcap?loop=1&speed=max#{name.split('-')[0]}"]
    if cpu is not None:
        cmd = ["taskset", "-c", str(cpu), *cmd]
    proc, url = launched(cmd, checkout, timeout_s=900)
    try:
        with httpx.Client(base_url=url, timeout=10) as client:
            wait_first_results(client, [name.split("-")[0] for name in SAME_LOGS])
        time.sleep(seconds)
        proc.terminate()
        proc.wait(120)
    finally:
        if proc.poll() is None:
            proc.kill()


def stored(db: Path) -> dict[str, dict[tuple, dict]]:
    """Each table's rows by key, write times left out, JSON text parsed."""
    import sqlite3

    keys = {"cycles": ("engine_id", "cycle_index"), "estimates": ("engine_id", "cycle_index", "cylinder"),
            "alerts": ("engine_id", "alert_id"), "baselines": ("engine_id", "seq")}
    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    con.row_factory = sqlite3.Row
    out: dict[str, dict[tuple, dict]] = {}
    for table, key in keys.items():
        rows = {}
        for row in con.execute(f"SELECT * FROM {table}"):  # noqa: S608 - the table names above
            doc = {k: row[k] for k in row.keys() if k not in WRITE_TIMES}
            for k, v in doc.items():
                if isinstance(v, str) and v[:1] in "[{":
                    doc[k] = json.loads(v)
            rows[tuple(row[k] for k in key)] = doc
        out[table] = rows
    con.close()
    return out


def same_value(a, b, path: str, bad: list[str]) -> None:
    """``a`` equals ``b``: numbers within rtol 1e-12 (NaN as NaN, None as None), the rest equal; what differs goes
    into ``bad``."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in WRITE_TIMES or k == "at_s":
                continue
            same_value(a.get(k), b.get(k), f"{path}.{k}", bad)
    elif isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            same_value(x, y, f"{path}[{i}]", bad)
    elif isinstance(a, int | float) and isinstance(b, int | float) and not isinstance(a, bool):
        if not np.isclose(a, b, rtol=1e-12, atol=0.0, equal_nan=True):
            bad.append(f"{path}: {a!r} != {b!r}")
    elif a != b:
        bad.append(f"{path}: {a!r} != {b!r}")


def run_same(args) -> dict:
    import tempfile

    other = Path(args.against).resolve()
    with tempfile.TemporaryDirectory(prefix="fw-same-") as tmp:
        dbs = {}
        for name, checkout in (("this", ROOT), ("against", other)):
            serve_to(checkout, Path(tmp) / name, args.seconds, args.cpu)
            dbs[name] = stored(Path(tmp) / name / "frictionwatch.db")
    this, base = dbs["this"], dbs["against"]
    reached = {}  # per engine: the newest cycle both stored
    for e in {k[0] for k in this["cycles"]} | {k[0] for k in base["cycles"]}:
        reached[e] = min(max((k[1] for k in d["cycles"] if k[0] == e), default=-1) for d in (this, base))
    out: dict = {"engines_newest_cycle_both": reached, "tables": {}}
    for table in ("cycles", "estimates", "alerts", "baselines"):
        def within(key, row, table=table):
            cycle = row.get("raised_cycle") if table == "alerts" else key[1] if table != "baselines" else None
            return cycle is None or cycle <= reached.get(key[0], -1)
        a = {k: r for k, r in this[table].items() if within(k, r)}
        b = {k: r for k, r in base[table].items() if within(k, r)}
        if table == "baselines":  # the sequence both reached: the shorter one's
            a = {k: r for k, r in a.items() if k in b}
            b = {k: r for k, r in b.items() if k in a}
        bad: list[str] = [f"{k}: only in this" for k in sorted(set(a) - set(b))][:5]
        bad += [f"{k}: only in the other" for k in sorted(set(b) - set(a))][:5]
        for k in sorted(set(a) & set(b)):
            same_value(a[k], b[k], f"{table}{k}", bad)
        out["tables"][table] = {"compared": len(set(a) & set(b)), "this_only": len(set(a) - set(b)),
                                "other_only": len(set(b) - set(a)), "differences": len(bad), "first": bad[:5]}
    out["same"] = all(t["differences"] == 0 for t in out["tables"].values())
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=("mix", "lag", "idle", "same"))
    ap.add_argument("--against", help="same: the other checkout (its own .venv)")
    ap.add_argument("--engines", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=200.0)
    ap.add_argument("--settle", type=float, default=10.0, help="seconds after the first results before the load")
    ap.add_argument("--cpu", type=int, help="pin the server to this core (taskset)")
    ap.add_argument("--probe", help="mix: serve under bench/serve_probe.py, its timeline to this JSON file")
    ap.add_argument("--switch-interval", type=float, help="with --probe: serve's sys.setswitchinterval (s), a trial")
    ap.add_argument("--api-default-policy", action="store_true",
                    help="with --probe: serve's event loop and request threads back to SCHED_OTHER, a trial")
    ap.add_argument("--history-cycles", type=int, default=5000,
                    help="serve's history per engine: a short one shows the memory plateau in a short run")
    args = ap.parse_args()
    if args.mode == "same":
        print(json.dumps({"mode": "same", "seconds": args.seconds, "against": args.against, **run_same(args),
                          "loadavg": os.getloadavg()}, indent=1, default=str))
        return
    engines = [f"g{i + 1}" for i in range(args.engines)]
    proc, url = start_server(args.engines, args.cpu, args.history_cycles, args.probe, args.switch_interval,
                             args.api_default_policy)
    try:
        with httpx.Client(base_url=url, timeout=10) as client:
            first = wait_first_results(client, engines)
            run = {"mix": lambda: run_mix(args, client, url, proc.pid, engines),
                   "lag": lambda: run_lag(args, client, proc.pid, engines),
                   "idle": lambda: run_idle(args, client, proc.pid, engines)}[args.mode]
            out = run()
        proc.terminate()
        t = time.monotonic()
        proc.wait(60)
        out.update(first_results_s=first, sigterm_exit_s=time.monotonic() - t, exit_code=proc.returncode)
        time.sleep(0.5)  # the reader thread's last lines
        said = [proc.lines.get_nowait().strip() for _ in range(proc.lines.qsize())]
        out["stop_lines"] = [x for x in said if "stopped" in x]  # per engine: kernels compiled after the warm-up...
        lat = out.pop("_lat", None)
        if lat is not None:
            out["timeline"] = timeline(lat, Path(args.probe))
        print(json.dumps({"mode": args.mode, "engines": args.engines, "seconds": args.seconds, "rate": args.rate,
                          "cpu": args.cpu, "history_cycles": args.history_cycles, "loadavg": os.getloadavg(), **out}, indent=1, default=float))
    finally:
        if proc.poll() is None:
            proc.kill()


if __name__ == "__main__":
    main()
