"""Cycle assembly: stream records of one engine -> one typed ``Cycle`` per 720 deg (design.md §1; physics.md §14).

    cycles            ``CycleAssembler``: the pipeline from records to cycles
    two_wheels        ``TwoWheelAssembler``: the same, each cycle carrying a second (free-end) wheel's edges
    wheel2_cut        ``SecondWheelCut``: the second wheel's edges synced on their own and cut into a cycle
    cycle_sync        ``EpochSync``: tracker events -> segments and epochs, the phase of an epoch
    cycle_phase       the 4-stroke phase: cam edges placed on the wheel, or one cylinder's pressure
    cycle_parts       wheel positions, segments, epochs, pressure and load of a cycle
    cycle_kernels     one numba call for the edges and grid times of a cycle window
    wheel_sync        ``WheelTracker``: missing-tooth sync of a crank wheel (a numba state machine)
    resample          monotone cubic t(theta) and linear interpolation onto the grid
    engine_buffers    ``EngineBuffers``: the rings of one engine, filing each record
    ringbuffer        ``RingBuffer``: bounded, mirrored ring of parallel columns, and its search / write kernels
    pressure_ring     ``PressureGroup``: cylinders sampled on one clock share a time column
    pressure_kernels  a pressure group's rows at a cycle's grid times in one numba call
    frame_store       ``FrameGroup``: multi-cylinder frames kept by reference instead of copied into a ring
    frame_kernels     the kernels of a ``FrameGroup`` (searches, times, values, rows on the grid)
"""

from frictionwatch.drivers.assembly.cycles import CycleAssembler
from frictionwatch.drivers.assembly.engine_buffers import EngineBuffers
from frictionwatch.drivers.assembly.frame_store import FrameChannel, FrameGroup
from frictionwatch.drivers.assembly.pressure_ring import PressureChannel, PressureGroup, frame_blocks
from frictionwatch.drivers.assembly.resample import interp_checked, interp_sorted, pchip_eval
from frictionwatch.drivers.assembly.ringbuffer import RingBuffer
from frictionwatch.drivers.assembly.two_wheels import TwoWheelAssembler
from frictionwatch.drivers.assembly.wheel_sync import WheelTracker

__all__ = ["CycleAssembler", "EngineBuffers", "FrameChannel", "FrameGroup", "PressureChannel", "PressureGroup",
           "RingBuffer", "TwoWheelAssembler", "WheelTracker", "frame_blocks", "interp_checked", "interp_sorted", "pchip_eval"]
