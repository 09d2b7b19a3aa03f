"""The fleet view's cost against the rows stored (issue 28 item 7: bounded work per request).

A store (SQLite in a temp folder, or ``--url postgresql://...``: a fresh schema there, dropped at the end) holds
``--engines`` engines, each with ``--cycles`` cycles written in batches of 64 and three alerts (active, acknowledged,
cleared); then ``store.fleet()`` is timed ``--repeat`` times. Run it at two ``--cycles`` in one session and quote the
ratio of the medians: it should stay near 1 whatever the cycles (the query reads per-engine rows only); it grows with
the engines and with each engine's open alerts (counted on the (engine_id, state) index).

    .venv/bin/python -m bench.bench_store_fleet --engines 20 --cycles 500 5000
    .venv/bin/python -m bench.bench_store_fleet --engines 20 --cycles 500 5000 --url "$FW_TEST_POSTGRES_URL"

Seconds of wall time; not part of the tests. Quote `uptime` beside any absolute figure.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
import uuid
from pathlib import Path
from urllib.parse import quote

from frictionwatch.service.store import open_store
from frictionwatch.service.store.fleet import Writer

from tests.service.store_samples import TOML, alert, summary

FIGURE = {"fmep_bar": 1.8, "fmep_sigma_bar": 0.03, "status": "measured", "reason": None}


def filled(url: str, engines: int, cycles: int):
    store = open_store(url)
    me = Writer.this_process()
    for e in range(engines):
        eid = f"genset-{e + 1}"
        store.claim_engine(eid, me)
        store.register_engine(eid, TOML)
        for first in range(0, cycles, 64):
            rows = [summary(i, z=20, engine_id=eid) for i in range(first, min(first + 64, cycles))]
            store.write_batch(eid, cycles=rows, engine_figure=FIGURE)
        store.write_batch(eid, alerts=[alert(1), alert(2, state="acknowledged"), alert(3, state="cleared")])
    return store


def timed(store, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        rows = store.fleet()
        times.append(time.perf_counter() - t0)
    assert rows and all(r["engine"]["status"] == "measured" for r in rows)
    return statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--engines", type=int, default=20)
    ap.add_argument("--cycles", type=int, nargs="+", default=[500, 5000])
    ap.add_argument("--repeat", type=int, default=200)
    ap.add_argument("--url", help="a PostgreSQL URL (a schema is made and dropped); default: SQLite in a temp folder")
    args = ap.parse_args()
    medians = {}
    with tempfile.TemporaryDirectory() as tmp:
        for n in args.cycles:
            if args.url:
                import psycopg

                schema = f"fw_bench_{uuid.uuid4().hex[:12]}"
                with psycopg.connect(args.url, autocommit=True) as conn:
                    conn.execute(f"CREATE SCHEMA {schema}")
                sep = "&" if "?" in args.url else "?"
                url = f"{args.url}{sep}options={quote(f'-csearch_path={schema}')}"
            else:
                url = str(Path(tmp) / f"fleet-{n}.db")
            store = filled(url, args.engines, n)
            try:
                medians[n] = timed(store, args.repeat)
            finally:
                store.close()
                if args.url:
                    with psycopg.connect(args.url, autocommit=True) as conn:
                        conn.execute(f"DROP SCHEMA {schema} CASCADE")
            print(f"{args.engines} engines x {n} cycles: fleet() median {medians[n] * 1e3:.2f} ms over {args.repeat}",
                  flush=True)
    first = args.cycles[0]
    for n in args.cycles[1:]:
        print(f"ratio {n} / {first} cycles: {medians[n] / medians[first]:.2f}")


if __name__ == "__main__":
    main()
