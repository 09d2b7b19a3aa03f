"""Steps 2-4 of a cycle: the torques on the cycle's time grid, their response through the torsional chain, and the
transient (kinetic-energy) term of the mean balance.

    excitation.py          gas and reciprocating torque from the measured pressure; the loss-term basis
    harmonic_balance.py    the chain's response, affine in the loss coefficients; the operating point
      balance_pass_kernel.py, harmonic_balance_kernels.py   one pass: samples, FFT, chain, design rows
    transient.py           d/dt(1/2 J w^2)/w from measured mid-cycle speeds; coast-down segments
    coastdown.py           coast-down numerics: inertia and friction against speed
"""
