"""Two effects at once where one alone leaves a rest: a TDC offset the pressure reads below its naming threshold, and
the friction the speed asks for beside it (issue 27, design note 48).

Where the pressure reads a cylinder's TDC within TDC_SIGMAS of its sigma (maruti 4000 rpm: 1.52 +- 0.48 deg, 3
sigma) it is not named (pressure_channel.pressure_findings) and only starts the speed's TDC refinement; with a worn
ring in another cylinder as well, a single effect cannot explain both, and the speed's step ends between two stand-ins
of the pair (a worn ring in the TDC's cylinder, whose friction takes the TDC's indicated work, and a cam-order
friction). Here, when a step ends ambiguous and the pressure reads such a TDC (beyond SEED_SIGMAS and SEED_MIN_DEG),
the TDC is put at the pressure's reading (refined by the speed within the pressure's noise, as a named one is:
pressure_tdc.refined_by_speed) and each rival is refitted on top of it. The pair is taken only if

- each rival alone leaves the held-out residual beyond the null (features.beyond_null): a second effect is not
  fitted to the model's own error;
- it lowers the held-out coherent chi^2 of the best rival alone by ``min_delta`` (a step's own significance) and
  makes no channel worse than the current model or than that rival (choice.channel_worse; the pressure's TDC
  channel: choice.pressure_worse);
- the refitted rival is physical (choice.unphysical, choice.off_physics) and the TDC lies within REFINE_SIGMAS of
  the pressure's reading (it is);
- the other rival's pair does not explain the held-out cycles within AMBIGUOUS_DCHI2 as well.

The same pair is tried where a step ends with one explanation, an effect in a cylinder whose own TDC offset is a
significant second or whose pressure reads its TDC beyond SEED_SIGMAS (``beside_own_tdc``: the friction may be the
TDC's stand-in), with that cylinder's TDC as the pressure reads it however small. Where the explanations alone leave
nothing beyond the null but the pressure reads the TDC beyond SEED_SIGMAS (a rival step's seed always is), the TDC has
evidence of its own and the pair is judged with the model's own error allowed for (its floored held-out chi^2 must
fall by ``min_delta`` too; before design note 85 such a pair was not tried);
and in every pair the TDC is refined again with the friction in place (the speed's
first refinement ran without it; design note 81), the friction moved by its sigma held in that refinement so that
the TDC's sigma carries it (design note 91). Otherwise nothing is added and the ambiguity stands.

Where the step's one explanation is a friction whose cylinder's pressure reads its TDC off by more than SEED_MIN_DEG,
however few of its sigmas, the pair is tried too (design note 91) and ends one of three ways: named (its tests pass);
the friction named alone (the pair explains the held-out cycles worse, or says the same of the friction); or
**ambiguous** -- the pair fails only by being no better than the friction alone, explains the held-out cycles as well
(floored chi^2 and the pressure's within AMBIGUOUS_DCHI2) and contradicts what the friction alone claims (another
cylinder, or a parameter beyond 2 of its sigma): both are said with the measurement that separates them, and nothing
is added. Not a joint Gauss-Newton fit of both: the TDC's value is the
pressure's (its sigma enters the friction's by ``fit.polish``'s ``held``), the friction's the speed's on top of it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.choice import (
    AMBIGUOUS_DCHI2,
    RESOLUTION,
    channel_worse,
    chi2,
    chi2_floored,
    off_physics,
    pressure_worse,
    unphysical,
)
from frictionwatch.core.discrepancy.features import beyond_null, localise
from frictionwatch.core.discrepancy.fit import Trial, polish, with_fit
from frictionwatch.core.discrepancy.pressure_channel import (
    SEED_MIN_DEG,
    SEED_SIGMAS,
    PressureFinding,
    tdc_beyond,
)
from frictionwatch.core.discrepancy.pressure_tdc import moved_by_sigma, refined_by_speed, with_findings
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.model.engine_model import EngineModel

# rival fits refined on top of the TDC (each one polish: a few whole-log runs), the best by held-out chi^2 at the
# rival's own values; two so that the runner-up can show an ambiguity (not tuned)
POLISHED = 2


@dataclass(frozen=True)
class Pair:
    """A TDC the pressure read (``tdc``, as refined) and a rival refitted on top of it (``trial``): the model with
    both, its whole-log run, and the model and run with the TDC alone; ``why`` says why it was taken."""

    tdc: PressureFinding
    trial: Trial
    model: EngineModel
    res: Residuals
    tdc_model: EngineModel
    tdc_res: Residuals
    why: str


def own_tdc_reading(res: Residuals, cylinder: int) -> tuple[int, float, float] | None:
    """(cylinder, offset [deg], sigma [deg]) of what ``cylinder``'s pressure reads of its TDC in the run ``res``
    (less the whole wheel's where that is beyond SEED_SIGMAS, as tdc_beyond gives it), however small; None where the
    pressure reads nothing there."""
    if res.tdc_deg is None or not 1 <= cylinder <= res.tdc_deg.size or not np.isfinite(res.tdc_deg[cylinder - 1]):
        return None
    wheel = sum(deg for k, deg, _ in tdc_beyond(res, SEED_SIGMAS, SEED_MIN_DEG) if k == 0) if res.tdc_deg.size > 1 \
        else 0.0
    return cylinder, float(res.tdc_deg[cylinder - 1]) - wheel, float(res.tdc_sigma_deg[cylinder - 1])


def beside_own_tdc(t: Trial, confirmed_tdcs: list[str], res: Residuals) -> int | None:
    """The cylinder of the step's one explanation ``t`` (no rival within AMBIGUOUS_DCHI2) where it is an effect
    placed in a cylinder other than a TDC offset and that cylinder's TDC is in question too: its TDC offset is a
    significant explanation of the speed (``confirmed_tdcs``: the labels of the step's significant confirmed TDC
    trials) or its pressure reads its TDC off by more than SEED_MIN_DEG in the current model's run ``res``, however
    few of its sigmas (``own_tdc_reading``); else None. Both read one cylinder's work: a TDC offset moves its
    indicated work, a friction there takes it, so a friction found there may be the TDC's stand-in with the friction
    itself elsewhere or smaller (maruti 1500/0.5 s1: TDC 1.5 deg on 2, a worn ring on 3, named ring_wear[2] 3.58, the
    TDC the speed's second; s3: the same, ring_wear[2] 3.39 +- 0.074 with no TDC among the speed's seconds while
    the pressure read cylinder 2 at 1.49 +- 0.71 deg; design notes 81, 85; TDC 0.8 deg on 2, read under SEED_SIGMAS,
    and a ring on 3 named ring_wear[2] 2.95 +- 0.13 alone: note 91). The pair is then tried (``tdc_and_friction``)
    and its own tests decide: named, refused, or -- where it explains as well as the friction alone and differs from
    it -- an ambiguity."""
    c = t.candidate
    if c.effect == "tdc_offset" or not c.places_cylinder or c.cylinder is None:
        return None
    own = own_tdc_reading(res, c.cylinder)
    read = own is not None and (c.cylinder in {k for k, _, _ in tdc_beyond(res, SEED_SIGMAS, SEED_MIN_DEG)}
                                or (abs(own[1]) > SEED_MIN_DEG and not sensor_correction(t)))
    return c.cylinder if f"tdc_offset[cyl {c.cylinder}]" in confirmed_tdcs or read else None


def sensor_correction(t: Trial) -> bool:
    """Whether the trial corrects a pressure sensor (choice.RESOLUTION's effects) rather than a friction. Design note
    91's trigger, its quiet path and its ambiguity are for a friction beside a TDC, the gap it was built and measured
    on; beside a sensor correction the pair is tried as before it (the speed's TDC second, a reading beyond
    SEED_SIGMAS). Whether a gain beside such a TDC is an ambiguity too was not measured."""
    return any(t.candidate.effect == effect for effect, _ in RESOLUTION)


def tdc_and_friction(current: EngineModel, cur_res: Residuals, rivals: list[tuple[Trial, Residuals]],
                     full: Callable[[EngineModel], Residuals], parts, scale: np.ndarray, floor: np.ndarray,
                     pressure: Callable[[EngineModel], float], load_nm: float, min_delta: float,
                     significant: Callable[[Residuals], bool], cylinder: int | None = None
                     ) -> tuple[Pair | None, int, str, Pair | None]:
    """The pair to add (module doc) or None; the monitor runs spent; why not, in words ('' when nothing was tried);
    and, where the pair is not added only because it explains the held-out cycles no better than the friction alone
    (``as_well``), that pair: an ambiguity the workflow says rather than naming the friction alone (None otherwise).
    ``rivals``: the ambiguous step's two trials with their whole-log runs; ``parts(res)`` -> (training, held out);
    ``pressure(model)`` the TDC channel's chi^2 against the current run's readings; ``significant(res)`` the step's
    own test against the current model. ``cylinder``: the pair is tried with that cylinder's TDC as the pressure
    reads it however small (``own_tdc_reading``), not with a reading beyond SEED_SIGMAS; only there is an ambiguity
    returned (a rival step is ambiguous already)."""
    have = {e.values.get("cylinder") for e in current.effects if e.name == "tdc_offset"}
    seeds = [s for s in tdc_beyond(cur_res, SEED_SIGMAS, SEED_MIN_DEG) if s[0] not in have]
    if cylinder is not None:
        own = own_tdc_reading(cur_res, cylinder)
        seeds = [own] if own is not None and cylinder not in have else []
    if not seeds or any(t.candidate.effect == "tdc_offset" for t, _ in rivals):
        return None, 0, "", None
    k, deg, sigma = max(seeds, key=lambda s: abs(s[1]) / s[2])  # the clearest reading: one pair per step
    spec = current.spec
    singles = [parts(r)[1] for _, r in rivals]
    # each alone must leave something beyond the model's own error (a second effect is not fitted to that error),
    # except where the pressure reads this TDC beyond SEED_SIGMAS and SEED_MIN_DEG (a rival step's seeds always,
    # beside_own_tdc's cylinder where its reading is: the TDC has its own evidence) or where the friction is the step's
    # one explanation beside its own cylinder's TDC and a friction (``cylinder``: whether the pair explains the log as
    # well is the question, design note 91): there the pair is judged with the model-error floor in each feature's
    # variance (``quiet`` below)
    quiet = not all(beyond_null(localise(h, spec, scale)) for h in singles)
    friction = cylinder is not None and not sensor_correction(rivals[0][0])
    if quiet and not friction and k not in {c for c, _, _ in tdc_beyond(cur_res, SEED_SIGMAS, SEED_MIN_DEG)}:
        return None, 0, (f"tdc_offset[cyl {k}] as the pressure reads it ({deg:+.2f} +- {sigma:.2f} deg) with a friction "
                         "beside it: each alone leaves nothing beyond the model's own error"), None
    reading = PressureFinding("tdc_offset", k, "deg", deg, sigma,
                              f"the pressure reads TDC {deg:+.2f} +- {sigma:.2f} deg off (below the naming threshold; "
                              "taken with the friction beside it)")
    found, tdc_res, runs = refined_by_speed(current, [reading], full, lambda r: parts(r)[0], scale, floor)
    tdc_model = with_findings(current, found)
    held = [moved_by_sigma(tdc_model, found[0])]
    # each rival's effect in every cylinder at the rival's fitted values (with the TDC in place the friction need not
    # sit in the cylinder the TDC's indicated work pulled it to: maruti's worn ring, fitted in the TDC's cylinder 2,
    # is in 3), one whole-log run each; the POLISHED best held out refined on all training cycles
    library = candidate_library(tdc_model)
    starts = []
    for t, _ in rivals:
        same = [c for c in library if c.shape == t.candidate.shape and (
            c.label == t.candidate.label or (t.candidate.places_cylinder and c.cylinder is not None))]
        for cand in same:
            start = Trial(cand, t.x, t.sigma, t.cost, t.base_cost, 0)
            res0 = full(with_fit(tdc_model, start))
            runs += 1
            starts.append((chi2(parts(res0)[1], scale), start, res0))
    pairs = []
    for _, start, res0 in sorted(starts, key=lambda s: s[0])[:POLISHED]:
        t2, model2, res2, spent = polish(start, tdc_model, with_fit(tdc_model, start), res0, full,
                                         lambda r: parts(r)[0], scale, floor, held)
        runs += spent
        # the speed refined the TDC with the friction missing, so its TDC took part of the friction's work (maruti
        # 1500/0.5 s1: 1.73 deg for 1.5, and a balance 0.13 N m off; design note 81): the TDC is refined again from
        # the pressure's reading with the friction in place, and the friction polished once more on top of it
        # the friction moved by its sigma enters the speed's TDC sigma (the two take one cylinder's work)
        found2, _, spent = refined_by_speed(with_fit(current, t2), [reading], full, lambda r: parts(r)[0], scale,
                                            floor, [with_fit(current, replace(t2, x=t2.candidate.clip(t2.x + t2.sigma)))])
        tdc2 = with_findings(current, found2)
        start2 = with_fit(tdc2, t2)
        res_start2 = full(start2)
        t2, model2, res2, spent2 = polish(t2, tdc2, start2, res_start2, full, lambda r: parts(r)[0], scale, floor,
                                          [moved_by_sigma(tdc2, found2[0])])
        tdc_res2 = full(tdc2)
        runs += spent + spent2 + 2
        pairs.append((chi2(parts(res2)[1], scale) + pressure(model2), t2, model2, res2, found2[0], tdc2, tdc_res2))
    if not pairs:
        return None, runs, "", None
    pairs.sort(key=lambda p: p[0])
    best, t2, model2, res2, tdc_found, tdc_model, tdc_res = pairs[0]
    best_single = min(chi2(h, scale) + pressure(with_fit(current, t)) for (t, _), h in zip(rivals, singles,
                                                                                             strict=True))
    floored_single = min(chi2_floored(h, scale, floor) for h in singles)
    floored_pair = chi2_floored(parts(res2)[1], scale, floor)
    floored_fall = floored_single - floored_pair if quiet else np.inf
    test_pair, test_cur = parts(res2)[1], parts(cur_res)[1]
    no_better = (f"held-out chi^2 {best:.4g} is not {min_delta:g} below one effect alone's ({best_single:.4g})"
                 if best_single - best < min_delta else
                 f"with the model's own error allowed for, held-out chi^2 falls by {floored_fall:.3g} against one "
                 f"effect alone, not {min_delta:g}" if floored_fall < min_delta else "")
    not_pair = (channel_worse(test_cur, test_pair, scale) or channel_worse(min(singles, key=lambda h: chi2(h, scale)),
                                                                           test_pair, scale)
                or pressure_worse(pressure(current), pressure(model2), spec.n_cyl)
                or unphysical(t2, load_nm) or off_physics(t2)
                or ("the speed cannot place it in a cylinder" if not t2.candidate.places_cylinder and spec.n_cyl > 1
                    else "")
                or (f"{pairs[1][1].candidate.label} with the TDC explains it as well" if len(pairs) > 1
                    and pairs[1][0] - best < AMBIGUOUS_DCHI2 else ""))
    why = "not significant against the current model" if not significant(res2) else no_better or not_pair
    if why:
        # the friction alone named, or an ambiguity: where the pair fails only by explaining the held-out cycles no
        # better than the friction alone, it explains them as well (its floored chi^2 and the pressure's within
        # AMBIGUOUS_DCHI2 of the single's, choice.rival's test) and it reads the friction otherwise (another cylinder,
        # or a parameter beyond 2 sigma of the single's), the data cannot tell the two (design note 91)
        single_t = rivals[0][0]
        as_well = (friction and significant(res2) and no_better and not not_pair
                   and floored_pair + pressure(model2)
                   < floored_single + pressure(with_fit(current, single_t)) + AMBIGUOUS_DCHI2
                   and reads_otherwise(single_t, t2))
        pair = Pair(tdc_found, t2, model2, res2, tdc_model, tdc_res, why) if as_well else None
        return None, runs, f"tdc_offset[cyl {k}] with {t2.candidate.label}: {why}", pair
    return (Pair(tdc_found, t2, model2, res2, tdc_model, tdc_res,
                 f"held-out chi^2 {best:.4g} against {best_single:.4g} with one effect alone"
                 + (f" ({floored_fall:.3g} lower with the model's own error allowed for)" if quiet else "")), runs, "",
            None)


def wheel_not_read(t: Trial, res: Residuals) -> int | None:
    """The cylinder whose own TDC offset the pressure reads clearest (|offset| / sigma) in the current model's run
    ``res``, off by more than SEED_MIN_DEG however few of its sigmas (as ``beside_own_tdc`` asks), where the step's one
    explanation ``t`` is the whole wheel's TDC (cylinder 0) and the pressure reads no offset common to the wheel (its
    median cylinder within SEED_SIGMAS: tdc_beyond); else None. A whole-wheel offset moves every cylinder's indicated
    work, so it can stand in for one cylinder's TDC with a friction elsewhere (maruti 1500/0.5 s6: TDC 1.5 deg on 2
    and a worn ring on 3 named the wheel at 1.30 +- 0.028, the pressure reading -0.14, +1.55, +0.02 +- 0.70-0.82
    deg; cylinder 2's TDC alone fitted 2.66 deg and explained the held-out cycles much worse, and the pair was never
    tried; design note 106)."""
    c = t.candidate
    if c.effect != "tdc_offset" or c.cylinder != 0 or res.tdc_deg is None or res.tdc_deg.size < 2:
        return None
    if any(k == 0 for k, _, _ in tdc_beyond(res, SEED_SIGMAS, SEED_MIN_DEG)):
        return None
    ok = np.isfinite(res.tdc_deg) & np.isfinite(res.tdc_sigma_deg) & (res.tdc_sigma_deg > 0)
    off = ok & (np.abs(np.where(ok, res.tdc_deg, 0.0)) > SEED_MIN_DEG)
    if not np.any(off):
        return None
    clearest = np.where(off, np.abs(np.where(ok, res.tdc_deg, 0.0)) / np.where(ok, res.tdc_sigma_deg, 1.0), -1.0)
    return int(np.argmax(clearest)) + 1


def wheel_or_pair(wheel: tuple[Trial, EngineModel, Residuals], others: list[tuple[Trial, Residuals]],
                     current: EngineModel, cur_res: Residuals, full, parts, scale: np.ndarray, floor: np.ndarray,
                     pressure: Callable[[EngineModel], float], load_nm: float, min_delta: float,
                     significant: Callable[[Residuals], bool]) -> tuple[Pair | None, bool, int, str]:
    """Where ``wheel_not_read`` (else nothing is tried): the pair of the cylinder's TDC as the pressure reads it and the
    best two significant non-TDC explanations of the step (``others``: trials with their whole-log runs) refitted beside
    it (``tdc_and_friction``, its own tests), against the whole wheel (``wheel``: trial, model, run) on the held-out
    cycles with the model's own error allowed for and the pressure's chi^2 (choice.rival's measure). Returns the pair
    (None: the wheel stands), whether it only explains them as well as the wheel (within AMBIGUOUS_DCHI2: an ambiguity,
    nothing added), the monitor runs spent and why the pair was not taken ('' when it was or was as good)."""
    rivals = [(t, r) for t, r in others if t.candidate.effect != "tdc_offset" and significant(r)][:2]
    k = wheel_not_read(wheel[0], cur_res)
    if k is None or not rivals:
        return None, False, 0, ""
    pair, runs, why, _ = tdc_and_friction(current, cur_res, rivals, full, parts, scale, floor, pressure, load_nm,
                                          min_delta, significant, cylinder=k)
    if pair is None:
        return None, False, runs, why
    t, model, res = wheel
    held_out = chi2_floored(parts(pair.res)[1], scale, floor) + pressure(pair.model)
    against = chi2_floored(parts(res)[1], scale, floor) + pressure(model)
    if held_out > against + AMBIGUOUS_DCHI2:
        return None, False, runs, (f"tdc_offset[cyl {pair.tdc.cylinder}] with {pair.trial.candidate.label}: held-out "
                                   f"chi^2 {held_out:.4g} against the whole wheel's {against:.4g}")
    return pair, held_out > against - AMBIGUOUS_DCHI2, runs, ""


def reads_otherwise(single: Trial, paired: Trial) -> bool:
    """Whether the friction refitted beside the TDC (``paired``) contradicts what the friction alone (``single``)
    claims: another candidate (effect or cylinder), or a parameter beyond 2 of the single's sigma from the single's
    value (the matrix's coverage rule, not tuned). The single's sigma alone: it is the single that would be named,
    and its sigma does not carry the TDC the pressure cannot pin (k9k 1800/0.6 s2, TDC 0.3 deg and a ring on 2:
    ring_wear[2] 2.77 +- 0.053 alone, 2.48 +- 0.14 beside the TDC, the pair's floored held-out chi^2 28.6 lower;
    design note 91). Where it does not, naming the single claims nothing the pair denies: no ambiguity."""
    if paired.candidate.label != single.candidate.label:
        return True
    return bool(np.any(np.abs(paired.x - single.x) > 2.0 * single.sigma))


def _fitted(t: Trial) -> str:
    """A trial's fitted values with their sigmas, as an ambiguity lists them."""
    return ", ".join(f"{n} {float(x):.3g} +- {float(s):.2g}" for n, x, s in zip(t.candidate.params, t.x, t.sigma))


def said_alone(t: Trial) -> str:
    """The friction alone as an ambiguity lists it: its label and fitted values."""
    return f"{t.candidate.label} alone ({_fitted(t)})"


def said_pair(pair: Pair) -> str:
    """A pair as an ambiguity lists it: the TDC as the pressure read it (refined) and the friction beside it."""
    return (f"tdc_offset[cyl {pair.tdc.cylinder}] ({pair.tdc.value:+.2f} +- {pair.tdc.sigma:.2f} deg, under the "
            f"pressure's naming threshold) with {pair.trial.candidate.label} ({_fitted(pair.trial)})")


__all__ = ["POLISHED", "Pair", "beside_own_tdc", "own_tdc_reading", "reads_otherwise", "said_alone", "said_pair",
           "sensor_correction", "tdc_and_friction", "wheel_not_read", "wheel_or_pair"]
