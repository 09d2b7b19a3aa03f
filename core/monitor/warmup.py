"""The monitor as a warm-up runs it: every path a live run takes, within a few cycles instead of hundreds.

    config = warm_config(config)                  # the caller's settings, its cycle counts shortened
    stages = warm_stages()                        # each stage as it reaches all its paths in a few cycles
    pipe = CyclePipeline(model, config, stages=stages)   # then WARM_CYCLES cycles of the engine through it

Why: numba compiles a kernel (or loads it from its on-disk cache) when it is first called with new argument types.
Some are called only after the monitor has run a while -- the TDC watch's fit when its first 100-cycle window
closes, the accumulated equations once ``warmup_cycles`` have passed -- and on a fresh install their compile (10-16 s
for the TDC watch's Gauss-Newton kernel) ran on a live service's ingest thread mid-run, where its queue overran and
dropped input (design notes 124, 126). A warm-up that shortens those counts reaches the same kernels with the same
argument types in ``WARM_CYCLES`` cycles. Nothing here changes what a run computes: the warm-up's pipeline is thrown
away.

A stage (core.monitor.pipeline.Stage) that reads in windows gives its warm-up form by a
``warm_up()`` method; a stage without one runs as it is. A new stage whose kernels come later than ``WARM_CYCLES``
and that has no ``warm_up()`` is caught by tests/service/test_warmup.py (kernels added after the warm-up).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from frictionwatch.core.monitor.calibration.tdc import BLOCKS
from frictionwatch.core.monitor.pipeline import STAGES, Stage
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState

# A warm window closes after BLOCKS cycles (the fewest ``close_window`` reads); the TDC watch's first window fits every
# cylinder of a commissioned model, its second and third those in turn and screen the rest (a path of their own):
# three windows, after the first cycle (the first cycle has no previous one to pair its traces with)
WARM_WINDOW = BLOCKS
WARM_WINDOWS = 3
WARM_CYCLES = 1 + WARM_WINDOWS * WARM_WINDOW + 2  # + 2: a cycle refused on the way (a seam's) leaves the count met
# cycles before the accumulated equations and the tooth refit's end in the warm-up (a live run: 20 and 50)
WARM_SETTLE_CYCLES = 3
# bound_state's lift of the lower bounds: the parameters are scale factors ~1 (core.monitor.monitor.initial_state), so
# a bound of 10 is met by every cycle's unconstrained solution
BOUND_LIFT = 10.0


def warm_config(config: MonitorConfig | None) -> MonitorConfig:
    """The caller's settings with the monitor's own cycle counts shortened (``warmup_cycles``, ``tooth_refit_cycles``):
    the paths after them are reached in the warm-up's cycles; every type a kernel sees stays the same."""
    return dataclasses.replace(config or MonitorConfig(), warmup_cycles=WARM_SETTLE_CYCLES,
                               tooth_refit_cycles=WARM_SETTLE_CYCLES)


def warm_stages(stages: tuple[Stage, ...] = STAGES) -> tuple[Stage, ...]:
    """Each stage in its warm-up form (its ``warm_up()``; as it is where it has none)."""
    return tuple(stage.warm_up() if hasattr(stage, "warm_up") else stage for stage in stages)


def bound_state(state: MonitorState) -> MonitorState:
    """``state`` with every bounded parameter's lower bound raised BOUND_LIFT above it, read-only as
    ``initial_state`` makes it: the identification's next cycles meet an active bound (the fused step's NEEDS_BOUND:
    NNLS, ``posterior_kernel``, ``posterior_moments_kernel``, ``report_kernel``), the branch a live run takes where
    an estimate reaches its bound (met at cycles 7-23 of the demo log, design note 124), which a short healthy
    stream need not take. For a warm-up's throwaway pipeline only."""
    lower = np.where(np.isfinite(state.lower), state.lower + BOUND_LIFT, state.lower)
    lower.flags.writeable = False
    return dataclasses.replace(state, lower=lower)


# sensor_fault_state's faults: a pressure channel's gain error and a wheel offset, each well past its flag's
# threshold (core.monitor.checks.sensor_health.SensorHealthConfig: gain 0.02, wheel_deg 0.8) and its floor's 4 sigma
FAULT_GAIN = 0.10
FAULT_WHEEL_RAD = math.radians(2.0)
FAULT_COUNT = 100  # cycles the faulty state claims (past min_cycles; its EWMA keeps the flags for the pass)


def sensor_fault_state(state: MonitorState) -> MonitorState:
    """``state`` with its sensor-health estimates saying that cylinder 1's pressure reads FAULT_GAIN high (where it
    has siblings to be compared with: three or more cylinders) and the wheel is FAULT_WHEEL_RAD off, flagged and
    corrected from the next cycle (core.monitor.checks.sensor_health: ``corrected_inputs``, the flags, the figures
    withheld): a sensor fault's branch, which a healthy stream never takes, run by a warm-up where the monitor's
    sensor-health stage is on (design note 136). As it is where the state has no sensor-health estimates yet. For a
    warm-up's throwaway pipeline only."""
    sensor = state.sensor
    if sensor is None:
        return state
    z = sensor.tdc_rhs.shape[0]
    mean = np.zeros_like(sensor.mean)
    if z >= 3:
        mean[z] = FAULT_GAIN
    mean[-1] = FAULT_WHEEL_RAD
    faulty = dataclasses.replace(sensor, count=max(sensor.count, FAULT_COUNT), mean=mean, var=np.zeros_like(mean),
                                 applied=mean.copy())
    return dataclasses.replace(state, sensor=faulty)


__all__ = ["BOUND_LIFT", "FAULT_GAIN", "FAULT_WHEEL_RAD", "WARM_CYCLES", "WARM_WINDOW", "WARM_WINDOWS", "bound_state",
           "sensor_fault_state", "warm_config", "warm_stages"]
