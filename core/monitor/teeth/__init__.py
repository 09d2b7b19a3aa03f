"""Step 1 of a cycle: the flywheel's motion from the raw tooth times.

    tooth_fit.py     fit_cycle_teeth: one cycle's tooth edges -> FlywheelMotion, with on-line tooth-spacing learning;
                     fit_second_wheel: a second (free-end) wheel's own speed and tooth-spacing learning, the same fit
    flywheel.py      the Fourier series in time fitted to tooth times; the ToothLearner   (+ flywheel_kernels.py)
"""
