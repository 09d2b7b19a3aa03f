"""Sensor models of the plant simulator: crank tooth wheel, timer ticks, cam pulse, pressure ADC, load readings.

Angles here are in the *wheel frame*: the crank angle (cylinder-1 convention) that the wheel's stated
``first_tooth_deg`` implies. Without a ``tdc_offset`` effect it equals the true flywheel crank angle.

Tooth edge j (0 = first edge after the missing-tooth gap, j < teeth - missing) lies at
    theta_W = first_tooth_deg + j * 360/teeth + err_j  [deg],  sum_j err_j = 0,
repeated every 360 deg. Edge times are converted to integer timer ticks as floor(t * tick_hz + jitter), tick 0 being the
start of the records. ``core.plant.sim_records`` turns the plant's events into records chunk by chunk with these.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec, SensorParams
from frictionwatch.core.types import (
    CamBatch,
    FreeEndToothBatch,
    LoadSample,
    PressureFrame,
    StreamRecord,
    ToothBatch,
)

CAM_DEG = 630.0  # cam / phase edge: 90 deg before cylinder-1 firing TDC, wheel frame
LOAD_RATE_HZ = 100.0
PRESSURE_BLOCK_S = 0.010


def second_wheel_sensors(spec: EngineSpec) -> SensorParams:
    """The engine file's second wheel as a ``SensorParams`` of its own (its teeth, gap and first edge; the timer and
    the rest as the flywheel's), so the wheel functions here serve both wheels."""
    w = spec.sensors.second_wheel
    if w is None:
        raise ValueError(f"{spec.name} has no second wheel: add [sensors.second_wheel] (teeth, missing, "
                         "first_tooth_deg, node) to its engine file")
    return replace(spec.sensors, wheel_teeth=w.teeth, wheel_missing=w.missing, first_tooth_deg=w.first_tooth_deg,
                   second_wheel=None)


def tooth_errors(sensors: SensorParams, rng: np.random.Generator, sigma_deg: float, runout_deg: float = 0.0,
                 runout_phase_deg: float = 0.0) -> np.ndarray:
    """Angle error [deg] of each present tooth edge: random (rms ``sigma_deg``) + runout at order 1, mean removed."""
    n_present = sensors.wheel_teeth - sensors.wheel_missing
    j = np.arange(n_present)
    err = rng.normal(0.0, sigma_deg, n_present) if sigma_deg > 0 else np.zeros(n_present)
    ang = np.radians(sensors.first_tooth_deg + j * 360.0 / sensors.wheel_teeth)
    err = err + runout_deg * np.sin(ang + np.radians(runout_phase_deg))
    return err - err.mean()


def edge_angles(sensors: SensorParams, errors_deg: np.ndarray) -> np.ndarray:
    """Wheel-frame angle [rad] of each present edge over one revolution, starting at the first tooth after the gap."""
    j = np.arange(sensors.wheel_teeth - sensors.wheel_missing)
    ang = np.radians(sensors.first_tooth_deg + j * 360.0 / sensors.wheel_teeth + errors_deg)
    if np.any(np.diff(ang) <= 0):
        raise ValueError("tooth errors are so large that edges swap order; lower sigma_deg / runout_deg")
    return ang


