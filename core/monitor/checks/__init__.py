"""Per-cycle checks on the result: are the sensors and the engine what the model assumes?

    pressure_trace.py    is each channel a cylinder's pressure at all (dead, clipped, negated, spikes, out of phase)?
                         a stage before the view (core.monitor.pipeline.PressureTrace), kernels beside their references
    sensor_health.py     the speed-based sensor checks (TDC, gain) and their corrections   (evidence: sensor_evidence.py)
    condition.py         engine-condition flags from sibling windows (blow-by, ring wear, model misfit)
    change.py            the CUSUM change detector that discounts the accumulated equations once
    ring_pressure.py     the pressure ring indicators of every cylinder, for service.alerts
    pressure_statistics.py  the alert engine's per-cycle statistics of those indicators as one kernel (its numpy
                         reference: service/alert_interface.py, strung together by service/alerts.py)
The running calibration watches (TDC, gain, pegging against the commissioned state) are in ../calibration/.
"""
