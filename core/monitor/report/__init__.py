"""What a cycle and a run report: the typed results and the words on each figure.

    results.py        CycleResult, FrictionEstimate (one FMEP = torque x 4 pi / V_d: core.model.engine.mep_per_torque)
    cycle_report.py   build_result: traces, measured vs model speed, residuals (+ their kernels)
    grid_rows.py      rows from the time grid onto the crank-angle grid (the traces, and a stored result's)
    figure_status.py  what each friction figure is: measured, share, prior, unresolved or withheld
    run_summary.py    over a run: the window an estimate stands for, flags per window, run means
"""
