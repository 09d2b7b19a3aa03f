"""The discrepancy workflow (issue 18): find where the model and the measurement disagree, name the missing effect,
add it to the model, show the gap shrink. Pure numerics over assembled cycles; the CLI and the report are in
service/ (cmd_discrepancy.py, discrepancy_report.py).

    view.py        what the monitor makes of a model's effects (pressure corrections, chain, terms, coefficients)
    residuals.py   the monitor run with a model's view: per-cycle speed-residual harmonics and balance residual
    features.py    Find: the coherent residual by order, crank angle, cylinder, trend, channel; the gap metric
    candidates.py  Name: the candidate library (an effect, its cylinder, its free parameters)
    fit.py         finite-difference sensitivities, Gauss-Newton and a chord step on a training window
    workflow.py    Add: the loop (fit all, confirm the best on held-out cycles, add while significant)
    discovery.py   what it found: the options, each step, the outcome and its JSON

    found = discover(model, cycles)      # found.model, found.to_json()
"""

from frictionwatch.core.discrepancy.candidates import Candidate, candidate_library
from frictionwatch.core.discrepancy.discovery import METRIC, Discovery, Options
from frictionwatch.core.discrepancy.workflow import discover

__all__ = ["METRIC", "Candidate", "Discovery", "Options", "candidate_library", "discover"]
