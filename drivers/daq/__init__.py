"""Raw DAQ voltage tables -> stream records, as a live source would give them (offline import).

    raw           read a DAQ table, find the teeth, calibrate the pressure: ``process_daq``, ``daq_to_records``;
                  ``trace_wheel``: the wheel read from the file's own edges, a stated one checked against it
    teeth         tooth edges from a sampled analog wheel signal, missing-tooth sync, ``wheel_pattern``
    pressure      crank angle of every sample, 4-stroke phase, pegging and gain of the pressure volts
    angle_traces  one cylinder's pressure cycles from bench exports the monitor cannot run on (crank-angle CSV,
                  gapless encoder + TDC marker tables): ``read_angle_csv``, ``read_encoder_table``
    xlsx          one sheet of an .xlsx workbook as header + float table (standard library only)
"""

from frictionwatch.drivers.daq.pressure import CycleCalibration, apply_calibration, calibrate_cycles
from frictionwatch.drivers.daq.raw import DaqResult, DaqTrace, daq_to_records, detect_teeth, process_daq, read_daq_table
from frictionwatch.drivers.daq.teeth import ToothEdges

__all__ = ["CycleCalibration", "DaqResult", "DaqTrace", "ToothEdges", "apply_calibration", "calibrate_cycles",
           "daq_to_records", "detect_teeth", "process_daq", "read_daq_table"]
