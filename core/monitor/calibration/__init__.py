"""Commissioning: what the monitor otherwise takes on trust, found from the engine's own data, each with its 1-sigma
and evidence (issue 25): every cylinder's TDC and pegging from its pressure (tdc.py), J and a friction-vs-speed law
from coast-downs (inertia.py). `frictionwatch commission` writes the results into the model's calibration section
(core.model.calibration), which analyze, serve, reanalyze and discrepancy read."""
