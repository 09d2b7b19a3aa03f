"""The shaft line's own error in a fitted parameter: the model-error floors no cycle count removes (the chain's
stiffness and damping, tuned on healthy logs), the chain stiffness's carried through the line's lowest mode to any
other parameter that moves it (the flywheel's inertia), a one-node line's own, and the bias that grows with a fitted
stiffness's distance from the record's (core.discrepancy.fit uses them in each fit's sigma; design notes 50, 103,
109)."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.discrepancy.candidates import Candidate
from frictionwatch.core.discrepancy.tuned import tuned_constants

_TUNED = tuned_constants()
# the 1-sigma error of the monitor's shaft line against the engine's, in the chain candidate's scales: near a
# resonance of the line (k9k 1800 rpm, order 2) a healthy log read stiffness 0.993-1.006 at sigma ~0.001 and named it
# (design note 50). Tuned on healthy logs none of the matrix's (bench/calibrate_chain_floor.py --write;
# core/discrepancy/tuned.json: its provenance); 0 until that has run
CHAIN_FLOOR = {("chain_mismatch", p): _TUNED[name].value if name in _TUNED else 0.0
               for p, name in (("stiffness_scale", "CHAIN_FLOOR_STIFFNESS"),
                               ("damping_scale", "CHAIN_FLOOR_DAMPING"))}
# the shaft line's bias in a fitted stiffness, relative to the fitted excess |stiffness_scale - 1|: the monitor's line
# reads a stiffer plant's low (k9k, the chain 50 % stiffer: 1.404-1.458 at sigma 0.013-0.021, the fit converged;
# design note 101), an error that grows with the distance from the record's line, which CHAIN_FLOOR (a healthy log's,
# near 1) does not carry. Tuned on chain logs none of the matrix's (bench/calibrate_chain_bias.py --write;
# core/discrepancy/tuned.json: its provenance; design note 103); 0 until that has run
CHAIN_STIFFNESS_REL = _TUNED["CHAIN_STIFFNESS_REL"].value if "CHAIN_STIFFNESS_REL" in _TUNED else 0.0
CHAIN_REL = {("chain_mismatch", "stiffness_scale"): CHAIN_STIFFNESS_REL}
# the same error carried to any other parameter that moves the line's lowest mode (Candidate.mode_share, |d ln
# omega^2 / d x|): the chain's stiffness scale moves omega^2 one for one (every section scaled), so CHAIN_FLOOR's
# stiffness is the line's own error in ln omega^2, and near that mode a fit of the flywheel's inertia reads it as
# CHAIN_FLOOR_STIFFNESS / share (k9k 0.0078 / 0.441 = 0.0177, maruti / 0.519 = 0.0150). Nothing tuned here: tuned on
# CHAIN_FLOOR's healthy logs (k9k 1700-2800 rpm, maruti 2000 and 3000 rpm, seeds 1, 4, 8, 21-24); tested on the
# healthy k9k 1800/0.6 seed 7 log (tests/core/test_discrepancy_workflow.py) and the matrix's seeds 6, 7, 10
# (design note 109)
MODE_SHARE_ZERO = 1e-6  # a share below this is rounding (a friction, a damping: exactly 0), not a mode moved
# a one-node line has no mode to carry it through: there the flywheel node is the whole crank, and its inertia reads
# the model's own error in the total inertia (deutz 3000/0.9 seed 5, healthy: 0.9975 +- 0.0012). Tuned on healthy
# deutz logs of seeds 1-5 at points none of the matrix's nor the tests' (bench/calibrate_inertia_floor.py --write;
# tuned.json: its provenance); tested on that seed-5 log and the matrix's deutz seeds 6, 7, 10; 0 until it has run
ONE_NODE_FLOOR = {("flywheel_inertia", "inertia_scale"): _TUNED["INERTIA_FLOOR_ONE_NODE"].value
                  if "INERTIA_FLOOR_ONE_NODE" in _TUNED else 0.0}


def parameter_floor(cand: Candidate, x: np.ndarray | None = None) -> np.ndarray:
    """(p,) the model's own 1-sigma error in each of the candidate's parameters that no cycle count removes
    (CHAIN_FLOOR; for another parameter that moves the line's lowest mode, the chain stiffness's carried through
    it, CHAIN_FLOOR_STIFFNESS / Candidate.mode_share; on a one-node line ONE_NODE_FLOOR; 0 where none is known), and
    at a fitted ``x`` (p,) the part that grows with its distance from the no-effect value (CHAIN_REL x |x - x0|: the
    shaft line's bias in a stiffness far from the record's), in quadrature."""
    share = cand.mode_share or (None,) * len(cand.params)  # none: a one-node line (or a cylinder's effect)
    floor = np.array([_own_floor(cand.effect, p, s) for p, s in zip(cand.params, share)], dtype=np.float64)
    if x is None:
        return floor
    rel = np.array([CHAIN_REL.get((cand.effect, p), 0.0) for p in cand.params], dtype=np.float64)
    return np.hypot(floor, rel * np.abs(np.asarray(x, dtype=np.float64) - np.asarray(cand.x0, dtype=np.float64)))



def _own_floor(effect: str, param: str, mode_share: float | None) -> float:
    """One parameter's floor (``parameter_floor``): the chain's own where tuned; else, where the parameter moves the
    line's lowest mode, the chain stiffness's carried through that share; on a line without modes (``mode_share``
    None) the one-node floor; else 0."""
    if (effect, param) in CHAIN_FLOOR:
        return CHAIN_FLOOR[(effect, param)]
    if mode_share is None:
        return ONE_NODE_FLOOR.get((effect, param), 0.0)
    if mode_share > MODE_SHARE_ZERO:
        return CHAIN_FLOOR.get(("chain_mismatch", "stiffness_scale"), 0.0) / mode_share
    return 0.0


__all__ = ["CHAIN_FLOOR", "CHAIN_REL", "CHAIN_STIFFNESS_REL", "MODE_SHARE_ZERO", "ONE_NODE_FLOOR", "parameter_floor"]