def first_index_at_or_after(start_rad: float, per_rev: np.ndarray, period: float) -> int:
    """Smallest global index e (rev r = e // n, edge e % n at per_rev[e % n] + r*period) with angle >= start_rad."""
    n = per_rev.shape[0]
    r = int(np.floor((start_rad - per_rev[0]) / period)) - 1
    e = r * n
    while per_rev[e % n] + period * (e // n) < start_rad:
        e += 1
    return e


def to_ticks(times_s: np.ndarray, tick_hz: float, jitter_s: float, rng: np.random.Generator,
             after: int = -1) -> np.ndarray:
    """Integer timer ticks of event times [s since tick 0]: floor(t * f + jitter), forced strictly increasing and
    above ``after`` (the last tick of the events before these: a run converted chunk by chunk gives the same ticks
    as in one piece, the jitter drawn in order from ``rng``)."""
    x = times_s * tick_hz
    if jitter_s > 0:
        x = x + rng.normal(0.0, jitter_s * tick_hz, x.shape[0])
    ticks = np.floor(x).astype(np.int64)
    # jitter can never reorder teeth at realistic levels; keep it safe: tick_j = max(floor_j, tick_(j-1) + 1)
    j = np.arange(ticks.shape[0], dtype=np.int64)
    return np.maximum.accumulate(np.maximum(ticks - j, after + 1)) + j


def pressure_adc(p: np.ndarray, sensors: SensorParams, noise_pa: float,
                 rng: np.random.Generator | Sequence[np.random.Generator], offset_pa=0.0, gain=1.0) -> np.ndarray:
    """Sensor reading [Pa]: gain * p + offset + noise, quantised to the ADC step and clipped to 0..range (gain and
    offset scalars or arrays of p's shape: a fault with an onset, core.plant.sim_records). p (m,) with one
    generator, or (m, z), z channels at once, with one generator per channel: column k's noise is drawn from rng[k]
    as for that column alone (the same numbers; all channels in one pass cost ~half of a loop of columns, design
    note 129)."""
    y = gain * p + offset_pa
    if noise_pa > 0:
        if p.ndim == 1:
            y = y + rng.normal(0.0, noise_pa, p.shape)
        else:
            noise = np.empty(p.shape)
            for k, g in enumerate(rng):
                noise[:, k] = g.normal(0.0, noise_pa, p.shape[0])
            y = y + noise
    lsb = sensors.pressure_range_pa / 2**sensors.pressure_adc_bits
    y = np.round(y / lsb) * lsb
    return np.clip(y, 0.0, sensors.pressure_range_pa)


def keyed_records(edge_ticks: np.ndarray, teeth_per_batch: int, cam_ticks: np.ndarray, samples: np.ndarray,
                  sample_period_ticks: float, block_samples: int, load_ticks: np.ndarray, load_torque: np.ndarray,
                  load_power: np.ndarray, first_sample: int = 0, edge2_ticks: np.ndarray | None = None,
                  teeth2_per_batch: int = 1) -> list[tuple[int, int, StreamRecord]]:
    """Stream records, each with its arrival key (its last tick, then the stream: teeth, cam, pressure, load, second
    wheel), in stream order; sorting by the first two (stably) gives the arrival order.

    samples : (m, z) pressure readings [Pa] of cylinders 1..z, sample i at (first_sample + i) * sample_period_ticks,
    cut into ``PressureFrame`` s of ``block_samples`` (all z cylinders sampled together, as an indicating system
    does); t0_ticks = round((first_sample + i0) * period) (exact when the period is whole ticks).
    """
    keyed: list[tuple[int, int, StreamRecord]] = []
    for i in range(0, edge_ticks.shape[0], teeth_per_batch):
        b = edge_ticks[i:i + teeth_per_batch]
        keyed.append((int(b[-1]), 0, ToothBatch(ticks=b.copy())))
    for c in cam_ticks:
        keyed.append((int(c), 1, CamBatch(ticks=np.array([c], dtype=np.int64))))
    m, z = samples.shape
    cylinders = tuple(range(1, z + 1))
    by_cylinder = np.ascontiguousarray(samples.T)  # (z, m): one frame is a slice of it
    for i0 in range(0, m if z else 0, block_samples):
        i1 = min(i0 + block_samples, m)
        t0 = round((first_sample + i0) * sample_period_ticks)
        last = round((first_sample + i1 - 1) * sample_period_ticks)
        frame = PressureFrame(cylinders=cylinders, t0_ticks=t0, period_ticks=float(sample_period_ticks),
                              values=np.ascontiguousarray(by_cylinder[:, i0:i1]))
        keyed.append((last, 2, frame))
    for t, tq, pw in zip(load_ticks, load_torque, load_power):
        keyed.append((int(t), 3, LoadSample(ticks=int(t), torque=float(tq), power=float(pw))))
    if edge2_ticks is not None:
        for i in range(0, edge2_ticks.shape[0], teeth2_per_batch):
            b = edge2_ticks[i:i + teeth2_per_batch]
            keyed.append((int(b[-1]), 4, FreeEndToothBatch(ticks=b.copy())))
    return keyed
