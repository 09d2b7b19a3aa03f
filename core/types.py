"""Plain typed values that cross package boundaries (design.md §1: each arrow is a dataclass of numpy arrays).

Stream records (what a driver yields, in acquisition order, time in integer timer ticks):

- ``ToothBatch``    rising-edge times of the crank wheel teeth
- ``CamBatch``      edges of the cam / phase sensor (one per 720 deg)
- ``PressureBlock`` equally spaced samples of one cylinder's pressure
- ``LoadSample``    generator / brake load readings

Then ``Cycle`` (one assembled 720 deg engine cycle, drivers/cycles.py) feeds the core.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class ToothBatch:
    """Rising edges of the crank-wheel sensor. ``ticks`` int64, strictly increasing, timer clock ``tick_hz``."""

    ticks: np.ndarray


@dataclass(frozen=True)
class CamBatch:
    """Cam / phase edges (one per cycle), int64 ticks."""

    ticks: np.ndarray


@dataclass(frozen=True)
class PressureBlock:
    """``values`` [Pa, absolute] of cylinder ``cylinder`` (1-based), sample i at ``t0_ticks + i*period_ticks``.

    ``period_ticks`` is a float so non-integer sample periods stay exact over a block; ``t0_ticks`` is an int.
    """

    cylinder: int
    t0_ticks: int
    period_ticks: float
    values: np.ndarray  # float64 (n,), Pa absolute; NaN marks a saturated / invalid sample


@dataclass(frozen=True)
class LoadSample:
    """Load reading at ``ticks``: brake/generator shaft torque [N m] and electrical power [W] (NaN if unknown)."""

    ticks: int
    torque: float
    power: float


StreamRecord = ToothBatch | CamBatch | PressureBlock | LoadSample


@dataclass(frozen=True)
class AcquisitionInfo:
    """What a log or live session states about its sensors (never assumed from the engine preset)."""

    tick_hz: float
    wheel_teeth: int  # tooth positions including missing ones
    wheel_missing: int
    first_tooth_deg: float  # crank angle (cyl-1 firing TDC = 0) of the first edge after the gap
    cam_deg: float | None = None  # crank angle of the cam edge, None if no cam signal
    pressure_cylinders: tuple[int, ...] = ()


@dataclass(frozen=True)
class Cycle:
    """One complete 720 deg cycle, starting at the first tooth at or after cylinder-1 firing TDC minus nothing:
    the cycle spans crank angle [theta0, theta0 + 4 pi) of cylinder 1's convention.

    tooth_ticks      (m+1,) int64: edge times of every tooth edge in the cycle plus the closing edge of the next
    tooth_angle      (m+1,) float64 rad: nominal crank angle of each edge (cyl-1 convention, unwrapped, increasing)
    tooth_index      (m+1,) int64: index of each edge on the wheel (0 = first after the gap), for spacing learning
    pressure         (z, n) float64 Pa absolute, on the uniform grid ``grid`` [rad, cyl-1 angle, 0..4pi)
    load_torque      mean brake/generator torque over the cycle [N m] (NaN if not measured)
    load_power       mean electrical power [W] (NaN if not measured)
    """

    index: int
    tick_hz: float
    tooth_ticks: np.ndarray
    tooth_angle: np.ndarray
    tooth_index: np.ndarray
    grid: np.ndarray
    pressure: np.ndarray
    load_torque: float
    load_power: float
    phase_source: str = "cam"  # 'cam' or 'pressure'
    flags: tuple[str, ...] = field(default=())

    @property
    def t_start(self) -> float:
        return float(self.tooth_ticks[0]) / self.tick_hz

    @property
    def duration(self) -> float:
        return float(self.tooth_ticks[-1] - self.tooth_ticks[0]) / self.tick_hz
