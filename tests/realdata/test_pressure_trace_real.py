"""The pressure-trace plausibility check (core.monitor.checks.pressure_trace, design note 144) on measured traces:
none of them is flagged. TU/e 4GB10 (every group14 file: fired at three loads, fired -> motored, motored
coast-downs; noisy, pegged per cycle by the DAQ reader) through the pipeline's assembler, and PoliTo's
cylinder-1 trace on the 0.1-deg grid of its file. Neither was used to set a threshold."""

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.checks.pressure_trace import (
    PressureTraceConfig,
    PressureTraceState,
    check_traces,
    failures,
    trace_features,
)
from frictionwatch.drivers.daq.raw import daq_to_records
from frictionwatch.service.pipeline import assembled_cycles

from tests.realdata.test_polito_pressure import load_trace

CFG = PressureTraceConfig()


def test_tue_traces_are_not_flagged(realdata):
    spec = load_engine("tue-4gb10")
    files = sorted((realdata / "tue-4gb10-si-encoder-pressure").glob("group14_*.txt.gz"))
    assert len(files) == 19
    seen = 0
    for path in files:
        info, records = daq_to_records(path)
        cycles, _ = assembled_cycles(spec, info, records)
        state = PressureTraceState.empty(spec.n_cyl)
        for c in cycles:
            state, _, flags, refused = check_traces(CFG, state, c.pressure, c.grid, spec.firing_angles)
            assert flags == () and not refused, (path.name, c.index, flags)
            seen += 1
    assert seen >= 160  # 165 complete cycles in the 19 files


def test_polito_trace_is_not_flagged(realdata):
    grid, p = load_trace(realdata)
    feat = trace_features(p[None, :], grid, np.zeros(1), CFG.flat_tol)
    assert failures(CFG, feat).tolist() == [-1]
