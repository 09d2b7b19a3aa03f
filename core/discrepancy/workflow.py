"""Find, name, add: the discrepancy workflow over a list of assembled cycles (issue 18).

    found = discover(model, cycles)            # model: the baseline EngineModel; cycles: core.types.Cycle in order
    found.model                                # the baseline with every significant effect added (fitted, sigma)
    found.to_json()                            # {"found": [...], "gap_before", "gap_after", "metric", "steps", ...}

The cycles are split in time: the first ``warmup`` settle the monitor (tooth learner, noise model) and are not
scored; of the rest the first half trains (the fits, on its first ``fit_cycles``) and the second half is held out
(the choice and every reported gap). First, what the pressure names outright (a pegging offset, a TDC offset far
beyond its reading's sigma, a misfiring cylinder: core.discrepancy.pressure_channel) is added as one step. Then, while the held-out residual holds something beyond the healthy model's own error
(``features.beyond_null``: an engine order above its model-error floor, or a significant balance residual), each step
linearises every candidate of the library on top of the current model, refines the ``refine`` best by predicted cost
and the best of each of the first ``confirm`` shapes (and of any further shape whose prediction beats a refined one's
cost that would be held out: choice.up_to_the_edge), re-runs the best of each of those shapes over the whole log,
takes one more Gauss-Newton step for the best of them on all training cycles (its sigma from there), and adds it if
its held-out gain is significant: the held-out coherent chi^2 falls by at least ``min_delta_chi2`` (its noise under no
effect is about sqrt(2 F) ~ 10 for F ~ 50 features) and the gap by at least ``min_reduction``. A significant step is
still refused, and the model left as it was, when it makes a channel worse on the held-out cycles (the flywheel speed or
the mean torque balance, beyond that channel's noise; TDC against the cylinders' pressure) or when a fitted parameter
ends on the bound of its range (the fit ran into the wall: not a physical value) or at one of its declared start points
(it did not move: choice.not_fitted), or a sensor correction lies within what the pressure methods resolve, or any fit
with every parameter within 2 sigma of none (its size not told from zero, on a residual no larger than a healthy log's
or a louder one; a shaft-line fit's sigma with the line's own model error in it: choice.unresolved,
choice.quiet_residual, fit.CHAIN_FLOOR), or -- on a residual inside the null (nothing beyond a floor, the speed gap
within GAP_NULL: choice.within_null) -- a fit whose held-out chi^2 with the model-error floor allowed for falls by less
than ``min_delta_chi2`` (choice.within_model_error: the model's own error, coherent, passes the plain test); the
refusal and its reason are reported. A whole wheel's TDC where the pressure reads one cylinder's is weighed against
that TDC with a friction (pair.wheel_or_pair). Which trials are held out, when two are one explanation and why a step
is refused: core.discrepancy.choice. On a log of several operating points the fits run on the whole training half
(Options.fit_all_points), not its first ``fit_cycles``.

The outcome says which of three it is: ``named`` (effects added), ``nothing`` (nothing significant before or after)
or ``unexplained`` (a coherent residual remains that no candidate explains: significant engine orders or a
significant balance residual on the held-out cycles, with its signature); ``named`` and a remainder are both said.
When ``max_steps`` is used up, that is said too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from frictionwatch.core.discrepancy.across_points import law_against_balance, laws_across_points, sized_by_balance
from frictionwatch.core.discrepancy.candidates import candidate_library
from frictionwatch.core.discrepancy.choice import (
    best_of_shapes,
    channel_worse,
    chi2,
    chi2_floored,
    close_cylinders,
    nested,
    not_fitted,
    off_physics,
    one_per_candidate,
    pressure_worse,
    quiet_residual,
    rival,
    said_where,
    significance,
    to_confirm,
    unphysical,
    unresolved,
    up_to_the_edge,
    within_model_error,
    within_null,
)
from frictionwatch.core.discrepancy.common_gain import common_gain_of, engine_wide_friction
from frictionwatch.core.discrepancy.discovery import Discovery, Options, Step
from frictionwatch.core.discrepancy.features import (
    beyond_healthy_gap,
    beyond_null,
    feature_floor,
    gap,
    localise,
    noise_scale,
)
from frictionwatch.core.discrepancy.fit import Evaluator, linearise, polish, refine, with_fit
from frictionwatch.core.discrepancy.leak_share import leak_share, mean_pressure
from frictionwatch.core.discrepancy.pair import beside_own_tdc, said_alone, said_pair, tdc_and_friction, wheel_or_pair
from frictionwatch.core.discrepancy.pressure_channel import (
    pressure_findings,
    pressure_seeds,
    tdc_chi2,
    tdc_offsets_deg,
)
from frictionwatch.core.discrepancy.pressure_tdc import moved_by_sigma, refined_by_speed, with_findings
from frictionwatch.core.discrepancy.residuals import (
    Residuals,
    mean_load,
    pinned_config,
    run_model,
)
from frictionwatch.core.discrepancy.resonance import one_resonance_in, said_as_one
from frictionwatch.core.discrepancy.sensor_faults import (
    said_fault,
    separation,
    stood_in_channels,
    undescribed_faults,
)
from frictionwatch.core.discrepancy.words import within_floor_separation
from frictionwatch.core.model.effects import EFFECTS
from frictionwatch.core.model.engine_model import EngineModel
from frictionwatch.core.model.view import reference
from frictionwatch.core.monitor.calibration.tdc_memo import TdcFitMemo
from frictionwatch.core.types import Cycle


def discover(model: EngineModel, cycles: Sequence[Cycle], options: Options | None = None) -> Discovery:
    """Run the workflow (module doc). Raises ValueError when the cycles are too few to train and hold out."""
    opt = options or Options()
    cycles = list(cycles)
    if len(cycles) < opt.warmup + 16:
        raise ValueError(f"{len(cycles)} cycles: the workflow needs at least {opt.warmup + 16} "
                         f"({opt.warmup} to settle, 8 to train, 8 held out)")
    ref = reference(cycles)
    # what a load ripple's swing is measured against (Effect.unphysical): the shaft's, as the monitor reads it
    load_nm = mean_load(cycles, ref.omega, model.calibration.generator_efficiency)
    split = opt.warmup + (len(cycles) - opt.warmup) // 2
    first, held = cycles[opt.warmup].index, cycles[split].index

    pinned = pinned_config(opt.monitor_config)  # the question is whether each model reproduces the log as it stands
    # most candidates leave the pressure and the geometry as they were: the TDC watch's fits of this log, made once
    tdc_memo = TdcFitMemo()

    def full(m: EngineModel) -> Residuals:
        return run_model(m, ref, pinned, cycles, tdc_memo)

    def sub(m: EngineModel) -> Residuals:  # the fits' window, set below once the baseline's run says its points
        return run_model(m, ref, pinned, window, tdc_memo)

    def parts(res: Residuals) -> tuple[Residuals, Residuals]:
        return res.take((res.index >= first) & (res.index < held)), res.take(res.index >= held)

    cur_res = full(model)
    runs = 1
    train, test = parts(cur_res)
    if train.n_cycles < 4 or test.n_cycles < 4:
        raise ValueError(f"the monitor analysed {cur_res.n_cycles} of {len(cycles)} cycles: too few to train and "
                         "hold out")
    # the fits' window (``sub``): the first ``fit_cycles`` after the warm-up; on a log of several operating points
    # the whole training half, whose cycles hold each point as the held-out half does (Options.fit_all_points)
    several = train.group is not None and np.unique(train.group[train.group >= 0]).size > 1
    window = cycles[:split if several and opt.fit_all_points else min(split, opt.warmup + opt.fit_cycles)]
    scale = noise_scale(train)
    found = Discovery(model, model, [], gap(test, scale), gap(test, scale), localise(test, model.spec, scale),
                      {}, [("baseline", test.angles, test.speed.mean(axis=0))])
    # a pressure sensor the monitor flags with a fault no candidate describes: whatever is fitted rests on it
    # (counted over every analysed cycle: a load step's are left out of the residuals, not of the sensors' reading)
    analysed = cur_res.n_cycles + cur_res.between_points
    found.sensor_faults = undescribed_faults(cur_res.sensor_flag_cycles or {}, analysed)
    found.stood_in = stood_in_channels(cur_res.sensor_flag_cycles or {}, analysed)  # said, nothing else
    base_test = test
    current = model
    speed_law = None  # (label, balance fit) of a friction law the speed steps sized and the balance read otherwise
    # what the pressure names outright (pegging, TDC, misfire: pressure_channel.pressure_findings), first and apart from
    # the step limit; the speed steps then start from the corrected pressure
    # the share of a leak gone by the compression reading, from the scored cycles' own pressure (sizes a blow_by)
    share = leak_share(model.spec, *mean_pressure(cycles[opt.warmup:])) if model.spec.n_cyl > 1 else math.nan
    current, cur_res, test, extra = _pressure_step(found, current, cur_res, test, full, parts, scale, first, held,
                                                   share)
    runs += extra
    for step in range(opt.max_steps):
        loc = localise(test, model.spec, scale)
        beyond = beyond_null(loc)
        # nothing beyond the null, but a speed gap far beyond a healthy log's at these amplitudes: an ambiguity with
        # the model's own error at those orders, not a fit of it (``_said_ambiguous``; design note 48)
        inside = loc["healthy_gap"] if beyond_healthy_gap(loc) else None
        # after a step, nothing beyond the healthy model's own error is left to explain: a further candidate that
        # lowers the plain chi^2 there fits that error (deutz 3000 rpm seed 2: a Stribeck ring added after the right
        # pegging, an extra friction after the right Stribeck ring). Before any step the plain test stands (maruti
        # 4000 rpm seed 2: the Stribeck ring, the side-thrust skirt, the inertia left out are named right with no
        # order nor the balance beyond the null: the per-order floors are wide there), but an ambiguity within the
        # null is no discrepancy (``_said_ambiguous``: Discovery.within_null_fits)
        if found.steps and not beyond:
            break
        # each shape held out is one more chance to fit that error: with nothing beyond the null, the narrower test
        # (deutz 3000 rpm seed 2, a load-dependent bearing law no speed signature shows: four shapes held out named
        # a Stribeck ring at fraction 0.20 +- 0.07, two said nothing; chosen after seeing that log, design note 39)
        breadth = opt.confirm if beyond else opt.confirm_within_null
        floor = feature_floor(parts(cur_res)[0], scale)  # of the current model, what a found sigma adds
        ev = Evaluator(sub, scale, first, floor)
        base = ev.vector(current)
        lins = sorted((linearise(c, current, ev, base) for c in candidate_library(current)), key=lambda x: x.predicted)
        # a toggle's window cost is exact (one run, nothing to refine): it competes with the refined, whose
        # linear predictions can promise more than they keep
        chosen = lins[:opt.refine] + [lin for lin in lins[opt.refine:] if lin.candidate.toggle]
        # and the best of each shape that can reach the held-out test (to_confirm), refined however it ranks
        chosen += [lin for lin in best_of_shapes(lins, breadth) if not any(lin is c for c in chosen)]
        # and the same effect in the other cylinders that the window cannot tell from the lead's (close_cylinders)
        chosen += close_cylinders(lins, lins[:opt.refine], lambda lin: lin.predicted)
        # what the pressure says of TDC (the pipeline's TDC watch on the current model's run) starts a TDC
        # candidate's refinement at that reading: the linear step from 0 can stop short of a large offset
        chosen += [replace(lin, x_gn=lin.candidate.clip(np.array([x]))) for lin in lins
                   for label, x in pressure_seeds(cur_res).items() if lin.candidate.label == label]
        # and where the effect declares further starting points (a strongly nonlinear fit), from each of them
        chosen += [replace(lin, x_gn=lin.candidate.clip(np.array(x))) for lin in lins for x in lin.candidate.seeds]
        # the pressure channel: what each model leaves of the TDC offsets the pressure read in the current model's
        # run, a chi^2 beside the speed and balance ones (independent data, added once per run)
        def pressure(m: EngineModel, reading: Residuals = cur_res, base: EngineModel = current) -> float:
            return tdc_chi2(reading, tdc_offsets_deg(m) - tdc_offsets_deg(base))

        refined = [refine(lin, current, ev) for lin in chosen]
        # and each further shape whose linear promise would put it among those held out (choice.up_to_the_edge)
        refined += up_to_the_edge(lins, refined, breadth, lambda lin, m=current, e=ev: refine(lin, m, e))
        trials = one_per_candidate(sorted(refined, key=lambda tr: tr.cost + pressure(with_fit(current, tr))))
        dropped = {t.candidate.label: unphysical(t, load_nm) for t in trials}
        found.dropped.update({label: why for label, why in dropped.items() if why})
        trials = [t for t in trials if not dropped[t.candidate.label]]
        runs += ev.calls
        confirmed = []
        for t in to_confirm(trials, breadth):
            trial_model = with_fit(current, t)
            res = full(trial_model)
            runs += 1
            confirmed.append((gap(parts(res)[1], scale), t, trial_model, res))
        if not confirmed:
            break
        confirmed.sort(key=lambda c: chi2(parts(c[3])[1], scale) + pressure(c[2]))
        g_cur, chi_before = gap(test, scale), chi2(test, scale)
        significant = significance(test, scale, opt, lambda r: parts(r)[1])
        _, t, new_model, res = confirmed[0]
        # whether the runner-up explains the held-out cycles as well: judged with the model-error floor in each
        # feature's variance (a difference inside the model's own error is no evidence for either)
        other = rival(confirmed, significant,
                      lambda c, f=floor: chi2_floored(parts(c[3])[1], scale, f) + pressure(c[2]))
        if other is not None and nested(t.candidate, other.candidate):  # one explanation within the other's
            if len(other.candidate.names) < len(t.candidate.names):  # as good and simpler: the simpler one
                _, t, new_model, res = confirmed[1]
            other = None
        twin = None if other is not None or not significant(res) else one_resonance_in(
            current, confirmed, significant, lambda r, f=floor: chi2_floored(parts(r)[1], scale, f), floor.size)
        if twin is not None:  # the line's stiffness and the flywheel's inertia read one resonance (resonance.py)
            _said_ambiguous(found, beyond, *said_as_one(t, twin), inside)
            break
        if other is not None:  # two explanations: a TDC the pressure reads beside one of them (pair.py), or neither
            pair, spent, found.pair_not_taken, _ = tdc_and_friction(
                current, cur_res, [(c[1], c[3]) for c in confirmed[:2]], full, parts, scale, floor, pressure,
                load_nm, opt.min_delta_chi2, significant)
            runs += spent
            if pair is not None:
                current, test, cur_res = _add_pair(found, pair, test, scale, parts, model.spec)
                found.step_limit_reached = step == opt.max_steps - 1
                continue
            _said_ambiguous(found, beyond, [said_where(c.candidate, model.spec.n_cyl) for c in (t, other)],
                            [c.separated_by for c in (t.candidate, other.candidate)], inside,
                            _gain_beside([t, other], loc))
            break
        own = beside_own_tdc(t, [c[1].candidate.label for c in confirmed[1:] if significant(c[3])], cur_res)
        as_well = None  # a pair that explains the held-out cycles as well as the friction alone (pair.py)
        if other is None and own is not None:  # a friction where the TDC of its cylinder explains much too (pair.py)
            pair, spent, found.pair_not_taken, as_well = tdc_and_friction(
                current, cur_res, [(t, res)], full, parts, scale, floor, pressure, load_nm, opt.min_delta_chi2,
                significant, cylinder=own)
            runs += spent
            if pair is not None:
                current, test, cur_res = _add_pair(found, pair, test, scale, parts, model.spec)
                found.step_limit_reached = step == opt.max_steps - 1
                continue
        if other is None:  # the whole wheel's TDC where the pressure reads one cylinder's (pair.wheel_or_pair)
            pair, as_well_wheel, spent, why_not = wheel_or_pair(
                (t, new_model, res), [(c[1], c[3]) for c in confirmed[1:]], current, cur_res, full, parts, scale,
                floor, pressure, load_nm, opt.min_delta_chi2, significant)
            runs, found.pair_not_taken = runs + spent, why_not or found.pair_not_taken
            if pair is not None and as_well_wheel:
                _said_ambiguous(found, True, [said_alone(t), said_pair(pair)],
                                [t.candidate.separated_by, pair.trial.candidate.separated_by])
                break
            if pair is not None:
                current, test, cur_res = _add_pair(found, pair, test, scale, parts, model.spec)
                found.step_limit_reached = step == opt.max_steps - 1
                continue
        if significant(res):  # polished only if significant as it stands, and kept only if still significant
            t, new_model, res, extra = polish(t, current, new_model, res, full, lambda r: parts(r)[0], scale, floor,
                                              [moved_by_sigma(current, f) for f in found.held])
            runs += extra
        if not significant(res):
            found.rejected.update({c[1].candidate.label: c[0] for c in confirmed})
            break
        if not t.candidate.places_cylinder and model.spec.n_cyl > 1:  # explained, but the speed cannot say where
            _said_ambiguous(found, beyond, [said_where(t.candidate, model.spec.n_cyl)], [t.candidate.separated_by],
                            inside, _gain_beside([t], loc))
            break
        test_new = parts(res)[1]
        channel = ""  # the speed's step (Step.channel)
        quiet = quiet_residual(loc)
        in_null = within_null(loc)  # the floored test's gate (note 155; note 61's was ``quiet``)
        floored_fall = chi2_floored(test, scale, floor) - chi2_floored(test_new, scale, floor)
        why = (channel_worse(test, test_new, scale) or pressure_worse(pressure(current), pressure(new_model),
                                                                        model.spec.n_cyl) or off_physics(t)
               or not_fitted(t)
               or unresolved(t, quiet) or within_model_error((in_null if opt.floored_within_null else quiet)
                                                              and opt.floored_when_quiet, floored_fall,
                                                              opt.min_delta_chi2))
        if not why:  # a friction law on a log of several points: the balance across them must agree (note 62)
            why, spent, law_fit = law_against_balance(t, current, cur_res, full, parts)
            runs += spent
            speed_law = (t.candidate.label, law_fit) if why else None
            if not why and law_fit is not None:  # both channels read the law: the balance's share is named
                sized = sized_by_balance(t, law_fit, current, test, full, parts, scale, significant)
                runs += 1
                if sized is not None:
                    new_model, res, test_new, channel = sized
                    floored_fall = chi2_floored(test, scale, floor) - chi2_floored(test_new, scale, floor)
        if why:  # significant, but it makes something else worse or is not physical: the model stays as it was
            found.refused.append({"candidate": t.candidate.label, "reason": why,
                                  "gap_before": g_cur, "gap_after": gap(test_new, scale),
                                  "delta_chi2_heldout": chi_before - chi2(test_new, scale),
                                  "delta_chi2_heldout_floored": floored_fall, "quiet_before": quiet,
                                  "within_null_before": in_null})
            break
        if as_well is not None:  # the friction alone would be named, but the TDC beside it explains as well: said
            _said_ambiguous(found, True, [said_alone(t), said_pair(as_well)],
                            [EFFECTS["tdc_offset"].candidate.separated_by, t.candidate.separated_by])
            found.pair_not_taken = ""
            break
        g_new, chi_after = gap(test_new, scale), chi2(test_new, scale)
        runner = confirmed[1][1].candidate.label if len(confirmed) > 1 else None
        added = new_model.effects[-len(t.candidate.names):]
        found.steps.append(Step(t, added[0], g_cur, g_new, chi_before, chi_after, runner,
                                localise(test, model.spec, scale), localise(test_new, model.spec, scale), added[1:],
                                channel=channel, floored_fall=floored_fall, quiet=quiet, within_null=in_null))
        found.curves.append((f"+ {t.candidate.label}", test_new.angles, test_new.speed.mean(axis=0)))
        current, test, cur_res = new_model, test_new, res
        found.step_limit_reached = step == opt.max_steps - 1
    if not found.steps:  # the friction laws, told by the balance across operating points (laws.py)
        current, test, cur_res, extra = laws_across_points(found, current, cur_res, test, full, parts, scale,
                                                            model.spec, speed_law)
        runs += extra
    if found.sensor_faults and (found.steps or found.ambiguous):  # none of it named: the model stays as it was
        _beside_sensor_faults(found)
        current, test = model, base_test
    found.model = current
    found.gap_after = gap(test, scale)
    found.final = localise(test, model.spec, scale)
    found.evaluations = runs
    return found


def _add_pair(found: Discovery, pair, test: Residuals, scale: np.ndarray, parts, spec) -> tuple:
    """Add a pair (pair.tdc_and_friction) as two steps: the TDC as the pressure read it (held: its sigma enters
    later fits'), the friction refitted on top of it. Returns the model, its held-out part and its run."""
    tdc_test, pair_test = parts(pair.tdc_res)[1], parts(pair.res)[1]
    found.held.append(pair.tdc)
    found.steps.append(Step(None, pair.tdc_model.effects[-1], gap(test, scale), gap(tdc_test, scale),
                            chi2(test, scale), chi2(tdc_test, scale), None, localise(test, spec, scale),
                            localise(tdc_test, spec, scale), (), (pair.tdc.reading,)))
    added = pair.model.effects[-len(pair.trial.candidate.names):]
    found.steps.append(Step(pair.trial, added[0], gap(tdc_test, scale), gap(pair_test, scale), chi2(tdc_test, scale),
                            chi2(pair_test, scale), None, localise(tdc_test, spec, scale),
                            localise(pair_test, spec, scale), added[1:]))
    found.curves.append((f"+ {found.steps[-2].label} + {pair.trial.candidate.label}", pair_test.angles,
                         pair_test.speed.mean(axis=0)))
    return pair.model, pair_test, pair.res


def _gain_beside(trials: list, loc: dict) -> dict | None:
    """A gain common to every pressure sensor (common_gain), sized from the held-out residual ``loc`` the step
    explains, where every one of ``trials`` is an engine-wide friction excess (common_gain.engine_wide_friction):
    one more explanation of it, said beside them (design note 104); else None."""
    return common_gain_of(loc) if all(engine_wide_friction(t.candidate) for t in trials) else None


def _beside_sensor_faults(found: Discovery) -> None:
    """What the fits named (or found ambiguous) becomes one side of an ambiguity whose other side is the pressure
    sensors the monitor flags with a fault no candidate describes (core.discrepancy.sensor_faults): the steps are
    taken back, and the measurement that tells the sensor from the engine is said first."""
    before = dict(found.ambiguous or {})
    fits = list(dict.fromkeys([s.label for s in found.steps] + before.get("candidates", [])))
    found.ambiguous = {**before, "candidates": fits + [said_fault(f) for f in found.sensor_faults],
                       "separated_by": list(dict.fromkeys([separation(found.sensor_faults),
                                                           *before.get("separated_by", [])])),
                       "inside_floor": before.get("inside_floor"), "sensor_faults": found.sensor_faults,
                       "fits": fits}
    found.steps, found.held, found.curves = [], [], found.curves[:1]


def _said_ambiguous(found: Discovery, beyond: bool, candidates: list[str], separated_by: list[str],
                    inside: dict | None = None, gain: dict | None = None) -> None:
    """Two explanations (or one the speed cannot place) within the noise: an ambiguity where the residual they
    explain is beyond the null; where it is not, but the speed gap is far beyond a healthy log's (``inside``:
    features.healthy_gap), an ambiguity with the model's own error at those orders as one more explanation and the
    measurement that tells a model error from a missing effect; else only said (``within_null_fits``): nothing
    there is a discrepancy."""
    if beyond or inside is not None:
        if inside is not None:
            separated_by = [within_floor_separation(inside), *separated_by]
        found.ambiguous = {"candidates": candidates, "separated_by": list(dict.fromkeys(x for x in separated_by if x)),
                           "inside_floor": inside}
        if gain is not None:  # a common pressure gain explains an engine-wide friction excess too (common_gain)
            found.ambiguous["common_gain"] = gain
    else:
        found.within_null_fits = candidates


def _pressure_step(found: Discovery, current: EngineModel, cur_res: Residuals, test: Residuals, full, parts,
                   scale: np.ndarray, first: int, held: int, share: float
                   ) -> tuple[EngineModel, Residuals, Residuals, int]:
    """Add what the pressure names (module doc) as one step: its sensor offsets and TDC offsets only if the run with
    them does not make the speed or the balance worse on the held-out cycles (``channel_worse``; refused and said
    otherwise), its
    misfires and leaks as they are (the monitor reads them in the pressure: the run does not change). Returns the model, its
    run, its held-out part and the monitor runs spent. A misfire must show in the training and the held-out cycles
    (cycle index ``first`` on, held out from ``held``); a leak is sized with ``share`` (pressure_findings)."""
    scored = cur_res.take(cur_res.index >= first)
    have = {(e.name, e.values.get("cylinder")) for e in current.effects}  # a model that states one already: left
    findings = [f for f in pressure_findings(scored, (scored.index < held, scored.index >= held), current.spec,
                                                 share)
                if (f.effect, f.cylinder) not in have]
    if not findings:
        return current, cur_res, test, 0
    res, runs, kept = cur_res, 0, []
    # the sensor corrections, the peggings first and then the TDC offsets on top, each kept only where its run does
    # not make the speed or the balance worse on the held-out cycles; a refused group stays out, said
    for group in [[f for f in findings if f.effect == name] for name in ("pressure_offset", "tdc_offset")]:
        if not group:
            continue
        if group[0].effect == "tdc_offset":  # the speed refines each within the pressure's noise (pressure_tdc)
            group, run, spent = refined_by_speed(with_findings(current, kept), group, full, lambda r: parts(r)[0],
                                                 scale, feature_floor(parts(res)[0], scale))
        else:
            run, spent = full(with_findings(current, kept + group)), 1
        runs += spent
        why = channel_worse(parts(res)[1], parts(run)[1], scale)
        if why:
            found.refused += [{"candidate": f.label, "reason": why, "channel": "pressure",
                               "gap_before": gap(parts(res)[1], scale), "gap_after": gap(parts(run)[1], scale)}
                              for f in group]
        else:
            res, kept = run, kept + group
    found.held = [f for f in kept if f.effect == "tdc_offset"]
    findings = kept + [f for f in findings if f.effect in ("misfire", "blow_by")]  # in the order they are added
    if not findings:
        return current, cur_res, test, runs
    new_model = with_findings(current, findings)
    test_new = parts(res)[1]
    added = new_model.effects[-len(findings):]
    found.steps.append(Step(None, added[0], gap(test, scale), gap(test_new, scale), chi2(test, scale),
                            chi2(test_new, scale), None, localise(test, current.spec, scale),
                            localise(test_new, current.spec, scale), added[1:], tuple(f.reading for f in findings)))
    found.curves.append((f"+ {found.steps[-1].label}", test_new.angles, test_new.speed.mean(axis=0)))
    return new_model, res, test_new, runs


__all__ = ["discover"]
