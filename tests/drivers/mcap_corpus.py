"""Seeded stream corpus for the MCAP log tests, and helpers to compare streams independent of batching."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
from frictionwatch.core.types import (
    AcquisitionInfo,
    CamBatch,
    LoadSample,
    PressureBlock,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)

ENGINE_TOML = (Path(__file__).resolve().parents[2] / "core" / "model" / "engines" / "k9k-4cyl.toml").read_text()
INFO = AcquisitionInfo(
    tick_hz=10e6, wheel_teeth=60, wheel_missing=2, first_tooth_deg=-84.0, cam_deg=12.5, pressure_cylinders=(1, 2, 3, 4)
)


def corpus(
    seconds: float = 0.3,
    seed: int = 0,
    rpm: float = 1500.0,
    info: AcquisitionInfo = INFO,
    pressure_hz: float = 20e3,
    window_s: float = 0.004,
    frames: bool = False,
) -> list[StreamRecord]:
    """Records in acquisition order: irregular windows of teeth, pressure blocks per cylinder (``frames``: one
    PressureFrame of all cylinders per window instead), load samples, cam."""
    rng = np.random.default_rng(seed)
    tick_hz = info.tick_hz
    rev_s = 60.0 / rpm
    angles = np.arange(info.wheel_teeth - info.wheel_missing) / info.wheel_teeth  # fraction of a revolution
    n_rev = int(np.ceil(seconds / rev_s)) + 1
    t_edges = (np.arange(n_rev)[:, None] + angles[None, :]).ravel() * rev_s
    t_edges = t_edges + 2e-3 * np.sin(2 * np.pi * t_edges / (2 * rev_s)) * rev_s / 50  # speed ripple
    t0 = 0.0123  # the timer does not start at zero
    teeth = (
        np.floor((t_edges[t_edges < seconds] + t0) * tick_hz).astype(np.int64)
        + rng.integers(0, 3, t_edges.size)[t_edges < seconds]
    )
    cam = np.floor((np.arange(0, seconds, 2 * rev_s) + t0 + 0.1 * rev_s) * tick_hz).astype(np.int64)
    period = tick_hz / pressure_hz
    n_samples = int(seconds * pressure_hz)
    sample_ticks0 = int(t0 * tick_hz)
    lsb = 25e6 / 65536
    phase = (np.arange(n_samples) / pressure_hz) % (2 * rev_s)  # s into the 720 deg cycle
    pressure = {}
    for c in info.pressure_cylinders:
        p = 2e5 + 60e5 * np.exp(-((phase - 0.2 * c * rev_s) ** 2) / 1e-6) + rng.normal(0, 1e4, n_samples)
        pressure[c] = np.round(p / lsb) * lsb  # 16-bit ADC over 25 MPa
    pressure[info.pressure_cylinders[0]][5] = np.nan  # a saturated sample
    out: list[StreamRecord] = []
    edges = np.arange(0.0, seconds + window_s, window_s)
    sample_at = 0
    for a, b in itertools.pairwise(edges):
        lo, hi = int((a + t0) * tick_hz), int((b + t0) * tick_hz)
        sel = teeth[(teeth >= lo) & (teeth < hi)]
        if sel.size:
            out.append(ToothBatch(sel))
        sel = cam[(cam >= lo) & (cam < hi)]
        if sel.size:
            out.append(CamBatch(sel))
        n_to = min(n_samples, int(np.ceil((hi - sample_ticks0) / period)))
        if n_to > sample_at and frames:
            rows = np.array([values[sample_at:n_to] for values in pressure.values()])
            out.append(PressureFrame(tuple(pressure), sample_ticks0 + int(sample_at * period), period, rows))
            sample_at = n_to
        if n_to > sample_at:
            for c, values in pressure.items():
                out.append(PressureBlock(c, sample_ticks0 + int(sample_at * period), period, values[sample_at:n_to]))
            sample_at = n_to
        ticks = (lo + hi) // 2
        out.append(LoadSample(int(ticks), 150.0 + rng.normal(0, 2.0), float(rng.normal(25e3, 100.0))))
    return out


def streams(records: list[StreamRecord]) -> dict[object, object]:
    """Concatenated content per stream: teeth / cam ticks, per-cylinder (sample ticks, values), load tuples."""
    teeth = [r.ticks for r in records if isinstance(r, ToothBatch)]
    cam = [r.ticks for r in records if isinstance(r, CamBatch)]
    out: dict[object, object] = {
        "teeth": np.concatenate(teeth) if teeth else np.zeros(0, np.int64),
        "cam": np.concatenate(cam) if cam else np.zeros(0, np.int64),
        "load": sorted((r.ticks, r.torque, r.power) for r in records if isinstance(r, LoadSample)),
    }
    for r in records:
        if isinstance(r, PressureBlock):
            t, v = out.setdefault(("p", r.cylinder), ([], []))  # type: ignore[misc]
            t.append(r.t0_ticks + np.arange(len(r.values)) * r.period_ticks)
            v.append(r.values)
        if isinstance(r, PressureFrame):  # per cylinder, apart from blocks of the same cylinder
            for c, row in zip(r.cylinders, r.values, strict=True):
                t, v = out.setdefault(("f", c), ([], []))  # type: ignore[misc]
                t.append(r.t0_ticks + np.arange(len(row)) * r.period_ticks)
                v.append(row)
    for key, value in list(out.items()):
        if isinstance(key, tuple):
            out[key] = (np.concatenate(value[0]), np.concatenate(value[1]))  # type: ignore[index]
    return out


def assert_same_streams(got: list[StreamRecord], want: list[StreamRecord]) -> None:
    a, b = streams(got), streams(want)
    assert a.keys() == b.keys()
    for key in a:
        if isinstance(key, tuple):
            np.testing.assert_array_equal(a[key][0], b[key][0])  # type: ignore[index]
            np.testing.assert_array_equal(a[key][1], b[key][1])  # type: ignore[index]  (NaN == NaN here)
        elif key == "load":
            assert a[key] == b[key]
        else:
            np.testing.assert_array_equal(a[key], b[key])
