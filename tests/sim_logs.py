"""Simulated replay logs for the tests, made through the CLI as a user makes them (`frictionwatch simulate`)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.core.types import CamBatch, FreeEndToothBatch, LoadSample, PressureFrame, ToothBatch
from frictionwatch.service.cli import main
from frictionwatch.service.pipeline import run
from numpy.testing import assert_allclose, assert_array_equal


def simulate_log(path: Path, engine: str, rpm: float, load: float, seed: int, cycles: int,
                 effect: str | None = None) -> Path:
    """``path`` (OUT.mcap, its truth beside it) of ``engine`` at ``rpm`` and ``load`` with one optional effect."""
    args = ["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles),
            "--seed", str(seed), "-o", str(path)]
    assert main(args + (["--effect", effect] if effect else [])) == 0
    return path


def commissioned_model(folder: Path, engine: str, rpm: float, load: float, seed: int, cycles: int) -> Path:
    """MODEL.toml written by `frictionwatch commission` from a healthy simulated log in ``folder``."""
    log = simulate_log(folder / "commissioning.mcap", engine, rpm, load, seed, cycles)
    assert main(["commission", str(log), "-o", str(folder / "model.toml")]) == 0
    return folder / "model.toml"


def sensor_flags(analysis) -> tuple[list[str], int]:
    """The sensor flags of an analysis's last cycle, and the first cycle that had any (-1: none)."""
    first = next((r.index for r in analysis.results if any(f.startswith("sensor_") for f in r.flags)), -1)
    return sorted(f for f in analysis.results[-1].flags if f.startswith("sensor_")), first


def withheld_cylinders(analysis) -> list[int]:
    """The cylinders (1-based) whose friction figure the last result withholds, under its own flags."""
    from frictionwatch.core.monitor.report.figure_status import friction_status

    last = analysis.results[-1]
    return [k + 1 for k, c in enumerate(friction_status(last.smoothed, last.flags).cylinders) if c.status == "withheld"]


def pipeline_results(engine, sim, config=None) -> tuple[list[CycleResult], Counter[str]]:
    """A simulated log (``simulate``'s records) through the one pipeline (service.pipeline.run: the assembler, the
    monitor, the running calibration watches): the analysed cycles' results in order, and the cycles lost on the
    way by reason (the assembler's and the monitor's refusals alike)."""
    outcomes = list(run(engine, sim.info, sim.records, config))
    return [o.result for o in outcomes if o.ok], Counter(o.skipped for o in outcomes if not o.ok)


def assert_same_records(got: list, want: list, rtol: float = 0.0) -> None:
    """Two simulated record streams alike: the same kinds in the same order, ticks equal, pressures and load
    samples within ``rtol`` (0: to the bit)."""
    assert [type(r) for r in got] == [type(r) for r in want]
    for a, b in zip(got, want):
        if isinstance(b, ToothBatch | CamBatch | FreeEndToothBatch):
            assert_array_equal(a.ticks, b.ticks)
        elif isinstance(b, PressureFrame):
            assert (a.cylinders, a.t0_ticks, a.period_ticks) == (b.cylinders, b.t0_ticks, b.period_ticks)
            assert_allclose(a.values, b.values, rtol=rtol, atol=0.0)
        else:
            assert isinstance(b, LoadSample) and a.ticks == b.ticks
            assert_allclose([a.torque, a.power], [b.torque, b.power], rtol=rtol, atol=0.0)


def two_point_steps(rpm: float, load: float, rpm2: float, load2: float, cycles: int,
                    blocks: tuple[int, int]) -> list[tuple[float, float, float]]:
    """The simulator's steps [(time_s, load, rpm)] of a log in blocks of (rpm, load) and (rpm2, load2) in turn, the
    first point's first (where the simulator sizes a law), ``blocks`` cycles each, ``cycles`` in all (the times from
    the requested speeds: the first cycle starts one revolution after tick 0)."""
    steps, t, c, first = [], 60.0 / rpm, 0, True
    while True:
        t += blocks[0 if first else 1] * 120.0 / (rpm if first else rpm2)
        c += blocks[0 if first else 1]
        first = not first
        if c >= cycles:
            return steps
        steps.append((t, load, rpm) if first else (t, load2, rpm2))
