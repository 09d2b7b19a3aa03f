"""Fit a candidate's parameters: finite-difference sensitivities of the whitened residual features, Gauss-Newton.

The model is nonlinear in most parameters and every evaluation is a monitor run, so the fit is linearised: one run
at the candidate's no-effect point (shared by all candidates: the current model), one per parameter at x0 + step,
and the Gauss-Newton step's predicted cost ranks the candidates (``linearise``); the best few are then evaluated
at that step and one chord step further (the same sensitivities, the new residual), the better kept (``refine``). The evaluations run on a short training window (``Evaluator``); the workflow confirms the
best few on the whole log and chooses on held-out cycles.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.discrepancy.candidates import Candidate
from frictionwatch.core.discrepancy.features import coherent_power, feature_floor
from frictionwatch.core.discrepancy.line_floor import (  # the shaft line's own error in a fit (re-exported)
    CHAIN_FLOOR,
    CHAIN_REL,
    CHAIN_STIFFNESS_REL,
    MODE_SHARE_ZERO,
    ONE_NODE_FLOOR,
    parameter_floor,
)
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.discrepancy.tuned import tuned_constants
from frictionwatch.core.model.effects import make_effect
from frictionwatch.core.model.engine_model import EngineModel

DAMPING = 1e-6  # Levenberg term relative to the largest diagonal of J'J: keeps a flat direction finite
# the relative error of a found effect's size: the effect as the model writes it is not the engine's (the simulator
# sizes an extra friction on its own quasi-static friction, the monitor on its basis means: ~1 % apart on deutz).
# Tuned on logs none of the matrix's as the smallest value that puts 90 % of the truths within 2 sigma
# (bench/discrepancy_sigma.py --write; core/discrepancy/tuned.json: its provenance); 0 until that has run
_TUNED = tuned_constants()
EFFECT_REL_ERROR = _TUNED["EFFECT_REL_ERROR"].value if "EFFECT_REL_ERROR" in _TUNED else 0.0


@dataclass(frozen=True)
class Trial:
    """A candidate fitted on the training window: x (p,) its parameters, sigma (p,) their 1-sigma, cost the whitened
    sum of squares there (``base_cost`` the current model's), evaluations the monitor runs it took."""

    candidate: Candidate
    x: np.ndarray
    sigma: np.ndarray
    cost: float
    base_cost: float
    evaluations: int

    @property
    def gain(self) -> float:
        """Fractional cost reduction on the training window."""
        return (self.base_cost - self.cost) / self.base_cost if self.base_cost > 0 else 0.0


class Evaluator:
    """Whitened residual vectors of models on one training window: ``run(model) -> Residuals`` (a monitor run),
    features from ``first`` cycle index on, whitened by ``scale``; ``floor`` (F,) the whitened model-error floor of
    each feature (core.discrepancy.features.feature_floor; zeros: the statistical sigma alone)."""

    def __init__(self, run: Callable[[EngineModel], Residuals], scale: np.ndarray, first: int,
                 floor: np.ndarray | None = None):
        self._run, self.scale, self.first = run, scale, first
        self.floor = np.zeros_like(scale) if floor is None else floor
        self.calls = 0

    def vector(self, model: EngineModel) -> tuple[np.ndarray, np.ndarray]:
        """(cycle indices, whitened features (N, F)) of ``model``."""
        self.calls += 1
        res = self._run(model)
        keep = res.index >= self.first
        return res.index[keep], res.features()[keep] / self.scale


def _aligned(ia: np.ndarray, a: np.ndarray, ib: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows of a and b of the cycles both analysed (a trial can lose a cycle the base kept, or the reverse)."""
    if ia.shape == ib.shape and np.array_equal(ia, ib):
        return a, b
    common = np.intersect1d(ia, ib)
    return a[np.isin(ia, common)], b[np.isin(ib, common)]


@dataclass(frozen=True)
class Linearised:
    """A candidate's sensitivities on the training window: x0, jac (N F, p) of the whitened residual, r0 the base
    residual on the same cycles (idx), and the Gauss-Newton step's predicted cost."""

    candidate: Candidate
    idx: np.ndarray
    r0: np.ndarray
    jac: np.ndarray
    x_gn: np.ndarray
    predicted: float
    base_cost: float


def linearise(cand: Candidate, model: EngineModel, ev: Evaluator, base: tuple[np.ndarray, np.ndarray]) -> Linearised:
    """One monitor run per parameter at x0 + step (a toggle: one run with it on; its cost is then exact)."""
    idx0, r0 = base
    base_cost = float(np.sum(r0**2))
    if cand.toggle:
        idx, r = ev.vector(cand.model_at(model, None))
        a, b = _aligned(idx0, r0, idx, r)  # on the cycles both analysed, scaled to the base's count
        cost = float(np.sum(b**2)) * base_cost / max(float(np.sum(a**2)), 1e-300)
        return Linearised(cand, idx0, r0.ravel(), np.zeros((r0.size, 0)), np.zeros(0), cost, base_cost)
    x0 = np.asarray(cand.x0, float)
    cols: list[np.ndarray] = []
    idx_common, r_base = idx0, r0
    for i, h in enumerate(cand.step):
        xi = x0.copy()
        xi[i] += h
        idx, r = ev.vector(cand.model_at(model, xi))
        common = np.intersect1d(idx_common, idx)
        cols = [c[np.isin(idx_common, common)] for c in cols]
        r_base = r_base[np.isin(idx_common, common)]
        cols.append((r[np.isin(idx, common)] - r_base) / h)
        idx_common = common
    jac = np.stack([c.ravel() for c in cols], axis=1)
    rb = r_base.ravel()
    x_gn = cand.clip(x0 - _solve(jac, rb))
    pred = rb + jac @ (x_gn - x0)
    return Linearised(cand, idx_common, rb, jac, x_gn, float(pred @ pred), base_cost)


def _solve(jac: np.ndarray, r: np.ndarray) -> np.ndarray:
    jtj = jac.T @ jac
    return np.linalg.solve(jtj + DAMPING * np.max(np.diag(jtj), initial=1e-300) * np.eye(jtj.shape[0]), jac.T @ r)


def parameter_sigma(jac: np.ndarray, n_cycles: int, cost: float, floor: np.ndarray,
                    residual: np.ndarray | None = None, size: np.ndarray | None = None,
                    own_floor: np.ndarray | None = None,
                    points: Sequence[tuple[np.ndarray, np.ndarray]] = ()) -> np.ndarray:
    """(p,) 1-sigma of the parameters fitted with ``jac`` (N F, p: cycle-major rows of whitened features) at the
    whitened sum of squares ``cost``: the statistical part, (J'J)^-1 inflated by the reduced chi^2 when above 1, and
    the model-error part, a coherent error in every cycle propagated through the same least-squares step:
    A (sum_n J_n)' diag(e^2) (sum_n J_n) A' with A = (J'J)^-1, e^2 = floor^2 (the healthy model's rms error, (F,))
    + the coherent power the fit leaves in ``residual`` (N F,) (a sandwich estimate: the found effect's own model
    is not the engine's either). The second part does not shrink with more cycles; without it the found
    parameters' sigma was 7-22x too small against the truth (issue 27). And the effect's own model error,
    EFFECT_REL_ERROR x ``size`` (p,), each parameter's distance from its no-effect value; and ``own_floor`` (p,),
    the model's own error in the parameter itself (parameter_floor: the shaft line's).
    Over several operating points (``points``: each point's cycle mask (N,) and its own whitened floor (F,), two or
    more) the model's error may be each point's own, apart from the others' (wrong by another amount, at another
    phase, at another speed and load): then the coherent part sums over the points, b_g = A (sum_{n in g} J_n)' with
    the point's floor and the coherent power the fit leaves there; the larger of that and the shared reading is
    taken. The shared reading alone let the points' sensitivities cancel and pooled the residual's power across
    phases (maruti 4000/0.8 <-> 1500/0.5 seed 2, a side-thrust skirt: 0.082, against 0.119 apart; design note 65)."""
    p = jac.shape[1]
    jtj = jac.T @ jac
    a = np.linalg.pinv(jtj + DAMPING * np.max(np.diag(jtj), initial=1e-300) * np.eye(p))
    stat = a * max(1.0, cost / max(jac.shape[0] - p, 1))
    j3 = jac.reshape(n_cycles, -1, p)
    r2 = None if residual is None else residual.reshape(n_cycles, -1)

    def coherent(shares) -> np.ndarray:  # each share: its cycles and its floor, its error apart from the others'
        out = np.zeros(p)
        for rows, share_floor in shares:
            e2 = share_floor**2 + (0.0 if r2 is None else np.maximum(coherent_power(r2[rows]), 0.0))
            b = a @ j3[rows].sum(axis=0).T  # (p, F): the share's coherent feature error -> parameter shift
            out = out + np.sum(b**2 * e2, axis=1)
        return out

    # one error in every cycle; over several points also each point's own, and the larger of the two: whether the
    # model's errors at two points are one or apart is not known (deutz's single cylinder, where the points'
    # sensitivities agree, reads less apart than shared: 0.035 against 0.044 for s2's side thrust, truth 2.3 of it)
    model_error = coherent([(np.ones(n_cycles, dtype=bool), floor)])
    if len(points) >= 2:
        model_error = np.maximum(model_error, coherent(points))
    own = 0.0 if size is None else (EFFECT_REL_ERROR * np.asarray(size, dtype=np.float64)) ** 2
    own = own + (0.0 if own_floor is None else np.asarray(own_floor, dtype=np.float64) ** 2)
    return np.sqrt(np.diag(stat) + model_error + own)


SECANT_STEPS = 3  # monitor runs along the main parameter when the full linear step fails (module doc of refine)


def refine(lin: Linearised, model: EngineModel, ev: Evaluator) -> Trial:
    """Evaluate the Gauss-Newton point; where it lowers the cost take one chord step (same sensitivities, the new
    residual) and keep the better; where it does not (the model is too nonlinear for one step, e.g. a shaft line's
    stiffness near a resonance), fall back to the candidate's main parameter alone by secant steps (_along_main).
    Sigma from the sensitivities and the model-error floor (parameter_sigma)."""
    cand = lin.candidate
    calls = ev.calls
    if cand.toggle:
        return Trial(cand, np.zeros(0), np.zeros(0), lin.predicted, lin.base_cost, 0)
    x0 = np.asarray(cand.x0, float)
    best = (x0, float(lin.r0 @ lin.r0), lin.r0)
    r_gn = _evaluate(lin, model, ev, lin.x_gn)
    if r_gn is not None and float(r_gn @ r_gn) < best[1]:
        best = (lin.x_gn, float(r_gn @ r_gn), r_gn)
        x = cand.clip(lin.x_gn - _solve(lin.jac, r_gn))
        r = _evaluate(lin, model, ev, x)
        if r is not None and float(r @ r) < best[1]:
            best = (x, float(r @ r), r)
    elif r_gn is not None:
        best = _along_main(lin, model, ev, best, (lin.x_gn, r_gn) if len(x0) == 1 else None)
    jac = lin.jac
    if at_start(cand, best[0]):  # started at a declared start point and not moved from it: fit it from there
        best, jac = _from_start(lin, model, ev, best)
    best_x, best_cost, best_r = best
    sigma = parameter_sigma(jac, lin.idx.shape[0], best_cost, ev.floor, best_r, np.abs(best_x - x0),
                            parameter_floor(cand, best_x))
    scale = best_cost / max(float(lin.r0 @ lin.r0), 1e-300)  # costs on the base's cycle count
    return Trial(cand, best_x, sigma, scale * lin.base_cost, lin.base_cost, ev.calls - calls)


def _evaluate(lin: Linearised, model: EngineModel, ev: Evaluator, x: np.ndarray) -> np.ndarray | None:
    """The whitened residual at x on the linearisation's cycles (None where a cycle was lost or gained: only like is
    compared with like)."""
    idx, r = ev.vector(lin.candidate.model_at(model, x))
    return r.ravel() if np.array_equal(idx, lin.idx) else None


def _along_main(lin: Linearised, model: EngineModel, ev: Evaluator, best: tuple, tried: tuple | None) -> tuple:
    """Secant steps on the candidate's first parameter, the others at their no-effect values, from x0 (and the
    failed full step when it moved that parameter alone, ``tried``); SECANT_STEPS runs, stopping when a step makes
    the cost worse. Measured on maruti 1500 rpm with the shaft line 20 % softer (truth 0.8): the full step
    (stiffness 0.79, damping 1.85) raised the cost 69,600 -> 181,800; along the stiffness the steps go 0.934
    (28,900), 0.902 (18,800), 0.859 (8,260), and a fourth would reach 0.813 (1,820): the polish takes it on."""
    cand = lin.candidate
    x_a, r_a = best[0], lin.r0
    slope = lin.jac[:, 0]
    if tried is not None and tried[0][0] != x_a[0]:  # a step clipped back to x0 (a share at 0) gives no chord
        slope = (tried[1] - r_a) / (tried[0][0] - x_a[0])
        x_a, r_a = tried
    for _ in range(SECANT_STEPS):
        x = x_a.copy()
        x[0] -= (slope @ r_a) / max(float(slope @ slope), 1e-300)
        x = cand.clip(x)
        if x[0] == x_a[0]:
            break
        r = _evaluate(lin, model, ev, x)
        if r is None:
            break
        cost = float(r @ r)
        if cost >= float(r_a @ r_a):
            break
        if cost < best[1]:
            best = (x, cost, r)
        slope = (r - r_a) / (x[0] - x_a[0])
        x_a, r_a = x, r
    return best


def at_start(cand: Candidate, x: np.ndarray) -> bool:
    """Whether ``x`` is one of the candidate's declared start points (``Candidate.seeds``, clipped), every parameter
    exactly: a refinement that ends there has not fitted anything (design note 106)."""
    return any(np.array_equal(np.asarray(x, float), cand.clip(np.asarray(s, float))) for s in cand.seeds)


# Gauss-Newton iterations from a declared start point, each with the sensitivities taken there (p monitor runs) and
# its step halved until the cost falls (at most BACKTRACK halvings). The start points exist because the speed is far
# from linear in the parameter (a shaft line's stiffness across a resonance of the line): the chord step refine takes
# with the sensitivities at the no-effect point then points the wrong way, and the fit stayed at the start point
# (k9k 2000/0.5 seed 31, the chain 70 % stiffer: 0.75 named with the window cost 8,860, where 1.7 costs 806 and the
# start 4/3 lies on the slope down to it; design note 106). Not tuned: enough steps to cross from a start point to
# the optimum on the tuning logs of note 103, where the scan shows one valley each side of the resonance.
START_STEPS = 4
BACKTRACK = 3


def _from_start(lin: Linearised, model: EngineModel, ev: Evaluator, best: tuple) -> tuple[tuple, np.ndarray]:
    """Damped Gauss-Newton from ``best`` (x, cost, r) at a start point: returns the best point reached and the
    sensitivities (N F, p) at it (or at the last point they were taken; ``lin.jac`` when none could be)."""
    cand = lin.candidate
    x, cost, r = best
    jac = lin.jac
    for _ in range(START_STEPS):
        cols = []
        for i, h in enumerate(cand.step):
            xi = x.copy()
            xi[i] = xi[i] + h if xi[i] + h <= cand.hi[i] else xi[i] - h
            ri = _evaluate(lin, model, ev, xi)
            if ri is None:
                return (x, cost, r), jac
            cols.append((ri - r) / (xi[i] - x[i]))
        jac = np.stack(cols, axis=1)
        dx = -_solve(jac, r)
        for _ in range(BACKTRACK + 1):
            xn = cand.clip(x + dx)
            rn = None if np.array_equal(xn, x) else _evaluate(lin, model, ev, xn)
            if rn is not None and float(rn @ rn) < cost:
                break
            dx = dx / 2.0
        else:
            return (x, cost, r), jac
        x, cost, r = xn, float(rn @ rn), rn
    return (x, cost, r), jac


def polish(t: Trial, current: EngineModel, model: EngineModel, res: Residuals, full, train_of, scale: np.ndarray,
           floor: np.ndarray, held: Sequence[EngineModel] = ()) -> tuple[Trial, EngineModel, Residuals, int]:
    """One more Gauss-Newton step for the chosen candidate on all training cycles (the window was a short part of
    them): sensitivities from whole-log runs at x + step, kept if the training cost falls; sigma from them and the
    model-error floor (core.discrepancy.fit.parameter_sigma), and from each parameter the model holds at another
    channel's reading: ``held``, ``current`` with one such parameter moved by its sigma (a TDC held at the
    pressure's reading, pressure_tdc), one run each, its shift of the fit added in quadrature; likewise each fixed
    parameter of the candidate that declares its own sigma (``Candidate.fixed_sigma``). Returns
    the (possibly) new trial, model, its run and the monitor runs spent."""
    cand = t.candidate
    if cand.toggle:
        return t, model, res, 0
    train = train_of(res)
    r0 = (train.features() / scale).ravel()
    cols, runs = [], 0
    for i, h in enumerate(cand.step):
        xi = t.x.copy()
        xi[i] = xi[i] + h if xi[i] + h <= cand.hi[i] else xi[i] - h
        ri = train_of(full(cand.model_at(current, xi)))
        runs += 1
        if not np.array_equal(ri.index, train.index):
            return t, model, res, runs
        cols.append(((ri.features() / scale).ravel() - r0) / (xi[i] - t.x[i]))
    jac = np.stack(cols, axis=1)
    x_new = cand.clip(t.x - np.linalg.lstsq(jac, r0, rcond=None)[0])
    trial = replace(t, x=x_new)
    new_model = with_fit(current, trial)
    new_res = full(new_model)
    runs += 1
    new_train = train_of(new_res)
    if not np.array_equal(new_train.index, train.index):
        return t, model, res, runs
    r1 = (new_train.features() / scale).ravel()
    better = float(r1 @ r1) < float(r0 @ r0)
    cost = float(min(r1 @ r1, r0 @ r0))
    kept = trial if better else t
    sigma = parameter_sigma(jac, train.n_cycles, cost, floor, r1 if better else r0, np.abs(kept.x - cand.x0),
                            parameter_floor(cand, kept.x), point_floors(train, scale))
    # what the fit moves by when a held parameter, or a fixed one of the candidate, is off by its sigma (first order)
    shifted_models = [with_fit(other, kept) for other in held] + [
        replace(cand, fixed={**cand.fixed, name: cand.fixed[name] + s}).model_at(current, kept.x)
        for name, s in cand.fixed_sigma.items()]
    for shifted_model in shifted_models:
        shifted = train_of(full(shifted_model))
        runs += 1
        if np.array_equal(shifted.index, train.index):
            dx = np.linalg.lstsq(jac, (shifted.features() / scale).ravel() - (r1 if better else r0), rcond=None)[0]
            sigma = np.hypot(sigma, dx)
    chosen = replace(kept, sigma=sigma)
    return chosen, with_fit(current, chosen), new_res if better else res, runs


def point_floors(train: Residuals, scale: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each operating point of at least two cycles: its cycle mask and its own whitened model-error floor
    (feature_floor of its cycles); empty at one point (parameter_sigma's ``points``)."""
    groups = train.group
    labels = [] if groups is None else [g for g in np.unique(groups) if g >= 0 and np.sum(groups == g) >= 2]
    return [(groups == g, feature_floor(train.take(groups == g), scale)) for g in labels] if len(labels) >= 2 else []


def with_fit(model: EngineModel, trial: Trial) -> EngineModel:
    cand: Candidate = trial.candidate
    if cand.toggle:
        return cand.model_at(model, None)
    e = cand.effect_at(trial.x)
    sigma = {k: float(s) for k, s in zip(cand.params, trial.sigma) if np.isfinite(s)}
    return model.with_effect(make_effect(e.name, dict(e.values), sigma))


def rank(trials: Sequence[Trial]) -> list[Trial]:
    return sorted(trials, key=lambda t: t.cost)


__all__ = ["CHAIN_FLOOR", "CHAIN_REL", "CHAIN_STIFFNESS_REL", "Evaluator", "Linearised", "MODE_SHARE_ZERO",
           "ONE_NODE_FLOOR", "Trial", "at_start", "linearise", "parameter_floor", "parameter_sigma", "point_floors",
           "polish", "rank", "refine", "with_fit"]
