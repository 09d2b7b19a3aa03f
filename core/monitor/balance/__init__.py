"""Steps 2-4 of a cycle: the torques on the cycle's time grid, their response through the torsional chain, and the
transient (kinetic-energy) term of the mean balance.

    excitation.py          gas and reciprocating torque from the measured pressure; the loss-term basis
    harmonic_balance.py    the chain's response, affine in the loss coefficients; the operating point
      harmonic_balance_kernels.py   one pass's first half: samples, pressure, gas and known torques (the second
                                    half, pass_rows: FFT, chain, design rows, in harmonic_balance.py)
    mean_balance.py        the cycle's mean balance: grid geometry, cycle energy, the transient (kinetic) term of two
                           cycles, TDC sensitivity; across cycles, inertia and friction against speed
    coastdown.py           coast-down numerics: inertia and friction against speed
"""
