"""Step 5 of a cycle: the whitened equations, their accumulation with forgetting, and the friction posterior.

    identification.py   identify_cycle and the mean balance (grid geometry, cycle energy, transient balance)
                                                                                     (+ energy_kernels.py)
    layout.py           ParameterLayout (which coefficients share a scale) and the bounded solve
    noise_model.py      the per-cycle noise model and whitening
    accumulate.py       the accumulated normal equations and the posterior             (+ accumulate_kernels.py)
      posterior_kernels.py, spd_kernels.py   the bounded MAP estimate on small SPD systems (LAPACK reference beside)
    sharing.py          Eq. 6: a mean loss shared among cylinders
    priors.py           the priors of the loss coefficients
    estimate.py         reported estimates with honest sigmas: model-error floor, calibration  (+ estimate_kernels.py)
"""
