"""Batcher: joining and splitting records into ~span messages never changes a tick or a sample."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from frictionwatch.core.types import CamBatch, LoadSample, PressureBlock, ToothBatch
from frictionwatch.drivers.logs.mcap_batching import Batcher

from tests.drivers.mcap_corpus import assert_same_streams


def run(batcher: Batcher, records: list) -> list:
    out = []
    for record in records:
        out += batcher.add(record)
    return out + batcher.drain()


def test_teeth_are_split_and_joined_to_the_span() -> None:
    ticks = np.cumsum(np.random.default_rng(0).integers(900, 1100, 5000)).astype(np.int64)
    records = [ToothBatch(ticks[:3000]), ToothBatch(ticks[3000:3007]), ToothBatch(ticks[3007:])]
    out = run(Batcher(span_ticks=50_000), records)
    assert_same_streams(out, records)
    spans = [int(r.ticks[-1] - r.ticks[0]) for r in out[:-1]]
    assert max(spans) < 50_000 and min(spans) >= 48_000  # ~50 edges of ~1000 ticks each


def test_restart_is_not_joined() -> None:
    records = [ToothBatch(np.array([100, 200])), ToothBatch(np.array([50, 60])), CamBatch(np.array([7]))]
    out = run(Batcher(span_ticks=1e6), records)
    teeth = [r.ticks.tolist() for r in out if isinstance(r, ToothBatch)]
    assert teeth == [[100, 200], [50, 60]]


def test_pressure_with_a_fractional_period_splits_only_on_integer_ticks() -> None:
    period = 1.5  # sample k at t0 + 1.5 k: only even k land on an integer tick
    values = np.arange(1000, dtype=np.float64)
    records = [PressureBlock(3, 10, period, values[:334]), PressureBlock(3, 511, period, values[334:])]
    assert Fraction(10) + 334 * Fraction(period) == 511  # the second block continues the grid: joined
    out = run(Batcher(span_ticks=100), records)
    assert_same_streams(out, records)
    assert len(out) > 10
    for r in out:
        k = Fraction(r.t0_ticks - 10) / Fraction(period)
        assert isinstance(r.t0_ticks, int) and k.denominator == 1 and k % 2 == 0
        assert r.values[0] == k  # the sample that belongs at that tick


def test_contiguous_pressure_blocks_are_joined_and_load_passes_through() -> None:
    values = np.random.default_rng(1).normal(1e5, 1e3, 400)
    records = [PressureBlock(1, 1000 + 500 * i * 10, 500.0, values[i * 10 : (i + 1) * 10]) for i in range(40)]
    records.insert(5, LoadSample(1234, 1.0, 2.0))
    out = run(Batcher(span_ticks=100_000), records)
    assert_same_streams(out, records)
    blocks = [r for r in out if isinstance(r, PressureBlock)]
    assert [len(b.values) for b in blocks] == [200, 200]
    assert [r for r in out if isinstance(r, LoadSample)] == [records[5]]
