"""The per-cycle monitor: ``state, result = process_cycle(model, state, cycle)`` (design.md §4), in the order a cycle
walks through it.

    monitor.py            orchestration only: initial_state, process_cycle, CycleRejected
    state.py              MonitorConfig (hyper-parameters) and MonitorState (everything carried between cycles)
    tooth_fit.py          step 1: the flywheel fit of one cycle's tooth edges, with on-line tooth-spacing learning
      flywheel.py           Fourier series in time fitted to raw tooth times; the tooth learner   (+ _kernels)
    harmonic_balance.py   steps 2-3: torques on the time grid and the chain's response, affine in the coefficients
      excitation.py         the cycle's torques and the model's loss-term basis (core.model.terms)  (+ _kernels)
      balance_pass_kernel.py, harmonic_balance_kernels.py   one pass: samples, FFT, chain, design rows
    identification.py     steps 4-5: noise model, accumulation, Eq. 6 shares, posteriors, reported estimates
      identify.py           ParameterLayout (which coefficients share a scale) and the bounded solve
      noise_model.py, accumulate.py, sharing.py, priors.py, estimate.py   (+ their _kernels)
      posterior_kernels.py, spd_kernels.py   the bounded MAP estimate and its posterior on small SPD systems
    condition.py          engine-condition flags per cycle (blow-by, ring wear, model misfit) from sibling windows,
      change.py             and the CUSUM change detector that discounts the accumulated equations once
      ring_pressure.py      the pressure ring indicators of every cylinder (compression vs siblings, polytropic
                            exponents, expansion deficit) for service.alerts
    cycle_report.py       the typed per-cycle result (results.py): traces, measured vs model speed, residuals
    figure_status.py      what each friction figure is: measured, share, prior, unresolved or withheld
    run_summary.py        over a run: the window an estimate stands for, flags per window, run means
    speed.py, speed_spacing.py, speed_stream.py   the classic instantaneous-speed route (tooth speed, spacing
                          learning, zero-phase filtering) for display, coast-downs and the discrepancy work
    coastdown.py          coast-down numerics: inertia and friction against speed
"""

from frictionwatch.core.monitor.monitor import CycleRejected, default_max_order, initial_state, process_cycle
from frictionwatch.core.monitor.results import CycleResult, FrictionEstimate
from frictionwatch.core.monitor.state import MonitorConfig, MonitorState

__all__ = ["CycleRejected", "CycleResult", "FrictionEstimate", "MonitorConfig", "MonitorState", "default_max_order",
           "initial_state", "process_cycle"]
