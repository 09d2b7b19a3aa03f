"""The per-cycle monitor: ``state, result = process_cycle(model, state, cycle)`` (design.md §4), its rooms in the
order a cycle walks through them.

    monitor.py     orchestration only: initial_state, process_cycle, CycleRejected
    state.py       MonitorConfig (hyper-parameters) and MonitorState (everything carried between cycles)
    teeth/         step 1: the flywheel's motion from the raw tooth times, with on-line tooth-spacing learning
    balance/       steps 2-4: torques on the time grid, the chain's response, the transient (kinetic-energy) term,
                   coast-down numerics
    identify/      step 5: noise model, accumulation with forgetting, shares, priors, the posterior and its sigmas
    checks/        per-cycle checks: speed-based sensor health, engine condition, change detection, ring indicators
    report/        the typed results, the per-cycle report, what each figure is, run summaries
    calibration/   commissioning (TDC, gain, J from the engine's own data) and the running calibration watches
"""

from frictionwatch.core.monitor.monitor import CycleRejected, default_max_order, initial_state, process_cycle
from frictionwatch.core.monitor.pipeline import CycleOutcome, CyclePipeline, run_cycles
from frictionwatch.core.monitor.report.results import CycleResult, FrictionEstimate
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState

__all__ = ["CycleOutcome", "CyclePipeline", "CycleRejected", "CycleResult", "FrictionEstimate", "MonitorConfig",
           "MonitorState", "default_max_order", "initial_state", "process_cycle", "run_cycles"]
