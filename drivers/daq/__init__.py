"""Raw DAQ voltage tables -> stream records, as a live source would give them (offline import).

    raw       read a DAQ table, find the teeth, calibrate the pressure: ``process_daq``, ``daq_to_records``
    teeth     tooth edges from a sampled analog wheel signal, and missing-tooth sync
    pressure  crank angle of every sample, 4-stroke phase, pegging and gain of the pressure volts
"""

from frictionwatch.drivers.daq.pressure import CycleCalibration, apply_calibration, calibrate_cycles
from frictionwatch.drivers.daq.raw import DaqResult, DaqTrace, daq_to_records, detect_teeth, process_daq, read_daq_table
from frictionwatch.drivers.daq.teeth import ToothEdges

__all__ = ["CycleCalibration", "DaqResult", "DaqTrace", "ToothEdges", "apply_calibration", "calibrate_cycles",
           "daq_to_records", "detect_teeth", "process_daq", "read_daq_table"]
