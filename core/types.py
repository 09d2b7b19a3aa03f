"""Plain typed values that cross package boundaries (design.md §1: each arrow is a dataclass of numpy arrays).

Stream records (what a driver yields, in acquisition order, time in integer timer ticks):

- ``ToothBatch``    rising-edge times of the crank wheel teeth
- ``FreeEndToothBatch`` rising-edge times of a second wheel's teeth (at the free end of the crankshaft), same clock
- ``CamBatch``      edges of the cam / phase sensor (one per 720 deg)
- ``PressureBlock`` equally spaced samples of one cylinder's pressure
- ``PressureFrame`` equally spaced samples of several cylinders taken together on one clock (an indicating system
  samples all its channels at once); equivalent to one ``PressureBlock`` per row
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
class FreeEndToothBatch:
    """Rising edges of the second wheel's sensor (``AcquisitionInfo.second_wheel``): int64 ticks, strictly increasing,
    on the same timer clock as ``ToothBatch``."""

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
class PressureFrame:
    """``values[r]`` [Pa, absolute] of cylinder ``cylinders[r]`` (1-based, distinct), sample i of every row at
    ``t0_ticks + i*period_ticks``: the channels of one indicating system, sampled together.

    Row r carries exactly what ``PressureBlock(cylinders[r], t0_ticks, period_ticks, values[r])`` would.
    """

    cylinders: tuple[int, ...]
    t0_ticks: int
    period_ticks: float
    values: np.ndarray  # float64 (k, n), k = len(cylinders), Pa absolute; NaN marks a saturated / invalid sample


@dataclass(frozen=True)
class LoadSample:
    """Load reading at ``ticks``: brake/generator shaft torque [N m] and electrical power [W] (NaN if unknown)."""

    ticks: int
    torque: float
    power: float


StreamRecord = ToothBatch | CamBatch | PressureBlock | PressureFrame | LoadSample | FreeEndToothBatch


@dataclass(frozen=True)
class WheelInfo:
    """A tooth wheel as the acquisition states it: tooth positions including missing ones, missing teeth (the gap),
    and the crank angle [deg] (cylinder-1 firing TDC = 0, at the wheel's own node) of the first edge after the gap."""

    teeth: int
    missing: int
    first_tooth_deg: float


@dataclass(frozen=True)
class AcquisitionInfo:
    """What a log or live session states about its sensors (never assumed from the engine preset)."""

    tick_hz: float
    wheel_teeth: int  # tooth positions including missing ones
    wheel_missing: int
    first_tooth_deg: float  # crank angle (cyl-1 firing TDC = 0) of the first edge after the gap
    cam_deg: float | None = None  # crank angle of the cam edge, None if no cam signal
    pressure_cylinders: tuple[int, ...] = ()
    second_wheel: WheelInfo | None = None  # the free-end wheel (FreeEndToothBatch), None if there is none


@dataclass(frozen=True)
class WheelTeeth:
    """One cycle's edges of the second wheel, cut as ``Cycle``'s own (the same bracketing of [0, 4 pi], in that
    wheel's nominal angle): ``ticks`` (m,) int64, ``angle`` (m,) rad nominal (first_tooth_deg + j 360/N, unwrapped),
    ``index`` (m,) int64 tooth index on that wheel (0 = first after its gap), ``teeth`` its tooth positions
    (missing ones included: the index runs modulo it)."""

    ticks: np.ndarray
    angle: np.ndarray
    index: np.ndarray
    teeth: int


@dataclass(frozen=True)
class Cycle:
    """One complete 720 deg engine cycle: crank angle theta in [0, 4 pi] of cylinder 1's convention, where
    theta = 0 and theta = 4 pi are cylinder 1's firing TDC at the start of this cycle and of the next one.

    The tooth edges bracket that span: from the last edge at or before theta = 0 through the first edge at or after
    theta = 4 pi, so tooth_angle[0] <= 0 < tooth_angle[1] and tooth_angle[-2] < 4 pi <= tooth_angle[-1]. An edge
    exactly on 0 (or 4 pi) is the first (or last) one. Next to the missing-tooth gap the bracketing edge can lie
    up to k+1 pitches outside. Consecutive cycles share their boundary edge(s).

    index            running cycle number of the stream (skipped cycles use up their number)
    tooth_ticks      (m,) int64: edge times [timer ticks at ``tick_hz``]
    tooth_angle      (m,) float64 rad: nominal crank angle of each edge (cyl-1 convention, unwrapped, increasing;
                     nominal = first_tooth_deg + j 360/N, without tooth-spacing error)
    tooth_index      (m,) int64: index of each edge on the wheel (0 = first after the gap), for spacing learning
    grid             (n,) float64 rad: uniform grid 4 pi i / n, i = 0..n-1 (cyl-1 angle, [0, 4 pi))
    pressure         (z, n) float64 Pa absolute on ``grid`` for every cylinder (row k-1 = cylinder k; NaN rows for
                     cylinders without a sensor), resampled through the monotone tooth angle -> time map
    load_torque      mean brake/generator torque over the cycle [N m] (NaN if not measured)
    load_power       mean electrical power [W] (NaN if not measured)
    load_early       the torque's mean under the weight 2 (1 - u), u the cycle's time fraction, and
    load_late        under 2 u [N m] (both load_torque for a constant load): the two halves of the transient
                     balance's triangle (drivers.assembly.cycle_parts.load_mean; NaN: not given, the balance then
                     takes load_torque)
    phase_source     how the 4-stroke phase was found: 'cam' or 'pressure' (physics.md §14.5)
    flags            notes that do not void the cycle, e.g. 'phase_unchecked', 'no_cam_edge'
    wheel2           the second wheel's edges of this cycle (``WheelTeeth``), None without a second wheel or when
                     its edges do not cover the cycle (then flag 'no_second_wheel')
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
    wheel2: WheelTeeth | None = None
    load_early: float = float("nan")
    load_late: float = float("nan")

    @property
    def t_start(self) -> float:
        return float(self.tooth_ticks[0]) / self.tick_hz

    @property
    def duration(self) -> float:
        return float(self.tooth_ticks[-1] - self.tooth_ticks[0]) / self.tick_hz

    @property
    def mean_omega(self) -> float:
        """The crank's mean speed over the cycle's tooth span [rad/s] (NaN on a span of no time)."""
        span = self.duration
        return float(self.tooth_angle[-1] - self.tooth_angle[0]) / span if span > 0 else float("nan")
