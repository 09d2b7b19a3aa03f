"""The time-domain plant simulator, built from an EngineModel (core.model): what the monitor is tested against.

    simulate.py         simulate(model or spec, rpm, load, cycles, seed) -> SimResult (stream records + truth);
                        start_simulation(...) -> Simulation, the same run streamed (memory flat in cycles)
    sim_stream.py       Simulation.chunks(): the run a few cycles at a time as SimChunk (records, truth entries)
    plant.py            the RK4 kernel over the torsional chain, each throw's J(theta) and the model's loss terms
    plant_setup.py      the plant's arrays from the model's drive train and term library
    sim_run.py          runs the kernel chunk by chunk, switches load laws, hands over its events
    sim_records.py      the events -> stream records in arrival order, chunk by chunk (sensor noise, batching)
    sim_truth.py        ground truth from the plant's cycle-boundary integrals, cycle by cycle with running sums
    sensors.py          tooth wheel, timer, cam, pressure ADC and load sensor models
    operating_point.py  quasi-static operating point (fuel for a load, leak sizing)

It integrates in the time domain on purpose: the monitor's harmonic balance must not be tested against itself.


    from frictionwatch.core.plant.simulate import simulate

(``simulate`` is not re-exported here: the function would shadow its module, which tests patch.)
"""

from frictionwatch.core.plant.simulate import SimResult

__all__ = ["SimResult"]
