"""Decode throughput of the wire drivers against the data rate of genset-v20 at 1500 rpm (target >= 50x, one core).

genset-v20 at 1500 rpm: a 160-2 crank wheel gives 158 edges/rev x 25 rev/s = 3,950 edges/s (plus 12.5 cam edges/s);
20 cylinders of pressure at 20 kHz are 400,000 samples/s = 16,000 CAN FD frames/s of 25 samples. The decoders
are timed on pre-encoded input (bytes as the serial port delivers them in 4 kB reads; python-can messages in
batches of 4,096 as CanSource drains the bus; log arrays as the MDF4 replay feeds them). Best of ``repeats``.
Classic CAN cannot carry the genset's pressure rate at all (a 1 Mbit/s bus moves about 8,000 frames/s = 24,000
samples/s), so its line is measured against a fully loaded 1 Mbit/s bus instead.

    python -m bench.bench_drivers
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from frictionwatch.drivers.can.decoder import CanDecoder
from frictionwatch.drivers.can.encoder import PressureEncoder
from frictionwatch.drivers.serial.codec import Decoder, Encoder

RPM = 1500.0
EDGES_PER_REV = 158  # 160-2 wheel
CYLINDERS = 20
PRESSURE_HZ = 20e3
TICK_HZ = 10e6
TARGET = 50.0
CLASSIC_BUS_FRAMES_PER_S = 1e6 / 125  # 8-byte standard frames at 1 Mbit/s, 100 % load (111 bits + ~14 stuff bits)


def genset_rates() -> dict[str, float]:
    """Data rate of genset-v20 at 1500 rpm: edges/s, pressure frames/s (CAN FD, 25 samples), samples/s."""
    edges = RPM / 60 * EDGES_PER_REV
    samples = CYLINDERS * PRESSURE_HZ
    return {"edges_per_s": edges, "pressure_samples_per_s": samples, "fd_frames_per_s": samples / 25,
            "classic_frames_per_s": samples / 3}


def _best(fn: Callable[[], object], repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return float(best)


def _tooth_ticks(n: int) -> np.ndarray:
    rng = np.random.default_rng(0)
    period = TICK_HZ / (RPM / 60 * 160)  # 2,500 ticks per tooth
    d = np.rint(period * (1 + 0.002 * rng.standard_normal(n))).astype(np.int64)
    d[::EDGES_PER_REV] *= 3  # the gap of two missing teeth
    return (1 << 32) - 10**7 + np.cumsum(d)  # crosses the 32-bit wrap


def bench_serial(max_edges: int, n_edges: int = 200_000, repeats: int = 3) -> dict[str, float]:
    stream = Encoder(max_edges=max_edges).teeth(_tooth_ticks(n_edges))
    chunks = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]
    frames = 0

    def run_once() -> None:
        nonlocal frames
        dec = Decoder()
        frames = sum(len(dec.feed(c)) for c in chunks)

    dt = _best(run_once, repeats)
    return {"frames_per_s": frames / dt, "mb_per_s": len(stream) / dt / 1e6, "edges_per_s": n_edges / dt,
            "x_realtime": n_edges / dt / genset_rates()["edges_per_s"]}


def _pressure_messages(fd: bool, n_per_cyl: int) -> list:
    enc = PressureEncoder(fd=fd)
    rng = np.random.default_rng(1)
    period = TICK_HZ / PRESSURE_HZ
    msgs = []
    block = 25 * 8 if fd else 3 * 64
    for k in range(n_per_cyl // block):
        t0 = 1_000_000 + k * block * period
        for c in range(1, CYLINDERS + 1):
            ms = enc.block(c, round(t0), period, 1e5 + 1.7e7 * rng.random(block))
            for m in ms:
                m.timestamp = t0 / TICK_HZ
            msgs += ms
    return msgs


def bench_can(fd: bool, n_per_cyl: int = 40_000, repeats: int = 3) -> dict[str, float]:
    msgs = _pressure_messages(fd, n_per_cyl)
    batches = [msgs[i:i + 4096] for i in range(0, len(msgs), 4096)]
    nbytes = sum(len(m.data) for m in msgs)
    samples = 0

    def run_once() -> None:
        nonlocal samples
        dec = CanDecoder()
        samples = sum(r.values.size for b in batches for r in dec.feed(b))

    dt = _best(run_once, repeats)
    if fd:
        x = samples / dt / genset_rates()["pressure_samples_per_s"]
    else:  # classic CAN cannot carry the genset's rate; the most one 1 Mbit/s bus can bring is the yardstick
        x = len(msgs) / dt / CLASSIC_BUS_FRAMES_PER_S
    return {"frames_per_s": len(msgs) / dt, "mb_per_s": nbytes / dt / 1e6, "samples_per_s": samples / dt,
            "x_realtime": x}


def bench_can_arrays(n_per_cyl: int = 40_000, repeats: int = 3) -> dict[str, float]:
    """The CAN FD decoder on log arrays (the MDF4 replay path: no python-can Message objects)."""
    msgs = _pressure_messages(True, n_per_cyl)
    n = len(msgs)
    ts = np.array([m.timestamp for m in msgs])
    ids = np.array([m.arbitration_id for m in msgs], np.int64)
    ext = np.zeros(n, bool)
    lengths = np.full(n, 64)
    data = np.frombuffer(b"".join(bytes(m.data) for m in msgs), np.uint8).reshape(n, 64)
    samples = 0

    def run_once() -> None:
        nonlocal samples
        dec = CanDecoder()
        samples = sum(r.values.size for i in range(0, n, 4096)
                      for r in dec.feed_arrays(ts[i:i + 4096], ids[i:i + 4096], ext[i:i + 4096],
                                               lengths[i:i + 4096], data[i:i + 4096]))

    dt = _best(run_once, repeats)
    return {"frames_per_s": n / dt, "mb_per_s": n * 64 / dt / 1e6, "samples_per_s": samples / dt,
            "x_realtime": samples / dt / genset_rates()["pressure_samples_per_s"]}


def run(repeats: int = 3) -> dict:
    """All driver throughput figures; ``x_realtime`` is against genset-v20 at 1500 rpm, target >= 50."""
    return {
        "genset_v20_1500rpm": genset_rates(),
        "target_x_realtime": TARGET,
        "serial_32_edges_per_frame": bench_serial(32, repeats=repeats),
        "serial_1_edge_per_frame": bench_serial(1, n_edges=50_000, repeats=repeats),
        "can_fd_messages": bench_can(True, repeats=repeats),
        "can_fd_log_arrays": bench_can_arrays(repeats=repeats),
        "can_classic_messages": bench_can(False, n_per_cyl=6_144, repeats=repeats),
    }


def main() -> None:
    res = run()
    rates = res["genset_v20_1500rpm"]
    print(f"genset-v20 @ 1500 rpm: {rates['edges_per_s']:.0f} edges/s, {rates['pressure_samples_per_s']:.0f} "
          f"pressure samples/s ({rates['fd_frames_per_s']:.0f} CAN FD frames/s); target >= {TARGET:.0f}x")
    print(f"{'decoder':28s} {'frames/s':>12s} {'MB/s':>8s} {'x real time':>12s}  ok   real time =")
    for name, r in res.items():
        if isinstance(r, dict) and "x_realtime" in r:
            ok = "yes" if r["x_realtime"] >= TARGET else "NO"
            ref = "a full 1 Mbit/s classic bus" if "classic" in name else "genset-v20 @ 1500 rpm"
            print(f"{name:28s} {r['frames_per_s']:12,.0f} {r['mb_per_s']:8.2f} {r['x_realtime']:12.0f}  {ok:4s} {ref}")


if __name__ == "__main__":
    main()
