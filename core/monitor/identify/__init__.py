"""Step 5 of a cycle: the whitened equations, their accumulation with forgetting, and the friction posterior. Files
by what a cycle does with the state, in the order it does it (design note 82; the cycle's mean balance, which comes
first, is in balance/mean_balance.py, design note 87):

    identification.py  identify_cycle: the stage's orchestration
    noise_model.py     the residual statistics, the per-cycle noise model and whitening (the free end's rows too)
    accumulate.py      one cycle's normal equations folded into the accumulated information (+ their kernels)
    parameters.py      ParameterLayout (which coefficients share a scale), the priors, Eq. 6 sharing
    posterior.py       the posterior (MAP estimate and covariances) from the information and the priors
      bounded_solve.py the bounded solve (numba kernel, NNLS reference) the posterior falls back on
      spd.py           small SPD factors and inverses by LAPACK, their scipy references
    estimate.py        reported estimates with honest sigmas: model-error floor, calibration (+ their kernels)
    pull_check.py      the smoothed figures' pull check (apart: the monitor's state imports its settings)
"""
